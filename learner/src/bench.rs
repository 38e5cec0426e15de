//! `selkd bench learner`: the real SELKD round on synthetic data, timed.

use crate::config::{AlgoConfig, Sharing};
use crate::replay::ReplayBuffer;
use crate::selkd::Selkd;
use rand::{Rng, SeedableRng};
use std::time::Instant;
use tch::Device;

pub struct BenchResult {
    pub critic_updates_per_sec: f64,
    pub rounds_per_sec: f64,
}

/// Fills a replay buffer with random transitions, runs one warm-up round, then times `rounds`
/// rounds (G critic updates and one update of every actor each).
pub fn learner(
    cfg: &AlgoConfig,
    obs: usize,
    act: usize,
    device: Device,
    rounds: usize,
) -> BenchResult {
    crate::keep_freed_memory();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
    let mut replay = ReplayBuffer::new(cfg.replay_capacity, obs, act, device);
    for _ in 0..cfg.replay_capacity.min(100_000) {
        let mut v = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect() };
        let (s, a, s2) = (v(obs), v(act), v(obs));
        replay.push(&s, &a, rng.gen_range(-1.0..1.0), &s2, false);
    }
    let mut selkd = Selkd::new(cfg, obs, act, device, 0);
    selkd.train_round(&mut replay, 0);
    sync(device);
    let t0 = Instant::now();
    for r in 0..rounds {
        selkd.train_round(&mut replay, r % cfg.actors);
    }
    sync(device);
    let dt = t0.elapsed().as_secs_f64();
    BenchResult {
        critic_updates_per_sec: (rounds * cfg.utd) as f64 / dt,
        rounds_per_sec: rounds as f64 / dt,
    }
}

/// Matrix-multiplication FLOPs of one round (G critic updates and one update of every actor) for
/// the SAC backbone, counting 2 per multiply-add: what the GFLOP/s figure divides by.
///
/// Per critic update: the K actors on the next states (`groups` × B each); the M target critics on
/// K·B rows per group; the N critics forward and backward (weight gradients, and input gradients
/// below the first layer). Per round, the actors' update: the K actors and the best actor on K·B
/// states, the N (fixed) critics forward and back to the action, and the actors' backward.
pub fn flops_per_round(cfg: &AlgoConfig, obs: usize, act: usize) -> f64 {
    let h = cfg.hidden.iter().map(|&x| x as f64).collect::<Vec<_>>();
    let mlp = |dims: &[f64]| -> (f64, f64) {
        // (multiply-adds per row of the forward pass, those of the input gradients below layer 1)
        let fwd: f64 = dims.windows(2).map(|w| w[0] * w[1]).sum();
        let below_first: f64 = dims.windows(2).skip(1).map(|w| w[0] * w[1]).sum();
        (fwd, below_first)
    };
    let mut actor = vec![obs as f64];
    actor.extend(&h);
    actor.push(2.0 * act as f64);
    let mut critic = vec![(obs + act) as f64];
    critic.extend(&h);
    critic.push(1.0);
    let (actor_fwd, actor_below) = mlp(&actor);
    let (critic_fwd, critic_below) = mlp(&critic);
    let (k, n, m, b) = (
        cfg.actors as f64,
        cfg.critics as f64,
        cfg.subset as f64,
        cfg.batch_size as f64,
    );
    let groups = match cfg.method.sharing() {
        Sharing::PerUpdate => 1.0,
        Sharing::PerCritic => n,
    };
    let critic_update = groups * k * b * actor_fwd
        + groups * m * k * b * critic_fwd
        + n * b * (2.0 * critic_fwd + critic_below);
    let actor_update = 2.0 * k * b * actor_fwd
        + n * k * b * (critic_fwd + critic_fwd)
        + k * b * (actor_fwd + actor_below);
    2.0 * (cfg.utd as f64 * critic_update + actor_update)
}

fn sync(device: Device) {
    if let Device::Cuda(i) = device {
        tch::Cuda::synchronize(i as i64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's sizes (K = 1, N = 10, M = 2, B = 256, 256×256, Ant-like 27/8) come to about
    /// 1.2 GFLOP per critic update, as counted by hand when the benchmark was specified.
    #[test]
    fn a_paper_sized_update_is_about_1_2_gflop() {
        let cfg = AlgoConfig {
            actors: 1,
            critics: 10,
            subset: 2,
            utd: 20,
            batch_size: 256,
            hidden: vec![256, 256],
            ..AlgoConfig::default()
        };
        let per_update = flops_per_round(&cfg, 27, 8) / 20.0;
        assert!((1.1e9..1.35e9).contains(&per_update), "{per_update:e}");
        // The N critics' forward and backward dominate: by hand, 10·256·(35·256 + 256² + 256)
        // multiply-adds forward is 191 M, so forward + weight gradients + input gradients is
        // 2·(2·191 M + 10·256·(256² + 256)) = 1.10 GFLOP.
        let critics_only = 2.0
            * (2.0 * 10.0 * 256.0 * (35.0 * 256.0 + 65536.0 + 256.0)
                + 10.0 * 256.0 * (65536.0 + 256.0));
        assert!(per_update > critics_only && per_update < 1.15 * critics_only);
    }
}
