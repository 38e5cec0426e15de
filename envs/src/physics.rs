//! Rigid-body physics shared by the locomotion robots (hopper, walker2d, halfcheetah, ant,
//! humanoid), on rapier3d's reduced-coordinate multibodies.
//!
//! Why multibodies: a robot is a tree of links joined by hinges, and reduced coordinates keep the
//! joints exact (no drift, no joint-constraint blow-ups under 200 N·m torques) and give joint
//! angles and velocities directly, the way MuJoCo's `qpos`/`qvel` do. Impulse joints were tried by
//! a colleague and blew up.
//!
//! Conventions (MuJoCo's): Z is up, gravity is −9.81 along Z. A robot is described in its rest
//! pose in world coordinates ([`LinkDesc`]); each link's body origin is its joint anchor, so a
//! link's pose at zero joint angles equals the description. Only the floor touches robot parts
//! (collision groups [`ROBOT`] / [`FLOOR`] and self-contacts off), as in Gymnasium's MuJoCo models
//! where the robots' geoms do not collide with each other.
//!
//! The root of a planar robot ([`RootJoint::Planar`]) is a generic multibody joint from a fixed,
//! collider-less anchor body at the world origin to the root link, with the free axes
//! x-slide, z-slide and y-hinge (pitch): the robot cannot leave the x–z plane, and its root
//! coordinates are MuJoCo's `rootx`, `rootz`, `rooty`. A free root ([`RootJoint::Free`]) is a
//! multibody whose root body is dynamic: position and quaternion, as MuJoCo's `freejoint`.
//!
//! Every hinge has one axis. MuJoCo bodies with two or three hinges (the humanoid's hips,
//! abdomen and shoulders) become chains of single-hinge links through geom-less connector links
//! of negligible mass: rapier's multibody joints cannot have exactly two free rotations.
//! Joint springs (MuJoCo `stiffness`) use rapier's implicit multibody springs.
//!
//! State layout: `qpos` = root coordinates then one angle per hinge, in link order; `qvel` the
//! matching generalized velocities (see [`RootJoint`] for the root's part). Joint torques are applied as equal and opposite world torques
//! about the hinge axis on the child and parent bodies, which projects onto exactly that joint's
//! generalized force (the ancestor contributions cancel).

use rapier3d::prelude::*;

/// Collision group of every robot part: it only collides with [`FLOOR`].
pub const ROBOT: Group = Group::GROUP_1;
/// Collision group of the ground: it collides with [`ROBOT`].
pub const FLOOR: Group = Group::GROUP_2;

/// Gravity along Z, m/s².
pub const GRAVITY_Z: f32 = -9.81;

/// How a control step is integrated.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimParams {
    /// Control period, s.
    pub control_dt: f32,
    /// Rapier steps per control step (each of `control_dt / substeps`).
    pub substeps: usize,
    /// Rapier's `num_solver_iterations` per step (rapier's TGS substeps the contact/limit solve
    /// this many times inside a step).
    pub solver_iterations: usize,
    /// Rapier's `normalized_prediction_distance`, m: contacts are generated for shapes this far
    /// apart. A contact found ahead of touching can act within the step ("speculative"), so at
    /// coarse steps a large distance lets a fast foot push off the floor before it touches it.
    pub prediction_distance: f32,
    /// Natural frequency of every hinge's joint limit, Hz. Rapier's default,
    /// [`RAPIER_LIMIT_FREQUENCY`], is its hard limit constraint: it removes a violation within
    /// one solver pass, so the velocity it leaves grows with the passes per control step (issue
    /// 32: a walker reset 4 mrad past a thigh limit spun at 33 rad/s after one 8 ms step at
    /// 40 × 8, 0.85 at 4 × 2; MuJoCo 0.04), and its give shrinks with them. Below it, each
    /// limit is a spring–damper of this frequency and damping ratio 1 on the hinge's coordinate
    /// (explicit, as MuJoCo's `solref`; see [`Articulation::set_limit_frequency`]), which gives
    /// the same at any number of solver passes and converges with the step: rapier's own soft
    /// limit constraint did neither. About 16 Hz gives the overshoot of MuJoCo's default
    /// limits on the walker on the geometric mean over its hinges
    /// (`walker2d::tests::limit_frequencies`, `deploy/compare/mujoco_limit_overshoot.py`):
    /// MuJoCo's 0.02 s `solref` is about 8 Hz, but its impedance takes most of a load at once,
    /// which a plain spring does not. Soft limits need `4π·frequency·step ≤ 1`
    /// ([`SimParams::check_limit`]) to be stable; to be accurate, well under it (the hopper's
    /// 0.80 at 2 × 4 let a policy trained 100k env steps lean on the spring's integration error:
    /// `docs/results/fidelity.md`, "The learned check at 100k env steps").
    pub limit_frequency: f32,
    /// Whether the limit springs are integrated implicitly (backward Euler on each hinge's own
    /// coordinate, [`Articulation::add_limit_torques`]) instead of explicitly: stable at any
    /// step (issue 32: the walker's gait in the air, its hips starting at their limit, pitched
    /// 19% further at 4 × 4 than at 40 × 4 with explicit springs, 1.5% with implicit ones), but
    /// numerically damped: our SAC's walker policies trained at 4 × 4 with them leaned on that
    /// damping, 41–42% off 40 × 16 (`docs/results/fidelity.md`, "Implicit limit springs"), so
    /// every task ships with it off. Absent in records older than it (so false).
    #[serde(default)]
    pub implicit_limits: bool,
    /// Rapier's `num_internal_stabilization_iterations`: the unbiased "relax" iterations each
    /// solver pass runs after its penetration-correcting solve, to take the correction's
    /// velocity out again (rapier's default 1). Issue 32: with 1, the walker's gait goes
    /// further the more passes a control step has and does not settle (0.57 m at 4 × 4, 0.84 at
    /// 80 × 32); with 0 it is within 2–12% of 80 × 32 at every setting from 2 × 4 to 8 × 4
    /// (`docs/results/fidelity.md`, "… rapier's stabilization pass"). The walker ships 0 since
    /// its learned check held there ([`crate::walker2d::SIM`]); every other task 1 (the hopper's
    /// policies trained without it fell sooner at 4 × 4 than converged, 16–24% on two seeds of
    /// three: "The hopper's relax pass"). Absent in records older than it (so 1).
    #[serde(default = "rapier_stabilization_iterations")]
    pub stabilization_iterations: usize,
    /// Rapier's `num_internal_pgs_iterations`: the contact and limit solve's Gauss–Seidel
    /// iterations inside each solver pass, at the pass's positions (rapier's default 1). Unlike
    /// a solver pass ([`SimParams::solver_iterations`]) it neither integrates nor updates the
    /// articulations (forward kinematics, mass matrix and its factorisation), so it costs a
    /// fraction of one; it converges the pass's impulses without shortening its step. Absent in
    /// records older than it (so 1).
    #[serde(default = "rapier_pgs_iterations")]
    pub pgs_iterations: usize,
    /// Natural frequency of the contacts' softness, Hz, for contacts with the floor and between
    /// moving bodies alike; `None` keeps rapier's own (60 Hz against fixed bodies, 30 Hz
    /// between moving ones). Issue 32: MuJoCo's contacts are soft (`solref` 0.02 s, about
    /// 8 Hz, with an impedance that starts at 0 on touching), rapier's stiff; on the cheetah's
    /// running gait 8–30 Hz changed little where the step size changed much
    /// (`docs/results/fidelity.md`, "The cheetah fails goal 2 at 100k env steps"; measured
    /// while the planar robots' feet had almost no friction, before the vendored fix). Absent
    /// in records older than it (so `None`).
    #[serde(default)]
    pub contact_frequency: Option<f32>,
    /// Damping ratio of the contacts' softness; `None` keeps rapier's own (10).
    #[serde(default)]
    pub contact_damping_ratio: Option<f32>,
}

/// Rapier's own default of [`SimParams::stabilization_iterations`].
pub const RAPIER_STABILIZATION_ITERATIONS: usize = 1;

fn rapier_stabilization_iterations() -> usize {
    RAPIER_STABILIZATION_ITERATIONS
}

/// Rapier's own default of [`SimParams::pgs_iterations`].
pub const RAPIER_PGS_ITERATIONS: usize = 1;

fn rapier_pgs_iterations() -> usize {
    RAPIER_PGS_ITERATIONS
}

