//! The native half of the `selkd` Python package (`selkd._native`): one env ([`Env`]) and n envs
//! stepped together on threads ([`VecEnv`]), straight over the Rust registry, plus drawing a
//! frame with the ray caster. The Gymnasium classes in `selkd/envs.py` wrap these; nothing here
//! knows Gymnasium.
//!
//! Every user mistake (an unknown env, a bad option, an action of the wrong shape or with a NaN)
//! is a `selkd.SelkdError` (a `ValueError`) with a one-line message, never a panic.

use numpy::ndarray::{Array2, Array3};
use numpy::{
    PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use selkd_envs::scene::Scene;
use selkd_envs::{EnvOptions, EnvSpec};
use std::sync::Mutex;

pyo3::create_exception!(
    _native,
    SelkdError,
    PyValueError,
    "A mistake in what was asked of selkd: an unknown env or option, a bad action, a bad bundle."
);

fn error(message: impl std::fmt::Display) -> PyErr {
    SelkdError::new_err(message.to_string())
}

/// The registry's env names, in order.
#[pyfunction]
fn names() -> Vec<&'static str> {
    selkd_envs::names()
}

/// An env's options from their JSON text (what Python's keyword arguments become): a TOML
/// table, as a run config's `[env_options]`.
fn options_from_json(name: &str, json: &str) -> PyResult<EnvOptions> {
    let value: serde_json::Value =
        serde_json::from_str(json).map_err(|e| error(format!("options for `{name}`: {e}")))?;
    match json_to_toml(&value) {
        Some(toml::Value::Table(t)) => Ok(t),
        _ => Err(error(format!(
            "options for `{name}` must be keyword arguments with numbers, strings, booleans or lists as values, got {json}"
        ))),
    }
}

fn json_to_toml(v: &serde_json::Value) -> Option<toml::Value> {
    use serde_json::Value as J;
    Some(match v {
        J::Bool(b) => toml::Value::Boolean(*b),
        J::Number(n) => match n.as_i64() {
            Some(i) => toml::Value::Integer(i),
            None => toml::Value::Float(n.as_f64()?),
        },
        J::String(s) => toml::Value::String(s.clone()),
        J::Array(a) => toml::Value::Array(a.iter().map(json_to_toml).collect::<Option<_>>()?),
        J::Object(o) => toml::Value::Table(
            o.iter()
                .map(|(k, v)| Some((k.clone(), json_to_toml(v)?)))
                .collect::<Option<_>>()?,
        ),
        J::Null => return None,
    })
}

fn make(name: &str, options_json: &str) -> PyResult<Box<dyn selkd_envs::Env>> {
    let options = options_from_json(name, options_json)?;
    selkd_envs::make_with(name, &options).map_err(error)
}

/// Checks one action: its length and that it holds no NaN (the env clips everything else).
/// `shape` describes the action for the error only, so a valid step allocates nothing.
fn check_action(spec: &EnvSpec, action: &[f32], shape: impl FnOnce() -> String) -> PyResult<()> {
    if action.len() != spec.act_dim {
        return Err(error(format!(
            "{}: the action has shape {}, expected ({},)",
            spec.id,
            shape(),
            spec.act_dim
        )));
    }
    if let Some(i) = action.iter().position(|a| a.is_nan()) {
        return Err(error(format!(
            "{}: the action's entry {i} is NaN; actions are in [-1, 1]",
            spec.id
        )));
    }
    Ok(())
}

/// An env's description, read-only from Python.
#[pyclass(module = "selkd._native", frozen, get_all)]
#[derive(Clone)]
struct Spec {
    /// Registry name.
    id: &'static str,
    obs_dim: usize,
    act_dim: usize,
    /// The step at which the env truncates an episode.
    max_episode_steps: usize,
    /// Gymnasium's own version of the task takes this times our action.
    gymnasium_action_scale: f32,
    /// Simulated seconds per step.
    control_dt: Option<f64>,
}

impl Spec {
    fn of(spec: &EnvSpec, control_dt: Option<f64>) -> Self {
        Self {
            id: spec.id,
            obs_dim: spec.obs_dim,
            act_dim: spec.act_dim,
            max_episode_steps: spec.max_episode_steps,
            gymnasium_action_scale: spec.gymnasium_action_scale,
            control_dt,
        }
    }
}

/// One env. Not thread-safe by itself in Rust terms (`Box<dyn Env>` is only `Send`), so it sits
/// behind a mutex; Python's GIL is released while the physics steps.
#[pyclass(module = "selkd._native")]
struct Env {
    inner: Mutex<EnvState>,
    spec: EnvSpec,
    control_dt: Option<f64>,
}

