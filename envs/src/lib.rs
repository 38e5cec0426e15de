//! Environments for SELKD behind one trait with Gymnasium semantics, and a registry by name.
//!
//! An env knows nothing of processes or training: it resets from a seed, steps with an action in
//! `[-1, 1]^A` (scaling to its own actuator range inside), and says whether the episode ended
//! because of a real terminal state (`terminated`) or a time limit (`truncated`).
//!
//! Envs: `pendulum` (Gymnasium `Pendulum-v1`, exact); `hopper`, `walker2d`, `halfcheetah`,
//! `ant` / `ant-contacts` and `humanoid` (Gymnasium v5's MuJoCo locomotion tasks on rapier3d
//! physics instead of MuJoCo; [`Humanoid`]'s observation parts are chosen by
//! [`HumanoidOptions`]); and `fpc-assembly` (the paper's 3C assembly task: a
//! gripper inserts a flexible printed circuit into a connector slot with 0.05 mm clearance,
//! scored by success rate; [`FpcAssembly`], configured by [`FpcConfig`]). [`Ant`]'s default
//! observation is 27-dim; `ant-contacts` adds v5's 78 contact-force terms (105-dim).
//!
//! [`physics`] holds the rapier helpers that the locomotion robots share: world setup, planar
//! root, hinge chains, joint torques and state, and [`physics::Robot`], a robot in its own world
//! with its physics settings (which a run may override: [`physics::PhysicsOptions`]).
//!
//! One episode, as a worker plays it (`make`, `reset` with a seed, `step` until it ends):
//!
//! ```no_run
//! let mut env = selkd_envs::make("pendulum")?; // or "Pendulum-v1", "hopper", "fpc-assembly", ...
//! let spec = env.spec().clone(); // obs_dim 3, act_dim 1, max_episode_steps 200
//! let mut obs = env.reset(Some(0)); // the same seed gives the same episode, bit for bit
//! let mut episode_return = 0.0;
//! loop {
//!     let action = vec![0.5f32; spec.act_dim]; // always in [-1, 1]; the env scales it
//!     let step = env.step(&action);
//!     episode_return += step.reward;
//!     // `terminated`: a real terminal state (no bootstrapping); `truncated`: the time limit.
//!     if step.terminated || step.truncated {
//!         break;
//!     }
//!     obs = step.obs;
//! }
//! println!("return {episode_return}, last observation {obs:?}");
//! # Ok::<(), selkd_envs::EnvError>(())
//! ```

pub mod ant;
#[cfg(test)]
mod fidelity;
pub mod fpc_assembly;
pub mod gaits;
pub mod halfcheetah;
pub mod hopper;
pub mod humanoid;
mod pendulum;
pub mod physics;
pub mod scene;
#[cfg(test)]
mod testing;
pub mod walker2d;

pub use ant::{Ant, AntObs};
pub use fpc_assembly::{FpcAssembly, FpcConfig};
pub use halfcheetah::HalfCheetah;
pub use hopper::Hopper;
pub use humanoid::{Humanoid, HumanoidOptions};
pub use pendulum::{Pendulum, PendulumOptions};
pub use walker2d::Walker2d;

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
    /// Gymnasium's own version of the task (`Pendulum-v1`, `Hopper-v5`, ...) takes
    /// `gymnasium_action_scale · a` for our action `a`: its action space is ±this (the
    /// pendulum's 2 N·m, the humanoid's 0.4 ctrl range; 1 for the other robots, and for
    /// `fpc-assembly`, which has no counterpart). A `gymnasium:<id>` env whose action Box is not
    /// ±c in every dimension has no such scale: NaN (`selkd export` refuses it).
    pub gymnasium_action_scale: f32,
}

/// An RGB picture, row by row from the top, 3 bytes a pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Picture {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
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

impl Step {
    /// The step that ends an episode whose physics state went non-finite (rapier quarantined a
    /// body): a zero observation, terminated with `reward`, so no env ever emits NaN.
    pub fn non_finite_state(obs_dim: usize, reward: f64, truncated: bool) -> Step {
        Step {
            obs: vec![0.0; obs_dim],
            reward,
            terminated: true,
            truncated,
            success: None,
        }
    }
}

