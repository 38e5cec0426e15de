//! Gymnasium's `Ant-v5` task on rapier3d physics (see [`crate::physics`]): a four-legged robot
//! on a free-floating torso learns to walk forward along +x. Registered as `ant` (alias `Ant-v5`;
//! the 27-dim observation without contact forces, the SELKD default) and `ant-contacts` (the
//! 105-dim observation of Gymnasium's v5 default, with the 78 contact-force terms).
//!
//! Kept from Gymnasium v5 (meaning, not MuJoCo's exact dynamics):
//! - MuJoCo's `ant.xml` geometry, Z up: torso sphere r 0.25 at z 0.75 with four r 0.08 capsules
//!   to (±0.2, ±0.2) (MuJoCo's jointless leg bodies, welded to the torso); per leg a hip hinge
//!   about +Z at (±0.2, ±0.2), range ±30°, carrying a capsule to (±0.4, ±0.4), and an ankle hinge
//!   at (±0.4, ±0.4) about the XML's axis (`-1 1 0` or `1 1 0`), range [30°, 70°] or
//!   [−70°, −30°], carrying a capsule to (±0.8, ±0.8). Density 5, so 0.91088 kg in all, as
//!   MuJoCo's (measured with mujoco: 0.9108801 kg; torso 0.32725, thigh 0.03916, shin 0.06759).
//!   Hinges: armature 1, damping 1 (the XML's joint defaults). Friction 1 (floor and geoms).
//! - State in MuJoCo's layout: `qpos` (15) = torso x, y, z, quaternion w x y z, then hip_1,
//!   ankle_1, …, hip_4, ankle_4; `qvel` (14) = torso world linear velocity, body-frame angular
//!   velocity, 8 joint rates.
//! - Observation: `qpos[2:]` (13) + `qvel` (14) = 27; `ant-contacts` appends MuJoCo's
//!   `cfrc_ext[1:]` clipped to ±1 (as v5's `contact_forces` property clips it): 13 bodies × 6
//!   (`[torque; force]`, world frame, about the robot's centre of mass) in MuJoCo's body order
//!   torso, then per leg 1..4 the welded leg capsule, the hip link, the ankle link.
//! - Action (8) in [−1, 1] (clipped; NaN → 0), × gear 150 → joint torque, N·m, in the XML's
//!   actuator order hip_4, ankle_4, hip_1, ankle_1, hip_2, ankle_2, hip_3, ankle_3.
//! - Control dt 0.05 s (MuJoCo 0.01 × frame_skip 5). Reward = ẋ (torso x over the step / dt),
//!   plus 1 if healthy, − 0.5‖a‖² − 5e-4‖clip(cfrc_ext, ±1)‖² (the contact cost in both
//!   variants, as in Gymnasium v5). Healthy: torso z ∈ [0.2, 1.0] and the state finite; unhealthy
//!   terminates; 1000 steps truncates. As in Gymnasium, lying on its back is healthy.
//! - Reset: the model pose plus U(±0.1) on every `qpos` entry (the quaternion is renormalised)
//!   and 0.1·N(0, 1) on every `qvel` entry.
//!
//! Deliberate deviation: MuJoCo's model pose has the ankles at 0, outside their own ranges;
//! MuJoCo's soft limits ease them in, but rapier's hard limits would kick the robot. The ankles
//! start at the nearest limit (±30°) with the reset noise folded into the range (|U(±0.1)|
//! inward). The robot then falls ~0.4 m onto its feet, as in MuJoCo.
//!
//! Contact forces ([`crate::physics::colliders_contact_wrench`]): normal and friction forces of
//! the last rapier step of the control step, about the robot's centre of mass (MuJoCo's
//! `cfrc_ext` is about the centre of mass of the body's kinematic tree, which is the whole ant).
//! MuJoCo's soft contacts and rapier's rigid ones differ in detail (MuJoCo also reports forces
//! from within its 0.01 m contact margin).
//!
//! Measured (this 2-core machine shared with other jobs, load average 4–6, same sitting):
//! - Speed, `selkd bench env ant` against Gymnasium `Ant-v5` (MuJoCo, its default 105-dim
//!   observation, single thread, random actions), six sittings interleaved: 1.3–2.1× (e.g.
//!   3.64k/2.45k, 3.56k/1.69k env steps/s). `ant-contacts` costs the same (the contact terms
//!   are computed for the reward in both).
//! - Mass 0.91088 kg, as MuJoCo's. Standing (zero action, 200 steps from seed 0): torso z
//!   0.363 m; MuJoCo 0.382 m. Standing still, the vertical contact forces sum to 98% of m·g after
//!   200 steps (MuJoCo: 100%).
//! - Random-policy episode lengths (uniform actions, 50 episodes): here median 176, 16–1000
//!   (10th/90th percentiles 59/1000, 6 of 50 reach the 1000-step limit, mean 269); MuJoCo
//!   Ant-v5: median 67, 12–1000 (percentiles 20/258, mean 114). The rapier ant is harder to
//!   bounce out of the healthy range (most MuJoCo episodes end with the torso thrown above
//!   1.0 m): its contacts are rigid where MuJoCo's are soft and springy. Returns of the two are
//!   therefore not comparable number for number.
//! - An open-loop trot (tests) goes 5.6–7.7 m in 200 steps on seeds 0–2; standing still drifts
//!   < 0.04 m.
//!
//! A state that goes non-finite terminates the episode with a zero observation: the env never
//! emits NaN.

