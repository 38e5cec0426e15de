//! `selkd experiment`: a grid of (method, task, seed) runs described by one TOML file.
//!
//! - [`spec`]: the experiment file, its checks, and each run's resolved config (every mistake
//!   is found before the first run starts).
//! - [`state`]: whether a run directory is finished, resumable or fresh (from its checkpoints).
//! - [`runner`]: `selkd experiment run`, J child `selkd train` processes at a time, one progress
//!   line, safe to run again, stopped with a checkpoint on Ctrl-C or SIGTERM.
//! - [`plan`]: `selkd experiment plan`, the same runs as shell commands and a Slurm job array.
//! - [`publish`]: `selkd experiment publish`, finished runs' small outputs as data for the
//!   repository (`docs/results/<experiment>/`), from which the report regenerates.
//!
//! The run directories are `DIR/<method>/<task>/seed-<s>/`, ordinary `selkd train` outputs, and
//! `DIR/experiment.toml` is the experiment as run (config paths made absolute), which
//! `selkd experiment report` reads.

pub mod plan;
pub mod publish;
pub mod runner;
pub mod spec;
pub mod state;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Subcommand, Debug)]
pub enum ExperimentCommand {
    /// Run every (method, task, seed) of an experiment file, J at a time; safe to run again.
    Run(RunArgs),
    /// Write the runs as shell commands (DIR/commands.txt) and, with --slurm, a job array.
    Plan(PlanArgs),
    /// Tables and figures from an experiment's runs (or from their published copy).
    Report(crate::report::ReportArgs),
    /// Copy each finished run's small outputs (config, metrics, state.json without weights,
    /// fresh evaluation, progress) to DEST, e.g. docs/results/<experiment>/, for the report.
    Publish(publish::PublishArgs),
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The experiment file (TOML; see experiments/ and the README's "Experiments").
    pub experiment: PathBuf,
    /// Where the runs go (default: experiments/runs/<experiment file name without .toml>).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Runs at a time (default: the number of cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Only this run, named <method>/<task>/seed-<s> (repeatable; the runs start in the order
    /// named).
    #[arg(long, value_name = "METHOD/TASK/seed-S")]
    pub only: Vec<String>,
    /// A published copy of this experiment (`selkd experiment publish`'s DEST, e.g.
    /// docs/results/<experiment>): its runs not yet started here count as finished, so a new
    /// machine runs only what is missing.
    #[arg(long, value_name = "DEST")]
    pub published: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct PlanArgs {
    /// The experiment file.
    pub experiment: PathBuf,
    /// Where the runs go (default: experiments/runs/<experiment file name without .toml>).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Also write DIR/slurm.sbatch, a job array with one task per line of commands.txt.
    #[arg(long)]
    pub slurm: bool,
    /// Slurm partition (#SBATCH --partition).
    #[arg(long, requires = "slurm")]
    pub partition: Option<String>,
    /// Slurm time limit per run (#SBATCH --time): a Slurm time such as 12:00:00 or 1-06:00:00;
    /// `auto` (the default) measures each run's learner here and allows 1.5× its critic
    /// updates' time plus 10 minutes; `none` leaves it to the cluster's default. A run that
    /// reaches it stops with a checkpoint and is requeued, so a short limit costs restarts, not
    /// work.
    #[arg(long, requires = "slurm", default_value = "auto")]
    pub time: String,
    /// CPU cores per run (#SBATCH --cpus-per-task); default: the runs' `run.threads` (the
    /// learner's threads; the workers wait on it in sync mode).
    #[arg(long, requires = "slurm")]
    pub cpus: Option<usize>,
    /// GPUs per run (#SBATCH --gres=gpu:G); set run.device = "cuda" in the experiment to use them.
    #[arg(long, requires = "slurm")]
    pub gpus: Option<usize>,
}

pub fn run(cmd: ExperimentCommand) -> Result<i32> {
    match cmd {
        ExperimentCommand::Run(args) => runner::run(args),
        ExperimentCommand::Plan(args) => plan::run(args).map(|()| 0),
        ExperimentCommand::Publish(args) => publish::run(&args).map(|()| 0),
        ExperimentCommand::Report(args) => crate::report::run(&args).map(|p| {
            let _ = writeln!(std::io::stderr(), "selkd: wrote {}", p.display());
            0
        }),
    }
}

/// `--dir`, or `experiments/runs/<file stem>`.
pub fn experiment_dir(experiment: &Path, dir: Option<&Path>) -> PathBuf {
    dir.map(Path::to_path_buf).unwrap_or_else(|| {
        let stem = experiment
            .file_stem()
            .map_or("experiment".into(), |s| s.to_string_lossy().into_owned());
        Path::new("experiments").join("runs").join(stem)
    })
}

/// `DIR/experiment.toml`, the experiment as run. Written through a temporary file and a rename,
/// because Slurm array tasks write it at once and a reader must never see half of one.
pub fn write_experiment(exp: &spec::Experiment, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let tmp = dir.join(format!(".experiment.toml.{}", std::process::id()));
    let text = format!(
        "# Written by `selkd experiment`: the experiment as run (config paths absolute).\n{}",
        exp.to_toml()
    );
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, dir.join("experiment.toml"))
        .with_context(|| format!("writing {}", dir.join("experiment.toml").display()))
}
