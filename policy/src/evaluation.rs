//! Deterministic evaluation of an actor: the episodes that score it for the ranking (in the
//! workers) and, after training, for the results table (`selkd experiment report`).
//!
//! Episode seeds come from here so that every caller agrees on them. Within one epoch every actor
//! plays the same seeds (common random numbers: the ranking compares actors on equal episodes, not
//! on different luck); the seeds change from epoch to epoch. Re-evaluation after training uses a
//! separate stream of seeds that no in-run evaluation ever played.

use crate::Actor;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use selkd_envs::Env;

/// What `episodes` deterministic episodes gave.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Evaluation {
    /// Undiscounted return of each episode.
    pub returns: Vec<f64>,
    /// Whether each episode succeeded, for tasks with a success criterion (else `None`).
    pub successes: Vec<Option<bool>>,
    /// Steps of each episode (shorter than the time limit where the task terminated it).
    pub lengths: Vec<usize>,
}

impl Evaluation {
    pub fn mean_return(&self) -> f64 {
        self.returns.iter().sum::<f64>() / self.returns.len().max(1) as f64
    }

    pub fn mean_length(&self) -> f64 {
        self.lengths.iter().sum::<usize>() as f64 / self.lengths.len().max(1) as f64
    }

    /// Fraction of successful episodes; NaN for tasks without success.
    pub fn success_rate(&self) -> f64 {
        let judged: Vec<bool> = self.successes.iter().filter_map(|s| *s).collect();
        if judged.is_empty() {
            f64::NAN
        } else {
            judged.iter().filter(|&&s| s).count() as f64 / judged.len() as f64
        }
    }
}

/// Plays one episode per seed with the deterministic action `tanh(μ)`.
pub fn evaluate(
    env: &mut dyn Env,
    policy: &Actor,
    seeds: impl IntoIterator<Item = u64>,
) -> Evaluation {
    let mut out = Evaluation::default();
    for seed in seeds {
        let mut obs = env.reset(Some(seed));
        let (mut total, mut length) = (0.0, 0);
        loop {
            let step = env.step(&policy.mean_action(&obs));
            total += step.reward;
            length += 1;
            if step.terminated || step.truncated {
                out.returns.push(total);
                out.successes.push(step.success);
                out.lengths.push(length);
                break;
            }
            obs = step.obs;
        }
    }
    out
}

/// Seed of evaluation episode `episode` of epoch `epoch` in a run seeded `run_seed`: the same for
/// every actor (common random numbers).
pub fn epoch_seed(run_seed: u64, epoch: u64, episode: u64) -> u64 {
    mix(
        run_seed,
        0x65_7661_6c00 ^ epoch.wrapping_mul(0x1_0000_0001),
        episode,
    )
}

/// Seed of re-evaluation episode `episode` after training: one stream for every run, method and
/// seed (so a results table compares them on equal episodes), apart from every [`epoch_seed`].
pub fn fresh_seed(episode: u64) -> u64 {
    mix(0xf7e5_4000_0000_0000, 0x66_7265_7368, episode)
}

fn mix(a: u64, b: u64, c: u64) -> u64 {
    let mut rng = Pcg64::seed_from_u64(a ^ b.rotate_left(17));
    let base: u64 = rng.gen();
    let mut rng = Pcg64::seed_from_u64(base ^ c.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    rng.gen()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn epoch_seeds_are_shared_by_actors_and_differ_between_epochs_and_from_fresh_ones() {
        let a: Vec<u64> = (0..10).map(|e| epoch_seed(1, 3, e)).collect();
        let b: Vec<u64> = (0..10).map(|e| epoch_seed(1, 4, e)).collect();
        let c: Vec<u64> = (0..10).map(|e| epoch_seed(2, 3, e)).collect();
        assert_eq!(a, (0..10).map(|e| epoch_seed(1, 3, e)).collect::<Vec<_>>());
        let mut all: Vec<u64> = a.iter().chain(&b).chain(&c).copied().collect();
        all.extend((0..10).map(fresh_seed));
        let n = all.len();
        all.sort_unstable();
        all.dedup();
        assert_eq!(
            all.len(),
            n,
            "no seed is played twice across epochs, runs and re-evaluation"
        );
    }
}
