//! The data path from a worker's env step to the learner's replay buffer, checked row by row
//! against references written here from the envs' published definitions (not from our code):
//! every stored `[s, a, r, s', terminated]` must be a real step of the env, time-limit
//! truncations must not be stored as terminal, termination must be, the reset observation must
//! never appear as an s', and no step may be lost or stored twice, even when a worker is killed
//! mid-episode and its successor replays the episode.

mod common;
use common::*;
use std::collections::HashMap;
use std::path::Path;
use std::time::{Duration, Instant};

/// One stored transition.
struct Row {
    s: Vec<f32>,
    a: Vec<f32>,
    r: f32,
    s2: Vec<f32>,
    terminated: f32,
}

/// The final checkpoint's replay rows, oldest first (`[s, a, r, s', terminated]` per row).
fn replay_rows(dir: &Path, obs: usize, act: usize) -> Vec<Row> {
    let tensors = read_safetensors(&dir.join("checkpoints/final/replay.safetensors"));
    let (shape, values) = &tensors["rows"];
    assert_eq!(shape[1], 2 * obs + act + 2, "row width");
    values
        .chunks_exact(shape[1])
        .map(|v| Row {
            s: v[..obs].to_vec(),
            a: v[obs..obs + act].to_vec(),
            r: v[obs + act],
            s2: v[obs + act + 1..2 * obs + act + 1].to_vec(),
            terminated: v[2 * obs + act + 1],
        })
        .collect()
}

fn key(x: &[f32]) -> Vec<u32> {
    x.iter().map(|v| v.to_bits()).collect()
}

/// The episodes the rows form: a row continues into the row whose s is its s' (observations are
/// continuous floats, so two steps never share one by chance). Returns each episode's rows in
/// order. Fails if a row has two successors or predecessors (a step stored twice) or the rows
/// form a cycle.
fn episodes(rows: &[Row]) -> Vec<Vec<usize>> {
    let mut by_s: HashMap<Vec<u32>, usize> = HashMap::new();
    for (i, r) in rows.iter().enumerate() {
        assert!(
            by_s.insert(key(&r.s), i).is_none(),
            "row {i}: its s is stored twice (a step stored twice?)"
        );
    }
    let mut prev = vec![None; rows.len()];
    let mut next = vec![None; rows.len()];
    for (i, r) in rows.iter().enumerate() {
        if let Some(&j) = by_s.get(&key(&r.s2)) {
            assert!(prev[j].is_none(), "row {j} follows two rows");
            prev[j] = Some(i);
            next[i] = Some(j);
        }
    }
    let mut out = Vec::new();
    for start in (0..rows.len()).filter(|&i| prev[i].is_none()) {
        let mut ep = vec![start];
        while let Some(j) = next[*ep.last().unwrap()] {
            ep.push(j);
        }
        out.push(ep);
    }
    let covered: usize = out.iter().map(Vec::len).sum();
    assert_eq!(covered, rows.len(), "some rows form a cycle");
    out
}

/// Gymnasium's Pendulum-v1 (g = 10, m = l = 1, dt = 0.05, |θ̇| ≤ 8, torque = 2·a clipped to ±2):
/// the next observation and the reward of acting `a` in the state whose observation is `s`.
fn pendulum_step(s: &[f32], a: f32) -> ([f64; 3], f64) {
    let (c, sn, thdot) = (s[0] as f64, s[1] as f64, s[2] as f64);
    let th = sn.atan2(c);
    let u = 2.0 * (a as f64).clamp(-1.0, 1.0);
    let reward = -(th * th + 0.1 * thdot * thdot + 0.001 * u * u);
    let new_thdot = (thdot + (3.0 * 10.0 / 2.0 * th.sin() + 3.0 * u) * 0.05).clamp(-8.0, 8.0);
    let new_th = th + new_thdot * 0.05;
    ([new_th.cos(), new_th.sin(), new_thdot], reward)
}

