//! `selkd bench learner` and `selkd bench env`.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use rand::{Rng, SeedableRng};
use selkd_learner::config::{
    bytes, physical_memory, AlgoConfig, AlgoKeys, Config, Precision, Regulariser, Sharing,
};
use selkd_learner::matmul::CpuGemm;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The names `--sharing` and `--critic-matmul` take, for the header line.
fn sharing_name(s: Sharing) -> &'static str {
    match s {
        Sharing::PerUpdate => "per-update",
        Sharing::PerCritic => "per-critic",
    }
}

fn precision_name(p: Precision) -> &'static str {
    match p {
        Precision::Fp32 => "fp32",
        Precision::Bf16 => "bf16",
    }
}

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
    /// Bench a config file's own settings instead of the flags above: its `[algo]`, the sizes
    /// of its `run.env`, its `run.device`, `run.threads` and `run.cpu_gemm`; then say how long
    /// its budget of critic updates takes at the rate measured.
    #[arg(long, conflicts_with_all = [
        "k", "n", "m", "g", "batch", "obs", "act", "hidden", "sharing", "device",
        "critic_matmul", "threads", "cpu_gemm", "variants",
    ])]
    config: Option<PathBuf>,
    /// With --config: override one of its keys, as `selkd train --set` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE", requires = "config")]
    set: Vec<String>,
}

/// What one `selkd bench learner` runs: the learner's settings, the env's sizes, the device,
/// and (from a config file) the run's budget.
struct Setup {
    cfg: AlgoConfig,
    obs: usize,
    act: usize,
    device: String,
    budget: Option<Budget>,
}

/// A config file's budget, for the time estimate.
struct Budget {
    file: String,
    total_env_steps: u64,
    critic_updates: u64,
}

/// The settings of `selkd bench learner`'s flags, checked.
fn from_flags(b: &LearnerBench) -> Result<Setup> {
    let sharing = match b.sharing.as_str() {
        "per-update" => Sharing::PerUpdate,
        "per-critic" => Sharing::PerCritic,
        other => anyhow::bail!("--sharing {other}: use per-update or per-critic"),
    };
    for (flag, value) in [
        ("--g", b.g),
        ("--batch", b.batch),
        ("--obs", b.obs),
        ("--act", b.act),
        ("--hidden", b.hidden),
    ] {
        if value == 0 {
            anyhow::bail!("{flag} must be at least 1");
        }
    }
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
    if b.variants > 0 && b.k != 1 {
        anyhow::bail!("--variants (AVTD) needs --k 1");
    }
    // The flags are `[algo]` keys: the method they make is read as a config file's is.
    let cfg = AlgoConfig::try_from(AlgoKeys {
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
        ..AlgoKeys::default()
    })
    .map_err(anyhow::Error::msg)?;
    // As `selkd train` refuses a config that cannot fit: an allocation failing inside libtorch
    // is an abort, not a message.
    if b.device == "cpu" {
        if let Some(physical) = physical_memory() {
            let need = cfg.network_bytes(b.obs, b.act);
            if need > physical {
                anyhow::bail!(
                    "the networks (--hidden {}, --k {}, --n {}) with their gradients and Adam state need at least {}, more than this machine's {}; lower them",
                    b.hidden,
                    b.k,
                    b.n,
                    bytes(need),
                    bytes(physical)
                );
            }
        }
    }
    Ok(Setup {
        cfg,
        obs: b.obs,
        act: b.act,
        device: b.device.clone(),
        budget: None,
    })
}

/// The settings of a config file (validated as `selkd train` validates it), with `--set` applied.
fn from_config(path: &Path, set: &[String]) -> Result<Setup> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading config {}", path.display()))?;
    let cfg = Config::from_toml_with_overrides(&text, set)?;
    let spec = cfg.env_spec()?;
    selkd_learner::threads::set(cfg.run.threads);
    selkd_learner::matmul::set(cfg.run.cpu_gemm);
    Ok(Setup {
        obs: spec.obs_dim,
        act: spec.act_dim,
        device: cfg.run.device.clone(),
        budget: Some(Budget {
            file: path.display().to_string(),
            total_env_steps: cfg.run.total_env_steps,
            critic_updates: cfg.critic_updates_in_budget(),
        }),
        cfg: cfg.algo,
    })
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Learner(b) => {
            if b.rounds == 0 {
                anyhow::bail!("--rounds must be at least 1");
            }
            let Setup {
                cfg,
                obs,
                act,
                device: device_name,
                budget,
            } = match &b.config {
                Some(path) => from_config(path, &b.set)?,
                None => from_flags(&b)?,
            };
            let device = selkd_learner::service::parse_device(&device_name)?;
            selkd_learner::service::check_matmul(cfg.critic_matmul, device)?;
            let r = selkd_learner::bench::learner(&cfg, obs, act, device, b.rounds);
            let variants = cfg.method.variants().len();
            // AVTD's round is V REDQ rounds' matmuls, stacked.
            let gflops = selkd_learner::bench::flops_per_round(&cfg, obs, act)
                * variants.max(1) as f64
                * r.rounds_per_sec
                / 1e9;
            println!(
                "K={} N={} M={} G={}{} batch={} obs={obs} act={act} hidden={} {} {} on {device_name} ({}, {} threads, fp32 products by {}): {:.1} rounds/s, {gflops:.1} GFLOP/s in matmuls",
                cfg.actors, cfg.critics, cfg.subset, cfg.utd,
                if variants > 0 { format!(" V={variants}") } else { String::new() }, cfg.batch_size,
                cfg.hidden.iter().map(usize::to_string).collect::<Vec<_>>().join("x"),
                sharing_name(cfg.method.sharing()), precision_name(cfg.critic_matmul),
                selkd_learner::service::cpu_model(), selkd_learner::threads::get(), selkd_learner::matmul::chosen().describe(), r.rounds_per_sec
            );
            if let Some(budget) = budget {
                println!(
                    "{}: {} critic updates in run.total_env_steps = {}, about {} at this rate (the learner's time alone; evaluation and checkpoints add to it)",
                    budget.file,
                    budget.critic_updates,
                    budget.total_env_steps,
                    crate::progress::duration(budget.critic_updates as f64 / r.critic_updates_per_sec)
                );
            }
            println!("{:.2} updates/s", r.critic_updates_per_sec);
        }
        BenchCommand::Env {
            name,
            steps,
            env_options,
        } => {
            if steps == 0 {
                anyhow::bail!("--steps must be at least 1");
            }
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
