//! Gymnasium environments behind the envs crate's [`Env`] trait: `run.env = "gymnasium:<id>"`
//! (`gymnasium:Hopper-v5`, `gymnasium:Pendulum-v1`, or any id a package registers) is
//! `gymnasium.make(id, **env_options)`, stepped in a Python interpreter embedded in this process.
//!
//! Why embedded: a worker steps its env tens of thousands of times a second at most, and a
//! round trip to a Python child over a pipe costs about what a MuJoCo step does; in-process, a
//! step costs one Python call more than Gymnasium's own (measured in docs/performance.md).
//!
//! - Spaces: `Box` observations and actions (flattened), anything else is an error naming the
//!   space. The policy's actions in `[-1, 1]` map affinely onto the action Box's bounds, which
//!   must be finite.
//! - Episodes: `terminated` stops bootstrapping, `truncated` (Gymnasium's time limit) does not;
//!   `reset(Some(seed))` is `env.reset(seed=seed)`, so a deterministic env (MuJoCo is) replays an
//!   episode exactly from its seed and actions.
//! - Options: `[env_options]` are `gymnasium.make`'s keywords, except `import = ["pkg", ...]`,
//!   modules imported first (packages that register their own ids).
//! - Python: the interpreter this binary was linked with, with the project's venv
//!   (`deploy/python.sh`: `SELKD_PYTHON_VENV`, else `python-venv` in the per-user cache) added to
//!   its path.
//! - Failures: an exception in `reset` or `step` ends the episode (terminated, zero observation)
//!   and [`Env::failure`] says why; non-finite observations or rewards end the episode the same
//!   way, as our own envs do.

use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};
use selkd_envs::{Env, EnvError, EnvOptions, EnvSpec, Picture, Step};
use std::ffi::CString;
use std::path::PathBuf;
use std::sync::Mutex;

/// The name prefix of Gymnasium envs.
pub const PREFIX: &str = "gymnasium:";

/// A Box space as the glue reads it: low, high (flattened), shape, dtype.
type BoxSpace = (Vec<f64>, Vec<f64>, Vec<usize>, String);

/// The `env_options` key that lists modules to import before `gymnasium.make`.
pub const IMPORT_KEY: &str = "import";

/// Lets this process's envs registry make `gymnasium:` envs.
pub fn register() {
    selkd_envs::register_family(PREFIX, make);
}

/// What runs on the Python side: one call per reset or step, with the observation flattened to
/// float32 bytes and the action passed as float64 bytes, so that no per-element objects are made.
const GLUE: &str = r#"
import numpy as _np

def _flat(o):
    return _np.asarray(o, dtype=_np.float32).ravel().tobytes()

def reset(env, seed):
    o, _ = env.reset(seed=seed) if seed is not None else env.reset()
    return _flat(o)

def step(env, action, dtype, shape):
    a = _np.frombuffer(action, dtype=_np.float64).astype(dtype).reshape(shape)
    o, r, terminated, truncated, _ = env.step(a)
    return _flat(o), float(r), bool(terminated), bool(truncated)

def frame(env):
    f = env.render()
    if f is None:
        return None
    a = _np.asarray(f)
    if a.dtype != _np.uint8 or a.ndim != 3 or a.shape[2] not in (3, 4):
        raise ValueError(f"render() gave a {a.dtype} array of shape {a.shape}, not uint8 (height, width, 3)")
    return a.shape[1], a.shape[0], _np.ascontiguousarray(a[:, :, :3]).tobytes()

def box(space):
    from gymnasium.spaces import Box
    if not isinstance(space, Box):
        return None
    low = _np.asarray(space.low, dtype=_np.float64).ravel()
    high = _np.asarray(space.high, dtype=_np.float64).ravel()
    return low.tolist(), high.tolist(), tuple(space.shape), str(space.dtype)
"#;