impl SimParams {
    /// Each setting by name, as it reads (the shortest decimal that is the same `f32`).
    pub fn fields(&self) -> [(&'static str, String); 10] {
        // Destructured, so that a new setting cannot be left out of the records.
        let SimParams {
            control_dt,
            substeps,
            solver_iterations,
            prediction_distance,
            limit_frequency,
            implicit_limits,
            stabilization_iterations,
            pgs_iterations,
            contact_frequency,
            contact_damping_ratio,
        } = *self;
        let rapier = |x: Option<f32>| x.map_or_else(|| "rapier's".to_string(), |x| x.to_string());
        [
            ("control_dt", control_dt.to_string()),
            ("substeps", substeps.to_string()),
            ("solver_iterations", solver_iterations.to_string()),
            ("prediction_distance", prediction_distance.to_string()),
            ("limit_frequency", limit_frequency.to_string()),
            ("implicit_limits", implicit_limits.to_string()),
            (
                "stabilization_iterations",
                stabilization_iterations.to_string(),
            ),
            ("pgs_iterations", pgs_iterations.to_string()),
            ("contact_frequency", rapier(contact_frequency)),
            ("contact_damping_ratio", rapier(contact_damping_ratio)),
        ]
    }

    /// Whether soft limits of [`Self::limit_frequency`] are stable at this step: their damping is
    /// explicit, so it needs `2ζωh ≤ 1` (ω = 2π·frequency, ζ = 1, h the rapier step), MuJoCo's
    /// rule for its `solref` (a time constant of at least two steps) in other words. Hard limits
    /// (rapier's constraints) and implicit springs need nothing.
    pub fn check_limit(&self) -> Result<(), String> {
        let hz = self.limit_frequency;
        if hz >= RAPIER_LIMIT_FREQUENCY || self.implicit_limits {
            return Ok(());
        }
        let h = self.control_dt / self.substeps as f32;
        // 2ζωh per Hz of the limit's frequency.
        let per_hz = 4.0 * std::f32::consts::PI * LIMIT_DAMPING_RATIO * h;
        let damping_h = per_hz * hz;
        if damping_h <= 1.0 {
            return Ok(());
        }
        let substeps = (self.substeps as f32 * damping_h).ceil() as usize;
        let max_hz = 1.0 / per_hz;
        Err(format!(
            "`limit_frequency` {hz} Hz is too stiff for rapier steps of {:.3} ms (soft limits \
             need 4π·frequency·step ≤ 1): set `substeps` to at least {substeps}, \
             `limit_frequency` to at most {max_hz:.1}, or `implicit_limits` to true",
            h * 1e3
        ))
    }
}

/// Rapier's own default prediction distance, m.
pub const RAPIER_PREDICTION_DISTANCE: f32 = 0.02;

/// Rapier's default joint-constraint frequency, Hz: a hard limit.
pub const RAPIER_LIMIT_FREQUENCY: f32 = 1.0e6;

/// The damping ratio of every joint limit: 1, rapier's default and MuJoCo's.
const LIMIT_DAMPING_RATIO: f32 = 1.0;

/// A user's override of a robot's [`SimParams`] (the keys `substeps`, `solver_iterations`,
/// `prediction_distance`, `limit_frequency`, `implicit_limits`, `stabilization_iterations`,
/// `pgs_iterations`, `contact_frequency` and `contact_damping_ratio` of a run's
/// `[env_options]`):
/// trade speed for integration accuracy.
/// Unset keys keep the robot's own choice, documented at each robot's `SIM`.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhysicsOptions {
    /// Rapier steps per control step.
    pub substeps: Option<usize>,
    /// Rapier solver iterations per step.
    pub solver_iterations: Option<usize>,
    /// Rapier's contact prediction distance, m.
    pub prediction_distance: Option<f32>,
    /// The hinges' joint-limit frequency, Hz ([`SimParams::limit_frequency`]).
    pub limit_frequency: Option<f32>,
    /// Limit springs integrated implicitly ([`SimParams::implicit_limits`]).
    pub implicit_limits: Option<bool>,
    /// Rapier's relax iterations per solver pass ([`SimParams::stabilization_iterations`]).
    pub stabilization_iterations: Option<usize>,
    /// Rapier's Gauss–Seidel iterations per solver pass ([`SimParams::pgs_iterations`]).
    pub pgs_iterations: Option<usize>,
    /// The contacts' natural frequency, Hz ([`SimParams::contact_frequency`]).
    pub contact_frequency: Option<f32>,
    /// The contacts' damping ratio ([`SimParams::contact_damping_ratio`]).
    pub contact_damping_ratio: Option<f32>,
}

/// The largest [`PhysicsOptions::contact_frequency`], Hz.
pub const MAX_CONTACT_FREQUENCY: f32 = 1000.0;
/// The largest [`PhysicsOptions::contact_damping_ratio`].
pub const MAX_CONTACT_DAMPING_RATIO: f32 = 100.0;

/// The largest [`PhysicsOptions::prediction_distance`], m: a contact a metre away is not one.
pub const MAX_PREDICTION_DISTANCE: f32 = 1.0;

/// The most of `substeps` or `solver_iterations`: 10× the finest setting worth training at (64),
/// so that any such setting can be replayed 10× finer (issue 32's convergence check); a control
/// step at the most takes about a second.
pub const MAX_PHYSICS_STEPS: usize = 640;

impl PhysicsOptions {
    /// `default` with these overrides, or a message naming the bad key.
    pub fn apply(&self, default: SimParams) -> Result<SimParams, String> {
        // A count from `min` to `max`.
        let count =
            |key: &str, value: Option<usize>, default: usize, min: usize, max: usize| match value {
                None => Ok(default),
                Some(n) if (min..=max).contains(&n) => Ok(n),
                Some(n) => Err(format!(
                    "`{key}` must be {min} to {max}, got {n} (the default is {default})"
                )),
            };
        // A positive amount up to `max`, in `unit`.
        let positive =
            |key: &str, value: Option<f32>, default: f32, max: f32, unit: &str| match value {
                None => Ok(default),
                Some(x) if x > 0.0 && x <= max => Ok(x),
                Some(x) => Err(format!(
                    "`{key}` must be above 0 and at most {max} {unit}, got {x} (the default is \
                     {default})"
                )),
            };
        let prediction_distance = positive(
            "prediction_distance",
            self.prediction_distance,
            default.prediction_distance,
            MAX_PREDICTION_DISTANCE,
            "m",
        )?;
        let limit_frequency = positive(
            "limit_frequency",
            self.limit_frequency,
            default.limit_frequency,
            RAPIER_LIMIT_FREQUENCY,
            "Hz (a hard limit)",
        )?;
        // An optional positive amount up to `max`: unset keeps the robot's own.
        let optional = |key: &str, value: Option<f32>, default: Option<f32>, max: f32| match value {
            None => Ok(default),
            Some(x) if x > 0.0 && x <= max => Ok(Some(x)),
            Some(x) => Err(format!(
                "`{key}` must be above 0 and at most {max}, got {x} (unset keeps rapier's own)"
            )),
        };
        let sim = SimParams {
            control_dt: default.control_dt,
            substeps: count(
                "substeps",
                self.substeps,
                default.substeps,
                1,
                MAX_PHYSICS_STEPS,
            )?,
            solver_iterations: count(
                "solver_iterations",
                self.solver_iterations,
                default.solver_iterations,
                1,
                MAX_PHYSICS_STEPS,
            )?,
            prediction_distance,
            limit_frequency,
            implicit_limits: self.implicit_limits.unwrap_or(default.implicit_limits),
            stabilization_iterations: count(
                "stabilization_iterations",
                self.stabilization_iterations,
                default.stabilization_iterations,
                0,
                MAX_STABILIZATION_ITERATIONS,
            )?,
            pgs_iterations: count(
                "pgs_iterations",
                self.pgs_iterations,
                default.pgs_iterations,
                1,
                MAX_PGS_ITERATIONS,
            )?,
            contact_frequency: optional(
                "contact_frequency",
                self.contact_frequency,
                default.contact_frequency,
                MAX_CONTACT_FREQUENCY,
            )?,
            contact_damping_ratio: optional(
                "contact_damping_ratio",
                self.contact_damping_ratio,
                default.contact_damping_ratio,
                MAX_CONTACT_DAMPING_RATIO,
            )?,
        };
        sim.check_limit()?;
        Ok(sim)
    }
}

/// The most of [`PhysicsOptions::stabilization_iterations`] (rapier's default is 1).
pub const MAX_STABILIZATION_ITERATIONS: usize = 16;

/// The most of [`PhysicsOptions::pgs_iterations`] (rapier's default is 1).
pub const MAX_PGS_ITERATIONS: usize = 64;

/// A new world: gravity −Z, the time step and solver settings of `p`.
pub fn new_world(p: &SimParams) -> PhysicsWorld {
    let mut w = PhysicsWorld::new();
    w.gravity = Vector::new(0.0, 0.0, GRAVITY_Z);
    w.integration_parameters.dt = p.control_dt / p.substeps as f32;
    w.integration_parameters.num_solver_iterations = p.solver_iterations;
    w.integration_parameters.normalized_prediction_distance = p.prediction_distance;
    w.integration_parameters
        .num_internal_stabilization_iterations = p.stabilization_iterations;
    w.integration_parameters.num_internal_pgs_iterations = p.pgs_iterations;
    let ip = &mut w.integration_parameters;
    for softness in [&mut ip.contact_softness, &mut ip.static_contact_softness] {
        if let Some(hz) = p.contact_frequency {
            softness.natural_frequency = hz;
        }
        if let Some(zeta) = p.contact_damping_ratio {
            softness.damping_ratio = zeta;
        }
    }
    w
}

