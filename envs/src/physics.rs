//! Rigid-body physics shared by the locomotion robots (hopper now; walker2d, halfcheetah, ant and
//! humanoid later), on rapier3d's reduced-coordinate multibodies.
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
//! coordinates are MuJoCo's `rootx`, `rootz`, `rooty`.
//!
//! State layout: `qpos` = root coordinates then one angle per hinge, in link order; `qvel` the
//! matching generalized velocities. Joint torques are applied as equal and opposite world torques
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
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimParams {
    /// Control period, s.
    pub control_dt: f32,
    /// Rapier steps per control step (each of `control_dt / substeps`).
    pub substeps: usize,
    /// Rapier's `num_solver_iterations` per step (rapier's TGS substeps the contact/limit solve
    /// this many times inside a step).
    pub solver_iterations: usize,
}

/// A new world: gravity −Z, the time step and solver settings of `p`.
pub fn new_world(p: &SimParams) -> PhysicsWorld {
    let mut w = PhysicsWorld::new();
    w.gravity = Vector::new(0.0, 0.0, GRAVITY_Z);
    w.integration_parameters.dt = p.control_dt / p.substeps as f32;
    w.integration_parameters.num_solver_iterations = p.solver_iterations;
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
}

impl RootJoint {
    fn ndofs(self) -> usize {
        match self {
            RootJoint::Planar => 3,
        }
    }
}

/// A capsule between two points, radius `r`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Capsule {
    pub a: [f32; 3],
    pub b: [f32; 3],
    pub r: f32,
}

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
    pub geom: Capsule,
    pub density: f32,
    pub friction: f32,
    /// Reflected rotor inertia added on the hinge's coordinate (MuJoCo `armature`), kg·m².
    pub armature: f32,
    /// Viscous joint damping (MuJoCo `damping`), N·m·s/rad.
    pub damping: f32,
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
    nq: usize,
}

impl Articulation {
    /// Builds the robot of `links` (link 0 is the root) attached to the world by `root`, at its
    /// rest pose. Panics on a malformed description (a bug, not an input error).
    pub fn build(w: &mut PhysicsWorld, root: RootJoint, links: &[LinkDesc]) -> Self {
        assert!(!links.is_empty() && links[0].parent.is_none());
        let groups = InteractionGroups::new(ROBOT, FLOOR, InteractionTestMode::And);
        let mut bodies = Vec::with_capacity(links.len());
        for l in links {
            let origin = v3(l.anchor);
            // Robot bodies must never sleep: a sleeping body ignores applied torques.
            let body = w.bodies.insert(
                RigidBodyBuilder::dynamic()
                    .translation(origin)
                    .can_sleep(false),
            );
            let c = ColliderBuilder::capsule_from_endpoints(
                v3(l.geom.a) - origin,
                v3(l.geom.b) - origin,
                l.geom.r,
            )
            .density(l.density)
            .friction(l.friction)
            .friction_combine_rule(CoefficientCombineRule::Max)
            .collision_groups(groups);
            w.colliders.insert_with_parent(c, body, &mut w.bodies);
            bodies.push(body);
        }

        // The root joint: from a collider-less fixed anchor at the world origin.
        let anchor = w.bodies.insert(RigidBodyBuilder::fixed());
        let root_joint = match root {
            RootJoint::Planar => GenericJointBuilder::new(
                JointAxesMask::LIN_Y | JointAxesMask::ANG_X | JointAxesMask::ANG_Z,
            )
            .contacts_enabled(false)
            .build(),
        };
        w.multibody_joints
            .insert(anchor, bodies[0], root_joint, true)
            .expect("root multibody joint");

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
            nq: root.ndofs() + links.len() - 1,
            bodies,
            parents,
            axes_in_parent,
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
        assert_eq!(mb.ndofs(), art.nq, "multibody dofs vs description");
        for d in 0..root.ndofs() {
            mb.damping_mut()[d] = 0.0;
            mb.armature_mut()[d] = 0.0;
        }
        for (i, l) in links.iter().enumerate().skip(1) {
            let d = art.dof(w, i);
            let mb = art.multibody_mut(w);
            mb.damping_mut()[d] = l.damping;
            mb.armature_mut()[d] = l.armature;
        }
        // The rest pose: root coordinates at the root anchor, hinges at zero.
        let mut q = vec![0.0; art.nq];
        match root {
            RootJoint::Planar => {
                q[0] = links[0].anchor[0];
                q[1] = links[0].anchor[2];
            }
        }
        art.set_state(w, &q, &vec![0.0; art.nq]);
        art
    }

