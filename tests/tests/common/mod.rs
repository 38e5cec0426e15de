//! Helpers for the end-to-end tests: find the built binaries, run `selkd train`, read run outputs.
#![allow(dead_code)]

pub mod report_check;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStderr, Command, Output, Stdio};

/// A binary of this workspace, built in the same profile as the tests (`cargo build --release`).
pub fn bin(name: &str) -> PathBuf {
    let dir = std::env::current_exe()
        .unwrap()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    let p = dir.join(name);
    assert!(
        p.exists(),
        "{} is missing: run `cargo build --release --workspace` before the tests",
        p.display()
    );
    p
}

/// The venv's interpreter, found as `selkd export --onnx` finds it: `SELKD_PYTHON`, else the
/// venv deploy/python.sh makes (`SELKD_PYTHON_VENV`, else `python-venv` in the cache).
pub fn python() -> PathBuf {
    let p = std::env::var_os("SELKD_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            std::env::var_os("SELKD_PYTHON_VENV")
                .map(PathBuf::from)
                .unwrap_or_else(|| cache_dir().join("python-venv"))
                .join("bin/python")
        });
    assert!(
        p.exists(),
        "{} is missing: run `bash deploy/python.sh` (deploy/test.sh does) before the tests",
        p.display()
    );
    p
}

/// The per-user cache the set-up scripts install into (libtorch, TensorBoard, the Python venv),
/// computed as they compute it: `SELKD_CACHE`, else `XDG_CACHE_HOME/selkd`, else `~/.cache/selkd`.
pub fn cache_dir() -> PathBuf {
    std::env::var_os("SELKD_CACHE")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("XDG_CACHE_HOME").map(|c| PathBuf::from(c).join("selkd")))
        .unwrap_or_else(|| PathBuf::from(std::env::var("HOME").unwrap()).join(".cache/selkd"))
}

/// The workspace's root (python/, configs/, gymnasium/tests/python).
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Runs one pytest file of python/tests with `vars` in its environment; fails with its output.
pub fn pytest(file: &str, vars: &[(&str, &Path)]) {
    let mut c = Command::new(python());
    c.args([
        "-m",
        "pytest",
        "-q",
        "-p",
        "no:cacheprovider",
        "-W",
        "ignore::DeprecationWarning",
    ])
    .arg(repo().join("python/tests").join(file))
    .current_dir(repo())
    .env("OMP_NUM_THREADS", "1");
    for (k, v) in vars {
        c.env(k, v);
    }
    let out = c.output().expect("starting python");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "pytest {file} failed:\n{text}");
    eprintln!("{}", text.lines().last().unwrap_or(""));
}

