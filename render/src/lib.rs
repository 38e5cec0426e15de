//! A small software ray caster for [`selkd_envs::scene::Scene`]s: one ray per pixel against
//! spheres, capsules, boxes and a checkered floor, Lambert shading from one sun with a shadow
//! ray, and a sky gradient. Enough to see what a robot does, with no GPU or window, fast enough
//! for a thousand-step episode in a few seconds.
//!
//! Used by `selkd render` (GIFs and PNG strips) and by the Python package's
//! `render_mode="rgb_array"`; [`Camera::following`] frames an episode the same way for both.

use selkd_envs::scene::{Scene, Shape, ShapeKind, View};

type V3 = [f32; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn scale(a: V3, s: f32) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V3, b: V3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn normalize(a: V3) -> V3 {
    scale(a, 1.0 / dot(a, a).sqrt().max(1e-20))
}

/// `q · v · q⁻¹` for a unit quaternion `[w, x, y, z]`.
fn rotate(q: [f32; 4], v: V3) -> V3 {
    let u = [q[1], q[2], q[3]];
    let c1 = cross(u, v);
    let c2 = cross(u, c1);
    add(v, add(scale(c1, 2.0 * q[0]), scale(c2, 2.0)))
}

fn inverse_rotate(q: [f32; 4], v: V3) -> V3 {
    rotate([q[0], -q[1], -q[2], -q[3]], v)
}

/// A pinhole camera.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub eye: V3,
    forward: V3,
    right: V3,
    up: V3,
    /// tan(vertical field of view / 2).
    tan_half: f32,
}

const FOV_DEG: f32 = 40.0;

impl Camera {
    /// A camera that looks at `target` along the view's direction, from far enough that about
    /// `extent` around the target fills the picture's height.
    pub fn looking_at(target: V3, extent: f32, view: View) -> Self {
        let dir = normalize(match view {
            View::Side => [0.0, 1.0, -0.12],
            View::ThreeQuarter => [0.45, 0.85, -0.5],
        });
        let tan_half = (FOV_DEG.to_radians() / 2.0).tan();
        let distance = 0.65 * extent / tan_half;
        let right = normalize(cross(dir, [0.0, 0.0, 1.0]));
        Self {
            eye: sub(target, scale(dir, distance)),
            forward: dir,
            right,
            up: cross(right, dir),
            tan_half,
        }
    }

    /// The camera for frame `now` of an episode that started with `first`: distance (the
    /// first frame's extent), height (its focus) and view stay fixed, and the camera follows the
    /// focus sideways, so a running robot stays in the picture while the floor shows it moving.
    pub fn following(first: &Scene, now: &Scene) -> Self {
        Self::looking_at(
            [now.focus[0], now.focus[1], first.focus[2]],
            first.extent,
            first.view,
        )
    }

    /// The ray through pixel centre `(px, py)` of a `w`×`h` picture (y down).
    fn ray(&self, px: f32, py: f32, w: usize, h: usize) -> V3 {
        let aspect = w as f32 / h as f32;
        let sx = (2.0 * px / w as f32 - 1.0) * self.tan_half * aspect;
        let sy = (1.0 - 2.0 * py / h as f32) * self.tan_half;
        normalize(add(
            self.forward,
            add(scale(self.right, sx), scale(self.up, sy)),
        ))
    }
}

/// The colour of the sky for a ray going in direction `d`.
fn sky(d: V3) -> V3 {
    let t = d[2].clamp(-0.2, 1.0) * 0.5 + 0.5;
    let horizon = [0.86, 0.9, 0.95];
    let zenith = [0.45, 0.62, 0.85];
    add(scale(horizon, 1.0 - t), scale(zenith, t))
}

/// The sky's colour for a ray in direction `d` (what an empty scene shows).
#[cfg(test)]
fn sky_rgb(d: V3) -> [u8; 3] {
    to_rgb(sky(normalize(d)))
}

