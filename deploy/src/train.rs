//! `selkd train`: the learner and K actor workers on this host, supervised.

use anyhow::{bail, Context, Result};
use clap::Args;
use selkd_learner::config::Config;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tokio::sync::mpsc;

/// Writes a line to stderr, ignoring failure: a closed terminal (SIGHUP) or pipe must not turn a
/// clean stop into a panic.
macro_rules! say {
    ($($arg:tt)*) => {{
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}
/// As `say!`, without the newline.
macro_rules! sayp {
    ($($arg:tt)*) => {{
        let mut e = std::io::stderr();
        let _ = write!(e, $($arg)*).and_then(|()| e.flush());
    }};
}

/// The quick default: learning on Pendulum within a few minutes on 2 cores.
pub(crate) const QUICK_CONFIG: &str = include_str!("../../configs/quick.toml");

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Config file (TOML). Without one, configs/quick.toml's settings are used.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override a config key, e.g. `--set algo.actors=5` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Run directory (default: runs/<env>-<unix time>).
    #[arg(long)]
    run_dir: Option<PathBuf>,
    /// Continue a run: its directory (from its latest checkpoint), or a checkpoint directory such as runs/X/checkpoints/final (raise run.total_env_steps to train further).
    #[arg(long)]
    resume: Option<PathBuf>,
    /// Give up on a worker that died more than this many times within --restart-window.
    #[arg(long, default_value_t = 20)]
    max_restarts: usize,
    /// With --resume: continue even though this build's env (its physics settings or dynamics,
    /// `env` in the checkpoint's state.json) differs from the one the run trained on; the change
    /// is recorded in the checkpoints.
    #[arg(long, requires = "resume")]
    accept_env_change: bool,
    /// The window (seconds) in which --max-restarts counts a worker's deaths.
    #[arg(long, default_value_t = 600.0, value_parser = parse_restart_window, allow_hyphen_values = true)]
    restart_window: f64,
}

/// Longest `--restart-window`: a year, far beyond any run, and far inside what a `Duration` holds.
const MAX_RESTART_WINDOW: f64 = 365.0 * 24.0 * 3600.0;

/// `--restart-window`: seconds, finite and positive (a window of 0 or NaN would never count two
/// deaths together, so `--max-restarts` would never trigger).
fn parse_restart_window(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v <= MAX_RESTART_WINDOW => Ok(v),
        _ => Err(format!(
            "must be a number of seconds above 0 and at most {MAX_RESTART_WINDOW} (a year)"
        )),
    }
}

/// A worker that dies again soon after its start waits this long before the next, doubling up to
/// `MAX_BACKOFF`; one that lived `STEADY` or longer restarts at once.
const FIRST_BACKOFF: Duration = Duration::from_millis(500);
const MAX_BACKOFF: Duration = Duration::from_secs(10);
const STEADY: Duration = Duration::from_secs(30);

/// One worker slot's restart history.
struct Slot {
    generation: u32,
    pid: Option<u32>,
    started: Instant,
    deaths: std::collections::VecDeque<Instant>,
    backoff: Duration,
}

impl Slot {
    fn new(pid: u32) -> Self {
        Self {
            generation: 0,
            pid: Some(pid),
            started: Instant::now(),
            deaths: Default::default(),
            backoff: Duration::ZERO,
        }
    }

    /// Records a death; returns how long to wait before the restart, or `None` when the worker
    /// died more than `max` times within `window`.
    fn died(&mut self, max: usize, window: Duration) -> Option<Duration> {
        let now = Instant::now();
        self.pid = None;
        self.deaths.push_back(now);
        while self.deaths.front().is_some_and(|&t| now - t > window) {
            self.deaths.pop_front();
        }
        if self.deaths.len() > max {
            return None;
        }
        self.backoff = if now - self.started >= STEADY {
            Duration::ZERO
        } else if self.backoff.is_zero() {
            if self.deaths.len() >= 2 {
                FIRST_BACKOFF
            } else {
                Duration::ZERO
            }
        } else {
            (self.backoff * 2).min(MAX_BACKOFF)
        };
        Some(self.backoff)
    }
}

enum Event {
    Progress(serde_json::Value),
    WorkerExited {
        worker: usize,
        generation: u32,
        code: Option<i32>,
        signal: Option<i32>,
    },
    LearnerExited(std::process::ExitStatus),
    /// The learner reports a worker it waits on as silent for `run.worker_timeout`.
    Stalled {
        worker: usize,
        silent_s: f64,
    },
    /// A restart's back-off is over.
    Restart {
        worker: usize,
        generation: u32,
    },
}

