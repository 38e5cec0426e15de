//! examples/: the by-hand run (a learner and two actor-workers, the commands a user types in three
//! terminals) runs as written and finishes with its metrics and final checkpoint.

mod common;

use common::*;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn the_by_hand_example_trains_a_run_with_a_learner_and_two_workers() {
    let dir = temp_dir("by-hand");
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let run_dir = dir.join("run");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bin_dir = bin("learner").parent().unwrap().to_path_buf();
    bin("actor-worker");
    let mut c = Command::new("bash");
    c.current_dir(&root)
        .arg("examples/by-hand.sh")
        .args(["--set", "run.total_env_steps=1000"])
        .env("BIN", &bin_dir)
        .env("CONFIG", &config)
        .env("RUN_DIR", &run_dir)
        .env("RUN_ID", format!("byhand{}", std::process::id()))
        .env("ENV", "pendulum")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        // Its own group: a run that hangs is killed whole, learner and workers with the script.
        .process_group(0);
    let child = c.spawn().unwrap();
    let pid = child.id() as i32;
    let waiter = std::thread::spawn(move || child.wait_with_output().unwrap());
    let deadline = Instant::now() + Duration::from_secs(300);
    while !waiter.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(200));
    }
    if !waiter.is_finished() {
        unsafe { libc::kill(-pid, libc::SIGKILL) };
    }
    let out = waiter.join().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "examples/by-hand.sh failed ({}):\n{stderr}",
        out.status
    );
    // The learner's progress lines, which `selkd train` would read.
    assert!(stdout.contains("PROGRESS {"), "{stdout}");

    let (header, rows) = metrics(&run_dir);
    assert_eq!(
        rows.len(),
        2,
        "one row per 500 env steps:\n{header:?}\n{rows:?}"
    );
    assert_eq!(column(&header, &rows, "env_steps"), [500.0, 1000.0]);
    assert!(column(&header, &rows, "critic_updates")[1] > 0.0);
    for actor in 0..2 {
        let returns = column(&header, &rows, &format!("eval_return_{actor}"));
        assert!(
            returns.iter().all(|r| r.is_finite()),
            "actor {actor}: {returns:?}"
        );
    }
    let last = run_dir.join("checkpoints/final");
    assert!(last.join("model.safetensors").exists());
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(last.join("state.json")).unwrap()).unwrap();
    assert_eq!(state["inserted"], 1000, "{state}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A worker started by hand has no launcher to stop it: when its learner dies (SIGKILL, no
/// stop order), it must notice on its own and exit with an error that says so.
#[test]
fn workers_started_by_hand_exit_when_their_learner_is_gone() {
    use std::io::BufRead;
    let dir = temp_dir("by-hand-gone");
    let run_id = format!("gone{}", std::process::id());
    let (mut learner, mut workers) = start_by_hand(&dir, &run_id, 1_000_000);
    // Training is under way: past the warm-up, so the workers wait on the learner's rounds.
    let mut progress = std::io::BufReader::new(learner.stdout.take().unwrap());
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut line = String::new();
    loop {
        line.clear();
        assert!(
            progress.read_line(&mut line).unwrap() > 0,
            "the learner ended"
        );
        let updates = line
            .strip_prefix("PROGRESS ")
            .and_then(|j| serde_json::from_str::<serde_json::Value>(j).ok())
            .and_then(|p| p["critic_updates"].as_u64())
            .unwrap_or(0);
        if updates > 0 {
            break;
        }
        assert!(Instant::now() < deadline, "no training after 120 s");
    }
    unsafe { libc::kill(learner.id() as i32, libc::SIGKILL) };
    learner.wait().unwrap();
    // (Workers left running when this fails die with the test's thread: `spawn`'s PDEATHSIG.)
    wait_until(
        "the workers to leave after their learner was killed",
        Duration::from_secs(30),
        || workers.iter_mut().all(|w| w.try_wait().unwrap().is_some()),
    );
    for w in workers {
        let out = w.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("is gone"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The learner broadcasts the actors' ranking (each one's Monte-Carlo score and the best one) for
/// any program on the host: an observer subscribed by hand (a fourth terminal) sees it change as
/// the run goes, and the last one it sees is the final checkpoint's.
#[test]
fn an_observer_on_the_host_reads_the_ranking_the_learner_broadcasts() {
    use selkd_protocol::{services, Services};
    let dir = temp_dir("by-hand-ranking");
    let run_id = format!("ranking{}", std::process::id());
    let run_dir = dir.join("run");
    let node = services::node(&format!("observer{}", std::process::id())).unwrap();
    let observer = services::ranking(&node, &Services::new(&run_id))
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let (mut learner, workers) = start_by_hand(&dir, &run_id, 1000);
    // (version, best, scores) of each ranking seen, polled faster than the learner's passes.
    let mut seen: Vec<(u64, u32, [f64; 2])> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(300);
    while learner.try_wait().unwrap().is_none() {
        assert!(Instant::now() < deadline, "the run did not finish in 300 s");
        while let Some(r) = observer.receive().unwrap() {
            assert_eq!(r.actors, 2);
            seen.push((r.version, r.best, [r.scores[0], r.scores[1]]));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(learner.wait().unwrap().success());
    for w in workers {
        assert!(w.wait_with_output().unwrap().status.success());
    }
    assert!(
        seen.windows(2).all(|p| p[0].0 < p[1].0),
        "each ranking once, in order: {seen:?}"
    );
    let &(_, best, scores) = seen.last().expect("no ranking seen");
    // The final checkpoint's ranking: the latest evaluation's return per actor (both actors are
    // evaluated at each epoch's end), the best its argmax, ties to the lower index.
    let state: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run_dir.join("checkpoints/final/state.json")).unwrap(),
    )
    .unwrap();
    let want: Vec<f64> = (0..2)
        .map(|i| state["ranking"]["evaluation"][i].as_f64().unwrap())
        .collect();
    assert_eq!(scores.to_vec(), want, "{seen:?}");
    assert_eq!(best, if want[1] > want[0] { 1 } else { 0 }, "{seen:?}");
    assert!(seen.len() >= 2, "only the final ranking was seen: {seen:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A learner (run directory DIR/run, the tiny config) and two Pendulum workers started as a user
/// starts them in three terminals, without the launcher.
fn start_by_hand(
    dir: &Path,
    run_id: &str,
    total_env_steps: u64,
) -> (std::process::Child, Vec<std::process::Child>) {
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let mut learner = Command::new(bin("learner"));
    learner
        .arg("--config")
        .arg(&config)
        .arg("--set")
        .arg(format!("run.total_env_steps={total_env_steps}"))
        .arg("--run-dir")
        .arg(dir.join("run"))
        .args(["--run-id", run_id]);
    // The learner first: the workers wait for it (up to their connect timeout).
    let learner = spawn(learner);
    let workers = (0..2)
        .map(|w| {
            let mut c = Command::new(bin("actor-worker"));
            c.args(["--run-id", run_id, "--worker", &w.to_string()])
                .args(["--env", "pendulum"]);
            spawn(c)
        })
        .collect();
    (learner, workers)
}
