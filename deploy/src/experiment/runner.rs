//! `selkd experiment run`: every (method, task, seed) as a child `selkd train`, J at a time.
//!
//! Each run is an ordinary run directory, so everything `selkd train` does (checkpoints, resume,
//! restarting workers) is reused rather than re-implemented; this module only decides which runs
//! to start, how (fresh or `--resume`), and what to do when they end or the user stops.

use super::spec::{self, Run};
use super::state::{state, State};
use super::RunArgs;
use crate::progress::duration;
use anyhow::{Context, Result};
use selkd_learner::config::DirMode;
use std::collections::{HashMap, VecDeque};
use std::io::{IsTerminal, Read, Seek, SeekFrom};
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};
use tokio::process::Command;
use tokio::signal::unix::{signal, SignalKind};
use tokio::sync::mpsc;

struct Running {
    pid: i32,
    /// Held while the run trains (see [`lock`]).
    _lock: selkd_protocol::lock::PidLock,
}

/// Claims a run directory for this process: an exclusive `flock` on `.selkd.lock`, or `None`
/// when another `selkd experiment run` holds it (the same experiment started twice, or a Slurm
/// array resubmitted while its first tasks still run). Two `selkd train` in one directory would
/// each overwrite the other's checkpoints. The lock goes with this process, however it ends.
fn lock(dir: &Path, mode: DirMode) -> Result<Option<selkd_protocol::lock::PidLock>> {
    selkd_learner::config::create_run_dir(dir, mode)
        .with_context(|| format!("creating run directory {}", dir.display()))?;
    let path = dir.join(".selkd.lock");
    match selkd_protocol::lock::pid_lock(&path) {
        Ok(f) => Ok(Some(f)),
        Err(selkd_protocol::lock::LockError::Held(_)) => Ok(None),
        Err(e) => Err(e).with_context(|| format!("locking {}", path.display())),
    }
}

/// A run that never reached a checkpoint has nothing to resume: clear what it left (its
/// metrics rows and an empty checkpoints folder) so that it starts again from the beginning;
/// `selkd train` refuses to start a new run over an old one.
fn clear_unresumable(dir: &Path) -> Result<()> {
    let metrics = dir.join("metrics.csv");
    if metrics.exists() {
        std::fs::remove_file(&metrics)
            .with_context(|| format!("removing {}", metrics.display()))?;
    }
    let checkpoints = dir.join("checkpoints");
    if checkpoints.exists() {
        std::fs::remove_dir_all(&checkpoints)
            .with_context(|| format!("removing {}", checkpoints.display()))?;
    }
    Ok(())
}

enum Outcome {
    Finished,
    Stopped,
    Failed(String),
}