/// Ids as `&'static str` for [`EnvSpec::id`]: one leaked copy per distinct id, ever.
fn intern(id: &str) -> &'static str {
    static IDS: Mutex<Vec<&'static str>> = Mutex::new(Vec::new());
    let mut ids = IDS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(s) = ids.iter().find(|s| **s == id) {
        return s;
    }
    let s: &'static str = Box::leak(id.to_string().into_boxed_str());
    ids.push(s);
    s
}

/// The venv `deploy/python.sh` makes, found as it finds it.
pub fn venv() -> PathBuf {
    if let Some(v) = std::env::var_os("SELKD_PYTHON_VENV") {
        return PathBuf::from(v);
    }
    let cache = std::env::var_os("SELKD_CACHE")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("XDG_CACHE_HOME").map(|c| PathBuf::from(c).join("selkd")))
        .unwrap_or_else(|| {
            PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/selkd")
        });
    cache.join("python-venv")
}

/// An exception as one line: its type and message, newlines folded.
fn one_line(py: Python<'_>, e: &PyErr) -> String {
    let kind = e
        .get_type(py)
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "Exception".into());
    let msg = e.value(py).to_string();
    let msg = msg.split_whitespace().collect::<Vec<_>>().join(" ");
    format!("{kind}: {msg}")
}

/// The glue module, made once per process (adding the venv to the path first). A PyO3 once-cell,
/// not a mutex: Python may let another thread run in the middle of an import, and a thread that
/// then waited on a mutex while holding the interpreter would deadlock with the importer.
fn glue(py: Python<'_>) -> PyResult<Py<PyModule>> {
    static GLUE_MODULE: pyo3::sync::PyOnceLock<Py<PyModule>> = pyo3::sync::PyOnceLock::new();
    GLUE_MODULE
        .get_or_try_init(py, || -> PyResult<Py<PyModule>> {
            let sys = py.import("sys")?;
            let info = sys.getattr("version_info")?;
            let (major, minor): (u8, u8) =
                (info.get_item(0)?.extract()?, info.get_item(1)?.extract()?);
            let site = venv()
                .join("lib")
                .join(format!("python{major}.{minor}"))
                .join("site-packages");
            if site.is_dir() {
                py.import("site")?
                    .call_method1("addsitedir", (site.to_string_lossy().as_ref(),))?;
            }
            let code = CString::new(GLUE).expect("no NUL in the glue");
            let m = PyModule::from_code(
                py,
                &code,
                c"selkd_gymnasium_glue.py",
                c"selkd_gymnasium_glue",
            )?;
            Ok(m.unbind())
        })
        .map(|m| m.clone_ref(py))
}

/// Gymnasium's "run `pip install …`", with where: the extra must go into our venv.
fn into_venv(message: String) -> String {
    if !message.contains("pip install") {
        return message;
    }
    let v = venv();
    format!("{message} (into {}: {}/bin/pip)", v.display(), v.display())
}

fn options_error(name: &str, message: String) -> EnvError {
    EnvError::Options {
        env: name.to_string(),
        message,
    }
}

/// `gymnasium.make(id, **options)`, checked: Box spaces with finite action bounds, a time limit.
pub fn make(name: &str, options: &EnvOptions) -> Result<Box<dyn Env>, EnvError> {
    make_gym(name, options).map(|e| Box::new(e) as Box<dyn Env>)
}

