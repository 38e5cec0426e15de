//! How far a task's physics settings are from converged: each task's scripted gait
//! ([`crate::gaits`]) over 3 seeds at a setting, against the same policy integrated 10× finer
//! (rapier steps × 10, same control step, same iterations and contact tuning). The table in
//! `docs/results/fidelity.md` comes from [`table`] (the command there; a shorter example):
//!
//! ```text
//! FIDELITY='hopper:1x4,2x4;walker2d:4x2;halfcheetah:5x1' nice -n 15 \
//!   cargo test --release -p selkd-envs fidelity::table -- --ignored --nocapture
//! ```
//!
//! A setting is `STEPSxITERATIONS`, optionally followed by `/cHZ@ZETA` (contact softness: natural
//! frequency Hz and damping ratio, for floor and self contacts) and `/pMETRES` (rapier's
//! prediction distance), `/e` or `/i` (the articulation's Coriolis terms explicit or rapier's
//! semi-implicit default: [`crate::physics::Articulation::set_explicit_coriolis`]), `/jHZ@1`
//! (every hinge's joint-limit frequency, [`SimParams::limit_frequency`]; damping ratio 1), `/zN`
//! (rapier's relax iterations per solver pass, [`SimParams::stabilization_iterations`]), `/gN`
//! (rapier's Gauss–Seidel iterations per solver pass, [`SimParams::pgs_iterations`]); without
//! `FIDELITY` every task is measured at its shipped `SIM`.
//! `FIDELITY_SEEDS=N` measures seeds 0..N instead of 0–2; `FIDELITY_REF=SxP` makes the reference
//! S× the rapier steps and P× the solver passes (10x1 unless set; 10x4 is converged in both).

use crate::halfcheetah::HalfCheetah;
use crate::hopper::Hopper;
use crate::physics::{PhysicsTuning, SimParams};
use crate::walker2d::Walker2d;
use crate::{gaits, Env};

/// One episode's outcome: forward distance (m), return, length, terminated.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Outcome {
    pub distance: f64,
    pub ret: f64,
    pub len: usize,
    pub terminated: bool,
}

/// The shipped settings of a task.
pub(crate) fn shipped(task: &str) -> SimParams {
    match task {
        "hopper" => crate::hopper::SIM,
        "walker2d" => crate::walker2d::SIM,
        "halfcheetah" | "halfcheetah-random" => crate::halfcheetah::SIM,
        _ => panic!("no scripted gait for task {task}"),
    }
}

/// The scripted gait of `task` for episodes `seeds`, integrated as `sim` and `tuning` say;
/// also the seconds spent in `step`.
pub(crate) fn gait_episodes(
    task: &str,
    sim: SimParams,
    tuning: PhysicsTuning,
    seeds: &[u64],
) -> (Vec<Outcome>, f64) {
    fn run<E: Env>(
        env: &mut E,
        x: impl Fn(&E) -> f32,
        seed: u64,
        policy: impl Fn(&[f32], usize) -> Vec<f32>,
        secs: &mut f64,
    ) -> Outcome {
        let mut obs = env.reset(Some(seed));
        let x0 = x(env);
        let mut ret = 0.0;
        for t in 0.. {
            let a = policy(&obs, t);
            let start = std::time::Instant::now();
            let s = env.step(&a);
            *secs += start.elapsed().as_secs_f64();
            ret += s.reward;
            obs = s.obs;
            if s.terminated || s.truncated {
                return Outcome {
                    distance: (x(env) - x0) as f64,
                    ret,
                    len: t + 1,
                    terminated: s.terminated,
                };
            }
        }
        unreachable!()
    }
    let mut secs = 0.0;
    let outcomes = seeds
        .iter()
        .map(|&seed| match task {
            "hopper" => {
                let mut env = Hopper::with_sim(sim);
                env.robot.set_tuning(tuning);
                let policy = |o: &[f32], _| gaits::hopper(o).to_vec();
                run(&mut env, |e| e.qpos()[0], seed, policy, &mut secs)
            }
            "walker2d" => {
                let mut env = Walker2d::with_sim(sim);
                env.robot.set_tuning(tuning);
                let policy = |o: &[f32], t| gaits::walker2d(o, t).to_vec();
                run(&mut env, |e| e.qpos()[0], seed, policy, &mut secs)
            }
            "halfcheetah" => {
                let mut env = HalfCheetah::with_sim(sim);
                env.robot.set_tuning(tuning);
                let policy = |_: &[f32], t| gaits::halfcheetah(t).to_vec();
                run(&mut env, |e| e.qpos()[0], seed, policy, &mut secs)
            }
            // The cheetah flailing: uniform random actions, the same ones at every setting
            // (those of the reward-band test).
            "halfcheetah-random" => {
                let mut env = HalfCheetah::with_sim(sim);
                env.robot.set_tuning(tuning);
                let actions = crate::testing::random_actions::<6>(seed + 1000, 1000);
                let policy = |_: &[f32], t: usize| actions[t].to_vec();
                run(&mut env, |e| e.qpos()[0], seed, policy, &mut secs)
            }
            _ => panic!("no scripted gait for task {task}"),
        })
        .collect();
    (outcomes, secs)
}

