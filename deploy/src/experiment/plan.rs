//! `selkd experiment plan`: the experiment's runs as shell commands, for a cluster.
//!
//! Each line of `DIR/commands.txt` is `selkd experiment run EXP --dir DIR --only <run>`, so a
//! cluster task runs one run through the same runner as this host does: skipping it when
//! finished, resuming it from its checkpoint, stopping it with one on SIGTERM. `--slurm` adds
//! `DIR/slurm.sbatch`, a job array whose task i runs line i + 1, with what a cluster needs: CPUs
//! from the runs' threads, a time limit from the learner's measured rate, and a warning signal
//! before that limit on which the task stops its run with a checkpoint and requeues itself, so a
//! run longer than any limit the cluster allows still finishes, resuming each time.

use super::{spec, PlanArgs};
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

pub fn run(args: PlanArgs) -> Result<()> {
    let dir = super::experiment_dir(&args.experiment, args.dir.as_deref());
    // The same gate as `run`: a plan that would fail on the cluster fails here.
    let (exp, runs) = spec::prepare(&args.experiment, &dir, 1, 1, &[])?;
    super::write_experiment(&exp, &dir)?;
    let dir = absolute(&dir)?;
    let selkd = std::env::current_exe().context("locating selkd")?;
    let experiment = absolute(&args.experiment)?;
    let lines: Vec<String> = runs
        .iter()
        .map(|r| {
            [
                quote(&selkd.to_string_lossy()),
                "experiment run".into(),
                quote(&experiment.to_string_lossy()),
                "--dir".into(),
                quote(&dir.to_string_lossy()),
                "--only".into(),
                quote(&r.id),
            ]
            .join(" ")
        })
        .collect();
    let commands = dir.join("commands.txt");
    std::fs::write(&commands, lines.join("\n") + "\n")
        .with_context(|| format!("writing {}", commands.display()))?;
    eprintln!("selkd: wrote {} ({} runs)", commands.display(), lines.len());
    if args.slurm {
        let limits = Limits {
            partition: args.partition.clone(),
            time: time_limit(&args.time, &runs)?,
            cpus: match args.cpus {
                Some(c) => c,
                None => runs
                    .iter()
                    .map(|r| r.config.run.threads)
                    .max()
                    .unwrap_or(1)
                    .max(1),
            },
            gpus: args.gpus,
        };
        let script = dir.join("slurm.sbatch");
        std::fs::write(
            &script,
            sbatch(&limits, &exp_name(&args.experiment), &dir, lines.len()),
        )
        .with_context(|| format!("writing {}", script.display()))?;
        eprintln!(
            "selkd: wrote {}; submit it with `sbatch {}`",
            script.display(),
            script.display()
        );
    }
    Ok(())
}

fn exp_name(experiment: &Path) -> String {
    experiment
        .file_stem()
        .map_or("experiment".into(), |s| s.to_string_lossy().into_owned())
}

/// Seconds before the time limit at which Slurm warns a task (SIGUSR1 to the batch shell):
/// time for the run to write its checkpoint and for the task to requeue itself.
const WARN_SECONDS: u32 = 300;

/// What each array task asks the cluster for.
struct Limits {
    partition: Option<String>,
    /// A Slurm time, or `None` for the cluster's default.
    time: Option<String>,
    cpus: usize,
    gpus: Option<usize>,
}

/// `--time`: checked when given, measured when `auto`.
fn time_limit(arg: &str, runs: &[spec::Run]) -> Result<Option<String>> {
    match arg {
        "none" => Ok(None),
        "auto" => measured_time(runs).map(Some),
        t if is_slurm_time(t) => Ok(Some(t.to_string())),
        t => anyhow::bail!(
            "--time {t}: write a Slurm time (MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM or D-HH:MM:SS), auto or none"
        ),
    }
}

/// Slurm's time formats: minutes, minutes:seconds, hours:minutes:seconds, days-hours,
/// days-hours:minutes and days-hours:minutes:seconds.
fn is_slurm_time(t: &str) -> bool {
    let num = |p: &str| !p.is_empty() && p.len() <= 4 && p.chars().all(|c| c.is_ascii_digit());
    let (days, rest) = match t.split_once('-') {
        Some((d, r)) => (Some(d), r),
        None => (None, t),
    };
    let parts: Vec<&str> = rest.split(':').collect();
    days.is_none_or(num) && parts.iter().all(|p| num(p)) && (1..=3).contains(&parts.len())
}

