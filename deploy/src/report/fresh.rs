//! Table 2's scores: the actor the final checkpoint's ranking picks, re-evaluated on E fresh
//! episodes (`selkd_policy::evaluation::fresh_seed(0..E)`, the same for every method and seed,
//! none of them played during training), deterministic actions, on the run's env and
//! `[env_options]`.
//!
//! Why fresh episodes: the ranking picked its actor because that actor's in-run evaluations were
//! the highest; reporting those same evaluations would report the maximum of noisy numbers, which
//! is biased upward (most for methods with many actors). Episodes that played no part in the pick
//! give an unbiased estimate of the picked actor's quality.
//!
//! Each run's result is cached in `RUN/fresh_eval.json`; it is recomputed when the final
//! checkpoint is newer than the cache, or when E or the checkpoint differ.

use super::runs::Run;
use anyhow::{Context, Result};
use selkd_learner::checkpoint::load_actor;
use selkd_policy::evaluation::{evaluate, fresh_seed};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// `RUN/fresh_eval.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FreshEval {
    /// The checkpoint evaluated, relative to the run directory.
    pub checkpoint: String,
    /// Which actor of it (its ranking's best).
    pub actor: usize,
    pub env: String,
    /// The episodes' seeds, `fresh_seed(0..E)`.
    pub seeds: Vec<u64>,
    /// Undiscounted return of each episode.
    pub returns: Vec<f64>,
    /// Success of each episode, for tasks with success (else null).
    pub successes: Vec<Option<bool>>,
}

impl FreshEval {
    /// The run's score: success rate where `success`, else the mean return.
    pub fn score(&self, success: bool) -> f64 {
        if success {
            let judged: Vec<bool> = self.successes.iter().filter_map(|s| *s).collect();
            judged.iter().filter(|s| **s).count() as f64 / judged.len().max(1) as f64
        } else {
            self.returns.iter().sum::<f64>() / self.returns.len().max(1) as f64
        }
    }
}

const CHECKPOINT: &str = "checkpoints/final";

fn modified(p: &Path) -> Option<std::time::SystemTime> {
    std::fs::metadata(p).and_then(|m| m.modified()).ok()
}

/// The cached evaluation of `run` if it is still valid, else a new one (written to the cache).
pub fn fresh_eval(run: &Run, episodes: usize) -> Result<FreshEval> {
    let cache = run.dir.join("fresh_eval.json");
    let ckpt = run.dir.join(CHECKPOINT);
    let seeds: Vec<u64> = (0..episodes as u64).map(fresh_seed).collect();
    let newest_ckpt = ["state.json", "model.safetensors"]
        .iter()
        .filter_map(|f| modified(&ckpt.join(f)))
        .max();
    if let (Some(c), Some(k)) = (modified(&cache), newest_ckpt) {
        if c >= k {
            let old: Option<FreshEval> = std::fs::read_to_string(&cache)
                .ok()
                .and_then(|t| serde_json::from_str(&t).ok());
            if let Some(old) = old.filter(|o| o.seeds == seeds && o.checkpoint == CHECKPOINT) {
                return Ok(old);
            }
        }
    }
    if !ckpt.exists() {
        // A published run (`selkd experiment publish`) has no weights: its fresh evaluation is
        // the data, and it can only be read, not redone with another E.
        let old: FreshEval = std::fs::read_to_string(&cache)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .with_context(|| {
                format!(
                    "{} has neither {CHECKPOINT} nor a readable fresh_eval.json, so Table 2 cannot score it",
                    run.dir.display()
                )
            })?;
        if old.seeds != seeds {
            anyhow::bail!(
                "{} has no checkpoint (published data) and its fresh_eval.json holds {} episodes, not --episodes {episodes}; report with --episodes {}",
                run.dir.display(),
                old.seeds.len(),
                old.seeds.len()
            );
        }
        return Ok(old);
    }
    let loaded = load_actor(&ckpt, None)
        .with_context(|| format!("loading the ranked actor of {}", ckpt.display()))?;
    let options = run
        .config
        .get("env_options")
        .and_then(|v| v.as_table())
        .cloned()
        .unwrap_or_default();
    let mut env = selkd_envs::make_with(&run.env, &options)
        .with_context(|| format!("making env {} for {}", run.env, run.dir.display()))?;
    let e = evaluate(env.as_mut(), &loaded.actor, seeds.iter().copied());
    let out = FreshEval {
        checkpoint: CHECKPOINT.into(),
        actor: loaded.index,
        env: run.env.clone(),
        seeds,
        returns: e.returns,
        successes: e.successes,
    };
    std::fs::write(&cache, serde_json::to_string_pretty(&out)?)
        .with_context(|| format!("writing {}", cache.display()))?;
    Ok(out)
}

/// [`fresh_eval`] of every run, on up to as many threads as there are cores.
pub fn fresh_evals(runs: &[&Run], episodes: usize) -> Result<Vec<FreshEval>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut out: Vec<Option<Result<FreshEval>>> = (0..runs.len()).map(|_| None).collect();
    for (chunk_runs, chunk_out) in runs.chunks(threads).zip(out.chunks_mut(threads)) {
        std::thread::scope(|s| {
            for (r, o) in chunk_runs.iter().zip(chunk_out.iter_mut()) {
                s.spawn(move || *o = Some(fresh_eval(r, episodes)));
            }
        });
    }
    out.into_iter()
        .map(|o| o.expect("every run evaluated"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_score_is_the_success_rate_for_success_tasks_else_the_mean_return() {
        let f = FreshEval {
            checkpoint: CHECKPOINT.into(),
            actor: 0,
            env: "fpc-assembly".into(),
            seeds: vec![1, 2, 3],
            returns: vec![3.0, 6.0, 12.0],
            successes: vec![Some(true), Some(false), Some(true)],
        };
        assert!((f.score(true) - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(f.score(false), 7.0);
    }
}