struct EnvState {
    env: Box<dyn selkd_envs::Env>,
    /// The episode's first scene, which fixes the camera of `render`; kept only when asked.
    first_scene: Option<Scene>,
    keep_scene: bool,
}

#[pymethods]
impl Env {
    /// `Env(name, options_json, render)`: `render` keeps what `render()` needs at every reset.
    #[new]
    #[pyo3(signature = (name, options_json = "{}", render = false))]
    fn new(name: &str, options_json: &str, render: bool) -> PyResult<Self> {
        let env = make(name, options_json)?;
        let spec = env.spec().clone();
        let control_dt = env.control_dt();
        Ok(Self {
            inner: Mutex::new(EnvState {
                env,
                first_scene: None,
                keep_scene: render,
            }),
            spec,
            control_dt,
        })
    }

    /// What the env is: sizes, time limit, action scale of Gymnasium's counterpart, step length.
    #[getter]
    fn spec(&self) -> Spec {
        Spec::of(&self.spec, self.control_dt)
    }

    /// Starts an episode: `seed` reseeds the env, `None` continues its generator.
    #[pyo3(signature = (seed = None))]
    fn reset<'py>(&self, py: Python<'py>, seed: Option<u64>) -> Bound<'py, PyArray1<f32>> {
        let obs = py.detach(|| {
            let mut s = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            let obs = s.env.reset(seed);
            s.first_scene = if s.keep_scene { s.env.scene() } else { None };
            obs
        });
        PyArray1::from_vec(py, obs)
    }

    /// One step with `action` (float32, shape `(act_dim,)`): `(obs, reward, terminated,
    /// truncated, success)`, `success` `None` for tasks without one and before an episode's end.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        action: PyReadonlyArray1<'py, f32>,
    ) -> PyResult<(Bound<'py, PyArray1<f32>>, f64, bool, bool, Option<bool>)> {
        let a = action.as_slice().map_err(error)?;
        check_action(&self.spec, a, || format!("{:?}", action.shape()))?;
        let s = py.detach(|| {
            let mut s = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            s.env.step(a)
        });
        Ok((
            PyArray1::from_vec(py, s.obs),
            s.reward,
            s.terminated,
            s.truncated,
            s.success,
        ))
    }

    /// The world now as `height × width × 3` RGB bytes, through the ray caster, the camera
    /// framed by the episode's first scene.
    fn render<'py>(
        &self,
        py: Python<'py>,
        width: usize,
        height: usize,
    ) -> PyResult<Bound<'py, PyArray3<u8>>> {
        if width == 0 || height == 0 || width > 4096 || height > 4096 {
            return Err(error(format!(
                "render size {width}x{height}: width and height must be 1 to 4096"
            )));
        }
        let id = self.spec.id;
        let pixels = py.detach(|| {
            let s = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            let now = s.env.scene()?;
            let first = s.first_scene.as_ref().unwrap_or(&now);
            let cam = selkd_render::Camera::following(first, &now);
            Some(selkd_render::render(&now, &cam, width, height))
        });
        let pixels = pixels.ok_or_else(|| error(format!("{id} cannot be drawn")))?;
        let pixels = Array3::from_shape_vec((height, width, 3), pixels).map_err(error)?;
        Ok(PyArray3::from_owned_array(py, pixels))
    }
}

/// `n` envs of one kind stepped together, split over a pool of threads, without a Python call
/// per env. An env whose episode ended is reset by the next `step` (Gymnasium's next-step
/// autoreset): that step ignores its action and returns the new episode's first observation
/// with reward 0 and neither flag set.
#[pyclass(module = "selkd._native")]
struct VecEnv {
    inner: Mutex<VecState>,
    spec: EnvSpec,
    control_dt: Option<f64>,
    n: usize,
}

struct VecState {
    envs: Vec<Box<dyn selkd_envs::Env>>,
    ended: Vec<bool>,
    pool: rayon::ThreadPool,
}

/// What one env of a [`VecEnv`] returns from a step.
struct Outcome {
    obs: Vec<f32>,
    reward: f64,
    terminated: bool,
    truncated: bool,
    /// -1: no success flag this step; 0 or 1: the task's success.
    success: i8,
}