/// The longest run's limit: its critic updates at the learner's rate measured here (a few
/// rounds of each distinct method and task), ×1.5 for env steps, evaluation and checkpoints, plus
/// 10 minutes for start-up and the warning, in whole minutes as D-HH:MM:SS.
fn measured_time(runs: &[spec::Run]) -> Result<String> {
    let mut seconds = 0.0f64;
    let mut measured: Vec<(String, f64)> = Vec::new();
    for r in runs {
        let c = &r.config;
        if c.run.device != "cpu" {
            anyhow::bail!(
                "--time auto measures the learner on this machine's CPU, but run {} uses run.device = {}; pass --time",
                r.id,
                c.run.device
            );
        }
        let spec = c.env_spec()?;
        let key = format!("{:?} {} {}", c.algo, spec.obs_dim, spec.act_dim);
        let rate = match measured.iter().find(|(k, _)| *k == key) {
            Some((_, rate)) => *rate,
            None => {
                selkd_learner::threads::set(c.run.threads);
                selkd_learner::matmul::set(c.run.cpu_gemm);
                let rate = selkd_learner::bench::learner(
                    &c.algo,
                    spec.obs_dim,
                    spec.act_dim,
                    tch::Device::Cpu,
                    5,
                )
                .critic_updates_per_sec;
                eprintln!(
                    "selkd: {}: {rate:.0} critic updates/s here, {} updates",
                    r.id,
                    c.critic_updates_in_budget()
                );
                measured.push((key, rate));
                rate
            }
        };
        seconds = seconds.max(c.critic_updates_in_budget() as f64 / rate);
    }
    let minutes = ((seconds * 1.5 + 600.0) / 60.0).ceil() as u64;
    Ok(format!(
        "{}-{:02}:{:02}:00",
        minutes / (24 * 60),
        minutes / 60 % 24,
        minutes % 60
    ))
}

/// A job array over commands.txt. The task runs its command in the background and waits, so
/// that its shell can act on Slurm's signals: SIGUSR1, the warning before the time limit, stops
/// the run (SIGTERM: it writes a checkpoint) and requeues the task, which resumes the run;
/// SIGTERM (scancel, preemption, `scontrol requeue`) only stops it, with a checkpoint.
fn sbatch(limits: &Limits, name: &str, dir: &Path, runs: usize) -> String {
    let mut s = String::from("#!/bin/bash\n");
    s += &format!("#SBATCH --job-name=selkd-{name}\n");
    s += &format!("#SBATCH --array=0-{}\n", runs - 1);
    if let Some(p) = &limits.partition {
        s += &format!("#SBATCH --partition={p}\n");
    }
    if let Some(t) = &limits.time {
        s += &format!("#SBATCH --time={t}\n");
    }
    s += &format!("#SBATCH --cpus-per-task={}\n", limits.cpus);
    if let Some(g) = limits.gpus {
        s += &format!("#SBATCH --gres=gpu:{g}\n");
    }
    s += "#SBATCH --requeue\n";
    if limits.time.is_some() {
        s += &format!("#SBATCH --signal=B:USR1@{WARN_SECONDS}\n");
    }
    // Appended: a requeued task's output follows its earlier attempts'.
    s += "#SBATCH --open-mode=append\n";
    s += &format!("#SBATCH --output={}/slurm-%A_%a.out\n", dir.display());
    s += "set -uo pipefail\n";
    s += &format!(
        "line=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" {})\n",
        quote(&dir.join("commands.txt").to_string_lossy())
    );
    s += r#"echo "selkd: array task $SLURM_ARRAY_TASK_ID (restart ${SLURM_RESTART_COUNT:-0}): $line"
bash -c "exec $line" &
run=$!
requeue=0
trap 'kill -TERM "$run" 2>/dev/null' TERM
trap 'requeue=1; kill -TERM "$run" 2>/dev/null' USR1
# `wait` returns early when a trapped signal arrives; wait again until the run has exited.
while :; do
    wait "$run"
    status=$?
    kill -0 "$run" 2>/dev/null || break
done
if [ "$requeue" = 1 ]; then
    echo "selkd: the time limit is near; the run stopped with a checkpoint; requeueing this task"
    scontrol requeue "${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}"
fi
exit "$status"
"#;
    s
}

fn absolute(p: &Path) -> Result<PathBuf> {
    if p.is_absolute() {
        return Ok(p.to_path_buf());
    }
    Ok(std::env::current_dir()?.join(p))
}

/// One shell word: single-quoted unless it is plainly safe.
fn quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:+@".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slurm_times_are_checked_as_slurm_reads_them() {
        for ok in ["30", "30:00", "12:00:00", "1-06", "1-06:30", "2-00:00:00"] {
            assert!(is_slurm_time(ok), "{ok}");
        }
        for bad in ["", "1h", "12:00:00:00", "-5", "1-", "a:b", "1--2", "12:"] {
            assert!(!is_slurm_time(bad), "{bad}");
        }
    }

    #[test]
    fn words_with_spaces_or_quotes_are_quoted_for_the_shell() {
        assert_eq!(quote("a/b/seed-1"), "a/b/seed-1");
        assert_eq!(quote("my runs"), "'my runs'");
        assert_eq!(quote("it's"), r"'it'\''s'");
    }
}
