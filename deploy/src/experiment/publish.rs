//! `selkd experiment publish DIR DEST`: each finished run's small outputs, copied into the
//! repository as data, so that a reader re-draws and re-tests every published figure from a
//! clone (`selkd experiment report DEST`, which needs no checkpoint), and a finished run is never
//! lost with the machine it ran on.
//!
//! `DEST/experiment.toml` (the experiment as run: its `[[figure]]`s) and, per finished run,
//! `DEST/<method>/<task>/seed-<s>/`:
//! - `config.toml`, the resolved config;
//! - `metrics.csv`, one row per epoch;
//! - `state.json`, the final checkpoint's counters, ranking and config (the weights, Adam moments
//!   and replay buffer stay behind: they are megabytes to gigabytes, and nothing the report reads);
//! - `fresh_eval.json`, Table 2's fresh evaluation of the ranked actor, made here first when the
//!   run has none for `--episodes` (after this, E is fixed for the published copy);
//! - `progress.json`, the last line of `logs/progress.jsonl` (rates, lag, drops, wall time at the
//!   end), when the run has one.
//!
//! Runs that stopped short of their budget are not published (a table of them would be read as
//! final); they are named, so that the published table can say it is partial.

use crate::report::fresh::fresh_evals;
use crate::report::runs::{discover, Run};
use anyhow::{bail, Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct PublishArgs {
    /// The experiment directory (`selkd experiment run`'s, with checkpoints).
    pub dir: PathBuf,
    /// Where the data goes, e.g. docs/results/<experiment>/.
    pub dest: PathBuf,
    /// Fresh evaluation episodes per run for Table 2 (as `selkd experiment report --episodes`),
    /// evaluated here for runs that have none yet.
    #[arg(long, default_value_t = 20)]
    pub episodes: usize,
}

/// The files of one published run, relative to its directories: (from, to).
const FILES: [(&str, &str); 4] = [
    ("config.toml", "config.toml"),
    ("metrics.csv", "metrics.csv"),
    ("checkpoints/final/state.json", "state.json"),
    ("fresh_eval.json", "fresh_eval.json"),
];

/// Copies every finished run of `dir` into `dest`; returns (published, not finished) run ids.
pub fn publish(args: &PublishArgs) -> Result<(Vec<String>, Vec<String>)> {
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let (src, dest) = (&args.dir, &args.dest);
    if !src.join("experiment.toml").exists() && !src.is_dir() {
        bail!("{} is not an experiment directory", src.display());
    }
    let all = discover(src)?;
    let (finished, short): (Vec<_>, Vec<_>) = all.iter().partition(|(_, _, r)| r.finished());
    if finished.is_empty() {
        bail!(
            "no finished run under {} ({} runs; a run is finished when checkpoints/final/state.json reached its budget)",
            src.display(),
            all.len()
        );
    }
    let id = |m: &str, t: &str, r: &Run| format!("{m}/{t}/seed-{}", r.seed);
    // Evaluate first (the slow part, on every core), so that nothing is copied half.
    let runs: Vec<&Run> = finished.iter().map(|(_, _, r)| r).collect();
    fresh_evals(&runs, args.episodes).context("the fresh evaluation for Table 2")?;
    std::fs::create_dir_all(dest).with_context(|| format!("creating {}", dest.display()))?;
    let exp = src.join("experiment.toml");
    if exp.exists() {
        copy(&exp, &dest.join("experiment.toml"))?;
    }
    let mut done = Vec::new();
    for (m, t, r) in &finished {
        let to = dest.join(m).join(t).join(format!("seed-{}", r.seed));
        std::fs::create_dir_all(&to).with_context(|| format!("creating {}", to.display()))?;
        for (from, name) in FILES {
            copy(&r.dir.join(from), &to.join(name))?;
        }
        let last = last_progress(&r.dir.join("logs/progress.jsonl"))?;
        if let Some(line) = last {
            write(&to.join("progress.json"), &format!("{line}\n"))?;
        }
        done.push(id(m, t, r));
    }
    let short = short.iter().map(|(m, t, r)| id(m, t, r)).collect();
    Ok((done, short))
}

fn copy(from: &Path, to: &Path) -> Result<()> {
    let text = std::fs::read(from).with_context(|| format!("reading {}", from.display()))?;
    write(to, &String::from_utf8_lossy(&text))
}

/// Through a temporary file and a rename: a published file is whole or absent.
fn write(to: &Path, text: &str) -> Result<()> {
    selkd_learner::checkpoint::write_atomically(to, text)
        .with_context(|| format!("writing {}", to.display()))
}

/// The last complete JSON line of progress.jsonl (a line cut short by a kill is skipped).
fn last_progress(path: &Path) -> Result<Option<String>> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(None);
    };
    Ok(text
        .lines()
        .rev()
        .find(|l| serde_json::from_str::<serde_json::Value>(l).is_ok())
        .map(str::to_string))
}

pub fn run(args: &PublishArgs) -> Result<()> {
    let (done, short) = publish(args)?;
    eprintln!(
        "selkd: published {} finished run(s) to {}",
        done.len(),
        args.dest.display()
    );
    if !short.is_empty() {
        eprintln!(
            "selkd: not finished, not published (the published tables are partial until they are): {}",
            short.join(", ")
        );
    }
    Ok(())
}
