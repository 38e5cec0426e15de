//! What the envs' tests share.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// `n` uniform random actions in `[-1, 1]^N` from `seed`.
pub(crate) fn random_actions<const N: usize>(seed: u64, n: usize) -> Vec<[f32; N]> {
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..n)
        .map(|_| [0; N].map(|_| rng.gen_range(-1.0f32..1.0)))
        .collect()
}

/// How deep the robot's lowest ball or capsule reaches below the floor (z = 0), m; negative
/// when it is clear of it.
pub(crate) fn sinking(robot: &crate::physics::Robot) -> f32 {
    let mut deepest = f32::NEG_INFINITY;
    for i in 0..robot.links.num_links() {
        for &c in robot.links.colliders(i) {
            let col = &robot.world.colliders[c];
            let p = col.position();
            if let Some(cap) = col.shape().as_capsule() {
                let z = (p * cap.segment.a).z.min((p * cap.segment.b).z);
                deepest = deepest.max(cap.radius - z);
            } else if let Some(ball) = col.shape().as_ball() {
                deepest = deepest.max(ball.radius - p.translation.z);
            }
        }
    }
    deepest
}

/// One scripted episode's summary.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ep {
    /// Forward progress of the root, m.
    pub dist: f32,
    pub steps: usize,
    pub ret: f64,
}

/// Runs one episode of `policy` (obs, step → action) from `seed`; `x` reads the root's forward
/// position.
pub(crate) fn rollout<E: crate::Env>(
    env: &mut E,
    seed: u64,
    x: impl Fn(&E) -> f32,
    mut policy: impl FnMut(&[f32], usize) -> Vec<f32>,
) -> Ep {
    let mut obs = env.reset(Some(seed));
    let x0 = x(env);
    let mut ret = 0.0;
    for t in 0.. {
        let s = env.step(&policy(&obs, t));
        ret += s.reward;
        obs = s.obs;
        if s.terminated || s.truncated {
            return Ep {
                dist: x(env) - x0,
                steps: t + 1,
                ret,
            };
        }
    }
    unreachable!()
}

/// Mean of `f` over episodes.
pub(crate) fn mean(eps: &[Ep], f: impl Fn(&Ep) -> f64) -> f64 {
    eps.iter().map(f).sum::<f64>() / eps.len() as f64
}

/// The convergence measurement of issue 32: for each physics setting, `policy` over `seeds` at
/// that setting and at 10× the rapier steps (same control step, same iterations), the relative
/// gaps of mean distance, return and episode length, and the env's speed on random actions
/// (single thread, this machine). Prints one markdown row per setting.
pub(crate) fn fidelity_table<E: crate::Env>(
    task: &str,
    make: impl Fn(crate::physics::SimParams) -> E,
    settings: &[crate::physics::SimParams],
    seeds: std::ops::Range<u64>,
    x: impl Fn(&E) -> f32 + Copy,
    policy: impl Fn(&[f32], usize) -> Vec<f32> + Copy,
) {
    println!("| task | setting | gait dist m | 10× dist m | dist gap | return | 10× return | return gap | steps | 10× steps | steps gap | env steps/s |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for &sim in settings {
        let fine = crate::physics::SimParams {
            substeps: sim.substeps * 10,
            ..sim
        };
        let run = |p| {
            let mut env = make(p);
            seeds
                .clone()
                .map(|s| rollout(&mut env, s, x, policy))
                .collect::<Vec<_>>()
        };
        let (a, b) = (run(sim), run(fine));
        let gap = |f: &dyn Fn(&Ep) -> f64| {
            let (u, v) = (mean(&a, f), mean(&b, f));
            (u, v, (u - v).abs() / v.abs().max(1e-9))
        };
        let d = gap(&|e| e.dist as f64);
        let r = gap(&|e| e.ret);
        let n = gap(&|e| e.steps as f64);
        let mut env = make(sim);
        let act = env.spec().act_dim;
        let acts = random_actions::<1>(7, 2000 * act);
        let start = std::time::Instant::now();
        let mut steps = 0usize;
        env.reset(Some(0));
        while steps < 2000 {
            let a: Vec<f32> = (0..act).map(|j| acts[steps * act + j][0]).collect();
            let s = env.step(&a);
            steps += 1;
            if s.terminated || s.truncated {
                env.reset(Some(steps as u64));
            }
        }
        let rate = steps as f64 / start.elapsed().as_secs_f64();
        println!(
            "| {task} | {}×{} | {:.2} | {:.2} | {:.0}% | {:.0} | {:.0} | {:.0}% | {:.0} | {:.0} | {:.0}% | {rate:.0} |",
            sim.substeps, sim.solver_iterations, d.0, d.1, 100.0 * d.2, r.0, r.1, 100.0 * r.2,
            n.0, n.1, 100.0 * n.2
        );
    }
}

/// Mean return of a uniform random policy over `seeds` (actions from `seed + 1000`) and of a
/// standing (zero-action) policy over the same seeds: the reward bands of issue 32.
pub(crate) fn random_and_standing_returns<E: crate::Env, const N: usize>(
    env: &mut E,
    seeds: std::ops::Range<u64>,
) -> (f64, f64) {
    let mut random = vec![];
    let mut standing = vec![];
    for seed in seeds {
        let acts = random_actions::<N>(seed + 1000, 1000);
        random.push(rollout(env, seed, |_| 0.0, |_, t| acts[t].to_vec()));
        standing.push(rollout(env, seed, |_| 0.0, |_, _| vec![0.0; N]));
    }
    (mean(&random, |e| e.ret), mean(&standing, |e| e.ret))
}

/// Issue 32's convergence check: `policy` over `seeds` at `sim` and at 10× its rapier steps;
/// returns the relative gaps of the mean distance, return and episode length, in that order.
pub(crate) fn gaps_to_10x_finer<E: crate::Env>(
    make: impl Fn(crate::physics::SimParams) -> E,
    sim: crate::physics::SimParams,
    seeds: std::ops::Range<u64>,
    x: impl Fn(&E) -> f32 + Copy,
    policy: impl Fn(&[f32], usize) -> Vec<f32> + Copy,
) -> [f64; 3] {
    let run = |p| {
        let mut env = make(p);
        seeds
            .clone()
            .map(|s| rollout(&mut env, s, x, policy))
            .collect::<Vec<_>>()
    };
    let fine = crate::physics::SimParams {
        substeps: sim.substeps * 10,
        ..sim
    };
    let (a, b) = (run(sim), run(fine));
    let gap =
        |f: &dyn Fn(&Ep) -> f64| (mean(&a, f) - mean(&b, f)).abs() / mean(&b, f).abs().max(1e-9);
    [
        gap(&|e| e.dist as f64),
        gap(&|e| e.ret),
        gap(&|e| e.steps as f64),
    ]
}
