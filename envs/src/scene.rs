//! What is in an env's world at one instant, as plain data for a renderer (`selkd render`):
//! spheres, capsules and boxes with poses and colours, an optional checkered floor, and where a
//! camera should look. No rendering here, and no physics: an env fills a [`Scene`] from its state
//! ([`crate::Env::scene`]); robots on [`crate::physics`] get theirs from
//! [`crate::physics::robot_scene`].
//!
//! Conventions: Z is up (as in every env), lengths are in the env's own unit (metres for the
//! robots, millimetres for `fpc-assembly`): [`Scene::extent`] says how large the interesting
//! part is, so a renderer frames any scale alike.

/// An sRGB colour.
pub type Color = [u8; 3];

/// Named colours, so that robots look alike (torso dark, limbs in a cycle of light colours).
pub mod colors {
    use super::Color;
    pub const TORSO: Color = [196, 84, 60];
    pub const ORANGE: Color = [232, 150, 52];
    pub const YELLOW: Color = [226, 204, 72];
    pub const GREEN: Color = [96, 176, 96];
    pub const BLUE: Color = [72, 126, 210];
    pub const PURPLE: Color = [150, 100, 190];
    pub const GREY: Color = [150, 150, 150];
    pub const DARK: Color = [60, 60, 66];
    pub const STEEL: Color = [120, 130, 145];
    pub const BOARD: Color = [40, 110, 70];
    pub const AMBER: Color = [214, 150, 40];
    /// Link `i`'s colour: the torso (link 0), then a cycle that tells neighbouring links apart.
    pub fn link(i: usize) -> Color {
        const CYCLE: [Color; 5] = [ORANGE, BLUE, YELLOW, GREEN, PURPLE];
        if i == 0 {
            TORSO
        } else {
            CYCLE[(i - 1) % CYCLE.len()]
        }
    }
}

/// A solid's form, in its own frame (centred at the shape's position).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ShapeKind {
    Sphere {
        r: f32,
    },
    /// A capsule along its local Z axis: the segment from −`half_height` to +`half_height`,
    /// swept by a ball of radius `r`.
    Capsule {
        half_height: f32,
        r: f32,
    },
    Box {
        half_extents: [f32; 3],
    },
}

/// One solid in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    pub kind: ShapeKind,
    /// Centre, world frame.
    pub position: [f32; 3],
    /// Orientation as a unit quaternion `[w, x, y, z]` (local → world).
    pub rotation: [f32; 4],
    pub color: Color,
}

/// The identity rotation.
pub const IDENTITY: [f32; 4] = [1.0, 0.0, 0.0, 0.0];

impl Shape {
    pub fn sphere(c: [f32; 3], r: f32, color: Color) -> Self {
        Self {
            kind: ShapeKind::Sphere { r },
            position: c,
            rotation: IDENTITY,
            color,
        }
    }

    /// A capsule from `a` to `b` (world frame), radius `r`.
    pub fn capsule(a: [f32; 3], b: [f32; 3], r: f32, color: Color) -> Self {
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        Self {
            kind: ShapeKind::Capsule {
                half_height: len / 2.0,
                r,
            },
            position: [
                (a[0] + b[0]) / 2.0,
                (a[1] + b[1]) / 2.0,
                (a[2] + b[2]) / 2.0,
            ],
            rotation: rotation_from_z(d),
            color,
        }
    }

    /// A box about `c` with `half_extents` along its local axes, turned by `rotation`.
    pub fn cuboid(c: [f32; 3], half_extents: [f32; 3], rotation: [f32; 4], color: Color) -> Self {
        Self {
            kind: ShapeKind::Box { half_extents },
            position: c,
            rotation,
            color,
        }
    }

    /// Radius of a ball about [`Self::position`] that holds the whole shape.
    pub fn bounding_radius(&self) -> f32 {
        match self.kind {
            ShapeKind::Sphere { r } => r,
            ShapeKind::Capsule { half_height, r } => half_height + r,
            ShapeKind::Box { half_extents: h } => (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt(),
        }
    }
}

/// The rotation `[w, x, y, z]` that turns +Z onto the direction `d` (identity for a zero `d`).
pub fn rotation_from_z(d: [f32; 3]) -> [f32; 4] {
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if len.is_nan() || len <= 1e-12 {
        return IDENTITY;
    }
    let (x, y, z) = (d[0] / len, d[1] / len, d[2] / len);
    if z < -1.0 + 1e-6 {
        // Opposite: half a turn about X.
        return [0.0, 1.0, 0.0, 0.0];
    }
    // q = (1 + z·d, Z × d) normalised; Z × d = (−y, x, 0).
    let w = 1.0 + z;
    let n = (w * w + x * x + y * y).sqrt();
    [w / n, -y / n, x / n, 0.0]
}

/// The ground: the plane `z = height`, drawn as a checkerboard of `checker`-sized squares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    pub height: f32,
    pub checker: f32,
    pub colors: [Color; 2],
}

impl Floor {
    pub fn new(height: f32, checker: f32) -> Self {
        Self {
            height,
            checker,
            colors: [[205, 205, 200], [150, 155, 160]],
        }
    }
}

/// Where the camera looks from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// From −Y toward +Y, X to the right and Z up: the plane a planar robot moves in.
    Side,
    /// From the front-left and above (a three-quarter view), for robots that move in 3-D.
    ThreeQuarter,
}

/// Everything a renderer needs to draw one instant of an env.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub shapes: Vec<Shape>,
    pub floor: Option<Floor>,
    /// The camera's target (e.g. the robot's root), world frame.
    pub focus: [f32; 3],
    /// The size of the interesting part (e.g. the robot's height): a camera frames about this
    /// much around the focus.
    pub extent: f32,
    pub view: View,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
        let [w, x, y, z] = q;
        // v' = v + 2w(u × v) + 2u × (u × v), u = (x, y, z).
        let c1 = [
            y * v[2] - z * v[1],
            z * v[0] - x * v[2],
            x * v[1] - y * v[0],
        ];
        let c2 = [
            y * c1[2] - z * c1[1],
            z * c1[0] - x * c1[2],
            x * c1[1] - y * c1[0],
        ];
        [0, 1, 2].map(|i| v[i] + 2.0 * w * c1[i] + 2.0 * c2[i])
    }

    #[test]
    fn capsule_between_points_turns_z_onto_the_segment() {
        for (a, b) in [
            ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
            ([0.0, 0.0, 0.0], [0.0, 0.0, 2.0]),
            ([1.0, 2.0, 0.0], [2.0, 2.0, 1.0]),
            ([0.0, 0.0, 0.0], [0.3, -0.4, 0.0]),
        ] {
            let s = Shape::capsule(a, b, 0.1, colors::GREY);
            let ShapeKind::Capsule { half_height, .. } = s.kind else {
                unreachable!()
            };
            let top = rotate(s.rotation, [0.0, 0.0, half_height]);
            for i in 0..3 {
                assert!((s.position[i] + top[i] - b[i]).abs() < 1e-5, "{a:?} {b:?}");
            }
        }
    }
}