/// `sim` with 10× the rapier steps per control step.
pub(crate) fn finer(sim: SimParams) -> SimParams {
    finer_by(sim, 10, 1)
}

/// `sim` with `steps`× the rapier steps per control step and `passes`× the solver passes per
/// step. 10× the steps with the same passes is not converged in solver passes for every policy
/// (`docs/results/fidelity.md`, "The walker at 100k, and the second axis"): 10 × 4 is the
/// reference converged in both.
pub(crate) fn finer_by(sim: SimParams, steps: usize, passes: usize) -> SimParams {
    SimParams {
        substeps: sim.substeps * steps,
        solver_iterations: sim.solver_iterations * passes,
        ..sim
    }
}

/// |a − b| / |b|.
pub(crate) fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-9)
}

fn mean(o: &[Outcome], f: impl Fn(&Outcome) -> f64) -> f64 {
    o.iter().map(f).sum::<f64>() / o.len() as f64
}

/// Parses a setting (see the module doc) on top of `task`'s control step.
fn parse(task: &str, spec: &str) -> (SimParams, PhysicsTuning) {
    let mut parts = spec.split('/');
    let (s, i) = parts
        .next()
        .unwrap()
        .split_once('x')
        .expect("STEPSxITERATIONS");
    let mut sim = SimParams {
        substeps: s.parse().unwrap(),
        solver_iterations: i.parse().unwrap(),
        ..shipped(task)
    };
    let mut tuning = PhysicsTuning::default();
    for p in parts {
        if let Some(c) = p.strip_prefix('c') {
            let (hz, zeta) = c.split_once('@').expect("cHZ@ZETA");
            sim.contact_frequency = Some(hz.parse().unwrap());
            sim.contact_damping_ratio = Some(zeta.parse().unwrap());
        } else if let Some(j) = p.strip_prefix('j') {
            let (hz, zeta) = j.split_once('@').expect("jHZ@ZETA");
            assert_eq!(zeta, "1", "limits have damping ratio 1: /jHZ@1");
            sim.limit_frequency = hz.parse().unwrap();
        } else if p == "e" {
            tuning.explicit_coriolis = Some(true);
        } else if p == "i" {
            tuning.explicit_coriolis = Some(false);
        } else if let Some(d) = p.strip_prefix('p') {
            sim.prediction_distance = d.parse().unwrap();
        } else if let Some(n) = p.strip_prefix('z') {
            sim.stabilization_iterations = n.parse().unwrap();
        } else if let Some(n) = p.strip_prefix('g') {
            sim.pgs_iterations = n.parse().unwrap();
        } else {
            panic!("unknown part {p} of setting {spec}");
        }
    }
    (sim, tuning)
}

