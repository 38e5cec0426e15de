//! What the learner reports, each metric named here and nowhere else in the learner:
//! - [`MetricsRow`], one epoch: a `metrics.csv` row (and the header) and its TensorBoard scalars;
//! - [`Progress`], once a second: the `PROGRESS {json}` line the launcher draws its progress line
//!   from and keeps in `logs/progress.jsonl`;
//! - [`live_scalars`], every few seconds: the latest round's numbers in TensorBoard's `live/`;
//! - [`Intake`], the counters both derive from (drops, policy lag), each derived number computed
//!   in one method.
//!
//! Readers elsewhere go by these names: `deploy/src/report/runs.rs` and `plot.rs` (CSV columns),
//! `deploy/src/progress.rs` and `experiment/` (progress keys), `tests/` (all three).

use crate::selkd::RoundStats;
use serde::Serialize;

/// What happened to the transitions the learner received, beyond storing them: those it dropped,
/// and how far the weights that chose them trailed the learner's.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Intake {
    /// Rows with a NaN or infinite value (counted as the worker's step, never stored).
    pub dropped_nonfinite: u64,
    /// Rows that do not fit the run (sizes, worker index).
    pub dropped_malformed: u64,
    /// Rows from a worker process the learner had already replaced: its successor sends those
    /// steps itself.
    pub dropped_stale: u64,
    lag_sum: f64,
    lag_count: u64,
    pub lag_max: u64,
}

impl Intake {
    /// From a checkpoint's `dropped` and `policy_lag`.
    pub fn restore(dropped: [u64; 3], (lag_sum, lag_count, lag_max): (f64, u64, u64)) -> Self {
        Self {
            dropped_nonfinite: dropped[0],
            dropped_malformed: dropped[1],
            dropped_stale: dropped[2],
            lag_sum,
            lag_count,
            lag_max,
        }
    }

    /// A checkpoint's `dropped` and `policy_lag`, as [`Intake::restore`] reads them.
    pub fn saved(&self) -> ([u64; 3], (f64, u64, u64)) {
        (
            [
                self.dropped_nonfinite,
                self.dropped_malformed,
                self.dropped_stale,
            ],
            (self.lag_sum, self.lag_count, self.lag_max),
        )
    }

    /// Counts one policy-chosen transition whose weights trailed the learner's by `lag` versions.
    pub fn policy_lag(&mut self, lag: u64) {
        self.lag_sum += lag as f64;
        self.lag_count += 1;
        self.lag_max = self.lag_max.max(lag);
    }

    /// 0 until a policy-chosen transition arrives (warm-up steps have no lag).
    pub fn policy_lag_mean(&self) -> f64 {
        if self.lag_count > 0 {
            self.lag_sum / self.lag_count as f64
        } else {
            0.0
        }
    }

    pub fn dropped(&self) -> u64 {
        self.dropped_nonfinite + self.dropped_malformed + self.dropped_stale
    }
}

/// One epoch's row. The per-actor columns hold one value per actor (NaN where there is none).
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsRow {
    pub epoch: u64,
    /// Env steps when the epoch ended.
    pub env_steps: u64,
    pub wall_s: f64,
    pub critic_updates: u64,
    /// Over the whole run so far (wall clock), as are `env_steps_per_s`.
    pub updates_per_s: f64,
    pub env_steps_per_s: f64,
    pub critic_loss: f64,
    pub q_mean: f64,
    pub best: usize,
    /// This epoch's evaluation return, NaN for an actor whose evaluation of it is not the latest.
    pub eval_return: Vec<f64>,
    pub score: Vec<f64>,
    pub alpha: Vec<f64>,
    pub kl_to_best: Vec<f64>,
    pub policy_lag_mean: f64,
    pub dropped: u64,
    /// The evaluation's success rate; NaN for tasks without a success criterion.
    pub eval_success: Vec<f64>,
}

