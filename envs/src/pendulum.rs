//! Gymnasium's `Pendulum-v1`, ported exactly (g = 10, m = 1, l = 1, dt = 0.05, max speed 8,
//! max torque 2). Torque = 2 · action. The 200-step limit is a truncation: the task never terminates.
//! Like Gymnasium's `g` argument, the gravity can be changed ([`PendulumOptions`]).

use crate::{Env, EnvSpec, Step};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::f64::consts::PI;

const M: f64 = 1.0;
const L: f64 = 1.0;
const DT: f64 = 0.05;
const MAX_SPEED: f64 = 8.0;
const MAX_TORQUE: f64 = 2.0;

/// Options (the run config's `[env_options]`).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PendulumOptions {
    /// Gravity, m/s² (Gymnasium's default 10).
    pub g: f64,
}

impl Default for PendulumOptions {
    fn default() -> Self {
        Self { g: 10.0 }
    }
}

impl PendulumOptions {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.g.is_finite() && self.g > 0.0) {
            return Err(format!("g = {} must be a positive number", self.g));
        }
        Ok(())
    }
}

pub struct Pendulum {
    spec: EnvSpec,
    g: f64,
    theta: f64,
    theta_dot: f64,
    t: usize,
    rng: Pcg64,
}

impl Default for Pendulum {
    fn default() -> Self {
        Self::new()
    }
}

impl Pendulum {
    pub fn new() -> Self {
        Self::with_options(&PendulumOptions::default())
    }

    /// Options are assumed valid ([`PendulumOptions::validate`]).
    pub fn with_options(options: &PendulumOptions) -> Self {
        Self {
            g: options.g,
            spec: EnvSpec {
                id: "pendulum",
                obs_dim: 3,
                act_dim: 1,
                max_episode_steps: 200,
                gymnasium_action_scale: MAX_TORQUE as f32,
            },
            theta: 0.0,
            theta_dot: 0.0,
            t: 0,
            rng: Pcg64::seed_from_u64(0),
        }
    }

    /// Puts the pendulum in a given physical state (angle, angular velocity) at episode start.
    pub fn set_state(&mut self, theta: f64, theta_dot: f64) -> Vec<f32> {
        self.theta = theta;
        self.theta_dot = theta_dot;
        self.t = 0;
        self.obs()
    }

    pub fn state(&self) -> (f64, f64) {
        (self.theta, self.theta_dot)
    }

    fn obs(&self) -> Vec<f32> {
        vec![
            self.theta.cos() as f32,
            self.theta.sin() as f32,
            self.theta_dot as f32,
        ]
    }
}

fn angle_normalize(x: f64) -> f64 {
    (x + PI).rem_euclid(2.0 * PI) - PI
}