/// Adds the ground: the half-space z ≤ 0, in group [`FLOOR`]. Contact friction combines by the
/// maximum (MuJoCo's rule), so a robot geom's own friction wins where it is larger.
pub fn add_floor(w: &mut PhysicsWorld, friction: f32) -> ColliderHandle {
    let body = w.bodies.insert(RigidBodyBuilder::fixed());
    let collider = ColliderBuilder::new(SharedShape::halfspace(Vector::Z))
        .friction(friction)
        .friction_combine_rule(CoefficientCombineRule::Max)
        .collision_groups(InteractionGroups::new(
            FLOOR,
            ROBOT,
            InteractionTestMode::And,
        ));
    w.colliders
        .insert_with_parent(collider, body, &mut w.bodies)
}

/// The joint between the world and a robot's root link.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RootJoint {
    /// x-slide, z-slide, y-hinge (pitch) about the root link's origin: 3 coordinates, in that
    /// order, with x and z the origin's world position and pitch the rotation about +Y.
    Planar,
    /// A free-floating root (MuJoCo's `freejoint`): 7 coordinates, the root origin's world
    /// position then its orientation as a unit quaternion `w, x, y, z`; 6 velocities, the
    /// origin's world-frame linear velocity then the angular velocity in the root's own frame
    /// (MuJoCo's conventions for both).
    Free,
}

impl RootJoint {
    /// Generalized velocities of the root.
    fn nv(self) -> usize {
        match self {
            RootJoint::Planar => 3,
            RootJoint::Free => 6,
        }
    }

    /// Generalized coordinates of the root.
    fn nq(self) -> usize {
        match self {
            RootJoint::Planar => 3,
            RootJoint::Free => 7,
        }
    }
}

/// One collision and mass shape of a link, in the world frame of the rest pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Geom {
    /// A capsule between two points (MuJoCo `fromto`), radius `r`.
    Capsule { a: [f32; 3], b: [f32; 3], r: f32 },
    /// A sphere about `c`, radius `r`.
    Sphere { c: [f32; 3], r: f32 },
}

impl Geom {
    /// A capsule between two points, radius `r`.
    pub fn capsule(a: [f32; 3], b: [f32; 3], r: f32) -> Self {
        Geom::Capsule { a, b, r }
    }

    /// Volume, m³ (a link's mass is density × the sum over its geoms, as MuJoCo computes it).
    pub fn volume(&self) -> f32 {
        use std::f32::consts::PI;
        match *self {
            Geom::Capsule { a, b, r } => {
                let len = (v3(b) - v3(a)).length();
                PI * r * r * len + 4.0 / 3.0 * PI * r * r * r
            }
            Geom::Sphere { r, .. } => 4.0 / 3.0 * PI * r * r * r,
        }
    }
}

/// Scales every link's density so that the robot weighs `total` kg (MuJoCo's `settotalmass`).
pub fn set_total_mass(links: &mut [LinkDesc], total: f32) {
    let mass: f32 = links
        .iter()
        .map(|l| l.density * l.geoms.iter().map(Geom::volume).sum::<f32>())
        .sum();
    for l in links {
        l.density *= total / mass;
    }
}

/// Mass and inertia given to a link without geoms (the intermediate links that chain single
/// hinges into a multi-axis joint): small next to any real link, but non-zero, so that the
/// articulated inertia stays invertible.
const CONNECTOR_MASS: f32 = 1e-3;
const CONNECTOR_INERTIA: f32 = 1e-6;

/// One link of a robot, in the world frame of the rest pose (all joint coordinates zero).
#[derive(Clone, Debug, PartialEq)]
pub struct LinkDesc {
    pub name: &'static str,
    /// Index of the parent link in the description; `None` only for the root (link 0).
    pub parent: Option<usize>,
    /// The joint anchor (the body origin), world frame.
    pub anchor: [f32; 3],
    /// Hinge axis (ignored for the root), world frame; positive angles turn about it.
    pub axis: [f32; 3],
    /// Hinge range in radians, if limited.
    pub range: Option<[f32; 2]>,
    /// Collision and mass shapes; none for a connector link inside a multi-axis joint.
    pub geoms: Vec<Geom>,
    pub density: f32,
    pub friction: f32,
    /// Reflected rotor inertia added on the hinge's coordinate (MuJoCo `armature`), kg·m².
    pub armature: f32,
    /// Viscous joint damping (MuJoCo `damping`), N·m·s/rad.
    pub damping: f32,
    /// Joint spring toward angle 0 (MuJoCo `stiffness`), N·m/rad; integrated implicitly.
    pub stiffness: f32,
}

impl LinkDesc {
    /// A hinge link with MuJoCo's defaults otherwise zero: no limit, no armature, damping or
    /// spring, density 1000, friction 1.
    pub fn hinge(
        name: &'static str,
        parent: usize,
        anchor: [f32; 3],
        axis: [f32; 3],
        geoms: Vec<Geom>,
    ) -> Self {
        Self {
            name,
            parent: Some(parent),
            anchor,
            axis,
            range: None,
            geoms,
            density: 1000.0,
            friction: 1.0,
            armature: 0.0,
            damping: 0.0,
            stiffness: 0.0,
        }
    }

    /// The root link, its origin at `anchor`.
    pub fn root(name: &'static str, anchor: [f32; 3], geoms: Vec<Geom>) -> Self {
        Self {
            parent: None,
            ..Self::hinge(name, 0, anchor, [0.0; 3], geoms)
        }
    }
}

fn v3(a: [f32; 3]) -> Vector {
    Vector::new(a[0], a[1], a[2])
}

/// A robot built in a world: its bodies, and the map between rapier's multibody and the
/// `qpos`/`qvel` layout.
pub struct Articulation {
    root: RootJoint,
    /// Body of each link, in description order.
    pub bodies: Vec<RigidBodyHandle>,
    /// Parent link of each link (`usize::MAX` for the root).
    parents: Vec<usize>,
    /// Hinge axis of each non-root link, in its parent's body frame.
    axes_in_parent: Vec<Vector>,
    /// Every collider of each link.
    colliders: Vec<Vec<ColliderHandle>>,
    nq: usize,
    nv: usize,
    /// Each link's hinge range (`None` for the root and unlimited hinges).
    ranges: Vec<Option<[f32; 2]>>,
    /// The limits as springs, when soft ([`Articulation::set_limit_frequency`]).
    soft_limits: Option<SoftLimits>,
}

/// Soft joint limits as spring–dampers on each limited hinge's coordinate, computed by us
/// instead of rapier's limit constraint (see [`Articulation::set_limit_frequency`]).
#[derive(Clone, Debug)]
struct SoftLimits {
    /// Angular frequency, rad/s.
    omega: f32,
    /// Each link's apparent inertia at its hinge at the rest pose, kg·m² (1 / MuJoCo's
    /// `dof_invweight0`, armature included); 0 for the root.
    inertia: Vec<f32>,
    /// The rapier step, s, when the springs are implicit ([`SimParams::implicit_limits`]).
    implicit_step: Option<f32>,
}

