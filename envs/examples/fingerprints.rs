//! Prints each registered env's dynamics fingerprints: the 200-step record rollout that every
//! checkpoint keeps (`EnvRecord::rollout`) and a 3 000-step one under uniform random actions
//! (seeded, episodes reset with the next seed). Run it before and after a change that must not
//! change the physics (a speed-up in the vendored rapier, a refactor of an env) and compare:
//!   cargo run --release -p selkd-envs --example fingerprints
use rand::{Rng, SeedableRng};
use selkd_envs::{make, names, EnvOptions, EnvRecord};

fn main() {
    for name in names() {
        let record =
            EnvRecord::of(name, &EnvOptions::new()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut env = make(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        let n = env.spec().act_dim;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        // FNV-1a over every observation, reward and ending, as `rollout_fingerprint`.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for b in bytes {
                h = (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3);
            }
        };
        let mut seed = 0;
        for x in env.reset(Some(seed)) {
            eat(&x.to_bits().to_le_bytes());
        }
        for _ in 0..3000 {
            let a: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..=1.0)).collect();
            let s = env.step(&a);
            for x in &s.obs {
                eat(&x.to_bits().to_le_bytes());
            }
            eat(&s.reward.to_bits().to_le_bytes());
            eat(&[s.terminated as u8, s.truncated as u8]);
            if s.terminated || s.truncated {
                seed += 1;
                for x in env.reset(Some(seed)) {
                    eat(&x.to_bits().to_le_bytes());
                }
            }
        }
        println!(
            "{name:<14} record {}  random-3000 {h:016x}",
            record.rollout.as_deref().unwrap_or("none")
        );
    }
}