impl Env for Pendulum {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: Option<u64>) -> Vec<f32> {
        if let Some(s) = seed {
            self.rng = Pcg64::seed_from_u64(s);
        }
        let theta = self.rng.gen_range(-PI..PI);
        let theta_dot = self.rng.gen_range(-1.0..1.0);
        self.set_state(theta, theta_dot)
    }

    fn step(&mut self, action: &[f32]) -> Step {
        // Gymnasium's action is float32 and, under NumPy 2's promotion rules, a float32 times a
        // Python float stays float32: the torque term `3/(m l²)·u` and the control cost
        // `0.001·u²` are rounded to float32 before they meet the float64 state.
        let u = MAX_TORQUE as f32 * action[0].clamp(-1.0, 1.0);
        let (th, thdot) = (self.theta, self.theta_dot);
        let control_cost = (0.001f32 * (u * u)) as f64;
        let torque_term = ((3.0 / (M * L * L)) as f32 * u) as f64;
        let cost = angle_normalize(th).powi(2) + 0.1 * thdot.powi(2) + control_cost;
        let new_thdot = (thdot + (3.0 * self.g / (2.0 * L) * th.sin() + torque_term) * DT)
            .clamp(-MAX_SPEED, MAX_SPEED);
        self.theta = th + new_thdot * DT;
        self.theta_dot = new_thdot;
        self.t += 1;
        debug_assert!(u.abs() as f64 <= MAX_TORQUE);
        Step {
            obs: self.obs(),
            reward: -cost,
            terminated: false,
            truncated: self.t >= self.spec.max_episode_steps,
            success: None,
        }
    }

    /// Gymnasium's picture: a rod of length `L` on a pivot, upright at θ = 0 and turning
    /// counter-clockwise as θ grows, seen from the side (here in the x–z plane, pivot 1.2 above
    /// a floor so that the hanging rod clears it).
    fn scene(&self) -> Option<crate::scene::Scene> {
        use crate::scene::{colors, Floor, Scene, Shape, View};
        let pivot = [0.0, 0.0, 1.2];
        let (s, c) = (self.theta as f32).sin_cos();
        let tip = [-(L as f32) * s, 0.0, pivot[2] + L as f32 * c];
        Some(Scene {
            shapes: vec![
                Shape::capsule(pivot, tip, 0.1, colors::TORSO),
                Shape::sphere([pivot[0], -0.06, pivot[2]], 0.07, colors::DARK),
            ],
            floor: Some(Floor::new(0.0, 0.5)),
            focus: [0.0, 0.0, 1.1],
            extent: 2.4,
            view: View::Side,
        })
    }

    fn control_dt(&self) -> Option<f64> {
        Some(DT)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    fn golden() -> Vec<Value> {
        // Gymnasium's own transitions (how they were made: envs/testdata/README.md).
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/testdata/pendulum_v1.jsonl");
        let text = std::fs::read_to_string(path).expect("envs/testdata/pendulum_v1.jsonl");
        text.lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    }

    fn f(v: &Value) -> f64 {
        v.as_f64().unwrap()
    }

    fn close(a: f64, b: f64, what: &str) {
        assert!((a - b).abs() <= 1e-6, "{what}: {a} vs golden {b}");
    }

    /// The float64 state after one step: float32 rounding of the torque term shows here as
    /// ~1e-8 (float64 arithmetic throughout would miss by that much), so this is held to 1e-12.
    fn exact(a: f64, b: f64, what: &str) {
        assert!((a - b).abs() <= 1e-12, "{what}: {a} vs golden {b}");
    }

    #[test]
    fn matches_gymnasium_single_steps() {
        let rows = golden();
        let steps: Vec<_> = rows.iter().filter(|r| r["kind"] == "step").collect();
        assert!(steps.len() >= 100);
        for r in steps {
            let mut env = Pendulum::new();
            env.set_state(f(&r["state"][0]), f(&r["state"][1]));
            let out = env.step(&[(f(&r["torque"]) / 2.0) as f32]);
            for d in 0..3 {
                close(out.obs[d] as f64, f(&r["obs"][d]), "obs");
            }
            exact(out.reward, f(&r["reward"]), "reward");
            let (th, thd) = env.state();
            exact(th, f(&r["next_state"][0]), "theta");
            exact(thd, f(&r["next_state"][1]), "theta_dot");
            assert!(!out.terminated && !out.truncated);
        }
    }

    #[test]
    fn matches_gymnasium_trajectories_and_truncates_at_200() {
        let rows = golden();
        let trajs: Vec<_> = rows.iter().filter(|r| r["kind"] == "trajectory").collect();
        assert!(!trajs.is_empty());
        for r in trajs {
            let mut env = Pendulum::new();
            env.set_state(f(&r["state"][0]), f(&r["state"][1]));
            let torques = r["torques"].as_array().unwrap();
            assert_eq!(torques.len(), 200);
            for (t, u) in torques.iter().enumerate() {
                let out = env.step(&[(f(u) / 2.0) as f32]);
                for d in 0..3 {
                    close(out.obs[d] as f64, f(&r["obs"][t][d]), "trajectory obs");
                }
                close(out.reward, f(&r["rewards"][t]), "trajectory reward");
                assert_eq!(out.truncated, t == 199, "truncation at step {t}");
                assert_eq!(
                    Some(out.truncated),
                    r["truncated"][t].as_bool(),
                    "Gymnasium's TimeLimit"
                );
                assert!(!out.terminated);
            }
        }
    }

    #[test]
    fn same_seed_same_episode() {
        let run = |seed| {
            let mut env = Pendulum::new();
            let mut obs = env.reset(Some(seed));
            for i in 0..50 {
                obs.extend(env.step(&[((i as f32) * 0.37).sin()]).obs);
            }
            obs
        };
        assert_eq!(run(7), run(7));
        assert_ne!(run(7), run(8));
    }
}