impl Articulation {
    /// Builds the robot of `links` (link 0 is the root) attached to the world by `root`, at its
    /// rest pose. Panics on a malformed description (a bug, not an input error).
    pub fn build(w: &mut PhysicsWorld, root: RootJoint, links: &[LinkDesc]) -> Self {
        assert!(!links.is_empty() && links[0].parent.is_none());
        let groups = InteractionGroups::new(ROBOT, FLOOR, InteractionTestMode::And);
        let mut bodies = Vec::with_capacity(links.len());
        let mut colliders = Vec::with_capacity(links.len());
        for l in links {
            let origin = v3(l.anchor);
            // Robot bodies must never sleep: a sleeping body ignores applied torques.
            let mut b = RigidBodyBuilder::dynamic()
                .translation(origin)
                .can_sleep(false);
            if l.geoms.is_empty() {
                b = b.additional_mass_properties(MassProperties::new(
                    Vector::ZERO,
                    CONNECTOR_MASS,
                    Vector::splat(CONNECTOR_INERTIA),
                ));
            }
            let body = w.bodies.insert(b);
            let mut handles = Vec::with_capacity(l.geoms.len());
            for g in &l.geoms {
                let c = match *g {
                    Geom::Capsule { a, b, r } => {
                        ColliderBuilder::capsule_from_endpoints(v3(a) - origin, v3(b) - origin, r)
                    }
                    Geom::Sphere { c, r } => ColliderBuilder::ball(r).translation(v3(c) - origin),
                }
                .density(l.density)
                .friction(l.friction)
                .friction_combine_rule(CoefficientCombineRule::Max)
                .collision_groups(groups);
                handles.push(w.colliders.insert_with_parent(c, body, &mut w.bodies));
            }
            // Mass properties now, not at the first step: the multibody's inertia and
            // `mass()` must be right from the start.
            w.bodies[body].recompute_mass_properties_from_colliders(&w.colliders);
            bodies.push(body);
            colliders.push(handles);
        }

        // The planar root joint: from a collider-less fixed anchor at the world origin. A free
        // root needs no joint: a multibody whose root body is dynamic floats freely.
        match root {
            RootJoint::Planar => {
                let anchor = w.bodies.insert(RigidBodyBuilder::fixed());
                let joint = GenericJointBuilder::new(
                    JointAxesMask::LIN_Y | JointAxesMask::ANG_X | JointAxesMask::ANG_Z,
                )
                .contacts_enabled(false)
                .build();
                w.multibody_joints
                    .insert(anchor, bodies[0], joint, true)
                    .expect("root multibody joint");
            }
            RootJoint::Free => assert!(links.len() > 1, "a free robot needs a hinge"),
        }

        let mut parents = vec![usize::MAX];
        let mut axes_in_parent = vec![Vector::ZERO];
        for (i, l) in links.iter().enumerate().skip(1) {
            let p = l.parent.expect("non-root link without a parent");
            assert!(p < i, "links must come after their parent");
            let axis = v3(l.axis).normalize();
            // The joint frame's X axis is the hinge axis; rapier's revolute coordinate is AngX.
            let rot = Rotation::from_rotation_arc(Vector::X, axis);
            let offset = v3(l.anchor) - v3(links[p].anchor);
            let mut joint = GenericJointBuilder::new(JointAxesMask::LOCKED_REVOLUTE_AXES)
                .local_frame1(Pose::from_parts(offset, rot))
                .local_frame2(Pose::from_rotation(rot))
                .contacts_enabled(false);
            if let Some(r) = l.range {
                joint = joint.limits(JointAxis::AngX, r);
            }
            w.multibody_joints
                .insert(bodies[p], bodies[i], joint.build(), true)
                .expect("hinge multibody joint");
            parents.push(p);
            axes_in_parent.push(axis);
        }

        let art = Self {
            root,
            nq: root.nq() + links.len() - 1,
            nv: root.nv() + links.len() - 1,
            bodies,
            parents,
            axes_in_parent,
            colliders,
            ranges: links.iter().map(|l| l.range).collect(),
            soft_limits: None,
        };

        // Settle the multibody's root type (fixed anchor: no free root dofs), then the per-dof
        // damping and armature, which are indexed by the final dof layout.
        let mb = w
            .multibody_joints
            .get_mut(MultibodyJointHandle(art.bodies[0].0))
            .expect("robot multibody")
            .0;
        mb.set_self_contacts_enabled(false);
        mb.forward_kinematics(&w.bodies, true);
        let mb = art.multibody_mut(w);
        assert_eq!(mb.ndofs(), art.nv, "multibody dofs vs description");
        for d in 0..root.nv() {
            mb.damping_mut()[d] = 0.0;
            mb.armature_mut()[d] = 0.0;
        }
        for (i, l) in links.iter().enumerate().skip(1) {
            let d = art.dof(w, i);
            let (mb, id) = w
                .multibody_joints
                .get_mut(MultibodyJointHandle(art.bodies[i].0))
                .expect("robot link");
            mb.damping_mut()[d] = l.damping;
            mb.armature_mut()[d] = l.armature;
            if l.stiffness != 0.0 {
                // Rapier's revolute coordinate is the joint frame's AngX (index 3 of 6).
                let joint = &mut mb.link_mut(id).expect("robot link").joint;
                joint.set_spring(3, l.stiffness, 0.0);
            }
        }
        art.set_state(w, &art.rest_qpos(&links[0]), &vec![0.0; art.nv]);
        art
    }

    /// Integrates the robot's Coriolis and gyroscopic terms explicitly in each (sub)step (the
    /// vendored rapier's opt-in patch, `vendor/README.md`) instead of rapier's semi-implicit
    /// solve, which does not conserve the articulation's momentum at large steps (issue 32: the
    /// cheetah's 10 ms steps let an open-loop gait "swim" forward 500 m). MuJoCo's Euler
    /// integrator treats them explicitly too.
    pub fn set_explicit_coriolis(&self, w: &mut PhysicsWorld, explicit: bool) {
        self.multibody_mut(w).set_explicit_coriolis(explicit);
    }

    /// Sets every hinge's joint-limit frequency ([`SimParams::limit_frequency`]) on the robot
    /// at its rest pose. At [`RAPIER_LIMIT_FREQUENCY`] (or above) the limits are rapier's hard
    /// constraints. Below, they are springs of that frequency and damping ratio 1 on each hinge's
    /// coordinate, which [`Robot::step`] applies as torques each rapier step: rapier's own soft
    /// limit held 2.2× stiffer at 8 solver passes a control step than at 320 (the walker's
    /// hinges in the air under full torque, `walker2d::tests::soft_limit_in_the_air`), so a
    /// policy trained at a coarse setting learned to lean on limits that give way finer.
    /// `implicit_step`: the rapier step, s, to integrate the springs implicitly at
    /// ([`SimParams::implicit_limits`]); `None` for explicit springs.
    pub fn set_limit_frequency(
        &mut self,
        w: &mut PhysicsWorld,
        hz: f32,
        implicit_step: Option<f32>,
    ) {
        let soft = hz < RAPIER_LIMIT_FREQUENCY;
        for &body in &self.bodies[1..] {
            let (mb, id) = w
                .multibody_joints
                .get_mut(MultibodyJointHandle(body.0))
                .expect("robot link");
            let joint = &mut mb.link_mut(id).expect("robot link").joint;
            if soft {
                joint.data.limit_axes.remove(JointAxesMask::ANG_X);
            } else {
                joint.data.softness = SpringCoefficients::new(hz, LIMIT_DAMPING_RATIO);
            }
        }
        self.soft_limits = soft.then(|| {
            let (bodies, mb) = self.bodies_and_multibody(w);
            let inv = mb.dof_inverse_inertia(bodies);
            let mut inertia = vec![0.0; self.bodies.len()];
            for (i, x) in inertia.iter_mut().enumerate().skip(1) {
                *x = 1.0 / inv[self.dof(w, i)];
            }
            SoftLimits {
                omega: 2.0 * std::f32::consts::PI * hz,
                inertia,
                implicit_step,
            }
        });
    }

    /// Whether the limits are our springs ([`Articulation::set_limit_frequency`]).
    pub fn has_soft_limits(&self) -> bool {
        self.soft_limits.is_some()
    }

    /// With soft limits, each hinge's limit torque (N·m, hinge order) from the current state,
    /// added to `torques`; nothing with rapier's hard limits. A hinge past its range by `r`
    /// (moving outward at `u`) is pushed back by the spring–damper `I·(ω²·r + 2ζω·u)` (`I` its
    /// rest-pose apparent inertia), explicit in the state as MuJoCo's soft constraints are, and
    /// only pushing back, as a limit does. Explicit damping needs `2ζωh ≤ 1` for a rapier step
    /// of `h` s ([`SimParams::check_limit`]). Implicit springs push with the state at the end of
    /// the step instead, as if the hinge moved alone with inertia `I` (backward Euler: the push
    /// is `I·(ω²·r + (2ζω + hω²)·u) / (1 + h·(2ζω + hω²))`, the explicit push at `h = 0`),
    /// which is stable at any `h`.
    pub fn add_limit_torques(&self, w: &PhysicsWorld, torques: &mut [f32]) {
        let Some(soft) = &self.soft_limits else {
            return;
        };
        let (q, v) = (self.qpos(w), self.qvel(w));
        let (root_nq, root_nv) = (self.root.nq(), self.root.nv());
        let omega = soft.omega;
        // Explicit springs are the implicit ones at h = 0 (the same push, bit for bit).
        let h = soft.implicit_step.unwrap_or(0.0);
        // The velocity term's coefficient once the spring acts on r + h·u, and the divisor.
        let velocity_gain = 2.0 * LIMIT_DAMPING_RATIO * omega + h * omega * omega;
        let divisor = 1.0 + h * velocity_gain;
        for i in 1..self.bodies.len() {
            let Some([lo, hi]) = self.ranges[i] else {
                continue;
            };
            let (qi, vi) = (q[root_nq + i - 1], v[root_nv + i - 1]);
            // s: +1 past the upper end, −1 past the lower; r the distance past it.
            let (s, r) = if qi > hi {
                (1.0, qi - hi)
            } else if qi < lo {
                (-1.0, lo - qi)
            } else {
                continue;
            };
            let push = soft.inertia[i] * (omega * omega * r + velocity_gain * s * vi) / divisor;
            torques[i - 1] -= s * push.max(0.0);
        }
    }

    /// Number of generalized coordinates (`qpos`).
    pub fn nq(&self) -> usize {
        self.nq
    }

    /// Number of generalized velocities (`qvel`); `nq − 1` for a free root (its quaternion).
    pub fn nv(&self) -> usize {
        self.nv
    }

    /// The rest pose: root coordinates at the root anchor (upright), hinges at zero.
    fn rest_qpos(&self, root_link: &LinkDesc) -> Vec<f32> {
        let mut q = vec![0.0; self.nq];
        let [x, y, z] = root_link.anchor;
        match self.root {
            RootJoint::Planar => (q[0], q[1]) = (x, z),
            RootJoint::Free => q[..4].copy_from_slice(&[x, y, z, 1.0]),
        }
        q
    }