/// A Gymnasium-style environment. Actions outside `[-1, 1]` are clipped by the env.
pub trait Env: Send {
    fn spec(&self) -> &EnvSpec;
    /// Starts an episode. `Some(seed)` reseeds the env's generator; `None` continues it.
    fn reset(&mut self, seed: Option<u64>) -> Vec<f32>;
    /// Advances one control step. Calling `step` after an episode ended, before `reset`, is a
    /// caller error; envs then keep stepping from the final state.
    fn step(&mut self, action: &[f32]) -> Step;
    /// What is in the world now, for drawing (`selkd render`); `None` for an env that cannot
    /// be drawn. A robot on [`physics`] implements it as `Some(self.robot.scene())`.
    fn scene(&self) -> Option<scene::Scene> {
        None
    }
    /// Seconds of simulated time per `step` (frame timing of a rendered episode).
    fn control_dt(&self) -> Option<f64> {
        None
    }
    /// The rapier settings this env integrates with, after its options (a robot on
    /// [`physics`]); `None` for an env without them. Part of a run's [`EnvRecord`].
    fn physics(&self) -> Option<physics::SimParams> {
        None
    }
    /// A picture the env draws itself, for an env with no [`Env::scene`] (a Gymnasium env made
    /// with `render_mode="rgb_array"`): `None` if it cannot draw, else the picture or why
    /// drawing failed.
    fn picture(&self) -> Option<Result<Picture, String>> {
        None
    }
    /// Why the env cannot go on, once it has failed (an exception inside a Gymnasium env's
    /// `reset` or `step`: that step came back terminated, with a zero observation). Our own
    /// envs never fail. A caller checks it after each `reset` and `step`.
    fn failure(&self) -> Option<String> {
        None
    }
}

#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    #[error("unknown env `{name}`; known envs: {known}")]
    Unknown { name: String, known: String },
    #[error("env_options for `{env}`: {message}")]
    Options { env: String, message: String },
    #[error("`{name}`: this program cannot step Gymnasium envs (only selkd, learner and actor-worker can)")]
    Family { name: String },
    /// The env failed (a Python exception in Gymnasium's `make`, `reset` or `step`).
    #[error("{0}")]
    Failed(String),
}

/// An env's options as a TOML table (the run config's `[env_options]`); each env reads them
/// into its own options struct, which rejects unknown keys.
pub type EnvOptions = toml::Table;

type Constructor = fn(&EnvOptions) -> Result<Box<dyn Env>, EnvError>;

/// Every env by registry name.
const REGISTRY: &[(&str, Constructor)] = &[
    ("pendulum", |o| {
        let options: PendulumOptions = parse_options("pendulum", o)?;
        check("pendulum", options.validate())?;
        Ok(Box::new(Pendulum::with_options(&options)))
    }),
    ("hopper", |o| {
        let sim = physics_options("hopper", o, hopper::SIM)?;
        Ok(Box::new(Hopper::with_sim(sim)))
    }),
    ("walker2d", |o| {
        let sim = physics_options("walker2d", o, walker2d::SIM)?;
        Ok(Box::new(Walker2d::with_sim(sim)))
    }),
    ("halfcheetah", |o| {
        let sim = physics_options("halfcheetah", o, halfcheetah::SIM)?;
        Ok(Box::new(HalfCheetah::with_sim(sim)))
    }),
    ("ant", |o| {
        let sim = physics_options("ant", o, ant::SIM)?;
        Ok(Box::new(Ant::with_sim(AntObs::State, sim)))
    }),
    ("ant-contacts", |o| {
        let sim = physics_options("ant-contacts", o, ant::SIM)?;
        Ok(Box::new(Ant::with_sim(AntObs::WithContacts, sim)))
    }),
    ("humanoid", |o| {
        let options: HumanoidOptions = parse_options("humanoid", o)?;
        let sim = check("humanoid", options.physics().apply(humanoid::SIM))?;
        Ok(Box::new(Humanoid::with_sim(&options, sim)))
    }),
    ("fpc-assembly", |o| {
        let config: FpcConfig = parse_options("fpc-assembly", o)?;
        Ok(Box::new(FpcAssembly::with_config(config).map_err(
            |message| EnvError::Options {
                env: "fpc-assembly".into(),
                message,
            },
        )?))
    }),
];

