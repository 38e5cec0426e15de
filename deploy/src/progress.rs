//! The launcher's progress line, drawn from the learner's `PROGRESS {json}` lines (one a second).
//!
//! Rates are averaged over the last [`WINDOW_S`] seconds of that history (the learner's own
//! per-second rates jump with every evaluation and checkpoint), and the ETA divides the env steps
//! left by that rate. Tasks with a success criterion show each actor's success rate instead of
//! its score (their returns are small and say little): PROGRESS's `success` when the learner
//! sends one, else the latest `eval_success_i` of the run's `metrics.csv`.

use serde_json::Value;
use std::cell::RefCell;
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

thread_local! {
    /// `selkd train`'s meter. Its supervision runs on one thread (a current-thread runtime), so a
    /// thread-local holds the history without threading it through the supervision loop.
    static METER: RefCell<ProgressMeter> = RefCell::new(ProgressMeter::new(WINDOW_S));
}

/// The progress line for one PROGRESS value, from this thread's meter.
pub fn line(p: &Value, elapsed: Duration) -> String {
    METER.with(|m| m.borrow_mut().line(p, elapsed))
}

/// Tells this thread's meter where the run's `metrics.csv` is (for success rates).
pub fn watch_metrics(path: PathBuf) {
    METER.with(|m| m.borrow_mut().metrics = Some(MetricsFile::new(path)));
}

/// The run's metrics.csv, re-read only when it changes.
struct MetricsFile {
    path: PathBuf,
    seen: Option<SystemTime>,
    success: Option<Vec<Option<f64>>>,
}

impl MetricsFile {
    fn new(path: PathBuf) -> Self {
        Self {
            path,
            seen: None,
            success: None,
        }
    }

    fn success(&mut self) -> Option<Vec<Option<f64>>> {
        let modified = std::fs::metadata(&self.path)
            .and_then(|m| m.modified())
            .ok();
        if modified.is_some() && modified != self.seen {
            self.seen = modified;
            self.success = latest_success(&self.path);
        }
        self.success.clone()
    }
}

/// Each actor's success rate in the last row of `metrics.csv` (`eval_success_i`; NaN for tasks
/// without success); `None` when there is no row or no actor has a rate.
fn latest_success(path: &Path) -> Option<Vec<Option<f64>>> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<&str> = lines.next()?.split(',').collect();
    let last: Vec<&str> = lines.last()?.split(',').collect();
    let rates: Vec<Option<f64>> = (0..)
        .map_while(|i| {
            header
                .iter()
                .position(|h| *h == format!("eval_success_{i}"))
        })
        .map(|col| {
            last.get(col)
                .and_then(|v| v.trim().parse::<f64>().ok())
                .filter(|v| v.is_finite())
        })
        .collect();
    rates.iter().any(Option::is_some).then_some(rates)
}

/// Seconds of PROGRESS history the rates are averaged over.
pub const WINDOW_S: f64 = 10.0;

/// One PROGRESS sample: the learner's wall clock, env steps and critic updates.
#[derive(Clone, Copy, Debug)]
struct Sample {
    wall_s: f64,
    env_steps: f64,
    critic_updates: f64,
}

/// Keeps the recent PROGRESS history and formats the line.
pub struct ProgressMeter {
    history: VecDeque<Sample>,
    window_s: f64,
    metrics: Option<MetricsFile>,
}

impl ProgressMeter {
    pub fn new(window_s: f64) -> Self {
        Self {
            history: VecDeque::new(),
            window_s,
            metrics: None,
        }
    }