    fn multibody<'a>(&self, w: &'a PhysicsWorld) -> &'a Multibody {
        w.multibody_joints
            .get(MultibodyJointHandle(self.bodies[0].0))
            .expect("robot multibody")
            .0
    }

    fn multibody_mut<'a>(&self, w: &'a mut PhysicsWorld) -> &'a mut Multibody {
        self.bodies_and_multibody(w).1
    }

    /// The world's rigid bodies beside the robot's multibody (rapier's multibody calls that
    /// read the bodies while changing the multibody need both at once).
    fn bodies_and_multibody<'a>(
        &self,
        w: &'a mut PhysicsWorld,
    ) -> (&'a RigidBodySet, &'a mut Multibody) {
        let mb = w
            .multibody_joints
            .get_mut(MultibodyJointHandle(self.bodies[0].0))
            .expect("robot multibody")
            .0;
        (&w.bodies, mb)
    }

    fn link<'a>(&self, w: &'a PhysicsWorld, i: usize) -> &'a MultibodyLink {
        let (mb, id) = w
            .multibody_joints
            .get(MultibodyJointHandle(self.bodies[i].0))
            .expect("robot link");
        mb.link(id).expect("robot link")
    }

    /// The generalized-velocity index of hinge link `i` (≥ 1).
    fn dof(&self, w: &PhysicsWorld, i: usize) -> usize {
        self.link(w, i).assembly_id()
    }

    /// Generalized coordinates: root coordinates, then hinge angles in link order.
    pub fn qpos(&self, w: &PhysicsWorld) -> Vec<f32> {
        let mut q = Vec::with_capacity(self.nq);
        let joint = self.link(w, 0).joint();
        let c = joint.coords();
        match self.root {
            // Free coordinates of the planar root: LIN_X, LIN_Z, ANG_Y.
            RootJoint::Planar => q.extend([c[0], c[2], c[4]]),
            RootJoint::Free => {
                let r = joint.joint_rot();
                q.extend([c[0], c[1], c[2], r.w, r.x, r.y, r.z]);
            }
        }
        for i in 1..self.bodies.len() {
            q.push(self.link(w, i).joint().coords()[3]);
        }
        q
    }

    /// Generalized velocities, in the order of [`Self::qpos`].
    pub fn qvel(&self, w: &PhysicsWorld) -> Vec<f32> {
        let mb = self.multibody(w);
        let mut v = Vec::with_capacity(self.nv);
        let root = self.link(w, 0);
        let rv = mb.joint_velocity(root);
        match self.root {
            RootJoint::Planar => v.extend(rv.iter()),
            RootJoint::Free => {
                // Rapier's free root turns with a world-frame angular velocity; MuJoCo's qvel
                // holds it in the body frame.
                let local = root.joint().joint_rot().inverse() * Vector::new(rv[3], rv[4], rv[5]);
                v.extend([rv[0], rv[1], rv[2], local.x, local.y, local.z]);
            }
        }
        for i in 1..self.bodies.len() {
            v.push(mb.joint_velocity(self.link(w, i))[0]);
        }
        v
    }

    /// Puts the robot in the state `(qpos, qvel)` and moves its bodies there.
    /// A free root's quaternion is normalised first.
    pub fn set_state(&self, w: &mut PhysicsWorld, qpos: &[f32], qvel: &[f32]) {
        assert!(qpos.len() == self.nq && qvel.len() == self.nv);
        let cur = self.qpos(w);
        // Displacements are indexed by dof, like velocities; link i's dof order follows `qpos`.
        let mut disp = vec![0.0; self.nv];
        let mut vel = vec![0.0; self.nv];
        let (root_nq, root_nv) = (self.root.nq(), self.root.nv());
        match self.root {
            RootJoint::Planar => {
                for k in 0..root_nv {
                    disp[k] = qpos[k] - cur[k];
                    vel[k] = qvel[k];
                }
            }
            RootJoint::Free => {
                // The root pose goes in through its rigid body (forward kinematics reads it
                // back); the velocity's angular part turns from the body to the world frame.
                let rot = Rotation::from_xyzw(qpos[4], qpos[5], qpos[6], qpos[3]).normalize();
                let pose = Pose::from_parts(Vector::new(qpos[0], qpos[1], qpos[2]), rot);
                w.bodies[self.bodies[0]].set_position(pose, false);
                let ang = rot * Vector::new(qvel[3], qvel[4], qvel[5]);
                vel[..6].copy_from_slice(&[qvel[0], qvel[1], qvel[2], ang.x, ang.y, ang.z]);
            }
        }
        for i in 1..self.bodies.len() {
            let d = self.dof(w, i);
            disp[d] = qpos[root_nq + i - 1] - cur[root_nq + i - 1];
            vel[d] = qvel[root_nv + i - 1];
        }
        let free = self.root == RootJoint::Free;
        let (bodies, mb) = self.bodies_and_multibody(w);
        if free {
            mb.forward_kinematics(bodies, true);
        }
        mb.apply_displacements(&disp);
        mb.generalized_velocity_mut().copy_from_slice(&vel);
        self.sync_bodies(w);
    }

    /// Forward kinematics, then copies the link poses onto the rigid bodies.
    fn sync_bodies(&self, w: &mut PhysicsWorld) {
        let mb = w
            .multibody_joints
            .get_mut(MultibodyJointHandle(self.bodies[0].0))
            .expect("robot multibody")
            .0;
        mb.forward_kinematics(&w.bodies, false);
        mb.update_rigid_bodies(&mut w.bodies, true);
        // The rigid bodies' own velocities are not written: rapier's solver works on the
        // multibody's generalized velocities and derives the body velocities in its step.
    }

    /// Sets the hinge torques (N·m, one per non-root link, in link order), replacing any
    /// previous user forces on the robot. User forces persist across rapier steps, so call this
    /// before every step (the hinge axes move with the parents).
    pub fn apply_joint_torques(&self, w: &mut PhysicsWorld, torques: &[f32]) {
        assert_eq!(torques.len(), self.bodies.len() - 1);
        for &h in &self.bodies {
            let rb = &mut w.bodies[h];
            rb.reset_forces(false);
            rb.reset_torques(false);
        }
        for (i, &tau) in torques.iter().enumerate() {
            let child = i + 1;
            let parent = self.parents[child];
            let rot = *w.bodies[self.bodies[parent]].rotation();
            let t = rot * self.axes_in_parent[child] * tau;
            w.bodies[self.bodies[child]].add_torque(t, false);
            w.bodies[self.bodies[parent]].add_torque(-t, false);
        }
    }

    /// The colliders of link `i`.
    pub fn colliders(&self, i: usize) -> &[ColliderHandle] {
        &self.colliders[i]
    }

    /// Number of links.
    pub fn num_links(&self) -> usize {
        self.bodies.len()
    }

    /// The world-frame contact force on each link from the last rapier step (N; normal forces
    /// only: rapier reports the normal impulse per contact pair).
    pub fn contact_forces(&self, w: &PhysicsWorld) -> Vec<Vector> {
        let dt = w.integration_parameters.dt;
        self.colliders
            .iter()
            .map(|cs| {
                let mut f = Vector::ZERO;
                for &c in cs {
                    for pair in w.contact_pairs_with(c) {
                        // The impulse pushes collider2 along the normal, collider1 against it.
                        let sign = if pair.collider1 == c { -1.0 } else { 1.0 };
                        f += sign * pair.total_impulse() / dt;
                    }
                }
                f
            })
            .collect()
    }

    /// World pose of link `i`'s body.
    pub fn pose(&self, w: &PhysicsWorld, i: usize) -> Pose {
        *w.bodies[self.bodies[i]].position()
    }

    /// Total mass of the robot, kg.
    pub fn mass(&self, w: &PhysicsWorld) -> f32 {
        self.bodies.iter().map(|&h| w.bodies[h].mass()).sum()
    }

    /// False once rapier quarantined a robot body (its state went non-finite) or a pose or
    /// coordinate is non-finite: the simulation of this robot can no longer be trusted.
    pub fn is_sane(&self, w: &PhysicsWorld) -> bool {
        let q = w.quarantine();
        if self.bodies.iter().any(|h| q.bodies().contains(h)) {
            return false;
        }
        self.bodies.iter().all(|&h| {
            let rb = &w.bodies[h];
            rb.is_enabled() && rb.position().is_finite()
        }) && self.qpos(w).iter().all(|x| x.is_finite())
            && self.qvel(w).iter().all(|x| x.is_finite())
    }
}

