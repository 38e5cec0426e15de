//! Gymnasium's `Hopper-v5` task on rapier3d physics (see [`crate::physics`]): a one-legged planar
//! robot learns to hop forward. The first physics robot of SELKD, and the standard first
//! locomotion benchmark after the classic-control tasks.
//!
//! Kept from Gymnasium v5 (meaning, not MuJoCo's exact dynamics):
//! - MuJoCo's `hopper.xml` geometry: torso capsule z 1.45→1.05 (r 0.05), thigh 1.05→0.6 (r 0.05),
//!   leg 0.6→0.1 (r 0.04), foot along x from −0.13 to 0.26 at z 0.1 (r 0.06); density 1000
//!   (masses ≈ 3.7, 4.1, 2.8, 5.3 kg; about MuJoCo's, from the same geoms). Hinges about −Y (the XML's
//!   `0 -1 0` axis, so angle signs match MuJoCo's) at z 1.05, 0.6, 0.1 with ranges [−150°, 0°],
//!   [−150°, 0°], [−45°, 45°]; the XML's joint defaults armature 1 and damping 1 on them. The root
//!   is `rootx`, `rootz`, `rooty` (planar, about the torso centre at z 1.25).
//! - Friction: geoms 0.9, the foot 2.0 (the XML's values), the floor 1.0, combined by maximum as
//!   MuJoCo does.
//! - Observation (11): `qpos[1:]` = [z, pitch, thigh, leg, foot angles] and `qvel` = [ẋ, ż,
//!   pitch rate, 3 joint velocities] clipped to ±10.
//! - Action (3) in [−1, 1] (clipped), × gear 200 → joint torque, N·m.
//! - Control dt 0.008 s. Reward = ẋ (torso x over the step / dt) + 1 if healthy − 1e-3·‖a‖².
//! - Healthy: z > 0.7, |pitch| < 0.2 and every entry of `qpos[2:]` and `qvel` within ±100;
//!   unhealthy terminates. 1000 steps truncates.
//! - Reset: the model pose (torso centre at z 1.25, joints at 0: the foot 4 cm above the floor, as
//!   in MuJoCo) plus U(±5e-3) on every `qpos` and `qvel` entry.
//!
//! A state that goes non-finite (rapier quarantines such bodies) terminates the episode with a
//! zero observation: the env never emits NaN.

use crate::physics::{
    add_floor, clip_actions, new_world, Articulation, Geom, LinkDesc, Robot, RootJoint, SimParams,
    RAPIER_PREDICTION_DISTANCE,
};
use crate::{Env, EnvSpec, Step};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rapier3d::prelude::PhysicsWorld;

const GEAR: f32 = 200.0;
const CONTROL_DT: f32 = 0.008;
/// Physics integration per control step: four rapier steps of 2 ms with four solver passes each
/// (rapier's TGS substeps: the contact and limit solve four times a step), and joint limits as
/// 16 Hz springs ([`SimParams::limit_frequency`]), since the sixteenth session. Chosen by issue
/// 32's learned check at 100k env steps against a reference converged in both rapier steps and
/// solver passes (10 × the steps and 4 × the passes: 40 × 16; `docs/results/fidelity.md`, "The
/// hopper ships 4 × 4"): our SAC's policies trained 100k env steps at 4 × 4 keep their return
/// and episode length there (3 seeds, 50 episodes each). At the previous 8 × 1 (fifteenth
/// session) they kept them 10× finer in steps alone (80 × 1) within 7%, but three of six 100k
/// policies were 20–49% off 80 × 16: they leaned on the single solver pass. Before that, at 2 × 4
/// (4 ms steps), they leaned on the step itself and on the springs' explicit integration
/// (4π·f·h = 0.80; SAC seed 1 lost 49% of its return 10× finer, 80% against 80 × 16). The cost:
/// about 0.8× 8 × 1's speed, still about 1.3–1.5× Gymnasium's MuJoCo Hopper-v5 (one loaded
/// sitting, AMD EPYC).
///
/// Before, 2 × 4 with the springs (thirteenth session): our SAC's policies at 30k env steps
/// kept their return and episode length within 11% on every seed (mean 2% / 7%), where at 1 × 8
/// with hard limits one seed lost 37% / 45%; the gait below converges at either (24 seeds:
/// distance 3%, return and length 0%).
///
/// Before that (the hard-limit 1 × 8):
/// Chosen for convergence (issue 32, `docs/results/fidelity.md`; `tests::fidelity` prints the
/// table): the scripted gait at 1×8 and integrated 10× finer (10×8) agrees within 3% in
/// distance and 0% in return and episode length over 24 seeds. The old 1×4 (2 ms TGS substeps)
/// did not: its gait, climbed at 1×4, survived 1000 steps only there and fell after ~200 steps
/// at 10×4 (return 955 against 242). What matters is the TGS substep length: 2×4 (also 1 ms)
/// converges too, 2×2 (2 ms) does not.
/// Earlier measurements (bang-bang torques, random episodes): every setting from 1×2 to 8×8
/// stayed finite and on the floor; joint-limit overshoot 1×2 0.022 rad, 1×4 0.003 rad.
///
/// The measurements above were made while the hopper's foot had almost no friction (a rapier bug
/// on planar multibodies, fixed in the vendored copy on 2026-12-07; `vendor/README.md`): this
/// setting's learned checks are owed again (`docs/results/fidelity.md`, "Read first").
pub const SIM: SimParams = SimParams {
    control_dt: CONTROL_DT,
    substeps: 4,
    solver_iterations: 4,
    prediction_distance: RAPIER_PREDICTION_DISTANCE,
    limit_frequency: 16.0,
    implicit_limits: false,
    stabilization_iterations: crate::physics::RAPIER_STABILIZATION_ITERATIONS,
    pgs_iterations: crate::physics::RAPIER_PGS_ITERATIONS,
    contact_frequency: None,
    contact_damping_ratio: None,
};
const INIT_Z: f32 = 1.25;
const RESET_NOISE: f32 = 5e-3;
const CTRL_COST_WEIGHT: f64 = 1e-3;
const HEALTHY_REWARD: f64 = 1.0;
const OBS_VEL_CLIP: f32 = 10.0;
const NQ: usize = 6;

