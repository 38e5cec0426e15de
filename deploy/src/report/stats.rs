//! The pairwise Mann-Whitney test of Table 2's scores: does one method's seeds score higher than
//! another's more often than chance would have it?
//!
//! `U` is the number of (seed of A, seed of B) pairs where A scored higher, a tie counting ½, out
//! of nA·nB. The p value is exact and two-sided: the share of all C(nA + nB, nA) ways to split
//! the pooled scores into groups of nA and nB whose U lies at least as far from its centre nA·nB/2
//! as the observed one. With few seeds that share cannot be small: its least value is
//! 2 / C(nA + nB, nA) (only the two fully separated splits are as extreme), 0.10 for 3 vs 3
//! seeds, so there no difference at all can reach p < 0.05; [`smallest_p`] says which floor
//! applies, and the report prints it beside every p.
//!
//! The splits are counted, not listed: U of a split is its group A's sum of (mid)ranks in the
//! pooled values less nA(nA + 1)/2, so counting the subsets of nA ranks by their sum (a dynamic
//! programme over the pooled values) gives the same share as enumerating every split, exactly,
//! with ties, in time polynomial in the seeds (no normal approximation needed at any seed count a
//! report will hold; beyond [`MAX_POOLED`] pooled seeds the test is not computed and the report
//! says so). Ranks are doubled so that midranks are integers and no comparison is of floats.

/// The test of A against B.
#[derive(Clone, Debug, PartialEq)]
pub struct MannWhitney {
    /// Pairs where A scored higher, ties counting ½.
    pub u: f64,
    /// nA·nB, the number of pairs.
    pub pairs: usize,
    /// Exact two-sided p.
    pub p: f64,
}

/// Why a test was not computed.
#[derive(Clone, Debug, PartialEq)]
pub enum NoTest {
    /// A group has no scores.
    Empty,
    /// A score is NaN or infinite (a broken fresh evaluation): no ranking is defined.
    NotFinite,
    /// More pooled seeds than [`MAX_POOLED`].
    TooMany(usize),
}

impl std::fmt::Display for NoTest {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            NoTest::Empty => write!(f, "a method has no finished seed"),
            NoTest::NotFinite => write!(f, "a score is not a finite number"),
            NoTest::TooMany(n) => write!(
                f,
                "{n} seeds pooled, more than the {MAX_POOLED} the exact count is made for"
            ),
        }
    }
}

/// The most pooled seeds the exact count is run for: it takes about n · nA · n² additions,
/// 8·10⁸ at 200 (a second or so); no experiment here comes near.
pub const MAX_POOLED: usize = 200;

/// U of `a` over `b`: pairs where a's value is higher, ties counting ½.
pub fn u_statistic(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .flat_map(|x| b.iter().map(move |y| (x, y)))
        .map(|(x, y)| {
            if x > y {
                1.0
            } else if x == y {
                0.5
            } else {
                0.0
            }
        })
        .sum()
}

/// C(n, k) as f64 (exact for every count a report meets: below 2⁵³ up to n ≈ 55).
fn choose(n: usize, k: usize) -> f64 {
    let k = k.min(n.saturating_sub(k));
    (0..k).fold(1.0, |c, i| c * (n - i) as f64 / (i + 1) as f64)
}

/// The least p any split of nA and nB distinct values can give: 2 / C(nA + nB, nA), capped at 1
/// (1 vs 1: both splits are equally extreme). Ties can only raise it.
pub fn smallest_p(na: usize, nb: usize) -> f64 {
    if na == 0 || nb == 0 {
        return 1.0;
    }
    (2.0 / choose(na + nb, na)).min(1.0)
}

/// Doubled midranks (1-based) of `v`: tied values share the mean of their ranks; doubled, that
/// mean is an integer.
fn doubled_midranks(v: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..v.len()).collect();
    order.sort_by(|&i, &j| v[i].total_cmp(&v[j]));
    let mut ranks = vec![0; v.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && v[order[j + 1]] == v[order[i]] {
            j += 1;
        }
        // Positions i..=j (0-based) hold ranks i+1..=j+1, whose mean doubled is i + j + 2.
        for &o in &order[i..=j] {
            ranks[o] = i + j + 2;
        }
        i = j + 1;
    }
    ranks
}

