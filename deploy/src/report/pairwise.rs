//! Pairwise Mann-Whitney tests of Table 2's scores, per task: every pair of methods with finished
//! seeds there, as Markdown (under the task's Table 2) and as `pairwise.csv`.
//!
//! Each table says the least p its seed counts allow: with 3 seeds against 3 no pair can reach
//! p < 0.05 whatever the scores, and a reader who does not know that would read "p = 0.10" as
//! "nearly significant" rather than "as separated as three seeds can be".

use super::stats::{mann_whitney, smallest_p, MannWhitney, NoTest};
use super::table::Row;
use std::fmt::Write as _;

/// One pair's test: `a` against `b` (U counts a's wins).
pub struct Pair<'a> {
    pub a: &'a Row,
    pub b: &'a Row,
    pub test: Result<MannWhitney, NoTest>,
}

/// Every pair (in table order) of rows that both have finished seeds.
pub fn pairs(rows: &[Row]) -> Vec<Pair<'_>> {
    let scored: Vec<&Row> = rows.iter().filter(|r| !r.scores.is_empty()).collect();
    let mut out = Vec::new();
    for (i, a) in scored.iter().enumerate() {
        for b in &scored[i + 1..] {
            out.push(Pair {
                a,
                b,
                test: mann_whitney(&a.scores, &b.scores),
            });
        }
    }
    out
}

/// p with the digits it needs: 0.100, 0.008, 2.2e-5.
pub fn fmt_p(p: f64) -> String {
    if p >= 0.001 {
        format!("{p:.3}")
    } else {
        format!("{p:.1e}")
    }
}

/// The task's pairwise table and what the seed counts allow.
pub fn markdown(rows: &[Row], rate: bool) -> String {
    let what = if rate { "success rate" } else { "mean return" };
    let ps = pairs(rows);
    let mut s = String::new();
    if ps.is_empty() {
        let _ = writeln!(
            s,
            "Pairwise Mann-Whitney tests: none; they need two methods with finished seeds on this task.\n"
        );
        return s;
    }
    let _ = writeln!(
        s,
        "Pairwise Mann-Whitney tests on the score ({what} on the fresh episodes, one number per seed; each method at its own budget): U is the number of (seed of A, seed of B) pairs where A scored higher, a tie counting ½, out of nA·nB; p is exact and two-sided (the share of all splits of the pooled scores into groups of nA and nB whose U is at least as far from nA·nB/2), per pair, not corrected for the {} pairs tested.\n",
        ps.len()
    );
    let _ = writeln!(
        s,
        "| A | B | seeds A + B | U (A > B) of nA·nB | p | least p these seeds allow |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for p in &ps {
        let (na, nb) = (p.a.scores.len(), p.b.scores.len());
        let (u, pv) = match &p.test {
            Ok(t) => (format!("{} of {}", t.u, t.pairs), fmt_p(t.p)),
            Err(e) => ("–".to_string(), format!("not computed: {e}")),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {na} + {nb} | {u} | {pv} | {} |",
            p.a.method,
            p.b.method,
            fmt_p(smallest_p(na, nb))
        );
    }
    // The floor: 2 / C(nA + nB, nA), reached only when every seed of one beats every seed of
    // the other; a reader must know it before reading any p.
    let floors: Vec<f64> = ps
        .iter()
        .map(|p| smallest_p(p.a.scores.len(), p.b.scores.len()))
        .collect();
    let blocked = floors.iter().filter(|f| **f >= 0.05).count();
    let lowest = floors.iter().copied().fold(f64::INFINITY, f64::min);
    let _ = write!(
        s,
        "\nThe least p a pair can reach is 2 / C(nA + nB, nA), when every seed of one method beats every seed of the other (last column; 0.100 at 3 vs 3 seeds, 0.008 at 5 vs 5); the lowest here is {}. ",
        fmt_p(lowest)
    );
    if blocked == ps.len() {
        let _ = writeln!(s, "**With these seed counts no pair can reach p < 0.05, whatever the scores**: read U as how often one method's seed beat the other's, not as a verdict.\n");
    } else if blocked > 0 {
        let _ = writeln!(s, "**{blocked} of the {} pairs cannot reach p < 0.05 with their seed counts, whatever the scores.**\n", ps.len());
    } else {
        let _ = writeln!(s, "Every pair can reach p < 0.05 with its seed counts.\n");
    }
    s
}

