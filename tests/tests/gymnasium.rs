//! End to end on Gymnasium's own envs (`run.env = "gymnasium:<id>"`, stepped in each worker's
//! embedded Python): SAC (5 000 env steps) and the quick SELKD config (K = 3) learn Pendulum-v1; a sync Hopper-v5 run whose worker and then
//! learner are SIGKILLed ends bit-identical to its twin; an exception inside the env's `step`
//! stops the run with the env's message instead of restarting the worker again and again.

mod common;
use common::*;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn config(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs")
        .join(name)
}

/// Pendulum-v1 from Gymnasium at the baselines tests' scale (5 000 env steps, G = 3, 64 × 64):
/// the config's last evaluation beats a random policy by more than 600.
fn learns_gymnasium_pendulum(tag: &str, config_file: &str, extra: &[&str]) {
    let dir = temp_dir(tag);
    let sets: Vec<String> = [
        "run.env=gymnasium:Pendulum-v1",
        "run.total_env_steps=5000",
        "run.threads=1",
        "algo.utd=3",
        "algo.hidden=[64,64]",
        "algo.batch_size=128",
        "algo.warmup_steps=1000",
        "eval.epoch_env_steps=1000",
        "eval.episodes=5",
    ]
    .iter()
    .chain(extra)
    .flat_map(|s| ["--set".to_string(), s.to_string()])
    .collect();
    let mut c = train(&dir, &sets);
    c.arg("--config").arg(config(config_file));
    assert_success(&run(c), &dir);
    let (h, rows) = metrics(&dir);
    let k = h.iter().filter(|c| c.starts_with("eval_return_")).count();
    let best = (0..k)
        .map(|i| {
            *column(&h, &rows, &format!("eval_return_{i}"))
                .last()
                .unwrap()
        })
        .fold(f64::MIN, f64::max);
    // Our `pendulum` is Gymnasium's Pendulum-v1 exactly (the golden test checks it), so its
    // random policy is the bar.
    let random = random_policy_return(20);
    assert!(
        best > random + 600.0,
        "{config_file} on gymnasium:Pendulum-v1: final evaluation {best:.0} is not well beyond random {random:.0}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sac_learns_gymnasium_pendulum_within_5k_env_steps() {
    learns_gymnasium_pendulum("gym-sac", "baselines/sac.toml", &[]);
}

/// The quick config as shipped (K = 3 workers, 12 000 env steps: 4 000 rounds), on Gymnasium's
/// Pendulum. At 5 000 env steps its actors would have had about 1 300 updates each, too few (it
/// stayed at random's level when tried).
#[test]
fn the_quick_selkd_config_with_three_workers_learns_gymnasium_pendulum() {
    let dir = temp_dir("gym-selkd");
    let mut c = train(
        &dir,
        &["--set".into(), "run.env=gymnasium:Pendulum-v1".into()],
    );
    c.arg("--config").arg(config("quick.toml"));
    assert_success(&run(c), &dir);
    let (h, rows) = metrics(&dir);
    let best = (0..3)
        .map(|i| {
            *column(&h, &rows, &format!("eval_return_{i}"))
                .last()
                .unwrap()
        })
        .fold(f64::MIN, f64::max);
    let random = random_policy_return(20);
    assert!(
        best > random + 600.0,
        "quick.toml on gymnasium:Pendulum-v1: final best evaluation {best:.0} is not well beyond random {random:.0}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn wait_until(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !done() {
        assert!(t0.elapsed() < limit, "waited {limit:?} for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_gymnasium_hopper_run_with_a_worker_and_the_learner_killed_ends_as_its_twin() {
    let sets = small_run(&[
        "run.env=gymnasium:Hopper-v5",
        "algo.actors=2",
        "run.total_env_steps=4000",
        "run.checkpoint_every=2000",
        "run.checkpoint_replay=true",
        "run.seed=5",
    ]);
    let twin = temp_dir("gym-twin");
    let twin_run = spawn(train(&twin, &sets));
    let dir = temp_dir("gym-killed");
    let mut child = spawn(train(&dir, &sets));
    let (id, mut stderr) = run_id(&mut child);
    // A worker dies mid-episode: its successor replays the episode on its seed and goes on.
    wait_until("1000 env steps", Duration::from_secs(120), || {
        env_steps_so_far(&dir) >= 1000
    });
    let pids = worker_pids(&id, 1);
    assert_eq!(pids.len(), 1, "{pids:?}");
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    // Then the learner, after its periodic checkpoint.
    let latest = dir.join("checkpoints/latest");
    wait_until("a periodic checkpoint", Duration::from_secs(120), || {
        std::fs::read_to_string(&latest).is_ok_and(|n| n.starts_with("step-"))
    });
    unsafe { libc::kill(learner_pid(&id).expect("the learner runs"), libc::SIGKILL) };
    let mut rest = String::new();
    stderr.read_to_string(&mut rest).unwrap();
    assert_ne!(child.wait().unwrap().code(), Some(0), "{rest}");
    assert!(
        rest.contains("worker 1 died (signal 9); restarting it"),
        "{rest}"
    );
    wait_until("the workers to go", Duration::from_secs(30), || {
        worker_pids(&id, 0).is_empty() && worker_pids(&id, 1).is_empty()
    });
    let mut resume = std::process::Command::new(bin("selkd"));
    resume.args(["train", "--resume"]).arg(&dir);
    assert_success(&run(resume), &dir);
    assert_success(&twin_run.wait_with_output().unwrap(), &twin);
    assert_same_run(&dir, &twin, "gymnasium:Hopper-v5 killed and resumed");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&twin);
}

/// `selkd train` on the test envs of gymnasium/tests/python (importable through PYTHONPATH,
/// which every process of the run inherits).
fn train_test_env(dir: &Path, env: &str, extra: &[&str]) -> std::process::Output {
    let mut sets = vec![
        format!("run.env=gymnasium:{env}"),
        "env_options.import=[\"selkd_test_gym\"]".to_string(),
        "run.total_env_steps=1500".to_string(),
    ];
    sets.extend(extra.iter().map(|s| s.to_string()));
    let sets: Vec<&str> = sets.iter().map(String::as_str).collect();
    let mut c = train(dir, &small_run(&sets));
    c.env(
        "PYTHONPATH",
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../gymnasium/tests/python"),
    );
    run(c)
}

#[test]
fn an_exception_in_step_stops_the_run_with_its_message_and_nan_observations_end_episodes() {
    let dir = temp_dir("gym-boom");
    let t0 = Instant::now();
    let out = train_test_env(&dir, "SelkdEcho-v0", &["env_options.boom_at=30"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_ne!(out.status.code(), Some(0), "{err}");
    assert!(
        err.contains("RuntimeError: boom at step 30") && err.contains("cannot join the run"),
        "{err}"
    );
    assert!(!err.contains("restarting it"), "no restart loop: {err}");
    assert!(t0.elapsed() < Duration::from_secs(60));
    let _ = std::fs::remove_dir_all(&dir);
    // NaN every 7th observation: each such step ends its episode, and the run goes on.
    let dir = temp_dir("gym-nan");
    let out = train_test_env(&dir, "SelkdEcho-v0", &["env_options.nan_every=7"]);
    assert_success(&out, &dir);
    // Bad ids, spaces and keywords are refused before anything starts, in one line.
    for (env, extra, says) in [
        ("SelkdDiscrete-v0", "", "only Box spaces"),
        ("SelkdUnbounded-v0", "", "infinite bound"),
        (
            "SelkdEcho-v0",
            "env_options.frobnicate=1",
            "unexpected keyword argument",
        ),
        ("SelkdEchoo-v0", "", "Did you mean"),
    ] {
        let extra: Vec<&str> = [extra].into_iter().filter(|s| !s.is_empty()).collect();
        let out = train_test_env(&dir, env, &extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{env}: {err}");
        assert!(
            err.contains(says) && err.trim().lines().count() == 1,
            "{env}: {err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
