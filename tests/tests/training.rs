//! End to end: `selkd train` starts the real learner and actor-worker processes, which talk over
//! iceoryx2, and SELKD learns Pendulum.

mod common;
use common::*;

#[test]
fn selkd_learns_pendulum_well_beyond_a_random_policy() {
    let dir = temp_dir("learn");
    // The shipped quick config (K = 3 actors), as a user's `selkd train` runs it.
    let out = run(train(&dir, &[]));
    assert_success(&out, &dir);
    let (h, rows) = metrics(&dir);
    let k = 3;
    let last = rows.last().unwrap();
    let best_final = (0..k)
        .map(|i| {
            column(&h, &rows, &format!("eval_return_{i}"))
                .last()
                .copied()
                .unwrap()
        })
        .fold(f64::MIN, f64::max);
    let random = random_policy_return(20);
    let first_best = (0..k)
        .map(|i| column(&h, &rows, &format!("eval_return_{i}"))[0])
        .fold(f64::MIN, f64::max);
    eprintln!("random policy {random:.0}; first evaluation (best actor) {first_best:.0}; final evaluation (best actor) {best_final:.0}");
    assert!(
        random < -900.0,
        "sanity: a random policy scores about -1200 on Pendulum, got {random}"
    );
    assert!(
        best_final > random + 600.0,
        "final best evaluation {best_final:.0} is not well beyond random {random:.0}"
    );
    // The quick config's reach, measured on seeds 1-10 (README, "The shipped configs"): its best
    // actor's last evaluation was -79 to -234; -300 leaves room for another CPU's round-off.
    assert!(
        best_final >= -300.0,
        "final best evaluation {best_final:.0}: the quick config reaches -79 to -234 on seeds 1-10"
    );
    assert_eq!(
        last[h.iter().position(|c| c == "env_steps").unwrap()],
        12000.0
    );
    assert!(dir.join("checkpoints/final/model.safetensors").exists());
    assert!(dir.join("config.toml").exists());
    // The learning curve as a picture.
    let mut plot = std::process::Command::new(bin("selkd"));
    plot.arg("plot").arg(&dir);
    let out = run(plot);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let svg = std::fs::read_to_string(dir.join("returns.svg")).unwrap();
    assert_eq!(
        svg.matches("<polyline").count(),
        k + 1,
        "one curve per actor and the best"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Trains `configs/baselines/<config>` through the real processes at Pendulum's scale (5 000 env
/// steps, G = 3, 64 × 64, plus `extra` overrides) and asserts that its last evaluation beats a
/// random policy by more than 600. Returns the run directory for the method's own checks.
fn baseline_beats_random_on_pendulum(
    tag: &str,
    config: &str,
    extra: &[&str],
) -> std::path::PathBuf {
    let dir = temp_dir(tag);
    let sets: Vec<String> = [
        "run.env=pendulum",
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
    c.arg("--config").arg(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../configs/baselines")
            .join(config),
    );
    let out = run(c);
    assert_success(&out, &dir);
    let (h, rows) = metrics(&dir);
    let last = *column(&h, &rows, "eval_return_0").last().unwrap();
    let random = random_policy_return(20);
    assert!(
        last > random + 600.0,
        "{config}'s final evaluation {last:.0} is not well beyond random {random:.0}"
    );
    dir
}

/// DNS (configs/baselines/dns.toml) through the real processes, at Pendulum's scale (N = 5
/// critics of which k = 2 train per update, G = 3): it learns, and the checkpoint shows that
/// every update trained exactly k critics.
#[test]
fn dns_learns_pendulum_beyond_a_random_policy() {
    let dir = baseline_beats_random_on_pendulum(
        "dns",
        "dns.toml",
        &["algo.critics=5", "algo.trained_critics=2"],
    );
    let state: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("checkpoints/final/state.json")).unwrap(),
    )
    .unwrap();
    let steps: Vec<u64> = state["critic_member_steps"]
        .as_array()
        .expect("DNS checkpoints each critic's Adam steps")
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    let updates = state["critic_updates"].as_u64().unwrap();
    assert_eq!(steps.len(), 5);
    assert_eq!(
        steps.iter().sum::<u64>(),
        2 * updates,
        "k = 2 critics per update: {steps:?}"
    );
    assert!(
        steps.iter().all(|&s| s > 0 && s < updates),
        "{steps:?} of {updates}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// AVTD (configs/baselines/avtd.toml) through the real processes, at Pendulum's scale (each of
/// the three variants with N = 3 critics, G = 3): it learns, the checkpoint holds one actor per
/// variant, and the run's policy (what `selkd eval` and `selkd export` take) is the selected one.
#[test]
fn avtd_learns_pendulum_beyond_a_random_policy() {
    let dir = baseline_beats_random_on_pendulum("avtd", "avtd.toml", &["algo.critics=3"]);
    let model = read_safetensors(&dir.join("checkpoints/final/model.safetensors"));
    assert_eq!(model["actors.0.weight"].0[0], 3, "one actor per variant");
    assert_eq!(
        model["critics.0.weight"].0[0], 9,
        "three critics per variant"
    );
    let state: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("checkpoints/final/state.json")).unwrap(),
    )
    .unwrap();
    let selected = state["selected_variant"]
        .as_u64()
        .expect("AVTD checkpoints its selection");
    assert!(selected < 3);
    // The run's policy is the selected variant's actor.
    let bundle = dir.join("bundle");
    let mut export = std::process::Command::new(bin("selkd"));
    export.arg("export").arg(&dir).arg("--out").arg(&bundle);
    let out = run(export);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(bundle.join("policy.json")).unwrap())
            .unwrap();
    assert_eq!(meta["actor"].as_u64(), Some(selected), "{meta}");
    assert_eq!(meta["best_actor"].as_u64(), Some(selected));
    assert_eq!(meta["actors"].as_u64(), Some(3));
    assert!(meta["score"].is_number(), "{meta}");
    // Python's loader agrees: the run's "best" is the selected variant, the bundle's actor.
    let check = format!(
        "import selkd, torch\n\
         p = selkd.load_policy({run:?})\n\
         assert p.metadata['actor'] == {selected}, p.metadata\n\
         assert p.metadata['score'] is not None\n\
         other = selkd.load_policy({run:?}, actor={other})\n\
         assert other.metadata['score'] is None\n\
         x = torch.randn(16, 3)\n\
         assert torch.equal(p(x), selkd.load_policy({bundle:?})(x))\n",
        run = dir.display().to_string(),
        bundle = bundle.display().to_string(),
        other = (selected + 1) % 3,
    );
    let mut py = std::process::Command::new(python());
    py.arg("-c").arg(check);
    let out = run(py);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_config_gets_a_one_line_error_and_no_run() {
    let dir = temp_dir("badcfg");
    for (set, key) in [
        ("algo.subset=20", "algo.subset"),
        ("algo.actors=0", "algo.actors"),
        ("run.env=humanoidd", "pendulum"),
        ("algo.batch_size=-5", "batch_size"),
    ] {
        let out = run(train(&dir.join("x"), &["--set".into(), set.into()]));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{set}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{set}: one line, got {err}");
        assert!(
            err.contains(key) && !err.contains("panicked"),
            "{set}: {err}"
        );
    }
    assert!(
        !dir.join("x").exists(),
        "no run directory for a rejected config"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn async_mode_holds_the_update_to_insert_ratio_and_bounds_policy_lag() {
    let dir = temp_dir("async");
    let sets = small_run(&[
        "algo.actors=2",
        "run.mode=async",
        "run.total_env_steps=4000",
        "algo.utd=2",
        "async.max_policy_lag=3",
        "async.ratio_tolerance=20",
    ]);
    let out = run(train(&dir, &sets));
    assert_success(&out, &dir);
    let progress = log(&dir, "progress.jsonl");
    let last: serde_json::Value = serde_json::from_str(progress.lines().last().unwrap()).unwrap();
    let (ratio, target) = (
        last["updates_per_transition"].as_f64().unwrap(),
        last["target_updates_per_transition"].as_f64().unwrap(),
    );
    eprintln!("async: {ratio:.3} critic updates per transition (target {target}), policy lag mean {} max {}", last["policy_lag_mean"], last["policy_lag_max"]);
    assert_eq!(target, 1.0, "G/K = 2/2");
    // The learner may trail by at most the tolerance (20 updates over 3600 post-warm-up transitions).
    assert!(
        (ratio - target).abs() <= 0.02 * target,
        "update ratio {ratio} strays from {target}: {last}"
    );
    // A worker starts a step only with weights at most 3 versions behind the learner's latest
    // broadcast, which may trail the learner by the round in training. While the transition is
    // in flight the learner may work off the rounds it owes: at most the tolerance (10 rounds of
    // G = 2) and the warm-up's one. (This once asserted 3 + 1, which holds only while no worker is
    // descheduled between its check and its send; the test failed once in CI, whose output did
    // not say which assertion.) The mean shows the usual case: the check at each step.
    let (lag_max, lag_mean) = (
        last["policy_lag_max"].as_u64().unwrap(),
        last["policy_lag_mean"].as_f64().unwrap(),
    );
    assert!(
        lag_max <= 3 + 1 + 10 + 1,
        "policy lag max {lag_max}: {last}"
    );
    assert!(lag_mean <= 3.0, "policy lag mean {lag_mean}: {last}");
    assert_eq!(last["env_steps"].as_u64(), Some(4000));
    let (h, rows) = metrics(&dir);
    assert_eq!(rows.len(), 4, "one metrics row per epoch");
    let updates = *column(&h, &rows, "critic_updates").last().unwrap();
    assert!(updates > 3000.0, "{updates} critic updates: {last}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn fpc_assembly_trains_end_to_end_and_reports_success_rates() {
    // The 3C assembly task through the real processes, with a tightened tolerance from
    // [env_options]: every evaluation row carries each actor's success rate, and it plots.
    let dir = temp_dir("fpc");
    let sets = small_run(&[
        "run.env=fpc-assembly",
        "env_options.lateral_tol_mm=0.08",
        "algo.actors=2",
        "run.total_env_steps=2000",
        "eval.episodes=2",
    ]);
    let out = run(train(&dir, &sets));
    assert_success(&out, &dir);
    let (h, rows) = metrics(&dir);
    assert_eq!(rows.len(), 2, "one metrics row per epoch");
    for i in 0..2 {
        for rate in column(&h, &rows, &format!("eval_success_{i}")) {
            assert!(
                rate == 0.0 || rate == 0.5 || rate == 1.0,
                "success rate of 2 episodes: {rate}"
            );
        }
    }
    let config = std::fs::read_to_string(dir.join("config.toml")).unwrap();
    assert!(config.contains("lateral_tol_mm = 0.08"), "{config}");
    let mut plot = std::process::Command::new(bin("selkd"));
    plot.arg("plot").arg(&dir).args(["--metric", "success"]);
    let out = run(plot);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dir.join("success.svg").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_locomotion_task_trains_through_the_real_processes_without_losing_data() {
    // Two actors on each physics task: KD is on, and the humanoid's observation holds values in
    // the thousands (contact forces), which once made NaN weights and NaN actions. Every
    // transition must be stored and the losses must stay finite.
    for env in [
        "hopper",
        "walker2d",
        "halfcheetah",
        "ant-contacts",
        "humanoid",
    ] {
        let dir = temp_dir(env);
        let sets = small_run(&[
            &format!("run.env={env}"),
            "algo.actors=2",
            "algo.hidden=[64,64]",
            "run.total_env_steps=1200",
        ]);
        let out = run(train(&dir, &sets));
        assert_success(&out, &dir);
        let (h, rows) = metrics(&dir);
        assert!(!rows.is_empty(), "{env}: no metrics rows");
        assert!(
            column(&h, &rows, "dropped").iter().all(|&d| d == 0.0),
            "{env}: transitions dropped: {}",
            log(&dir, "learner.log")
        );
        for col in [
            "critic_loss",
            "q_mean",
            "alpha_0",
            "alpha_1",
            "eval_return_0",
        ] {
            let v = column(&h, &rows, col);
            assert!(v.iter().all(|x| x.is_finite()), "{env}: {col} = {v:?}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// The K sweep's K = 3 with the paper's 1000-step epochs: each epoch ends at the first round
/// boundary (a multiple of K = 3 env steps) at or past each multiple of 1000, which the metrics'
/// `env_steps` column records: 1002, 2001, then the budget, 3000. Every actor is evaluated every
/// epoch on the same episode seeds (common random numbers), so two actors with equal weights would
/// tie; here we check each epoch has every actor's evaluation.
#[test]
fn any_k_evaluates_at_the_first_round_boundary_past_each_epoch() {
    let dir = temp_dir("k3-epochs");
    let sets = small_run(&["algo.actors=3", "run.total_env_steps=3000"]);
    assert_success(&run(train(&dir, &sets)), &dir);
    let (h, rows) = metrics(&dir);
    assert_eq!(column(&h, &rows, "epoch"), vec![1.0, 2.0, 3.0]);
    assert_eq!(column(&h, &rows, "env_steps"), vec![1002.0, 2001.0, 3000.0]);
    for i in 0..3 {
        assert!(
            column(&h, &rows, &format!("eval_return_{i}"))
                .iter()
                .all(|v| v.is_finite()),
            "actor {i} evaluated every epoch"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