use crate::physics::{
    add_floor, clip_actions, colliders_contact_wrench, new_world, Articulation, Geom, LinkDesc,
    Robot, RootJoint, SimParams, RAPIER_LIMIT_FREQUENCY,
};
use crate::{Env, EnvSpec, Step};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64;
use rapier3d::prelude::{ColliderHandle, PhysicsWorld};

const GEAR: f32 = 150.0;
const CONTROL_DT: f32 = 0.05;
/// Physics integration per control step: 5 rapier steps of 10 ms (MuJoCo's own timestep) with 1
/// solver iteration each, and a contact prediction distance of 0.1 m (contacts are found before
/// the fast, light feet reach the floor).
///
/// Measured (`tests::sim_settings`: 30 random episodes; 400 steps of saturated bang-bang
/// torques ignoring termination; rapier steps × iterations):
///
/// | setting | bang-bang: worst limit overshoot, deepest sinking | random median length | speed vs 5×2 |
/// |---|---|---|---|
/// | 5×2 | 0.067 rad, 1.4 mm | 310 | 1 |
/// | **5×1** | 0.103 rad, 7 mm | 186 | 1.55× |
/// | 3×2 | 0.111 rad, 107 mm | 240 | 1.8× |
/// | 2×2 | 0.181 rad, 193 mm | 187 | 2.8× |
/// | 2×1 | 0.480 rad, 291 mm | 73 | 4.7× |
///
/// Fewer than 5 rapier steps let the feet sink centimetres into the floor; 5×1 holds the limits
/// better under bang-bang torques than MuJoCo's soft limits do under random actions (0.17 rad
/// worst over 30 `Ant-v5` episodes), and each rapier step's contact forces still equal the
/// robot's momentum change (`tests::contact_forces_match_the_momentum_change`), so the
/// 5×1 setting's 1.55× speed costs nothing the task observes. Learning, SELKD with 2 actors for
/// 20k env steps (seeds 1–2): best-actor returns 373–590 at 5×1, 559–677 at 5×2, both mostly
/// the healthy reward (no ant walks yet at that budget): no sign of a gap, on a short run.
pub const SIM: SimParams = SimParams {
    control_dt: CONTROL_DT,
    substeps: 5,
    solver_iterations: 1,
    prediction_distance: PREDICTION_DISTANCE,
    limit_frequency: RAPIER_LIMIT_FREQUENCY,
    implicit_limits: false,
    stabilization_iterations: crate::physics::RAPIER_STABILIZATION_ITERATIONS,
    pgs_iterations: crate::physics::RAPIER_PGS_ITERATIONS,
    contact_frequency: None,
    contact_damping_ratio: None,
};
const PREDICTION_DISTANCE: f32 = 0.1;
const INIT_Z: f32 = 0.75;
const RESET_NOISE: f32 = 0.1;
const CTRL_COST_WEIGHT: f64 = 0.5;
const CONTACT_COST_WEIGHT: f64 = 5e-4;
const HEALTHY_REWARD: f64 = 1.0;
const HEALTHY_Z: [f32; 2] = [0.2, 1.0];
/// `qpos` (free root 7 + 8 hinges) and `qvel` lengths.
pub const NQ: usize = 15;
pub const NV: usize = 14;
/// MuJoCo bodies with contact forces (all but the world), 6 numbers each.
const CONTACT_BODIES: usize = 13;
const OBS_DIM: usize = 27;
const OBS_DIM_CONTACTS: usize = OBS_DIM + 6 * CONTACT_BODIES;
/// Link of each action entry (the XML's actuator order); links are torso, hip_1, ankle_1, …,
/// hip_4, ankle_4.
const ACTUATED_LINK: [usize; 8] = [7, 8, 1, 2, 3, 4, 5, 6];

fn deg(d: f32) -> f32 {
    d.to_radians()
}

/// Leg directions in the x–y plane, the ankle axis and range, legs 1..4 of `ant.xml`.
const LEGS: [([f32; 2], [f32; 3], [f32; 2]); 4] = [
    ([1.0, 1.0], [-1.0, 1.0, 0.0], [30.0, 70.0]),
    ([-1.0, 1.0], [1.0, 1.0, 0.0], [-70.0, -30.0]),
    ([-1.0, -1.0], [-1.0, 1.0, 0.0], [-70.0, -30.0]),
    ([1.0, -1.0], [1.0, 1.0, 0.0], [30.0, 70.0]),
];

/// The ankle angle nearest to MuJoCo's rest angle 0 within its range (see the module doc).
fn ankle_rest(leg: usize) -> f32 {
    let r = LEGS[leg].2;
    deg(if r[0] > 0.0 { r[0] } else { r[1] })
}

