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

/// `iters` steps of hill-climbing from `start`: each perturbs the best parameters so far with
/// `perturb` and keeps the result if `score` rises. Prints the start and each improvement;
/// returns the best and its score. (The scripted gaits' searches, ignored tests run by hand.)
pub(crate) fn hill_climb<const N: usize, R: Rng>(
    start: [f32; N],
    iters: usize,
    rng: &mut R,
    mut perturb: impl FnMut(&mut [f32; N], &mut R),
    mut score: impl FnMut(&[f32; N]) -> f64,
) -> ([f32; N], f64) {
    let (mut best, mut best_score) = (start, score(&start));
    println!("start {best_score:.3}");
    for i in 0..iters {
        let mut p = best;
        perturb(&mut p, rng);
        let sc = score(&p);
        if sc > best_score {
            (best, best_score) = (p, sc);
            println!("{i}: {best_score:.3} {best:?}");
        }
    }
    (best, best_score)
}

/// One scripted episode's summary.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ep {
    pub ret: f64,
}

/// Runs one episode of `policy` (obs, step → action) from `seed`.
pub(crate) fn rollout<E: crate::Env>(
    env: &mut E,
    seed: u64,
    mut policy: impl FnMut(&[f32], usize) -> Vec<f32>,
) -> Ep {
    let mut obs = env.reset(Some(seed));
    let mut ret = 0.0;
    for t in 0.. {
        let s = env.step(&policy(&obs, t));
        ret += s.reward;
        obs = s.obs;
        if s.terminated || s.truncated {
            return Ep { ret };
        }
    }
    unreachable!()
}

/// Mean of `f` over episodes.
pub(crate) fn mean(eps: &[Ep], f: impl Fn(&Ep) -> f64) -> f64 {
    eps.iter().map(f).sum::<f64>() / eps.len() as f64
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
        random.push(rollout(env, seed, |_, t| acts[t].to_vec()));
        standing.push(rollout(env, seed, |_, _| vec![0.0; N]));
    }
    (mean(&random, |e| e.ret), mean(&standing, |e| e.ret))
}
