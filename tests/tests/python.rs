//! The `selkd` Python package (python/, built into the project venv by deploy/python.sh) through
//! its real pieces: Gymnasium's own checker on every env, episodes through Python against the
//! same episodes stepped here in Rust, a policy trained by the real binaries and exported by
//! `selkd export --onnx`, loaded in PyTorch and ONNX Runtime and checked against the Rust actor,
//! and Stable-Baselines3's SAC learning one of our envs. The Python halves are
//! python/tests/test_*.py (pytest), each run here with the data it checks against.

mod common;
use common::*;
use rand::{Rng, SeedableRng};
use serde_json::json;
use std::process::Command;

#[test]
fn every_env_passes_gymnasium_checks_and_bad_input_is_a_python_error() {
    pytest("test_envs.py", &[]);
}

/// Each env, 120 steps from seed 7 with fixed actions, stepped here through the Rust crate:
/// Python must give the same observations and rewards to the bit, and the same flags.
#[test]
fn python_gives_the_rust_episodes_bit_for_bit() {
    let dir = temp_dir("python-episodes");
    let mut episodes = vec![];
    for name in selkd_envs::names() {
        let mut env = selkd_envs::make(name).unwrap();
        let n = env.spec().act_dim;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let mut steps = vec![];
        let first = env.reset(Some(7));
        for _ in 0..120 {
            let a: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0f32..1.0)).collect();
            let s = env.step(&a);
            steps.push(json!({
                "action": a,
                "obs_bits": s.obs.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                "reward_bits": s.reward.to_bits().to_string(),
                "terminated": s.terminated,
                "truncated": s.truncated,
                "success": s.success,
            }));
            if s.terminated || s.truncated {
                break;
            }
        }
        episodes.push(json!({
            "env": name,
            "seed": 7,
            "first_obs_bits": first.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            "steps": steps,
        }));
    }
    let file = dir.join("episodes.json");
    std::fs::write(&file, serde_json::to_string(&episodes).unwrap()).unwrap();
    pytest("test_same_episode.py", &[("SELKD_TEST_EPISODES", &file)]);
}

/// A Pendulum run of the quick config, exported with `--onnx`; the Rust actor's actions on 64
/// observations, for the module and the ONNX file to match.
#[test]
fn a_trained_policy_loads_in_pytorch_and_onnx_and_plays_gymnasiums_pendulum() {
    let dir = temp_dir("python-policy");
    let run_dir = dir.join("run");
    let mut c = Command::new(bin("selkd"));
    c.args(["train", "--config"])
        .arg(repo().join("configs/quick.toml"))
        .arg("--run-dir")
        .arg(&run_dir);
    let out = run(c);
    assert_success(&out, &run_dir);

    let bundle = dir.join("bundle");
    let mut c = Command::new(bin("selkd"));
    c.arg("export")
        .arg(&run_dir)
        .arg("--out")
        .arg(&bundle)
        .arg("--onnx")
        .env("SELKD_PYTHON", python());
    let out = run(c);
    assert!(
        out.status.success(),
        "selkd export failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in ["policy.json", "policy.safetensors", "policy.onnx"] {
        assert!(bundle.join(f).exists(), "the bundle has no {f}");
    }

    // The Rust actor (selkd_policy, what the workers and `selkd eval` act with), built from the
    // checkpoint's stacked tensors.
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(bundle.join("policy.json")).unwrap())
            .unwrap();
    let actor_index = meta["actor"].as_u64().unwrap() as usize;
    let tensors = read_safetensors(&run_dir.join("checkpoints/final/model.safetensors"));
    let mut flat = vec![];
    let mut dims = vec![];
    let mut l = 0;
    while let Some((shape, w)) = tensors.get(&format!("actors.{l}.weight")) {
        let (_, b) = &tensors[&format!("actors.{l}.bias")];
        let (n_in, n_out) = (shape[1], shape[2]);
        flat.extend_from_slice(&w[actor_index * n_in * n_out..(actor_index + 1) * n_in * n_out]);
        flat.extend_from_slice(&b[actor_index * n_out..(actor_index + 1) * n_out]);
        dims.push((n_in, n_out));
        l += 1;
    }
    let hidden: Vec<usize> = dims[1..].iter().map(|d| d.0).collect();
    let layout = selkd_policy::ActorLayout::new(dims[0].0, dims.last().unwrap().1 / 2, &hidden);
    let actor = selkd_policy::Actor::from_flat(layout, flat).unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let cases: Vec<_> = (0..64)
        .map(|_| {
            let th: f32 = rng.gen_range(-3.2..3.2);
            let obs = vec![th.cos(), th.sin(), rng.gen_range(-8.0..8.0)];
            let action = actor.mean_action(&obs);
            json!({"obs": obs, "action": action})
        })
        .collect();
    let file = dir.join("actions.json");
    std::fs::write(&file, serde_json::to_string(&cases).unwrap()).unwrap();
    pytest(
        "test_policy.py",
        &[
            ("SELKD_TEST_RUN", &run_dir),
            ("SELKD_TEST_BUNDLE", &bundle),
            ("SELKD_TEST_ACTIONS", &file),
        ],
    );
}

#[test]
fn stable_baselines3_sac_learns_selkd_pendulum() {
    pytest("test_sb3.py", &[]);
}

/// `selkd export`'s mistakes: one line each, exit 2.
#[test]
fn export_errors_are_one_line() {
    let dir = temp_dir("python-export-errors");
    let run_dir = dir.join("run");
    let sets = small_run(&["algo.actors=3", "run.total_env_steps=600"]);
    assert_success(&run(train(&run_dir, &sets)), &run_dir);
    let cases: &[(&[&str], &str)] = &[
        (&["--actor", "7"], "--actor 7: the checkpoint has 3 actors"),
        (
            &["--actor", "x"],
            "--actor x: expected best or an actor index",
        ),
    ];
    for (extra, want) in cases {
        let mut c = Command::new(bin("selkd"));
        c.arg("export")
            .arg(&run_dir)
            .args(["--out"])
            .arg(dir.join("b"))
            .args(*extra);
        let out = run(c);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(
            err.contains(want) && err.trim().lines().count() == 1,
            "{extra:?}: {err}"
        );
    }
    let mut c = Command::new(bin("selkd"));
    c.arg("export")
        .arg(dir.join("nope"))
        .args(["--out"])
        .arg(dir.join("b"));
    let out = run(c);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no such run or checkpoint directory") && out.status.code() == Some(2),
        "{err}"
    );
    let mut c = Command::new(bin("selkd"));
    c.arg("export")
        .arg(&run_dir)
        .args(["--out"])
        .arg(dir.join("b"))
        .arg("--onnx")
        .env("SELKD_PYTHON", dir.join("no-python"));
    let out = run(c);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--onnx") && err.trim().lines().count() == 1 && out.status.code() == Some(2),
        "{err}"
    );
}