/// The ant's links, MuJoCo's `ant.xml` in its rest pose (all joints at 0, torso at z 0.75).
pub fn links() -> Vec<LinkDesc> {
    let z = INIT_Z;
    let at = |d: [f32; 2], s: f32| [d[0] * s, d[1] * s, z];
    let cap = |a, b| Geom::capsule(a, b, 0.08);
    let mut torso_geoms = vec![Geom::Sphere {
        c: [0.0, 0.0, z],
        r: 0.25,
    }];
    torso_geoms.extend(LEGS.iter().map(|(d, _, _)| cap(at(*d, 0.0), at(*d, 0.2))));
    let joint = |l: LinkDesc, range: [f32; 2]| LinkDesc {
        range: Some([deg(range[0]), deg(range[1])]),
        density: 5.0,
        armature: 1.0,
        damping: 1.0,
        ..l
    };
    let mut links = vec![LinkDesc {
        density: 5.0,
        ..LinkDesc::root("torso", [0.0, 0.0, z], torso_geoms)
    }];
    const HIPS: [&str; 4] = ["hip_1", "hip_2", "hip_3", "hip_4"];
    const ANKLES: [&str; 4] = ["ankle_1", "ankle_2", "ankle_3", "ankle_4"];
    for (k, (d, axis, range)) in LEGS.iter().enumerate() {
        let hip = LinkDesc::hinge(
            HIPS[k],
            0,
            at(*d, 0.2),
            [0.0, 0.0, 1.0],
            vec![cap(at(*d, 0.2), at(*d, 0.4))],
        );
        links.push(joint(hip, [-30.0, 30.0]));
        let ankle = LinkDesc::hinge(
            ANKLES[k],
            links.len() - 1,
            at(*d, 0.4),
            *axis,
            vec![cap(at(*d, 0.4), at(*d, 0.8))],
        );
        links.push(joint(ankle, *range));
    }
    links
}

/// Which observation an [`Ant`] gives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AntObs {
    /// `qpos[2:]` + `qvel`: 27 numbers (`ant`).
    State,
    /// Also the 78 clipped contact-force terms: 105 numbers (`ant-contacts`).
    WithContacts,
}

pub struct Ant {
    spec: EnvSpec,
    obs_kind: AntObs,
    pub(crate) robot: Robot,
    /// The colliders of each MuJoCo body that reports contact forces, in MuJoCo's order.
    contact_bodies: Vec<Vec<ColliderHandle>>,
    t: usize,
    rng: Pcg64,
}

impl Default for Ant {
    fn default() -> Self {
        Self::new()
    }
}

fn build(sim: &SimParams) -> (PhysicsWorld, Articulation) {
    let mut world = new_world(sim);
    add_floor(&mut world, 1.0);
    let robot = Articulation::build(&mut world, RootJoint::Free, &links());
    (world, robot)
}

/// The colliders of MuJoCo's bodies: torso (the sphere), then per leg its welded capsule (a
/// torso collider), the hip link and the ankle link.
fn contact_bodies(robot: &Articulation) -> Vec<Vec<ColliderHandle>> {
    let torso = robot.colliders(0);
    let mut bodies = vec![vec![torso[0]]];
    for k in 0..4 {
        bodies.push(vec![torso[1 + k]]);
        bodies.push(robot.colliders(1 + 2 * k).to_vec());
        bodies.push(robot.colliders(2 + 2 * k).to_vec());
    }
    bodies
}

impl Ant {
    /// `ant`: the 27-dim observation.
    pub fn new() -> Self {
        Self::with_obs(AntObs::State)
    }

    /// `ant-contacts`: the 105-dim observation of Gymnasium's `Ant-v5` default.
    pub fn with_contacts() -> Self {
        Self::with_obs(AntObs::WithContacts)
    }

    pub fn with_obs(obs_kind: AntObs) -> Self {
        Self::with_sim(obs_kind, SIM)
    }

    /// The ant with other physics settings (`control_dt` must stay [`SIM`]'s 0.05 s).
    pub fn with_sim(obs_kind: AntObs, sim: SimParams) -> Self {
        assert_eq!(sim.control_dt, CONTROL_DT);
        let robot = Robot::new(sim, build);
        let (id, obs_dim) = match obs_kind {
            AntObs::State => ("ant", OBS_DIM),
            AntObs::WithContacts => ("ant-contacts", OBS_DIM_CONTACTS),
        };
        Self {
            spec: EnvSpec {
                id,
                obs_dim,
                act_dim: 8,
                max_episode_steps: 1000,
                gymnasium_action_scale: 1.0,
            },
            obs_kind,
            contact_bodies: contact_bodies(&robot.links),
            robot,
            t: 0,
            rng: Pcg64::seed_from_u64(0),
        }
    }

