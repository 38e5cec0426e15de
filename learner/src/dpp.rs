//! DNS's critic sampler (Sheikh, Frisbee, Phielipp, ICML 2022): which k of the N critics an
//! update trains, drawn from a k-DPP whose kernel is the critics' similarity on the batch.
//!
//! - Similarity: linear CKA (Kornblith et al. 2019) between two critics' Q-values on the batch's
//!   (s, a) pairs. For one feature per example (a critic's Q-value) linear CKA is the squared
//!   Pearson correlation of the two value vectors.
//! - Kernel: that N × N matrix, made positive semi-definite if round-off left it slightly
//!   indefinite (negative eigenvalues set to 0, as DNS's code does after Higham).
//! - Sampler: an exact k-DPP draw (Kulesza & Taskar 2012, Algorithms 1 and 8): P(S) ∝ det(L_S)
//!   over the k-subsets S, so critics whose values move together are rarely trained together.
//!   If the kernel's rank is below k, k drops to the rank (DNS's code does the same).
//!
//! Plain f64 on N ≤ a few dozen: a Jacobi eigen-decomposition and O(N k²) sampling, microseconds
//! beside an update.

use rand::Rng;

/// Linear CKA between every pair of critics' value vectors `q[j]` (each of the batch's length):
/// `⟨q̃_i, q̃_j⟩² / (‖q̃_i‖² ‖q̃_j‖²)` with q̃ centred; 1 on the diagonal. A constant vector
/// (no variance) is taken as unlike every other (0), like itself (1).
pub fn linear_cka(q: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let centred: Vec<Vec<f64>> = q
        .iter()
        .map(|v| {
            let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
            v.iter().map(|x| x - mean).collect()
        })
        .collect();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let n = q.len();
    let mut k = vec![vec![0.0; n]; n];
    for i in 0..n {
        k[i][i] = 1.0;
        for j in 0..i {
            let (a, b) = (&centred[i], &centred[j]);
            let denom = dot(a, a) * dot(b, b);
            let s = if denom > 0.0 {
                dot(a, b).powi(2) / denom
            } else {
                0.0
            };
            k[i][j] = s;
            k[j][i] = s;
        }
    }
    k
}

/// Eigen-decomposition of a symmetric matrix by cyclic Jacobi rotations: (eigenvalues,
/// eigenvectors as columns `v[row][col]`).
// The rotations index rows and columns as the textbook writes them.
#[allow(clippy::needless_range_loop)]
pub fn symmetric_eigen(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut a: Vec<Vec<f64>> = a.to_vec();
    let mut v = vec![vec![0.0; n]; n];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let scale: f64 = (0..n).map(|i| a[i][i] * a[i][i]).sum::<f64>().max(1e-300);
        if off <= 1e-30 * scale {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                // The rotation that zeroes a[p][q] (Golub & Van Loan, 8.4).
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vkp, vkq) = (row[p], row[q]);
                    row[p] = c * vkp - s * vkq;
                    row[q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i][i]).collect(), v)
}

/// The elementary symmetric polynomials `e[l][m]` of the first m eigenvalues, l = 0..=k.
fn elementary_symmetric(lambda: &[f64], k: usize) -> Vec<Vec<f64>> {
    let n = lambda.len();
    let mut e = vec![vec![0.0; n + 1]; k + 1];
    e[0].iter_mut().for_each(|x| *x = 1.0);
    for l in 1..=k {
        for m in 1..=n {
            e[l][m] = e[l][m - 1] + lambda[m - 1] * e[l - 1][m - 1];
        }
    }
    e
}