pub fn run(args: RunArgs) -> Result<i32> {
    let dir = super::experiment_dir(&args.experiment, args.dir.as_deref());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let jobs = args.jobs.unwrap_or(cores);
    if jobs == 0 {
        anyhow::bail!("--jobs 0: at least one run must be able to run; leave it out for one per core ({cores})");
    }
    if let Some(published) = &args.published {
        let ids = spec::Experiment::load(&args.experiment)?.run_ids();
        let restored = super::publish::restore(published, &dir, &ids)?;
        eprintln!(
            "selkd: experiment: {} published run(s) put back from {} as finished",
            restored.len(),
            published.display()
        );
    }
    let (exp, runs) = spec::prepare(&args.experiment, &dir, cores, jobs, &args.only)?;
    super::write_experiment(&exp, &dir)?;

    // What each run needs now; decided again when it starts (see `schedule`).
    let (mut skipped, mut resumed) = (0, 0);
    let mut todo = VecDeque::new();
    for (i, r) in runs.iter().enumerate() {
        match state(&r.dir, r.config.run.total_env_steps) {
            State::Finished => skipped += 1,
            State::Resume(_) => {
                resumed += 1;
                todo.push_back(i);
            }
            State::Fresh => todo.push_back(i),
        }
    }
    // Resolved once, now: rebuilding or upgrading selkd while an experiment runs replaces the
    // file, and from then on the kernel names this process's own image "selkd (deleted)", so a
    // later `current_exe()` could not start the next run. The path itself still leads to selkd.
    let exe = std::env::current_exe().context("locating selkd")?;
    let threads = runs.first().map_or(1, |r| r.config.run.threads);
    eprintln!(
        "selkd: experiment {}: {} runs: {skipped} finished (skipped), {resumed} to resume, {} to start; {} at a time, run.threads = {threads} unless the experiment sets it → {}",
        args.experiment.display(),
        runs.len(),
        todo.len() - resumed,
        jobs.min(todo.len().max(1)),
        dir.display()
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(schedule(&exe, &runs, todo, jobs, skipped))
}

fn spawn(
    exe: &Path,
    run: &Run,
    resume: Option<&Path>,
    tx: &mpsc::UnboundedSender<(usize, Outcome)>,
    index: usize,
) -> Result<i32> {
    let logs = run.dir.join("logs");
    std::fs::create_dir_all(&logs)
        .with_context(|| format!("creating run directory {}", run.dir.display()))?;
    let log_path = logs.join("selkd.log");
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .with_context(|| format!("opening {}", log_path.display()))?;
    let mut cmd = Command::new(exe);
    cmd.arg("train")
        .arg("--config")
        .arg(&run.config_file)
        .args(run.sets.iter().flat_map(|s| ["--set", s.as_str()]))
        .arg("--run-dir")
        .arg(&run.dir);
    if let Some(c) = resume {
        cmd.arg("--resume").arg(c);
    }
    // Its own process group: a Ctrl-C at the terminal reaches only this process, which then
    // stops every child once, in order, instead of each child seeing the signal by itself.
    cmd.process_group(0)
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log);
    // If this process dies without stopping them, the children stop themselves.
    unsafe {
        cmd.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    let mut child = cmd
        .spawn()
        .with_context(|| format!("run {}: starting selkd train", run.id))?;
    let pid = child.id().unwrap_or(0) as i32;
    let tx = tx.clone();
    let (budget, dir) = (run.config.run.total_env_steps, run.dir.clone());
    tokio::spawn(async move {
        use std::os::unix::process::ExitStatusExt;
        let outcome = match child.wait().await {
            Ok(s) if s.success() => {
                if state(&dir, budget) == State::Finished {
                    Outcome::Finished
                } else {
                    Outcome::Failed("exited 0 but its final checkpoint is below the budget".into())
                }
            }
            Ok(s)
                if matches!(s.code(), Some(130) | Some(143))
                    || matches!(s.signal(), Some(libc::SIGINT) | Some(libc::SIGTERM)) =>
            {
                Outcome::Stopped
            }
            Ok(s) => Outcome::Failed(s.to_string()),
            Err(e) => Outcome::Failed(format!("waiting for it: {e}")),
        };
        let _ = tx.send((index, outcome));
    });
    Ok(pid)
}

async fn schedule(
    exe: &Path,
    runs: &[Run],
    mut todo: VecDeque<usize>,
    jobs: usize,
    skipped: usize,
) -> Result<i32> {
    let (tx, mut rx) = mpsc::unbounded_channel();
    let mut sigint = signal(SignalKind::interrupt())?;
    let mut sigterm = signal(SignalKind::terminate())?;
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    let mut progress = Progress::new(runs.len(), jobs, skipped);
    let mut running: HashMap<usize, Running> = HashMap::new();
    let (mut failed, mut stopped) = (Vec::new(), 0);
    // Runs another selkd trains now, tried again every second: that runner finishing one is
    // success here too (a Slurm array counts exit codes), and one it stops is resumed here.
    let mut elsewhere: Vec<usize> = Vec::new();
    let mut announced = std::collections::HashSet::new();
    let mut stop: Option<i32> = None;
    loop {
        while stop.is_none() && running.len() < jobs {
            let Some(i) = todo.pop_front() else {
                break;
            };
            // A run that cannot start (its directory cannot be made or cleared, selkd cannot be
            // started) fails alone: the runs already training go on, and so does the queue.
            let claimed = match lock(&runs[i].dir, runs[i].config.run.dir_mode) {
                Ok(claimed) => claimed,
                Err(e) => {
                    fail(&mut progress, &mut failed, &runs[i].id, &cannot_start(e));
                    continue;
                }
            };
            let Some(lock) = claimed else {
                if announced.insert(i) {
                    progress.clear();
                    eprintln!(
                        "selkd: run {} is being trained by another selkd (it holds {}); waiting for it to finish or stop",
                        runs[i].id,
                        runs[i].dir.join(".selkd.lock").display()
                    );
                }
                elsewhere.push(i);
                continue;
            };
            // Judged under the lock, not from the list made at the start: a run that waited in
            // the queue may have been advanced or finished by another runner meanwhile.
            let resume = match state(&runs[i].dir, runs[i].config.run.total_env_steps) {
                State::Finished => {
                    progress.done += 1; // finished elsewhere: no duration to learn from
                    continue;
                }
                State::Resume(c) => Some(c),
                State::Fresh => {
                    if let Err(e) = clear_unresumable(&runs[i].dir) {
                        fail(&mut progress, &mut failed, &runs[i].id, &cannot_start(e));
                        continue;
                    }
                    None
                }
            };
            match spawn(exe, &runs[i], resume.as_deref(), &tx, i) {
                Ok(pid) => {
                    running.insert(i, Running { pid, _lock: lock });
                }
                Err(e) => fail(&mut progress, &mut failed, &runs[i].id, &cannot_start(e)),
            }
        }
        if running.is_empty() && (elsewhere.is_empty() || stop.is_some()) {
            break;
        }
        tokio::select! {
            _ = sigint.recv(), if stop.is_none() => stop = Some(libc::SIGINT),
            _ = sigterm.recv(), if stop.is_none() => stop = Some(libc::SIGTERM),
            Some((i, outcome)) = rx.recv() => {
                running.remove(&i).expect("a started run");
                match outcome {
                    Outcome::Finished => progress.finished(),
                    Outcome::Stopped => stopped += 1,
                    Outcome::Failed(why) => {
                        let log = runs[i].dir.join("logs").join("selkd.log");
                        let why = format!("failed ({why}): {}\nselkd: its log: {}", last_line(&log), log.display());
                        fail(&mut progress, &mut failed, &runs[i].id, &why);
                    }
                }
                continue;
            }
            _ = tick.tick() => {
                let left: Vec<usize> = todo.iter().chain(&elsewhere).copied().collect();
                progress.show(runs, &running, &left, failed.len());
                todo.extend(elsewhere.drain(..));
                continue;
            }
        }
        // A stop was asked for: every running run writes its checkpoint and exits.
        progress.clear();
        eprintln!(
            "selkd: stopping {} running runs (each writes a checkpoint; run the experiment again to resume them)",
            running.len()
        );
        // SIGTERM, as a scheduler or `kill` sends: `selkd train` stops with a checkpoint.
        let sig = libc::SIGTERM;
        for r in running.values() {
            unsafe { libc::kill(r.pid, sig) };
        }
    }
    progress.clear();
    let done = progress.done;
    eprintln!(
        "selkd: experiment: {done}/{} runs finished ({skipped} already were), {} failed, {stopped} stopped, {} not started",
        runs.len(),
        failed.len(),
        todo.len() + elsewhere.len()
    );
    if !failed.is_empty() {
        eprintln!("selkd: failed runs: {}", failed.join(", "));
    }
    Ok(match stop {
        Some(sig) => 128 + sig,
        None if !failed.is_empty() || stopped > 0 => 1,
        None => 0,
    })
}

/// Counts run `id` as failed and says `why` ("failed ..."), below the progress line.
fn fail(progress: &mut Progress, failed: &mut Vec<String>, id: &str, why: &str) {
    progress.clear();
    eprintln!("selkd: run {id} {why}");
    failed.push(id.to_string());
}

/// What [`fail`] says of a run that could not be started.
fn cannot_start(e: anyhow::Error) -> String {
    format!("failed to start: {e:#}")
}

/// The line of a log that says why a run failed: the last one with an error (`selkd train`
/// ends with a pointer to the learner's log, which says less), else the last line.
fn last_line(path: &Path) -> String {
    let text = tail(path, 8192);
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines
        .iter()
        .rev()
        .find(|l| l.contains("error") || l.contains("failed"))
        .or(lines.last())
        .map_or("(empty log)".to_string(), |l| l.to_string())
}

/// The last `bytes` of a file (progress.jsonl grows by a line a second; reading it whole every
/// second for J runs would not scale to day-long runs).
fn tail(path: &Path, bytes: u64) -> String {
    let Ok(mut f) = std::fs::File::open(path) else {
        return String::new();
    };
    let len = f.metadata().map_or(0, |m| m.len());
    let _ = f.seek(SeekFrom::Start(len.saturating_sub(bytes)));
    let mut buf = Vec::new();
    let _ = f.read_to_end(&mut buf);
    String::from_utf8_lossy(&buf).into_owned()
}

/// The experiment's one progress line.
struct Progress {
    total: usize,
    jobs: usize,
    done: usize,
    tty: bool,
    started: Instant,
    last_line: Option<Instant>,
}

/// What the ETA knows of one run: its method (the first part of its id), its budget, and, from
/// its latest progress line, how far it got in how much wall time (`wall_s` is kept across
/// resumes, so a resumed run's rate is its whole history's).
#[derive(Clone, Debug, PartialEq)]
struct Seen<'a> {
    method: &'a str,
    total_env_steps: f64,
    /// (env steps, wall seconds) so far; `None` for a run not started.
    so_far: Option<(f64, f64)>,
}

