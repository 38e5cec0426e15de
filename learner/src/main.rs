//! `learner`: the SELKD learner process. Usually started by `selkd train`; it can also be run by
//! hand beside `actor-worker` processes that use the same `--run-id`.

use anyhow::{Context, Result};
use clap::Parser;
use selkd_learner::config::Config;
use selkd_learner::service::{Learner, Outcome, Resume};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "The SELKD learner: trains K actors and N critics from the transitions of actor-worker processes"
)]
struct Args {
    /// Config file (TOML); defaults apply to every key it leaves out.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override one config key, e.g. `--set algo.critics=4` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Where metrics.csv and checkpoints go.
    #[arg(long, default_value = "runs/manual")]
    run_dir: PathBuf,
    /// Run id shared with the workers.
    #[arg(long)]
    run_id: String,
    /// Continue from a checkpoint directory (e.g. RUN/checkpoints/final).
    #[arg(long)]
    resume: Option<PathBuf>,
    /// With --resume: continue even though this build's env (its physics settings or dynamics)
    /// differs from the one the run trained on; the change is recorded in the checkpoints.
    #[arg(long, requires = "resume")]
    accept_env_change: bool,
}

fn main() {
    selkd_learner::restart_with_runtime_settings();
    // `gymnasium:` envs step in an embedded Python.
    selkd_gymnasium::register();
    selkd_protocol::init_tracing();
    let args = Args::parse();
    let signal = Arc::new(AtomicUsize::new(0));
    match run(&args, &signal) {
        Ok(Outcome::Finished) => {}
        // 128 + the signal, as a shell reports a process the signal ended: `selkd train` (and
        // schedulers) tell a SIGTERM (143) from a Ctrl-C (130).
        Ok(Outcome::Interrupted) => {
            let sig = match signal.load(Ordering::SeqCst) {
                0 => signal_hook::consts::SIGINT as usize,
                s => s,
            };
            std::process::exit(128 + sig as i32)
        }
        Err(e) => {
            eprintln!("learner: error: {e:#}");
            std::process::exit(1);
        }
    }
}

fn run(args: &Args, signal: &Arc<AtomicUsize>) -> Result<Outcome> {
    selkd_learner::keep_freed_memory();
    let text = match &args.config {
        Some(p) => {
            std::fs::read_to_string(p).with_context(|| format!("reading config {}", p.display()))?
        }
        None => String::new(),
    };
    let cfg = Config::from_toml_with_overrides(&text, &args.set)?;
    let stop = Arc::new(AtomicBool::new(false));
    // SIGHUP too: a closed terminal must stop the run with a checkpoint, not kill the learner.
    for sig in [
        signal_hook::consts::SIGINT,
        signal_hook::consts::SIGTERM,
        signal_hook::consts::SIGHUP,
    ] {
        signal_hook::flag::register(sig, stop.clone()).context("installing signal handlers")?;
        signal_hook::flag::register_usize(sig, signal.clone(), sig as usize)
            .context("installing signal handlers")?;
    }
    let _lock = lock_run_id(&args.run_id)?;
    let resume = args.resume.as_deref().map(|checkpoint| Resume {
        checkpoint,
        accept_env_change: args.accept_env_change,
    });
    let mut learner = Learner::new(cfg, &args.run_dir, resume)?;
    learner.run(&args.run_id, stop)
}

/// One learner per run id: two would both accept the same workers (split brain). The lock lives
/// in this user's private lock directory, never in the shared temp directory, where another
/// local user could plant a link to a file of ours or hold the lock to block our runs.
fn lock_run_id(run_id: &str) -> Result<selkd_protocol::lock::PidLock> {
    selkd_protocol::Services::new(run_id).transitions()?; // the run id must be a valid name
    let dir = selkd_protocol::lock::user_lock_dir().context("the per-user lock directory")?;
    let path = dir.join(format!("learner-{run_id}.lock"));
    match selkd_protocol::lock::pid_lock(&path) {
        Ok(f) => Ok(f),
        Err(selkd_protocol::lock::LockError::Held(pid)) => {
            anyhow::bail!(
                "run id `{run_id}` already has a learner (pid {pid}); pick another --run-id"
            )
        }
        Err(e) => Err(e).with_context(|| format!("locking run id `{run_id}`")),
    }
}