    /// Takes one PROGRESS value and returns the line to show. `elapsed` is the launcher's time
    /// since the start, used when the learner gives no `wall_s`.
    pub fn line(&mut self, p: &Value, elapsed: Duration) -> String {
        let f = |k: &str| p[k].as_f64().unwrap_or(0.0);
        let now = p["wall_s"].as_f64().unwrap_or(elapsed.as_secs_f64());
        let sample = Sample {
            wall_s: now,
            env_steps: f("env_steps"),
            critic_updates: f("critic_updates"),
        };
        // A clock that went back (a resumed learner restarts its clock) starts a new history.
        if self.history.back().is_some_and(|b| b.wall_s > now) {
            self.history.clear();
        }
        self.history.push_back(sample);
        // Keep the newest sample at least `window_s` old, so the window is always covered.
        while self.history.len() > 2 && now - self.history[1].wall_s >= self.window_s {
            self.history.pop_front();
        }
        // Warm-up steps need no updates and fly by: once updates start, the window starts there.
        if sample.critic_updates > 0.0 {
            while self.history.len() > 1 && self.history[0].critic_updates == 0.0 {
                self.history.pop_front();
            }
        }
        let oldest = self.history[0];
        let span = now - oldest.wall_s;
        let (steps_per_s, updates_per_s) = if self.history.len() >= 2 && span > 0.0 {
            (
                (sample.env_steps - oldest.env_steps) / span,
                (sample.critic_updates - oldest.critic_updates) / span,
            )
        } else {
            (f("env_steps_per_s"), f("updates_per_s"))
        };
        let total = f("total_env_steps").max(1.0);
        let left = (total - sample.env_steps).max(0.0);
        let eta = if left == 0.0 {
            "ETA 0s".to_string()
        } else if sample.critic_updates == 0.0 {
            // Warm-up steps need no updates and fly by; the rate after them is the learner's.
            "warm-up, ETA after it".to_string()
        } else if self.history.len() >= 2 && steps_per_s > 0.0 {
            format!("ETA {}", duration(left / steps_per_s))
        } else {
            "ETA –".to_string()
        };
        let success = per_actor(&p["success"])
            .filter(|r| r.iter().any(Option::is_some))
            .or_else(|| self.metrics.as_mut().and_then(MetricsFile::success));
        let scores = match success {
            Some(rates) if rates.iter().any(Option::is_some) => format!(
                "success [{}]",
                rates
                    .iter()
                    .map(|r| r.map_or("–".into(), |v| format!("{:.0}%", 100.0 * v)))
                    .collect::<Vec<_>>()
                    .join(" ")
            ),
            _ => format!(
                "scores [{}]",
                per_actor(&p["scores"])
                    .unwrap_or_default()
                    .iter()
                    .map(|s| s.map_or("–".into(), score))
                    .collect::<Vec<_>>()
                    .join(" ")
            ),
        };
        format!(
            "[{}] env steps {}/{} ({:.0}%, {eta}) | {:.0} updates/s | {:.0} env steps/s | {scores} | best {} | lag {:.1}",
            duration(elapsed.as_secs_f64()),
            sample.env_steps as u64,
            total as u64,
            // The last round may pass the budget by up to K − 1 steps.
            (100.0 * sample.env_steps / total).min(100.0),
            updates_per_s,
            steps_per_s,
            p["best"].as_u64().unwrap_or(0),
            f("policy_lag_mean"),
        )
    }
}

/// A per-actor array of numbers or nulls; `None` when absent.
fn per_actor(v: &Value) -> Option<Vec<Option<f64>>> {
    v.as_array().map(|a| {
        a.iter()
            .map(|s| s.as_f64().filter(|x| x.is_finite()))
            .collect()
    })
}

/// A score with three significant figures at most and never `-0`: small returns (the assembly
/// task's) stay readable, large ones stay short.
fn score(v: f64) -> String {
    let digits = if v.abs() >= 100.0 {
        0
    } else if v.abs() >= 10.0 {
        1
    } else {
        2
    };
    let s = format!("{v:.digits$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => s,
    }
}