    /// Starts an episode from a given state (MuJoCo's `qpos`/`qvel` layout) in a fresh world.
    pub fn set_state(&mut self, qpos: &[f32; NQ], qvel: &[f32; NV]) -> Vec<f32> {
        self.robot.restart(qpos, qvel);
        self.contact_bodies = contact_bodies(&self.robot.links);
        self.t = 0;
        if !self.robot.is_sane() {
            return vec![0.0; self.spec.obs_dim];
        }
        let contacts = self.contact_forces();
        self.obs(&self.qpos(), &self.qvel(), &contacts)
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

    /// MuJoCo's `cfrc_ext[1:]` from the last rapier step, unclipped: 13 bodies × `[torque;
    /// force]`, world frame, about the robot's centre of mass.
    pub fn contact_forces(&self) -> Vec<[f32; 6]> {
        let com = self.robot.links.center_of_mass(&self.robot.world);
        self.contact_bodies
            .iter()
            .map(|cs| colliders_contact_wrench(&self.robot.world, cs, com))
            .collect()
    }

    fn obs(&self, q: &[f32], v: &[f32], contacts: &[[f32; 6]]) -> Vec<f32> {
        let mut o = Vec::with_capacity(self.spec.obs_dim);
        o.extend_from_slice(&q[2..]);
        o.extend_from_slice(v);
        if self.obs_kind == AntObs::WithContacts {
            o.extend(contacts.iter().flatten().map(|x| x.clamp(-1.0, 1.0)));
        }
        o
    }
}

impl Env for Ant {
    fn scene(&self) -> Option<crate::scene::Scene> {
        Some(self.robot.scene())
    }

    fn control_dt(&self) -> Option<f64> {
        Some(CONTROL_DT as f64)
    }
    fn physics(&self) -> Option<crate::physics::SimParams> {
        Some(self.robot.sim())
    }

    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: Option<u64>) -> Vec<f32> {
        if let Some(s) = seed {
            self.rng = Pcg64::seed_from_u64(s);
        }
        let mut q = [0.0f32; NQ];
        q[2] = INIT_Z;
        q[3] = 1.0;
        for x in q.iter_mut() {
            *x += self.rng.gen_range(-RESET_NOISE..RESET_NOISE);
        }
        for leg in 0..4 {
            // The ankle starts at its limit nearest MuJoCo's 0, the noise folded inward.
            let rest = ankle_rest(leg);
            let i = 8 + 2 * leg;
            q[i] = rest + rest.signum() * (q[i] - 0.0).abs();
        }
        let mut v = [0.0f32; NV];
        for x in v.iter_mut() {
            *x = RESET_NOISE * self.rng.sample::<f32, _>(StandardNormal);
        }
        self.set_state(&q, &v)
    }