pub fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("selkd-test-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A small, fast run on Pendulum for tests.
pub fn small_run(extra: &[&str]) -> Vec<String> {
    let mut sets: Vec<String> = [
        "run.threads=1",
        "algo.hidden=[32,32]",
        "algo.critics=2",
        "algo.utd=1",
        "algo.batch_size=64",
        "algo.warmup_steps=400",
        "eval.epoch_env_steps=1000",
        "eval.episodes=1",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    sets.extend(extra.iter().map(|s| s.to_string()));
    sets.iter()
        .flat_map(|s| ["--set".to_string(), s.clone()])
        .collect()
}

pub fn train(run_dir: &Path, sets: &[String]) -> Command {
    let mut c = Command::new(bin("selkd"));
    c.arg("train").arg("--run-dir").arg(run_dir).args(sets);
    c
}

/// Starts `c`, which dies with the test that started it (the test's thread, which is what
/// `PR_SET_PDEATHSIG` watches): a test that fails midway leaves no run behind (a launcher's
/// learner and workers die with it).
pub fn spawn(mut c: Command) -> Child {
    use std::os::unix::process::CommandExt;
    unsafe {
        c.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    c.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

pub fn run(mut c: Command) -> Output {
    c.stdin(Stdio::null()).output().unwrap()
}

/// metrics.csv as (header, rows).
pub fn metrics(run_dir: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(run_dir.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.parse::<f64>().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    (header, rows)
}

pub fn column(header: &[String], rows: &[Vec<f64>], name: &str) -> Vec<f64> {
    let i = header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    rows.iter().map(|r| r[i]).collect()
}

pub fn log(run_dir: &Path, name: &str) -> String {
    std::fs::read_to_string(run_dir.join("logs").join(name)).unwrap_or_default()
}

pub fn assert_success(out: &Output, run_dir: &Path) {
    assert!(
        out.status.success(),
        "selkd train failed ({}):\n{}\n--- learner.log ---\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr),
        log(run_dir, "learner.log")
    );
}

/// Pids of the processes whose command line (arguments joined by NUL) satisfies `pred`.
fn pids_where(pred: impl Fn(&str) -> bool) -> Vec<i32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<i32>().ok())
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/cmdline"))
                .is_ok_and(|c| pred(&String::from_utf8_lossy(&c)))
        })
        .collect()
}

/// Pids of this run's actor-worker processes for `worker`, from /proc.
pub fn worker_pids(run_id: &str, worker: usize) -> Vec<i32> {
    let want = format!("--run-id\0{run_id}\0--worker\0{worker}\0");
    pids_where(|c| c.contains(&want))
}

/// Pid of this run's learner process.
pub fn learner_pid(run_id: &str) -> Option<i32> {
    let want = format!("--run-id\0{run_id}\0");
    pids_where(|c| {
        c.split('\0')
            .next()
            .is_some_and(|exe| exe.ends_with("/learner"))
            && c.contains(&want)
    })
    .first()
    .copied()
}

/// The run id from `selkd train`'s first stderr line; the rest of stderr is left to read.
pub fn run_id(child: &mut Child) -> (String, BufReader<ChildStderr>) {
    let mut stderr = BufReader::new(child.stderr.take().unwrap());
    let mut first = String::new();
    stderr.read_line(&mut first).unwrap();
    let id = first
        .split_whitespace()
        .nth(2)
        .unwrap()
        .trim_end_matches(':');
    (id.to_string(), stderr)
}

pub fn env_steps_so_far(dir: &std::path::Path) -> u64 {
    let text = log(dir, "progress.jsonl");
    text.lines()
        .last()
        .and_then(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .and_then(|v| v["env_steps"].as_u64())
        .unwrap_or(0)
}

/// The f32 tensors of a safetensors file by name, as (shape, values): the format is an 8-byte
/// little-endian header length, a JSON header, then the raw data.
pub fn read_safetensors(path: &Path) -> std::collections::HashMap<String, (Vec<usize>, Vec<f32>)> {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    let mut out = std::collections::HashMap::new();
    for (name, t) in header.as_object().unwrap() {
        if name == "__metadata__" || t["dtype"] != "F32" {
            continue;
        }
        let shape: Vec<usize> = t["shape"]
            .as_array()
            .unwrap()
            .iter()
            .map(|d| d.as_u64().unwrap() as usize)
            .collect();
        let (s, e) = (
            t["data_offsets"][0].as_u64().unwrap() as usize,
            t["data_offsets"][1].as_u64().unwrap() as usize,
        );
        let values = data[s..e]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        out.insert(name.clone(), (shape, values));
    }
    out
}

/// metrics.csv without the columns that measure wall-clock time, as text (bit for bit).
pub fn exact_metrics(dir: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    let rows: Vec<Vec<&str>> = text.lines().map(|l| l.split(',').collect()).collect();
    let keep: Vec<usize> = (0..rows[0].len())
        .filter(|&i| !["wall_s", "updates_per_s", "env_steps_per_s"].contains(&rows[0][i]))
        .collect();
    rows.iter()
        .map(|r| keep.iter().map(|&i| r[i].to_string()).collect())
        .collect()
}

/// The final checkpoint's files; state.json without its wall-clock time.
pub fn final_checkpoint(dir: &Path) -> (Vec<u8>, Option<Vec<u8>>, serde_json::Value) {
    let c = dir.join("checkpoints/final");
    let mut state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(c.join("state.json")).unwrap()).unwrap();
    state.as_object_mut().unwrap().remove("wall_seconds");
    (
        std::fs::read(c.join("model.safetensors")).unwrap(),
        std::fs::read(c.join("replay.safetensors")).ok(),
        state,
    )
}

pub fn assert_same_run(a: &Path, b: &Path, what: &str) {
    let (ma, mb) = (exact_metrics(a), exact_metrics(b));
    assert_eq!(ma.len(), mb.len(), "{what}: epochs differ");
    for (ra, rb) in ma.iter().zip(&mb) {
        assert_eq!(ra, rb, "{what}: metrics differ from the twin's");
    }
    let (wa, ra, sa) = final_checkpoint(a);
    let (wb, rb, sb) = final_checkpoint(b);
    assert_eq!(sa, sb, "{what}: final state.json differs from the twin's");
    assert!(
        ra == rb,
        "{what}: final replay buffer differs from the twin's"
    );
    assert!(wa == wb, "{what}: final weights differ from the twin's");
}

/// A tiny Pendulum config (the sizes of `small_run`), as a method's config file.
pub const TINY: &str = r#"
[run]
env = "pendulum"
seed = 1
threads = 1
checkpoint_every = 1000

[algo]
actors = 2
critics = 2
subset = 2
utd = 1
batch_size = 64
hidden = [32, 32]
warmup_steps = 400

[eval]
epoch_env_steps = 500
episodes = 1
"#;

/// Mean undiscounted return of a uniform-random policy on Pendulum (the bar to beat).
pub fn random_policy_return(episodes: u64) -> f64 {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(99);
    let mut env = selkd_envs::make("pendulum").unwrap();
    let mut total = 0.0;
    for e in 0..episodes {
        env.reset(Some(1000 + e));
        loop {
            let s = env.step(&[rng.gen_range(-1.0..=1.0)]);
            total += s.reward;
            if s.terminated || s.truncated {
                break;
            }
        }
    }
    total / episodes as f64
}

/// Polls `done` every 20 ms; fails the test after `limit`, naming `what` it waited for.
pub fn wait_until(what: &str, limit: std::time::Duration, mut done: impl FnMut() -> bool) {
    let t0 = std::time::Instant::now();
    while !done() {
        assert!(t0.elapsed() < limit, "waited {limit:?} for {what}");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}