    /// Number of generalized coordinates (= velocities: planar roots have no quaternion).
    pub fn nq(&self) -> usize {
        self.nq
    }

    fn multibody<'a>(&self, w: &'a PhysicsWorld) -> &'a Multibody {
        w.multibody_joints
            .get(MultibodyJointHandle(self.bodies[0].0))
            .expect("robot multibody")
            .0
    }

    fn multibody_mut<'a>(&self, w: &'a mut PhysicsWorld) -> &'a mut Multibody {
        w.multibody_joints
            .get_mut(MultibodyJointHandle(self.bodies[0].0))
            .expect("robot multibody")
            .0
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
        let c = self.link(w, 0).joint().coords();
        match self.root {
            // Free coordinates of the planar root: LIN_X, LIN_Z, ANG_Y.
            RootJoint::Planar => q.extend([c[0], c[2], c[4]]),
        }
        for i in 1..self.bodies.len() {
            q.push(self.link(w, i).joint().coords()[3]);
        }
        q
    }

    /// Generalized velocities, in the order of [`Self::qpos`].
    pub fn qvel(&self, w: &PhysicsWorld) -> Vec<f32> {
        let mb = self.multibody(w);
        let mut v = Vec::with_capacity(self.nq);
        v.extend(mb.joint_velocity(self.link(w, 0)).iter());
        for i in 1..self.bodies.len() {
            v.push(mb.joint_velocity(self.link(w, i))[0]);
        }
        v
    }

    /// Puts the robot in the state `(qpos, qvel)` and moves its bodies there.
    pub fn set_state(&self, w: &mut PhysicsWorld, qpos: &[f32], qvel: &[f32]) {
        assert!(qpos.len() == self.nq && qvel.len() == self.nq);
        let cur = self.qpos(w);
        // Displacements are indexed by dof, like velocities; link i's dof order follows `qpos`.
        let mut disp = vec![0.0; self.nq];
        let mut vel = vec![0.0; self.nq];
        let root_dofs = self.root.ndofs();
        for k in 0..root_dofs {
            disp[k] = qpos[k] - cur[k];
            vel[k] = qvel[k];
        }
        for i in 1..self.bodies.len() {
            let d = self.dof(w, i);
            let k = root_dofs + i - 1;
            disp[d] = qpos[k] - cur[k];
            vel[d] = qvel[k];
        }
        let mb = self.multibody_mut(w);
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

#[cfg(test)]
mod tests {
    use super::*;

    fn pendulum_world() -> (PhysicsWorld, Articulation) {
        let p = SimParams {
            control_dt: 0.01,
            substeps: 1,
            solver_iterations: 4,
        };
        let mut w = new_world(&p);
        add_floor(&mut w, 1.0);
        let links = [
            LinkDesc {
                name: "base",
                parent: None,
                anchor: [0.0, 0.0, 2.0],
                axis: [0.0; 3],
                range: None,
                geom: Capsule {
                    a: [0.0, 0.0, 2.0],
                    b: [0.0, 0.0, 2.2],
                    r: 0.05,
                },
                density: 1000.0,
                friction: 1.0,
                armature: 0.0,
                damping: 0.0,
            },
            LinkDesc {
                name: "arm",
                parent: Some(0),
                anchor: [0.0, 0.0, 2.0],
                axis: [0.0, 1.0, 0.0],
                range: None,
                geom: Capsule {
                    a: [0.0, 0.0, 2.0],
                    b: [0.5, 0.0, 2.0],
                    r: 0.05,
                },
                density: 1000.0,
                friction: 1.0,
                armature: 0.0,
                damping: 0.0,
            },
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
}