/// Every row is one Pendulum step (dynamics and reward), none is terminal, every episode is
/// 200 steps (the time limit) except the K still running when the run stopped, and the
/// episodes hold exactly the run's env steps.
#[test]
fn pendulum_rows_are_real_steps_and_a_killed_worker_loses_or_repeats_none() {
    let dir = temp_dir("data-path-pendulum");
    let k = 3;
    let steps = 7500;
    let sets = small_run(&[
        "algo.actors=3",
        &format!("run.total_env_steps={steps}"),
        "run.checkpoint_replay=true",
        "eval.epoch_env_steps=2500",
        "run.seed=11",
    ]);
    let mut child = spawn(train(&dir, &sets));
    let (id, mut stderr) = run_id(&mut child);
    // Kill worker 1 mid-episode: its successor must replay the episode, not store it again.
    let t0 = Instant::now();
    while env_steps_so_far(&dir) < 2500 {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "the run does not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let pids = worker_pids(&id, 1);
    assert_eq!(pids.len(), 1, "{pids:?}");
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stderr, &mut rest).unwrap();
    let status = child.wait().unwrap();
    assert!(
        status.success(),
        "the run did not finish after the kill ({status}):\n{rest}"
    );
    assert!(
        rest.contains("worker 1 died (signal 9); restarting it"),
        "{rest}"
    );

    let rows = replay_rows(&dir, 3, 1);
    assert_eq!(
        rows.len(),
        steps,
        "the replay buffer holds every env step once"
    );
    for (i, r) in rows.iter().enumerate() {
        let (next, reward) = pendulum_step(&r.s, r.a[0]);
        for d in 0..3 {
            assert!(
                (next[d] - r.s2[d] as f64).abs() < 1e-4,
                "row {i}: s' {:?} is not Pendulum's step from s {:?} under a {:?} (expected {next:?}): a reset observation, or s and s' of different steps",
                r.s2,
                r.s,
                r.a
            );
        }
        assert!(
            (reward - r.r as f64).abs() < 1e-4 * reward.abs().max(1.0),
            "row {i}: reward {} where Pendulum pays {reward}",
            r.r
        );
        assert_eq!(
            r.terminated, 0.0,
            "row {i}: Pendulum never terminates; a time limit must not be stored as terminal"
        );
    }
    let eps = episodes(&rows);
    // 7 500 steps of 3 actors in lockstep: 2 500 each, 12 full episodes and one of 100 each.
    let full = eps.iter().filter(|e| e.len() == 200).count();
    let mut short: Vec<usize> = eps.iter().map(Vec::len).filter(|&n| n != 200).collect();
    short.sort();
    assert_eq!(
        (full, short),
        (12 * k, vec![100; k]),
        "episodes are 200 steps (the time limit) but for the last of each worker"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Hopper's termination rule as Gymnasium v5 states it, read from an observation
/// (`qpos[1:]`, then `qvel` clipped to ±10): healthy while z > 0.7, |pitch| < 0.2 and every
/// entry of `qpos[2:]` and `qvel` lies within ±100.
fn hopper_healthy(obs: &[f32]) -> bool {
    let (z, pitch) = (obs[0], obs[1]);
    z > 0.7 && pitch > -0.2 && pitch < 0.2 && obs[1..].iter().all(|x| x.abs() < 100.0)
}

/// A Hopper run's rows: `terminated` is set exactly on the steps whose s' is unhealthy, a
/// terminal step ends its episode, and every other episode end is the time limit or the run's end.
fn hopper_rows_terminate_exactly_when_unhealthy(tag: &str, env: &str, actors: usize) {
    let dir = temp_dir(tag);
    let steps = 2000;
    let sets = small_run(&[
        &format!("run.env={env}"),
        &format!("algo.actors={actors}"),
        &format!("run.total_env_steps={steps}"),
        "run.checkpoint_replay=true",
        "eval.epoch_env_steps=2000",
        "run.seed=3",
    ]);
    assert_success(&run(train(&dir, &sets)), &dir);
    let rows = replay_rows(&dir, 11, 3);
    assert_eq!(
        rows.len(),
        steps,
        "the replay buffer holds every env step once"
    );
    let mut terminal = 0;
    for (i, r) in rows.iter().enumerate() {
        assert!(
            hopper_healthy(&r.s),
            "row {i}: s is unhealthy, so the episode had ended before this step"
        );
        let unhealthy = !hopper_healthy(&r.s2);
        assert_eq!(
            r.terminated == 1.0,
            unhealthy,
            "row {i}: terminated = {} but s' is {}",
            r.terminated,
            if unhealthy { "unhealthy" } else { "healthy" }
        );
        terminal += unhealthy as usize;
    }
    let eps = episodes(&rows);
    let mut open = 0;
    for ep in &eps {
        let last = &rows[*ep.last().unwrap()];
        for &i in &ep[..ep.len() - 1] {
            assert_eq!(
                rows[i].terminated, 0.0,
                "row {i}: a terminal step has a successor"
            );
        }
        if last.terminated == 0.0 {
            assert!(ep.len() <= 1000, "an episode longer than the time limit");
            open += (ep.len() < 1000) as usize;
        }
    }
    assert!(
        terminal > 10,
        "{terminal} terminations in {steps} steps: the check saw too few"
    );
    assert!(
        open <= actors,
        "{open} episodes end neither in a termination nor at the time limit (at most one per worker, when the run stopped)"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn hopper_rows_are_terminal_exactly_when_the_next_state_is_unhealthy() {
    hopper_rows_terminate_exactly_when_unhealthy("data-path-hopper", "hopper", 1);
}

#[test]
fn gymnasium_hopper_rows_are_terminal_exactly_when_the_next_state_is_unhealthy() {
    hopper_rows_terminate_exactly_when_unhealthy("data-path-gym-hopper", "gymnasium:Hopper-v5", 2);
}