fn make_gym(name: &str, options: &EnvOptions) -> Result<GymEnv, EnvError> {
    let id = name.strip_prefix(PREFIX).unwrap_or(name);
    let mut kwargs = options.clone();
    let imports: Vec<String> = match kwargs.remove(IMPORT_KEY) {
        None => vec![],
        Some(toml::Value::Array(a)) => a
            .iter()
            .map(|v| v.as_str().map(str::to_string))
            .collect::<Option<_>>()
            .ok_or_else(|| {
                options_error(
                    name,
                    format!("`{IMPORT_KEY}` must be a list of module names"),
                )
            })?,
        Some(_) => {
            return Err(options_error(
                name,
                format!("`{IMPORT_KEY}` must be a list of module names, e.g. [\"ale_py\"]"),
            ))
        }
    };
    let kwargs_json = serde_json::to_string(&kwargs)
        .map_err(|e| options_error(name, format!("options as make() keywords: {e}")))?;
    Python::attach(|py| -> Result<GymEnv, EnvError> {
        let py_err = |e: PyErr| options_error(name, one_line(py, &e));
        let glue = glue(py).map_err(py_err)?;
        let gym = py.import("gymnasium").map_err(|e| {
            options_error(
                name,
                format!(
                    "Gymnasium is not installed for this Python ({}); run `bash deploy/python.sh`, which installs it into {}, or set SELKD_PYTHON_VENV to a venv that has it",
                    one_line(py, &e),
                    venv().display()
                ),
            )
        })?;
        for module in &imports {
            py.import(module.as_str()).map_err(|e| {
                options_error(
                    name,
                    format!(
                        "importing `{module}` ({}): install it into {} ({}/bin/pip install …)",
                        one_line(py, &e),
                        venv().display(),
                        venv().display()
                    ),
                )
            })?;
        }
        let kw = py
            .import("json")
            .and_then(|j| j.call_method1("loads", (kwargs_json.as_str(),)))
            .and_then(|d| d.cast_into::<PyDict>().map_err(Into::into))
            .map_err(py_err)?;
        let env = gym
            .call_method("make", (id,), Some(&kw))
            .map_err(|e| options_error(name, into_venv(one_line(py, &e))))?;
        let space = |attr: &str| -> Result<BoxSpace, EnvError> {
            let s = env.getattr(attr).map_err(py_err)?;
            let b = glue.bind(py).call_method1("box", (&s,)).map_err(py_err)?;
            if b.is_none() {
                return Err(options_error(
                    name,
                    format!(
                        "its {attr} is {}; only Box spaces are supported",
                        s.repr().map(|r| r.to_string()).unwrap_or_default()
                    ),
                ));
            }
            b.extract().map_err(py_err)
        };
        let (_, _, obs_shape, _) = space("observation_space")?;
        let (low, high, act_shape, act_dtype) = space("action_space")?;
        if let Some(i) = (0..low.len()).find(|&i| !low[i].is_finite() || !high[i].is_finite()) {
            return Err(options_error(
                name,
                format!(
                    "its action space has an infinite bound ([{}, {}] at index {i}); actions in [-1, 1] can only be mapped onto finite bounds",
                    low[i], high[i]
                ),
            ));
        }
        let limit: Option<usize> = env
            .getattr("spec")
            .and_then(|s| s.getattr("max_episode_steps"))
            .and_then(|m| m.extract())
            .map_err(py_err)?;
        let Some(max_episode_steps) = limit else {
            return Err(options_error(
                name,
                "it has no time limit; set env_options.max_episode_steps".into(),
            ));
        };
        let symmetric = low.iter().zip(&high).all(|(l, h)| (l + h).abs() < 1e-9);
        let spec = EnvSpec {
            id: intern(name),
            obs_dim: obs_shape.iter().product(),
            act_dim: act_shape.iter().product(),
            max_episode_steps,
            // One number maps [-1, 1] onto the Box only when it is ±c in every dimension.
            gymnasium_action_scale: if symmetric
                && !high.is_empty()
                && high
                    .iter()
                    .all(|h| (h - high[0]).abs() <= 1e-9 * h.abs().max(1.0))
            {
                high[0] as f32
            } else {
                f32::NAN
            },
        };
        // Simulated seconds per step (MuJoCo's and the classic envs' `dt`), for frame timing.
        let dt: Option<f64> = env
            .getattr("unwrapped")
            .and_then(|u| u.getattr("dt"))
            .and_then(|d| d.extract())
            .ok();
        Ok(GymEnv {
            env: env.unbind(),
            glue,
            spec,
            low,
            high,
            act_shape,
            act_dtype,
            dt,
            drawing: false,
            failure: None,
        })
    })
}