/// The measurement: one markdown row per task and setting (means over seeds 0–2).
#[test]
#[ignore]
fn table() {
    let spec = std::env::var("FIDELITY")
        .unwrap_or_else(|_| "hopper:1x4;walker2d:4x2;halfcheetah:5x1".into());
    // FIDELITY_REF=SxP: the reference is S× the rapier steps and P× the solver passes (10x1
    // unless set; 10x4 is converged in both).
    let (ref_steps, ref_passes) = std::env::var("FIDELITY_REF").map_or((10, 1), |r| {
        let (s, p) = r.split_once('x').expect("FIDELITY_REF=SxP");
        (s.parse().unwrap(), p.parse().unwrap())
    });
    let fine_name = format!("{ref_steps}×{ref_passes} finer");
    println!(
        "| task | setting | distance m (per seed) | {fine_name} | Δ distance | return | {fine_name} \
         | Δ return | length (terminated) | {fine_name} | Δ length | steps/s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    // FIDELITY_SEEDS=N measures seeds 0..N instead, to see how much of a Δ is seed noise.
    let n: u64 = std::env::var("FIDELITY_SEEDS").map_or(3, |n| n.parse().unwrap());
    let seeds: Vec<u64> = (0..n).collect();
    for task_spec in spec.split(';').filter(|s| !s.is_empty()) {
        let (task, settings) = task_spec.split_once(':').expect("TASK:SETTINGS");
        for setting in settings.split(',') {
            let (sim, tuning) = parse(task, setting);
            let (at, secs) = gait_episodes(task, sim, tuning, &seeds);
            let fine_sim = finer_by(sim, ref_steps, ref_passes);
            let (fine, _) = gait_episodes(task, fine_sim, tuning, &seeds);
            let steps: usize = at.iter().map(|o| o.len).sum();
            let per_seed: Vec<String> = at.iter().map(|o| format!("{:.2}", o.distance)).collect();
            let fine_seed: Vec<String> =
                fine.iter().map(|o| format!("{:.2}", o.distance)).collect();
            let d = |o: &Outcome| o.distance;
            let r = |o: &Outcome| o.ret;
            let l = |o: &Outcome| o.len as f64;
            println!(
                "| {task} | {setting} | {:.2} ({}) | {:.2} ({}) | {:.0}% | {:.1} | {:.1} | {:.0}% \
                 | {:.0} ({}T) | {:.0} ({}T) | {:.0}% | {:.0} |",
                mean(&at, d),
                per_seed.join(", "),
                mean(&fine, d),
                fine_seed.join(", "),
                100.0 * rel(mean(&at, d), mean(&fine, d)),
                mean(&at, r),
                mean(&fine, r),
                100.0 * rel(mean(&at, r), mean(&fine, r)),
                mean(&at, l),
                at.iter().filter(|o| o.terminated).count(),
                mean(&fine, l),
                fine.iter().filter(|o| o.terminated).count(),
                100.0 * rel(mean(&at, l), mean(&fine, l)),
                steps as f64 / secs,
            );
        }
    }
}

/// The convergence check of issue 32, per task: the scripted gait's mean distance over seeds
/// 0–9 (three seeds of a gait that falls after ~100–250 steps are too few: seed noise alone
/// moves the means by 10–20%) at the shipped settings is within 15% of the same gait's
/// integrated finer, at each reference `(steps, passes)` (`steps`× the rapier steps, `passes`×
/// the solver passes: [`finer_by`]), and so are its mean episode length and return (a gait that
/// only stands up through integration error lives much longer at the shipped settings: hopper's
/// old 1 × 4 ran ~920 steps against 206, a 348% error).
fn assert_converged(task: &str, references: &[(usize, usize)]) {
    let seeds: Vec<u64> = (0..10).collect();
    let sim = shipped(task);
    let (at, _) = gait_episodes(task, sim, PhysicsTuning::default(), &seeds);
    for &(steps, passes) in references {
        let fine_sim = finer_by(sim, steps, passes);
        let (fine, _) = gait_episodes(task, fine_sim, PhysicsTuning::default(), &seeds);
        for (what, f) in [
            (
                "distance",
                &(|o: &Outcome| o.distance) as &dyn Fn(&Outcome) -> f64,
            ),
            ("return", &|o: &Outcome| o.ret),
            ("length", &|o: &Outcome| o.len as f64),
        ] {
            let (a, b) = (mean(&at, f), mean(&fine, f));
            assert!(
                rel(a, b) <= 0.15,
                "{task}: gait {what} {a:.3} at {sim:?} vs {b:.3} at {steps}x the steps and \
                 {passes}x the passes\n{at:?}\n{fine:?}"
            );
        }
    }
}

/// The hopper against 10× the steps and against 10× the steps and 4× the solver passes (the
/// reference its setting was chosen by).
#[test]
fn hopper_gait_converged() {
    assert_converged("hopper", &[(10, 1), (10, 4)]);
}

#[test]
fn walker2d_gait_converged() {
    assert_converged("walker2d", &[(10, 1), (10, 4)]);
}

/// Diagnosis (scratch): the cheetah's sine gait in the air (50 m up, so the floor is never
/// touched): joint angles after each of the first control steps at several settings.
#[test]
#[ignore]
fn cheetah_in_air() {
    let air = std::env::var("AIR").unwrap_or_else(|_| "5x1,50x1,500x1,5x1/e,50x1/e".into());
    let steps: usize = std::env::var("AIR_STEPS").map_or(20, |n| n.parse().unwrap());
    let z: f32 = std::env::var("AIR_Z").map_or(50.0, |n| n.parse().unwrap());
    for setting in air.split(',') {
        let (sim, tuning) = parse("halfcheetah", setting);
        let mut env = HalfCheetah::with_sim(sim);
        env.robot.set_tuning(tuning);
        let mut q = [0.0f32; 9];
        q[1] = z;
        env.set_state(&q, &[0.0; 9]);
        for t in 0..steps {
            env.step(&gaits::halfcheetah(t));
        }
        let q = env.qpos();
        let v = env.qvel();
        println!(
            "{setting}: qpos {:?}\n      qvel {:?}",
            q.iter().map(|x| format!("{x:.3}")).collect::<Vec<_>>(),
            v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>()
        );
    }
}

/// The cheetah under `policy(obs, t)` for episodes `seeds`.
fn cheetah_episodes(
    sim: SimParams,
    tuning: PhysicsTuning,
    seeds: &[u64],
    policy: impl Fn(&[f32], usize) -> [f32; 6],
) -> Vec<Outcome> {
    let mut env = HalfCheetah::with_sim(sim);
    env.robot.set_tuning(tuning);
    seeds
        .iter()
        .map(|&seed| {
            let mut obs = env.reset(Some(seed));
            let x0 = env.qpos()[0];
            let mut ret = 0.0;
            for t in 0..1000 {
                let s = env.step(&policy(&obs, t));
                ret += s.reward;
                obs = s.obs;
            }
            Outcome {
                distance: (env.qpos()[0] - x0) as f64,
                ret,
                len: 1000,
                terminated: false,
            }
        })
        .collect()
}

/// The gaits [`climb_cheetah`] searches: open-loop sines ([`gaits::cheetah_sine`], 13
/// parameters) or closed-loop sine + PD ([`gaits::cheetah_pd`], 21).
#[derive(Clone, Copy)]
enum CheetahGait {
    Sine,
    Pd,
}

impl CheetahGait {
    fn act(self, p: &[f32], obs: &[f32], t: usize) -> [f32; 6] {
        match self {
            CheetahGait::Sine => gaits::cheetah_sine(p, t),
            CheetahGait::Pd => gaits::cheetah_pd(p, obs, t),
        }
    }
    /// A random gait.
    fn sample(self, rng: &mut impl rand::Rng) -> Vec<f32> {
        let pi = std::f32::consts::PI;
        let mut p = vec![rng.gen_range(0.5..6.0)];
        match self {
            CheetahGait::Sine => {
                p.extend((0..6).map(|_| rng.gen_range(-pi..pi)));
                p.extend((0..6).map(|_| rng.gen_range(0.0..1.0)));
            }
            CheetahGait::Pd => {
                for _ in 0..6 {
                    p.extend([
                        rng.gen_range(-0.5..0.5),
                        rng.gen_range(0.0..1.0),
                        rng.gen_range(-pi..pi),
                    ]);
                }
                p.extend([rng.gen_range(1.0..10.0), rng.gen_range(0.0..1.0)]);
            }
        }
        p
    }
    /// A hill-climbing step from `p`.
    fn perturb(self, p: &[f32], rng: &mut impl rand::Rng) -> Vec<f32> {
        let mut p = p.to_vec();
        p[0] = (p[0] + 0.2 * rng.gen_range(-1.0..1.0)).clamp(0.3, 8.0);
        match self {
            CheetahGait::Sine => {
                for x in &mut p[1..7] {
                    *x += 0.3 * rng.gen_range(-1.0f32..1.0);
                }
                for x in &mut p[7..] {
                    *x = (*x + 0.1 * rng.gen_range(-1.0f32..1.0)).clamp(0.0, 1.0);
                }
            }
            CheetahGait::Pd => {
                for j in 0..6 {
                    let c = &mut p[1 + 3 * j];
                    *c = (*c + 0.1 * rng.gen_range(-1.0f32..1.0)).clamp(-1.0, 1.0);
                    let a = &mut p[2 + 3 * j];
                    *a = (*a + 0.1 * rng.gen_range(-1.0f32..1.0)).clamp(0.0, 1.5);
                    p[3 + 3 * j] += 0.3 * rng.gen_range(-1.0f32..1.0);
                }
                p[19] = (p[19] + rng.gen_range(-1.0f32..1.0)).clamp(0.5, 20.0);
                p[20] = (p[20] + 0.1 * rng.gen_range(-1.0f32..1.0)).clamp(0.0, 2.0);
            }
        }
        p
    }
}

/// How exploitable a cheetah setting is: a search for the gait with the best mean return on
/// seeds 100–101 at the setting `CLIMB` (default `5x1`), `CLIMB_RANDOM` random samples then
/// `CLIMB_ITERS` hill-climbing steps from RNG seed `CLIMB_SEED`, over open-loop sine gaits
/// (`CLIMB_GAIT=sine`, the default) or sine + PD gaits (`CLIMB_GAIT=pd`); then the best gait at
/// that setting and 10× finer over seeds 0–9 (one table row, as [`table`]'s).
#[test]
#[ignore]
fn climb_cheetah() {
    use rand::SeedableRng;
    let spec = std::env::var("CLIMB").unwrap_or_else(|_| "5x1".into());
    let var = |k: &str, d: u64| std::env::var(k).map_or(d, |v| v.parse().unwrap());
    let (n_random, iters, seed) = (
        var("CLIMB_RANDOM", 60),
        var("CLIMB_ITERS", 200),
        var("CLIMB_SEED", 0),
    );
    let gait = match std::env::var("CLIMB_GAIT").as_deref() {
        Ok("pd") => CheetahGait::Pd,
        Ok("sine") | Err(_) => CheetahGait::Sine,
        Ok(other) => panic!("CLIMB_GAIT is sine or pd, got {other}"),
    };
    let (sim, tuning) = parse("halfcheetah", &spec);
    let episodes = |sim, seeds: &[u64], p: &[f32]| {
        cheetah_episodes(sim, tuning, seeds, |o, t| gait.act(p, o, t))
    };
    let score = |p: &[f32]| mean(&episodes(sim, &[100, 101], p), |o| o.ret);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut best: Vec<f32> = vec![];
    let mut best_score = f64::NEG_INFINITY;
    let start = std::time::Instant::now();
    for i in 0..n_random + iters {
        let p = if i < n_random {
            gait.sample(&mut rng)
        } else {
            gait.perturb(&best, &mut rng)
        };
        let s = score(&p);
        if s > best_score {
            (best, best_score) = (p, s);
        }
    }
    let climb_s = start.elapsed().as_secs_f64();
    let seeds: Vec<u64> = (0..10).collect();
    let start = std::time::Instant::now();
    let at = episodes(sim, &seeds, &best);
    let secs = start.elapsed().as_secs_f64();
    let fine = episodes(finer(sim), &seeds, &best);
    let d = |o: &Outcome| o.distance;
    let r = |o: &Outcome| o.ret;
    println!(
        "CLIMB {spec} seed {seed}: climbed return {best_score:.1} ({climb_s:.0} s) gait {best:?}\n\
         | halfcheetah | {spec} (climbed, seed {seed}) | {:.2} | {:.2} | {:.0}% | {:.1} | {:.1} | {:.0}% | {:.0} |",
        mean(&at, d),
        mean(&fine, d),
        100.0 * rel(mean(&at, d), mean(&fine, d)),
        mean(&at, r),
        mean(&fine, r),
        100.0 * rel(mean(&at, r), mean(&fine, r)),
        10_000.0 / secs,
    );
}

/// The halfcheetah's convergence check (issue 32's criterion, distance, return and length within
/// 15% of 10× finer over seeds 0–9), on the cheetah flailing with random actions: at the shipped
/// 5 × 4 −14.5 m against −14.6 m over 24 seeds; at the old 5 × 1 −7.9 m against −11.2 m (29%),
/// which fails it. The open-loop sine gait is no probe for this: its coarse settings miss their
/// references by 10% (5 × 1) to 235% (5 × 4) with no order, as MuJoCo misses its own by 24%
/// (`docs/results/fidelity.md`; `FIDELITY='halfcheetah:5x4'` in [`table`] measures it).
#[test]
fn halfcheetah_random_flailing_converged() {
    assert_converged("halfcheetah-random", &[(10, 1)]);
}