/// Seconds of work left: each running run's rest at its own rate, and each run not started at
/// the mean seconds per env step of its method's runs seen so far (finished or running, in any
/// invocation), else of every run seen; spread over the `jobs` slots. `None` when no run has a
/// rate yet. Runs differ in budget (rounds × K against env steps) and in cost per env step by
/// method, so one mean run length would be wrong for both.
fn eta_seconds(running: &[Seen], seen: &[Seen], left: &[Seen], jobs: usize) -> Option<f64> {
    let rate = |s: &Seen| {
        s.so_far
            .filter(|&(n, w)| n > 0.0 && w > 0.0)
            .map(|(n, w)| w / n)
    };
    let mean = |rates: Vec<f64>| {
        (!rates.is_empty()).then(|| rates.iter().sum::<f64>() / rates.len() as f64)
    };
    let all = mean(running.iter().chain(seen).filter_map(rate).collect())?;
    let of_method = |m: &str| {
        mean(
            running
                .iter()
                .chain(seen)
                .filter(|s| s.method == m)
                .filter_map(rate)
                .collect(),
        )
        .unwrap_or(all)
    };
    let mut work = 0.0;
    for r in running {
        let n = r.so_far.map_or(0.0, |(n, _)| n);
        work += (r.total_env_steps - n).max(0.0) * rate(r).unwrap_or_else(|| of_method(r.method));
    }
    for l in left {
        work += l.total_env_steps * of_method(l.method);
    }
    Some(work / jobs.min(running.len() + left.len()).max(1) as f64)
}

