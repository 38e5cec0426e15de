//! End to end, faults injected into real runs: a sync run that is SIGKILLed and resumed, or
//! whose workers are killed (a storm of SIGKILLs, one during warm-up) or hang (SIGSTOP), ends
//! exactly as its uninterrupted twin with the same seed: the same metrics (but for wall-clock
//! columns) and a bit-identical final checkpoint. Async runs, which do not reproduce, finish
//! with their budgets and nothing lost. And a full disk fails a checkpoint, not the run.

mod common;
use common::*;
use std::io::{BufReader, Read};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

fn wait_until(what: &str, dir: &Path, limit: Duration, mut done: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !done() {
        assert!(
            t0.elapsed() < limit,
            "waited {limit:?} for {what}:\n{}",
            log(dir, "learner.log")
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn finish(mut child: Child, mut stderr: BufReader<std::process::ChildStderr>) -> (i32, String) {
    let mut rest = String::new();
    stderr.read_to_string(&mut rest).unwrap();
    (child.wait().unwrap().code().unwrap_or(-1), rest)
}

/// The learner alone, or the whole process group (launcher, learner, workers), is SIGKILLed
/// right after a periodic checkpoint; `selkd train --resume RUN` (no other flags: the
/// checkpoint's config) ends bit-identical to the twin that was never stopped.
#[test]
fn a_sync_run_killed_and_resumed_ends_bit_identical_to_its_uninterrupted_twin() {
    let sets = small_run(&[
        "algo.actors=2",
        "run.total_env_steps=7000",
        "run.checkpoint_every=2000",
        "run.checkpoint_replay=true",
        "run.seed=11",
    ]);
    let twin = temp_dir("exact-twin");
    let mut twin_run = Some(spawn(train(&twin, &sets)));
    for how in ["learner", "group"] {
        let dir = temp_dir(&format!("exact-{how}"));
        let mut c = train(&dir, &sets);
        c.process_group(0);
        let mut child = spawn(c);
        let (id, stderr) = run_id(&mut child);
        let latest = dir.join("checkpoints/latest");
        wait_until(
            "a periodic checkpoint",
            &dir,
            Duration::from_secs(120),
            || std::fs::read_to_string(&latest).is_ok_and(|n| n.starts_with("step-")),
        );
        if how == "learner" {
            let pid = learner_pid(&id).expect("the learner is running");
            unsafe { libc::kill(pid, libc::SIGKILL) };
        } else {
            unsafe { libc::killpg(child.id() as i32, libc::SIGKILL) };
        }
        let (code, rest) = finish(child, stderr);
        assert_ne!(
            code, 0,
            "{how}: the killed run must not report success: {rest}"
        );
        assert!(
            !dir.join("checkpoints/final").exists(),
            "{how}: killed before its end"
        );
        wait_until("the workers to go", &dir, Duration::from_secs(30), || {
            worker_pids(&id, 0).is_empty() && worker_pids(&id, 1).is_empty()
        });
        let mut resume = std::process::Command::new(bin("selkd"));
        resume.args(["train", "--resume"]).arg(&dir);
        assert_success(&run(resume), &dir);
        assert!(log(&dir, "learner.log").contains("resumed from"));
        if let Some(t) = twin_run.take() {
            assert_success(&t.wait_with_output().unwrap(), &twin);
        }
        assert_same_run(&dir, &twin, &format!("killed ({how}) and resumed"));
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&twin);
}

/// Kills every worker of `run` it finds joined, one at a time at random, `kills` times in all,
/// `every` apart, while the run lasts. Returns how many it killed.
fn kill_storm(dir: &Path, id: &str, k: usize, kills: usize, every: Duration) -> usize {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut killed = vec![0usize; k];
    while killed.iter().sum::<usize>() < kills && !dir.join("checkpoints/final").exists() {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let w = (state % k as u64) as usize;
        let pids = worker_pids(id, w);
        // Only a worker that has joined (each generation logs one "joined run").
        let joined = log(dir, &format!("worker-{w}.log"))
            .matches("joined run")
            .count();
        if pids.len() == 1 && joined == killed[w] + 1 {
            unsafe { libc::kill(pids[0], libc::SIGKILL) };
            killed[w] += 1;
            std::thread::sleep(every);
        } else {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    killed.iter().sum()
}

/// At least ten SIGKILLs of random workers in one run, sync and async: both finish with their
/// budgets (sync: 4000 env steps per worker; async: 12 000 in all), nothing lost or sent twice (no transition dropped), and the sync one ends exactly as
/// its twin, since every restarted worker continues its predecessor's rollout where the learner's
/// record of it ends.
#[test]
fn a_storm_of_worker_kills_loses_nothing_and_a_sync_run_ends_as_its_twin() {
    let common = ["algo.actors=3", "run.total_env_steps=12000", "run.seed=5"];
    let sync = small_run(&common);
    let mut asynchronous = small_run(&common);
    asynchronous.extend(["--set".into(), "run.mode=async".into()]);
    let twin = temp_dir("storm-twin");
    let twin_run = spawn(train(&twin, &sync));
    let storms: Vec<_> = [("sync", sync), ("async", asynchronous)]
        .into_iter()
        .map(|(mode, sets)| {
            std::thread::spawn(move || {
                let dir = temp_dir(&format!("storm-{mode}"));
                let mut child = spawn(train(&dir, &sets));
                let (id, stderr) = run_id(&mut child);
                let killed = kill_storm(&dir, &id, 3, 12, Duration::from_millis(250));
                let (code, rest) = finish(child, stderr);
                (mode, dir, killed, code, rest)
            })
        })
        .collect();
    assert_success(&twin_run.wait_with_output().unwrap(), &twin);
    for storm in storms {
        let (mode, dir, killed, code, rest) = storm.join().unwrap();
        assert_eq!(code, 0, "{mode}: {rest}\n{}", log(&dir, "learner.log"));
        assert!(
            killed >= 10,
            "{mode}: the run ended after only {killed} kills"
        );
        assert_eq!(
            rest.matches("died (signal 9); restarting it").count(),
            killed,
            "{mode}: {rest}"
        );
        let (h, rows) = metrics(&dir);
        assert_eq!(
            column(&h, &rows, "env_steps").last(),
            Some(&12000.0),
            "{mode}"
        );
        assert!(
            column(&h, &rows, "dropped").iter().all(|&d| d == 0.0),
            "{mode}: transitions dropped"
        );
        let (_, _, state) = final_checkpoint(&dir);
        assert_eq!(state["inserted"], 12000, "{mode}");
        if mode == "sync" {
            assert_eq!(state["received"], serde_json::json!([4000, 4000, 4000]));
        } else {
            // Async: the live workers take a killed one's share (issue 30), so only the sum is
            // fixed.
            let received: Vec<u64> = serde_json::from_value(state["received"].clone()).unwrap();
            assert_eq!(received.iter().sum::<u64>(), 12000, "{received:?}");
        }
        if mode == "sync" {
            assert_same_run(&dir, &twin, "sync run under a kill storm");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&twin);
}

/// A worker killed during warm-up continues its count exactly (its random warm-up steps are
/// neither sent twice nor skipped): the run ends as its twin. On hopper, whose physics keeps a
/// worker's 20 000 warm-up steps above a second (Pendulum's take a few milliseconds).
#[test]
fn a_worker_killed_during_warm_up_continues_its_count_exactly() {
    let sets = small_run(&[
        "run.env=hopper",
        "algo.actors=2",
        "algo.warmup_steps=40000",
        "run.total_env_steps=41000",
        "eval.epoch_env_steps=10000",
        "run.seed=3",
    ]);
    let twin = temp_dir("warmup-twin");
    let twin_run = spawn(train(&twin, &sets));
    let dir = temp_dir("warmup-kill");
    let mut child = spawn(train(&dir, &sets));
    let (id, stderr) = run_id(&mut child);
    wait_until("worker 1 to join", &dir, Duration::from_secs(60), || {
        log(&dir, "worker-1.log").contains("joined run")
    });
    std::thread::sleep(Duration::from_millis(100));
    let pids = worker_pids(&id, 1);
    assert_eq!(pids.len(), 1);
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let (code, rest) = finish(child, stderr);
    assert_eq!(code, 0, "{rest}");
    let learner = log(&dir, "learner.log");
    let line = learner
        .lines()
        .find(|l| l.contains("worker 1 joined (generation 1)"))
        .unwrap_or_else(|| panic!("no rejoin:\n{learner}"));
    let at: u64 = line
        .split("continues at transition ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    assert!(
        at > 0 && at < 20_000,
        "the kill did not land in worker 1's warm-up (it continued at {at}): {line}"
    );
    assert_success(&twin_run.wait_with_output().unwrap(), &twin);
    assert_same_run(&dir, &twin, "worker killed in warm-up");
    for d in [dir, twin] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// A worker stopped with SIGSTOP (hung) is noticed after `run.worker_timeout`, killed and
/// replaced by the launcher, and the run goes on to its budget, in both modes.
#[test]
fn a_hung_worker_is_noticed_killed_and_replaced_in_both_modes() {
    let runs: Vec<_> = ["sync", "async"]
        .into_iter()
        .map(|mode| {
            std::thread::spawn(move || {
                let dir = temp_dir(&format!("hung-{mode}"));
                let sets = small_run(&[
                    "algo.actors=2",
                    "run.total_env_steps=5000",
                    "run.worker_timeout=3",
                    &format!("run.mode={mode}"),
                ]);
                let mut child = spawn(train(&dir, &sets));
                let (id, stderr) = run_id(&mut child);
                wait_until("1500 env steps", &dir, Duration::from_secs(120), || {
                    env_steps_so_far(&dir) >= 1500
                });
                let pid = worker_pids(&id, 1)[0];
                unsafe { libc::kill(pid, libc::SIGSTOP) };
                let stopped = Instant::now();
                wait_until(
                    "the hung worker to be killed",
                    &dir,
                    Duration::from_secs(30),
                    || !worker_pids(&id, 1).contains(&pid),
                );
                let replaced_after = stopped.elapsed();
                let (code, rest) = finish(child, stderr);
                (mode, dir, replaced_after, code, rest)
            })
        })
        .collect();
    for r in runs {
        let (mode, dir, after, code, rest) = r.join().unwrap();
        assert_eq!(code, 0, "{mode}: {rest}");
        assert!(
            rest.contains("selkd: worker 1 sent nothing for")
                && rest.contains("worker 1 died (signal 9); restarting it"),
            "{mode}: {rest}"
        );
        // The timeout, plus a pass of the learner and the launcher's reaction.
        assert!(
            after >= Duration::from_secs(3) && after < Duration::from_secs(10),
            "{mode}: replaced after {after:?}"
        );
        let (h, rows) = metrics(&dir);
        assert_eq!(
            column(&h, &rows, "env_steps").last(),
            Some(&5000.0),
            "{mode}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// The script run in a user and mount namespace of its own (where an unprivileged user may
/// mount a tmpfs): a run on a small tmpfs whose disk is filled after its first checkpoint, then
/// emptied and the run resumed. Its output ends with the run directory copied to `$3`.
const DISK_FULL: &str = r#"
set -u
dir=$1; selkd=$2; out=$3; shift 3
mount -t tmpfs -o size=16m tmpfs "$dir" || exit 0
echo MOUNTED
"$selkd" train --run-dir "$dir/run" "$@" 2>"$out/first.err" &
pid=$!
while [ ! -f "$dir/run/checkpoints/latest" ]; do sleep 0.02; done
# Leave 64 KiB: room for metrics and logs, none for a checkpoint.
avail=$(df --output=avail -B1 "$dir" | tail -1)
head -c $((avail - 65536)) /dev/zero > "$dir/filler" 2>/dev/null
wait $pid
echo "FIRST_EXIT $?"
ls "$dir/run/checkpoints" > "$out/after-first.txt"
rm "$dir/filler"
"$selkd" train --resume "$dir/run" 2>"$out/second.err"
echo "SECOND_EXIT $?"
cp -a "$dir/run" "$out/run"
"#;

/// A full disk: the periodic checkpoints that fail are logged and leave nothing behind, the run
/// trains on to its budget, the final checkpoint's failure is a one-line error naming the last
/// complete checkpoint, and after space is freed the run resumes from it and finishes. Skipped
/// (with a message) where a tmpfs cannot be mounted.
#[test]
fn a_full_disk_fails_checkpoints_not_the_run_and_the_run_resumes_once_space_is_back() {
    let base = temp_dir("disk-full");
    let (mnt, out) = (base.join("mnt"), base.join("out"));
    std::fs::create_dir_all(&mnt).unwrap();
    std::fs::create_dir_all(&out).unwrap();
    let sets = small_run(&[
        "algo.actors=2",
        "run.total_env_steps=8000",
        "run.checkpoint_every=1000",
        "run.checkpoint_replay=true",
    ]);
    let result = std::process::Command::new("unshare")
        .args([
            "--user",
            "--map-root-user",
            "--mount",
            "sh",
            "-c",
            DISK_FULL,
            "sh",
        ])
        .arg(&mnt)
        .arg(bin("selkd"))
        .arg(&out)
        .args(&sets)
        .stdin(std::process::Stdio::null())
        .output();
    let stdout = result
        .as_ref()
        .map(|o| String::from_utf8_lossy(&o.stdout).to_string())
        .unwrap_or_default();
    if !stdout.contains("MOUNTED") {
        eprintln!(
            "skipped: cannot mount a tmpfs in a user namespace here ({})",
            result.map_or_else(
                |e| e.to_string(),
                |o| String::from_utf8_lossy(&o.stderr).trim().to_string()
            )
        );
        let _ = std::fs::remove_dir_all(&base);
        return;
    }
    let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap_or_default();
    let first_err = read("first.err");
    assert!(stdout.contains("FIRST_EXIT 1"), "{stdout}\n{first_err}");
    assert!(
        first_err.contains("writing the final checkpoint (the latest complete one: ")
            && first_err.contains("No space left on device")
            && first_err.contains("--resume"),
        "{first_err}"
    );
    assert!(!first_err.contains("panicked"), "{first_err}");
    let run = out.join("run");
    let learner = log(&run, "learner.log");
    assert!(
        learner.contains("env steps failed") && learner.contains("training goes on"),
        "a periodic checkpoint failed and was logged:\n{learner}"
    );
    let listed = read("after-first.txt");
    assert!(
        !listed.contains("partial") && !listed.contains("final"),
        "a failed checkpoint leaves nothing behind: {listed}"
    );
    assert!(
        stdout.contains("SECOND_EXIT 0"),
        "{stdout}\n{}",
        read("second.err")
    );
    let (h, rows) = metrics(&run);
    assert_eq!(
        column(&h, &rows, "epoch"),
        (1..=8).map(|e| e as f64).collect::<Vec<_>>(),
        "one row per epoch, the budget reached"
    );
    assert!(run.join("checkpoints/final/state.json").exists());
    let _ = std::fs::remove_dir_all(&base);
}