/// The contact wrench on `colliders` from the last rapier step, as MuJoCo's `cfrc_ext` gives it:
/// `[torque; force]` in the world frame, the torque about the world point `point` (N·m, N).
///
/// Normal and friction forces are both included: each solver contact point's normal impulse
/// (summed over the step's solver substeps) along the contact normal, plus its friction impulse
/// in the tangent plane, divided by the step's `dt`; the torque is `(p − point) × f` with `p` the
/// contact point on the collider's own surface. Rapier keeps a contact's total friction impulse in
/// its step-local tangent basis only; the basis is recovered from the last substep's impulse,
/// which rapier also stores as a world vector (exact when that impulse is non-zero; a contact
/// whose last substep carried no friction contributes its normal force only).
///
/// MuJoCo's `cfrc_ext` of a body is about the centre of mass of its kinematic tree (for a
/// free-floating robot, [`Articulation::center_of_mass`]), so pass that point to match it.
pub fn colliders_contact_wrench(
    w: &PhysicsWorld,
    colliders: &[ColliderHandle],
    point: Vector,
) -> [f32; 6] {
    let dt = w.integration_parameters.dt;
    let (mut torque, mut force) = (Vector::ZERO, Vector::ZERO);
    for &c in colliders {
        for pair in w.contact_pairs_with(c) {
            let first = pair.collider1 == c;
            let pose = *w.colliders[c].position();
            for m in pair.solver_manifolds() {
                // Rapier's solver pushes collider1's body along −normal (and collider2's along
                // +normal), with the friction impulse expressed for collider1's body.
                let dir1 = -m.data.normal;
                for pt in &m.points {
                    let d = &pt.data;
                    let mut f1 = dir1 * d.impulse;
                    let last = d.warmstart_tangent_impulse;
                    let last_norm = last.norm();
                    if last_norm > 0.0 && d.warmstart_tangent_world.length() > 0.0 {
                        // warmstart_tangent_world = t1·last.x + t2·last.y with t2 = dir1 × t1:
                        // turn it back by last's angle to rebuild (t1, t2), then apply the
                        // total tangent impulse in that basis.
                        let u = d.warmstart_tangent_world.normalize();
                        let u_perp = dir1.cross(u);
                        let (cx, cy) = (last.x / last_norm, last.y / last_norm);
                        let tot = d.tangent_impulse;
                        f1 += u * (cx * tot.x + cy * tot.y) + u_perp * (cx * tot.y - cy * tot.x);
                    }
                    let (f, local) = if first {
                        (f1, pt.local_p1)
                    } else {
                        (-f1, pt.local_p2)
                    };
                    let f = f / dt;
                    let p = pose.transform_point(local);
                    force += f;
                    torque += (p - point).cross(f);
                }
            }
        }
    }
    [torque.x, torque.y, torque.z, force.x, force.y, force.z]
}

impl Articulation {
    /// The contact wrench on link `i` (all its colliders) from the last rapier step,
    /// `[torque; force]` in the world frame about the world point `point`: see
    /// [`colliders_contact_wrench`]. With `point` = [`Self::center_of_mass`] of a free-floating
    /// robot, this is MuJoCo's `cfrc_ext` of the matching body.
    pub fn contact_wrench(&self, w: &PhysicsWorld, i: usize, point: Vector) -> [f32; 6] {
        colliders_contact_wrench(w, &self.colliders[i], point)
    }

    /// The world-frame velocity of every link: `(angular velocity, linear velocity of the
    /// link's body origin)`, by forward recursion from the root over the hinges (exact rigid
    /// kinematics from `qvel` and the current poses, independent of when rapier last wrote the
    /// rigid bodies' own velocities). For a free root, `qvel`'s linear part is taken as the
    /// root origin's velocity: rapier moves a free root with its centre of mass, so put the
    /// root origin at its centre of mass (as the humanoid does) for this to be exact. The
    /// velocity of a point `x` fixed to link `i` is `v + ω × (x − origin_i)`.
    pub fn link_velocities(&self, w: &PhysicsWorld) -> Vec<(Vector, Vector)> {
        let qvel = self.qvel(w);
        let mut out: Vec<(Vector, Vector)> = Vec::with_capacity(self.bodies.len());
        let root = match self.root {
            RootJoint::Planar => (
                Vector::new(0.0, qvel[2], 0.0),
                Vector::new(qvel[0], 0.0, qvel[1]),
            ),
            RootJoint::Free => {
                let rot = self.pose(w, 0).rotation;
                (
                    rot * Vector::new(qvel[3], qvel[4], qvel[5]),
                    Vector::new(qvel[0], qvel[1], qvel[2]),
                )
            }
        };
        out.push(root);
        let nv_root = self.root.nv();
        for i in 1..self.bodies.len() {
            let p = self.parents[i];
            let (wp, vp) = out[p];
            let parent_pose = self.pose(w, p);
            let axis = parent_pose.rotation * self.axes_in_parent[i];
            let r = self.pose(w, i).translation - parent_pose.translation;
            out.push((wp + axis * qvel[nv_root + i - 1], vp + wp.cross(r)));
        }
        out
    }

    /// The robot's centre of mass in the world frame (every link, connectors included), m.
    pub fn center_of_mass(&self, w: &PhysicsWorld) -> Vector {
        let (mut sum, mut mass) = (Vector::ZERO, 0.0);
        for &h in &self.bodies {
            let rb = &w.bodies[h];
            let m = rb.mass();
            sum += m * rb.position().transform_point(rb.local_center_of_mass());
            mass += m;
        }
        sum / mass
    }
}

/// An action as the robots take it: each entry clipped to [−1, 1], NaN read as 0 (zero torque
/// rather than poisoned physics); missing entries are 0.
pub fn clip_actions<const N: usize>(action: &[f32]) -> [f32; N] {
    let mut a = [0.0f32; N];
    for (ai, x) in a.iter_mut().zip(action) {
        *ai = if x.is_nan() { 0.0 } else { x.clamp(-1.0, 1.0) };
    }
    a
}

/// A robot in a world of its own, integrated as its [`SimParams`] say: what each locomotion env
/// holds. It knows how to build its world afresh, so every episode starts from a new world (no
/// contact or solver cache carries over, and an episode depends only on its seed and actions).
pub struct Robot {
    /// The world: the floor and the robot's bodies.
    pub world: PhysicsWorld,
    /// The robot's links in [`Robot::world`].
    pub links: Articulation,
    sim: SimParams,
    build: fn(&SimParams) -> (PhysicsWorld, Articulation),
    tuning: PhysicsTuning,
}

/// Overrides of a robot's physics settings on top of what its `build` chose: what the
/// fidelity measurement ([`crate`]'s `fidelity` tests) sweeps; unset fields keep the robot's own.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhysicsTuning {
    /// The articulation's Coriolis terms explicit (see [`Articulation::set_explicit_coriolis`]).
    pub explicit_coriolis: Option<bool>,
}

impl PhysicsTuning {
    fn apply(&self, w: &mut PhysicsWorld, art: &Articulation) {
        if let Some(e) = self.explicit_coriolis {
            art.set_explicit_coriolis(w, e);
        }
    }
}

impl Robot {
    /// The robot of `build` at its rest pose, integrated with `sim`.
    pub fn new(sim: SimParams, build: fn(&SimParams) -> (PhysicsWorld, Articulation)) -> Self {
        let (world, links) = Self::fresh(&sim, build);
        Self {
            world,
            links,
            sim,
            build,
            tuning: PhysicsTuning::default(),
        }
    }

    /// The robot's world as `build` makes it, with `sim`'s joint limits.
    fn fresh(
        sim: &SimParams,
        build: fn(&SimParams) -> (PhysicsWorld, Articulation),
    ) -> (PhysicsWorld, Articulation) {
        if let Err(e) = sim.check_limit() {
            panic!("{e}");
        }
        let (mut world, mut links) = build(sim);
        let implicit_step = sim
            .implicit_limits
            .then(|| sim.control_dt / sim.substeps as f32);
        links.set_limit_frequency(&mut world, sim.limit_frequency, implicit_step);
        (world, links)
    }

    /// Applies `tuning` now and to every world built from here on.
    pub fn set_tuning(&mut self, tuning: PhysicsTuning) {
        self.tuning = tuning;
        tuning.apply(&mut self.world, &self.links);
    }

    /// Puts the robot at `qpos`/`qvel` (see [`Articulation::set_state`]) in a fresh world.
    pub fn restart(&mut self, qpos: &[f32], qvel: &[f32]) {
        let (mut world, links) = Self::fresh(&self.sim, self.build);
        self.tuning.apply(&mut world, &links);
        links.set_state(&mut world, qpos, qvel);
        self.world = world;
        self.links = links;
    }

    /// One control step: the joint `torques` (N·m, one per hinge) held over the rapier steps
    /// (with soft limits, each step's limit torques added to them).
    pub fn step(&mut self, torques: &[f32]) {
        // Only soft limits change the torques from one rapier step to the next.
        let mut with_limits = Vec::new();
        for _ in 0..self.sim.substeps {
            let applied = if self.links.has_soft_limits() {
                with_limits.clear();
                with_limits.extend_from_slice(torques);
                self.links.add_limit_torques(&self.world, &mut with_limits);
                &with_limits
            } else {
                torques
            };
            // Rapier's user forces persist until cleared; `apply_joint_torques` sets them anew.
            self.links.apply_joint_torques(&mut self.world, applied);
            self.world.step();
        }
    }

    /// The settings this robot integrates with.
    pub fn sim(&self) -> SimParams {
        self.sim
    }

    pub fn qpos(&self) -> Vec<f32> {
        self.links.qpos(&self.world)
    }

    pub fn qvel(&self) -> Vec<f32> {
        self.links.qvel(&self.world)
    }

    /// Total mass, kg.
    pub fn mass(&self) -> f32 {
        self.links.mass(&self.world)
    }

    /// Whether every body is still finite (see [`Articulation::is_sane`]).
    pub fn is_sane(&self) -> bool {
        self.links.is_sane(&self.world)
    }

    /// Link `i`'s body pose.
    pub fn pose(&self, i: usize) -> Pose {
        self.links.pose(&self.world, i)
    }

    /// What the world holds, to draw (see [`robot_scene`]).
    pub fn scene(&self) -> crate::scene::Scene {
        robot_scene(&self.world, &self.links)
    }
}