/// Reads `options` into an env's options struct (its defaults fill what is missing).
fn parse_options<T: serde::de::DeserializeOwned>(
    env: &str,
    options: &EnvOptions,
) -> Result<T, EnvError> {
    let read = |table: &EnvOptions| -> Result<T, String> {
        toml::Value::Table(table.clone())
            .try_into()
            .map_err(|e: toml::de::Error| e.message().trim().to_string())
    };
    read(options).map_err(|message| {
        // toml's type errors ("invalid type: integer `1`, expected a boolean") do not say which
        // key: the key that alone gives the same error is the one (named as the run config's
        // own errors name theirs).
        let culprit = options.iter().find(|(key, value)| {
            let alone = EnvOptions::from_iter([((*key).clone(), (*value).clone())]);
            read(&alone).err().as_deref() == Some(message.as_str())
        });
        let message = match culprit {
            Some((key, _)) if !message.contains(&format!("`{key}`")) => {
                format!("{message} in `{key}`")
            }
            _ => message,
        };
        EnvError::Options {
            env: env.into(),
            message,
        }
    })
}

/// A robot's physics settings: its `default`, overridden by the `substeps`,
/// `solver_iterations`, `prediction_distance` and `limit_frequency` keys of `options` (its only
/// keys).
fn physics_options(
    env: &str,
    options: &EnvOptions,
    default: physics::SimParams,
) -> Result<physics::SimParams, EnvError> {
    let overrides: physics::PhysicsOptions = parse_options(env, options)?;
    check(env, overrides.apply(default))
}

fn check<T>(env: &str, valid: Result<T, String>) -> Result<T, EnvError> {
    valid.map_err(|message| EnvError::Options {
        env: env.into(),
        message,
    })
}

/// The registry names, in order.
pub fn names() -> Vec<&'static str> {
    REGISTRY.iter().map(|(n, _)| *n).collect()
}

/// Builds an env by registry name with its default options (Gymnasium ids such as
/// `Pendulum-v1` and `Hopper-v5` are accepted for `pendulum` and `hopper`).
pub fn make(name: &str) -> Result<Box<dyn Env>, EnvError> {
    make_with(name, &EnvOptions::new())
}

/// Envs from outside this crate, by name prefix (`gymnasium:` for Gymnasium's registry): a
/// process that can step them registers their constructor once at start-up
/// ([`register_family`]); this crate only routes names to it.
static FAMILIES: std::sync::Mutex<Vec<(&'static str, ExternalConstructor)>> =
    std::sync::Mutex::new(Vec::new());

/// Builds an env of a family from its full name (`gymnasium:Hopper-v5`) and options.
pub type ExternalConstructor = fn(&str, &EnvOptions) -> Result<Box<dyn Env>, EnvError>;

/// Routes every name that starts with `prefix` (e.g. `"gymnasium:"`) to `make`; registering a
/// prefix again replaces its constructor.
pub fn register_family(prefix: &'static str, make: ExternalConstructor) {
    let mut families = FAMILIES.lock().unwrap_or_else(|e| e.into_inner());
    families.retain(|(p, _)| *p != prefix);
    families.push((prefix, make));
}

/// Builds an env by registry name with `options` (checked: unknown keys and bad values are
/// errors that name them).
///
/// ```no_run
/// // The run config's `[env_options]` table: Pendulum on the Moon.
/// let options: selkd_envs::EnvOptions = toml::from_str("g = 1.62")?;
/// let mut env = selkd_envs::make_with("pendulum", &options)?;
/// let obs = env.reset(Some(7));
/// let step = env.step(&[-1.0]);
/// assert_eq!(obs.len(), step.obs.len());
/// // A learner and its workers compare this to check that they run the same variant.
/// let _fingerprint = selkd_envs::variant_fingerprint(&options, env.physics());
/// // Unknown keys are refused, naming them.
/// let bad: selkd_envs::EnvOptions = toml::from_str("gravity = 1.62")?;
/// assert!(selkd_envs::make_with("pendulum", &bad).is_err());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn make_with(name: &str, options: &EnvOptions) -> Result<Box<dyn Env>, EnvError> {
    let family = FAMILIES
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .iter()
        .find(|(prefix, _)| name.starts_with(prefix))
        .map(|(_, make)| *make);
    if let Some(make) = family {
        return make(name, options);
    }
    if name.starts_with("gymnasium:") {
        return Err(EnvError::Family {
            name: name.to_string(),
        });
    }
    let key = canonical(name);
    let make = REGISTRY
        .iter()
        .find(|(n, _)| *n == key)
        .map(|(_, make)| make)
        .ok_or_else(|| EnvError::Unknown {
            name: name.to_string(),
            known: names().join(", "),
        })?;
    make(options)
}

/// The spec of a registered env, without keeping the env.
pub fn spec(name: &str) -> Result<EnvSpec, EnvError> {
    make(name).map(|e| e.spec().clone())
}