fn deg(d: f32) -> f32 {
    d.to_radians()
}

/// The hopper's links, MuJoCo's `hopper.xml` in its rest pose.
pub fn links() -> Vec<LinkDesc> {
    let hinge = |name, parent, z: f32, range: [f32; 2], geom| LinkDesc {
        range: Some(range),
        friction: 0.9,
        armature: 1.0,
        damping: 1.0,
        ..LinkDesc::hinge(name, parent, [0.0, 0.0, z], [0.0, -1.0, 0.0], vec![geom])
    };
    let cap = Geom::capsule;
    let mut foot = hinge(
        "foot",
        2,
        0.1,
        [deg(-45.0), deg(45.0)],
        cap([-0.13, 0.0, 0.1], [0.26, 0.0, 0.1], 0.06),
    );
    foot.friction = 2.0;
    vec![
        LinkDesc {
            friction: 0.9,
            ..LinkDesc::root(
                "torso",
                [0.0, 0.0, INIT_Z],
                vec![cap([0.0, 0.0, 1.45], [0.0, 0.0, 1.05], 0.05)],
            )
        },
        hinge(
            "thigh",
            0,
            1.05,
            [deg(-150.0), 0.0],
            cap([0.0, 0.0, 1.05], [0.0, 0.0, 0.6], 0.05),
        ),
        hinge(
            "leg",
            1,
            0.6,
            [deg(-150.0), 0.0],
            cap([0.0, 0.0, 0.6], [0.0, 0.0, 0.1], 0.04),
        ),
        foot,
    ]
}

pub struct Hopper {
    spec: EnvSpec,
    pub(crate) robot: Robot,
    t: usize,
    rng: Pcg64,
}

impl Default for Hopper {
    fn default() -> Self {
        Self::new()
    }
}

fn build(sim: &SimParams) -> (PhysicsWorld, Articulation) {
    let mut world = new_world(sim);
    add_floor(&mut world, 1.0);
    let robot = Articulation::build(&mut world, RootJoint::Planar, &links());
    (world, robot)
}

impl Hopper {
    pub fn new() -> Self {
        Self::with_sim(SIM)
    }

    /// The hopper with other physics settings (`control_dt` must stay [`SIM`]'s 0.008 s).
    pub fn with_sim(sim: SimParams) -> Self {
        assert_eq!(sim.control_dt, CONTROL_DT);
        Self {
            spec: EnvSpec {
                id: "hopper",
                obs_dim: 11,
                act_dim: 3,
                max_episode_steps: 1000,
                gymnasium_action_scale: 1.0,
            },
            robot: Robot::new(sim, build),
            t: 0,
            rng: Pcg64::seed_from_u64(0),
        }
    }