pub fn run(mut args: TrainArgs) -> Result<i32> {
    if let Some(r) = &args.resume {
        let checkpoint = resolve_resume(r)?;
        warn_missing_replay(&checkpoint);
        args.resume = Some(checkpoint);
    }
    // A resumed run keeps the checkpoint's config unless a --config is given; --set applies on top.
    let text = match (&args.config, &args.resume) {
        (Some(p), _) => {
            std::fs::read_to_string(p).with_context(|| format!("reading config {}", p.display()))?
        }
        (None, Some(r)) => checkpoint_config(r)?,
        (None, None) => QUICK_CONFIG.to_string(),
    };
    let cfg = Config::from_toml_with_overrides(&text, &args.set)?;
    if let Some(checkpoint) = &args.resume {
        check_env_to_resume(checkpoint, &cfg, args.accept_env_change)?;
    }
    // A device that is not there is a config error, found before any process starts.
    let device = selkd_learner::service::parse_device(&cfg.run.device)?;
    selkd_learner::service::check_matmul(cfg.algo.critic_matmul, device)?;
    let bin_dir = std::env::current_exe()?
        .parent()
        .map(Path::to_path_buf)
        .context("locating selkd's directory")?;
    let (learner_bin, worker_bin) = (bin_dir.join("learner"), bin_dir.join("actor-worker"));
    for b in [&learner_bin, &worker_bin] {
        if !b.exists() {
            bail!(
                "cannot find {} next to selkd; build all binaries with `cargo build --release`",
                b.display()
            );
        }
    }
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)?
        .as_secs();
    // A resumed run continues in its own directory (RUN/checkpoints/NAME → RUN) unless told otherwise.
    let run_dir = match (&args.run_dir, &args.resume) {
        (Some(d), _) => d.clone(),
        (None, Some(r)) => r
            .canonicalize()
            .ok()
            .and_then(|c| c.parent()?.parent().map(Path::to_path_buf))
            .with_context(|| {
                format!(
                    "finding the run directory of {}; pass --run-dir",
                    r.display()
                )
            })?,
        (None, None) => PathBuf::from("runs").join(format!("{}-{stamp}", cfg.run.env)),
    };
    let created = !run_dir.exists();
    selkd_learner::config::create_run_dir(&run_dir, cfg.run.dir_mode)
        .and_then(|()| std::fs::create_dir_all(run_dir.join("logs")))
        .with_context(|| format!("creating run directory {}", run_dir.display()))?;
    // One launcher per run directory; the lock goes with the process, so a dead holder's is free.
    let _lock = lock_run_dir(&run_dir)?;
    if args.resume.is_none() && holds_run(&run_dir) && !has_checkpoint(&run_dir) {
        // A run stopped (killed, diverged) before its first checkpoint left metrics and logs but
        // nothing to resume: it starts anew rather than leaving the directory stuck.
        start_anew(&run_dir)?;
        say!(
            "selkd: {} holds a run that stopped before its first checkpoint (nothing to resume); starting it anew (its metrics.csv and tb/ are replaced, its logs are appended to)",
            run_dir.display()
        );
    }
    if args.resume.is_none() && holds_run(&run_dir) {
        bail!(
            "run directory {} already holds a run; continue it with --resume {} (from its latest complete checkpoint), or choose another --run-dir",
            run_dir.display(),
            run_dir.display()
        );
    }
    std::fs::write(run_dir.join("config.toml"), cfg.to_toml())?;
    let run_id = format!(
        "r{}x{:x}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)?
            .subsec_nanos()
    );
    say!(
        "selkd: run {run_id}: {} with K={} actors, N={} critics ({:?} mode) → {}",
        cfg.run.env,
        cfg.algo.actors,
        cfg.algo.critics,
        cfg.run.mode,
        run_dir.display()
    );

    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    // The progress line reads the success rates of tasks that have them from metrics.csv.
    crate::progress::watch_metrics(run_dir.join("metrics.csv"));
    let result = rt.block_on(supervise(
        &args,
        &cfg,
        &run_dir,
        &run_id,
        &learner_bin,
        &worker_bin,
    ));
    if !matches!(result, Ok(0)) {
        tidy_failed_start(&run_dir, created);
    }
    result
}