/// One exact draw of a k-DPP with kernel `l` (symmetric; negative eigenvalues from round-off are
/// set to 0): k distinct indices, in increasing order. k is capped at the kernel's rank.
pub fn sample_k_dpp(l: &[Vec<f64>], k: usize, rng: &mut impl Rng) -> Vec<usize> {
    let n = l.len();
    let (mut lambda, vecs) = symmetric_eigen(l);
    let top = lambda.iter().cloned().fold(0.0f64, f64::max);
    for x in lambda.iter_mut() {
        if *x < 1e-12 * top.max(1e-300) {
            *x = 0.0;
        }
    }
    let rank = lambda.iter().filter(|&&x| x > 0.0).count();
    let k = k.min(rank).min(n);
    if k == 0 {
        return vec![];
    }
    // Algorithm 8: pick k eigenvectors, eigenvector m with probability λ_m e_{l-1}^{m-1} / e_l^m.
    let e = elementary_symmetric(&lambda, k);
    let mut chosen = vec![];
    let mut left = k;
    for m in (1..=n).rev() {
        if left == 0 {
            break;
        }
        let p = if left == m {
            1.0
        } else {
            lambda[m - 1] * e[left - 1][m - 1] / e[left][m]
        };
        if rng.gen::<f64>() < p {
            chosen.push(m - 1);
            left -= 1;
        }
    }
    // Algorithm 1, second phase: the elementary DPP of the chosen eigenvectors.
    let mut basis: Vec<Vec<f64>> = chosen
        .iter()
        .map(|&c| (0..n).map(|r| vecs[r][c]).collect())
        .collect();
    let mut items = vec![];
    while !basis.is_empty() {
        // P(i) = (1/|V|) Σ_v v_i².
        let weights: Vec<f64> = (0..n)
            .map(|i| basis.iter().map(|v| v[i] * v[i]).sum::<f64>())
            .collect();
        let total: f64 = weights.iter().sum();
        let mut u = rng.gen::<f64>() * total;
        let mut item = n - 1;
        for (i, w) in weights.iter().enumerate() {
            if items.contains(&i) {
                continue;
            }
            if u < *w {
                item = i;
                break;
            }
            u -= w;
        }
        while items.contains(&item) {
            item -= 1; // round-off at the end of the scan
        }
        items.push(item);
        // V ← an orthonormal basis of V's part orthogonal to e_item: eliminate the vector with the
        // largest entry at `item` from the others, drop it, then Gram–Schmidt.
        let pivot = (0..basis.len())
            .max_by(|&a, &b| basis[a][item].abs().total_cmp(&basis[b][item].abs()))
            .expect("non-empty basis");
        let pv = basis.swap_remove(pivot);
        for v in basis.iter_mut() {
            let f = v[item] / pv[item];
            for (x, p) in v.iter_mut().zip(&pv) {
                *x -= f * p;
            }
            v[item] = 0.0;
        }
        let mut orthonormal: Vec<Vec<f64>> = vec![];
        for mut v in basis.drain(..) {
            for o in &orthonormal {
                let d: f64 = v.iter().zip(o).map(|(a, b)| a * b).sum();
                for (x, y) in v.iter_mut().zip(o) {
                    *x -= d * y;
                }
            }
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > 1e-12 {
                v.iter_mut().for_each(|x| *x /= norm);
                orthonormal.push(v);
            }
        }
        basis = orthonormal;
    }
    items.sort_unstable();
    items
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Determinant by Gaussian elimination with partial pivoting (plain, for the reference).
    #[allow(clippy::needless_range_loop)]
    fn det(m: &[Vec<f64>]) -> f64 {
        let mut a = m.to_vec();
        let n = a.len();
        let mut d = 1.0;
        for c in 0..n {
            let p = (c..n)
                .max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))
                .unwrap();
            if a[p][c] == 0.0 {
                return 0.0;
            }
            if p != c {
                a.swap(p, c);
                d = -d;
            }
            d *= a[c][c];
            for r in c + 1..n {
                let f = a[r][c] / a[c][c];
                for k in c..n {
                    a[r][k] -= f * a[c][k];
                }
            }
        }
        d
    }

    fn subsets(n: usize, k: usize) -> Vec<Vec<usize>> {
        (0u32..1 << n)
            .filter(|m| m.count_ones() as usize == k)
            .map(|m| (0..n).filter(|i| m >> i & 1 == 1).collect())
            .collect()
    }

    fn minor(l: &[Vec<f64>], s: &[usize]) -> Vec<Vec<f64>> {
        s.iter()
            .map(|&i| s.iter().map(|&j| l[i][j]).collect())
            .collect()
    }

    /// A small kernel of the kind DNS builds: squared correlations of five value vectors, two
    /// pairs of them nearly alike.
    fn kernel() -> Vec<Vec<f64>> {
        let base: Vec<Vec<f64>> = (0..3)
            .map(|c| {
                (0..40)
                    .map(|t| ((t * (c + 2)) as f64 * 0.37).sin())
                    .collect()
            })
            .collect();
        let q = vec![
            base[0].clone(),
            base[0]
                .iter()
                .enumerate()
                .map(|(t, x)| x + 0.2 * (t as f64 * 1.7).cos())
                .collect(),
            base[1].clone(),
            base[1]
                .iter()
                .enumerate()
                .map(|(t, x)| x + 0.3 * (t as f64 * 0.9).sin())
                .collect(),
            base[2].clone(),
        ];
        linear_cka(&q)
    }

    #[test]
    fn linear_cka_matches_the_gram_matrix_form() {
        // Kornblith et al.'s definition through centred Gram matrices K = x xᵀ, L = y yᵀ:
        // CKA = ⟨HKH, HLH⟩_F / (‖HKH‖_F ‖HLH‖_F).
        let x: Vec<f64> = (0..9).map(|t| (t as f64).sin() * 3.0 + 1.0).collect();
        let y: Vec<f64> = (0..9)
            .map(|t| (t as f64 * 0.5).cos() - (t as f64) * 0.1)
            .collect();
        let centred_gram = |v: &[f64]| {
            let n = v.len();
            let k: Vec<Vec<f64>> = (0..n)
                .map(|i| (0..n).map(|j| v[i] * v[j]).collect())
                .collect();
            let row: Vec<f64> = (0..n)
                .map(|i| k[i].iter().sum::<f64>() / n as f64)
                .collect();
            let all = row.iter().sum::<f64>() / n as f64;
            (0..n)
                .map(|i| {
                    (0..n)
                        .map(|j| k[i][j] - row[i] - row[j] + all)
                        .collect::<Vec<_>>()
                })
                .collect::<Vec<_>>()
        };
        let (gx, gy) = (centred_gram(&x), centred_gram(&y));
        let f = |a: &Vec<Vec<f64>>, b: &Vec<Vec<f64>>| {
            a.iter()
                .flatten()
                .zip(b.iter().flatten())
                .map(|(p, q)| p * q)
                .sum::<f64>()
        };
        let want = f(&gx, &gy) / (f(&gx, &gx).sqrt() * f(&gy, &gy).sqrt());
        let got = linear_cka(&[x.clone(), y.clone()]);
        assert!((got[0][1] - want).abs() < 1e-12, "{} vs {want}", got[0][1]);
        assert_eq!(got[0][0], 1.0);
        assert_eq!(got[0][1], got[1][0]);
        // Shifts and scales do not change it; a constant vector is unlike everything.
        let shifted: Vec<f64> = x.iter().map(|v| 5.0 - 2.0 * v).collect();
        assert!((linear_cka(&[x.clone(), shifted])[0][1] - 1.0).abs() < 1e-12);
        assert_eq!(linear_cka(&[x, vec![2.0; 9]])[0][1], 0.0);
    }

    #[test]
    fn eigen_decomposition_reconstructs_the_matrix() {
        let l = kernel();
        let (lambda, v) = symmetric_eigen(&l);
        let n = l.len();
        for i in 0..n {
            for j in 0..n {
                let r: f64 = (0..n).map(|m| v[i][m] * lambda[m] * v[j][m]).sum();
                assert!((r - l[i][j]).abs() < 1e-10, "({i},{j}): {r} vs {}", l[i][j]);
            }
        }
        assert!(
            lambda.iter().all(|&x| x > -1e-12),
            "a correlation² kernel is PSD: {lambda:?}"
        );
    }

    /// The sampler's frequencies over many draws against the k-DPP's exact probabilities
    /// det(L_S) / Σ_{|T|=k} det(L_T), computed here by enumerating every k-subset.
    #[test]
    fn k_dpp_draws_match_the_exact_subset_probabilities() {
        let l = kernel();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        for k in [1, 2, 3] {
            let all = subsets(5, k);
            let dets: Vec<f64> = all.iter().map(|s| det(&minor(&l, s))).collect();
            let z: f64 = dets.iter().sum();
            let draws = 40_000;
            let mut counts = vec![0usize; all.len()];
            for _ in 0..draws {
                let s = sample_k_dpp(&l, k, &mut rng);
                counts[all.iter().position(|t| *t == s).expect("a k-subset")] += 1;
            }
            for ((s, d), c) in all.iter().zip(&dets).zip(&counts) {
                let p = d / z;
                let f = *c as f64 / draws as f64;
                let sd = (p * (1.0 - p) / draws as f64).sqrt();
                assert!(
                    (f - p).abs() < 5.0 * sd + 1e-4,
                    "k = {k}, {s:?}: drawn {f:.4}, exact {p:.4}"
                );
            }
            if k == 2 {
                // The nearly alike pairs (0, 1) and (2, 3) are the least likely pairs.
                let p = |s: &[usize]| dets[all.iter().position(|t| t == s).unwrap()] / z;
                assert!(p(&[0, 1]) < p(&[0, 2]) && p(&[2, 3]) < p(&[1, 3]));
            }
        }
    }

    #[test]
    fn k_is_capped_at_the_kernels_rank() {
        // Three identical critics and one other: rank 2.
        let q = vec![
            vec![1.0, 2.0, 4.0],
            vec![1.0, 2.0, 4.0],
            vec![1.0, 2.0, 4.0],
            vec![3.0, 1.0, 2.0],
        ];
        let l = linear_cka(&q);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        for _ in 0..100 {
            let s = sample_k_dpp(&l, 3, &mut rng);
            assert_eq!(s.len(), 2, "{s:?}");
            assert!(s.contains(&3), "two alike critics never go together: {s:?}");
        }
    }
}