impl MetricsRow {
    /// The CSV columns in order, each name beside its formatted value: the header and the rows
    /// are both read off this one list.
    fn columns(&self) -> Vec<(String, String)> {
        let mut columns: Vec<(String, String)> = [
            ("epoch", self.epoch.to_string()),
            ("env_steps", self.env_steps.to_string()),
            ("wall_s", format!("{:.3}", self.wall_s)),
            ("critic_updates", self.critic_updates.to_string()),
            ("updates_per_s", format!("{:.3}", self.updates_per_s)),
            ("env_steps_per_s", format!("{:.3}", self.env_steps_per_s)),
            ("critic_loss", format!("{:.6}", self.critic_loss)),
            ("q_mean", format!("{:.6}", self.q_mean)),
            ("best", self.best.to_string()),
        ]
        .into_iter()
        .map(|(name, value)| (name.to_string(), value))
        .collect();
        let per_actor = |columns: &mut Vec<(String, String)>, name: &str, values: &[f64]| {
            for (i, v) in values.iter().enumerate() {
                columns.push((format!("{name}_{i}"), format!("{v:.6}")));
            }
        };
        per_actor(&mut columns, "eval_return", &self.eval_return);
        per_actor(&mut columns, "score", &self.score);
        per_actor(&mut columns, "alpha", &self.alpha);
        per_actor(&mut columns, "kl_to_best", &self.kl_to_best);
        columns.push((
            "policy_lag_mean".into(),
            format!("{:.3}", self.policy_lag_mean),
        ));
        columns.push(("dropped".into(), self.dropped.to_string()));
        per_actor(&mut columns, "eval_success", &self.eval_success);
        columns
    }

    /// `metrics.csv`'s header for a run of `actors` actors.
    pub fn header(actors: usize) -> String {
        let nan = vec![f64::NAN; actors];
        let empty = MetricsRow {
            epoch: 0,
            env_steps: 0,
            wall_s: 0.0,
            critic_updates: 0,
            updates_per_s: 0.0,
            env_steps_per_s: 0.0,
            critic_loss: 0.0,
            q_mean: 0.0,
            best: 0,
            eval_return: nan.clone(),
            score: nan.clone(),
            alpha: nan.clone(),
            kl_to_best: nan.clone(),
            policy_lag_mean: 0.0,
            dropped: 0,
            eval_success: nan,
        };
        let names: Vec<String> = empty.columns().into_iter().map(|(n, _)| n).collect();
        names.join(",")
    }

    /// The row's line in `metrics.csv` (without the newline).
    pub fn csv(&self) -> String {
        let values: Vec<String> = self.columns().into_iter().map(|(_, v)| v).collect();
        values.join(",")
    }

    /// The row as TensorBoard scalars (written at `env_steps`).
    pub fn scalars(&self) -> Vec<(String, f64)> {
        let mut values: Vec<(String, f64)> = vec![
            ("eval/best".into(), self.best as f64),
            ("train/epoch".into(), self.epoch as f64),
            ("train/critic_updates".into(), self.critic_updates as f64),
            ("train/critic_loss".into(), self.critic_loss),
            ("train/q_mean".into(), self.q_mean),
            ("train/policy_lag_mean".into(), self.policy_lag_mean),
            ("train/dropped".into(), self.dropped as f64),
            ("rates/updates_per_s".into(), self.updates_per_s),
            ("rates/env_steps_per_s".into(), self.env_steps_per_s),
        ];
        for i in 0..self.score.len() {
            let at = |v: &[f64]| v.get(i).copied().unwrap_or(f64::NAN);
            values.push((format!("eval/return_{i}"), at(&self.eval_return)));
            values.push((format!("eval/score_{i}"), at(&self.score)));
            values.push((format!("eval/success_{i}"), at(&self.eval_success)));
            values.push((format!("train/alpha_{i}"), at(&self.alpha)));
            values.push((format!("train/kl_to_best_{i}"), at(&self.kl_to_best)));
        }
        values
    }
}

/// The learner's state once a second, as the `PROGRESS {json}` line. The fields are in
/// alphabetical order because that is the order the line's keys have always had (serde_json's
/// maps sort them), and a field serializes in its declared place.
#[derive(Debug, Clone, Serialize)]
pub struct Progress {
    pub best: usize,
    pub critic_updates: u64,
    pub dropped_malformed: u64,
    pub dropped_nonfinite: u64,
    pub dropped_stale: u64,
    pub env_steps: u64,
    /// Over the last second or so, as is `updates_per_s` (the CSV's are over the whole run).
    pub env_steps_per_s: f64,
    pub policy_lag_max: u64,
    pub policy_lag_mean: f64,
    /// Every actor's score, `null` where it has none yet.
    pub scores: Vec<Option<f64>>,
    /// Each actor's latest evaluation success rate (`null` for tasks without one).
    pub success: Vec<Option<f64>>,
    pub target_updates_per_transition: f64,
    pub total_env_steps: u64,
    pub updates_per_s: f64,
    pub updates_per_transition: f64,
    pub wall_s: f64,
    pub weights_version: u64,
}

impl Progress {
    /// The JSON object the `PROGRESS ` prefix is followed by.
    pub fn json(&self) -> String {
        serde_json::to_string(self).expect("a struct of numbers serializes")
    }
}

