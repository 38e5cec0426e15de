//! `selkd experiment plan`: the experiment's runs as shell commands, for a cluster.
//!
//! Each line of `DIR/commands.txt` is `selkd experiment run EXP --dir DIR --only <run>`, so a
//! cluster task runs one run through the same runner as this host does: skipping it when
//! finished, resuming it from its checkpoint, stopping it with one on SIGTERM (Slurm sends
//! SIGTERM at the time limit). `--slurm` adds `DIR/slurm.sbatch`, a job array whose task i runs
//! line i + 1.

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
        let script = dir.join("slurm.sbatch");
        std::fs::write(
            &script,
            sbatch(&args, &exp_name(&args.experiment), &dir, lines.len()),
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

/// A job array over commands.txt; only the directives asked for are written, so the cluster's
/// defaults apply to the rest.
fn sbatch(args: &PlanArgs, name: &str, dir: &Path, runs: usize) -> String {
    let mut s = String::from("#!/bin/bash\n");
    s += &format!("#SBATCH --job-name=selkd-{name}\n");
    s += &format!("#SBATCH --array=0-{}\n", runs - 1);
    if let Some(p) = &args.partition {
        s += &format!("#SBATCH --partition={p}\n");
    }
    if let Some(t) = &args.time {
        s += &format!("#SBATCH --time={t}\n");
    }
    if let Some(c) = args.cpus {
        s += &format!("#SBATCH --cpus-per-task={c}\n");
    }
    if let Some(g) = args.gpus {
        s += &format!("#SBATCH --gres=gpu:{g}\n");
    }
    s += &format!("#SBATCH --output={}/slurm-%A_%a.out\n", dir.display());
    // Slurm's SIGTERM at the time limit goes to the job step; `exec` makes selkd that process,
    // so the run stops with a checkpoint and resubmitting the array resumes it.
    s += "set -euo pipefail\n";
    s += &format!(
        "line=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" {})\n",
        quote(&dir.join("commands.txt").to_string_lossy())
    );
    s += "exec bash -c \"exec $line\"\n";
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
    fn words_with_spaces_or_quotes_are_quoted_for_the_shell() {
        assert_eq!(quote("a/b/seed-1"), "a/b/seed-1");
        assert_eq!(quote("my runs"), "'my runs'");
        assert_eq!(quote("it's"), r"'it'\''s'");
    }
}
