//! `selkd bench learner` and `selkd bench env`.

use anyhow::Result;
use clap::{Args, Subcommand};
use rand::{Rng, SeedableRng};
use selkd_learner::config::{AlgoConfig, Precision, Regulariser, Sharing};
use selkd_learner::matmul::CpuGemm;
use std::time::Instant;

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// The real SELKD round on synthetic data: prints `X updates/s` (critic-ensemble updates).
    Learner(LearnerBench),
    /// One env stepped single-threaded with random actions: prints `X env steps/s`.
    Env {
        /// Env name (see the README for the list).
        name: String,
        #[arg(long, default_value_t = 20_000)]
        steps: usize,
        /// The env's options as JSON or TOML, e.g. `"substeps = 5"` for a robot's physics.
        #[arg(long)]
        env_options: Option<String>,
    },
}

#[derive(Args, Debug)]
pub struct LearnerBench {
    /// K actors.
    #[arg(long, default_value_t = 1)]
    k: usize,
    /// N critics.
    #[arg(long, default_value_t = 10)]
    n: usize,
    /// M, the target's critic subset.
    #[arg(long, default_value_t = 2)]
    m: usize,
    /// G, critic updates per round.
    #[arg(long, default_value_t = 20)]
    g: usize,
    #[arg(long, default_value_t = 256)]
    batch: usize,
    #[arg(long, default_value_t = 27)]
    obs: usize,
    #[arg(long, default_value_t = 8)]
    act: usize,
    #[arg(long, default_value_t = 256)]
    hidden: usize,
    /// per-update or per-critic.
    #[arg(long, default_value = "per-update")]
    sharing: String,
    #[arg(long, default_value = "cpu")]
    device: String,
    /// Timed rounds (after one warm-up round).
    #[arg(long, default_value_t = 10)]
    rounds: usize,
    /// Element type of the critics' matmuls: fp32 or bf16.
    #[arg(long, default_value = "fp32")]
    critic_matmul: String,
    /// Threads, as `run.threads` (0 = one per core): the critics' members split over them,
    /// libtorch on one each.
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Who multiplies the critics' fp32 matrices, as `run.cpu_gemm`: auto, libtorch or gemm.
    #[arg(long, default_value = "auto")]
    cpu_gemm: String,
    /// AVTD: this many variants side by side (none, layer-norm, weight-decay, then again), each
    /// with K = 1 and N critics; 0: not AVTD.
    #[arg(long, default_value_t = 0)]
    variants: usize,
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Learner(b) => {
            let sharing = match b.sharing.as_str() {
                "per-update" => Sharing::PerUpdate,
                "per-critic" => Sharing::PerCritic,
                other => anyhow::bail!("--sharing {other}: use per-update or per-critic"),
            };
            if b.m == 0 || b.m > b.n || b.k == 0 {
                anyhow::bail!(
                    "need 1 ≤ --m ≤ --n and --k ≥ 1 (got k {}, n {}, m {})",
                    b.k,
                    b.n,
                    b.m
                );
            }
            selkd_learner::threads::set(b.threads);
            selkd_learner::matmul::set(match b.cpu_gemm.as_str() {
                "auto" => CpuGemm::Auto,
                "libtorch" => CpuGemm::Libtorch,
                "gemm" => CpuGemm::Gemm,
                other => anyhow::bail!("--cpu-gemm {other}: use auto, libtorch or gemm"),
            });
            let critic_matmul = match b.critic_matmul.as_str() {
                "fp32" => Precision::Fp32,
                "bf16" => Precision::Bf16,
                other => anyhow::bail!("--critic-matmul {other}: use fp32 or bf16"),
            };
            let cfg = AlgoConfig {
                critic_matmul,
                actors: b.k,
                critics: b.n,
                subset: b.m,
                utd: b.g,
                batch_size: b.batch,
                hidden: vec![b.hidden, b.hidden],
                sharing,
                variants: [
                    Regulariser::None,
                    Regulariser::LayerNorm,
                    Regulariser::WeightDecay,
                ]
                .into_iter()
                .cycle()
                .take(b.variants)
                .collect(),
                ..AlgoConfig::default()
            };
            if b.variants > 0 && b.k != 1 {
                anyhow::bail!("--variants (AVTD) needs --k 1");
            }
            let device = selkd_learner::service::parse_device(&b.device)?;
            selkd_learner::service::check_matmul(cfg.critic_matmul, device)?;
            let r = selkd_learner::bench::learner(&cfg, b.obs, b.act, device, b.rounds);
            // AVTD's round is V REDQ rounds' matmuls, stacked.
            let gflops = selkd_learner::bench::flops_per_round(&cfg, b.obs, b.act)
                * b.variants.max(1) as f64
                * r.rounds_per_sec
                / 1e9;
            println!(
                "K={} N={} M={} G={}{} batch={} obs={} act={} hidden={} {} {} on {} ({}, {} threads, fp32 products by {}): {:.1} rounds/s, {gflops:.1} GFLOP/s in matmuls",
                b.k, b.n, b.m, b.g,
                if b.variants > 0 { format!(" V={}", b.variants) } else { String::new() }, b.batch, b.obs, b.act, b.hidden, b.sharing, b.critic_matmul, b.device,
                selkd_learner::service::cpu_model(), selkd_learner::threads::get(), selkd_learner::matmul::chosen().describe(), r.rounds_per_sec
            );
            println!("{:.2} updates/s", r.critic_updates_per_sec);
        }
        BenchCommand::Env {
            name,
            steps,
            env_options,
        } => {
            let options = match env_options {
                Some(text) => crate::render::parse_env_options(&text)?,
                None => Default::default(),
            };
            let mut env = selkd_envs::make_with(&name, &options)?;
            let act = env.spec().act_dim;
            let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
            env.reset(Some(0));
            let t0 = Instant::now();
            let mut episodes = 0;
            for _ in 0..steps {
                let a: Vec<f32> = (0..act).map(|_| rng.gen_range(-1.0..=1.0)).collect();
                let s = env.step(&a);
                if s.terminated || s.truncated {
                    env.reset(None);
                    episodes += 1;
                }
            }
            let dt = t0.elapsed().as_secs_f64();
            println!("{name}: {steps} steps, {episodes} episodes");
            println!("{:.0} env steps/s", steps as f64 / dt);
        }
    }
    Ok(())
}