/// The latest round's losses, α, KL and the rates as TensorBoard's `live/` scalars, and AVTD's
/// selection (`selected` variant, validation TD errors) where the method has one.
pub fn live_scalars(
    stats: &RoundStats,
    (updates_per_s, env_steps_per_s): (f64, f64),
    avtd: Option<(usize, &[f64])>,
) -> Vec<(String, f64)> {
    let mut values: Vec<(String, f64)> = vec![
        ("live/critic_loss".into(), stats.critic_loss),
        ("live/q_mean".into(), stats.q_mean),
        ("live/updates_per_s".into(), updates_per_s),
        ("live/env_steps_per_s".into(), env_steps_per_s),
    ];
    for (i, (a, kl)) in stats.alpha.iter().zip(&stats.kl_to_best).enumerate() {
        values.push((format!("live/alpha_{i}"), *a));
        values.push((format!("live/kl_to_best_{i}"), *kl));
    }
    if let Some((selected, validation_td)) = avtd {
        values.push(("avtd/selected".into(), selected as f64));
        for (v, td) in validation_td.iter().enumerate() {
            values.push((format!("avtd/validation_td_{v}"), *td));
        }
    }
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_and_row_keep_their_columns_and_formats() {
        assert_eq!(
            MetricsRow::header(2),
            "epoch,env_steps,wall_s,critic_updates,updates_per_s,env_steps_per_s,critic_loss,q_mean,best,eval_return_0,eval_return_1,score_0,score_1,alpha_0,alpha_1,kl_to_best_0,kl_to_best_1,policy_lag_mean,dropped,eval_success_0,eval_success_1"
        );
        let row = MetricsRow {
            epoch: 3,
            env_steps: 1500,
            wall_s: 12.34567,
            critic_updates: 1000,
            updates_per_s: 81.0004,
            env_steps_per_s: 121.5,
            critic_loss: 0.25,
            q_mean: -12.3456789,
            best: 1,
            eval_return: vec![-150.0, f64::NAN],
            score: vec![-160.5, -170.25],
            alpha: vec![0.1, 0.2],
            kl_to_best: vec![0.0, 1.5],
            policy_lag_mean: 0.5,
            dropped: 2,
            eval_success: vec![f64::NAN, 1.0],
        };
        assert_eq!(
            row.csv(),
            "3,1500,12.346,1000,81.000,121.500,0.250000,-12.345679,1,-150.000000,NaN,-160.500000,-170.250000,0.100000,0.200000,0.000000,1.500000,0.500,2,NaN,1.000000"
        );
        let tags: Vec<String> = row.scalars().into_iter().map(|(t, _)| t).collect();
        assert_eq!(tags.len(), 9 + 5 * 2);
        assert!(tags.contains(&"train/kl_to_best_1".to_string()));
    }

    #[test]
    fn progress_keys_stay_sorted_and_nan_is_null() {
        let p = Progress {
            best: 0,
            critic_updates: 10,
            dropped_malformed: 1,
            dropped_nonfinite: 2,
            dropped_stale: 3,
            env_steps: 20,
            env_steps_per_s: 5.5,
            policy_lag_max: 1,
            policy_lag_mean: 0.25,
            scores: vec![Some(-1.5), None],
            success: vec![None, None],
            target_updates_per_transition: 1.0,
            total_env_steps: 100,
            updates_per_s: f64::NAN,
            updates_per_transition: 0.5,
            wall_s: 2.0,
            weights_version: 7,
        };
        assert_eq!(
            p.json(),
            r#"{"best":0,"critic_updates":10,"dropped_malformed":1,"dropped_nonfinite":2,"dropped_stale":3,"env_steps":20,"env_steps_per_s":5.5,"policy_lag_max":1,"policy_lag_mean":0.25,"scores":[-1.5,null],"success":[null,null],"target_updates_per_transition":1.0,"total_env_steps":100,"updates_per_s":null,"updates_per_transition":0.5,"wall_s":2.0,"weights_version":7}"#
        );
    }

    #[test]
    fn intake_derives_its_numbers_and_round_trips_a_checkpoint() {
        let mut intake = Intake::default();
        assert_eq!(intake.policy_lag_mean(), 0.0);
        intake.policy_lag(1);
        intake.policy_lag(2);
        intake.dropped_stale = 4;
        intake.dropped_nonfinite = 1;
        assert_eq!((intake.policy_lag_mean(), intake.lag_max), (1.5, 2));
        assert_eq!(intake.dropped(), 5);
        let (dropped, lag) = intake.saved();
        assert_eq!(Intake::restore(dropped, lag), intake);
    }
}