/// The latest progress line of a run directory, if it has one.
fn last_progress(dir: &Path) -> Option<(f64, f64)> {
    let text = tail(&dir.join("logs").join("progress.jsonl"), 4096);
    let p = text
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())?;
    Some((p["env_steps"].as_f64()?, p["wall_s"].as_f64()?))
}

impl Progress {
    fn new(total: usize, jobs: usize, skipped: usize) -> Self {
        Self {
            total,
            jobs,
            done: skipped,
            tty: std::io::stderr().is_terminal(),
            started: Instant::now(),
            last_line: None,
        }
    }

    fn finished(&mut self) {
        self.done += 1;
    }

    fn clear(&self) {
        if self.tty {
            eprint!("\r\x1b[K");
        }
    }

    fn show(
        &mut self,
        runs: &[Run],
        running: &HashMap<usize, Running>,
        left: &[usize],
        failed: usize,
    ) {
        if !self.tty
            && self
                .last_line
                .is_some_and(|t| t.elapsed() < Duration::from_secs(10))
        {
            return;
        }
        // Each run's latest progress, read once per line: running, finished or stopped.
        let progress: Vec<Option<(f64, f64)>> =
            runs.iter().map(|r| last_progress(&r.dir)).collect();
        let seen = |i: usize| Seen {
            method: runs[i].id.split('/').next().unwrap_or(""),
            total_env_steps: runs[i].config.run.total_env_steps as f64,
            so_far: progress[i],
        };
        let now: Vec<Seen> = running.keys().map(|&i| seen(i)).collect();
        // Every other run with a progress line: finished ones, and stopped ones left to resume.
        let others: Vec<Seen> = (0..runs.len())
            .filter(|i| !running.contains_key(i) && progress[*i].is_some())
            .map(seen)
            .collect();
        let todo: Vec<Seen> = left
            .iter()
            .map(|&i| {
                let mut s = seen(i);
                // A stopped run left to resume has only its rest to do.
                if let Some((n, _)) = s.so_far.take() {
                    s.total_env_steps = (s.total_env_steps - n).max(0.0);
                }
                s
            })
            .collect();
        let left = left.len();
        let eta = eta_seconds(&now, &others, &todo, self.jobs).map_or("–".to_string(), duration);
        let line = format!(
            "[{}] runs: {}/{} done, {} running, {left} left, {failed} failed | ETA {eta}",
            duration(self.started.elapsed().as_secs_f64()),
            self.done,
            self.total,
            running.len(),
        );
        if self.tty {
            eprint!("\r\x1b[K{line}");
        } else {
            eprintln!("{line}");
        }
        self.last_line = Some(Instant::now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(method: &str, total: f64, so_far: Option<(f64, f64)>) -> Seen<'_> {
        Seen {
            method,
            total_env_steps: total,
            so_far,
        }
    }

    #[test]
    fn the_eta_prices_each_run_by_its_budget_and_its_methods_rate() {
        // Running: 250k of 500k env steps in 5 000 s (0.02 s a step), 5 000 s left. Seen: SAC
        // finished 100k in 1 000 s (0.01). Left: SAC 100k at 0.01 = 1 000 s; REDQ, never
        // seen, at the mean of the two rates (0.015) = 1 500 s; rounds 500k at 0.02 = 10 000 s.
        let running = [seen("rounds", 500e3, Some((250e3, 5000.0)))];
        let finished = [seen("sac", 100e3, Some((100e3, 1000.0)))];
        let left = [
            seen("sac", 100e3, None),
            seen("redq", 100e3, None),
            seen("rounds", 500e3, None),
        ];
        let work = 5000.0 + 1000.0 + 1500.0 + 10_000.0;
        let eta = |jobs| eta_seconds(&running, &finished, &left, jobs).unwrap();
        assert!((eta(1) - work).abs() < 1e-6, "{}", eta(1));
        assert!((eta(2) - work / 2.0).abs() < 1e-6, "{}", eta(2));
        // More slots than runs: the four runs' work over four.
        assert!((eta(8) - work / 4.0).abs() < 1e-6, "{}", eta(8));
        // Nothing has a rate yet: no ETA rather than a guess.
        assert_eq!(
            eta_seconds(&[seen("rounds", 500e3, None)], &[], &left, 1),
            None
        );
    }
}