/// A collider as a drawable [`crate::scene::Shape`] in the world frame: balls, capsules and
/// cuboids as they are, convex polyhedra as their local bounding box (close enough to see);
/// `None` for shapes with no solid to draw (half-spaces: see [`world_floor`]).
pub fn collider_shape(c: &Collider, color: crate::scene::Color) -> Option<crate::scene::Shape> {
    use crate::scene::Shape;
    let pose = c.position();
    let q = pose.rotation;
    let rotation = [q.w, q.x, q.y, q.z];
    let at = |v: Vector| [v.x, v.y, v.z];
    let shape = c.shape();
    if let Some(b) = shape.as_ball() {
        Some(Shape::sphere(at(pose.translation), b.radius, color))
    } else if let Some(cap) = shape.as_capsule() {
        let a = pose.transform_point(cap.segment.a);
        let b = pose.transform_point(cap.segment.b);
        Some(Shape::capsule(at(a), at(b), cap.radius, color))
    } else if let Some(cu) = shape.as_cuboid() {
        Some(Shape::cuboid(
            at(pose.translation),
            at(cu.half_extents),
            rotation,
            color,
        ))
    } else if shape.as_halfspace().is_some() {
        None
    } else {
        let aabb = shape.compute_local_aabb();
        Some(Shape::cuboid(
            at(pose.transform_point(aabb.center())),
            at(aabb.half_extents()),
            rotation,
            color,
        ))
    }
}

/// The height of the world's ground: its first half-space collider facing +Z.
pub fn world_floor(w: &PhysicsWorld) -> Option<f32> {
    w.colliders.iter().find_map(|(_, c)| {
        let h = c.shape().as_halfspace()?;
        let n = c.position().rotation * h.normal;
        (n.z > 0.99).then_some(c.position().translation.z)
    })
}