#[pymethods]
impl VecEnv {
    /// `VecEnv(name, n, options_json, threads)`; `threads = 0`: one per core, at most `n`.
    #[new]
    #[pyo3(signature = (name, n, options_json = "{}", threads = 0))]
    fn new(name: &str, n: usize, options_json: &str, threads: usize) -> PyResult<Self> {
        if n == 0 {
            return Err(error("num_envs must be at least 1"));
        }
        let envs = (0..n)
            .map(|_| make(name, options_json))
            .collect::<PyResult<Vec<_>>>()?;
        let spec = envs[0].spec().clone();
        let control_dt = envs[0].control_dt();
        let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
        let threads = if threads == 0 { cores } else { threads }.min(n);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("selkd-vec-{i}"))
            .build()
            .map_err(error)?;
        Ok(Self {
            inner: Mutex::new(VecState {
                envs,
                ended: vec![false; n],
                pool,
            }),
            spec,
            control_dt,
            n,
        })
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.n
    }
    /// What each env is (as `Env.spec`).
    #[getter]
    fn spec(&self) -> Spec {
        Spec::of(&self.spec, self.control_dt)
    }
    #[getter]
    fn threads(&self) -> usize {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .pool
            .current_num_threads()
    }

    /// Resets every env: env i with `seeds[i]` (`None`: continue its generator).
    fn reset<'py>(
        &self,
        py: Python<'py>,
        seeds: Vec<Option<u64>>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        if seeds.len() != self.n {
            return Err(error(format!(
                "reset: {} seeds for {} envs",
                seeds.len(),
                self.n
            )));
        }
        let obs = py.detach(|| {
            use rayon::prelude::*;
            let mut s = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            let VecState { envs, ended, pool } = &mut *s;
            ended.iter_mut().for_each(|e| *e = false);
            pool.install(|| {
                envs.par_iter_mut()
                    .zip(seeds)
                    .flat_map_iter(|(env, seed)| env.reset(seed))
                    .collect::<Vec<f32>>()
            })
        });
        let obs = Array2::from_shape_vec((self.n, self.spec.obs_dim), obs).map_err(error)?;
        Ok(PyArray2::from_owned_array(py, obs))
    }

    /// One step of every env with `actions` (float32, `(n, act_dim)`): observations `(n,
    /// obs_dim)`, rewards, terminated and truncated flags, and success (`-1` where there is
    /// none), each of length n.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        actions: PyReadonlyArray2<'py, f32>,
    ) -> PyResult<(
        Bound<'py, PyArray2<f32>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<bool>>,
        Bound<'py, PyArray1<bool>>,
        Bound<'py, PyArray1<i8>>,
    )> {
        let shape = actions.shape().to_vec();
        if shape != [self.n, self.spec.act_dim] {
            return Err(error(format!(
                "{}: the actions have shape {shape:?}, expected ({}, {}) (num_envs, action size)",
                self.spec.id, self.n, self.spec.act_dim
            )));
        }
        let a = actions.as_slice().map_err(error)?;
        for row in a.chunks_exact(self.spec.act_dim) {
            check_action(&self.spec, row, || format!("({},)", row.len()))?;
        }
        let outcomes = py.detach(|| {
            use rayon::prelude::*;
            let mut s = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            let VecState { envs, ended, pool } = &mut *s;
            pool.install(|| {
                envs.par_iter_mut()
                    .zip(ended.par_iter_mut())
                    .zip(a.par_chunks_exact(self.spec.act_dim))
                    .map(|((env, ended), action)| {
                        if *ended {
                            *ended = false;
                            return Outcome {
                                obs: env.reset(None),
                                reward: 0.0,
                                terminated: false,
                                truncated: false,
                                success: -1,
                            };
                        }
                        let s = env.step(action);
                        *ended = s.terminated || s.truncated;
                        Outcome {
                            obs: s.obs,
                            reward: s.reward,
                            terminated: s.terminated,
                            truncated: s.truncated,
                            success: s.success.map_or(-1, i8::from),
                        }
                    })
                    .collect::<Vec<_>>()
            })
        });
        let obs: Vec<f32> = outcomes
            .iter()
            .flat_map(|o| o.obs.iter().copied())
            .collect();
        let obs = Array2::from_shape_vec((self.n, self.spec.obs_dim), obs).map_err(error)?;
        Ok((
            PyArray2::from_owned_array(py, obs),
            PyArray1::from_vec(py, outcomes.iter().map(|o| o.reward).collect()),
            PyArray1::from_vec(py, outcomes.iter().map(|o| o.terminated).collect()),
            PyArray1::from_vec(py, outcomes.iter().map(|o| o.truncated).collect()),
            PyArray1::from_vec(py, outcomes.iter().map(|o| o.success).collect()),
        ))
    }
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SelkdError", m.py().get_type::<SelkdError>())?;
    m.add_function(wrap_pyfunction!(names, m)?)?;
    m.add_class::<Spec>()?;
    m.add_class::<Env>()?;
    m.add_class::<VecEnv>()?;
    Ok(())
}
