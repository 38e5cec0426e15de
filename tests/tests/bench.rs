//! `selkd bench env` through the real binary: it steps the env it is given, with the options it
//! is given, and prints the rate; bad names and options are one-line errors.

mod common;
use common::*;
use std::process::Command;

fn bench(args: &[&str]) -> (bool, String, String) {
    let mut c = Command::new(bin("selkd"));
    c.args(["bench", "env"]).args(args);
    let out = run(c);
    let text = |b: &[u8]| String::from_utf8_lossy(b).to_string();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

/// The rate in "`X` env steps/s".
fn rate(stdout: &str) -> f64 {
    let line = stdout.lines().find(|l| l.ends_with("env steps/s")).unwrap();
    line.split_whitespace().next().unwrap().parse().unwrap()
}

#[test]
fn bench_env_steps_the_env_with_its_options() {
    // The cheetah never terminates: 2000 steps are exactly 2 episodes of 1000.
    let (ok, out, err) = bench(&["halfcheetah", "--steps", "2000"]);
    assert!(ok, "{err}");
    assert!(out.contains("halfcheetah: 2000 steps, 2 episodes"), "{out}");
    let default = rate(&out);
    assert!(default > 0.0);
    // Five times the cheetah's 5 physics steps per control step runs measurably slower (the
    // options are applied, not just parsed); the ratio is loose because machines are shared.
    let (ok, out, err) = bench(&[
        "halfcheetah",
        "--steps",
        "2000",
        "--env-options",
        "substeps = 25",
    ]);
    assert!(ok, "{err}");
    assert!(rate(&out) < 0.6 * default, "{} vs {default}", rate(&out));
    for (args, want) in [
        (
            vec!["halfcheetah", "--env-options", "substeps = 0"],
            "`substeps` must be 1 to 640",
        ),
        (
            vec!["hopper", "--env-options", "g = 1.0"],
            "unknown field `g`",
        ),
        (
            vec!["hopper", "--env-options", "substeps ="],
            "--env-options",
        ),
        (vec!["hoper"], "hoper"),
        (vec!["hopper", "--steps", "0"], "--steps must be at least 1"),
    ] {
        let (ok, _, err) = bench(&args);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    }
}

fn bench_learner(args: &[&str]) -> (bool, String, String) {
    let mut c = Command::new(bin("selkd"));
    c.args(["bench", "learner", "--rounds", "2"]).args(args);
    c.current_dir(env!("CARGO_MANIFEST_DIR")).current_dir("..");
    let out = run(c);
    let text = |b: &[u8]| String::from_utf8_lossy(b).to_string();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

/// `--config` benches the file's own sizes (configs/quick.toml: K = 3, N = 4, M = 2, G = 3, batch
/// 128, 64 × 64, Pendulum's 3 observations and 1 action) and says what its budget of critic
/// updates takes: 12 000 env steps over 3 actors, 500 rounds each of them warm-up, × G = 3.
#[test]
fn bench_learner_with_a_config_benches_its_sizes_and_prices_its_budget() {
    let (ok, out, err) = bench_learner(&["--config", "configs/quick.toml"]);
    assert!(ok, "{err}");
    assert!(
        out.contains("K=3 N=4 M=2 G=3 batch=128 obs=3 act=1 hidden=64x64 per-update fp32 on cpu"),
        "{out}"
    );
    assert!(
        out.contains(
            "configs/quick.toml: 10503 critic updates in run.total_env_steps = 12000, about "
        ),
        "{out}"
    );
    assert!(out.lines().last().unwrap().ends_with(" updates/s"), "{out}");
    // --set applies on top, as in `selkd train`: G = 5 makes 3 501 × 5 updates (the round that completes the warm-up trains too), on hopper's sizes.
    let (ok, out, err) = bench_learner(&[
        "--config",
        "configs/quick.toml",
        "--set",
        "algo.utd=5",
        "--set",
        "run.env=hopper",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("G=5 batch=128 obs=11 act=3"), "{out}");
    assert!(out.contains(": 17505 critic updates"), "{out}");
    for (args, want) in [
        (
            vec!["--config", "configs/quick.toml", "--k", "5"],
            "cannot be used with",
        ),
        (vec!["--set", "algo.utd=5"], "--config"),
        (
            vec!["--config", "configs/quick.toml", "--set", "algo.subset=9"],
            "algo.subset",
        ),
        (vec!["--config", "configs/nope.toml"], "configs/nope.toml"),
        // Sizes of zero are refused in a line, not by a panic deep in the networks.
        (vec!["--batch", "0"], "--batch must be at least 1"),
        (vec!["--hidden", "0"], "--hidden must be at least 1"),
        (vec!["--obs", "0"], "--obs must be at least 1"),
        (vec!["--g", "0"], "--g must be at least 1"),
        // Networks no machine holds (10 critics of 10⁶ × 10⁶ weights: 200 TB with their
        // gradients, Adam state and targets) are refused before libtorch tries.
        (vec!["--hidden", "1000000"], "more than this machine's"),
    ] {
        let (ok, _, err) = bench_learner(&args);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    }
    let mut c = Command::new(bin("selkd"));
    c.args(["bench", "learner", "--rounds", "0"]);
    let out = run(c);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.trim() == "selkd: error: --rounds must be at least 1",
        "{err}"
    );
}
