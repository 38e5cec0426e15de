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
            "`substeps` must be 1 to 64",
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
    ] {
        let (ok, _, err) = bench(&args);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    }
}
