//! End to end: `selkd experiment run` over real `selkd train` children (stopped by a signal half
//! way and run again: finished runs are skipped, the stopped one resumes to its budget; SIGTERM
//! stops with a checkpoint and exits 143; a failed run is reported and the others go on; a locked
//! run is left alone; one that cannot start fails alone; selkd replaced by a rebuild mid-experiment
//! stops nothing), its one-line errors for bad experiment files, and `selkd experiment
//! plan`'s commands and job array, whose commands are run here through bash.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// An experiment directory with `tiny.toml` and `exp.toml` (the given experiment text).
fn setup(tag: &str, experiment: &str) -> (PathBuf, PathBuf) {
    let root = temp_dir(tag);
    std::fs::write(root.join("tiny.toml"), TINY).unwrap();
    let exp = root.join("exp.toml");
    std::fs::write(&exp, experiment).unwrap();
    (root, exp)
}

fn experiment(args: &[&str]) -> Command {
    let mut c = Command::new(bin("selkd"));
    c.arg("experiment").args(args);
    c
}

/// `inserted` of a run's final checkpoint.
fn final_inserted(run: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(run.join("checkpoints/final/state.json")).ok()?;
    serde_json::from_str::<serde_json::Value>(&text).ok()?["inserted"].as_u64()
}

/// An experiment of one method, `a` (tiny.toml), on pendulum, seeds 1 and 2, `budget` env steps.
fn two_seeds_of_a(budget: u64) -> String {
    format!(
        "{}[[method]]\nname = \"a\"\nconfig = \"tiny.toml\"\n",
        ONE.replace("seeds = [1]", "seeds = [1, 2]").replace(
            "total_env_steps = 1000",
            &format!("total_env_steps = {budget}")
        )
    )
}

/// Runs the experiment one run at a time, expects exit status 1 (a run failed), returns stderr.
fn run_failing_one_at_a_time(exp: &Path, dir: &Path) -> String {
    let out = run({
        let mut c = experiment(&["run"]);
        c.arg(exp).arg("--dir").arg(dir).args(["--jobs", "1"]);
        c
    });
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    stderr
}