/// `pairwise.csv`: every task's pairs, p at full precision.
pub fn csv(tasks: &[(String, bool, Vec<Row>)]) -> String {
    let mut s = String::from(
        "task,score,method_a,method_b,seeds_a,seeds_b,u,pairs,p,least_p,budget_env_steps_a,budget_env_steps_b,note\n",
    );
    for (task, rate, rows) in tasks {
        for p in pairs(rows) {
            let (na, nb) = (p.a.scores.len(), p.b.scores.len());
            let (u, pv, note) = match &p.test {
                Ok(t) => (t.u.to_string(), t.p.to_string(), String::new()),
                Err(e) => (String::new(), String::new(), e.to_string()),
            };
            let _ = writeln!(
                s,
                "{task},{},{},{},{na},{nb},{u},{},{pv},{},{},{},{note}",
                if *rate { "success_rate" } else { "return" },
                p.a.method,
                p.b.method,
                na * nb,
                smallest_p(na, nb),
                p.a.budget.env_steps,
                p.b.budget.env_steps,
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::super::table::Budget;
    use super::*;

    fn row(method: &str, scores: &[f64]) -> Row {
        Row {
            method: method.into(),
            scores: scores.to_vec(),
            in_run: scores.to_vec(),
            late: scores.to_vec(),
            short: vec![],
            budget: Budget {
                env_steps: 1000,
                rounds: 1000,
                actors: 1,
                in_rounds: false,
            },
        }
    }

    #[test]
    fn three_seeds_each_say_no_pair_can_reach_five_percent() {
        let rows = vec![
            row("a", &[1.0, 2.0, 3.0]),
            row("b", &[4.0, 5.0, 6.0]),
            row("c", &[]),
            row("d", &[1.5, 5.5, 2.5]),
        ];
        let md = markdown(&rows, false);
        // c has no finished seed: pairs a-b, a-d, b-d only.
        assert!(
            md.contains("| a | b | 3 + 3 | 0 of 9 | 0.100 | 0.100 |"),
            "{md}"
        );
        // b over d: 4>1.5, 4>2.5, 5>1.5, 5>2.5, 6>1.5, 6>2.5, 6>5.5 = 7 of 9 (4<5.5, 5<5.5).
        assert!(md.contains("| b | d | 3 + 3 | 7 of 9 |"), "{md}");
        assert!(
            !md.contains("| c |") && md.contains("the 3 pairs tested"),
            "{md}"
        );
        assert!(md.contains("no pair can reach p < 0.05"), "{md}");
        let csv = csv(&[("t".into(), false, rows)]);
        assert!(
            csv.contains("t,return,a,b,3,3,0,9,0.1,0.1,1000,1000,\n"),
            "{csv}"
        );
        assert_eq!(csv.lines().count(), 4);
    }

    #[test]
    fn five_seeds_each_can_reach_it_and_one_method_has_no_pair() {
        let rows = vec![
            row("a", &[1.0, 2.0, 3.0, 4.0, 5.0]),
            row("b", &[6.0, 7.0, 8.0, 9.0, 10.0]),
        ];
        let md = markdown(&rows, false);
        assert!(
            md.contains("| a | b | 5 + 5 | 0 of 25 | 0.008 | 0.008 |"),
            "{md}"
        );
        assert!(md.contains("Every pair can reach p < 0.05"), "{md}");
        let md = markdown(&rows[..1], false);
        assert!(md.contains("none; they need two methods"), "{md}");
        let rows = vec![row("a", &[1.0, f64::NAN]), row("b", &[2.0])];
        let md = markdown(&rows, false);
        assert!(
            md.contains("| – | not computed: a score is not a finite number |"),
            "{md}"
        );
    }
}
