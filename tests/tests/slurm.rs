//! End to end on a real Slurm: a single-node cluster brought up by `deploy/slurm.sh` runs
//! `selkd experiment plan --slurm`'s job array through `sbatch`. One task is preempted
//! (`scontrol requeue`), the other gets the time-limit warning (SIGUSR1 to its batch shell, as
//! `--signal` sends it) and requeues itself; both runs resume from their checkpoints and end
//! bit-identical to twins that were never stopped, and the experiment reports.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const EXPERIMENT: &str = r#"
total_env_steps = 6000
seeds = [1, 2]
tasks = ["pendulum"]

[set]
"run.checkpoint_every" = 500
"run.checkpoint_replay" = true

[[method]]
name = "a"
config = "tiny.toml"
"#;

/// The cluster of `deploy/slurm.sh up`, stopped when dropped.
struct Cluster {
    dir: PathBuf,
}

impl Cluster {
    fn up(dir: PathBuf) -> Option<Cluster> {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/slurm.sh");
        // A port of this test's own, so that two checkouts testing at once do not meet.
        let port = 20000 + std::process::id() % 20000;
        let out = Command::new("bash")
            .arg(&script)
            .arg("up")
            .arg(&dir)
            .env("SLURM_TEST_PORT", port.to_string())
            .output()
            .unwrap();
        let cluster = Cluster { dir };
        let err = String::from_utf8_lossy(&out.stderr);
        if !out.status.success() {
            if err.contains("is missing") {
                eprintln!("skipped: {err}");
                return None;
            }
            panic!("bringing Slurm up failed:\n{err}");
        }
        Some(cluster)
    }

    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", self.dir.join("slurm.conf"));
        c
    }

    fn ok(&self, program: &str, args: &[&str]) -> String {
        let out = self.command(program).args(args).output().unwrap();
        assert!(
            out.status.success(),
            "{program} {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    }

    /// A requeued task waits for its begin time (Slurm holds it back); release it at once.
    fn release(&self, task: &str) {
        let t0 = Instant::now();
        loop {
            let out = self
                .command("scontrol")
                .args(["update", &format!("JobId={task}"), "StartTime=now"])
                .output()
                .unwrap();
            if out.status.success() {
                return;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "releasing {task}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/slurm.sh");
        let _ = Command::new("bash")
            .arg(script)
            .arg("down")
            .arg(&self.dir)
            .status();
    }
}

fn wait_for(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !done() {
        assert!(t0.elapsed() < limit, "waited {limit:?} for {what}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn a_job_array_on_slurm_survives_a_preemption_and_a_time_limit_and_ends_as_its_twins() {
    let root = temp_dir("slurm");
    std::fs::write(root.join("tiny.toml"), TINY).unwrap();
    let exp = root.join("exp.toml");
    std::fs::write(&exp, EXPERIMENT).unwrap();
    let Some(cluster) = Cluster::up(root.join("cluster")) else {
        return;
    };
    let runs = root.join("runs");
    let out = run({
        let mut c = Command::new(bin("selkd"));
        c.args(["experiment", "plan"])
            .arg(&exp)
            .arg("--dir")
            .arg(&runs)
            .arg("--slurm");
        c
    });
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("critic updates/s here, 2801 updates"),
        "the time limit comes from a measured rate and the runs' updates: {stderr}"
    );
    let script = runs.join("slurm.sbatch");
    let text = std::fs::read_to_string(&script).unwrap();
    for want in [
        "#SBATCH --array=0-1\n",
        "#SBATCH --cpus-per-task=1\n",
        "#SBATCH --requeue\n",
        "#SBATCH --signal=B:USR1@300\n",
        "#SBATCH --time=0-00:",
    ] {
        assert!(text.contains(want), "wanted {want:?} in:\n{text}");
    }
    let job = cluster.ok("sbatch", &["--parsable", script.to_str().unwrap()]);
    let job = job.split(';').next().unwrap().to_string();
    let run_dir = |seed: u64| runs.join(format!("a/pendulum/seed-{seed}"));
    // Both tasks are stopped a third of the way in, past a checkpoint: task 0 preempted, task 1
    // warned of its time limit.
    wait_for(
        "both runs to pass 2000 env steps",
        Duration::from_secs(240),
        || env_steps_so_far(&run_dir(1)) >= 2000 && env_steps_so_far(&run_dir(2)) >= 2000,
    );
    let ids = [format!("{job}_0"), format!("{job}_1")];
    cluster.ok("scontrol", &["requeue", &ids[0]]);
    cluster.ok("scancel", &["--batch", "--signal=USR1", &ids[1]]);
    for (task, id) in ids.iter().enumerate() {
        let log = runs.join(format!("slurm-{id}.out"));
        let restarted = || std::fs::read_to_string(&log).is_ok_and(|t| t.contains("(restart 1)"));
        wait_for(
            &format!("task {id} to be requeued"),
            Duration::from_secs(120),
            || {
                restarted()
                    || cluster
                        .ok("squeue", &["-h", "-j", id, "-o", "%T"])
                        .contains("PENDING")
            },
        );
        if !restarted() {
            cluster.release(id);
        }
        wait_for(
            &format!("task {id} to start again"),
            Duration::from_secs(120),
            restarted,
        );
        if task == 1 {
            let text = std::fs::read_to_string(&log).unwrap();
            assert!(text.contains("requeueing this task"), "{text}");
        }
    }
    wait_for("the array to finish", Duration::from_secs(300), || {
        cluster.ok("squeue", &["-h", "-j", &job]).is_empty()
    });
    // The twins: the same runs, never stopped, through the same runner here.
    let twins = root.join("twins");
    let out = run({
        let mut c = Command::new(bin("selkd"));
        c.args(["experiment", "run"])
            .arg(&exp)
            .arg("--dir")
            .arg(&twins)
            .args(["--jobs", "1"]);
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for seed in [1, 2] {
        let stopped = run_dir(seed);
        let text = log(&stopped, "selkd.log");
        assert!(
            text.matches("selkd: run ").count() >= 2,
            "seed {seed} was stopped and resumed: {text}"
        );
        assert_same_run(
            &stopped,
            &twins.join(format!("a/pendulum/seed-{seed}")),
            &format!("seed {seed} on Slurm"),
        );
    }
    let out = run({
        let mut c = Command::new(bin("selkd"));
        c.args(["experiment", "report"]).arg(&runs);
        c
    });
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    drop(cluster);
    let _ = std::fs::remove_dir_all(&root);
}
