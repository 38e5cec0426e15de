//! Table 2: per task, each method's final score (mean ± sample std over its finished seeds), the
//! best mean in bold, as Markdown and CSV. Runs that stopped short of their budget are not in
//! the mean; their row is marked † and a footnote gives the env steps they reached.

use super::align::{mean, sample_std};
use std::fmt::Write as _;

/// One method on one task.
#[derive(Clone, Debug)]
pub struct Row {
    pub method: String,
    /// Each finished seed's score on the fresh episodes.
    pub scores: Vec<f64>,
    /// Each finished seed's in-run final evaluation of its ranked actor.
    pub in_run: Vec<f64>,
    /// `(seed, env steps reached, budget)` of runs that stopped short.
    pub short: Vec<(u64, u64, u64)>,
}

impl Row {
    pub fn score(&self) -> (f64, f64) {
        (mean(&self.scores), sample_std(&self.scores))
    }
    pub fn in_run(&self) -> (f64, f64) {
        (mean(&self.in_run), sample_std(&self.in_run))
    }
}

/// `mean ± std` with the precision a return (1 decimal) or a rate (3) needs.
pub fn pm(m: f64, s: f64, rate: bool) -> String {
    let d = if rate { 3 } else { 1 };
    let f = |v: f64| {
        if v.is_finite() {
            format!("{v:.d$}")
        } else {
            "n/a".to_string()
        }
    };
    format!("{} ± {}", f(m), f(s))
}

/// One task's table in Markdown (and its footnotes).
pub fn markdown(task: &str, rows: &[Row], rate: bool, episodes: usize) -> String {
    let best = rows
        .iter()
        .map(|r| r.score().0)
        .filter(|v| v.is_finite())
        .fold(f64::NAN, f64::max);
    let what = if rate { "success rate" } else { "mean return" };
    let mut s = String::new();
    let _ = writeln!(s, "#### `{task}`\n");
    let _ = writeln!(
        s,
        "| method | finished seeds | score: {what} on {episodes} fresh episodes, mean ± std | in-run final evaluation of the ranked actor, mean ± std |"
    );
    let _ = writeln!(s, "|---|---|---|---|");
    let mut notes = Vec::new();
    for r in rows {
        let (m, sd) = r.score();
        let mut score = pm(m, sd, rate);
        if m.is_finite() && m == best {
            score = format!("**{score}**");
        }
        let (im, isd) = r.in_run();
        let mark = if r.short.is_empty() { "" } else { " †" };
        let _ = writeln!(
            s,
            "| {} | {}{mark} | {score} | {} |",
            r.method,
            r.scores.len(),
            pm(im, isd, rate)
        );
        for (seed, steps, budget) in &r.short {
            notes.push(format!(
                "† {}: seed-{seed} stopped at {steps} of {budget} env steps; it is not in the mean.",
                r.method
            ));
        }
    }
    for n in notes {
        let _ = writeln!(s, "\n{n}");
    }
    s
}

/// `table2.csv`: every task's rows, numbers at full precision.
pub fn csv(tasks: &[(String, bool, Vec<Row>)]) -> String {
    let mut s = String::from(
        "task,method,score,finished_seeds,score_mean,score_std,in_run_mean,in_run_std,short_runs\n",
    );
    for (task, rate, rows) in tasks {
        for r in rows {
            let (m, sd) = r.score();
            let (im, isd) = r.in_run();
            let short: Vec<String> = r
                .short
                .iter()
                .map(|(seed, steps, budget)| format!("seed-{seed}@{steps}/{budget}"))
                .collect();
            let _ = writeln!(
                s,
                "{task},{},{},{},{m},{sd},{im},{isd},{}",
                r.method,
                if *rate { "success_rate" } else { "return" },
                r.scores.len(),
                short.join(";")
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_best_mean_is_bold_and_a_short_run_is_marked_not_averaged() {
        let rows = vec![
            Row {
                method: "a".into(),
                scores: vec![-100.0, -200.0],
                in_run: vec![-90.0, -110.0],
                short: vec![],
            },
            Row {
                method: "b".into(),
                scores: vec![-50.0],
                in_run: vec![-40.0],
                short: vec![(2, 1500, 2000)],
            },
        ];
        let md = markdown("pendulum", &rows, false, 20);
        // Sample std of {-100, -200}: 70.7.
        assert!(
            md.contains("| a | 2 | -150.0 ± 70.7 | -100.0 ± 14.1 |"),
            "{md}"
        );
        assert!(md.contains("| b | 1 † | **-50.0 ± n/a** |"), "{md}");
        assert!(
            md.contains("† b: seed-2 stopped at 1500 of 2000 env steps"),
            "{md}"
        );
        let csv = csv(&[("pendulum".into(), false, rows)]);
        assert!(
            csv.contains("pendulum,b,return,1,-50,NaN,-40,NaN,seed-2@1500/2000"),
            "{csv}"
        );
    }
}
