//! `selkd bench learner`: the real SELKD round on synthetic data, timed.

use crate::config::AlgoConfig;
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

fn sync(device: Device) {
    if let Device::Cuda(i) = device {
        tch::Cuda::synchronize(i as i64);
    }
}
