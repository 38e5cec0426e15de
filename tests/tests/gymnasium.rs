//! End to end on Gymnasium's own envs (`run.env = "gymnasium:<id>"`, stepped in each worker's
//! embedded Python): SAC (5 000 env steps) and the quick SELKD config (K = 3) learn Pendulum-v1; a sync Hopper-v5 run whose worker and then
//! learner are SIGKILLed ends bit-identical to its twin; an exception inside the env's `step`
//! stops the run with the env's message instead of restarting the worker again and again;
//! `selkd eval`, the report's fresh-episode scoring, `export` and `render` accept a Gymnasium run,
//! and `render` draws Hopper-v5 through MuJoCo without a display.

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

/// `selkd` with the test envs of gymnasium/tests/python importable.
fn selkd_with_test_envs(args: &[&str]) -> std::process::Output {
    let mut c = std::process::Command::new(bin("selkd"));
    c.args(args).env(
        "PYTHONPATH",
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../gymnasium/tests/python"),
    );
    run(c)
}

/// Every command that steps a run's env after training, on a `gymnasium:` run: `selkd eval`, the
/// experiment report's fresh-episode scoring (the same seeds, so the same returns), `selkd
/// export`'s metadata, and `selkd render`, which draws the env's own `rgb_array` pictures.
#[test]
fn eval_report_export_and_render_accept_a_gymnasium_run() {
    let dir = temp_dir("gym-after");
    let run_dir = dir.join("sac/gymnasium:SelkdEcho-v0/seed-1");
    // A ±1.5 box (the test env's `high`): one number scales it, so `selkd export` takes it.
    let out = train_test_env(
        &run_dir,
        "SelkdEcho-v0",
        &["eval.epoch_env_steps=500", "env_options.high=1.5"],
    );
    assert_success(&out, &run_dir);
    let run_arg = run_dir.to_str().unwrap();
    let ok = |out: std::process::Output, what: &str| -> std::process::Output {
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{what}: {err}");
        out
    };

    let out = ok(
        selkd_with_test_envs(&["eval", run_arg, "--episodes", "3", "--json"]),
        "eval",
    );
    let eval: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(eval["env"], "gymnasium:SelkdEcho-v0");
    let returns = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_f64().unwrap())
            .collect()
    };
    let best = &eval["actors"][0];
    let eval_returns = returns(&best["returns"]);
    // 50 steps of −|a|², a in [−1.5, 1.5]²: never positive, never below −225.
    assert!(
        eval_returns.len() == 3 && eval_returns.iter().all(|r| (-225.0..=0.0).contains(r)),
        "{eval_returns:?}"
    );

    ok(
        selkd_with_test_envs(&[
            "experiment",
            "report",
            dir.to_str().unwrap(),
            "--episodes",
            "3",
        ]),
        "experiment report",
    );
    let fresh: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("fresh_eval.json")).unwrap())
            .unwrap();
    assert_eq!(fresh["env"], "gymnasium:SelkdEcho-v0");
    assert_eq!(fresh["actor"], best["actor"]);
    assert_eq!(fresh["seeds"], eval["seeds"]);
    assert_eq!(
        returns(&fresh["returns"]),
        eval_returns,
        "the same episodes"
    );

    let bundle = dir.join("bundle");
    ok(
        selkd_with_test_envs(&["export", run_arg, "--out", bundle.to_str().unwrap()]),
        "export",
    );
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(bundle.join("policy.json")).unwrap())
            .unwrap();
    assert_eq!(meta["env"], "gymnasium:SelkdEcho-v0");
    assert_eq!(meta["env_options"]["import"][0], "selkd_test_gym");
    assert_eq!(meta["gymnasium_action_scale"], 1.5);
    assert_eq!(
        (meta["obs_dim"].as_u64(), meta["act_dim"].as_u64()),
        (Some(4), Some(2))
    );

    // The run's actor on the run's env, 10 steps, every step drawn at 40 × 30 (the test env
    // takes width and height, as MuJoCo's do): its green counts the steps, 10 a step.
    let gif_path = dir.join("echo.gif");
    let out = ok(
        selkd_with_test_envs(&[
            "render",
            "--run",
            run_arg,
            "--steps",
            "10",
            "--size",
            "40x30",
            "--out",
            gif_path.to_str().unwrap(),
        ]),
        "render",
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("(11 frames of 40x30)") && err.contains("actor"),
        "{err}"
    );
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut d = opts
        .read_info(std::fs::File::open(&gif_path).unwrap())
        .unwrap();
    assert_eq!((d.width(), d.height()), (40, 30));
    let mut t = 0;
    while let Some(f) = d.read_next_frame().unwrap() {
        // A flat picture; NeuQuant may move a colour by a step or two.
        let green = f.buffer[1] as i32;
        assert!((green - 10 * t).abs() <= 3, "frame {t}: green {green}");
        assert!(
            f.buffer.chunks(4).all(|p| p == &f.buffer[..4]),
            "frame {t} is not flat"
        );
        t += 1;
    }
    assert_eq!(t, 11);

    // An env without rgb_array: one line that says so.
    let out = selkd_with_test_envs(&[
        "render",
        "--env",
        "gymnasium:SelkdBlind-v0",
        "--env-options",
        r#"import = ["selkd_test_gym"]"#,
        "--out",
        gif_path.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.trim()
            .lines()
            .last()
            .unwrap()
            .contains("cannot be drawn: its render modes are"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Gymnasium's own Hopper-v5 drawn by MuJoCo without a display (EGL, which `selkd render` picks
/// when nothing else is set); with a GL that cannot work headless, one line says what to install.
#[test]
fn render_draws_gymnasium_hopper_headless_or_says_what_to_install() {
    let dir = temp_dir("gym-render");
    let png_path = dir.join("hopper.png");
    let mut c = std::process::Command::new(bin("selkd"));
    c.args([
        "render",
        "--env",
        "gymnasium:Hopper-v5",
        "--steps",
        "10",
        "--every",
        "5",
    ])
    .args(["--size", "64x48", "--strip-frames", "3", "--out"])
    .arg(&png_path)
    .env_remove("DISPLAY")
    .env_remove("WAYLAND_DISPLAY")
    .env_remove("MUJOCO_GL");
    let out = run(c);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let d = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(&png_path).unwrap(),
    ));
    let mut r = d.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (3 * 64 + 2 * 2, 48));
    // A picture, not a blank: many different colours in the first frame.
    let colours: std::collections::HashSet<&[u8]> = (0..48)
        .flat_map(|y| (0..64).map(move |x| 3 * (y * (3 * 64 + 4) + x)))
        .map(|i| &buf[i..i + 3])
        .collect();
    assert!(colours.len() > 20, "{} colours", colours.len());

    let mut c = std::process::Command::new(bin("selkd"));
    c.args([
        "render",
        "--env",
        "gymnasium:Hopper-v5",
        "--steps",
        "2",
        "--out",
    ])
    .arg(&png_path)
    .env_remove("DISPLAY")
    .env_remove("WAYLAND_DISPLAY")
    .env("MUJOCO_GL", "glfw");
    let out = run(c);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    let last = err.trim().lines().last().unwrap();
    assert!(
        last.contains("no working OpenGL (MUJOCO_GL=glfw")
            && last.contains("set MUJOCO_GL=egl")
            && last.contains("MUJOCO_GL=osmesa"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `selkd.load_policy` on a `gymnasium:` run (the test env's Box [-2, 2] × [0, 1], which no one
/// scale maps onto): the package reads the Box from Gymnasium itself, and the loaded policy,
/// stepped by Python through `env_action` on `selkd eval`'s seeds, plays the evaluated episodes
/// (python/tests/test_gym_policy.py).
#[test]
fn python_loads_a_gymnasium_run_and_replays_its_evaluation() {
    let dir = temp_dir("gym-policy");
    let run_dir = dir.join("run");
    let out = train_test_env(&run_dir, "SelkdEcho-v0", &["eval.epoch_env_steps=500"]);
    assert_success(&out, &run_dir);
    let out = selkd_with_test_envs(&[
        "eval",
        run_dir.to_str().unwrap(),
        "--episodes",
        "3",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "eval: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let eval = dir.join("eval.json");
    std::fs::write(&eval, &out.stdout).unwrap();
    let test_envs = repo().join("gymnasium/tests/python");
    pytest(
        "test_gym_policy.py",
        &[
            ("SELKD_TEST_RUN", &run_dir),
            ("SELKD_TEST_EVAL", &eval),
            ("PYTHONPATH", &test_envs),
        ],
    );
    let _ = std::fs::remove_dir_all(&dir);
}