/// Whether `dir` holds a run to continue rather than start: epochs logged or a checkpoint
/// written (an empty `checkpoints/`, which a learner that failed at start leaves, is none).
fn holds_run(dir: &Path) -> bool {
    let checkpoints = dir.join("checkpoints");
    dir.join("metrics.csv").exists()
        || checkpoints.join("latest").exists()
        || std::fs::read_dir(&checkpoints).is_ok_and(|entries| {
            entries
                .filter_map(|e| e.ok())
                .any(|e| e.path().join("state.json").exists())
        })
}

/// Whether `dir/checkpoints` holds a checkpoint directory (complete or not: a damaged one is
/// reported by `--resume`, never silently overwritten).
fn has_checkpoint(dir: &Path) -> bool {
    std::fs::read_dir(dir.join("checkpoints")).is_ok_and(|entries| {
        entries
            .filter_map(|e| e.ok())
            .any(|e| e.path().join("state.json").exists())
    })
}

/// Clears what a run without a checkpoint left, so a new one starts in its directory.
fn start_anew(dir: &Path) -> Result<()> {
    for f in ["metrics.csv", "logs/progress.jsonl"] {
        let p = dir.join(f);
        if p.exists() {
            std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }
    for d in ["tb", "checkpoints"] {
        let p = dir.join(d);
        if p.exists() {
            std::fs::remove_dir_all(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }
    Ok(())
}

/// After a run that failed before it held anything: drop the empty `checkpoints/` it left, and
/// the whole directory if this start created it and no log says anything (a directory that
/// does hold a log keeps it: the failure message points there).
fn tidy_failed_start(run_dir: &Path, created: bool) {
    if holds_run(run_dir) {
        return;
    }
    let _ = std::fs::remove_dir(run_dir.join("checkpoints")); // only if empty
    let logs_say_nothing = std::fs::read_dir(run_dir.join("logs")).is_ok_and(|entries| {
        entries
            .filter_map(|e| e.ok())
            .all(|e| e.metadata().is_ok_and(|m| m.is_file() && m.len() == 0))
    });
    if created && logs_say_nothing {
        let _ = std::fs::remove_dir_all(run_dir);
    }
}

/// The checkpoint `--resume` names: a checkpoint directory, or a run directory (the one its
/// `checkpoints/latest` names, else its newest complete one). Errors are one line naming the file.
fn resolve_resume(r: &Path) -> Result<PathBuf> {
    use selkd_learner::checkpoint::check_complete;
    if r.join("state.json").exists() {
        check_complete(r).map_err(|why| anyhow::anyhow!("--resume {}: {why}", r.display()))?;
        return Ok(r.to_path_buf());
    }
    let checkpoints = r.join("checkpoints");
    let latest = checkpoints.join("latest");
    let reason = match std::fs::read_to_string(&latest) {
        Ok(name) => {
            let dir = checkpoints.join(name.trim());
            match check_complete(&dir) {
                Ok(_) => return Ok(dir),
                Err(why) => format!(
                    "{} names `{}`, which is unusable: {why}",
                    latest.display(),
                    name.trim()
                ),
            }
        }
        Err(_) => format!("{} is missing", latest.display()),
    };
    if let Some((dir, inserted)) = newest_complete(&checkpoints) {
        say!(
            "selkd: {reason}; resuming from the newest complete checkpoint, {} ({inserted} env steps)",
            dir.display()
        );
        return Ok(dir);
    }
    if has_checkpoint(r) {
        bail!(
            "--resume {}: {reason}, and no checkpoint under {} is complete",
            r.display(),
            checkpoints.display()
        );
    }
    if r.join("config.toml").exists() {
        bail!(
            "--resume {}: this run stopped before its first checkpoint, so there is nothing to resume; start it anew with `selkd train --config {} --run-dir {}`",
            r.display(),
            r.join("config.toml").display(),
            r.display()
        );
    }
    bail!(
        "--resume {}: neither a checkpoint directory (no state.json) nor a run directory with checkpoints; pick RUN or one under RUN/checkpoints/",
        r.display()
    )
}

/// The complete checkpoint under `checkpoints` with the most env steps (`final` on a tie), and
/// its env steps. Temporary directories (`NAME.partial`, `NAME.old`) are never chosen.
fn newest_complete(checkpoints: &Path) -> Option<(PathBuf, u64)> {
    std::fs::read_dir(checkpoints)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.is_dir() && p.extension().is_none())
        .filter_map(|p| {
            let state = selkd_learner::checkpoint::check_complete(&p).ok()?;
            let is_final = p.file_name().is_some_and(|n| n == "final");
            Some((state.inserted, is_final, p))
        })
        .max_by_key(|(inserted, is_final, _)| (*inserted, *is_final))
        .map(|(inserted, _, p)| (p, inserted))
}

/// A checkpoint of a run that keeps its replay buffer, whose `replay.safetensors` is gone: the
/// learner starts with an empty buffer, which the user should hear of here, not in learner.log.
fn warn_missing_replay(checkpoint: &Path) {
    let Ok(state) = selkd_learner::checkpoint::check_complete(checkpoint) else {
        return;
    };
    let replay = checkpoint.join("replay.safetensors");
    if state.config.run.checkpoint_replay && !replay.exists() {
        say!(
            "selkd: warning: {} is missing although the run keeps its replay buffer (run.checkpoint_replay = true); it resumes with an empty buffer and trains again once a warm-up's worth of new transitions ({}) refill it",
            replay.display(),
            state.config.algo.warmup_steps
        );
    }
}

/// Children die with the launcher, even when it is SIGKILLed: an orphaned learner would go on
/// writing into a run directory that a resumed run then shares. Each leads a process group of
/// its own, so that a terminal's Ctrl-C (or `timeout`), which signals the launcher's whole group,
/// reaches the launcher alone, and it stops the run in order: a worker killed by the signal
/// itself would be reported dead and restarted on the way out.
fn die_with_parent(c: &mut Command) {
    c.process_group(0);
    unsafe {
        c.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// A resumed run's env against the one its checkpoint records, checked here so that a changed
/// physics is one line before any process starts (the learner checks again, for runs it is
/// given by hand).
fn check_env_to_resume(checkpoint: &Path, cfg: &Config, accept_change: bool) -> Result<()> {
    let state =
        selkd_learner::checkpoint::check_complete(checkpoint).map_err(anyhow::Error::msg)?;
    let now = selkd_envs::EnvRecord::of(&cfg.run.env, &cfg.env_options)?;
    let (_, note) = selkd_learner::checkpoint::continue_env_history(&state, &now, accept_change)?;
    if let Some(note) = note {
        say!("selkd: {note}");
    }
    Ok(())
}

/// The config a checkpoint was trained with, as TOML.
fn checkpoint_config(checkpoint: &Path) -> Result<String> {
    let path = checkpoint.join("state.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let state: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let cfg: Config = serde_json::from_value(state["config"].clone())
        .with_context(|| format!("reading the config in {}", path.display()))?;
    Ok(cfg.to_toml())
}

/// One launcher per run directory (`RUN/.lock`, which names the holder's pid).
fn lock_run_dir(run_dir: &Path) -> Result<selkd_protocol::lock::PidLock> {
    let path = run_dir.join(".lock");
    match selkd_protocol::lock::pid_lock(&path) {
        Ok(f) => Ok(f),
        Err(selkd_protocol::lock::LockError::Held(pid)) => bail!(
            "run directory {} is in use by another selkd (pid {pid}); wait for it, stop it, or choose another --run-dir",
            run_dir.display()
        ),
        Err(e) => Err(e).with_context(|| format!("locking {}", path.display())),
    }
}

fn log_file(run_dir: &Path, name: &str) -> Result<std::fs::File> {
    let p = run_dir.join("logs").join(name);
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&p)
        .with_context(|| format!("opening {}", p.display()))
}

fn spawn_worker(
    bin: &Path,
    run_dir: &Path,
    run_id: &str,
    cfg: &Config,
    worker: usize,
    generation: u32,
    tx: &mpsc::UnboundedSender<Event>,
) -> Result<u32> {
    let log = log_file(run_dir, &format!("worker-{worker}.log"))?;
    let env_options = serde_json::to_string(&cfg.env_options)?;
    let mut cmd = Command::new(bin);
    die_with_parent(&mut cmd);
    let mut child: Child = cmd
        .args([
            "--run-id",
            run_id,
            "--worker",
            &worker.to_string(),
            "--env",
            &cfg.run.env,
            "--env-options",
            &env_options,
            "--generation",
            &generation.to_string(),
        ])
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log)
        .kill_on_drop(true)
        .spawn()
        .with_context(|| format!("starting {}", bin.display()))?;
    let pid = child.id().unwrap_or(0);
    let tx = tx.clone();
    tokio::spawn(async move {
        use std::os::unix::process::ExitStatusExt;
        let status = child.wait().await;
        let (code, signal) = status
            .map(|s| (s.code(), s.signal()))
            .unwrap_or((None, None));
        let _ = tx.send(Event::WorkerExited {
            worker,
            generation,
            code,
            signal,
        });
    });
    Ok(pid)
}

/// Runs the learner and the K workers until the learner exits: restarts a dead worker (with
/// back-off, up to `--max-restarts`), kills a stalled one, turns a stop signal into the learner's
/// checkpoint-and-exit, and prints progress. Returns selkd's exit code.
async fn supervise(
    args: &TrainArgs,
    cfg: &Config,
    run_dir: &Path,
    run_id: &str,
    learner_bin: &Path,
    worker_bin: &Path,
) -> Result<i32> {
    let (tx, mut rx) = mpsc::unbounded_channel::<Event>();
    let learner_pid = spawn_learner(args, run_dir, run_id, learner_bin, &tx)?;
    let slots = (0..cfg.algo.actors)
        .map(|w| spawn_worker(worker_bin, run_dir, run_id, cfg, w, 0, &tx).map(Slot::new))
        .collect::<Result<Vec<Slot>>>()?;
    let mut run = Supervisor {
        args,
        cfg,
        run_dir,
        run_id,
        worker_bin,
        tx,
        learner_pid,
        slots,
        tty: std::io::stderr().is_terminal(),
        started: Instant::now(),
        last_line: Instant::now() - Duration::from_secs(60),
        stopping: false,
        failure: None,
    };
    // SIGINT (Ctrl-C), SIGTERM (kill, timeout, systemd, docker, Slurm) and SIGHUP (a closed
    // terminal) all stop the run the same way: the learner writes a final checkpoint and tells the
    // workers to exit; selkd then exits 128 + the signal's number.
    let mut signals = StopSignals::new()?;
    let mut stopped_by: Option<i32> = None;
    let learner_status = loop {
        tokio::select! {
            sig = signals.next(), if !run.stopping => {
                stopped_by = Some(sig);
                say!("\nselkd: stopping ({}): the learner writes a checkpoint, then everything exits", signal_name(sig));
                run.stop(None);
            }
            ev = rx.recv() => match ev {
                None => bail!("supervision channel closed"),
                Some(Event::Progress(p)) => run.progress(&p),
                Some(Event::WorkerExited { worker, generation, code, signal }) => {
                    run.worker_exited(worker, generation, code, signal)
                }
                Some(Event::Restart { worker, generation }) => run.restart(worker, generation)?,
                Some(Event::Stalled { worker, silent_s }) => run.stalled(worker, silent_s),
                Some(Event::LearnerExited(status)) => break status,
            }
        }
    };
    if run.tty {
        say!();
    }
    reap_workers(&run.slots).await;
    Ok(run.exit_code(learner_status, stopped_by))
}

/// Starts the learner; its stdout's `PROGRESS` lines go to `logs/progress.jsonl` and, like its
/// `STALLED` reports and its exit, to `tx`. Returns its pid.
fn spawn_learner(
    args: &TrainArgs,
    run_dir: &Path,
    run_id: &str,
    learner_bin: &Path,
    tx: &mpsc::UnboundedSender<Event>,
) -> Result<i32> {
    let mut learner_cmd = Command::new(learner_bin);
    die_with_parent(&mut learner_cmd);
    learner_cmd
        .arg("--config")
        .arg(run_dir.join("config.toml"))
        .arg("--run-dir")
        .arg(run_dir)
        .args(["--run-id", run_id]);
    if let Some(r) = &args.resume {
        learner_cmd.arg("--resume").arg(r);
        if args.accept_env_change {
            learner_cmd.arg("--accept-env-change");
        }
    }
    let mut learner = learner_cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(log_file(run_dir, "learner.log")?)
        .kill_on_drop(true)
        .spawn()
        .with_context(|| format!("starting {}", learner_bin.display()))?;
    let learner_pid = learner.id().unwrap_or(0) as i32;
    let stdout = learner.stdout.take().expect("piped");
    let (tx, tx_exit) = (tx.clone(), tx.clone());
    let mut progress_log = log_file(run_dir, "progress.jsonl")?;
    tokio::spawn(async move {
        let mut lines = BufReader::new(stdout).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            if let Some(json) = line.strip_prefix("PROGRESS ") {
                let _ = writeln!(progress_log, "{json}");
                if let Ok(v) = serde_json::from_str(json) {
                    let _ = tx.send(Event::Progress(v));
                }
            } else if let Some(json) = line.strip_prefix("STALLED ") {
                if let Ok(v) = serde_json::from_str::<serde_json::Value>(json) {
                    if let Some(worker) = v["worker"].as_u64() {
                        let silent_s = v["silent_s"].as_f64().unwrap_or(0.0);
                        let _ = tx.send(Event::Stalled {
                            worker: worker as usize,
                            silent_s,
                        });
                    }
                }
            }
        }
    });
    tokio::spawn(async move {
        if let Ok(status) = learner.wait().await {
            let _ = tx_exit.send(Event::LearnerExited(status));
        }
    });
    Ok(learner_pid)
}

/// What `supervise` decides from: the run's processes and whether it is stopping, and why.
struct Supervisor<'a> {
    args: &'a TrainArgs,
    cfg: &'a Config,
    run_dir: &'a Path,
    run_id: &'a str,
    worker_bin: &'a Path,
    tx: mpsc::UnboundedSender<Event>,
    learner_pid: i32,
    slots: Vec<Slot>,
    tty: bool,
    started: Instant,
    /// When the last progress line was printed (a non-terminal gets one every 10 s).
    last_line: Instant,
    /// The learner was told to stop; deaths and restarts no longer matter.
    stopping: bool,
    /// Why the run failed, once it has.
    failure: Option<String>,
}

impl Supervisor<'_> {
    /// Tells the learner to write its checkpoint and end the run (`failure`: because the run failed).
    fn stop(&mut self, failure: Option<String>) {
        self.stopping = true;
        if failure.is_some() {
            self.failure = failure;
        }
        unsafe { libc::kill(self.learner_pid, libc::SIGTERM) };
    }

    fn progress(&mut self, p: &serde_json::Value) {
        let line = progress_line(p, self.started.elapsed());
        if self.tty {
            sayp!("\r\x1b[K{line}");
        } else if self.last_line.elapsed() >= Duration::from_secs(10) {
            say!("{line}");
            self.last_line = Instant::now();
        }
    }

    /// A worker process ended: told to (exit 0), unable to join (the run fails with its reason),
    /// or died (restarted after its back-off, unless it died too often).
    fn worker_exited(
        &mut self,
        worker: usize,
        generation: u32,
        code: Option<i32>,
        signal: Option<i32>,
    ) {
        if generation != self.slots[worker].generation || self.stopping {
            return;
        }
        self.slots[worker].pid = None;
        if code == Some(0) {
            return; // the learner told it to stop
        }
        let log = self
            .run_dir
            .join("logs")
            .join(format!("worker-{worker}.log"));
        if code == Some(selkd_protocol::EXIT_CANNOT_JOIN) {
            // Its own one-line reason, as the worker wrote it last.
            let why = std::fs::read_to_string(&log).ok().and_then(|t| {
                t.lines()
                    .rev()
                    .find(|l| l.contains(": error: "))
                    .map(|l| l.split_once(": error: ").map_or(l, |(_, w)| w).to_string())
            });
            let why = why.map_or(String::new(), |w| format!(": {w}"));
            let failure = format!(
                "worker {worker} cannot join the run{why}; see {}",
                log.display()
            );
            return self.stop(Some(failure));
        }
        let (max, window_s) = (self.args.max_restarts, self.args.restart_window);
        let window = Duration::from_secs_f64(window_s); // bounded by its parser
        let Some(wait) = self.slots[worker].died(max, window) else {
            let deaths = self.slots[worker].deaths.len();
            let failure = format!("worker {worker} died {deaths} times within {window_s:.0} s (--max-restarts {max}, --restart-window {window_s}); giving up; see {}", log.display());
            return self.stop(Some(failure));
        };
        self.slots[worker].generation += 1;
        let generation = self.slots[worker].generation;
        let why = match (code, signal) {
            (_, Some(s)) => format!("signal {s}"),
            (Some(c), _) => format!("exit code {c}"),
            _ => "unknown".into(),
        };
        let after = if wait.is_zero() {
            String::new()
        } else {
            format!(" in {:.1} s", wait.as_secs_f64())
        };
        let nl = if self.tty { "\n" } else { "" };
        say!("{nl}selkd: worker {worker} died ({why}); restarting it{after} (generation {generation})");
        let tx = self.tx.clone();
        tokio::spawn(async move {
            tokio::time::sleep(wait).await;
            let _ = tx.send(Event::Restart { worker, generation });
        });
    }

    /// A restart's back-off is over: starts the worker's next generation, unless it is stale.
    fn restart(&mut self, worker: usize, generation: u32) -> Result<()> {
        if self.stopping || generation != self.slots[worker].generation {
            return Ok(());
        }
        let (bin, dir, id) = (self.worker_bin, self.run_dir, self.run_id);
        let pid = spawn_worker(bin, dir, id, self.cfg, worker, generation, &self.tx)?;
        self.slots[worker].pid = Some(pid);
        self.slots[worker].started = Instant::now();
        Ok(())
    }

    /// The learner waited `silent_s` on a silent worker: kill it, and its death restarts it.
    fn stalled(&mut self, worker: usize, silent_s: f64) {
        // Only a running worker is killed (a dead one's pid may already be another process's).
        if let (false, Some(pid)) = (self.stopping, self.slots.get(worker).and_then(|s| s.pid)) {
            let nl = if self.tty { "\n" } else { "" };
            say!("{nl}selkd: worker {worker} sent nothing for {silent_s:.0} s while the run waited on it (run.worker_timeout = {}); killing it", self.cfg.run.worker_timeout);
            unsafe { libc::kill(pid as i32, libc::SIGKILL) };
        }
    }

    /// The run's last line and selkd's exit code, from how the learner ended.
    fn exit_code(&self, learner_status: std::process::ExitStatus, stopped_by: Option<i32>) -> i32 {
        let run_dir = self.run_dir;
        let learner_log = run_dir.join("logs").join("learner.log");
        match (learner_status.code(), &self.failure) {
            (_, Some(f)) => {
                say!("selkd: run failed: {f}");
                1
            }
            (Some(0), None) => {
                say!(
                    "selkd: done in {:.0} s. Metrics: {}; checkpoint: {}",
                    self.started.elapsed().as_secs_f64(),
                    run_dir.join("metrics.csv").display(),
                    run_dir.join("checkpoints").join("final").display()
                );
                0
            }
            // The learner exits 128 + the signal that stopped it: selkd's own, else the one it got
            // directly (`kill` of the learner alone), so SIGTERM reads as 143, not as Ctrl-C.
            (Some(code @ (129 | 130 | 143)), None) => {
                say!(
                    "selkd: stopped; checkpoint at {}",
                    run_dir.join("checkpoints").join("final").display()
                );
                128 + stopped_by.unwrap_or(code - 128)
            }
            _ => {
                say!(
                    "selkd: the learner failed ({learner_status}): {}\nselkd: full log: {}",
                    last_error_line(&learner_log),
                    learner_log.display()
                );
                1
            }
        }
    }
}

