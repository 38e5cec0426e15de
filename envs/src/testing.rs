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
