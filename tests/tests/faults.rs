//! End to end: a worker killed with SIGKILL is restarted and rejoins with the current weights;
//! two runs on one host at once do not see each other (and, in sync mode, reproduce each other).

mod common;
use common::*;
use std::time::{Duration, Instant};

#[test]
fn a_killed_worker_is_restarted_and_rejoins_with_the_current_weights() {
    let dir = temp_dir("kill");
    let mut child = spawn(train(
        &dir,
        &small_run(&["algo.actors=2", "run.total_env_steps=6000"]),
    ));
    // The launcher's first line names the run id.
    let (run_id, mut stderr) = run_id(&mut child);
    let t0 = Instant::now();
    while env_steps_so_far(&dir) < 2000 {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "run made no progress: {}",
            log(&dir, "learner.log")
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let pids = worker_pids(&run_id, 1);
    assert_eq!(pids.len(), 1, "exactly one worker 1 running: {pids:?}");
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stderr, &mut rest).unwrap();
    let status = child.wait().unwrap();
    let learner = log(&dir, "learner.log");
    assert!(
        status.success(),
        "run {run_id} did not finish after the kill ({status}):\n{rest}\n{learner}"
    );
    assert!(
        rest.contains("worker 1 died (signal 9); restarting it (generation 1)"),
        "{rest}"
    );
    // The restarted worker's hello: the weights it holds must be the learner's current version.
    let line = learner
        .lines()
        .find(|l| l.contains("worker 1 joined (generation 1)"))
        .unwrap_or_else(|| panic!("no rejoin in learner log:\n{learner}"));
    let number_after = |key: &str| -> u64 {
        line.split(key)
            .nth(1)
            .and_then(|r| r.split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no `{key}` in: {line}"))
    };
    let (held, current) = (
        number_after("holding weights version "),
        number_after("learner at version "),
    );
    assert!(
        held > 1,
        "the restarted worker should hold trained weights, not the initial ones: {line}"
    );
    assert_eq!(
        held, current,
        "restarted worker holds version {held}, learner is at {current}: {line}"
    );
    let (h, rows) = metrics(&dir);
    assert_eq!(
        *column(&h, &rows, "env_steps").last().unwrap(),
        6000.0,
        "the run reached its budget"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn two_runs_at_once_do_not_cross_and_sync_runs_reproduce_bit_for_bit() {
    let (a, b, c) = (temp_dir("twin-a"), temp_dir("twin-b"), temp_dir("other-c"));
    let twin = small_run(&["algo.actors=2", "run.total_env_steps=3000", "run.seed=7"]);
    // A third run at the same time with another shape: crossing would mix sizes and fail loudly.
    let other = small_run(&[
        "algo.actors=3",
        "eval.epoch_env_steps=999",
        "algo.hidden=[16]",
        "run.total_env_steps=3000",
        "run.seed=8",
    ]);
    let children = [
        spawn(train(&a, &twin)),
        spawn(train(&b, &twin)),
        spawn(train(&c, &other)),
    ];
    for (child, dir) in children.into_iter().zip([&a, &b, &c]) {
        let out = child.wait_with_output().unwrap();
        assert_success(&out, dir);
        let learner = log(dir, "learner.log");
        assert!(
            !learner.contains("does not fit") && !learner.contains("dropped a transition"),
            "{learner}"
        );
    }
    let (ha, ra) = metrics(&a);
    let (hb, rb) = metrics(&b);
    assert_eq!(ha, hb);
    for col in [
        "critic_updates",
        "critic_loss",
        "q_mean",
        "eval_return_0",
        "eval_return_1",
        "alpha_0",
        "kl_to_best_1",
    ] {
        assert_eq!(
            column(&ha, &ra, col),
            column(&hb, &rb, col),
            "sync runs with one seed differ in {col}"
        );
    }
    let (hc, rc) = metrics(&c);
    assert!(hc.contains(&"eval_return_2".to_string()) && !rc.is_empty());
    let weights_a = std::fs::read(a.join("checkpoints/final/model.safetensors")).unwrap();
    let weights_b = std::fs::read(b.join("checkpoints/final/model.safetensors")).unwrap();
    assert!(
        weights_a == weights_b,
        "final checkpoints of the two sync runs differ"
    );
    for d in [a, b, c] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn a_run_resumes_from_its_checkpoint_with_workers_on_the_saved_weights() {
    let (first, second) = (temp_dir("resume-a"), temp_dir("resume-b"));
    let sets = small_run(&[
        "algo.actors=2",
        "run.total_env_steps=2000",
        "run.checkpoint_replay=true",
    ]);
    assert_success(&run(train(&first, &sets)), &first);
    let ckpt = first.join("checkpoints/final");
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ckpt.join("state.json")).unwrap()).unwrap();
    let saved_version = state["weights_version"].as_u64().unwrap();
    let mut more = small_run(&[
        "algo.actors=2",
        "run.total_env_steps=3000",
        "run.checkpoint_replay=true",
    ]);
    more.extend(["--resume".to_string(), ckpt.display().to_string()]);
    assert_success(&run(train(&second, &more)), &second);
    let learner = log(&second, "learner.log");
    assert!(learner.contains("resumed from"), "{learner}");
    let joined =
        format!("holding weights version {saved_version}; learner at version {saved_version}");
    assert_eq!(
        learner.matches(&joined).count(),
        2,
        "both workers start on the checkpoint's weights:\n{learner}"
    );
    let (h, rows) = metrics(&second);
    assert_eq!(
        column(&h, &rows, "env_steps"),
        vec![3000.0],
        "only the new epoch is logged in the new run"
    );
    for d in [first, second] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// A checkpoint without the replay buffer (the default): the resumed learner has nothing to
/// sample, so it trains again only after another warm-up's worth of transitions. An async run
/// used to crash there at once ("sample from an empty replay buffer"). K = 2, warm-up 400, G = 1:
/// the first run's rounds are at 400, 402, …, 2000; the resumed one's at 2400, …, 3000, 301 of
/// them (500 without the refill).
#[test]
fn a_run_resumed_without_its_replay_buffer_refills_it_before_training() {
    for mode in ["sync", "async"] {
        let (first, second) = (temp_dir("refill-a"), temp_dir("refill-b"));
        let mode_set = format!("run.mode={mode}");
        let sets = |steps: &str| small_run(&["algo.actors=2", &mode_set, steps]);
        assert_success(
            &run(train(&first, &sets("run.total_env_steps=2000"))),
            &first,
        );
        let mut more = sets("run.total_env_steps=3000");
        more.extend([
            "--resume".to_string(),
            first.join("checkpoints/final").display().to_string(),
        ]);
        assert_success(&run(train(&second, &more)), &second);
        let learner = log(&second, "learner.log");
        assert!(
            learner.contains("training resumes once 400 new transitions"),
            "{mode}: {learner}"
        );
        let updates = |dir| {
            let (h, rows) = metrics(dir);
            *column(&h, &rows, "critic_updates").last().unwrap()
        };
        let (before, after) = (updates(&first), updates(&second));
        let new = after - before;
        // Sync trains every round that is due; async trains what it has time for before the
        // budget ends the run (the first run stopped at about 700 rounds of its 801).
        let fewest = if mode == "sync" { 300.0 } else { 1.0 };
        assert!(
            (fewest..=302.0).contains(&new),
            "{mode}: {new} critic updates after the resume ({before} → {after})"
        );
        for d in [first, second] {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

#[test]
fn a_worker_that_does_not_fit_the_run_is_refused_with_a_clear_error() {
    let dir = temp_dir("refuse");
    let run_id = format!("refuse{}", std::process::id());
    let mut learner = std::process::Command::new(bin("learner"));
    learner
        .args(["--run-id", &run_id, "--set", "algo.actors=2"])
        .args(["--set", "env_options.g=9.81", "--run-dir"])
        .arg(&dir);
    let mut learner = spawn(learner);
    let worker = |index: &str, options: &str| {
        let mut worker = std::process::Command::new(bin("actor-worker"));
        worker.args(["--run-id", &run_id, "--worker", index, "--env", "pendulum"]);
        worker.args(["--env-options", options, "--connect-timeout", "30"]);
        let out = run(worker);
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        )
    };
    let out_of_range = worker("5", r#"{"g": 9.81}"#);
    // Same env, other options: a different task, refused rather than mixed into the run.
    let other_options = worker("0", r#"{"g": 3.7}"#);
    let _ = learner.kill();
    let _ = learner.wait();
    let (code, err) = out_of_range;
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--worker 5 is out of range: the run has 2 actors"),
        "{err}"
    );
    let (code, err) = other_options;
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("other options or physics settings than the run"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Starts a long run, waits until it has `steps` env steps, and sends `signal` to `selkd`, or
/// with `group` to its whole process group, as a terminal's Ctrl-C does (selkd leads a group of
/// its own here, as a shell's job does).
/// Returns (exit code, selkd's stderr after the first line, run id).
fn stop_a_run_with(
    dir: &std::path::Path,
    signal: i32,
    group: bool,
    steps: u64,
) -> (Option<i32>, String, String) {
    let mut command = train(
        dir,
        &small_run(&["algo.actors=2", "run.total_env_steps=1000000"]),
    );
    std::os::unix::process::CommandExt::process_group(&mut command, 0);
    let mut child = spawn(command);
    let (run_id, mut stderr) = run_id(&mut child);
    let t0 = Instant::now();
    while env_steps_so_far(dir) < steps {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "no progress: {}",
            log(dir, "learner.log")
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let pid = child.id() as i32;
    unsafe { libc::kill(if group { -pid } else { pid }, signal) };
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stderr, &mut rest).unwrap();
    let status = child.wait().unwrap();
    (status.code(), rest, run_id)
}

/// Ctrl-C, SIGTERM (kill, timeout, systemd, docker, Slurm) and SIGHUP (a closed terminal) each
/// stop the run the same way: a final checkpoint, no process left, no panic, exit 128 + signal.
/// A terminal's Ctrl-C (and `timeout`) signals selkd's whole process group: the learner and the
/// workers are in groups of their own, so selkd alone decides how they stop, and no worker dies
/// of the signal and gets restarted on the way out.
#[test]
fn ctrl_c_sigterm_and_sighup_stop_everything_cleanly_with_a_checkpoint() {
    for (signal, group, code) in [
        (libc::SIGINT, false, 130),
        (libc::SIGINT, true, 130),
        (libc::SIGTERM, false, 143),
        (libc::SIGHUP, false, 129),
    ] {
        let dir = temp_dir(&format!("stop{signal}{group}"));
        let (status, rest, run_id) = stop_a_run_with(&dir, signal, group, 1000);
        assert_eq!(status, Some(code), "signal {signal}: {rest}");
        assert!(rest.contains("stopped; checkpoint at"), "{rest}");
        assert!(
            !rest.contains("died"),
            "signal {signal}, group {group}: {rest}"
        );
        for w in 0..2 {
            let worker = log(&dir, &format!("worker-{w}.log"));
            assert!(
                worker.contains("learner asked to stop"),
                "signal {signal}, group {group}: worker {w} did not leave on the learner's order: {worker}"
            );
        }
        let state: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("checkpoints/final/state.json")).unwrap(),
        )
        .unwrap();
        assert!(state["inserted"].as_u64().unwrap() >= 1000);
        assert!(
            worker_pids(&run_id, 0).is_empty() && worker_pids(&run_id, 1).is_empty(),
            "workers left running"
        );
        let learner = log(&dir, "learner.log");
        assert!(!learner.contains("panicked"), "{learner}");
        assert!(!learner.contains('\x1b'), "no colour codes in log files");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// A stopped run resumed into its own directory continues its metrics.csv: one header, one row
/// per epoch, epochs 1, 2, 3, … without a gap or a repeat, up to the new budget.
#[test]
fn a_stopped_run_resumed_in_place_continues_its_metrics_one_row_per_epoch() {
    let dir = temp_dir("resume-in-place");
    let (status, rest, _) = stop_a_run_with(&dir, libc::SIGTERM, false, 1500);
    assert_eq!(status, Some(143), "{rest}");
    let mut more = small_run(&["algo.actors=2", "run.total_env_steps=4000"]);
    more.extend([
        "--resume".to_string(),
        dir.join("checkpoints/final").display().to_string(),
    ]);
    assert_success(&run(train(&dir, &more)), &dir);
    let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    assert_eq!(text.matches("epoch,env_steps").count(), 1, "{text}");
    let (h, rows) = metrics(&dir);
    let epochs = column(&h, &rows, "epoch");
    assert_eq!(
        epochs,
        (1..=4).map(|e| e as f64).collect::<Vec<_>>(),
        "{text}"
    );
    assert_eq!(
        column(&h, &rows, "env_steps"),
        vec![1000.0, 2000.0, 3000.0, 4000.0]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Divergence (`algo.lr = 1e30`): the run stops with a one-line error naming the round, exits
/// non-zero, and keeps its last good checkpoint: a healthy run's final checkpoint, resumed in
/// place with the diverging learning rate, is left as it was (no checkpoint full of NaN replaces
/// it).
#[test]
fn divergence_stops_the_run_with_a_clear_error_and_keeps_the_last_good_checkpoint() {
    let dir = temp_dir("diverge");
    assert_success(
        &run(train(
            &dir,
            &small_run(&["algo.actors=2", "run.total_env_steps=1000"]),
        )),
        &dir,
    );
    let good = std::fs::read(dir.join("checkpoints/final/model.safetensors")).unwrap();
    let mut sets = small_run(&["algo.actors=2", "algo.lr=1e30", "run.total_env_steps=4000"]);
    sets.extend([
        "--resume".to_string(),
        dir.join("checkpoints/final").display().to_string(),
    ]);
    let out = run(train(&dir, &sets));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("training diverged in round"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(
        std::fs::read(dir.join("checkpoints/final/model.safetensors")).unwrap(),
        good,
        "the last good checkpoint is kept"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// K = 20 actors (iceoryx2's default allows 20 nodes per service, so this needs the limits set
/// from K), and K above the protocol's 64 is a config error before any process starts.
#[test]
fn twenty_actors_run_and_more_than_sixty_four_are_refused() {
    let dir = temp_dir("k20");
    let sets = small_run(&["algo.actors=20", "run.total_env_steps=2000"]);
    assert_success(&run(train(&dir, &sets)), &dir);
    let (h, rows) = metrics(&dir);
    assert_eq!(column(&h, &rows, "env_steps").last(), Some(&2000.0));
    let _ = std::fs::remove_dir_all(&dir);
    for (set, key) in [
        ("algo.actors=65", "algo.actors"),
        ("algo.batch_size=200000", "algo.replay_capacity"),
        ("algo.hidden=[8,8,8,8,8,8,8,8,8]", "algo.hidden"),
        ("run.device=cuda", "run.device"),
    ] {
        let out = run(train(&dir.join("x"), &["--set".into(), set.into()]));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{set}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{set}: {err}");
        assert!(err.contains(key), "{set}: {err}");
        assert!(!dir.join("x").exists(), "{set}: nothing started");
    }
}

/// One launcher per run directory and one learner per run id: the second is refused with a
/// message naming the holder's pid; a stopped run's directory is not reused by a new run unless
/// it resumes; once the holder is gone its lock is free.
#[test]
fn a_second_launcher_or_learner_is_refused_naming_the_holder() {
    let dir = temp_dir("locked");
    let mut first = spawn(train(
        &dir,
        &small_run(&["algo.actors=2", "run.total_env_steps=1000000"]),
    ));
    let t0 = Instant::now();
    while env_steps_so_far(&dir) < 500 {
        assert!(t0.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = run(train(&dir, &small_run(&["algo.actors=2"])));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!("in use by another selkd (pid {})", first.id())),
        "{err}"
    );
    // Two learners with one run id.
    let run_id = format!("lock{}", std::process::id());
    let learner = |d: &std::path::Path| {
        let mut c = std::process::Command::new(bin("learner"));
        c.args(["--run-id", &run_id, "--run-dir"]).arg(d);
        c
    };
    let mut a = spawn(learner(&dir.join("l1")));
    std::thread::sleep(Duration::from_millis(1500));
    let out = run(learner(&dir.join("l2")));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("already has a learner (pid {})", a.id())),
        "{err}"
    );
    let _ = a.kill();
    let _ = a.wait();
    unsafe { libc::kill(first.id() as i32, libc::SIGTERM) };
    assert_eq!(first.wait().unwrap().code(), Some(143));
    // The holder is gone: the directory is free, but a new run may not overwrite it.
    let out = run(train(&dir, &small_run(&["algo.actors=2"])));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("already holds a run") && err.contains("--resume"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A worker that keeps dying past `--max-restarts` within `--restart-window` ends the run: selkd
/// says so in one line naming the flags and the worker's log, exits 1, and the learner still
/// writes its final checkpoint (nothing trained is lost).
#[test]
fn a_worker_that_keeps_dying_ends_the_run_with_its_reason_and_a_checkpoint() {
    let dir = temp_dir("gives-up");
    let mut c = train(
        &dir,
        &small_run(&["algo.actors=2", "run.total_env_steps=200000"]),
    );
    c.args(["--max-restarts", "1", "--restart-window", "600"]);
    let mut child = spawn(c);
    let (run_id, mut stderr) = run_id(&mut child);
    let t0 = Instant::now();
    // Two deaths of worker 0, the second once its successor runs.
    for death in 1..=2 {
        let pid = loop {
            assert!(
                t0.elapsed() < Duration::from_secs(120),
                "worker 0 never ran (death {death})"
            );
            if env_steps_so_far(&dir) >= 500 {
                if let [pid] = worker_pids(&run_id, 0)[..] {
                    break pid;
                }
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        unsafe { libc::kill(pid, libc::SIGKILL) };
        // Wait for the pid to go before looking for a successor.
        while worker_pids(&run_id, 0).contains(&pid) {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stderr, &mut rest).unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(1), "{rest}");
    let line = rest
        .lines()
        .find(|l| l.starts_with("selkd: run failed: "))
        .unwrap_or_else(|| panic!("no failure line:\n{rest}"));
    assert!(
        line.contains("worker 0 died 2 times within 600 s (--max-restarts 1, --restart-window 600); giving up; see")
            && line.ends_with("worker-0.log"),
        "{line}"
    );
    assert!(
        dir.join("checkpoints/final/state.json").exists(),
        "no final checkpoint after giving up:\n{}",
        log(&dir, "learner.log")
    );
    assert!(worker_pids(&run_id, 1).is_empty(), "worker 1 left running");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A learner whose workers have not come (or are between episodes) waits on the wake event
/// rather than polling: over 3 s without a worker it uses well under a core. Polling without the
/// wait spins a core for as long as the run waits, which nothing else here would notice.
#[test]
fn a_learner_waiting_for_its_workers_sleeps_rather_than_spinning_a_core() {
    use std::io::BufRead;
    let dir = temp_dir("idle-learner");
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let mut c = std::process::Command::new(bin("learner"));
    c.arg("--config")
        .arg(&config)
        .arg("--run-dir")
        .arg(dir.join("run"))
        .args(["--run-id", &format!("idle{}", std::process::id())]);
    let mut child = spawn(c);
    // The first progress line comes from the run's loop: start-up (libtorch, the networks) is over.
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    while !line.starts_with("PROGRESS") {
        line.clear();
        let n = stdout.read_line(&mut line).unwrap();
        assert!(
            n > 0,
            "the learner ended before its loop: {:?}",
            child.wait()
        );
    }
    // Keep reading its progress lines, so that a full pipe never blocks it.
    std::thread::spawn(move || for _ in stdout.lines() {});
    let cpu = || {
        let stat = std::fs::read_to_string(format!("/proc/{}/stat", child.id())).unwrap();
        // utime and stime, fields 14 and 15, after the command's closing parenthesis.
        let fields: Vec<&str> = stat[stat.rfind(')').unwrap() + 2..].split(' ').collect();
        let ticks: f64 = fields[11].parse::<f64>().unwrap() + fields[12].parse::<f64>().unwrap();
        ticks / unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64
    };
    let (cpu0, t0) = (cpu(), Instant::now());
    std::thread::sleep(Duration::from_secs(3));
    let (used, wall) = (cpu() - cpu0, t0.elapsed().as_secs_f64());
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let _ = child.wait();
    assert!(
        used < 0.25 * wall,
        "a learner with no workers used {used:.2} s of CPU in {wall:.2} s: it polls instead of waiting"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
