//! The Monte-Carlo ranking of the actors (SPEC "Ranking"): each actor's score is the mean return
//! of its latest evaluation, or before any, the mean of its latest completed training episodes.
//! The best actor is the argmax, ties to the lower index.

use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Ranking {
    evaluation: Vec<Option<f64>>,
    last_eval_epoch: Vec<u64>,
    training: Vec<VecDeque<f64>>,
    window: usize,
    /// Bumped whenever a score changes.
    pub version: u64,
}

impl Ranking {
    pub fn new(actors: usize, window: usize) -> Self {
        Self {
            evaluation: vec![None; actors],
            last_eval_epoch: vec![0; actors],
            training: vec![VecDeque::new(); actors],
            window,
            version: 0,
        }
    }

    /// A training episode of `actor` ended with this undiscounted return.
    pub fn training_episode(&mut self, actor: usize, ret: f64) {
        let q = &mut self.training[actor];
        q.push_back(ret);
        if q.len() > self.window {
            q.pop_front();
        }
        if self.evaluation[actor].is_none() {
            self.version += 1;
        }
    }

    /// `actor`'s evaluation of `epoch`; an epoch older than or equal to the last one is ignored.
    /// Returns whether it was taken.
    pub fn evaluation(&mut self, actor: usize, epoch: u64, mean_return: f64) -> bool {
        if epoch <= self.last_eval_epoch[actor] || !mean_return.is_finite() {
            return false;
        }
        self.last_eval_epoch[actor] = epoch;
        self.evaluation[actor] = Some(mean_return);
        self.version += 1;
        true
    }

    pub fn last_eval_epoch(&self, actor: usize) -> u64 {
        self.last_eval_epoch[actor]
    }

    /// Every actor's current score (None until it has one).
    pub fn scores(&self) -> Vec<Option<f64>> {
        self.evaluation
            .iter()
            .zip(&self.training)
            .map(|(e, t)| {
                e.or_else(|| (!t.is_empty()).then(|| t.iter().sum::<f64>() / t.len() as f64))
            })
            .collect()
    }

    /// The argmax of the scores, ties to the lower index; actor 0 while nobody has a score.
    pub fn best(&self) -> usize {
        let mut best: Option<(usize, f64)> = None;
        for (i, s) in self.scores().into_iter().enumerate() {
            if let Some(s) = s {
                if best.is_none_or(|(_, b)| s > b) {
                    best = Some((i, s));
                }
            }
        }
        best.map_or(0, |(i, _)| i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn training_returns_until_evaluated_then_latest_evaluation() {
        let mut r = Ranking::new(3, 2);
        assert_eq!(r.best(), 0);
        r.training_episode(1, -10.0);
        r.training_episode(2, -20.0);
        assert_eq!(r.best(), 1);
        r.training_episode(2, 10.0);
        r.training_episode(2, 0.0); // window 2: mean of (10, 0) = 5 beats -10
        assert_eq!(r.scores()[2], Some(5.0));
        assert_eq!(r.best(), 2);
        assert!(r.evaluation(0, 1, 7.0));
        assert_eq!(r.best(), 0);
        assert!(
            !r.evaluation(0, 1, -100.0),
            "an epoch already taken is ignored"
        );
        r.training_episode(0, -1000.0);
        assert_eq!(
            r.scores()[0],
            Some(7.0),
            "evaluation outranks training returns"
        );
    }

    /// `version` moves exactly when a score may have changed (the service re-sends the ranking
    /// then), and `last_eval_epoch` is the last evaluation taken (the service asks for the next).
    #[test]
    fn version_counts_score_changes_and_the_last_evaluated_epoch_is_kept() {
        let mut r = Ranking::new(2, 3);
        assert_eq!(
            (r.version, r.last_eval_epoch(0), r.last_eval_epoch(1)),
            (0, 0, 0)
        );
        r.training_episode(0, -5.0);
        assert_eq!(r.version, 1);
        r.training_episode(0, -6.0);
        assert_eq!(r.version, 2);
        assert!(r.evaluation(0, 3, 1.0));
        assert_eq!(
            (r.version, r.last_eval_epoch(0), r.last_eval_epoch(1)),
            (3, 3, 0)
        );
        r.training_episode(0, -7.0); // evaluated: a training return no longer scores it
        assert_eq!(r.version, 3);
        assert!(!r.evaluation(0, 2, 9.0), "an older epoch is ignored");
        assert!(
            !r.evaluation(0, 4, f64::NAN),
            "a non-finite return is ignored"
        );
        assert_eq!((r.version, r.last_eval_epoch(0)), (3, 3));
        assert!(r.evaluation(0, 7, 2.0));
        assert_eq!((r.version, r.last_eval_epoch(0)), (4, 7));
    }

    #[test]
    fn ties_go_to_the_lower_index() {
        let mut r = Ranking::new(3, 1);
        r.evaluation(2, 1, 5.0);
        r.evaluation(1, 1, 5.0);
        assert_eq!(r.best(), 1);
    }
}
