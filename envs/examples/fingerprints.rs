//! Prints each registered env's dynamics fingerprints: the 200-step record rollout that every
//! checkpoint keeps (`EnvRecord::rollout`) and a 3 000-step one under uniform random actions
//! (seeded, episodes reset with the next seed). Run it before and after a change that must not
//! change the physics (a speed-up in the vendored rapier, a refactor of an env) and compare:
//!   cargo run --release -p selkd-envs --example fingerprints
use rand::{Rng, SeedableRng};
use selkd_envs::{fingerprint_rollout, make, names, EnvOptions, EnvRecord};

fn main() {
    for name in names() {
        let record =
            EnvRecord::of(name, &EnvOptions::new()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut env = make(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        let n = env.spec().act_dim;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        let random = fingerprint_rollout(env.as_mut(), 3000, |_| {
            (0..n).map(|_| rng.gen_range(-1.0..=1.0)).collect()
        });
        println!(
            "{name:<14} record {}  random-3000 {random:016x}",
            record.rollout.as_deref().unwrap_or("none")
        );
    }
}