/// The learner's own error line, else its last ERROR, else its last line.
fn last_error_line(learner_log: &Path) -> String {
    std::fs::read_to_string(learner_log)
        .ok()
        .and_then(|t| {
            let lines: Vec<&str> = t.lines().filter(|l| !l.trim().is_empty()).collect();
            lines
                .iter()
                .rev()
                .find(|l| l.starts_with("learner: error:"))
                .or_else(|| lines.iter().rev().find(|l| l.contains("ERROR")))
                .or(lines.last())
                .map(|l| l.to_string())
        })
        .unwrap_or_default()
}

/// Workers leave on the learner's stop order; any still running after a grace period are killed.
async fn reap_workers(slots: &[Slot]) {
    let deadline = Instant::now() + Duration::from_secs(5);
    let pids: Vec<u32> = slots.iter().filter_map(|s| s.pid).collect();
    while Instant::now() < deadline && pids.iter().any(|&p| alive(p)) {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    for &p in &pids {
        if alive(p) {
            unsafe { libc::kill(p as i32, libc::SIGKILL) };
        }
    }
}

/// The signals that stop a run.
struct StopSignals {
    int: tokio::signal::unix::Signal,
    term: tokio::signal::unix::Signal,
    hup: tokio::signal::unix::Signal,
}

impl StopSignals {
    fn new() -> Result<Self> {
        use tokio::signal::unix::{signal, SignalKind};
        Ok(Self {
            int: signal(SignalKind::interrupt()).context("installing the SIGINT handler")?,
            term: signal(SignalKind::terminate()).context("installing the SIGTERM handler")?,
            hup: signal(SignalKind::hangup()).context("installing the SIGHUP handler")?,
        })
    }

    /// The number of the next stop signal.
    async fn next(&mut self) -> i32 {
        tokio::select! {
            _ = self.int.recv() => libc::SIGINT,
            _ = self.term.recv() => libc::SIGTERM,
            _ = self.hup.recv() => libc::SIGHUP,
        }
    }
}

fn signal_name(sig: i32) -> &'static str {
    match sig {
        libc::SIGINT => "Ctrl-C",
        libc::SIGTERM => "SIGTERM",
        libc::SIGHUP => "SIGHUP",
        _ => "signal",
    }
}