/// `45s`, `3m05s`, `2h04m` (also the experiment runner's).
pub(crate) fn duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match s {
        0..=59 => format!("{s}s"),
        60..=3599 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, (s % 3600) / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn progress(wall_s: f64, env_steps: u64, critic_updates: u64) -> Value {
        json!({
            "wall_s": wall_s, "env_steps": env_steps, "total_env_steps": 12000,
            "critic_updates": critic_updates,
            // The learner's own one-second rates: deliberately wrong, to show they are not used
            // once a window exists.
            "env_steps_per_s": 9999.0, "updates_per_s": 9999.0,
            "scores": [-1234.4, null, -0.004], "best": 0, "policy_lag_mean": 0.0,
        })
    }

    #[test]
    fn rates_are_averaged_over_the_window_and_the_eta_divides_what_is_left_by_them() {
        let mut m = ProgressMeter::new(10.0);
        let t = Duration::from_secs(5);
        // 100 env steps/s and 30 updates/s for 20 s, with a stall (an evaluation) at 14–16 s.
        let mut line = String::new();
        for s in 0..=20u64 {
            let steps = match s {
                0..=14 => 100 * s,
                15..=16 => 1400,
                _ => 1400 + 100 * (s - 16),
            };
            line = m.line(&progress(s as f64, steps, 3 * steps / 10), t);
        }
        // At 20 s: 1800 env steps; 10 s before: 1000. (1800 − 1000) / 10 = 80 env steps/s.
        assert!(line.contains("| 80 env steps/s"), "{line}");
        assert!(line.contains("| 24 updates/s"), "{line}");
        // (12000 − 1800) / 80 = 127.5 s.
        assert!(line.contains("1800/12000 (15%, ETA 2m08s)"), "{line}");
    }

    #[test]
    fn the_first_sample_uses_the_learners_rates_and_a_finished_run_has_no_eta_left() {
        let mut m = ProgressMeter::new(10.0);
        let line = m.line(&progress(1.0, 600, 0), Duration::from_secs(1));
        assert!(line.contains("| 9999 env steps/s"), "{line}");
        assert!(line.contains("| 9999 updates/s"), "{line}");
        // No update yet: still in the warm-up, whose pace says nothing about the rest.
        assert!(line.contains("(5%, warm-up, ETA after it)"), "{line}");
        let line = m.line(&progress(2.0, 12000, 10), Duration::from_secs(2));
        assert!(line.contains("(100%, ETA 0s)"), "{line}");
        // No progress over the window: no ETA rather than an infinite one.
        let mut m = ProgressMeter::new(10.0);
        m.line(&progress(1.0, 600, 10), Duration::from_secs(1));
        let line = m.line(&progress(2.0, 600, 10), Duration::from_secs(2));
        assert!(line.contains("ETA –"), "{line}");
    }

    /// Right after the warm-up the window still holds its fast steps; the ETA must not use them.
    #[test]
    fn the_eta_after_the_warm_up_uses_only_steps_taken_since_updates_began() {
        let mut m = ProgressMeter::new(10.0);
        let t = Duration::from_secs(3);
        m.line(&progress(0.0, 0, 0), t);
        m.line(&progress(1.0, 3000, 0), t);
        // The first second with updates: no window after the warm-up yet, so no ETA.
        let line = m.line(&progress(2.0, 5050, 20), t);
        assert!(line.contains("ETA –"), "{line}");
        // 10 env steps/s since then: (12000 − 5060) / 10 = 694 s, not the warm-up's pace.
        let line = m.line(&progress(3.0, 5060, 40), t);
        assert!(line.contains("(42%, ETA 11m34s)"), "{line}");
        assert!(line.contains("| 20 updates/s | 10 env steps/s"), "{line}");
    }

    #[test]
    fn scores_keep_three_figures_and_never_print_minus_zero() {
        let mut m = ProgressMeter::new(10.0);
        let line = m.line(&progress(1.0, 0, 0), Duration::from_secs(1));
        assert!(line.contains("scores [-1234 – 0.00]"), "{line}");
        assert_eq!(score(-0.36), "-0.36");
        assert_eq!(score(-12.34), "-12.3");
        assert_eq!(score(-0.0), "0.00");
    }

    #[test]
    fn tasks_with_success_show_success_rates_instead_of_scores() {
        let mut m = ProgressMeter::new(10.0);
        let mut p = progress(1.0, 0, 0);
        p["success"] = json!([0.8, null, 0.0]);
        let line = m.line(&p, Duration::from_secs(1));
        assert!(line.contains("success [80% – 0%]"), "{line}");
        assert!(!line.contains("scores"), "{line}");
        // A task without success (all null) keeps its scores.
        p["success"] = json!([null, null, null]);
        let line = m.line(&p, Duration::from_secs(2));
        assert!(line.contains("scores ["), "{line}");
    }

    #[test]
    fn success_rates_come_from_metrics_csv_when_progress_has_none() {
        let dir = std::env::temp_dir().join(format!("selkd-progress-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("metrics.csv");
        let mut m = ProgressMeter::new(10.0);
        m.metrics = Some(MetricsFile::new(path.clone()));
        // No metrics.csv yet: the scores.
        let line = m.line(&progress(1.0, 0, 0), Duration::from_secs(1));
        assert!(line.contains("scores [-1234 – 0.00]"), "{line}");
        // The assembly task's rows: the last row's rates (NaN: that actor has none).
        std::fs::write(
            &path,
            "epoch,env_steps,eval_return_0,eval_return_1,eval_return_2,eval_success_0,eval_success_1,eval_success_2\n\
             1,2000,-0.3,-0.2,-0.1,0.000,0.100,NaN\n\
             2,4000,1.3,-0.2,2.1,0.300,NaN,0.600\n",
        )
        .unwrap();
        let line = m.line(&progress(2.0, 10, 1), Duration::from_secs(2));
        assert!(line.contains("success [30% – 60%]"), "{line}");
        // A task without success: its NaN columns leave the scores.
        let other = dir.join("pendulum.csv");
        std::fs::write(
            &other,
            "epoch,env_steps,eval_return_0,eval_success_0\n1,1000,-150.0,NaN\n",
        )
        .unwrap();
        let mut m = ProgressMeter::new(10.0);
        m.metrics = Some(MetricsFile::new(other));
        let line = m.line(&progress(1.0, 0, 0), Duration::from_secs(1));
        assert!(line.contains("scores ["), "{line}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_clock_that_goes_back_starts_a_new_window() {
        let mut m = ProgressMeter::new(10.0);
        m.line(&progress(100.0, 5000, 0), Duration::from_secs(1));
        m.line(&progress(101.0, 5100, 0), Duration::from_secs(2));
        // A resumed learner's clock starts again: rates come from the new samples only.
        m.line(&progress(1.0, 6000, 0), Duration::from_secs(3));
        let line = m.line(&progress(3.0, 6100, 0), Duration::from_secs(4));
        assert!(line.contains("| 50 env steps/s"), "{line}");
    }

    #[test]
    fn durations_read_as_seconds_minutes_or_hours() {
        assert_eq!(duration(45.2), "45s");
        assert_eq!(duration(185.0), "3m05s");
        assert_eq!(duration(7440.0), "2h04m");
        assert_eq!(duration(125.0), "2m05s");
        assert_eq!(duration(7300.0), "2h01m");
    }
}