/// A fingerprint of an env variant: its `options` (order-independent) and the `physics`
/// settings they resolve to in this build ([`Env::physics`]), so that a learner and its workers
/// can check that they run the same variant: a worker of another build whose physics defaults
/// differ is told apart as one with other options is.
pub fn variant_fingerprint(options: &EnvOptions, physics: Option<physics::SimParams>) -> u64 {
    // `toml::Table` keeps keys sorted, so its text is canonical.
    let mut h = Fnv1a::new();
    h.eat(toml::to_string(options).unwrap_or_default().as_bytes());
    for (k, v) in physics.iter().flat_map(|p| p.fields()) {
        h.eat(format!("\n{k}={v}").as_bytes());
    }
    h.0
}

/// The 64-bit FNV-1a hash, stable across builds and platforms (std's hashers are not).
struct Fnv1a(u64);

impl Fnv1a {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    fn eat(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    }
}

/// What a run's env was, kept in each checkpoint (`env` in its `state.json`): the name and
/// options the run gives, the physics settings they resolve to in this build, and a fingerprint
/// of a short fixed rollout. The settings show a changed default; the rollout shows any change
/// of the dynamics between builds (a model, the integrator, a default), even where the
/// settings read the same. A run resumed by a build whose record differs would mix two tasks.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvRecord {
    pub env: String,
    pub options: EnvOptions,
    /// [`Env::physics`]: `None` for an env without rapier settings.
    pub physics: Option<physics::SimParams>,
    /// [`rollout_fingerprint`], 16 hex digits; `None` for an env whose seeded rollout does not
    /// repeat (a Gymnasium env that ignores its seed), which then has nothing to compare.
    pub rollout: Option<String>,
}

impl EnvRecord {
    /// This build's record of env `name` with `options` (builds the env and steps it
    /// [`ROLLOUT_STEPS`] times).
    pub fn of(name: &str, options: &EnvOptions) -> Result<Self, EnvError> {
        let mut env = make_with(name, options)?;
        Ok(Self::of_env(name, options, env.as_mut()))
    }

    /// The record of `env`, made as `name` with `options` (for a caller that keeps the env: the
    /// rollouts leave it mid-episode, and the next `reset` with a seed starts afresh).
    pub fn of_env(name: &str, options: &EnvOptions, env: &mut dyn Env) -> Self {
        let (first, second) = (rollout_fingerprint(env), rollout_fingerprint(env));
        Self {
            env: name.to_string(),
            options: options.clone(),
            physics: env.physics(),
            rollout: (first == second).then(|| format!("{first:016x}")),
        }
    }

    /// What differs from `now`, one `field: then → now` per field (empty when nothing does).
    pub fn differences(&self, now: &Self) -> Vec<String> {
        let fields = |r: &Self| {
            let mut f = std::collections::BTreeMap::new();
            f.insert("env".to_string(), r.env.clone());
            let options = toml::to_string(&r.options).unwrap_or_default();
            let options = match options.trim() {
                "" => "none".to_string(),
                o => o.replace('\n', ", "),
            };
            f.insert("options".to_string(), options);
            if let Some(p) = r.physics {
                f.extend(p.fields().map(|(k, x)| (format!("physics.{k}"), x)));
            }
            f
        };
        let (a_fields, b_fields) = (fields(self), fields(now));
        let keys: std::collections::BTreeSet<&String> =
            a_fields.keys().chain(b_fields.keys()).collect();
        let none = "none".to_string();
        let mut changed: Vec<String> = keys
            .into_iter()
            .filter_map(|k| {
                let (a, b) = (
                    a_fields.get(k).unwrap_or(&none),
                    b_fields.get(k).unwrap_or(&none),
                );
                (a != b).then(|| format!("{k}: {a} → {b}"))
            })
            .collect();
        // A rollout that does not repeat has nothing to compare.
        if let (Some(a), Some(b)) = (&self.rollout, &now.rollout) {
            if a != b {
                changed.push(format!("rollout: {a} → {b}"));
            }
        }
        changed
    }
}

/// Steps in [`rollout_fingerprint`]: 1–3 s of simulated time on the robots, through contacts,
/// falls and resets; well under a second to compute.
pub const ROLLOUT_STEPS: usize = 200;