    fn step(&mut self, action: &[f32]) -> Step {
        let a: [f32; 8] = clip_actions(action);
        let mut torques = [0.0f32; 8];
        for (k, &link) in ACTUATED_LINK.iter().enumerate() {
            torques[link - 1] = a[k] * GEAR;
        }
        let x_before = self.qpos()[0];
        self.robot.step(&torques);
        self.t += 1;
        let truncated = self.t >= self.spec.max_episode_steps;
        let ctrl_cost = CTRL_COST_WEIGHT * a.iter().map(|x| (*x as f64).powi(2)).sum::<f64>();
        if !self.robot.is_sane() {
            return Step::non_finite_state(self.spec.obs_dim, -ctrl_cost, truncated);
        }
        let (q, v) = (self.qpos(), self.qvel());
        let contacts = self.contact_forces();
        let contact_cost = CONTACT_COST_WEIGHT
            * contacts
                .iter()
                .flatten()
                .map(|x| (x.clamp(-1.0, 1.0) as f64).powi(2))
                .sum::<f64>();
        let x_velocity = (q[0] as f64 - x_before as f64) / CONTROL_DT as f64;
        let healthy = (HEALTHY_Z[0]..=HEALTHY_Z[1]).contains(&q[2]);
        let reward =
            x_velocity + if healthy { HEALTHY_REWARD } else { 0.0 } - ctrl_cost - contact_cost;
        Step {
            obs: self.obs(&q, &v, &contacts),
            reward,
            terminated: !healthy,
            truncated,
            success: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::random_actions;

    /// Runs one episode of `policy` (step → action) from `seed`; returns (torso x progress in
    /// m, steps, terminated).
    fn episode(
        env: &mut Ant,
        seed: u64,
        mut policy: impl FnMut(usize) -> [f32; 8],
    ) -> (f32, usize, bool) {
        env.reset(Some(seed));
        let x0 = env.qpos()[0];
        for t in 0..1000 {
            let s = env.step(&policy(t));
            assert!(s.obs.iter().all(|x| x.is_finite()) && s.reward.is_finite());
            if s.terminated || s.truncated {
                return (env.qpos()[0] - x0, t + 1, s.terminated);
            }
        }
        unreachable!()
    }

    /// An open-loop trot: diagonal leg pairs (1, 3) and (2, 4) swing their hips in antiphase,
    /// each ankle lifting (toward its 30° limit) while its hip swings forward.
    fn trot(t: usize, p: [f32; 4]) -> [f32; 8] {
        let [w, phase, hip_amp, ank_amp] = p;
        let s = (w * t as f32).sin();
        let c = (w * t as f32 + phase).sin();
        // Per leg k (1..4): hip sign, ankle sign (the lift direction of the ankle range).
        let mut a = [0.0f32; 8];
        for leg in 0..4 {
            let pair = if leg % 2 == 0 { 1.0 } else { -1.0 };
            let lift = -ankle_rest(leg).signum();
            // A positive hip angle moves the feet of legs 1 and 2 (front, +x) backward, those
            // of legs 3 and 4 forward.
            let back = if leg < 2 { 1.0 } else { -1.0 };
            let hip = hip_amp * back * pair * s;
            let ankle = ank_amp * lift * pair * c;
            // Actions in actuator order: hip_4, ankle_4, hip_1, ankle_1, ...
            let k = (leg + 1) % 4;
            a[2 * k] = hip;
            a[2 * k + 1] = ankle;
        }
        a
    }

    /// The open-loop trot of [`trot`] (frequency in rad per step, ankle phase, hip and ankle
    /// amplitudes), the best worst-case distance over seeds 0–2 of a grid search (6 frequencies
    /// × 8 phases × 6 hip × 3 ankle amplitudes), started after 10 steps of settling.
    const TROT: [f32; 4] = [1.0, std::f32::consts::PI, 0.7, 0.2];

    #[test]
    fn spaces_sizes_and_mass() {
        for (mut env, id, dim) in [
            (Ant::new(), "ant", 27),
            (Ant::with_contacts(), "ant-contacts", 105),
        ] {
            let s = env.spec().clone();
            assert_eq!(
                (s.id, s.obs_dim, s.act_dim, s.max_episode_steps),
                (id, dim, 8, 1000)
            );
            let o = env.reset(Some(0));
            assert_eq!(o.len(), dim);
            assert_eq!(env.step(&[0.0; 8]).obs.len(), dim);
            assert_eq!((env.qpos().len(), env.qvel().len()), (NQ, NV));
            // MuJoCo's mass for ant.xml (density 5): 0.9108801 kg.
            let m = env.mass();
            assert!((m - 0.91088).abs() < 1e-3, "mass {m}");
        }
        // Reset: torso near z 0.75, quaternion near identity, ankles inside their ranges.
        let mut env = Ant::new();
        for seed in 0..5 {
            env.reset(Some(seed));
            let q = env.qpos();
            assert!((q[2] - 0.75).abs() <= 0.1 && q[3] > 0.95, "{q:?}");
            for leg in 0..4 {
                let [lo, hi] = LEGS[leg].2.map(deg);
                let a = q[8 + 2 * leg];
                assert!(a >= lo - 1e-4 && a <= hi + 1e-4, "ankle {leg}: {a}");
            }
        }
    }

    #[test]
    fn random_episodes_stay_finite() {
        let mut env = Ant::with_contacts();
        for seed in 0..4 {
            let acts = random_actions::<8>(seed + 100, 1000);
            let (_, n, _) = episode(&mut env, seed, |t| acts[t]);
            assert!(n <= 1000);
        }
        // Saturated bang-bang torques, ignoring termination: no NaN, limits held, nothing sinks.
        env.reset(Some(1));
        for t in 0..400 {
            let s = if (t / 3) % 2 == 0 { 1.0 } else { -1.0 };
            let st = env.step(&[s, -s, s, s, -s, -s, s, -s]);
            assert!(st.obs.iter().all(|x| x.is_finite()) && st.reward.is_finite());
            let q = env.qpos();
            assert!(q[2] > 0.0, "torso below the floor: {q:?}");
            for leg in 0..4 {
                let h = q[7 + 2 * leg];
                assert!(h.abs() < deg(33.0), "hip {leg}: {h}");
            }
        }
        // NaN and out-of-range actions are tolerated.
        env.reset(Some(2));
        let s = env.step(&[f32::NAN, 5.0, -5.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(s.obs.iter().all(|x| x.is_finite()));
    }

    /// The rest pose with the ankles at their nearest limits, torso at height `z`.
    fn pose(z: f32) -> [f32; NQ] {
        let mut q = [0.0; NQ];
        q[2] = z;
        q[3] = 1.0;
        for leg in 0..4 {
            q[8 + 2 * leg] = ankle_rest(leg);
        }
        q
    }

    #[test]
    fn termination_follows_the_healthy_z_range() {
        let mut env = Ant::new();
        // Too high (z > 1.0): unhealthy at once.
        env.set_state(&pose(1.3), &[0.0; NV]);
        let s = env.step(&[0.0; 8]);
        assert!(s.terminated && !s.truncated && s.reward < 0.5, "{s:?}");
        // Dropped from 0.95: healthy through the fall and the landing.
        env.set_state(&pose(0.95), &[0.0; NV]);
        for t in 0..40 {
            assert!(!env.step(&[0.0; 8]).terminated, "terminated at {t}");
        }
        // Thrown up at 6 m/s: it leaves the range and terminates.
        let mut v = [0.0; NV];
        v[2] = 6.0;
        env.set_state(&pose(0.75), &v);
        assert!((0..20).any(|_| env.step(&[0.0; 8]).terminated));
        // Flipped onto its back: healthy, as in Gymnasium (z stays in range).
        let mut q = pose(0.7);
        (q[3], q[4]) = (0.0, 1.0);
        env.set_state(&q, &[0.0; NV]);
        for _ in 0..40 {
            assert!(!env.step(&[0.0; 8]).terminated);
        }
        let q = env.qpos();
        assert!(q[2] > 0.2 && q[2] < 0.5 && q[4].abs() > 0.9, "{q:?}");
        // A non-finite state terminates with a zero observation.
        let mut v = [0.0; NV];
        v[0] = f32::NAN;
        env.set_state(&pose(0.75), &v);
        let s = env.step(&[0.0; 8]);
        assert!(s.terminated && s.obs.iter().all(|x| *x == 0.0));
    }

    #[test]
    fn open_loop_trot_beats_standing_still() {
        let mut env = Ant::new();
        let run = |env: &mut Ant, seed, gait: bool| {
            env.reset(Some(seed));
            // Lands on its feet first (the reset pose is ~0.4 m up).
            for _ in 0..10 {
                env.step(&[0.0; 8]);
            }
            let (x0, mut reward) = (env.qpos()[0], 0.0);
            for t in 0..200 {
                let a = if gait { trot(t, TROT) } else { [0.0; 8] };
                let s = env.step(&a);
                assert!(!s.terminated, "seed {seed} gait {gait}: fell at {t}");
                reward += s.reward;
            }
            (env.qpos()[0] - x0, reward)
        };
        for seed in 0..3 {
            let (d_still, r_still) = run(&mut env, seed, false);
            let (d_trot, r_trot) = run(&mut env, seed, true);
            assert!(d_still.abs() < 0.3, "standing drifted {d_still} m");
            assert!(d_trot > 2.5, "trot went {d_trot} m");
            // The forward reward Σ ẋ is the distance / dt; the trot also pays its control cost.
            let (f_trot, f_still) = (d_trot / CONTROL_DT, d_still / CONTROL_DT);
            assert!(
                f_trot > f_still + 80.0,
                "forward reward {f_trot} vs {f_still}"
            );
            println!("seed {seed}: trot {d_trot} m, reward {r_trot}; standing {d_still} m, reward {r_still}");
        }
    }

    #[test]
    fn random_episode_length_in_band() {
        let mut env = Ant::new();
        let mut lens: Vec<usize> = (0..20)
            .map(|seed| {
                let acts = random_actions::<8>(seed + 1000, 1000);
                episode(&mut env, seed, |t| acts[t]).1
            })
            .collect();
        lens.sort();
        let median = lens[10];
        assert!((120..=600).contains(&median), "{lens:?}");
        assert!(lens[0] >= 15, "{lens:?}");
    }

    #[test]
    fn contact_forces_zero_in_the_air_and_carry_the_weight_standing() {
        let mut env = Ant::with_contacts();
        env.set_state(&pose(0.95), &[0.0; NV]);
        let s = env.step(&[0.0; 8]);
        assert!(s.obs[27..].iter().all(|x| *x == 0.0), "{:?}", &s.obs[27..]);
        assert!(env.contact_forces().iter().flatten().all(|x| *x == 0.0));
        let mut last = s;
        for _ in 0..100 {
            last = env.step(&[0.0; 8]);
        }
        let cf = env.contact_forces();
        let up: f32 = cf.iter().map(|w| w[5]).sum();
        let weight = env.mass() * 9.81;
        assert!((up - weight).abs() < 0.05 * weight, "{up} N vs {weight} N");
        // Standing on the four feet only (the ankle links: bodies 3, 6, 9, 12). The net friction
        // of the last rapier step is not zero: the feet's friction jitters from one 10 ms step
        // to the next (~1.8 N net here, while the torso's velocity stays below 0.03 m/s).
        for (b, w) in cf.iter().enumerate() {
            assert_eq!(w[5] > 0.5, b % 3 == 0 && b > 0, "body {b}: {w:?}");
        }
        let side: f32 = cf
            .iter()
            .map(|w| w[3])
            .sum::<f32>()
            .hypot(cf.iter().map(|w| w[4]).sum());
        assert!(side < 0.3 * weight, "net friction {side} N");
        // The observation holds the same terms clipped to ±1; the reward pays their cost.
        let obs_c = &last.obs[27..];
        for (o, w) in obs_c.iter().zip(cf.iter().flatten()) {
            assert_eq!(*o, w.clamp(-1.0, 1.0));
        }
        let cost: f64 = 5e-4 * obs_c.iter().map(|x| (*x as f64).powi(2)).sum::<f64>();
        assert!(
            cost > 0.0 && (last.reward - (1.0 - cost)).abs() < 0.05,
            "{}",
            last.reward
        );
    }

    /// Prints the standing height and the random-policy episode-length band (50 episodes).
    #[test]
    #[ignore]
    fn measure() {
        let mut env = Ant::new();
        env.reset(Some(0));
        for _ in 0..200 {
            env.step(&[0.0; 8]);
        }
        println!("standing z {} x {}", env.qpos()[2], env.qpos()[0]);
        let mut lens: Vec<usize> = (0..50)
            .map(|s| {
                let acts = random_actions::<8>(s + 1000, 1000);
                episode(&mut env, s, |t| acts[t]).1
            })
            .collect();
        lens.sort();
        let mean = lens.iter().sum::<usize>() as f64 / 50.0;
        println!("random lens {lens:?} median {} mean {mean}", lens[25]);
    }

    /// Newton, per rapier step: the vertical contact force the observation reports equals the
    /// robot's momentum change plus its weight, under random torques.
    #[test]
    fn contact_forces_match_the_momentum_change() {
        let mut env = Ant::with_contacts();
        // Σ m·v over the links, from the links' kinematic velocities and centres of mass.
        let momentum = |env: &Ant| {
            let vels = env.robot.links.link_velocities(&env.robot.world);
            let bodies = env.robot.links.bodies.iter().zip(vels);
            bodies.fold(rapier3d::prelude::Vector::ZERO, |p, (&h, (w, v))| {
                let rb = &env.robot.world.bodies[h];
                let o = rb.position().translation;
                let c = rb.position().transform_point(rb.local_center_of_mass());
                p + (v + w.cross(c - o)) * rb.mass()
            })
        };
        let dt = env.robot.world.integration_parameters.dt;
        let (mut errors, mut off) = (vec![], 0);
        for seed in 0..20 {
            env.reset(Some(seed));
            for a in random_actions::<8>(seed + 7, 40) {
                let torques = a.map(|x| GEAR * x);
                let p0 = momentum(&env);
                env.robot
                    .links
                    .apply_joint_torques(&mut env.robot.world, &torques);
                env.robot.world.step();
                let want = (momentum(&env) - p0).z / dt + 9.81 * env.mass();
                let fz: f32 = env.contact_forces().iter().map(|w| w[5]).sum();
                if fz > 0.0 {
                    errors.push((fz - want).abs());
                    off += ((fz - want).abs() > 0.1 * want.abs() + 1.0) as usize;
                }
            }
        }
        errors.sort_by(f32::total_cmp);
        let n = errors.len();
        // The weight is 8.9 N.
        assert!(n > 100, "only {n} steps on the floor");
        assert!(errors[n / 2] < 0.3, "median error {} N", errors[n / 2]);
        assert!(
            off * 50 <= n,
            "{off} of {n} steps off by more than 10% + 1 N"
        );
    }

    /// Compares physics settings (rapier steps × iterations per control step): joint-limit
    /// overshoot and sinking under saturated bang-bang torques, the random-policy episode
    /// length, the trot, and speed. A measurement run by hand; its numbers are in [`SIM`]'s doc.
    #[test]
    #[ignore]
    fn sim_settings() {
        let ranges: Vec<[f32; 2]> = links().iter().skip(1).map(|l| l.range.unwrap()).collect();
        for (substeps, solver_iterations) in [(5, 2), (5, 1), (3, 2), (2, 2), (3, 1), (2, 1)] {
            let sim = SimParams {
                control_dt: CONTROL_DT,
                substeps,
                solver_iterations,
                ..SIM
            };
            let mut env = Ant::with_sim(AntObs::State, sim);
            let start = std::time::Instant::now();
            let mut steps = 0;
            let mut lens: Vec<usize> = (0..30)
                .map(|s| {
                    let acts = random_actions::<8>(s + 1000, 1000);
                    let n = episode(&mut env, s, |t| acts[t]).1;
                    steps += n;
                    n
                })
                .collect();
            let rate = steps as f64 / start.elapsed().as_secs_f64();
            lens.sort();
            let (mut overshoot, mut sink) = (0.0f32, 0.0f32);
            env.reset(Some(1));
            for t in 0..400 {
                let s = if (t / 3) % 2 == 0 { 1.0 } else { -1.0 };
                env.step(&[s, -s, s, s, -s, -s, s, -s]);
                let q = env.qpos();
                for (j, [lo, hi]) in ranges.iter().enumerate() {
                    overshoot = overshoot.max(lo - q[7 + j]).max(q[7 + j] - hi);
                }
                sink = sink.max(crate::testing::sinking(&env.robot));
            }
            let trot: Vec<f32> = (0..3)
                .map(|s| {
                    episode(
                        &mut env,
                        s,
                        |t| if t < 10 { [0.0; 8] } else { trot(t, TROT) },
                    )
                    .0
                })
                .collect();
            println!(
                "{substeps}x{solver_iterations}: random median {} mean {:.0}, bang-bang overshoot \
                 {overshoot:.3} rad, sink {sink:.4} m, trot {trot:?} m, {rate:.0} steps/s",
                lens[15],
                lens.iter().sum::<usize>() as f32 / 30.0,
            );
        }
    }

    /// The open-loop trot (10 settling steps, then 200 of [`TROT`]) on each of `seeds` at `sim`
    /// (and the Coriolis step `explicit` asks for; `None`: the ant's own): per seed the distance
    /// along x over the trot, m, and its return; and how many episodes fell (terminated).
    fn trot_episodes(
        sim: SimParams,
        explicit: Option<bool>,
        seeds: u64,
    ) -> (Vec<(f32, f64)>, usize) {
        let mut env = Ant::with_sim(AntObs::State, sim);
        env.robot.set_tuning(crate::physics::PhysicsTuning {
            explicit_coriolis: explicit,
            ..Default::default()
        });
        let mut fell = 0;
        let episodes = (0..seeds)
            .map(|seed| {
                env.reset(Some(seed));
                for _ in 0..10 {
                    env.step(&[0.0; 8]);
                }
                let (x0, mut ret) = (env.qpos()[0], 0.0);
                for t in 0..200 {
                    let s = env.step(&trot(t, TROT));
                    ret += s.reward;
                    if s.terminated {
                        fell += 1;
                        break;
                    }
                }
                (env.qpos()[0] - x0, ret)
            })
            .collect();
        (episodes, fell)
    }

    fn mean(v: impl Iterator<Item = f64>) -> f64 {
        let v: Vec<f64> = v.collect();
        v.iter().sum::<f64>() / v.len() as f64
    }

    /// Issue 32's open-loop check for the ant: over seeds 0–23 (single seeds of this chaotic trot
    /// go anywhere from −5 to 10 m, so fewer cannot tell a 15% gap from noise) the trot's mean
    /// distance and return at [`SIM`] are within 15% of the same trot integrated 10× finer, and
    /// no episode falls. Measured: 5.80 m against 5.74 m (1%).
    #[test]
    fn trot_converged() {
        let (at, fell_at) = trot_episodes(SIM, None, 24);
        let (ref_, fell_ref) = trot_episodes(crate::fidelity::finer(SIM), None, 24);
        assert_eq!((fell_at, fell_ref), (0, 0), "the trot does not fall");
        for (what, f) in [
            (
                "distance",
                &(|e: &(f32, f64)| e.0 as f64) as &dyn Fn(&(f32, f64)) -> f64,
            ),
            ("return", &|e: &(f32, f64)| e.1),
        ] {
            let (a, b) = (mean(at.iter().map(f)), mean(ref_.iter().map(f)));
            assert!(
                crate::fidelity::rel(a, b) <= 0.15,
                "ant trot {what}: {a:.3} at {SIM:?} vs {b:.3} 10x finer\n{at:?}\n{ref_:?}"
            );
        }
    }

    /// Issue 32's reward band: a uniform random policy's and a standing (zero-action) policy's
    /// mean returns over seeds 0–9, against Gymnasium's MuJoCo Ant-v5 the same way
    /// (`deploy/compare/mujoco_random_standing.py Ant-v5 10`): random −77.7 (265 steps),
    /// standing 994.9 (never falls). Ours: random −128.4, standing 990.2. The random return is
    /// about −0.35 a step (healthy reward 1 against a control cost of 4/3 a step) times a
    /// heavy-tailed episode length (ours 67–1000 steps, mean 330; MuJoCo's mean 265 here, 278
    /// over 20 seeds, two to four of them the full 1000), so its band is wide; standing earns the
    /// healthy reward every step in both and its band is tight.
    #[test]
    fn random_and_standing_returns_stay_in_band() {
        let mut env = Ant::new();
        let (random, standing) =
            crate::testing::random_and_standing_returns::<_, 8>(&mut env, 0..10);
        println!("ant: random {random:.1}, standing {standing:.1}");
        assert!(
            (-250.0..-20.0).contains(&random),
            "random-policy mean return {random}"
        );
        assert!(
            (900.0..1010.0).contains(&standing),
            "standing mean return {standing}"
        );
    }

    /// The same trot as a table, by hand: seeds 0–4 (`ANT_SEEDS=N`: 0..N) at [`SIM`] and 10×
    /// finer, with rapier's semi-implicit multibody step (the ant's) and the explicit one the
    /// halfcheetah uses: `ANT_SEEDS=24 cargo test --release -p selkd-envs ant::tests::fidelity --
    /// --ignored --nocapture`.
    #[test]
    #[ignore]
    fn fidelity() {
        let seeds: u64 = std::env::var("ANT_SEEDS").map_or(5, |n| n.parse().unwrap());
        for explicit in [false, true] {
            for substeps in [SIM.substeps, 10 * SIM.substeps] {
                let sim = SimParams { substeps, ..SIM };
                let (e, fell) = trot_episodes(sim, Some(explicit), seeds);
                let d: Vec<f32> = e.iter().map(|e| e.0).collect();
                println!(
                    "ant {substeps}x{} explicit {explicit}: trot {:.2} m {d:.2?}, return {:.1}, {fell} fell",
                    SIM.solver_iterations,
                    mean(d.iter().map(|&x| x as f64)),
                    mean(e.iter().map(|e| e.1)),
                );
            }
        }
    }
}
