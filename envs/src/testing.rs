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