/// The exact two-sided Mann-Whitney test of `a` against `b`.
pub fn mann_whitney(a: &[f64], b: &[f64]) -> Result<MannWhitney, NoTest> {
    let (na, nb) = (a.len(), b.len());
    if na == 0 || nb == 0 {
        return Err(NoTest::Empty);
    }
    if a.iter().chain(b).any(|v| !v.is_finite()) {
        return Err(NoTest::NotFinite);
    }
    let n = na + nb;
    if n > MAX_POOLED {
        return Err(NoTest::TooMany(n));
    }
    let pooled: Vec<f64> = a.iter().chain(b).copied().collect();
    let ranks = doubled_midranks(&pooled);
    // 2U = (doubled rank sum of A) − nA(nA + 1); its centre, 2 · nA·nB/2 = nA·nB. All integers.
    let centre = (na * nb) as i64;
    let offset = (na * (na + 1)) as i64;
    let distance = |sum2: usize| (sum2 as i64 - offset - centre).abs();
    let observed = distance(ranks[..na].iter().sum());
    // count[k][s]: subsets of k of the values seen so far whose doubled ranks sum to s.
    let max_sum: usize = ranks.iter().sum();
    let mut count = vec![vec![0.0f64; max_sum + 1]; na + 1];
    count[0][0] = 1.0;
    for &r in &ranks {
        for k in (1..=na).rev() {
            let (lower, upper) = count.split_at_mut(k);
            for s in (r..=max_sum).rev() {
                upper[0][s] += lower[k - 1][s - r];
            }
        }
    }
    let far: f64 = count[na]
        .iter()
        .enumerate()
        .filter(|(s, c)| **c > 0.0 && distance(*s) >= observed)
        .map(|(_, c)| c)
        .sum();
    Ok(MannWhitney {
        u: u_statistic(a, b),
        pairs: na * nb,
        p: (far / choose(n, na)).min(1.0),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn fully_separated_three_against_three_is_u_0_of_9_p_one_tenth() {
        // Pooled 1..6; C(6,3) = 20 splits. |U − 4.5| ≥ 4.5 only for U = 0 ({1,2,3} low) and
        // U = 9 ({4,5,6} low): 2 of 20 = 0.10, the least 3 vs 3 seeds allow.
        let t = mann_whitney(&[1.0, 2.0, 3.0], &[4.0, 5.0, 6.0]).unwrap();
        assert_eq!((t.u, t.pairs), (0.0, 9));
        assert!(close(t.p, 0.10), "{t:?}");
        assert!(close(smallest_p(3, 3), 0.10));
        // The other way round: U = 9 of 9, the same p.
        let t = mann_whitney(&[4.0, 5.0, 6.0], &[1.0, 2.0, 3.0]).unwrap();
        assert_eq!(t.u, 9.0);
        assert!(close(t.p, 0.10));
    }

    #[test]
    fn three_against_two_with_u_4_of_6() {
        // A = {1, 4, 5}, B = {2, 3}: A beats B in (4,2) (4,3) (5,2) (5,3): U = 4 of 6, centre 3,
        // |U − 3| = 1. Over the C(5,3) = 10 splits of ranks 1..5, U = (rank sum of A) − 6; the
        // 3-subsets by sum (complements of the 2-subsets {1,2}..{4,5}): sum 6: 1, 7: 1, 8: 2,
        // 9: 2, 10: 2, 11: 1, 12: 1, i.e. U = 0..6 with counts 1,1,2,2,2,1,1. |U − 3| ≥ 1 for
        // all but U = 3: 10 − 2 = 8 splits, p = 0.8.
        let t = mann_whitney(&[1.0, 4.0, 5.0], &[2.0, 3.0]).unwrap();
        assert_eq!((t.u, t.pairs), (4.0, 6));
        assert!(close(t.p, 0.8), "{t:?}");
        // 2 / C(5,3) = 0.2.
        assert!(close(smallest_p(3, 2), 0.2));
    }

    #[test]
    fn ties_count_half_and_keep_their_midranks() {
        // A = {1, 2}, B = {2, 3}: (1,2) 0, (1,3) 0, (2,2) ½, (2,3) 0: U = 0.5 of 4, centre 2,
        // distance 1.5. The C(4,2) = 6 splits of {1, 2, 2', 3}: A = {1,2} or {1,2'}: U = 0.5;
        // {1,3}: U = 2 (3 beats both 2s); {2,2'}: U = 2 (each beats 1, loses to 3);
        // {2,3} or {2',3}: U = 3.5. Distance ≥ 1.5 for 4 of 6: p = 2/3.
        let t = mann_whitney(&[1.0, 2.0], &[2.0, 3.0]).unwrap();
        assert_eq!((t.u, t.pairs), (0.5, 4));
        assert!(close(t.p, 2.0 / 3.0), "{t:?}");
        // All tied: every split has U = centre, p = 1.
        let t = mann_whitney(&[7.0, 7.0], &[7.0, 7.0, 7.0]).unwrap();
        assert_eq!(t.u, 3.0);
        assert!(close(t.p, 1.0), "{t:?}");
    }

    #[test]
    fn one_seed_against_one_can_never_differ() {
        // Two splits, U = 1 and U = 0, both ½ from the centre ½: p = 1 whoever wins.
        let t = mann_whitney(&[5.0], &[3.0]).unwrap();
        assert_eq!((t.u, t.pairs), (1.0, 1));
        assert!(close(t.p, 1.0));
        let t = mann_whitney(&[4.0], &[4.0]).unwrap();
        assert_eq!(t.u, 0.5);
        assert!(close(t.p, 1.0));
        assert!(close(smallest_p(1, 1), 1.0));
    }

    #[test]
    fn five_against_five_separated_reaches_below_one_percent() {
        // C(10,5) = 252: 2/252.
        let t = mann_whitney(&[10.0, 11.0, 12.0, 13.0, 14.0], &[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
        assert_eq!(t.u, 25.0);
        assert!(close(t.p, 2.0 / 252.0), "{t:?}");
        assert!(close(smallest_p(5, 5), 2.0 / 252.0));
    }

    #[test]
    fn bad_scores_are_no_test_not_a_panic() {
        assert_eq!(mann_whitney(&[], &[1.0]), Err(NoTest::Empty));
        assert_eq!(mann_whitney(&[f64::NAN], &[1.0]), Err(NoTest::NotFinite));
        let big = vec![1.0; 150];
        assert_eq!(mann_whitney(&big, &big), Err(NoTest::TooMany(300)));
    }

    /// Every split listed, as the definition says, to check the counting on values with ties.
    fn listed(a: &[f64], b: &[f64]) -> f64 {
        let pooled: Vec<f64> = a.iter().chain(b).copied().collect();
        let (n, na) = (pooled.len(), a.len());
        let centre = (a.len() * b.len()) as f64 / 2.0;
        let observed = (u_statistic(a, b) - centre).abs();
        let (mut far, mut all) = (0u64, 0u64);
        for mask in 0u32..(1 << n) {
            if mask.count_ones() as usize != na {
                continue;
            }
            let (x, y): (Vec<(usize, f64)>, Vec<(usize, f64)>) = pooled
                .iter()
                .copied()
                .enumerate()
                .partition(|(i, _)| mask & (1 << i) != 0);
            let x: Vec<f64> = x.into_iter().map(|p| p.1).collect();
            let y: Vec<f64> = y.into_iter().map(|p| p.1).collect();
            all += 1;
            if (u_statistic(&x, &y) - centre).abs() >= observed - 1e-9 {
                far += 1;
            }
        }
        far as f64 / all as f64
    }

    #[test]
    fn counting_agrees_with_listing_every_split() {
        let cases: [(&[f64], &[f64]); 5] = [
            (&[3.0, 1.0, 4.0, 1.0, 5.0], &[9.0, 2.0, 6.0, 5.0]),
            (&[2.0, 2.0, 2.0], &[1.0, 2.0, 3.0, 3.0]),
            (
                &[0.5, 0.25, 0.5, 1.0, 0.0, 0.75],
                &[0.5, 0.5, 1.0, 0.0, 0.25],
            ),
            (&[-150.0, -120.0, -90.0, -200.0], &[-100.0, -130.0, -160.0]),
            (&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0], &[2.5, 3.5, 8.0]),
        ];
        for (a, b) in cases {
            let t = mann_whitney(a, b).unwrap();
            assert!(
                close(t.p, listed(a, b)),
                "{a:?} {b:?}: {t:?} vs {}",
                listed(a, b)
            );
        }
    }
}