/// A fingerprint of `env`'s dynamics in this build: FNV-1a over the bits of every observation,
/// reward and ending of [`ROLLOUT_STEPS`] steps from `reset(Some(0))` under fixed actions (an
/// episode that ends is reset with the next seed). Deterministic envs give the same value on
/// every run of a build; a change of model, integrator or default changes it. (So might a
/// machine whose maths library rounds a sine differently in its last bit: the envs call the
/// system's.)
pub fn rollout_fingerprint(env: &mut dyn Env) -> u64 {
    let n = env.spec().act_dim;
    fingerprint_rollout(env, ROLLOUT_STEPS, |t| {
        // Exact in f32 and free of libm, whose last bits may differ between machines.
        (0..n)
            .map(|i| ((7 * t + 3 * i) % 21) as f32 / 10.0 - 1.0)
            .collect()
    })
}

/// FNV-1a over the bits of every observation, reward and ending of `steps` steps from
/// `reset(Some(0))` under `action(t)` (an episode that ends is reset with the next seed):
/// [`rollout_fingerprint`] with actions of the caller's choice (the `fingerprints` example's
/// longer random-action rollout).
pub fn fingerprint_rollout(
    env: &mut dyn Env,
    steps: usize,
    mut action: impl FnMut(usize) -> Vec<f32>,
) -> u64 {
    let mut h = Fnv1a::new();
    let eat_obs = |h: &mut Fnv1a, obs: &[f32]| {
        for x in obs {
            h.eat(&x.to_bits().to_le_bytes());
        }
    };
    let mut seed = 0;
    eat_obs(&mut h, &env.reset(Some(seed)));
    for t in 0..steps {
        let s = env.step(&action(t));
        eat_obs(&mut h, &s.obs);
        h.eat(&s.reward.to_bits().to_le_bytes());
        h.eat(&[s.terminated as u8, s.truncated as u8]);
        if s.terminated || s.truncated {
            seed += 1;
            eat_obs(&mut h, &env.reset(Some(seed)));
        }
    }
    h.0
}

