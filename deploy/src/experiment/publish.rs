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

/// `selkd experiment run --published DEST`: puts back each run named in `ids` that DEST holds
/// (published, hence finished) and `dir` has never started, as a finished run: its config,
/// metrics, final checkpoint's state.json, fresh evaluation and progress. On a new machine (or
/// a fresh clone) the experiment then runs only what is missing instead of redoing days of
/// runs; a restored run has no weights, which nothing after training needs (its Table 2
/// evaluation is published). The runner then checks each restored config against the
/// experiment's, so a copy published under other settings is refused, not counted. Returns the
/// restored run ids.
pub fn restore(published: &Path, dir: &Path, ids: &[String]) -> Result<Vec<String>> {
    if !published.is_dir() {
        bail!(
            "--published {}: no such directory (it is `selkd experiment publish`'s DEST, e.g. docs/results/<experiment>)",
            published.display()
        );
    }
    let mut restored = Vec::new();
    for id in ids {
        let (from, to) = (published.join(id), dir.join(id));
        if !from.join("state.json").exists() || to.join("config.toml").exists() {
            continue; // not published, or started here: this machine's run wins
        }
        let progress = [("logs/progress.jsonl", "progress.json")];
        for (local, name) in FILES.iter().chain(&progress) {
            let src = from.join(name);
            if src.exists() {
                let dst = to.join(local);
                std::fs::create_dir_all(dst.parent().expect("a run file has a folder"))
                    .with_context(|| format!("creating {}", to.display()))?;
                copy(&src, &dst)?;
            }
        }
        restored.push(id.clone());
    }
    Ok(restored)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::state::{state, State};

    #[test]
    fn restore_puts_back_published_runs_as_finished_and_leaves_local_ones() {
        let tmp = std::env::temp_dir().join(format!("selkd-restore-{}", std::process::id()));
        let (published, dir) = (tmp.join("published"), tmp.join("runs"));
        let run = |root: &Path, id: &str, files: &[(&str, &str)]| {
            for (name, text) in files {
                let p = root.join(id).join(name);
                std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                std::fs::write(p, text).unwrap();
            }
        };
        let state_json = "{\"inserted\": 1000}";
        let published_files = [
            ("config.toml", "published config"),
            ("metrics.csv", "env_steps\n1000\n"),
            ("state.json", state_json),
            ("fresh_eval.json", "{}"),
            ("progress.json", "{\"env_steps\": 1000}\n"),
        ];
        for id in [
            "sac/pendulum/seed-1",
            "sac/pendulum/seed-2",
            "redq/pendulum/seed-1",
        ] {
            run(&published, id, &published_files);
        }
        // seed 2 was started here: it stays as it is.
        run(
            &dir,
            "sac/pendulum/seed-2",
            &[("config.toml", "local config")],
        );
        let ids: Vec<String> = [
            "sac/pendulum/seed-1",
            "sac/pendulum/seed-2",
            "sac/pendulum/seed-3",
        ]
        .map(String::from)
        .to_vec();

        let restored = restore(&published, &dir, &ids).unwrap();
        assert_eq!(restored, ["sac/pendulum/seed-1"]);
        let one = dir.join("sac/pendulum/seed-1");
        assert!(matches!(state(&one, 1000), State::Finished));
        let read = |p: &str| std::fs::read_to_string(one.join(p)).unwrap();
        assert_eq!(read("config.toml"), "published config");
        assert_eq!(read("metrics.csv"), "env_steps\n1000\n");
        assert_eq!(read("checkpoints/final/state.json"), state_json);
        assert_eq!(read("fresh_eval.json"), "{}");
        assert_eq!(read("logs/progress.jsonl"), "{\"env_steps\": 1000}\n");
        let two = std::fs::read_to_string(dir.join("sac/pendulum/seed-2/config.toml")).unwrap();
        assert_eq!(two, "local config");
        assert!(
            !dir.join("redq").exists(),
            "a run the experiment does not name is not restored"
        );
        assert!(!dir.join("sac/pendulum/seed-3").exists());
        let err = restore(&tmp.join("nowhere"), &dir, &ids)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--published") && err.contains("no such directory"),
            "{err}"
        );
        std::fs::remove_dir_all(&tmp).unwrap();
    }
}