/// `gymnasium:<id>` made to draw itself for `selkd render`: `render_mode="rgb_array"`, with
/// `width` and `height` where the env takes them (MuJoCo's do; others draw at their own size),
/// unless `options` set them. Without a display, MuJoCo is pointed at EGL (`MUJOCO_GL=egl`,
/// unless set), as its default, GLFW, needs one.
pub fn make_drawing(
    name: &str,
    options: &EnvOptions,
    width: usize,
    height: usize,
) -> Result<Box<dyn Env>, EnvError> {
    let headless = ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .all(|v| std::env::var_os(v).is_none_or(|d| d.is_empty()));
    Python::attach(|py| -> PyResult<()> {
        if headless {
            py.import("os")?
                .getattr("environ")?
                .call_method1("setdefault", ("MUJOCO_GL", "egl"))?;
        }
        Ok(())
    })
    .map_err(|e| options_error(name, Python::attach(|py| one_line(py, &e))))?;
    let mut drawn = options.clone();
    drawn.insert("render_mode".into(), "rgb_array".into());
    let mut sized = drawn.clone();
    for (key, value) in [("width", width), ("height", height)] {
        sized
            .entry(key)
            .or_insert(toml::Value::Integer(value as i64));
    }
    let made = match make_gym(name, &sized) {
        Err(EnvError::Options { message, .. })
            if sized != drawn
                && !options.contains_key("width")
                && !options.contains_key("height")
                && (message.contains("keyword argument 'width'")
                    || message.contains("keyword argument 'height'")) =>
        {
            make_gym(name, &drawn)
        }
        other => other,
    };
    let mut env = made.map_err(|e| match e {
        EnvError::Options { message, .. } if message.contains("keyword argument 'render_mode'") => {
            EnvError::Failed(format!(
                "{name} cannot be drawn: its constructor takes no render_mode (selkd render needs render_mode=\"rgb_array\")"
            ))
        }
        e => e,
    })?;
    let (mode, modes): (Option<String>, Vec<String>) = Python::attach(|py| {
        let e = env.env.bind(py);
        let mode = e
            .getattr("render_mode")
            .and_then(|m| m.extract())
            .ok()
            .flatten();
        let modes = e
            .getattr("metadata")
            .and_then(|m| m.get_item("render_modes"))
            .and_then(|m| m.extract())
            .unwrap_or_default();
        (mode, modes)
    });
    if mode.as_deref() != Some("rgb_array") || !modes.iter().any(|m| m == "rgb_array") {
        return Err(EnvError::Failed(format!(
            "{name} cannot be drawn: its render modes are {modes:?}, without rgb_array (selkd render needs render_mode=\"rgb_array\")"
        )));
    }
    env.drawing = true;
    Ok(Box::new(env))
}

/// A failed `render()`, with what to install when the cause is OpenGL (MuJoCo draws with it, and
/// a machine without a display needs EGL or OSMesa).
fn render_error(id: &str, e: String) -> String {
    let lower = e.to_lowercase();
    let gl = [
        "opengl",
        "egl",
        "glfw",
        "osmesa",
        "glgeterror",
        "mjr_makecontext",
    ]
    .iter()
    .any(|w| lower.contains(w));
    if !gl {
        return format!("{id}: render() raised {}", into_venv(e));
    }
    let now = std::env::var("MUJOCO_GL").unwrap_or_else(|_| "unset".into());
    format!(
        "{id}: render() found no working OpenGL (MUJOCO_GL={now}; {e}): without a display, install EGL (apt-get install libegl1, with Mesa or a GPU driver) and set MUJOCO_GL=egl, or OSMesa (apt-get install libosmesa6) and set MUJOCO_GL=osmesa"
    )
}

/// One `gymnasium.make` env.
pub struct GymEnv {
    env: Py<PyAny>,
    glue: Py<PyModule>,
    spec: EnvSpec,
    low: Vec<f64>,
    high: Vec<f64>,
    act_shape: Vec<usize>,
    act_dtype: String,
    dt: Option<f64>,
    /// Made by [`make_drawing`], with `render_mode="rgb_array"`.
    drawing: bool,
    failure: Option<String>,
}