fn canonical(name: &str) -> String {
    match name.to_ascii_lowercase().as_str() {
        "pendulum-v1" => "pendulum".to_string(),
        "hopper-v5" => "hopper".to_string(),
        "walker2d-v5" => "walker2d".to_string(),
        "halfcheetah-v5" => "halfcheetah".to_string(),
        "ant-v5" => "ant".to_string(),
        "humanoid-v5" => "humanoid".to_string(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every env: the same seed gives the same episode bit for bit (observations and rewards,
    /// stepping on past a termination: the physics itself must repeat), in a fresh env or in one
    /// that has run other episodes; another seed, or `reset(None)`, gives another episode.
    #[test]
    fn every_env_is_deterministic() {
        for name in names() {
            let mut env = make(name).unwrap();
            let n = env.spec().act_dim;
            let mut rng = rand_pcg::Pcg64::seed_from_u64(42);
            let acts: Vec<Vec<f32>> = (0..100)
                .map(|_| (0..n).map(|_| rng.gen_range(-1.0f32..1.0)).collect())
                .collect();
            let run = |env: &mut Box<dyn Env>, seed| {
                let mut obs = env.reset(Some(seed));
                let mut rewards = vec![];
                for a in &acts {
                    let s = env.step(a);
                    obs.extend(s.obs);
                    rewards.push(s.reward.to_bits());
                }
                (obs.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), rewards)
            };
            let first = run(&mut make(name).unwrap(), 7);
            assert_eq!(
                first,
                run(&mut make(name).unwrap(), 7),
                "{name}: a fresh env"
            );
            assert_ne!(first.0, run(&mut env, 8).0, "{name}: seeds 7 and 8");
            assert_eq!(first, run(&mut env, 7), "{name}: after another episode");
            let a = env.reset(Some(3));
            assert_ne!(a, env.reset(None), "{name}: reset(None)");
        }
    }

    #[test]
    fn registry_builds_every_name_and_rejects_unknown() {
        for n in names() {
            assert_eq!(make(n).unwrap().spec().id, n);
        }
        assert_eq!(spec("Pendulum-v1").unwrap().obs_dim, 3);
        assert_eq!(spec("Hopper-v5").unwrap().obs_dim, 11);
        assert_eq!(spec("Ant-v5").unwrap().obs_dim, 27);
        assert_eq!(spec("ant-contacts").unwrap().obs_dim, 105);
        let err = make("pendulm").err().unwrap().to_string();
        assert!(err.contains("pendulm") && err.contains("pendulum"), "{err}");
    }

    #[test]
    fn every_env_can_be_drawn() {
        for n in names() {
            let mut env = make(n).unwrap();
            let dt = env.control_dt();
            assert!(dt.is_some_and(|dt| dt > 0.0), "{n}: control_dt {dt:?}");
            env.reset(Some(0));
            let before = env.scene().unwrap_or_else(|| panic!("{n} has no scene"));
            assert!(!before.shapes.is_empty() && before.extent > 0.0, "{n}");
            env.step(&vec![0.5; env.spec().act_dim]);
            let after = env.scene().unwrap_or_else(|| panic!("{n} has no scene"));
            assert_eq!(before.shapes.len(), after.shapes.len(), "{n}");
            assert_ne!(before.shapes, after.shapes, "{n}: a step moves something");
            for s in before.shapes.iter().chain(&after.shapes) {
                assert!(
                    s.position.iter().chain(&s.rotation).all(|x| x.is_finite()),
                    "{n}: {s:?}"
                );
            }
        }
    }

    /// The published FNV-1a 64 test vectors (the empty string, "a", "foobar").
    #[test]
    fn fnv1a_matches_its_published_vectors() {
        let hash = |s: &str| {
            let mut h = Fnv1a::new();
            h.eat(s.as_bytes());
            h.0
        };
        assert_eq!(hash(""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(hash("a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(hash("foobar"), 0x8594_4171_f739_67e8);
    }

    /// A run's env record: the same in two fresh builds of an env (and through its JSON); a
    /// physics option changes the settings it shows and the rollout, and the differences name
    /// both; an env whose dynamics change with nothing in its settings (the pendulum's gravity
    /// here, standing for a changed model) changes the rollout alone.
    #[test]
    fn env_records_repeat_and_name_what_changed() {
        for name in names() {
            let a = EnvRecord::of(name, &EnvOptions::new()).unwrap();
            assert_eq!(
                a,
                EnvRecord::of(name, &EnvOptions::new()).unwrap(),
                "{name}"
            );
            let json = serde_json::to_string(&a).unwrap();
            assert_eq!(
                a,
                serde_json::from_str::<EnvRecord>(&json).unwrap(),
                "{name}"
            );
            assert!(a.differences(&a).is_empty());
            assert_eq!(
                a.physics.is_some(),
                !["pendulum", "fpc-assembly"].contains(&name),
                "{name}"
            );
        }
        let hopper = EnvRecord::of("hopper", &EnvOptions::new()).unwrap();
        let finer = EnvRecord::of("hopper", &table("substeps = 3")).unwrap();
        assert_eq!(finer.physics.unwrap().substeps, 3);
        assert_ne!(hopper.rollout, finer.rollout);
        let d = hopper.differences(&finer);
        assert_eq!(d.len(), 3, "{d:?}");
        assert_eq!(d[0], "options: none → substeps = 3");
        assert_eq!(d[1], "physics.substeps: 4 → 3");
        assert!(d[2].starts_with("rollout: "), "{d:?}");
        let near = EnvRecord::of("hopper", &table("prediction_distance = 0.03")).unwrap();
        assert_eq!(
            hopper.differences(&near)[1],
            "physics.prediction_distance: 0.02 → 0.03"
        );
        let earth = EnvRecord::of("pendulum", &EnvOptions::new()).unwrap();
        let mut moon = EnvRecord::of("pendulum", &table("g = 1.62")).unwrap();
        moon.options = earth.options.clone();
        let d = earth.differences(&moon);
        assert_eq!(d.len(), 1, "{d:?}");
        assert!(d[0].starts_with("rollout: "), "{d:?}");
        // An env whose seeded rollout does not repeat records none, and is compared without it.
        struct Unseeded(u64, EnvSpec);
        impl Env for Unseeded {
            fn spec(&self) -> &EnvSpec {
                &self.1
            }
            fn reset(&mut self, _seed: Option<u64>) -> Vec<f32> {
                self.0 += 1;
                vec![self.0 as f32]
            }
            fn step(&mut self, _action: &[f32]) -> Step {
                Step {
                    obs: vec![0.0],
                    reward: 0.0,
                    terminated: false,
                    truncated: false,
                    success: None,
                }
            }
        }
        let spec = spec("pendulum").unwrap();
        let unrepeatable =
            EnvRecord::of_env("pendulum", &EnvOptions::new(), &mut Unseeded(0, spec));
        assert_eq!(unrepeatable.rollout, None);
        assert!(earth.differences(&unrepeatable).is_empty());
        assert!(unrepeatable.differences(&moon).is_empty());
        // A record from before a field existed reads as "none".
        let bare = EnvRecord {
            physics: None,
            ..hopper.clone()
        };
        assert!(bare
            .differences(&hopper)
            .iter()
            .any(|l| l == "physics.substeps: none → 4"));
    }

    fn table(text: &str) -> EnvOptions {
        toml::from_str(text).unwrap()
    }

    #[test]
    fn options_are_read_checked_and_fingerprinted() {
        // Pendulum's gravity: from the same seeded start, a stronger pull changes the angular
        // velocity more in one step.
        let pull = |opts: &str| {
            let mut env = make_with("pendulum", &table(opts)).unwrap();
            let before = env.reset(Some(0))[2];
            (env.step(&[0.0]).obs[2] - before).abs()
        };
        assert!(pull("g = 20.0") > 1.5 * pull(""), "g is not applied");
        let err = |name: &str, opts: &str| make_with(name, &table(opts)).err().unwrap().to_string();
        let e = err("pendulum", "gravity = 3.0");
        assert!(
            e.contains("env_options for `pendulum`") && e.contains("gravity"),
            "{e}"
        );
        let e = err("pendulum", "g = \"strong\"");
        assert!(
            e.contains("invalid type: string \"strong\"") && e.ends_with("in `g`"),
            "{e}"
        );
        let e = err("pendulum", "g = -1.0");
        assert!(e.contains("g = -1 must be a positive number"), "{e}");
        let e = err("hopper", "g = 1.0");
        assert!(
            e.contains("env_options for `hopper`") && e.contains("`g`"),
            "{e}"
        );
        assert!(e.contains("substeps"), "names the keys there are: {e}");
        assert!(!e.contains('\n'));
        // The robots' physics settings are options, each checked.
        for name in [
            "hopper",
            "walker2d",
            "halfcheetah",
            "ant",
            "ant-contacts",
            "humanoid",
        ] {
            let e = err(name, "substeps = 0");
            assert!(
                e.contains(name) && e.contains("`substeps` must be 1 to 640, got 0"),
                "{e}"
            );
            let e = err(name, "solver_iterations = 641");
            assert!(
                e.contains("`solver_iterations` must be 1 to 640, got 641"),
                "{e}"
            );
            let e = err(name, "prediction_distance = 0.0");
            assert!(
                e.contains("`prediction_distance` must be above 0 and at most 1 m, got 0"),
                "{e}"
            );
            let e = err(name, "limit_frequency = 2e6");
            assert!(
                e.contains("`limit_frequency` must be above 0 and at most 1000000 Hz"),
                "{e}"
            );
            // Soft limits' explicit damping needs 4π·frequency·step ≤ 1: 500 Hz is too stiff
            // for every robot's own step, and the message says what to set.
            let e = err(name, "limit_frequency = 500");
            assert!(
                e.contains("`limit_frequency` 500 Hz is too stiff")
                    && e.contains("set `substeps` to at least")
                    && e.contains("or `implicit_limits` to true"),
                "{e}"
            );
            // Implicit springs are stable at any step.
            assert!(make_with(
                name,
                &table("limit_frequency = 500\nimplicit_limits = true")
            )
            .is_ok());
            // Rapier's relax iterations per pass: 0 is allowed (none), 17 is not.
            assert!(make_with(name, &table("stabilization_iterations = 0")).is_ok());
            let e = err(name, "stabilization_iterations = 17");
            // Rapier's 1 everywhere but the walker, which ships none (issue 32).
            let default = if name == "walker2d" { 0 } else { 1 };
            assert!(
                e.contains(&format!(
                    "`stabilization_iterations` must be 0 to 16, got 17 (the default is {default})"
                )),
                "{e}"
            );
            // Rapier's Gauss–Seidel iterations per pass: at least 1, at most 64.
            assert!(make_with(name, &table("pgs_iterations = 64")).is_ok());
            for bad in [0, 65] {
                let e = err(name, &format!("pgs_iterations = {bad}"));
                assert!(
                    e.contains(&format!(
                        "`pgs_iterations` must be 1 to 64, got {bad} (the default is 1)"
                    )),
                    "{e}"
                );
            }
            // Contact softness: unset keeps rapier's own; out of range is refused by name.
            assert!(make_with(
                name,
                &table("contact_frequency = 8\ncontact_damping_ratio = 1")
            )
            .is_ok());
            let e = err(name, "contact_frequency = 0");
            assert!(
                e.contains(
                    "`contact_frequency` must be above 0 and at most 1000, got 0 (unset keeps \
                     rapier's own)"
                ),
                "{e}"
            );
            let e = err(name, "contact_damping_ratio = 101");
            assert!(
                e.contains("`contact_damping_ratio` must be above 0 and at most 100, got 101"),
                "{e}"
            );
            // A wrong type names its key (toml's own message does not).
            let e = err(name, "substeps = 4\nimplicit_limits = 1");
            assert!(
                e.ends_with("invalid type: integer `1`, expected a boolean in `implicit_limits`"),
                "{e}"
            );
            assert!(make_with(
                name,
                &table(
                    "substeps = 30\nsolver_iterations = 2\nprediction_distance = 0.01\n\
                     limit_frequency = 16"
                )
            )
            .is_ok());
        }
        // ... and applied: the cheetah's own setting spelled out repeats its default episode;
        // another setting gives another one.
        let episode = |opts: &str| {
            let mut env = make_with("halfcheetah", &table(opts)).unwrap();
            env.reset(Some(0));
            (0..20).map(|_| env.step(&[0.5; 6]).obs).collect::<Vec<_>>()
        };
        let default = episode("");
        let (sub, it) = (
            halfcheetah::SIM.substeps,
            halfcheetah::SIM.solver_iterations,
        );
        assert_eq!(
            default,
            episode(&format!("substeps = {sub}\nsolver_iterations = {it}"))
        );
        assert_ne!(default, episode(&format!("substeps = {}", sub + 3)));
        // The prediction distance matters when a foot comes down fast: the sine gait's first
        // 100 steps.
        let gait = |opts: &str| {
            let mut env = make_with("halfcheetah", &table(opts)).unwrap();
            env.reset(Some(0));
            (0..100)
                .map(|t| env.step(&gaits::halfcheetah(t)).obs)
                .collect::<Vec<_>>()
        };
        let default = gait("");
        let shipped = halfcheetah::SIM.prediction_distance;
        assert_eq!(default, gait(&format!("prediction_distance = {shipped}")));
        assert_ne!(default, gait("prediction_distance = 0.005"));
        // The joint limits' frequency matters once a hinge reaches its limit.
        let limit = halfcheetah::SIM.limit_frequency;
        assert_eq!(default, gait(&format!("limit_frequency = {limit}")));
        // (7 Hz: the stiffest springs the cheetah's 10 ms steps allow are 8 Hz.)
        assert_ne!(default, gait("limit_frequency = 7"));
        // Rapier's relax iterations act once the feet touch the floor.
        assert_eq!(default, gait("stabilization_iterations = 1"));
        assert_ne!(default, gait("stabilization_iterations = 0"));
        // So do rapier's Gauss–Seidel iterations per pass.
        assert_eq!(default, gait("pgs_iterations = 1"));
        assert_ne!(default, gait("pgs_iterations = 4"));
        // Contact softness, frequency and damping ratio each, once the feet touch the floor.
        assert_ne!(default, gait("contact_frequency = 8"));
        assert_ne!(default, gait("contact_damping_ratio = 1"));
        // fpc-assembly's tolerances are options: read, and checked by the env.
        let e = err("fpc-assembly", "lateral_tol_mm = -0.1");
        assert!(
            e.contains("fpc-assembly") && e.contains("lateral_tol_mm"),
            "{e}"
        );
        let e = err("fpc-assembly", "slot_widht_mm = 8.1");
        assert!(e.contains("slot_widht_mm"), "{e}");
        assert!(make_with("fpc-assembly", &table("lateral_tol_mm = 0.2")).is_ok());
        assert_eq!(
            variant_fingerprint(&table("a = 1\nb = 2"), None),
            variant_fingerprint(&table("b = 2\na = 1"), None)
        );
        assert_ne!(
            variant_fingerprint(&table("g = 10.0"), None),
            variant_fingerprint(&EnvOptions::new(), None)
        );
        // The same options on another build's physics defaults are another variant.
        let hopper = make("hopper").unwrap().physics();
        let other = hopper.map(|p| physics::SimParams {
            substeps: p.substeps + 1,
            ..p
        });
        let none = EnvOptions::new();
        assert_eq!(
            variant_fingerprint(&none, hopper),
            variant_fingerprint(&none, make("hopper").unwrap().physics())
        );
        assert_ne!(
            variant_fingerprint(&none, hopper),
            variant_fingerprint(&none, other)
        );
        assert_ne!(
            variant_fingerprint(&none, hopper),
            variant_fingerprint(&none, None)
        );
    }
}