    /// Starts an episode from a given state (`qpos` = [x, z, pitch, thigh, leg, foot], `qvel`
    /// the matching velocities) in a fresh world.
    pub fn set_state(&mut self, qpos: &[f32; NQ], qvel: &[f32; NQ]) -> Vec<f32> {
        self.robot.restart(qpos, qvel);
        self.t = 0;
        self.obs(&self.qpos(), &self.qvel())
    }

    pub fn qpos(&self) -> Vec<f32> {
        self.robot.qpos()
    }

    pub fn qvel(&self) -> Vec<f32> {
        self.robot.qvel()
    }

    /// Total mass, kg.
    pub fn mass(&self) -> f32 {
        self.robot.mass()
    }

    fn obs(&self, q: &[f32], v: &[f32]) -> Vec<f32> {
        let mut o = Vec::with_capacity(11);
        o.extend_from_slice(&q[1..]);
        o.extend(v.iter().map(|x| x.clamp(-OBS_VEL_CLIP, OBS_VEL_CLIP)));
        o
    }

    fn healthy(q: &[f32], v: &[f32]) -> bool {
        let (z, angle) = (q[1], q[2]);
        let in_range = q[2..].iter().chain(v).all(|x| *x > -100.0 && *x < 100.0);
        in_range && z > 0.7 && angle > -0.2 && angle < 0.2
    }
}

