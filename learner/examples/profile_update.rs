//! Times one critic-ensemble update against its GEMM-bound core at the benchmark's sizes
//! (a profiling aid: the gap is the overhead worth attacking), and the bare batched matmuls of
//! the critics' layer shapes: the ceiling of this CPU's libtorch for them.
//!
//!     THREADS=1 [K=5] [MATMUL=bf16] cargo run --release -p selkd-learner --example profile_update
use rand::{Rng, SeedableRng};
use selkd_learner::config::AlgoConfig;
use selkd_learner::replay::ReplayBuffer;
use selkd_learner::selkd::Selkd;
use std::time::Instant;
use tch::{Device, Kind, Tensor};
fn time(name: &str, n: usize, mut f: impl FnMut()) {
    f();
    let t0 = Instant::now();
    for _ in 0..n {
        f();
    }
    println!(
        "{name}: {:.3} ms",
        t0.elapsed().as_secs_f64() * 1000.0 / n as f64
    );
}
fn main() {
    let threads = std::env::var("THREADS")
        .ok()
        .and_then(|t| t.parse().ok())
        .unwrap_or(2);
    selkd_learner::threads::set(threads);
    // The critics' forward and backward matmuls (N = 10, B = 256, 35 inputs, 256 hidden): what
    // they reach alone.
    for (m, k, n) in [
        (256, 256, 256),
        (256, 35, 256),
        (35, 256, 256),
        (256, 256, 1),
    ] {
        let a = Tensor::randn([10, m, k], (Kind::Float, Device::Cpu));
        let b = Tensor::randn([10, k, n], (Kind::Float, Device::Cpu));
        let t0 = Instant::now();
        let reps = 50;
        for _ in 0..reps {
            let _ = a.bmm(&b);
        }
        let dt = t0.elapsed().as_secs_f64() / reps as f64;
        println!(
            "bmm [10,{m},{k}]×[10,{k},{n}]: {:.3} ms, {:.1} GFLOP/s",
            dt * 1e3,
            20.0 * (m * k * n) as f64 / dt / 1e9
        );
    }
    selkd_learner::keep_freed_memory();
    let cfg = AlgoConfig::default();
    let (obs, act) = (27, 8);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
    let mut replay = ReplayBuffer::new(100_000, obs, act, Device::Cpu);
    for _ in 0..100_000 {
        let mut v = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect() };
        let (s, a, s2) = (v(obs), v(act), v(obs));
        replay.push(&s, &a, 0.5, &s2, false);
    }
    let mut s = Selkd::new(
        &AlgoConfig {
            actors: std::env::var("K")
                .ok()
                .and_then(|k| k.parse().ok())
                .unwrap_or(1),
            critic_matmul: match std::env::var("MATMUL").as_deref() {
                Ok("bf16") => selkd_learner::config::Precision::Bf16,
                _ => selkd_learner::config::Precision::Fp32,
            },
            ..cfg.clone()
        },
        obs,
        act,
        Device::Cpu,
        0,
    );
    for round in 0..3 {
        time(
            &format!("[{round}] whole round (G = 20 updates)"),
            5,
            || {
                s.train_round(&mut replay, 0);
            },
        );
        time(&format!("[{round}] actors' update"), 20, || {
            s.update_actors(&mut replay, 0, &mut Default::default());
        });
        time(&format!("[{round}] full critic update"), 40, || {
            s.update_critics(&mut replay);
        });
        let x = Tensor::randn(
            [1, 256, obs as i64 + act as i64],
            (Kind::Float, Device::Cpu),
        );
        let y = Tensor::randn([1, 256], (Kind::Float, Device::Cpu));
        time(
            &format!("[{round}] critic forward+backward, autograd"),
            40,
            || {
                let q = s
                    .critics
                    .forward(&x.expand([10, 256, -1], false))
                    .squeeze_dim(-1);
                let loss = ((&q - &y).square() * 0.5)
                    .mean_dim(1, false, Kind::Float)
                    .sum(Kind::Float);
                loss.backward();
            },
        );
        time(
            &format!("[{round}] critic forward+backward, by hand"),
            40,
            || {
                let _ = s.critics.regress(&x.expand([10, 256, -1], false), &y);
            },
        );
        let critics = s.critics.copy();
        time(&format!("[{round}] polyak"), 40, || {
            s.target_critics.polyak_toward(&critics, 0.995)
        });
        let idx = Tensor::from_slice(&[3i64, 7]);
        let x2 = Tensor::randn(
            [2, 256, obs as i64 + act as i64],
            (Kind::Float, Device::Cpu),
        );
        time(
            &format!("[{round}] target critics select+forward"),
            40,
            || {
                let _ = tch::no_grad(|| s.target_critics.select(&idx).forward(&x2));
            },
        );
        let s2 = Tensor::randn(
            [s.actors.layers[0].weight.size()[0], 256, obs as i64],
            (Kind::Float, Device::Cpu),
        );
        time(&format!("[{round}] actor forward (target)"), 40, || {
            let _ = tch::no_grad(|| s.actors.forward(&s2));
        });
        time(&format!("[{round}] adam"), 40, || {
            s.critic_opt.step(&s.critics.params())
        });
        let mut b = replay.sample(1, 256, &mut rng);
        time(&format!("[{round}] sample"), 40, || {
            b = replay.sample(1, 256, &mut rng)
        });
    }
}