fn to_rgb(c: V3) -> [u8; 3] {
    c.map(|x| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
}

/// The nearest hit of the ray `o + t·d` (t > `t_min`) on `s`: (t, world normal).
fn hit_shape(s: &Shape, o: V3, d: V3, t_min: f32) -> Option<(f32, V3)> {
    // Cheap reject: the ray misses the shape's bounding ball.
    let oc = sub(o, s.position);
    let r = s.bounding_radius();
    let b = dot(oc, d);
    let c = dot(oc, oc) - r * r;
    if c > 0.0 && (b > 0.0 || b * b < c) {
        return None;
    }
    let lo = inverse_rotate(s.rotation, oc);
    let ld = inverse_rotate(s.rotation, d);
    let (t, n) = match s.kind {
        ShapeKind::Sphere { r } => sphere(lo, ld, r, t_min)?,
        ShapeKind::Capsule { half_height, r } => capsule(lo, ld, half_height, r, t_min)?,
        ShapeKind::Box { half_extents } => cuboid(lo, ld, half_extents, t_min)?,
    };
    Some((t, rotate(s.rotation, n)))
}

/// Ray (unit `d`) against a ball of radius `r` at `c`, in local coordinates.
fn sphere_at(o: V3, d: V3, c: V3, r: f32, t_min: f32) -> Option<(f32, V3)> {
    let oc = sub(o, c);
    let b = dot(oc, d);
    let disc = b * b - (dot(oc, oc) - r * r);
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t = if -b - s > t_min { -b - s } else { -b + s };
    (t > t_min).then(|| (t, scale(add(oc, scale(d, t)), 1.0 / r)))
}

fn sphere(o: V3, d: V3, r: f32, t_min: f32) -> Option<(f32, V3)> {
    sphere_at(o, d, [0.0; 3], r, t_min)
}

fn capsule(o: V3, d: V3, hh: f32, r: f32, t_min: f32) -> Option<(f32, V3)> {
    let mut best: Option<(f32, V3)> = None;
    let mut take = |h: Option<(f32, V3)>| {
        if let Some(h) = h {
            if best.is_none_or(|b| h.0 < b.0) {
                best = Some(h);
            }
        }
    };
    // The side: x² + y² = r² for |z| ≤ hh.
    let a = d[0] * d[0] + d[1] * d[1];
    if a > 1e-12 {
        let b = o[0] * d[0] + o[1] * d[1];
        let c = o[0] * o[0] + o[1] * o[1] - r * r;
        let disc = b * b - a * c;
        if disc >= 0.0 {
            let s = disc.sqrt();
            for t in [(-b - s) / a, (-b + s) / a] {
                let z = o[2] + t * d[2];
                if t > t_min && z.abs() <= hh {
                    let p = add(o, scale(d, t));
                    take(Some((t, [p[0] / r, p[1] / r, 0.0])));
                    break;
                }
            }
        }
    }
    take(sphere_at(o, d, [0.0, 0.0, hh], r, t_min));
    take(sphere_at(o, d, [0.0, 0.0, -hh], r, t_min));
    best
}

fn cuboid(o: V3, d: V3, h: V3, t_min: f32) -> Option<(f32, V3)> {
    let (mut t0, mut t1) = (f32::MIN, f32::MAX);
    let (mut n0, mut n1) = ([0.0; 3], [0.0; 3]);
    for k in 0..3 {
        if d[k].abs() < 1e-12 {
            if o[k].abs() > h[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (mut a, mut b) = ((-h[k] - o[k]) * inv, (h[k] - o[k]) * inv);
        let mut na = [0.0; 3];
        na[k] = -d[k].signum();
        let mut nb = [0.0; 3];
        nb[k] = d[k].signum();
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t0 {
            t0 = a;
            n0 = na;
        }
        if b < t1 {
            t1 = b;
            n1 = nb;
        }
        if t0 > t1 {
            return None;
        }
    }
    if t0 > t_min {
        Some((t0, n0))
    } else if t1 > t_min {
        Some((t1, n1))
    } else {
        None
    }
}

/// Where a shape can appear, for skipping it cheaply: a conservative pixel rectangle of its
/// bounding ball, and the floor rectangle its shadow can fall in.
struct Cull {
    /// x0, x1, y0, y1 in pixels.
    screen: [f32; 4],
    /// x0, x1, y0, y1 on the floor.
    shadow: [f32; 4],
}

fn culls(scene: &Scene, cam: &Camera, w: usize, h: usize) -> Vec<Cull> {
    let l = normalize(SUN);
    let aspect = w as f32 / h as f32;
    scene
        .shapes
        .iter()
        .map(|s| {
            let r = s.bounding_radius();
            let rel = sub(s.position, cam.eye);
            let (x, y, z) = (dot(rel, cam.right), dot(rel, cam.up), dot(rel, cam.forward));
            let screen = if z - r > 1e-6 {
                // x/z over the box [x ± r] × [z ± r] is extreme at its corners.
                let range = |c: f32| {
                    let v = [
                        (c - r) / (z - r),
                        (c - r) / (z + r),
                        (c + r) / (z - r),
                        (c + r) / (z + r),
                    ];
                    (
                        v.iter().copied().fold(f32::MAX, f32::min),
                        v.iter().copied().fold(f32::MIN, f32::max),
                    )
                };
                let (sx0, sx1) = range(x);
                let (sy0, sy1) = range(y);
                let px = |sx: f32| (sx / (cam.tan_half * aspect) + 1.0) * 0.5 * w as f32;
                let py = |sy: f32| (1.0 - sy / cam.tan_half) * 0.5 * h as f32;
                [px(sx0) - 1.0, px(sx1) + 1.0, py(sy1) - 1.0, py(sy0) + 1.0]
            } else {
                [f32::MIN, f32::MAX, f32::MIN, f32::MAX]
            };
            let shadow = match scene.floor {
                Some(f) => {
                    // The ball's shadow along the sun: its centre's, widened by r / sin(sun).
                    let k = (s.position[2] - f.height) / l[2];
                    let (cx, cy) = (s.position[0] - l[0] * k, s.position[1] - l[1] * k);
                    let rr = r / l[2] + 1e-3 * scene.extent;
                    [cx - rr, cx + rr, cy - rr, cy + rr]
                }
                None => [f32::MIN, f32::MAX, f32::MIN, f32::MAX],
            };
            Cull { screen, shadow }
        })
        .collect()
}

/// Draws `scene` seen by `cam` as `w`×`h` RGB bytes, rows top to bottom.
pub fn render(scene: &Scene, cam: &Camera, w: usize, h: usize) -> Vec<u8> {
    let mut out = vec![0u8; w * h * 3];
    let culls = culls(scene, cam, w, h);
    let culls = &culls;
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, 8);
    let rows_per = h.div_ceil(threads).max(1);
    std::thread::scope(|sc| {
        for (chunk, rows) in out.chunks_mut(rows_per * w * 3).enumerate() {
            sc.spawn(move || {
                for (i, px) in rows.chunks_exact_mut(3).enumerate() {
                    let (x, y) = (i % w, chunk * rows_per + i / w);
                    let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
                    let d = cam.ray(fx, fy, w, h);
                    px.copy_from_slice(&to_rgb(trace(scene, culls, [fx, fy], cam.eye, d)));
                }
            });
        }
    });
    out
}

/// Direction toward the sun: high, from the camera's side and the left.
const SUN: V3 = [-0.35, -0.55, 0.76];

/// Whether `p` is in the shadow of a shape; `on_floor` points skip shapes whose shadow falls
/// elsewhere.
fn shadowed(scene: &Scene, culls: &[Cull], p: V3, on_floor: bool) -> bool {
    let l = normalize(SUN);
    let eps = 1e-4 * (1.0 + scene.extent);
    scene.shapes.iter().zip(culls).any(|(s, c)| {
        let b = c.shadow;
        (!on_floor || (p[0] >= b[0] && p[0] <= b[1] && p[1] >= b[2] && p[1] <= b[3]))
            && hit_shape(s, p, l, eps).is_some()
    })
}

fn trace(scene: &Scene, culls: &[Cull], pixel: [f32; 2], o: V3, d: V3) -> V3 {
    let mut best: Option<(f32, V3, [u8; 3])> = None;
    for (s, c) in scene.shapes.iter().zip(culls) {
        let r = c.screen;
        if pixel[0] < r[0] || pixel[0] > r[1] || pixel[1] < r[2] || pixel[1] > r[3] {
            continue;
        }
        if let Some((t, n)) = hit_shape(s, o, d, 0.0) {
            if best.is_none_or(|b| t < b.0) {
                best = Some((t, n, s.color));
            }
        }
    }
    let floor_t = scene.floor.and_then(|f| {
        let t = (f.height - o[2]) / d[2];
        (d[2] < 0.0 && t > 0.0).then_some(t)
    });
    let l = normalize(SUN);
    let lin = |c: [u8; 3]| c.map(|x| x as f32 / 255.0);
    match (best, floor_t) {
        (Some((t, n, color)), ft) if ft.is_none_or(|ft| t < ft) => {
            // Normals face the viewer (a ray from inside a shape sees its back faces).
            let n = if dot(n, d) > 0.0 { scale(n, -1.0) } else { n };
            let p = add(o, scale(d, t));
            let lambert = dot(n, l).max(0.0);
            let lit = if lambert > 0.0
                && shadowed(scene, culls, add(p, scale(n, 1e-3 * scene.extent)), false)
            {
                0.0
            } else {
                lambert
            };
            // A little light from the sky above keeps the shade side readable.
            let fill = 0.12 * (0.5 + 0.5 * n[2]);
            scale(lin(color), 0.28 + fill + 0.62 * lit)
        }
        (_, Some(t)) => {
            let f = scene.floor.expect("a floor hit");
            let p = add(o, scale(d, t));
            let c = f.checker.max(1e-6);
            let parity = ((p[0] / c).floor() as i64 + (p[1] / c).floor() as i64).rem_euclid(2);
            let base = lin(f.colors[parity as usize]);
            let lit = if shadowed(scene, culls, p, true) {
                0.55
            } else {
                1.0
            };
            // The far floor fades into the horizon.
            let fade = (-t / (12.0 * scene.extent.max(1e-6))).exp();
            add(scale(base, lit * fade), scale(sky(d), 1.0 - fade))
        }
        _ => sky(d),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use selkd_envs::scene::{Floor, IDENTITY};

    fn scene(shapes: Vec<Shape>, floor: Option<Floor>) -> Scene {
        Scene {
            shapes,
            floor,
            focus: [0.0, 0.0, 1.0],
            extent: 2.0,
            view: View::Side,
        }
    }

    fn pixel(img: &[u8], w: usize, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * w + x);
        [img[i], img[i + 1], img[i + 2]]
    }

    #[test]
    fn a_sphere_in_front_of_the_camera_colours_the_centre_floor_elsewhere() {
        let red = [220, 30, 30];
        let s = scene(
            vec![Shape::sphere([0.0, 0.0, 1.0], 0.3, red)],
            Some(Floor::new(0.0, 0.5)),
        );
        let cam = Camera::looking_at(s.focus, s.extent, s.view);
        let (w, h) = (64, 48);
        let img = render(&s, &cam, w, h);
        let c = pixel(&img, w, w / 2, h / 2);
        assert!(
            c[0] > 80 && c[0] > 2 * c[1] && c[0] > 2 * c[2],
            "centre {c:?}"
        );
        // The bottom row is the floor (grey checker), not the sphere nor the sky.
        let floor = pixel(&img, w, 3, h - 1);
        let sky = sky_rgb(cam.ray(3.5, h as f32 - 0.5, w, h));
        assert!(floor[0].abs_diff(floor[1]) < 30, "floor {floor:?}");
        assert_ne!(floor, sky);
        // The top corner is sky.
        let top = pixel(&img, w, 0, 0);
        assert_eq!(top, sky_rgb(cam.ray(0.5, 0.5, w, h)));
    }

    #[test]
    fn an_empty_scene_is_sky_and_every_shape_kind_is_hit() {
        let s = scene(vec![], None);
        let cam = Camera::looking_at(s.focus, s.extent, s.view);
        let (w, h) = (32, 24);
        let img = render(&s, &cam, w, h);
        for y in 0..h {
            for x in 0..w {
                let d = cam.ray(x as f32 + 0.5, y as f32 + 0.5, w, h);
                assert_eq!(pixel(&img, w, x, y), sky_rgb(d));
            }
        }
        let green = [30, 200, 30];
        for shape in [
            Shape::capsule([-0.5, 0.0, 1.0], [0.5, 0.0, 1.0], 0.2, green),
            Shape::cuboid([0.0, 0.0, 1.0], [0.3, 0.3, 0.3], IDENTITY, green),
            // A box turned 45° about Z still covers the centre.
            Shape::cuboid(
                [0.0, 0.0, 1.0],
                [0.3, 0.3, 0.3],
                [0.9238795, 0.0, 0.0, 0.38268343],
                green,
            ),
        ] {
            let img = render(&scene(vec![shape], None), &cam, w, h);
            let c = pixel(&img, w, w / 2, h / 2);
            assert!(c[1] > 2 * c[0] && c[1] > 2 * c[2], "{shape:?}: {c:?}");
            assert_eq!(pixel(&img, w, 0, 0), sky_rgb(cam.ray(0.5, 0.5, w, h)));
        }
    }

    #[test]
    fn a_shape_casts_a_shadow_on_the_floor() {
        let s = scene(
            vec![Shape::sphere([0.0, 0.0, 0.4], 0.3, [200, 200, 200])],
            Some(Floor::new(0.0, 100.0)),
        );
        // The floor point straight along the sun from below the ball is darker than one far away.
        let l = normalize(SUN);
        let t = 0.4 / l[2];
        let under = [-l[0] * t, -l[1] * t, 0.0];
        let cam = Camera::looking_at(s.focus, s.extent, s.view);
        let c = culls(&s, &cam, 64, 48);
        for on_floor in [false, true] {
            assert!(shadowed(&s, &c, under, on_floor));
            assert!(!shadowed(&s, &c, [3.0, 3.0, 0.0], on_floor));
        }
    }
}
