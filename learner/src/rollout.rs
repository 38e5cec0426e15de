//! What the learner has received from each worker: where its rollout stands (the record a
//! restarted worker, or every worker of a resumed run, continues from exactly), the transitions
//! waiting for their lockstep round, and how long a worker the run waits on has been silent.

use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// One worker's rollout as received: enough to hand a (re)started worker its cursor.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Rollout {
    /// Transitions received from this worker.
    pub sent: u64,
    /// The episode the next transition belongs to (counted per worker from 0).
    pub episode: u64,
    /// The next transition's step within that episode.
    pub step: u64,
    /// The actions of `episode` so far, `step × act_dim` values: replayed on the episode's seed
    /// they bring the worker's env back to where the last transition left it.
    pub actions: Vec<f32>,
}

impl Rollout {
    /// Records the next transition. Returns false if it is not the step the record expects (it
    /// then follows the transition, but the episode's actions before it are unknown).
    pub fn record(&mut self, episode: u64, step: u64, action: &[f32], ends_episode: bool) -> bool {
        let expected = episode == self.episode && step == self.step;
        if !expected {
            self.episode = episode;
            self.step = step;
            self.actions.clear();
        }
        self.sent += 1;
        if ends_episode {
            self.episode += 1;
            self.step = 0;
            self.actions.clear();
        } else {
            self.step += 1;
            self.actions.extend_from_slice(action);
        }
        expected
    }
}

/// A received transition on its way into the replay buffer (sync mode holds one per worker
/// until its round is complete). `row` is `None` for one dropped for a non-finite value: it
/// still counts as the worker's env step (so lockstep rounds, budgets and epochs carry on), but
/// nothing is stored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pending {
    pub worker: usize,
    /// The episode's return when this transition ends it.
    pub episode_return: Option<f64>,
    pub row: Option<Vec<f32>>,
}

/// Notices workers the run is waiting on that have sent nothing for `timeout`.
pub struct Watchdog {
    timeout: Duration,
    quiet_since: Vec<Instant>,
}

impl Watchdog {
    pub fn new(workers: usize, timeout: Duration, now: Instant) -> Self {
        Self {
            timeout,
            quiet_since: vec![now; workers],
        }
    }

    /// Worker `w` sent something.
    pub fn heard(&mut self, w: usize, now: Instant) {
        self.quiet_since[w] = now;
    }

    /// The workers that owe the run something (`owes[w]`) and have been silent since before
    /// `now − timeout`, each with how long. A worker that owes nothing is never late, and its
    /// silence starts counting when it begins to owe; a reported worker gets a fresh `timeout`.
    pub fn late(&mut self, owes: &[bool], now: Instant) -> Vec<(usize, Duration)> {
        let mut late = Vec::new();
        for (w, (&owes, since)) in owes.iter().zip(&mut self.quiet_since).enumerate() {
            if !owes {
                *since = now;
            } else if now.duration_since(*since) > self.timeout {
                late.push((w, now.duration_since(*since)));
                *since = now;
            }
        }
        late
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_record_follows_episodes_and_keeps_only_the_current_ones_actions() {
        let mut r = Rollout::default();
        assert!(r.record(0, 0, &[0.1, 0.2], false));
        assert!(r.record(0, 1, &[0.3, 0.4], false));
        assert_eq!((r.sent, r.episode, r.step), (2, 0, 2));
        assert_eq!(r.actions, vec![0.1, 0.2, 0.3, 0.4]);
        assert!(r.record(0, 2, &[0.5, 0.6], true), "the episode ends");
        assert_eq!((r.sent, r.episode, r.step), (3, 1, 0));
        assert!(r.actions.is_empty());
        assert!(r.record(1, 0, &[0.7, 0.8], false));
        assert_eq!(r.actions, vec![0.7, 0.8]);
        // A transition out of step is flagged, and the record follows it.
        assert!(!r.record(5, 3, &[0.9, 1.0], false));
        assert_eq!((r.sent, r.episode, r.step), (5, 5, 4));
    }

    #[test]
    fn pending_rows_survive_json_exactly() {
        let p = vec![
            Pending {
                worker: 1,
                episode_return: Some(-123.456_789_012_345),
                row: Some(vec![0.1, -3.4e-7, 1e30, f32::MIN_POSITIVE]),
            },
            Pending {
                worker: 0,
                episode_return: None,
                row: None,
            },
        ];
        let back: Vec<Pending> =
            serde_json::from_str(&serde_json::to_string_pretty(&p).unwrap()).unwrap();
        assert_eq!(back, p);
    }

    #[test]
    fn only_a_silent_worker_that_is_owed_something_is_late() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let mut dog = Watchdog::new(3, s(10), t0);
        // Worker 0 owes and stays silent; worker 1 owes but talks; worker 2 owes nothing.
        let owes = [true, true, false];
        dog.heard(1, t0 + s(8));
        assert!(dog.late(&owes, t0 + s(9)).is_empty());
        assert_eq!(dog.late(&owes, t0 + s(11)), vec![(0, s(11))]);
        // Reported once per timeout, not on every pass.
        assert!(dog.late(&owes, t0 + s(12)).is_empty());
        assert_eq!(
            dog.late(&owes, t0 + s(19)),
            vec![(1, s(11))],
            "worker 1, silent since 8 s"
        );
        assert_eq!(dog.late(&owes, t0 + s(22)), vec![(0, s(11))]);
        // Worker 2 was idle for 29 s; owing from then on, it gets the whole timeout.
        assert!(dog.late(&owes, t0 + s(29)).is_empty());
        let now_2_owes = [false, false, true];
        assert!(dog.late(&now_2_owes, t0 + s(39)).is_empty());
        assert_eq!(dog.late(&now_2_owes, t0 + s(40)), vec![(2, s(11))]);
    }
}