impl GymEnv {
    fn obs(&self, bytes: &[u8]) -> Result<Vec<f32>, String> {
        if bytes.len() != 4 * self.spec.obs_dim {
            return Err(format!(
                "{} returned an observation of {} values, not the {} of its observation space",
                self.spec.id,
                bytes.len() / 4,
                self.spec.obs_dim
            ));
        }
        Ok(bytes
            .chunks_exact(4)
            .map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    fn fail(&mut self, what: &str, e: String) -> Step {
        self.failure = Some(format!("{}: {what}: {e}", self.spec.id));
        Step::non_finite_state(self.spec.obs_dim, 0.0, false)
    }
}

impl Env for GymEnv {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: Option<u64>) -> Vec<f32> {
        let got = Python::attach(|py| -> Result<Vec<f32>, String> {
            let out = self
                .glue
                .bind(py)
                .call_method1("reset", (self.env.bind(py), seed))
                .map_err(|e| one_line(py, &e))?;
            let bytes = out.cast::<PyBytes>().map_err(|e| e.to_string())?;
            self.obs(bytes.as_bytes())
        });
        match got {
            Ok(obs) if obs.iter().all(|x| x.is_finite()) => obs,
            Ok(_) => vec![0.0; self.spec.obs_dim],
            Err(e) => {
                self.fail("reset raised", e);
                vec![0.0; self.spec.obs_dim]
            }
        }
    }

    fn step(&mut self, action: &[f32]) -> Step {
        if self.failure.is_some() {
            return Step::non_finite_state(self.spec.obs_dim, 0.0, false);
        }
        let mut bytes = Vec::with_capacity(8 * action.len());
        for ((a, l), h) in action.iter().zip(&self.low).zip(&self.high) {
            let a = (*a as f64).clamp(-1.0, 1.0);
            bytes.extend_from_slice(&(l + (a + 1.0) * 0.5 * (h - l)).to_ne_bytes());
        }
        let got = Python::attach(|py| -> Result<(Vec<f32>, f64, bool, bool), String> {
            let out = self
                .glue
                .bind(py)
                .call_method1(
                    "step",
                    (
                        self.env.bind(py),
                        PyBytes::new(py, &bytes),
                        self.act_dtype.as_str(),
                        PyTuple::new(py, &self.act_shape).map_err(|e| one_line(py, &e))?,
                    ),
                )
                .map_err(|e| one_line(py, &e))?;
            let (obs, reward, terminated, truncated): (Bound<'_, PyBytes>, f64, bool, bool) =
                out.extract().map_err(|e: PyErr| one_line(py, &e))?;
            Ok((self.obs(obs.as_bytes())?, reward, terminated, truncated))
        });
        match got {
            Ok((obs, reward, terminated, truncated)) => {
                if obs.iter().all(|x| x.is_finite()) && reward.is_finite() {
                    Step {
                        obs,
                        reward,
                        terminated,
                        truncated,
                        success: None,
                    }
                } else {
                    // As our envs do: the episode ends here, terminated, with nothing non-finite.
                    let reward = if reward.is_finite() { reward } else { 0.0 };
                    Step::non_finite_state(self.spec.obs_dim, reward, truncated)
                }
            }
            Err(e) => self.fail("step raised", e),
        }
    }

    fn failure(&self) -> Option<String> {
        self.failure.clone()
    }

    fn control_dt(&self) -> Option<f64> {
        self.dt
    }

    fn picture(&self) -> Option<Result<Picture, String>> {
        if !self.drawing {
            return None;
        }
        let got = Python::attach(|py| -> Result<Option<Picture>, String> {
            let out = self
                .glue
                .bind(py)
                .call_method1("frame", (self.env.bind(py),))
                .map_err(|e| one_line(py, &e))?;
            if out.is_none() {
                return Ok(None);
            }
            let (width, height, rgb): (usize, usize, Bound<'_, PyBytes>) =
                out.extract().map_err(|e: PyErr| one_line(py, &e))?;
            Ok(Some(Picture {
                width,
                height,
                rgb: rgb.as_bytes().to_vec(),
            }))
        });
        match got {
            Ok(Some(p)) => Some(Ok(p)),
            Ok(None) => Some(Err(format!(
                "{}: render() gave None, not a picture (render_mode=\"rgb_array\")",
                self.spec.id
            ))),
            Err(e) => Some(Err(render_error(self.spec.id, e))),
        }
    }
}

impl Drop for GymEnv {
    fn drop(&mut self) {
        Python::attach(|py| {
            let _ = self.env.bind(py).call_method0("close");
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Makes `gymnasium:<id>` with the test module `tests/python/selkd_test_gym.py` importable.
    fn test_env(id: &str, options: &str) -> Result<Box<dyn Env>, EnvError> {
        test_env_drawn(id, options, None)
    }

    /// As [`test_env`], made to draw at `size` when one is given.
    fn test_env_drawn(
        id: &str,
        options: &str,
        size: Option<(usize, usize)>,
    ) -> Result<Box<dyn Env>, EnvError> {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python");
        Python::attach(|py| {
            let path = py.import("sys").unwrap().getattr("path").unwrap();
            if !path.contains(dir).unwrap() {
                path.call_method1("insert", (0, dir)).unwrap();
            }
        });
        let mut o: EnvOptions = toml::from_str(options).unwrap();
        o.insert(
            IMPORT_KEY.into(),
            toml::Value::Array(vec!["selkd_test_gym".into()]),
        );
        let name = format!("{PREFIX}{id}");
        match size {
            Some((w, h)) => make_drawing(&name, &o, w, h),
            None => make(&name, &o),
        }
    }

    #[test]
    fn an_env_made_to_draw_gives_its_pictures_at_the_size_asked_where_it_takes_one() {
        let mut env = test_env_drawn("SelkdEcho-v0", "", Some((40, 30))).unwrap();
        env.reset(Some(0));
        env.step(&[0.0, 1.0]);
        let p = env.picture().expect("it draws").unwrap();
        assert_eq!((p.width, p.height, p.rgb.len()), (40, 30, 40 * 30 * 3));
        // Red is the action's second value (1 after the map onto [0, 1]); green 10 a step.
        assert_eq!(&p.rgb[..3], &[255, 10, 0]);
        // An env that takes no width or height draws at its own size.
        let mut env = test_env_drawn("SelkdSquare-v0", "", Some((40, 30))).unwrap();
        env.reset(Some(0));
        let p = env.picture().unwrap().unwrap();
        assert_eq!((p.width, p.height), (8, 8));
        // Made to train, an env does not draw; one without rgb_array cannot be made to.
        assert!(test_env("SelkdEcho-v0", "").unwrap().picture().is_none());
        let e = test_env_drawn("SelkdBlind-v0", "", Some((40, 30)))
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains(r#"cannot be drawn: its render modes are ["human"], without rgb_array"#),
            "{e}"
        );
    }

    #[test]
    fn actions_map_affinely_onto_the_box_and_observations_are_flattened() {
        let mut env = test_env("SelkdEcho-v0", "").unwrap();
        let s = env.spec().clone();
        assert_eq!(
            (s.id, s.obs_dim, s.act_dim, s.max_episode_steps),
            ("gymnasium:SelkdEcho-v0", 4, 2, 50)
        );
        // [-2, 2] × [0, 1] is no ±c box: no single export scale; Pendulum-v1's ±2 is.
        assert!(s.gymnasium_action_scale.is_nan());
        let pendulum = test_env("Pendulum-v1", "").unwrap();
        assert_eq!(pendulum.spec().gymnasium_action_scale, 2.0);
        env.reset(Some(3));
        // [-1, 1] → [-2, 2] and [0, 1]; out of range is clipped first.
        for (a, want) in [
            ([-1.0f32, -1.0], [-2.0f32, 0.0]),
            ([1.0, 1.0], [2.0, 1.0]),
            ([0.0, 0.0], [0.0, 0.5]),
            ([0.5, -0.5], [1.0, 0.25]),
            ([7.0, -7.0], [2.0, 0.0]),
        ] {
            let st = env.step(&a);
            assert_eq!(
                st.obs,
                vec![want[0], want[1], want[0], want[1]],
                "action {a:?}"
            );
            let r = -(want[0] as f64).powi(2) - (want[1] as f64).powi(2);
            assert!((st.reward - r).abs() < 1e-6, "{} vs {r}", st.reward);
            assert!(!st.terminated && !st.truncated);
        }
        assert!(env.failure().is_none());
    }

    #[test]
    fn a_seed_replays_its_episode_and_the_time_limit_truncates() {
        let mut env = test_env("SelkdEcho-v0", "").unwrap();
        let (a, b, c) = (env.reset(Some(7)), env.reset(Some(7)), env.reset(Some(8)));
        assert_eq!(a, b);
        assert_ne!(a, c);
        let ends: Vec<(bool, bool)> = (0..50)
            .map(|_| {
                let s = env.step(&[0.0, 0.0]);
                (s.terminated, s.truncated)
            })
            .collect();
        assert!(ends[..49].iter().all(|e| *e == (false, false)));
        assert_eq!(
            ends[49],
            (false, true),
            "truncated, not terminated, at the limit"
        );
    }

    #[test]
    fn an_exception_ends_the_episode_and_says_why_and_nan_ends_it_quietly() {
        let mut env = test_env("SelkdEcho-v0", "boom_at = 3").unwrap();
        env.reset(Some(0));
        assert!(env.step(&[0.0, 0.0]).obs.iter().all(|x| x.is_finite()));
        env.step(&[0.0, 0.0]);
        let s = env.step(&[0.0, 0.0]);
        assert!(s.terminated && s.obs == vec![0.0; 4]);
        let why = env.failure().expect("a failure");
        assert!(
            why.contains("RuntimeError: boom at step 3") && !why.contains('\n'),
            "{why}"
        );
        let mut env = test_env("SelkdEcho-v0", "nan_every = 2").unwrap();
        env.reset(Some(0));
        assert!(!env.step(&[0.0, 0.0]).terminated);
        let s = env.step(&[0.0, 0.0]);
        assert!(s.terminated && s.obs.iter().all(|x| *x == 0.0));
        assert!(
            env.failure().is_none(),
            "a NaN is the env's state, not a failure"
        );
    }

    #[test]
    fn bad_ids_spaces_keywords_and_imports_are_one_line_errors() {
        let err = |id: &str, o: &str| match test_env(id, o) {
            Ok(_) => panic!("{id} {o}: accepted"),
            Err(e) => e.to_string(),
        };
        for (id, o, says) in [
            ("SelkdEcho-v9", "", "VersionNotFound"),
            ("SelkdEcoh-v0", "", "Did you mean"),
            ("SelkdUnbounded-v0", "", "infinite bound"),
            ("SelkdDiscrete-v0", "", "Discrete(3); only Box spaces"),
            (
                "SelkdEcho-v0",
                "frobnicate = 1",
                "unexpected keyword argument 'frobnicate'",
            ),
        ] {
            let e = err(id, o);
            assert!(e.contains(says) && !e.contains('\n'), "{id} {o}: {e}");
        }
        let o: EnvOptions = toml::from_str("import = 3").unwrap();
        let e = make("gymnasium:SelkdEcho-v0", &o)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("list of module names"), "{e}");
        let mut o = EnvOptions::new();
        o.insert(
            IMPORT_KEY.into(),
            toml::Value::Array(vec!["no_such_module_x".into()]),
        );
        let e = make("gymnasium:SelkdEcho-v0", &o)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("No module named 'no_such_module_x'") && e.contains("pip install"),
            "{e}"
        );
    }
}
