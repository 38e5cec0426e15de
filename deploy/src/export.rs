//! `selkd export RUN|CHECKPOINT [--actor best|I] --out DIR [--onnx]`: one trained actor as a
//! self-describing bundle that needs nothing of this tool to use.
//!
//! - `DIR/policy.safetensors`: the actor's layers in PyTorch's `nn.Linear` layout, named as the
//!   `state_dict` of `nn.Sequential(Linear, ReLU, …, Linear)` under `net.`: `net.0.weight`
//!   `[out, in]`, `net.0.bias` `[out]`, `net.2.…` (the ReLUs take the odd indices).
//! - `DIR/policy.json`: what the network is and where it came from: the format and its version,
//!   the env (registry name, Gymnasium id, options, action scale of Gymnasium's counterpart), the
//!   sizes, the activation, the `log σ` clamp, the squashing, which actor and its score, the
//!   checkpoint, and the run's whole config.
//! - With `--onnx`, `DIR/policy.onnx` (the deterministic action), written by the `selkd` Python
//!   package through `torch.onnx` (`SELKD_PYTHON`, default the venv `deploy/python.sh` makes).
//!
//! `selkd.load_policy(DIR)` in Python turns the bundle into a `torch.nn.Module`.

use crate::eval::locate;
use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use selkd_learner::checkpoint::load_actor;
use std::path::{Path, PathBuf};
use tch::Tensor;

/// The bundle format this build writes; `load_policy` refuses newer ones.
pub const FORMAT_VERSION: u32 = 1;

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// A run directory (its latest checkpoint) or a checkpoint directory (RUN/checkpoints/NAME).
    path: PathBuf,
    /// Which actor: `best` (by the checkpoint's ranking) or an index.
    #[arg(long, default_value = "best")]
    actor: String,
    /// The bundle's directory (made if missing; the files in it are replaced).
    #[arg(long)]
    out: PathBuf,
    /// Also write policy.onnx (needs the selkd Python package with torch and onnx).
    #[arg(long)]
    onnx: bool,
}

pub fn run(args: ExportArgs) -> Result<()> {
    run_inner(args).map_err(|e| anyhow!("{}", format!("{e:#}").replace('\n', " ")))
}

fn run_inner(args: ExportArgs) -> Result<()> {
    let actor = match args.actor.as_str() {
        "best" => None,
        s => Some(
            s.parse::<usize>()
                .map_err(|_| anyhow!("--actor {s}: expected best or an actor index (0, 1, …)"))?,
        ),
    };
    let (checkpoint, cfg) = locate(&args.path)?;
    let loaded = load_actor(&checkpoint, actor)?;
    let state = loaded
        .state
        .as_ref()
        .expect("locate only returns directories with a state.json");
    let layout = loaded.actor.layout().clone();
    let spec = selkd_envs::make_with(&cfg.run.env, &cfg.env_options)
        .with_context(|| format!("making the run's env `{}`", cfg.run.env))?
        .spec()
        .clone();

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    // The layers, transposed to nn.Linear's [out, in].
    let params = loaded.actor.params();
    let mut tensors = vec![];
    let mut offset = 0;
    for (l, (n_in, n_out)) in layout.layers().into_iter().enumerate() {
        let w = Tensor::from_slice(&params[offset..offset + n_in * n_out])
            .reshape([n_in as i64, n_out as i64])
            .transpose(0, 1)
            .contiguous();
        offset += n_in * n_out;
        let b = Tensor::from_slice(&params[offset..offset + n_out]);
        offset += n_out;
        tensors.push((format!("net.{}.weight", 2 * l), w));
        tensors.push((format!("net.{}.bias", 2 * l), b));
    }
    let weights = args.out.join("policy.safetensors");
    Tensor::write_safetensors(&tensors, &weights)
        .with_context(|| format!("writing {}", weights.display()))?;

    if !spec.gymnasium_action_scale.is_finite() {
        bail!(
            "{}: its action space is not ±c in every dimension, so a bundle's one action_scale cannot map the policy's [-1, 1] onto it; map actions as the workers do, low + (a + 1)/2 · (high − low), from the env's own action_space",
            spec.id
        );
    }
    let scores = state.ranking.scores();
    let score = state.score_of(loaded.index);
    let metadata = serde_json::json!({
        "format": "selkd-policy",
        "format_version": FORMAT_VERSION,
        "env": spec.id,
        "env_options": cfg.env_options,
        "gymnasium_action_scale": spec.gymnasium_action_scale,
        "obs_dim": layout.obs_dim,
        "act_dim": layout.act_dim,
        "hidden": layout.hidden,
        "activation": "relu",
        "log_std_min": selkd_policy::LOG_STD_MIN,
        "log_std_max": selkd_policy::LOG_STD_MAX,
        "squash": "tanh",
        "deterministic_action": "tanh(mu); the network's output is [mu, log_std], act_dim each",
        "actor": loaded.index,
        "actors": loaded.actors,
        "best_actor": state.best_actor(),
        "score": score,
        "scores": scores,
        "env_steps": state.received.iter().sum::<u64>(),
        "checkpoint": std::fs::canonicalize(&checkpoint).unwrap_or(checkpoint.clone()),
        "config": cfg,
    });
    let meta = args.out.join("policy.json");
    std::fs::write(&meta, serde_json::to_string_pretty(&metadata)? + "\n")
        .with_context(|| format!("writing {}", meta.display()))?;
    if args.onnx {
        write_onnx(&args.out)?;
    }
    eprintln!(
        "selkd: exported actor {} of {} ({}, score {}) to {}{}",
        loaded.index,
        loaded.actors,
        spec.id,
        score.map_or("none yet".to_string(), |s| format!("{s:.1}")),
        args.out.display(),
        if args.onnx { " (with policy.onnx)" } else { "" }
    );
    Ok(())
}

/// The interpreter with the `selkd` package: `SELKD_PYTHON`, else the venv deploy/python.sh
/// makes (`SELKD_PYTHON_VENV`, else `python-venv` in the cache it uses).
fn python() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os("SELKD_PYTHON") {
        return Ok(PathBuf::from(p));
    }
    let venv = match std::env::var_os("SELKD_PYTHON_VENV") {
        Some(v) => PathBuf::from(v),
        None => std::env::var_os("SELKD_CACHE")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("XDG_CACHE_HOME").map(|c| Path::new(&c).join("selkd")))
            .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/selkd")))
            .ok_or_else(|| anyhow!("--onnx: set SELKD_PYTHON to a Python with the selkd package"))?
            .join("python-venv"),
    };
    let p = venv.join("bin/python");
    if !p.exists() {
        bail!(
            "--onnx needs the selkd Python package: run `bash deploy/python.sh` (or set SELKD_PYTHON to a Python that has it)"
        );
    }
    Ok(p)
}

fn write_onnx(dir: &Path) -> Result<()> {
    let python = python()?;
    let out = std::process::Command::new(&python)
        .args(["-m", "selkd.policy", "onnx"])
        .arg(dir)
        .output()
        .with_context(|| format!("--onnx: starting {}", python.display()))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err
            .lines()
            .rev()
            .find(|l| !l.trim().is_empty())
            .unwrap_or("");
        bail!(
            "--onnx: {} -m selkd.policy onnx failed: {last}",
            python.display()
        );
    }
    Ok(())
}
