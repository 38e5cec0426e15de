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
    /// Each finished seed's mean in-run evaluation of its ranked actor over the last fifth of
    /// the budget ([`super::runs::Metrics::late_ranked`]).
    pub late: Vec<f64>,
    /// `(seed, env steps reached, budget)` of runs that stopped short.
    pub short: Vec<(u64, u64, u64)>,
    /// The method's budget on this task (its runs share one config, so one budget).
    pub budget: Budget,
}

/// A run's budget in both units, and the unit it was set in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Budget {
    pub env_steps: u64,
    pub rounds: u64,
    pub actors: u64,
    pub in_rounds: bool,
}

impl Budget {
    pub fn unit(&self) -> &'static str {
        if self.in_rounds {
            "rounds"
        } else {
            "env_steps"
        }
    }

    /// `6000 env steps = 2000 rounds × K = 3`, the unit it was set in first.
    pub fn text(&self) -> String {
        let (e, r, k) = (self.env_steps, self.rounds, self.actors);
        if self.in_rounds {
            format!("{r} rounds × K = {k} = {e} env steps")
        } else {
            format!("{e} env steps = {r} rounds × K = {k}")
        }
    }
}

impl Row {
    pub fn score(&self) -> (f64, f64) {
        (mean(&self.scores), sample_std(&self.scores))
    }
    pub fn in_run(&self) -> (f64, f64) {
        (mean(&self.in_run), sample_std(&self.in_run))
    }
    pub fn late(&self) -> (f64, f64) {
        (mean(&self.late), sample_std(&self.late))
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
    // Which budget the scores are at: one for the whole table, or say that they differ (SELKD
    // at equal rounds has K× the env steps of a K = 1 baseline; a reader must see that here).
    let first = rows.first().map(|r| r.budget);
    let at = match first {
        Some(b) if rows.iter().all(|r| r.budget == b) => format!("all at {}", b.text()),
        Some(_)
            if rows
                .iter()
                .all(|r| r.budget.env_steps == rows[0].budget.env_steps) =>
        {
            format!("all at equal env steps, {}", rows[0].budget.env_steps)
        }
        Some(_)
            if rows
                .iter()
                .all(|r| r.budget.rounds == rows[0].budget.rounds) =>
        {
            format!("all at equal rounds, {}", rows[0].budget.rounds)
        }
        _ => "budgets differ between methods: see the budget column".to_string(),
    };
    let _ = writeln!(s, "#### `{task}` ({at})\n");
    let _ = writeln!(
        s,
        "| method | budget | finished seeds | score: {what} on {episodes} fresh episodes, mean ± std | in-run final evaluation of the ranked actor, mean ± std | in-run evaluations of the ranked actor over the budget's last fifth, mean ± std |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    let mut notes = Vec::new();
    for r in rows {
        let (m, sd) = r.score();
        let mut score = pm(m, sd, rate);
        if m.is_finite() && m == best {
            score = format!("**{score}**");
        }
        let (im, isd) = r.in_run();
        let (lm, lsd) = r.late();
        let mark = if r.short.is_empty() { "" } else { " †" };
        let _ = writeln!(
            s,
            "| {} | {} | {}{mark} | {score} | {} | {} |",
            r.method,
            r.budget.text(),
            r.scores.len(),
            pm(im, isd, rate),
            pm(lm, lsd, rate)
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
        "task,method,score,finished_seeds,score_mean,score_std,in_run_mean,in_run_std,short_runs,budget_env_steps,budget_rounds,actors,budget_set_in,late_mean,late_std\n",
    );
    for (task, rate, rows) in tasks {
        for r in rows {
            let (m, sd) = r.score();
            let (im, isd) = r.in_run();
            let (lm, lsd) = r.late();
            let short: Vec<String> = r
                .short
                .iter()
                .map(|(seed, steps, budget)| format!("seed-{seed}@{steps}/{budget}"))
                .collect();
            let _ = writeln!(
                s,
                "{task},{},{},{},{m},{sd},{im},{isd},{},{},{},{},{},{lm},{lsd}",
                r.method,
                if *rate { "success_rate" } else { "return" },
                r.scores.len(),
                short.join(";"),
                r.budget.env_steps,
                r.budget.rounds,
                r.budget.actors,
                r.budget.unit()
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
                late: vec![-95.0, -125.0],
                short: vec![],
                budget: Budget {
                    env_steps: 2000,
                    rounds: 400,
                    actors: 5,
                    in_rounds: true,
                },
            },
            Row {
                method: "b".into(),
                scores: vec![-50.0],
                in_run: vec![-40.0],
                late: vec![-45.0],
                short: vec![(2, 1500, 2000)],
                budget: Budget {
                    env_steps: 2000,
                    rounds: 2000,
                    actors: 1,
                    in_rounds: false,
                },
            },
        ];
        let md = markdown("pendulum", &rows, false, 20);
        // Sample std of {-100, -200}: 70.7.
        assert!(
            md.contains(
                "| a | 400 rounds × K = 5 = 2000 env steps | 2 | -150.0 ± 70.7 | -100.0 ± 14.1 | -110.0 ± 21.2 |"
            ),
            "{md}"
        );
        assert!(
            md.contains("| b | 2000 env steps = 2000 rounds × K = 1 | 1 † | **-50.0 ± n/a** |"),
            "{md}"
        );
        assert!(
            md.contains("#### `pendulum` (all at equal env steps, 2000)"),
            "{md}"
        );
        assert!(
            md.contains("† b: seed-2 stopped at 1500 of 2000 env steps"),
            "{md}"
        );
        let csv = csv(&[("pendulum".into(), false, rows)]);
        assert!(
            csv.contains(
                "pendulum,b,return,1,-50,NaN,-40,NaN,seed-2@1500/2000,2000,2000,1,env_steps,-45,NaN"
            ),
            "{csv}"
        );
    }
}
