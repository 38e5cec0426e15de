//! Environments for SELKD behind one trait with Gymnasium semantics, and a registry by name.
//!
//! An env knows nothing of processes or training: it resets from a seed, steps with an action in
//! `[-1, 1]^A` (scaling to its own actuator range inside), and says whether the episode ended
//! because of a real terminal state (`terminated`) or a time limit (`truncated`).
//!
//! Envs: `pendulum` (Gymnasium `Pendulum-v1`, exact), `hopper` (Gymnasium `Hopper-v5`'s task
//! on rapier3d physics instead of MuJoCo) and `fpc-assembly` (the paper's 3C assembly task: a
//! gripper inserts a flexible printed circuit into a connector slot with 0.05 mm clearance,
//! scored by success rate; [`FpcAssembly`], configured by [`FpcConfig`]). [`physics`] holds the
//! rapier helpers that the locomotion robots share: world setup, planar root, hinge chains,
//! joint torques and state.

pub mod fpc_assembly;
mod hopper;
mod pendulum;
pub mod physics;

pub use fpc_assembly::{FpcAssembly, FpcConfig};
pub use hopper::Hopper;
pub use pendulum::Pendulum;

/// What an env is, known before the first reset.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvSpec {
    /// Registry name, e.g. `pendulum`.
    pub id: &'static str,
    pub obs_dim: usize,
    /// Actions are always in `[-1, 1]^act_dim`; the env scales them to its actuators.
    pub act_dim: usize,
    /// Time limit: the step at which an episode is truncated.
    pub max_episode_steps: usize,
}

/// The result of one `step`.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    pub obs: Vec<f32>,
    pub reward: f64,
    /// A real terminal state: bootstrapping stops here.
    pub terminated: bool,
    /// The episode was cut by the time limit: the state is not terminal.
    pub truncated: bool,
    /// Task success, for tasks that have one (reported at episode end).
    pub success: Option<bool>,
}

/// A Gymnasium-style environment. Actions outside `[-1, 1]` are clipped by the env.
pub trait Env: Send {
    fn spec(&self) -> &EnvSpec;
    /// Starts an episode. `Some(seed)` reseeds the env's generator; `None` continues it.
    fn reset(&mut self, seed: Option<u64>) -> Vec<f32>;
    /// Advances one control step. Calling `step` after an episode ended, before `reset`, is a
    /// caller error; envs then keep stepping from the final state.
    fn step(&mut self, action: &[f32]) -> Step;
}

#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    #[error("unknown env `{name}`; known envs: {known}")]
    Unknown { name: String, known: String },
}

type Constructor = fn() -> Box<dyn Env>;

/// Every env by registry name.
const REGISTRY: &[(&str, Constructor)] = &[
    ("pendulum", || Box::new(Pendulum::new())),
    ("hopper", || Box::new(Hopper::new())),
    ("fpc-assembly", || Box::new(FpcAssembly::new())),
];

/// The registry names, in order.
pub fn names() -> Vec<&'static str> {
    REGISTRY.iter().map(|(n, _)| *n).collect()
}

/// Builds an env by registry name (Gymnasium ids such as `Pendulum-v1` and `Hopper-v5` are
/// accepted for `pendulum` and `hopper`).
pub fn make(name: &str) -> Result<Box<dyn Env>, EnvError> {
    let key = canonical(name);
    REGISTRY
        .iter()
        .find(|(n, _)| *n == key)
        .map(|(_, make)| make())
        .ok_or_else(|| EnvError::Unknown {
            name: name.to_string(),
            known: names().join(", "),
        })
}

/// The spec of a registered env, without keeping the env.
pub fn spec(name: &str) -> Result<EnvSpec, EnvError> {
    make(name).map(|e| e.spec().clone())
}

fn canonical(name: &str) -> String {
    match name.to_ascii_lowercase().as_str() {
        "pendulum-v1" => "pendulum".to_string(),
        "hopper-v5" => "hopper".to_string(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registry_builds_every_name_and_rejects_unknown() {
        for n in names() {
            assert_eq!(make(n).unwrap().spec().id, n);
        }
        assert_eq!(spec("Pendulum-v1").unwrap().obs_dim, 3);
        assert_eq!(spec("Hopper-v5").unwrap().obs_dim, 11);
        let err = make("pendulm").err().unwrap().to_string();
        assert!(err.contains("pendulm") && err.contains("pendulum"), "{err}");
    }
}