fn alive(pid: u32) -> bool {
    pid != 0 && unsafe { libc::kill(pid as i32, 0) } == 0 && !is_zombie(pid)
}

fn is_zombie(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .map(|s| {
            s.rsplit(')')
                .next()
                .is_some_and(|r| r.trim_start().starts_with('Z'))
        })
        .unwrap_or(true)
}

fn progress_line(p: &serde_json::Value, elapsed: Duration) -> String {
    // Windowed rates, the ETA and success rates need history: `crate::progress` keeps it.
    crate::progress::line(p, elapsed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_start_leaves_no_empty_run_directory_and_does_not_block_a_retry() {
        let root = std::env::temp_dir().join(format!("selkd-failed-start-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let logs = |d: &Path, text: &str| {
            std::fs::create_dir_all(d.join("logs")).unwrap();
            std::fs::create_dir_all(d.join("checkpoints")).unwrap();
            std::fs::write(d.join("config.toml"), "").unwrap();
            std::fs::write(d.join("logs/worker-0.log"), "").unwrap();
            std::fs::write(d.join("logs/learner.log"), text).unwrap();
        };
        // The learner said why it failed: its log stays, the empty checkpoints/ goes, and the
        // directory no longer counts as holding a run.
        let said = root.join("said");
        logs(&said, "learner: error: resuming from X: HeaderTooSmall\n");
        assert!(
            !holds_run(&said),
            "an empty checkpoints/ is no run: a retry may use the directory"
        );
        tidy_failed_start(&said, true);
        assert!(said.join("logs/learner.log").exists() && !said.join("checkpoints").exists());
        assert!(!holds_run(&said));
        // Nothing was said, and this start made the directory: nothing is left.
        let silent = root.join("silent");
        logs(&silent, "");
        tidy_failed_start(&silent, true);
        assert!(!silent.exists());
        // A directory the user had before is never removed.
        let theirs = root.join("theirs");
        logs(&theirs, "");
        tidy_failed_start(&theirs, false);
        assert!(theirs.join("config.toml").exists());
        // A run with a checkpoint is left alone.
        let real = root.join("real");
        logs(&real, "");
        std::fs::create_dir_all(real.join("checkpoints/final")).unwrap();
        std::fs::write(real.join("checkpoints/final/state.json"), "{}").unwrap();
        tidy_failed_start(&real, true);
        assert!(holds_run(&real) && real.join("checkpoints/final/state.json").exists());
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn restarts_back_off_while_a_worker_keeps_dying_and_give_up_past_the_window_limit() {
        let window = Duration::from_secs(600);
        let mut slot = Slot::new(1);
        let ms = Duration::from_millis;
        // Dying soon after each start: at once, then 0.5 s doubling, capped at 10 s.
        let waits: Vec<Option<Duration>> = (0..7).map(|_| slot.died(7, window)).collect();
        assert_eq!(
            waits,
            [0, 500, 1000, 2000, 4000, 8000, 10_000].map(|m| Some(ms(m)))
        );
        assert_eq!(slot.died(7, window), None, "the 8th death in the window");
        // A worker that lived STEADY restarts at once again.
        let mut slot = Slot::new(1);
        slot.died(20, window);
        slot.died(20, window);
        slot.started = Instant::now() - STEADY;
        assert_eq!(slot.died(20, window), Some(Duration::ZERO));
        // Deaths older than the window no longer count.
        let mut slot = Slot::new(1);
        let short = ms(50);
        assert!(slot.died(1, short).is_some());
        assert!(slot.died(1, short).is_none(), "two deaths within 50 ms");
        std::thread::sleep(ms(60));
        assert!(
            slot.died(1, short).is_some(),
            "the earlier ones left the window"
        );
    }
}
