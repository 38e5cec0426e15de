//! `selkd eval` through the real binary: a tiny trained run evaluated per actor, checked against
//! an evaluation done here from the checkpoint's raw tensors (its own safetensors reader and MLP,
//! and the env crate), against the checkpoint's ranking, and for one-line errors on bad input.

mod common;
use common::*;
use serde_json::Value;
use std::collections::HashMap;
use std::process::{Command, Output};

fn eval(args: &[&str]) -> Output {
    let mut c = Command::new(bin("selkd"));
    c.arg("eval").args(args);
    run(c)
}

fn eval_json(args: &[&str]) -> Value {
    let out = eval(args);
    assert!(
        out.status.success(),
        "selkd eval {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("--json prints one JSON object")
}

/// Actor `i`'s deterministic action tanh(μ(obs)) from the stacked tensors `actors.{l}.weight`
/// `[K, in, out]` and `actors.{l}.bias` `[K, 1, out]`; ReLU between layers; the head is μ then
/// log σ.
fn mean_action(t: &HashMap<String, (Vec<usize>, Vec<f32>)>, i: usize, obs: &[f32]) -> Vec<f32> {
    let mut x: Vec<f64> = obs.iter().map(|&v| v as f64).collect();
    let mut l = 0;
    while let Some((shape, w)) = t.get(&format!("actors.{l}.weight")) {
        let (_, b) = &t[&format!("actors.{l}.bias")];
        let (n_in, n_out) = (shape[1], shape[2]);
        let w = &w[i * n_in * n_out..(i + 1) * n_in * n_out];
        let b = &b[i * n_out..(i + 1) * n_out];
        let mut y: Vec<f64> = (0..n_out)
            .map(|o| {
                b[o] as f64
                    + (0..n_in)
                        .map(|k| x[k] * w[k * n_out + o] as f64)
                        .sum::<f64>()
            })
            .collect();
        l += 1;
        if t.contains_key(&format!("actors.{l}.weight")) {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        x = y;
    }
    let act = x.len() / 2;
    x[..act].iter().map(|m| m.tanh() as f32).collect()
}

#[test]
fn eval_reports_every_actor_on_the_runs_env_and_matches_an_independent_evaluation() {
    let dir = temp_dir("eval");
    let run_dir = dir.join("run");
    let sets = small_run(&[
        "algo.actors=3",
        "run.total_env_steps=1500",
        "eval.epoch_env_steps=600",
        // A non-default env option: eval must play the run's env, not the default one.
        "env_options.g=12.0",
    ]);
    let out = run(train(&run_dir, &sets));
    assert_success(&out, &run_dir);
    let run_arg = run_dir.to_str().unwrap();

    let all = eval_json(&[run_arg, "--actor", "all", "--episodes", "3", "--json"]);
    let actors = all["actors"].as_array().unwrap();
    assert_eq!(actors.len(), 3, "--actor all: one entry per actor");
    assert_eq!(all["env"], "pendulum");
    assert_eq!(all["episodes"], 3);

    // The best actor is the checkpoint ranking's argmax (latest evaluation, else the mean of the
    // training episodes; ties to the lower index), recomputed here from state.json.
    let state: Value = serde_json::from_str(
        &std::fs::read_to_string(run_dir.join("checkpoints/final/state.json")).unwrap(),
    )
    .unwrap();
    let ranking = &state["ranking"];
    let scores: Vec<Option<f64>> = (0..3)
        .map(|i| {
            ranking["evaluation"][i].as_f64().or_else(|| {
                let t: Vec<f64> = ranking["training"][i]
                    .as_array()?
                    .iter()
                    .filter_map(Value::as_f64)
                    .collect();
                (!t.is_empty()).then(|| t.iter().sum::<f64>() / t.len() as f64)
            })
        })
        .collect();
    let mut want_best = 0;
    for i in 0..3 {
        if let Some(s) = scores[i] {
            if scores[want_best].is_none_or(|b| s > b) {
                want_best = i;
            }
        }
    }
    assert_eq!(all["best"], want_best, "scores {scores:?}");
    for (i, a) in actors.iter().enumerate() {
        assert_eq!(a["actor"], i);
        assert_eq!(a["best"], i == want_best);
    }

    // An independent evaluation: the checkpoint's tensors read and run here, on Pendulum with the
    // run's g, on the seeds eval reports.
    let tensors = read_safetensors(&run_dir.join("checkpoints/final/model.safetensors"));
    let opts: selkd_envs::EnvOptions = serde_json::from_str(r#"{"g": 12.0}"#).unwrap();
    let mut env = selkd_envs::make_with("pendulum", &opts).unwrap();
    let seeds: Vec<u64> = all["seeds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s.as_u64().unwrap())
        .collect();
    assert_eq!(seeds.len(), 3);
    for (i, a) in actors.iter().enumerate() {
        let returns: Vec<f64> = a["returns"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_f64().unwrap())
            .collect();
        for (e, &seed) in seeds.iter().enumerate() {
            let mut obs = env.reset(Some(seed));
            let (mut total, mut length) = (0.0, 0);
            loop {
                let s = env.step(&mean_action(&tensors, i, &obs));
                total += s.reward;
                length += 1;
                if s.terminated || s.truncated {
                    break;
                }
                obs = s.obs;
            }
            assert_eq!(a["lengths"][e], length, "actor {i} episode {e}");
            // f64 here, f32 in the policy crate: the same episode up to round-off.
            assert!(
                (returns[e] - total).abs() <= 1e-3 * total.abs().max(1.0),
                "actor {i} episode {e}: eval {} vs here {total}",
                returns[e]
            );
        }
        let mean = returns.iter().sum::<f64>() / 3.0;
        let std = (returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / 2.0).sqrt();
        assert!((a["mean_return"].as_f64().unwrap() - mean).abs() < 1e-9);
        assert!((a["std_return"].as_f64().unwrap() - std).abs() < 1e-9);
        assert!(a["success_rate"].is_null(), "Pendulum has no success");
    }

    // The same seeds give the same numbers; the default picks the best actor; --seed changes
    // the episodes, and an index picks that actor.
    let again = eval_json(&[run_arg, "--actor", "all", "--episodes", "3", "--json"]);
    assert_eq!(again, all);
    let best = eval_json(&[run_arg, "--episodes", "3", "--json"]);
    assert_eq!(best["actors"].as_array().unwrap().len(), 1);
    assert_eq!(best["actors"][0], actors[want_best]);
    let seeded = eval_json(&[
        run_arg,
        "--actor",
        "1",
        "--episodes",
        "3",
        "--seed",
        "7",
        "--json",
    ]);
    assert_eq!(seeded["seeds"], serde_json::json!([7, 8, 9]));
    assert_eq!(seeded["actors"][0]["actor"], 1);
    assert_ne!(seeded["actors"][0]["returns"], actors[1]["returns"]);
    // A checkpoint directory works as well as the run directory.
    let ckpt = run_dir.join("checkpoints/final");
    let from_ckpt = eval_json(&[
        ckpt.to_str().unwrap(),
        "--actor",
        "all",
        "--episodes",
        "3",
        "--json",
    ]);
    assert_eq!(from_ckpt["actors"], all["actors"]);
    // The env is the one the run trained on: nothing to report.
    assert_eq!(all["env_changes_since_training"], serde_json::json!([]));

    // --env-options replaces the run's g for the replay (and only for it): the same actor on the
    // same seeds, played here at g = 9, gives eval's numbers; the run's own options are the
    // default again afterwards.
    let light = eval_json(&[
        run_arg,
        "--actor",
        "0",
        "--episodes",
        "2",
        "--env-options",
        "g = 9.0",
        "--json",
    ]);
    assert_eq!(light["env_options"], serde_json::json!({"g": 9.0}));
    // ... and says how that env differs from the one the policy trained on.
    let changes = light["env_changes_since_training"].as_array().unwrap();
    assert_eq!(changes[0], "options: g = 12.0 → g = 9.0", "{changes:?}");
    assert!(
        changes[1].as_str().unwrap().starts_with("rollout: "),
        "{changes:?}"
    );
    let opts9: selkd_envs::EnvOptions = serde_json::from_str(r#"{"g": 9.0}"#).unwrap();
    let mut env9 = selkd_envs::make_with("pendulum", &opts9).unwrap();
    for (e, seed) in light["seeds"].as_array().unwrap().iter().enumerate() {
        let mut obs = env9.reset(Some(seed.as_u64().unwrap()));
        let mut total = 0.0;
        loop {
            let s = env9.step(&mean_action(&tensors, 0, &obs));
            total += s.reward;
            if s.terminated || s.truncated {
                break;
            }
            obs = s.obs;
        }
        let got = light["actors"][0]["returns"][e].as_f64().unwrap();
        assert!(
            (got - total).abs() <= 1e-3 * total.abs().max(1.0),
            "episode {e} at g = 9: eval {got} vs here {total}"
        );
    }
    assert_ne!(light["actors"][0]["returns"], actors[0]["returns"]);
    let out = eval(&[run_arg, "--episodes", "1", "--env-options", r#"{"g": 9.0}"#]);
    assert!(out.status.success());
    let note = String::from_utf8_lossy(&out.stderr);
    assert!(
        note.contains("not the one the policy trained on (options: g = 12.0 → g = 9.0; rollout: "),
        "{note}"
    );
    let header = String::from_utf8_lossy(&out.stdout);
    assert!(header.contains("env pendulum (g = 9.0)"), "{header}");

    // The table: a row per actor, the best marked.
    let out = eval(&[run_arg, "--actor", "all", "--episodes", "2"]);
    assert!(out.status.success());
    let table = String::from_utf8_lossy(&out.stdout);
    let rows: Vec<&str> = table
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .collect();
    assert_eq!(rows.len(), 3, "{table}");
    assert!(
        rows.iter().all(|r| r.contains(" ± ")),
        "mean ± std with 2 episodes: {table}"
    );
    assert!(table.contains(&format!("{want_best} (best)")), "{table}");

    // Bad input: exit 2, one line, saying what to change.
    let model = ckpt.join("model.safetensors");
    for (args, says) in [
        (vec![run_arg, "--actor", "7"], "the checkpoint has 3 actors"),
        (
            vec![run_arg, "--actor", "worst"],
            "best, all or an actor index",
        ),
        (
            vec![run_arg, "--episodes", "0"],
            "--episodes must be at least 1",
        ),
        (vec!["/no/such/run"], "no such run or checkpoint directory"),
        (
            vec![model.to_str().unwrap()],
            "pass its checkpoint directory",
        ),
        (vec![dir.to_str().unwrap()], "neither a run directory"),
        (vec![run_arg, "--env-options", "gravity = 1.0"], "gravity"),
        (
            vec![run_arg, "--env-options", "{g: 1"],
            "--env-options is not a JSON",
        ),
    ] {
        let out = eval(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
        assert_eq!(
            err.trim_end().lines().count(),
            1,
            "{args:?}: one line: {err}"
        );
        assert!(out.stdout.is_empty());
    }
    let _ = std::fs::remove_dir_all(&dir);
}
