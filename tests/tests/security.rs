//! End to end: another local user cannot make a run write through a planted link, nor block a
//! run id by holding a lock; lock files are private and go with their run; run directories are
//! made 0700 unless the config says otherwise.

mod common;
use common::*;
use std::os::unix::fs::PermissionsExt;
use std::process::Command;
use std::time::{Duration, Instant};

/// The second user's uid: `nobody` on Debian.
const OTHER: &str = "65534";

/// A command run as the second user.
fn as_other_user(args: &[&str]) -> Command {
    let mut c = Command::new("setpriv");
    c.args(["--reuid", OTHER, "--regid", OTHER, "--clear-groups", "--"])
        .args(args);
    c
}

fn second_user_available() -> bool {
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("skipped: acting as a second user (uid {OTHER}) needs root");
        return false;
    }
    if !as_other_user(&["true"]).status().is_ok_and(|s| s.success()) {
        eprintln!("skipped: setpriv cannot switch to uid {OTHER} here");
        return false;
    }
    true
}

fn mode(p: &std::path::Path) -> u32 {
    std::fs::metadata(p).unwrap().permissions().mode() & 0o777
}

#[test]
fn another_user_can_neither_redirect_a_learners_lock_nor_block_its_run_id() {
    if !second_user_available() {
        return;
    }
    let dir = temp_dir("second-user");
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let victim = dir.join("victim");
    std::fs::write(&victim, "precious").unwrap();
    let private = dir.join("runtime");
    std::fs::create_dir(&private).unwrap();
    std::fs::set_permissions(&private, std::fs::Permissions::from_mode(0o700)).unwrap();
    let tmp = std::env::temp_dir();
    let (linked, blocked) = (
        format!("sec{}a", std::process::id()),
        format!("sec{}b", std::process::id()),
    );
    // Where the learner used to put its lock, which the run id in `ps` names: a link to a file
    // of ours for one run id, a lock held by the other user for the second.
    let link = tmp.join(format!("selkd-learner-{linked}.lock"));
    let held = tmp.join(format!("selkd-learner-{blocked}.lock"));
    let _ = std::fs::remove_file(&link);
    let _ = std::fs::remove_file(&held);
    let planted = as_other_user(&["ln", "-s", victim.to_str().unwrap(), link.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(planted.success());
    let mut holder = as_other_user(&["flock", held.to_str().unwrap(), "sleep", "120"])
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !held.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the other user's lock never appeared"
        );
        std::thread::sleep(Duration::from_millis(50));
    }

    for run_id in [&linked, &blocked] {
        let run_dir = dir.join(run_id.as_str());
        let mut learner = Command::new(bin("learner"));
        learner
            .args(["--run-id", run_id, "--run-dir"])
            .arg(&run_dir)
            .env("XDG_RUNTIME_DIR", &private);
        let mut learner = spawn(learner);
        let learner_pid = learner.id();
        // A learner that could not lock its run id exits at once. One that did writes its pid into
        // the lock; on a busy machine its start (libtorch, Python) can take seconds, so wait for
        // either rather than a fixed time.
        let ours = private.join("selkd").join(format!("learner-{run_id}.lock"));
        let t0 = Instant::now();
        let (exited, pid_in_lock) = loop {
            std::thread::sleep(Duration::from_millis(200));
            let exited = learner.try_wait().unwrap();
            let pid_in_lock = std::fs::read_to_string(&ours).unwrap_or_default();
            if exited.is_some() || !pid_in_lock.is_empty() || t0.elapsed() > Duration::from_secs(60)
            {
                // Still running a moment later: a learner that fails its lock exits at once.
                std::thread::sleep(Duration::from_millis(500));
                break (learner.try_wait().unwrap().or(exited), pid_in_lock);
            }
        };
        unsafe { libc::kill(learner_pid as i32, libc::SIGTERM) };
        let out = learner.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            exited.is_none(),
            "the learner of {run_id} stopped at start: {err}"
        );
        assert_eq!(
            pid_in_lock,
            learner_pid.to_string(),
            "the lock names its holder: {err}"
        );
        assert_eq!(mode(&private.join("selkd")), 0o700);
        assert!(
            !ours.exists(),
            "the learner's lock file is removed when it ends"
        );
        assert_eq!(mode(&run_dir), 0o700, "a new run directory is private");
    }
    let _ = holder.kill();
    let _ = holder.wait();
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        victim,
        "the link is left as it was"
    );
    let _ = std::fs::remove_file(&link);
    let _ = std::fs::remove_file(&held);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_finished_run_leaves_no_lock_files_and_its_directory_follows_run_dir_mode() {
    let dir = temp_dir("lock-cleanup");
    let private = dir.join("runtime");
    std::fs::create_dir(&private).unwrap();
    std::fs::set_permissions(&private, std::fs::Permissions::from_mode(0o700)).unwrap();
    for (sets, want) in [(vec![], 0o700), (vec!["run.dir_mode=\"0750\""], 0o750)] {
        let run_dir = dir.join(format!("run-{want:o}"));
        let mut sets = sets;
        sets.extend(["algo.actors=2", "run.total_env_steps=1200"]);
        let mut c = train(&run_dir, &small_run(&sets));
        c.env("XDG_RUNTIME_DIR", &private);
        let out = run(c);
        assert_success(&out, &run_dir);
        assert_eq!(mode(&run_dir), want);
        assert!(
            !run_dir.join(".lock").exists(),
            "selkd's run lock is removed"
        );
        let left: Vec<_> = std::fs::read_dir(private.join("selkd"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert!(left.is_empty(), "lock files left behind: {left:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
