//! End to end: a run's TensorBoard events (`RUN/tb/`), read back with TensorBoard's own reader,
//! hold each epoch's metrics at its env steps, as metrics.csv has them, per actor; the live
//! scalars appear too; and a run stopped and resumed has one value per epoch (the resumed file
//! supersedes what the stopped run wrote past its checkpoint).

mod common;
use common::*;
use std::path::{Path, PathBuf};

/// Where `deploy/test-deps.sh` installs TensorBoard (its cache path, computed the same way).
fn tensorboard_dir() -> PathBuf {
    let dir = cache_dir().join("tensorboard-2.21.0");
    assert!(
        dir.join(".complete").exists(),
        "TensorBoard is not installed at {}: run `bash deploy/test-deps.sh` (deploy/test.sh does)",
        dir.display()
    );
    dir
}

type Scalars = std::collections::BTreeMap<String, Vec<(u64, f64)>>;

fn read_events(run: &Path) -> Scalars {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/read_tensorboard.py");
    let out = std::process::Command::new("python3")
        .arg(script)
        .arg(run.join("tb"))
        .env("PYTHONPATH", tensorboard_dir())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "reading the events: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: std::collections::BTreeMap<String, Vec<(f64, f64)>> =
        serde_json::from_slice(&out.stdout).unwrap();
    v.into_iter()
        .map(|(k, pts)| (k, pts.into_iter().map(|(s, x)| (s as u64, x)).collect()))
        .collect()
}

/// Every epoch column of metrics.csv that TensorBoard shows, compared at each epoch's env steps
/// (as f32, the type TensorBoard stores).
fn assert_matches_metrics(run: &Path, tb: &Scalars, k: usize) {
    let (h, rows) = metrics(run);
    let steps: Vec<u64> = column(&h, &rows, "env_steps")
        .iter()
        .map(|&s| s as u64)
        .collect();
    let mut pairs = vec![
        ("critic_loss".to_string(), "train/critic_loss".to_string()),
        ("q_mean".into(), "train/q_mean".into()),
        ("best".into(), "eval/best".into()),
        ("critic_updates".into(), "train/critic_updates".into()),
    ];
    for i in 0..k {
        pairs.push((format!("eval_return_{i}"), format!("eval/return_{i}")));
        pairs.push((format!("score_{i}"), format!("eval/score_{i}")));
        pairs.push((format!("alpha_{i}"), format!("train/alpha_{i}")));
        pairs.push((format!("kl_to_best_{i}"), format!("train/kl_to_best_{i}")));
    }
    for (col, tag) in pairs {
        let want: Vec<(u64, f64)> = steps.iter().copied().zip(column(&h, &rows, &col)).collect();
        let got = tb
            .get(&tag)
            .unwrap_or_else(|| panic!("no {tag}; tags: {:?}", tb.keys()));
        assert_eq!(got.len(), want.len(), "{tag}: {got:?} vs metrics {want:?}");
        for (&(gs, gv), &(ws, wv)) in got.iter().zip(&want) {
            assert_eq!(gs, ws, "{tag}: steps");
            // metrics.csv prints 6 decimals; TensorBoard keeps f32.
            let tol = 1e-6 * wv.abs().max(1.0) + 5e-7;
            assert!(
                (gv - wv).abs() <= tol,
                "{tag} at {gs}: {gv} vs metrics {wv}"
            );
        }
    }
}

#[test]
fn tensorboard_events_hold_the_metrics_and_survive_a_resume() {
    let dir = temp_dir("tensorboard");
    let sets = small_run(&["algo.actors=2", "run.total_env_steps=3000"]);
    assert_success(&run(train(&dir, &sets)), &dir);
    let tb = read_events(&dir);
    assert_matches_metrics(&dir, &tb, 2);
    for tag in ["live/critic_loss", "live/updates_per_s", "live/alpha_1"] {
        assert!(
            tb.get(tag).is_some_and(|v| !v.is_empty()),
            "no {tag}: {:?}",
            tb.keys()
        );
    }

    // Stop at about 1500 steps, then resume to 3000: one value per epoch, as metrics.csv.
    let resumed = temp_dir("tensorboard-resume");
    let long = small_run(&["algo.actors=2", "run.total_env_steps=1000000"]);
    let mut child = spawn(train(&resumed, &long));
    let t0 = std::time::Instant::now();
    while env_steps_so_far(&resumed) < 1500 {
        assert!(t0.elapsed().as_secs() < 120, "no progress");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    assert_eq!(child.wait().unwrap().code(), Some(143));
    let mut more = vec![
        "train".to_string(),
        "--resume".into(),
        resumed.display().to_string(),
    ];
    more.extend(["--set".into(), "run.total_env_steps=3000".into()]);
    let mut c = std::process::Command::new(bin("selkd"));
    c.args(&more);
    assert_success(&run(c), &resumed);
    let files = std::fs::read_dir(resumed.join("tb")).unwrap().count();
    assert_eq!(files, 2, "one event file per learner process");
    assert_matches_metrics(&resumed, &read_events(&resumed), 2);
    for d in [dir, resumed] {
        let _ = std::fs::remove_dir_all(d);
    }
}