/// The scene of a robot built with [`Articulation::build`]: every link's colliders, coloured
/// per link ([`crate::scene::colors::link`]), the world's floor, the camera on the root link
/// (at half the robot's height);
/// a side view for a planar robot, a three-quarter view for a free one. Any [`Robot`] draws
/// with [`Robot::scene`].
pub fn robot_scene(world: &PhysicsWorld, robot: &Articulation) -> crate::scene::Scene {
    use crate::scene::{colors, Floor, Scene, View};
    let mut shapes = Vec::new();
    for (i, cs) in robot.colliders.iter().enumerate() {
        for &c in cs {
            if let Some(s) = collider_shape(&world.colliders[c], colors::link(i)) {
                shapes.push(s);
            }
        }
    }
    let root = robot.pose(world, 0).translation;
    let floor = world_floor(world);
    // The robot's size: the span of its shapes (from the floor up, if there is one).
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for s in &shapes {
        let r = s.bounding_radius();
        for k in 0..3 {
            lo[k] = lo[k].min(s.position[k] - r);
            hi[k] = hi[k].max(s.position[k] + r);
        }
    }
    if let Some(h) = floor {
        lo[2] = lo[2].min(h);
    }
    let extent = (0..3)
        .map(|k| hi[k] - lo[k])
        .filter(|x| x.is_finite())
        .fold(0.1f32, f32::max);
    Scene {
        shapes,
        floor: floor.map(|h| Floor::new(h, 0.5)),
        // Above the root, halfway up the robot (from the floor): a camera aimed there sees it
        // whole, feet and floor included.
        focus: [root.x, root.y, (lo[2] + hi[2]) / 2.0],
        extent,
        view: match robot.root {
            RootJoint::Planar => View::Side,
            RootJoint::Free => View::ThreeQuarter,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A checkpoint's env record written before `pgs_iterations` existed reads as rapier's 1,
    /// what every robot had then: such a run resumes on this build with no difference to accept.
    #[test]
    fn records_older_than_pgs_iterations_read_as_rapier_default() {
        use crate::{ant, halfcheetah, hopper, humanoid, walker2d};
        for sim in [
            hopper::SIM,
            walker2d::SIM,
            halfcheetah::SIM,
            ant::SIM,
            humanoid::SIM,
        ] {
            let mut old = serde_json::to_value(sim).unwrap();
            assert_eq!(old["pgs_iterations"], 1);
            old.as_object_mut().unwrap().remove("pgs_iterations");
            let read: SimParams = serde_json::from_value(old).unwrap();
            assert_eq!(read.pgs_iterations, 1);
            assert_eq!(read.fields(), sim.fields());
        }
    }

    fn pendulum_world() -> (PhysicsWorld, Articulation) {
        let p = SimParams {
            control_dt: 0.01,
            substeps: 1,
            solver_iterations: 4,
            prediction_distance: RAPIER_PREDICTION_DISTANCE,
            limit_frequency: RAPIER_LIMIT_FREQUENCY,
            implicit_limits: false,
            stabilization_iterations: RAPIER_STABILIZATION_ITERATIONS,
            pgs_iterations: RAPIER_PGS_ITERATIONS,
            contact_frequency: None,
            contact_damping_ratio: None,
        };
        let mut w = new_world(&p);
        add_floor(&mut w, 1.0);
        let links = [
            LinkDesc::root(
                "base",
                [0.0, 0.0, 2.0],
                vec![Geom::capsule([0.0, 0.0, 2.0], [0.0, 0.0, 2.2], 0.05)],
            ),
            LinkDesc::hinge(
                "arm",
                0,
                [0.0, 0.0, 2.0],
                [0.0, 1.0, 0.0],
                vec![Geom::capsule([0.0, 0.0, 2.0], [0.5, 0.0, 2.0], 0.05)],
            ),
        ];
        let art = Articulation::build(&mut w, RootJoint::Planar, &links);
        (w, art)
    }

    #[test]
    fn set_state_round_trips_and_places_bodies() {
        let (mut w, art) = pendulum_world();
        assert_eq!(art.nq(), 4);
        let q = [0.3, 1.5, 0.2, -0.4];
        let v = [0.1, -0.2, 0.3, 0.4];
        art.set_state(&mut w, &q, &v);
        assert_eq!(art.qpos(&w), q.to_vec());
        assert_eq!(art.qvel(&w), v.to_vec());
        let root = art.pose(&w, 0);
        assert!((root.translation.x - 0.3).abs() < 1e-6 && (root.translation.z - 1.5).abs() < 1e-6);
        // The arm's end: rotated by pitch + hinge about +Y from +X, 0.5 m from the hinge.
        let tip = art.pose(&w, 1).transform_point(Vector::new(0.5, 0.0, 0.0));
        let a = 0.2f32 - 0.4;
        assert!((tip.x - (0.3 + 0.5 * a.cos())).abs() < 1e-5, "{tip:?}");
        assert!((tip.z - (1.5 - 0.5 * a.sin())).abs() < 1e-5, "{tip:?}");
        assert!(tip.y.abs() < 1e-6);
    }

    #[test]
    fn falls_under_gravity_along_minus_z_and_stays_planar() {
        let (mut w, art) = pendulum_world();
        for _ in 0..20 {
            art.apply_joint_torques(&mut w, &[0.0]);
            w.step();
        }
        let q = art.qpos(&w);
        // Free fall for 0.2 s: about 0.196 m.
        assert!((2.0 - q[1] - 0.196).abs() < 0.02, "z {}", q[1]);
        assert!(q[0].abs() < 1e-4, "x {}", q[0]);
        for i in 0..2 {
            assert!(art.pose(&w, i).translation.y.abs() < 1e-6);
        }
        assert!(art.is_sane(&w));
    }

    #[test]
    fn joint_torque_drives_only_its_hinge_relative_motion() {
        let (mut w, art) = pendulum_world();
        w.gravity = Vector::ZERO;
        for _ in 0..10 {
            art.apply_joint_torques(&mut w, &[1.0]);
            w.step();
        }
        let v = art.qvel(&w);
        // Internal torque: the hinge spins up positively, the root pitches back negatively, the
        // centre of mass stays (no net external force).
        assert!(v[3] > 0.1, "{v:?}");
        assert!(v[2] < 0.0, "{v:?}");
    }

    /// A ball with one sprung arm on a free root, `z` above the floor, stepped 10 ms at a time
    /// with `solver_iterations`.
    fn free_world(z: f32, solver_iterations: usize) -> (PhysicsWorld, Articulation) {
        let p = SimParams {
            control_dt: 0.01,
            substeps: 1,
            solver_iterations,
            prediction_distance: RAPIER_PREDICTION_DISTANCE,
            limit_frequency: RAPIER_LIMIT_FREQUENCY,
            implicit_limits: false,
            stabilization_iterations: RAPIER_STABILIZATION_ITERATIONS,
            pgs_iterations: RAPIER_PGS_ITERATIONS,
            contact_frequency: None,
            contact_damping_ratio: None,
        };
        let mut w = new_world(&p);
        add_floor(&mut w, 1.0);
        let links = [
            LinkDesc::root(
                "ball",
                [0.0, 0.0, z],
                vec![Geom::Sphere {
                    c: [0.0, 0.0, z],
                    r: 0.25,
                }],
            ),
            LinkDesc {
                stiffness: 50.0,
                ..LinkDesc::hinge(
                    "arm",
                    0,
                    [0.25, 0.0, z],
                    [0.0, 0.0, 1.0],
                    vec![Geom::capsule([0.25, 0.0, z], [0.65, 0.0, z], 0.05)],
                )
            },
        ];
        let art = Articulation::build(&mut w, RootJoint::Free, &links);
        (w, art)
    }

    #[test]
    fn free_root_state_round_trips_in_mujoco_conventions() {
        let (mut w, art) = free_world(1.0, 4);
        assert_eq!((art.nq(), art.nv()), (8, 7));
        assert_eq!(art.qpos(&w), vec![0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
        // A quarter turn about +Z; angular velocity +X in the body frame is world +Y.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let q = [0.5, -0.2, 1.5, h, 0.0, 0.0, h, 0.3];
        let v = [0.1, 0.2, 0.3, 1.0, 0.0, 0.0, -0.5];
        art.set_state(&mut w, &q, &v);
        let (gq, gv) = (art.qpos(&w), art.qvel(&w));
        for k in 0..8 {
            assert!((gq[k] - q[k]).abs() < 1e-6, "qpos {gq:?}");
        }
        for k in 0..7 {
            assert!((gv[k] - v[k]).abs() < 1e-6, "qvel {gv:?}");
        }
        let mb = art.multibody(&w);
        let world_ang = mb.joint_velocity(art.link(&w, 0));
        assert!((world_ang[4] - 1.0).abs() < 1e-6, "{world_ang:?}");
        // The arm hangs off the ball's local +X, which the turn points along world +Y, then
        // the 0.3 rad hinge about Z swings it further.
        let tip = art.pose(&w, 1).transform_point(Vector::new(0.4, 0.0, 0.0));
        let (s, c) = (std::f32::consts::FRAC_PI_2 + 0.3).sin_cos();
        let want = Vector::new(0.5, -0.2, 1.5) + 0.25 * Vector::Y + 0.4 * Vector::new(c, s, 0.0);
        assert!((tip - want).length() < 1e-5, "{tip:?} vs {want:?}");
    }

    #[test]
    fn free_root_falls_lands_and_feels_its_weight() {
        let (mut w, art) = free_world(1.0, 4);
        for _ in 0..20 {
            art.apply_joint_torques(&mut w, &[0.0]);
            w.step();
        }
        // Free fall for 0.2 s (the arm's spring holds it straight).
        let q = art.qpos(&w);
        assert!((1.0 - q[2] - 0.196).abs() < 0.02, "{q:?}");
        assert!(art.contact_forces(&w).iter().all(|f| f.length() == 0.0));
        for _ in 0..300 {
            art.apply_joint_torques(&mut w, &[0.0]);
            w.step();
        }
        assert!(art.is_sane(&w));
        // At rest on the floor: the contact forces carry the weight.
        let weight = art.mass(&w) * -GRAVITY_Z;
        let up: f32 = art.contact_forces(&w).iter().map(|f| f.z).sum();
        assert!(
            (up - weight).abs() < 0.05 * weight,
            "contact {up} N vs weight {weight} N"
        );
    }

    #[test]
    fn joint_spring_pulls_back_to_zero() {
        let (mut w, art) = free_world(3.0, 4);
        w.gravity = Vector::ZERO;
        let mut q = art.qpos(&w);
        q[7] = 0.5;
        art.set_state(&mut w, &q, &[0.0; 7]);
        let mut crossed = false;
        for _ in 0..100 {
            art.apply_joint_torques(&mut w, &[0.0]);
            w.step();
            crossed |= art.qpos(&w)[7] < 0.0;
        }
        assert!(crossed, "the spring never pulled the hinge past 0");
        assert!(art.qpos(&w)[7].abs() < 0.6 && art.is_sane(&w));
    }

    #[test]
    fn connector_links_chain_hinges_into_a_two_axis_joint() {
        let p = SimParams {
            control_dt: 0.01,
            substeps: 1,
            solver_iterations: 4,
            prediction_distance: RAPIER_PREDICTION_DISTANCE,
            limit_frequency: RAPIER_LIMIT_FREQUENCY,
            implicit_limits: false,
            stabilization_iterations: RAPIER_STABILIZATION_ITERATIONS,
            pgs_iterations: RAPIER_PGS_ITERATIONS,
            contact_frequency: None,
            contact_damping_ratio: None,
        };
        let mut w = new_world(&p);
        w.gravity = Vector::ZERO;
        let cap = |a, b| vec![Geom::capsule(a, b, 0.05)];
        let links = [
            LinkDesc::root(
                "base",
                [0.0, 0.0, 1.0],
                cap([0.0, 0.0, 1.0], [0.0, 0.0, 1.2]),
            ),
            LinkDesc::hinge("hip_x", 0, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], vec![]),
            LinkDesc::hinge(
                "thigh",
                1,
                [0.0, 0.0, 1.0],
                [0.0, 1.0, 0.0],
                cap([0.0, 0.0, 1.0], [0.0, 0.0, 0.6]),
            ),
        ];
        let art = Articulation::build(&mut w, RootJoint::Free, &links);
        assert_eq!(art.nv(), 8);
        let connector = w.bodies[art.bodies[1]].mass();
        assert!(connector > 0.0 && connector < 0.01, "{connector}");
        // Torque on each hinge moves its own coordinate.
        for _ in 0..10 {
            art.apply_joint_torques(&mut w, &[1.0, -1.0]);
            w.step();
        }
        let v = art.qvel(&w);
        assert!(v[6] > 0.1 && v[7] < -0.1 && art.is_sane(&w), "{v:?}");
    }

    /// Each planar robot, settled on a floor where every friction coefficient is μ, then given
    /// 2 m/s forward: friction is the only horizontal force on it, so its centre of mass slows
    /// at μg (Coulomb) while it slides. Upstream rapier left a planar multibody's lower links
    /// almost no friction (`vendor/README.md`, "immobile friction directions"): over 0.3 s the
    /// hopper on its foot slowed by 0.000 m/s, the cheetah on its feet by 0.003, of 1.14.
    #[test]
    fn planar_robots_slide_and_slow_at_mu_g() {
        const MU: f32 = 0.4;
        for (name, mut links) in [
            ("hopper", crate::hopper::links()),
            ("walker2d", crate::walker2d::links()),
            ("halfcheetah", crate::halfcheetah::links()),
        ] {
            let sim = crate::halfcheetah::SIM;
            let mut w = new_world(&sim);
            add_floor(&mut w, MU);
            for l in &mut links {
                l.friction = MU;
            }
            let art = Articulation::build(&mut w, RootJoint::Planar, &links);
            let torques = vec![0.0; art.nv() - 3];
            let step = |w: &mut PhysicsWorld| {
                let before = art.center_of_mass(w);
                art.apply_joint_torques(w, &torques);
                w.step();
                (art.center_of_mass(w) - before) / w.integration_parameters.dt
            };
            for _ in 0..300 {
                step(&mut w);
            }
            let (rest, mut v) = (art.qpos(&w), vec![0.0; art.nv()]);
            v[0] = 2.0;
            art.set_state(&mut w, &rest, &v);
            let dt = w.integration_parameters.dt;
            // 0.1 s: the hopper, upright on its foot, tips over backward soon after.
            let steps = (0.1 / dt).round() as usize;
            let v0 = step(&mut w);
            let mut end = v0;
            for _ in 1..steps {
                end = step(&mut w);
            }
            let slowed = v0.x - end.x;
            let coulomb = MU * -GRAVITY_Z * ((steps - 1) as f32 * dt);
            assert!(
                (slowed - coulomb).abs() < 0.08 * coulomb,
                "{name}: slowed {slowed:.3} m/s in 0.1 s, Coulomb friction {coulomb:.3} (from {:.3})",
                v0.x
            );
        }
    }

    /// A ball with a sprung arm, sliding on the floor: the contact wrench's force (normal and
    /// friction) equals the robot's momentum change minus gravity, and the centre of mass lies
    /// between the ball's centre and the arm.
    #[test]
    fn contact_wrench_matches_the_momentum_change_when_sliding() {
        let (mut w, art) = free_world(0.25, 2);
        let com = art.center_of_mass(&w);
        assert!(com.x > 0.0 && com.x < 0.45 && com.y.abs() < 1e-6, "{com:?}");
        for _ in 0..50 {
            art.apply_joint_torques(&mut w, &[0.0]);
            w.step();
        }
        let q = art.qpos(&w);
        art.set_state(&mut w, &q, &[1.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let m = art.mass(&w);
        for t in 0..10 {
            let v0 = art.qvel(&w);
            art.apply_joint_torques(&mut w, &[0.0]);
            w.step();
            let v1 = art.qvel(&w);
            let com = art.center_of_mass(&w);
            let (a, b) = (
                art.contact_wrench(&w, 0, com),
                art.contact_wrench(&w, 1, com),
            );
            let f = Vector::new(a[3] + b[3], a[4] + b[4], a[5] + b[5]);
            let want = m * (Vector::new(v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]) / 0.01)
                - m * Vector::new(0.0, 0.0, GRAVITY_Z);
            // Sliding along (1, 0.5): friction opposes it (μ = 1, so about the weight).
            if t >= 4 {
                assert!(
                    (f - want).length() < 0.05 * want.length(),
                    "{f:?} vs {want:?}"
                );
                assert!(f.x < -0.5 * m * 9.81 && f.y < 0.0, "{f:?}");
            }
        }
    }
}