impl Env for Hopper {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: Option<u64>) -> Vec<f32> {
        if let Some(s) = seed {
            self.rng = Pcg64::seed_from_u64(s);
        }
        let mut q = [0.0, INIT_Z, 0.0, 0.0, 0.0, 0.0];
        let mut v = [0.0; NQ];
        for x in q.iter_mut() {
            *x += self.rng.gen_range(-RESET_NOISE..RESET_NOISE);
        }
        for x in v.iter_mut() {
            *x += self.rng.gen_range(-RESET_NOISE..RESET_NOISE);
        }
        self.set_state(&q, &v)
    }

    fn step(&mut self, action: &[f32]) -> Step {
        let a: [f32; 3] = clip_actions(action);
        let torques = a.map(|x| x * GEAR);
        let x_before = self.qpos()[0];
        self.robot.step(&torques);
        self.t += 1;
        let truncated = self.t >= self.spec.max_episode_steps;
        let ctrl_cost = CTRL_COST_WEIGHT * a.iter().map(|x| (*x as f64).powi(2)).sum::<f64>();
        if !self.robot.is_sane() {
            return Step::non_finite_state(self.spec.obs_dim, -ctrl_cost, truncated);
        }
        let (q, v) = (self.qpos(), self.qvel());
        let x_velocity = (q[0] as f64 - x_before as f64) / CONTROL_DT as f64;
        let healthy = Self::healthy(&q, &v);
        let reward = x_velocity + if healthy { HEALTHY_REWARD } else { 0.0 } - ctrl_cost;
        Step {
            obs: self.obs(&q, &v),
            reward,
            terminated: !healthy,
            truncated,
            success: None,
        }
    }

    fn scene(&self) -> Option<crate::scene::Scene> {
        Some(self.robot.scene())
    }

    fn control_dt(&self) -> Option<f64> {
        Some(CONTROL_DT as f64)
    }
    fn physics(&self) -> Option<crate::physics::SimParams> {
        Some(self.robot.sim())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::random_actions;

    /// Runs one episode of `policy` (obs → action) from `seed`; returns (forward progress of
    /// the torso in m, i.e. Σ ẋ·dt, steps, terminated).
    fn episode(
        env: &mut Hopper,
        seed: u64,
        mut policy: impl FnMut(&[f32], usize) -> [f32; 3],
    ) -> (f32, usize, bool) {
        let mut obs = env.reset(Some(seed));
        let x0 = env.qpos()[0];
        for t in 0..env.spec().max_episode_steps {
            let s = env.step(&policy(&obs, t));
            assert!(s.obs.iter().all(|x| x.is_finite()) && s.reward.is_finite());
            obs = s.obs;
            if s.terminated || s.truncated {
                assert!(s.terminated != s.truncated || t + 1 == 1000);
                return (env.qpos()[0] - x0, t + 1, s.terminated);
            }
        }
        unreachable!("the time limit truncates at 1000 steps")
    }

    #[test]
    fn spec_and_obs_length() {
        let mut env = Hopper::new();
        let s = env.spec().clone();
        assert_eq!(
            (s.id, s.obs_dim, s.act_dim, s.max_episode_steps),
            ("hopper", 11, 3, 1000)
        );
        let o = env.reset(Some(0));
        assert_eq!(o.len(), 11);
        // Reset: the model pose plus noise of at most 5e-3.
        assert!(
            (o[0] - 1.25).abs() <= 5e-3 && o[1..].iter().all(|x| x.abs() <= 5e-3),
            "{o:?}"
        );
        assert_eq!(env.step(&[0.0; 3]).obs.len(), 11);
        let m = env.mass();
        assert!((14.0..18.0).contains(&m), "mass {m}");
    }

    #[test]
    fn random_episodes_stay_finite_and_end() {
        let mut env = Hopper::new();
        for seed in 0..8 {
            let acts = random_actions::<3>(seed + 100, 1000);
            let (_, n, _) = episode(&mut env, seed, |_, t| acts[t]);
            assert!(n <= 1000);
        }
        // Saturated bang-bang torques for a whole episode, ignoring termination: no NaN, joint
        // limits held to within 5° (the 16 Hz springs' worst at 4 × 4: thigh 0.022, leg 0.037,
        // foot 0.029 rad; 0.019, 0.031, 0.029 at the previous 8 × 1, 0.026, 0.046, 0.030 at 2 × 4;
        // the hopper's armature of 1 makes them stiff in torque), nothing sinks into the floor.
        env.reset(Some(1));
        for t in 0..1000 {
            let s = if (t / 7) % 2 == 0 { 1.0 } else { -1.0 };
            let st = env.step(&[s, -s, s]);
            assert!(st.obs.iter().all(|x| x.is_finite()) && st.reward.is_finite());
            let q = env.qpos();
            assert!(q[1] > 0.0, "torso centre below the floor: {q:?}");
            assert!(q[3] > deg(-155.0) && q[3] < deg(5.0), "thigh {q:?}");
            assert!(q[4] > deg(-155.0) && q[4] < deg(5.0), "leg {q:?}");
            assert!(q[5] > deg(-50.0) && q[5] < deg(50.0), "foot {q:?}");
        }
        // NaN and out-of-range actions are tolerated.
        env.reset(Some(2));
        let s = env.step(&[f32::NAN, 5.0, -5.0]);
        assert!(s.obs.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn dropped_or_pushed_over_terminates() {
        let mut env = Hopper::new();
        // Dropped from 1.5 m higher with a slight lean (0.05 rad): healthy through the free
        // fall (~0.55 s), lands on the foot without passing through the floor, then topples and
        // terminates (measured: step ~115 of 8 ms). Perfectly upright (pitch 0) it lands and
        // balances for ~340 steps before toppling: straight joints at their 0 limits make it a
        // rigid inverted pendulum.
        env.set_state(&[0.0, 1.25 + 1.5, 0.05, 0.0, 0.0, 0.0], &[0.0; NQ]);
        let mut end = None;
        let mut min_z = f32::MAX;
        for t in 0..250 {
            let s = env.step(&[0.0; 3]);
            min_z = min_z.min(env.qpos()[1]);
            if t < 60 {
                assert!(!s.terminated, "terminated in free fall at step {t}");
            }
            if s.terminated {
                assert!(!s.truncated && s.reward < 1.0);
                end = Some(t);
                break;
            }
        }
        assert!(end.is_some(), "a 1.5 m drop never terminated");
        assert!(
            min_z > 1.0,
            "the robot sank into the floor on landing: z {min_z}"
        );
        // Pushed over: pitch 0.5 rad is already unhealthy.
        env.set_state(&[0.0, 1.25, 0.5, 0.0, 0.0, 0.0], &[0.0; NQ]);
        let s = env.step(&[0.0; 3]);
        assert!(s.terminated && !s.truncated);
        // A small lean falls past |pitch| 0.2 within a second.
        env.set_state(
            &[0.0, 1.25, 0.15, 0.0, 0.0, 0.0],
            &[0.0, 0.0, 0.5, 0.0, 0.0, 0.0],
        );
        assert!((0..125).any(|_| env.step(&[0.0; 3]).terminated));
    }

    use crate::gaits::{hopper as gait, HOPPER as GAIT};

    #[test]
    fn scripted_gait_beats_standing_still() {
        let mut env = Hopper::new();
        let (mut still, mut moving) = (0.0, 0.0);
        for seed in 0..3 {
            still += episode(&mut env, seed, |_, _| [0.0; 3]).0;
            let (d, n, _) = episode(&mut env, seed, |o, _| gait(o));
            assert!(n >= 500, "the gait fell after {n} steps");
            moving += d;
        }
        assert!(
            moving > still + 0.75,
            "gait {moving} m vs standing {still} m (3 episodes)"
        );
    }

    // Random-policy episode lengths. Gymnasium's Hopper-v5 (MuJoCo) random-policy episodes are
    // typically ~10–50 steps (mean about 20). Measured here over 20 episodes (uniform [−1, 1]
    // actions): lengths 8–69, median 15, mean 21 (rapier's
    // contacts and joint limits are stiffer than MuJoCo's soft ones, yet the band is the same).
    #[test]
    fn random_policy_episode_length_is_plausible() {
        let mut env = Hopper::new();
        let lens: Vec<usize> = (0..20)
            .map(|seed| {
                let acts = random_actions::<3>(seed + 1000, 1000);
                episode(&mut env, seed, |_, t| acts[t]).1
            })
            .collect();
        let mean = lens.iter().sum::<usize>() as f64 / lens.len() as f64;
        assert!(
            (12.0..45.0).contains(&mean),
            "mean random episode length {mean}: {lens:?}"
        );
        assert!(lens.iter().all(|n| (5..300).contains(n)), "{lens:?}");
    }

    #[test]
    fn standing_still_is_healthy_at_first() {
        let mut env = Hopper::new();
        for seed in 0..3 {
            env.reset(Some(seed));
            for t in 0..20 {
                let s = env.step(&[0.0; 3]);
                assert!(
                    !s.terminated,
                    "seed {seed}: unhealthy at step {t} standing still"
                );
                assert!(
                    s.reward > 0.8 && s.reward < 1.2,
                    "reward {} at {t}",
                    s.reward
                );
            }
            let q = env.qpos();
            // Landed on the foot (the model starts 4 cm up): torso centre near 1.21 m.
            assert!((q[1] - 1.21).abs() < 0.02, "{q:?}");
        }
    }

    /// Issue 32's reward band: a uniform random policy's and a standing (zero-action) policy's
    /// mean returns over seeds 0–9. The bands are our own measurement at [`SIM`] (random 15.8,
    /// standing 143.8 at 4 × 4 with the limit springs; 15.5 and 133.8 at 8 × 1 with them, 15.4
    /// and 122.3 at 2 × 4, 16.1
    /// and 163.0 at 1 × 8 with hard limits before),
    /// widened by about half, not a MuJoCo measurement: a physics or reward change that moves
    /// either far (a reward paying for an exploit, standing that no longer stands) fails here.
    #[test]
    fn random_and_standing_returns_stay_in_band() {
        let mut env = Hopper::new();
        let (random, standing) =
            crate::testing::random_and_standing_returns::<_, 3>(&mut env, 0..10);
        println!("hopper: random {random:.1}, standing {standing:.1}");
        assert!(
            (8.0..32.0).contains(&random),
            "random-policy mean return {random}"
        );
        assert!(
            (80.0..330.0).contains(&standing),
            "standing mean return {standing}"
        );
    }

    /// How [`GAIT`] was found: hill-climbing `W·obs + b` on the mean return of seeds 100–102 at
    /// [`SIM`], from the previous gait, Gaussian steps of 0.05 (seeded, so reproducible): `cargo
    /// test --release -p selkd-envs hopper::tests::climb_gait -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn climb_gait() {
        let mut env = Hopper::new();
        let score = |w: &[f32; 36]| {
            (100..103)
                .map(|s| {
                    let p = |o: &[f32]| -> [f32; 3] {
                        std::array::from_fn(|i| {
                            w[33 + i] + (0..11).map(|j| w[i * 11 + j] * o[j]).sum::<f32>()
                        })
                    };
                    crate::testing::rollout(&mut env, s, |o, _| p(o).to_vec()).ret
                })
                .sum::<f64>()
                / 3.0
        };
        let mut rng = Pcg64::seed_from_u64(32);
        let perturb = |w: &mut [f32; 36], rng: &mut Pcg64| {
            for x in w.iter_mut() {
                *x += 0.05 * (rng.gen::<f32>() + rng.gen::<f32>() + rng.gen::<f32>() - 1.5) * 2.0;
            }
        };
        let (best, best_score) = crate::testing::hill_climb(GAIT, 400, &mut rng, perturb, score);
        println!("{best_score:.1} {best:?}");
    }
}