/// Waits (up to a minute) until a run of the experiment `child` runs has logged progress.
fn wait_until_training(run_dir: &Path, child: &mut std::process::Child) {
    let t0 = Instant::now();
    while log(run_dir, "progress.jsonl").is_empty() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{} never started: {:?}",
            run_dir.display(),
            child.try_wait()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

const TWO_BY_TWO: &str = r#"
total_env_steps = 3000
seeds = [1, 2]
tasks = ["pendulum"]

[[method]]
name = "a"
config = "tiny.toml"

[[method]]
name = "b"
config = "tiny.toml"
set = { "algo.critics" = 3, "algo.subset" = 2 }
"#;

#[test]
fn a_stopped_experiment_run_again_skips_finished_runs_and_resumes_the_stopped_one() {
    let (root, exp) = setup("exp-smoke", TWO_BY_TWO);
    let dir = root.join("runs");
    let ids = [
        "a/pendulum/seed-1",
        "b/pendulum/seed-1",
        "a/pendulum/seed-2",
        "b/pendulum/seed-2",
    ];
    let mut child = spawn({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(&dir).args(["--jobs", "2"]);
        c
    });
    // Stop once one run has finished and another has a checkpoint but not its budget.
    let t0 = Instant::now();
    let finished_before = loop {
        let finished: Vec<&str> = ids
            .iter()
            .copied()
            .filter(|id| final_inserted(&dir.join(id)).is_some_and(|n| n >= 3000))
            .collect();
        let midway = ids
            .iter()
            .any(|id| !finished.contains(id) && dir.join(id).join("checkpoints/latest").exists());
        if !finished.is_empty() && midway {
            break finished;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "no run finished with another half-way; exited: {:?}",
            child.try_wait()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let metrics_before: Vec<String> = finished_before
        .iter()
        .map(|id| std::fs::read_to_string(dir.join(id).join("metrics.csv")).unwrap())
        .collect();
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{stderr}");
    assert!(stderr.contains("selkd: stopping"), "{stderr}");
    // Every run that had started holds a checkpoint now.
    let unfinished: Vec<&str> = ids
        .iter()
        .copied()
        .filter(|id| final_inserted(&dir.join(id)).is_none_or(|n| n < 3000))
        .collect();
    assert!(!unfinished.is_empty(), "{stderr}");
    for id in &unfinished {
        let d = dir.join(id);
        if d.exists() {
            assert!(
                d.join("checkpoints/latest").exists(),
                "{id} stopped without a checkpoint:\n{}",
                std::fs::read_to_string(d.join("logs/selkd.log")).unwrap_or_default()
            );
        }
    }

    let out = run({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(&dir).args(["--jobs", "2"]);
        c
    });
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let now_finished = ids.len() - unfinished.len();
    assert!(
        stderr.contains(&format!("{now_finished} finished (skipped)")),
        "{stderr}"
    );
    for (id, before) in finished_before.iter().zip(&metrics_before) {
        let after = std::fs::read_to_string(dir.join(id).join("metrics.csv")).unwrap();
        assert_eq!(&after, before, "{id}: a finished run was trained again");
    }
    for id in ids {
        let d = dir.join(id);
        assert!(
            final_inserted(&d).is_some_and(|n| n >= 3000),
            "{id} did not reach its budget: {:?}\n{}",
            final_inserted(&d),
            std::fs::read_to_string(d.join("logs/selkd.log")).unwrap_or_default()
        );
        // The child's own output went to its log, not the terminal.
        assert!(log(&d, "selkd.log").contains("selkd: run"), "{id}");
    }
    // A stopped run resumed: its log holds a stop, then the resume.
    let resumed = unfinished
        .iter()
        .filter(|id| dir.join(id).join("checkpoints").exists())
        .filter(|id| log(&dir.join(id), "learner.log").contains("resumed from"))
        .count();
    assert!(resumed >= 1, "no stopped run was resumed: {stderr}");
    let written = std::fs::read_to_string(dir.join("experiment.toml")).unwrap();
    assert!(written.contains("total_env_steps = 3000"), "{written}");
    // Then reported: Table 2 and a curve point, recomputed here from the runs.
    let out = run({
        let mut c = experiment(&["report"]);
        c.arg(&dir).args(["--episodes", "2"]);
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    common::report_check::check_report(&dir, "pendulum", &["a", "b"], &[1, 2], 2, 1500.0);
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(!md.contains("Partial"), "every run finished: {md}");
    let _ = std::fs::remove_dir_all(&root);
}

/// Runs `selkd experiment run` on an experiment text; returns (exit code, stderr).
fn rejected(tag: &str, text: &str) -> (Option<i32>, String, PathBuf) {
    let (root, exp) = setup(tag, text);
    let out = run({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(root.join("runs"));
        c
    });
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        root,
    )
}

const ONE: &str = r#"
total_env_steps = 1000
seeds = [1]
tasks = ["pendulum"]
"#;

#[test]
fn bad_experiment_files_get_one_line_errors_before_any_run_starts() {
    let method = "[[method]]\nname = \"a\"\nconfig = \"tiny.toml\"\n";
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "unknown-config",
            format!("{ONE}[[method]]\nname = \"a\"\nconfig = \"nope.toml\"\n"),
            vec!["method `a`", "nope.toml", "does not exist"],
        ),
        (
            "unknown-task",
            format!("{}{method}", ONE.replace("\"pendulum\"", "\"walker\"")),
            vec!["`walker` is not a known env", "walker2d"],
        ),
        (
            "duplicate-method",
            format!("{ONE}{method}{method}"),
            vec!["two methods are named `a`"],
        ),
        (
            "no-seeds",
            format!("{}{method}", ONE.replace("seeds = [1]", "seeds = []")),
            vec!["no seeds"],
        ),
        ("no-methods", ONE.to_string(), vec!["no methods"]),
        (
            "no-tasks",
            format!(
                "{}{method}",
                ONE.replace("tasks = [\"pendulum\"]", "tasks = []")
            ),
            vec!["no tasks"],
        ),
        (
            "zero-budget",
            format!("{}{method}", ONE.replace("1000", "0")),
            vec!["total_env_steps must be at least 1"],
        ),
        (
            "bad-key",
            format!("{ONE}{method}set = {{ \"algo.critcs\" = 3 }}\n"),
            vec!["method `a` on task `pendulum`", "critcs"],
        ),
        (
            "bad-value",
            format!("{ONE}{method}set = {{ \"algo.subset\" = 9 }}\n"),
            vec!["method `a`", "algo.subset"],
        ),
        (
            "owned-key",
            format!("{ONE}[set]\n\"run.seed\" = 4\n{method}"),
            vec!["`run.seed` is set by the experiment's `seeds`"],
        ),
        (
            "unknown-field",
            format!("{ONE}budget = 5\n{method}"),
            vec!["unknown field `budget`"],
        ),
    ];
    for (tag, text, wants) in cases {
        let (code, stderr, root) = rejected(&format!("exp-bad-{tag}"), &text);
        assert_eq!(code, Some(2), "{tag}: {stderr}");
        assert_eq!(
            stderr.trim().lines().count(),
            1,
            "{tag}: one line: {stderr}"
        );
        assert!(stderr.starts_with("selkd: error: "), "{tag}: {stderr}");
        for w in wants {
            assert!(stderr.contains(w), "{tag}: wanted `{w}` in: {stderr}");
        }
        assert!(
            !root.join("runs").join("a").exists(),
            "{tag}: a run started"
        );
        let _ = std::fs::remove_dir_all(&root);
    }
    // Bad flags, on a good file.
    let (root, exp) = setup("exp-bad-flags", &format!("{ONE}{method}"));
    for (flags, want) in [
        (
            &["--only", "a/pendulum/seed-9"][..],
            "--only a/pendulum/seed-9: no such run",
        ),
        (&["--jobs", "0"][..], "--jobs 0"),
    ] {
        let out = run({
            let mut c = experiment(&["run"]);
            c.arg(&exp).arg("--dir").arg(root.join("runs")).args(flags);
            c
        });
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flags:?}: {stderr}");
        assert!(
            stderr.contains(want),
            "{flags:?}: wanted `{want}` in: {stderr}"
        );
        assert!(
            !root.join("runs").join("a").exists(),
            "{flags:?}: a run started"
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn an_existing_run_with_another_config_is_named_with_the_keys_that_differ() {
    let text = format!("{ONE}[[method]]\nname = \"a\"\nconfig = \"tiny.toml\"\n");
    let (root, exp) = setup("exp-differs", &text);
    let run_dir = root.join("runs/a/pendulum/seed-1");
    std::fs::create_dir_all(&run_dir).unwrap();
    std::fs::write(
        run_dir.join("config.toml"),
        TINY.replace("critics = 2", "critics = 3"),
    )
    .unwrap();
    let out = run({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(root.join("runs"));
        c
    });
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("run a/pendulum/seed-1 already exists")
            && stderr.contains("algo.critics (3 there, 2 now)"),
        "{stderr}"
    );
    // run.total_env_steps and run.threads may change (a raised budget, another --jobs).
    assert!(
        !stderr.contains("run.threads") && !stderr.contains("total_env_steps"),
        "{stderr}"
    );
    assert!(!run_dir.join("logs").exists(), "the run was started");
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_plan_writes_one_command_per_run_and_a_job_array_and_its_commands_finish_the_runs() {
    let text = r#"
total_env_steps = 1000
seeds = [1, 2]
tasks = ["pendulum"]

[[method]]
name = "a"
config = "tiny.toml"
"#;
    let (root, exp) = setup("exp-plan", text);
    let dir = root.join("runs");
    let out = run({
        let mut c = experiment(&["plan"]);
        c.arg(&exp).arg("--dir").arg(&dir).args([
            "--slurm",
            "--partition",
            "gpu",
            "--time",
            "02:00:00",
            "--cpus",
            "4",
            "--gpus",
            "1",
        ]);
        c
    });
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let commands = std::fs::read_to_string(dir.join("commands.txt")).unwrap();
    let lines: Vec<&str> = commands.lines().collect();
    assert_eq!(lines.len(), 2, "{commands}");
    for (line, id) in lines.iter().zip(["a/pendulum/seed-1", "a/pendulum/seed-2"]) {
        assert!(
            line.contains(" experiment run ") && line.ends_with(&format!("--only {id}")),
            "{line}"
        );
    }
    let sbatch = std::fs::read_to_string(dir.join("slurm.sbatch")).unwrap();
    for want in [
        "#SBATCH --array=0-1\n",
        "#SBATCH --partition=gpu\n",
        "#SBATCH --time=02:00:00\n",
        "#SBATCH --cpus-per-task=4\n",
        "#SBATCH --gres=gpu:1\n",
        "SLURM_ARRAY_TASK_ID + 1",
        "commands.txt",
    ] {
        assert!(sbatch.contains(want), "wanted {want:?} in:\n{sbatch}");
    }
    assert!(sbatch.starts_with("#!/bin/bash\n"), "{sbatch}");
    // What an array task does, line by line, here.
    for line in &lines {
        let out = run({
            let mut c = Command::new("bash");
            c.args(["-c", line]);
            c
        });
        assert!(
            out.status.success(),
            "{line}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    for seed in [1, 2] {
        let d = dir.join(format!("a/pendulum/seed-{seed}"));
        assert!(
            final_inserted(&d).is_some_and(|n| n >= 1000),
            "seed {seed}: {:?}\n{}",
            final_inserted(&d),
            log(&d, "selkd.log")
        );
    }
    // Run again (a resubmitted array): nothing left to do.
    let out = run({
        let mut c = Command::new("bash");
        c.args(["-c", lines[0]]);
        c
    });
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && stderr.contains("1 finished (skipped)"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_failed_run_is_reported_with_its_log_and_the_others_go_on() {
    let text = two_seeds_of_a(1000);
    let (root, exp) = setup("exp-failed", &text);
    let dir = root.join("runs");
    // A checkpoint that names itself but holds no model: resuming from it fails in the learner.
    let broken = dir.join("a/pendulum/seed-1/checkpoints");
    std::fs::create_dir_all(broken.join("step-5")).unwrap();
    std::fs::write(broken.join("step-5/state.json"), "{\"inserted\": 5}").unwrap();
    std::fs::write(broken.join("latest"), "step-5\n").unwrap();
    let stderr = run_failing_one_at_a_time(&exp, &dir);
    assert!(
        stderr.contains("selkd: run a/pendulum/seed-1 failed")
            && stderr.contains("a/pendulum/seed-1/logs/selkd.log")
            && stderr.contains("1 failed"),
        "{stderr}"
    );
    let other = dir.join("a/pendulum/seed-2");
    assert!(
        final_inserted(&other).is_some_and(|n| n >= 1000),
        "the other run did not go on: {stderr}\n{}",
        log(&other, "selkd.log")
    );
    // Its report says which run is missing, so its table reads as partial.
    let out = run({
        let mut c = experiment(&["report"]);
        c.arg(&dir).args(["--episodes", "1"]);
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(
        md.contains("**Partial: 1 of the experiment's 2 runs are finished.** Not yet in these tables and curves: `a/pendulum/seed-1`."),
        "{md}"
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// A run whose directory cannot be made (here a file stands where it should be) fails alone,
/// with its reason; the runs after it in the queue still train. (The runner used to stop with
/// that error, and every later run with it.)
#[test]
fn a_run_that_cannot_start_fails_alone_and_the_queue_goes_on() {
    let text = two_seeds_of_a(1000);
    let (root, exp) = setup("exp-cannot-start", &text);
    let dir = root.join("runs");
    std::fs::create_dir_all(dir.join("a/pendulum")).unwrap();
    std::fs::write(dir.join("a/pendulum/seed-1"), "not a directory").unwrap();
    let stderr = run_failing_one_at_a_time(&exp, &dir);
    assert!(
        stderr.contains("selkd: run a/pendulum/seed-1 failed to start: creating run directory")
            && stderr.contains("1 failed"),
        "{stderr}"
    );
    let other = dir.join("a/pendulum/seed-2");
    assert!(
        final_inserted(&other).is_some_and(|n| n >= 1000),
        "the queue stopped at the run that could not start: {stderr}"
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// A run another runner holds is left alone and waited for: once that runner finishes it (here:
/// a final checkpoint at the budget appears and the lock is released), this runner counts it as
/// finished and exits 0, as a Slurm array's second task should (it exited 1 before).
#[test]
fn a_run_locked_by_another_selkd_is_left_alone_and_its_finish_there_is_success() {
    use std::io::BufRead;
    use std::os::fd::AsRawFd;
    let text = format!("{ONE}[[method]]\nname = \"a\"\nconfig = \"tiny.toml\"\n");
    let (root, exp) = setup("exp-locked", &text);
    let run_dir = root.join("runs/a/pendulum/seed-1");
    std::fs::create_dir_all(&run_dir).unwrap();
    // What another `selkd experiment run` training this run holds.
    let lock = std::fs::File::create(run_dir.join(".selkd.lock")).unwrap();
    assert_eq!(unsafe { libc::flock(lock.as_raw_fd(), libc::LOCK_EX) }, 0);
    let mut child = spawn({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(root.join("runs"));
        c
    });
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    let mut line = String::new();
    while !seen.contains("is being trained by another selkd") {
        line.clear();
        assert!(stderr.read_line(&mut line).unwrap() > 0, "{seen}");
        seen.push_str(&line);
    }
    assert!(
        seen.contains("run a/pendulum/seed-1 is being trained by another selkd")
            && seen.contains("waiting for it"),
        "{seen}"
    );
    std::thread::sleep(Duration::from_secs(2));
    assert!(
        child.try_wait().unwrap().is_none(),
        "it did not wait: {seen}"
    );
    // The other runner finishes the run.
    let fin = run_dir.join("checkpoints/final");
    std::fs::create_dir_all(&fin).unwrap();
    std::fs::write(fin.join("state.json"), "{\"inserted\": 1000}").unwrap();
    std::fs::write(run_dir.join("checkpoints/latest"), "final\n").unwrap();
    drop(lock);
    let status = child.wait().unwrap();
    let mut rest = String::new();
    let _ = std::io::Read::read_to_string(&mut stderr, &mut rest);
    assert_eq!(status.code(), Some(0), "{seen}{rest}");
    assert!(rest.contains("1/1 runs finished"), "{rest}");
    assert!(
        !run_dir.join("logs").exists(),
        "it was started anyway: {seen}{rest}"
    );
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn sigterm_stops_every_running_run_with_a_checkpoint_and_exits_143() {
    let text = r#"
total_env_steps = 100000
seeds = [1]
tasks = ["pendulum"]

[[method]]
name = "a"
config = "tiny.toml"
"#;
    let (root, exp) = setup("exp-sigterm", text);
    let dir = root.join("runs");
    let run_dir = dir.join("a/pendulum/seed-1");
    let mut child = spawn({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(&dir);
        c
    });
    wait_until_training(&run_dir, &mut child);
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{stderr}");
    let inserted = final_inserted(&run_dir);
    assert!(
        inserted.is_some_and(|n| n < 100000),
        "no final checkpoint below the budget: {inserted:?}\n{}",
        log(&run_dir, "selkd.log")
    );
    assert!(stderr.contains("1 stopped"), "{stderr}");
    let _ = std::fs::remove_dir_all(&root);
}

/// Rebuilding or upgrading selkd while an experiment runs replaces its file (a new inode, as
/// cargo's build and a package manager do). The runner must still start the runs after it and
/// leave the one training alone; it used to fail to start the next run ("No such file or
/// directory": the kernel then names its own image "selkd (deleted)") and stop them all.
#[test]
fn replacing_selkd_while_an_experiment_runs_stops_nothing() {
    let text = two_seeds_of_a(3000);
    let (root, exp) = setup("exp-replaced", &text);
    let bins = root.join("bin");
    std::fs::create_dir_all(&bins).unwrap();
    for b in ["selkd", "learner", "actor-worker"] {
        std::fs::copy(bin(b), bins.join(b)).unwrap();
    }
    let dir = root.join("runs");
    let (first, second) = (dir.join("a/pendulum/seed-1"), dir.join("a/pendulum/seed-2"));
    let mut child = spawn({
        let mut c = Command::new(bins.join("selkd"));
        c.args(["experiment", "run"])
            .arg(&exp)
            .arg("--dir")
            .arg(&dir)
            .args(["--jobs", "1"]);
        c
    });
    wait_until_training(&first, &mut child);
    std::fs::remove_file(bins.join("selkd")).unwrap();
    std::fs::copy(bin("selkd"), bins.join("selkd")).unwrap();
    assert!(
        final_inserted(&first).is_none() && !second.exists(),
        "the first run ended before selkd was replaced: this test checks nothing; raise the budget"
    );
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    for run in [&first, &second] {
        assert_eq!(
            final_inserted(run),
            Some(3000),
            "{}: {stderr}\n{}",
            run.display(),
            log(run, "selkd.log")
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// SELKD-like K = 2 at equal rounds and at equal env steps beside a K = 1 method, in one
/// experiment file; reported against rounds and critic updates; published, the originals
/// deleted, and reported again from the published copy alone, with the same tables.
const BUDGETS: &str = r#"
total_rounds = 1000
seeds = [1, 2]
tasks = ["pendulum"]

[[method]]
name = "k2-rounds"
config = "tiny.toml"

[[method]]
name = "k2-steps"
config = "tiny.toml"
total_env_steps = 1000

[[method]]
name = "k1"
config = "tiny.toml"
set = { "algo.actors" = 1 }

[[figure]]
title = "equal rounds"
methods = ["k2-rounds", "k1"]
x = "rounds"

[[figure]]
title = "equal env steps"
methods = ["k2-steps", "k1"]
"#;

#[test]
fn budgets_in_rounds_and_env_steps_are_reported_on_either_axis_and_from_their_published_copy() {
    let (root, exp) = setup("exp-budgets", BUDGETS);
    let dir = root.join("runs");
    let out = run({
        let mut c = experiment(&["run"]);
        c.arg(&exp).arg("--dir").arg(&dir).args(["--jobs", "2"]);
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Budgets counted by hand (tiny.toml: K = 2, warm-up 400 env steps, G = 1): 1 000 rounds
    // of K = 2 are 2 000 env steps; training starts with round 200, whose transitions complete
    // the warm-up, so rounds 200 to 1 000 make 801 critic updates; 1 000 env steps are 500
    // rounds, 301 updates; K = 1: 1 000 rounds, 1 000 env steps, rounds 400 to 1 000, 601.
    for (m, env_steps, updates) in [
        ("k2-rounds", 2000, 801.0),
        ("k2-steps", 1000, 301.0),
        ("k1", 1000, 601.0),
    ] {
        for s in [1, 2] {
            let r = dir.join(format!("{m}/pendulum/seed-{s}"));
            assert_eq!(final_inserted(&r), Some(env_steps), "{m} seed {s}");
            let (h, rows) = metrics(&r);
            assert_eq!(
                column(&h, &rows, "critic_updates").last(),
                Some(&updates),
                "{m} seed {s}"
            );
        }
    }
    let cfg = std::fs::read_to_string(dir.join("k2-rounds/pendulum/seed-1/config.toml")).unwrap();
    assert!(
        cfg.contains("total_rounds = 1000") && cfg.contains("total_env_steps = 2000"),
        "{cfg}"
    );
    let report = |d: &Path, x: &str, episodes: &str| {
        run({
            let mut c = experiment(&["report"]);
            c.arg(d).args(["--episodes", episodes, "--x", x]);
            c
        })
    };
    for x in ["env-steps", "rounds", "critic-updates"] {
        let out = report(&dir, x, "2");
        assert!(
            out.status.success(),
            "{x}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // Against env steps: Table 2 and a curve point recomputed here from the runs.
    common::report_check::check_report(
        &dir,
        "pendulum",
        &["k1", "k2-rounds", "k2-steps"],
        &[1, 2],
        2,
        1000.0,
    );
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.contains("budgets differ between methods"), "{md}");
    assert!(
        md.contains("| k2-rounds | 1000 rounds × K = 2 = 2000 env steps |"),
        "{md}"
    );
    assert!(
        md.contains("| k2-steps | 1000 env steps = 500 rounds × K = 2 |"),
        "{md}"
    );
    // The equal-rounds figure is drawn against rounds, the equal-env-steps one against env steps.
    assert!(dir.join("figures/fig6-pendulum-rounds.svg").exists());
    assert!(dir.join("figures/fig7-pendulum.svg").exists());
    let svg = std::fs::read_to_string(dir.join("figures/fig6-pendulum-rounds.svg")).unwrap();
    assert!(svg.contains("rounds (each of the K actors"), "{svg}");
    // Against rounds: k2-rounds at 500 rounds is its runs at 1 000 env steps.
    let rounds = common::report_check::csv_rows(&dir.join("figures/curves-pendulum-rounds.csv"));
    let header = std::fs::read_to_string(dir.join("figures/curves-pendulum-rounds.csv")).unwrap();
    assert!(header.starts_with("method,rounds,"), "{header}");
    let ys: Vec<f64> = [1, 2]
        .iter()
        .map(|s| {
            common::report_check::ranked_at(
                &dir.join(format!("k2-rounds/pendulum/seed-{s}")),
                1000.0,
            )
        })
        .collect();
    let p = rounds
        .iter()
        .find(|r| r[0] == "k2-rounds" && r[1] == "500")
        .expect("a point at 500 rounds");
    assert!(
        common::report_check::close(p[3].parse().unwrap(), common::report_check::mean(&ys)),
        "{p:?} {ys:?}"
    );
    assert!(dir.join("report-rounds.md").exists() && dir.join("report-critic-updates.md").exists());
    let updates =
        std::fs::read_to_string(dir.join("figures/curves-pendulum-critic-updates.csv")).unwrap();
    assert!(updates.starts_with("method,critic_updates,"), "{updates}");

    // Published, the originals deleted, reported again from the copy: the same tables.
    let published = root.join("published");
    let out = run({
        let mut c = experiment(&["publish"]);
        c.arg(&dir).arg(&published).args(["--episodes", "2"]);
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let one = published.join("k2-rounds/pendulum/seed-1");
    for f in [
        "config.toml",
        "metrics.csv",
        "state.json",
        "fresh_eval.json",
        "progress.json",
    ] {
        assert!(one.join(f).is_file(), "{f} not published");
    }
    assert!(!one.join("checkpoints").exists() && published.join("experiment.toml").is_file());
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(one.join("state.json")).unwrap()).unwrap();
    assert_eq!(state["inserted"].as_u64(), Some(2000));
    let size: u64 = walk(&published)
        .iter()
        .map(|p| std::fs::metadata(p).unwrap().len())
        .sum();
    assert!(size < 2_000_000, "published {size} bytes");
    let table_before = std::fs::read_to_string(dir.join("table2.csv")).unwrap();
    let curves_before =
        std::fs::read_to_string(dir.join("figures/curves-pendulum-rounds.csv")).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    for x in ["env-steps", "rounds"] {
        let out = report(&published, x, "2");
        assert!(
            out.status.success(),
            "{x}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert_eq!(
        std::fs::read_to_string(published.join("table2.csv")).unwrap(),
        table_before
    );
    assert_eq!(
        std::fs::read_to_string(published.join("figures/curves-pendulum-rounds.csv")).unwrap(),
        curves_before
    );
    // Without weights the fresh evaluation cannot be redone with another E: one line says so.
    let out = report(&published, "env-steps", "3");
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && e.contains("--episodes 2") && e.trim().lines().count() == 1,
        "{e}"
    );
    // selkd plot reads the published runs too.
    let out = run({
        let mut c = Command::new(bin("selkd"));
        c.arg("plot")
            .arg(published.join("k2-rounds/pendulum/seed-1"))
            .arg(published.join("k2-rounds/pendulum/seed-2"))
            .args(["--x", "rounds", "--out"])
            .arg(root.join("p.svg"));
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// Every file under `dir`.
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}
