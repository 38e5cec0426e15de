//! The experiment file: its format, its checks, and its expansion into runs whose configs are
//! resolved before anything starts.
//!
//! Everything a user can get wrong is found here, once, before the first child process starts,
//! with a one-line error that names the method, task or key to change: a sweep that fails on its
//! fortieth run after two days is the failure this module exists to prevent.

use super::state::{state, State};
use anyhow::{bail, Context, Result};
use selkd_learner::config::Config;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// An experiment file (TOML). The format is documented in the README ("Experiments") and at the
/// top of every file in `experiments/`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    /// One sentence for the report's heading.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Every run's budget in env steps (`run.total_env_steps`: transitions of all actors
    /// together); or `total_rounds`, never both.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub total_env_steps: u64,
    /// Every run's budget in rounds (`run.total_rounds`: each of the K actors takes one step).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub total_rounds: u64,
    /// Every (method, task) pair runs once per seed (`run.seed`).
    #[serde(default)]
    pub seeds: Vec<u64>,
    /// Env registry names (`run.env`).
    #[serde(default)]
    pub tasks: Vec<String>,
    /// Overrides for every run, `"section.key" = value` (nested tables are read as dotted keys).
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub set: toml::Table,
    /// Overrides for the runs of one task, e.g. `[task_set.fpc-assembly]`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub task_set: BTreeMap<String, toml::Table>,
    #[serde(default, rename = "method")]
    pub methods: Vec<Method>,
    /// Which methods the report draws together (`selkd experiment report`).
    #[serde(default, rename = "figure", skip_serializing_if = "Vec::is_empty")]
    pub figures: Vec<Figure>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Method {
    /// Directory name of its runs (letters, digits, `-`, `_`, `.`).
    pub name: String,
    /// Legend text for the report (default: `name`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// A `selkd train` config file, relative to the experiment file.
    pub config: PathBuf,
    /// This method's overrides, applied after the common and per-task ones.
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub set: toml::Table,
    /// This method's own budget in env steps, instead of the experiment's (one file can then
    /// hold SELKD at equal env steps and at equal rounds beside the same baselines).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub total_env_steps: u64,
    /// This method's own budget in rounds, instead of the experiment's.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub total_rounds: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// A budget and its unit, as the experiment (or a method) sets it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Budget {
    EnvSteps(u64),
    Rounds(u64),
}

impl Budget {
    /// The `--set` that gives a run this budget.
    pub fn set(self) -> String {
        match self {
            Budget::EnvSteps(n) => format!("run.total_env_steps={n}"),
            Budget::Rounds(n) => format!("run.total_rounds={n}"),
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Figure {
    pub title: String,
    pub methods: Vec<String>,
    /// This figure's x axis (`env-steps`, `rounds`, `critic-updates`, `wall-clock`); absent:
    /// the report's `--x`. A figure at equal rounds is drawn against rounds, one at equal env
    /// steps against env steps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub x: Option<String>,
}

/// The x axes a figure can be drawn against (`selkd experiment report --x`, `[[figure]] x`).
pub const X_AXES: [&str; 4] = ["env-steps", "rounds", "critic-updates", "wall-clock"];

/// The keys an experiment sets itself from `tasks`, `seeds` and its (or a method's) budget.
const OWNED_KEYS: [(&str, &str); 4] = [
    ("run.env", "tasks"),
    ("run.seed", "seeds"),
    ("run.total_env_steps", "total_env_steps"),
    ("run.total_rounds", "total_rounds"),
];

/// Keys whose change does not make an existing run directory another run: the libtorch thread
/// count follows `--jobs`, and a raised budget (in either unit) is how a finished run is
/// trained further.
pub const KEYS_FREE_TO_CHANGE: [&str; 3] =
    ["run.threads", "run.total_env_steps", "run.total_rounds"];

/// One (method, task, seed): an ordinary `selkd train` run directory.
#[derive(Clone, Debug)]
pub struct Run {
    /// `<method>/<task>/seed-<s>`, the run's directory below the experiment's, and `--only`'s name.
    pub id: String,
    pub dir: PathBuf,
    /// The method's config file (absolute).
    pub config_file: PathBuf,
    /// `--set` arguments for `selkd train`, in the order they apply.
    pub sets: Vec<String>,
    /// What `selkd train --config config_file --set sets…` resolves to.
    pub config: Config,
}

impl Experiment {
    /// Reads and checks an experiment file; config paths become absolute (relative to the file).
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading experiment {}", path.display()))?;
        let mut exp: Experiment = toml::from_str(&text).map_err(|e| {
            anyhow::anyhow!(
                "experiment {}: {}",
                path.display(),
                e.to_string()
                    .split_whitespace()
                    .collect::<Vec<_>>()
                    .join(" ")
            )
        })?;
        let base = path
            .canonicalize()
            .with_context(|| format!("locating {}", path.display()))?
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default();
        for m in &mut exp.methods {
            let abs = base.join(&m.config);
            m.config = abs.canonicalize().map_err(|_| {
                anyhow::anyhow!(
                    "experiment {}: method `{}`: config file {} does not exist (looked for {}; paths are relative to the experiment file)",
                    path.display(),
                    m.name,
                    m.config.display(),
                    abs.display()
                )
            })?;
        }
        exp.check()
            .with_context(|| format!("experiment {}", path.display()))?;
        Ok(exp)
    }

    /// The checks that need no config file.
    fn check(&self) -> Result<()> {
        if self.methods.is_empty() {
            bail!("no methods: add at least one [[method]] with a name and a config");
        }
        if self.tasks.is_empty() {
            bail!("no tasks: set tasks = [\"pendulum\", ...] (env registry names)");
        }
        if self.seeds.is_empty() {
            bail!("no seeds: set seeds = [1, 2, 3, ...]");
        }
        match (self.total_env_steps, self.total_rounds) {
            (0, 0) if self.methods.iter().all(|m| m.total_env_steps > 0 || m.total_rounds > 0) => {}
            (0, 0) => bail!("total_env_steps must be at least 1 (every run's budget, env steps of all actors together), or set total_rounds (rounds: each of the K actors takes one step)"),
            (s, r) if s > 0 && r > 0 => bail!("total_env_steps = {s} and total_rounds = {r} both set every run's budget; set only one (a method may set its own)"),
            _ => {}
        }
        for m in &self.methods {
            if m.total_env_steps > 0 && m.total_rounds > 0 {
                bail!("method `{}`: total_env_steps = {} and total_rounds = {} both set its budget; set only one", m.name, m.total_env_steps, m.total_rounds);
            }
        }
        let mut names = BTreeSet::new();
        for m in &self.methods {
            let ok = !m.name.is_empty()
                && !m.name.starts_with('.')
                && m.name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c));
            if !ok {
                bail!("method name `{}` must be letters, digits, `-`, `_` or `.` (it names a directory)", m.name);
            }
            if !names.insert(m.name.as_str()) {
                bail!(
                    "two methods are named `{}`: method names must be unique",
                    m.name
                );
            }
        }
        let known = selkd_envs::names();
        let mut tasks = BTreeSet::new();
        for t in &self.tasks {
            if t.starts_with(selkd_gymnasium::PREFIX) {
                // Gymnasium's registry knows its ids: make it once (with the runs' options,
                // checked again per run when each config is validated).
                if let Err(e) = selkd_envs::make_with(t, &selkd_envs::EnvOptions::new()) {
                    bail!("tasks: {e}");
                }
            } else if !known.contains(&t.as_str()) {
                bail!(
                    "tasks: `{t}` is not a known env; choose from: {}, or gymnasium:<id>",
                    known.join(", ")
                );
            }
            if !tasks.insert(t.as_str()) {
                bail!("tasks: `{t}` is listed twice");
            }
        }
        for t in self.task_set.keys() {
            if !tasks.contains(t.as_str()) {
                bail!("[task_set.{t}]: `{t}` is not in tasks = {:?}", self.tasks);
            }
        }
        let mut seeds = BTreeSet::new();
        for s in &self.seeds {
            if !seeds.insert(s) {
                bail!("seeds: {s} is listed twice");
            }
        }
        for f in &self.figures {
            if let Some(x) = f.x.as_deref().filter(|x| !X_AXES.contains(x)) {
                bail!(
                    "figure \"{}\": x = \"{x}\" is not an axis; choose one of: {}",
                    f.title,
                    X_AXES.join(", ")
                );
            }
            for m in &f.methods {
                if !names.contains(m.as_str()) {
                    bail!(
                        "figure \"{}\": no method is named `{m}` (methods: {})",
                        f.title,
                        names.iter().copied().collect::<Vec<_>>().join(", ")
                    );
                }
            }
        }
        let tables = std::iter::once(("set".to_string(), &self.set))
            .chain(
                self.task_set
                    .iter()
                    .map(|(t, s)| (format!("[task_set.{t}]"), s)),
            )
            .chain(
                self.methods
                    .iter()
                    .map(|m| (format!("method `{}`: set", m.name), &m.set)),
            );
        for (what, table) in tables {
            for (key, _) in flatten(table) {
                if !key.contains('.') {
                    bail!("{what}: `{key}` is not a config key; write \"section.key\" = value, e.g. \"algo.actors\" = 3");
                }
                if let Some((_, field)) = OWNED_KEYS.iter().find(|(k, _)| *k == key) {
                    bail!(
                        "{what}: `{key}` is set by the experiment's `{field}`; change that instead"
                    );
                }
            }
        }
        Ok(())
    }

    /// A method's budget: its own, else the experiment's.
    pub fn budget(&self, method: &Method) -> Budget {
        if method.total_rounds > 0 {
            Budget::Rounds(method.total_rounds)
        } else if method.total_env_steps > 0 {
            Budget::EnvSteps(method.total_env_steps)
        } else if self.total_rounds > 0 {
            Budget::Rounds(self.total_rounds)
        } else {
            Budget::EnvSteps(self.total_env_steps)
        }
    }

    /// Does any of the experiment's overrides set `key` for this (method, task)?
    fn sets_key(&self, method: &Method, task: &str, key: &str) -> bool {
        [Some(&self.set), self.task_set.get(task), Some(&method.set)]
            .into_iter()
            .flatten()
            .any(|t| flatten(t).iter().any(|(k, _)| k == key))
    }

    /// The ids of every run, in the order they start: seed-major, so that with fewer jobs than
    /// runs each seed's sweep is complete before the next one begins (a half-done experiment
    /// still compares every method).
    pub fn run_ids(&self) -> Vec<String> {
        let mut out = Vec::new();
        for seed in &self.seeds {
            for task in &self.tasks {
                for m in &self.methods {
                    out.push(format!("{}/{task}/seed-{seed}", m.name));
                }
            }
        }
        out
    }

    /// Every run with its resolved config. `threads` is `run.threads` for runs whose experiment
    /// overrides leave it unset (the method's config file does not count: it was written for a
    /// run alone, not for J at once).
    pub fn resolve(&self, dir: &Path, threads: usize) -> Result<Vec<Run>> {
        let mut runs = Vec::new();
        for seed in &self.seeds {
            for task in &self.tasks {
                for m in &self.methods {
                    let id = format!("{}/{task}/seed-{seed}", m.name);
                    let text = std::fs::read_to_string(&m.config).with_context(|| {
                        format!("method `{}`: reading {}", m.name, m.config.display())
                    })?;
                    let mut sets = Vec::new();
                    for table in [Some(&self.set), self.task_set.get(task), Some(&m.set)]
                        .into_iter()
                        .flatten()
                    {
                        for (k, v) in flatten(table) {
                            sets.push(format!("{k}={v}"));
                        }
                    }
                    sets.push(format!("run.env={task}"));
                    sets.push(format!("run.seed={seed}"));
                    sets.push(self.budget(m).set());
                    if !self.sets_key(m, task, "run.threads") {
                        sets.push(format!("run.threads={threads}"));
                    }
                    let config =
                        Config::from_toml_with_overrides(&text, &sets).with_context(|| {
                            format!(
                                "method `{}` on task `{task}` (config {}, overrides {})",
                                m.name,
                                m.config.display(),
                                sets.join(" ")
                            )
                        })?;
                    runs.push(Run {
                        dir: dir.join(&id),
                        id,
                        config_file: m.config.clone(),
                        sets,
                        config,
                    });
                }
            }
        }
        Ok(runs)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("experiment serialises")
    }
}

/// A table's leaves as (dotted key, value as TOML text), so `{ algo = { actors = 3 } }` and
/// `{ "algo.actors" = 3 }` both give `algo.actors=3`, the `--set` form `selkd train` reads.
fn flatten(table: &toml::Table) -> Vec<(String, String)> {
    fn walk(prefix: &str, t: &toml::Table, out: &mut Vec<(String, String)>) {
        for (k, v) in t {
            let key = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            match v {
                toml::Value::Table(inner) if !inner.is_empty() => walk(&key, inner, out),
                v => out.push((key, v.to_string())),
            }
        }
    }
    let mut out = Vec::new();
    walk("", table, &mut out);
    out
}

/// Checks that an existing run directory holds the same run: its `config.toml` must equal the
/// resolved config except for [`KEYS_FREE_TO_CHANGE`]. Returns the differing keys.
pub fn config_differences(run: &Run) -> Result<Vec<String>> {
    let path = run.dir.join("config.toml");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(Vec::new()); // a directory nothing has been trained in yet
    };
    let old = Config::from_toml_with_overrides(&text, &[])
        .with_context(|| format!("run {}: reading {}", run.id, path.display()))?;
    let as_table = |c: &Config| -> toml::Table {
        toml::from_str(&c.to_toml()).expect("a config's TOML parses")
    };
    let (old, new) = (flatten(&as_table(&old)), flatten(&as_table(&run.config)));
    let old: BTreeMap<_, _> = old.into_iter().collect();
    let new: BTreeMap<_, _> = new.into_iter().collect();
    let keys: BTreeSet<&String> = old.keys().chain(new.keys()).collect();
    Ok(keys
        .into_iter()
        .filter(|k| !KEYS_FREE_TO_CHANGE.contains(&k.as_str()) && old.get(*k) != new.get(*k))
        .map(|k| {
            format!(
                "{k} ({} there, {} now)",
                old.get(k).map_or("unset", String::as_str),
                new.get(k).map_or("unset", String::as_str)
            )
        })
        .collect())
}

/// Loads, resolves and checks every run against its directory: the one gate before any start.
/// `only` (run ids) narrows the runs and orders them as named; `cores` and `jobs` set the
/// default `run.threads`.
pub fn prepare(
    path: &Path,
    dir: &Path,
    cores: usize,
    jobs: usize,
    only: &[String],
) -> Result<(Experiment, Vec<Run>)> {
    let exp = Experiment::load(path)?;
    let ids = exp.run_ids();
    for o in only {
        if !ids.contains(o) {
            bail!(
                "--only {o}: no such run; runs are named <method>/<task>/seed-<s>, e.g. {}",
                ids[0]
            );
        }
    }
    // Split the cores over the runs that will train at once, so J runs never ask for more
    // learner threads than there are cores: oversubscribed, a run's update rate collapsed to
    // 3–8 updates/s, against 65–75 with one thread each.
    // Each run's budget in env steps needs its resolved config (a rounds budget is × K); the
    // thread count does not change it.
    let at_once = exp
        .resolve(dir, 1)?
        .iter()
        .filter(|r| only.is_empty() || only.contains(&r.id))
        .filter(|r| state(&r.dir, r.config.run.total_env_steps) != State::Finished)
        .count()
        .min(jobs)
        .max(1);
    let threads = (cores / at_once).max(1);
    let mut runs = exp.resolve(dir, threads)?;
    if !only.is_empty() {
        runs.retain(|r| only.contains(&r.id));
        // In the order named: `--only` is also how a user puts some runs first.
        runs.sort_by_key(|r| only.iter().position(|o| *o == r.id));
    }
    for r in &runs {
        let diff = config_differences(r)?;
        if !diff.is_empty() {
            bail!(
                "run {} already exists in {} with another config: {}; restore the experiment's settings, or give it another --dir",
                r.id,
                r.dir.display(),
                diff.join(", ")
            );
        }
    }
    Ok((exp, runs))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_and_dotted_keys_flatten_to_the_same_override() {
        let a: toml::Table =
            toml::from_str("algo = { actors = 3, hidden = [32, 32] }\nrun.mode = \"async\"")
                .unwrap();
        let b: toml::Table = toml::from_str(
            "\"algo.actors\" = 3\n\"algo.hidden\" = [32, 32]\n\"run.mode\" = \"async\"",
        )
        .unwrap();
        assert_eq!(flatten(&a), flatten(&b));
        assert!(flatten(&a).contains(&("run.mode".into(), "\"async\"".into())));
    }

    fn write_experiment(tag: &str, text: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("selkd-spec-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        let quick = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/quick.toml");
        std::fs::copy(quick, d.join("quick.toml")).unwrap();
        let path = d.join("e.toml");
        std::fs::write(&path, text).unwrap();
        path
    }

    /// SELKD at equal rounds and at equal env steps beside one baseline, in one file: each
    /// method's runs get their own budget (quick.toml has K = 3: 2 000 rounds are 6 000 env
    /// steps), and the file reads back the same.
    #[test]
    fn methods_that_differ_only_in_their_budget_coexist() {
        let path = write_experiment(
            "budgets",
            "total_rounds = 2000\nseeds = [1]\ntasks = [\"pendulum\"]\n\
             [[method]]\nname = \"selkd-rounds\"\nconfig = \"quick.toml\"\n\
             [[method]]\nname = \"selkd-steps\"\nconfig = \"quick.toml\"\ntotal_env_steps = 2000\n\
             [[method]]\nname = \"sac\"\nconfig = \"quick.toml\"\nset = { \"algo.actors\" = 1 }\n\
             [[figure]]\ntitle = \"equal rounds\"\nmethods = [\"selkd-rounds\", \"sac\"]\nx = \"rounds\"\n",
        );
        let exp = Experiment::load(&path).unwrap();
        let runs = exp.resolve(Path::new("/nonexistent"), 1).unwrap();
        let got: Vec<(String, u64, u64)> = runs
            .iter()
            .map(|r| {
                (
                    r.id.clone(),
                    r.config.run.total_env_steps,
                    r.config.run.total_rounds,
                )
            })
            .collect();
        assert_eq!(
            got,
            vec![
                ("selkd-rounds/pendulum/seed-1".into(), 6000, 2000),
                ("selkd-steps/pendulum/seed-1".into(), 2000, 0),
                ("sac/pendulum/seed-1".into(), 2000, 2000),
            ]
        );
        let back: Experiment = toml::from_str(&exp.to_toml()).unwrap();
        assert_eq!(back, exp);
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    /// `--only` narrows the runs to those named and starts them in the order named, not the
    /// file's (seed, task, method) order.
    #[test]
    fn only_keeps_the_runs_named_in_their_order() {
        let path = write_experiment(
            "only",
            "total_env_steps = 100\nseeds = [1, 2]\ntasks = [\"pendulum\"]\n\
             [[method]]\nname = \"a\"\nconfig = \"quick.toml\"\n\
             [[method]]\nname = \"b\"\nconfig = \"quick.toml\"\n",
        );
        let dir = path.parent().unwrap().join("runs");
        let only: Vec<String> = [
            "b/pendulum/seed-2",
            "a/pendulum/seed-1",
            "b/pendulum/seed-1",
        ]
        .map(String::from)
        .to_vec();
        let (_, runs) = prepare(&path, &dir, 1, 1, &only).unwrap();
        let ids: Vec<&str> = runs.iter().map(|r| r.id.as_str()).collect();
        assert_eq!(ids, only);
        let (_, all) = prepare(&path, &dir, 1, 1, &[]).unwrap();
        assert_eq!(all.len(), 4);
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
    }

    #[test]
    fn two_budgets_and_unknown_axes_are_one_line_errors() {
        for (text, says) in [
            ("total_env_steps = 10\ntotal_rounds = 10\n", "total_env_steps = 10 and total_rounds = 10 both set"),
            ("total_rounds = 10\n[[method]]\nname = \"m\"\nconfig = \"quick.toml\"\ntotal_env_steps = 5\ntotal_rounds = 5\n", "method `m`: total_env_steps = 5 and total_rounds = 5"),
            ("total_rounds = 10\n[[method]]\nname = \"m\"\nconfig = \"quick.toml\"\nset = { \"run.total_rounds\" = 5 }\n", "set by the experiment's `total_rounds`"),
            ("total_rounds = 10\n[[method]]\nname = \"m\"\nconfig = \"quick.toml\"\n[[figure]]\ntitle = \"f\"\nmethods = [\"m\"]\nx = \"time\"\n", "x = \"time\" is not an axis"),
        ] {
            let mut text = format!("seeds = [1]\ntasks = [\"pendulum\"]\n{text}");
            if !text.contains("[[method]]") {
                text.push_str("[[method]]\nname = \"m\"\nconfig = \"quick.toml\"\n");
            }
            let path = write_experiment("bad", &text);
            let e = format!("{:#}", Experiment::load(&path).unwrap_err());
            assert!(e.contains(says) && !e.contains('\n'), "{e}");
            let _ = std::fs::remove_dir_all(path.parent().unwrap());
        }
    }

    #[test]
    fn every_shipped_experiment_resolves_every_run() {
        // As selkd's main does: experiments/evidence.toml's tasks are Gymnasium's.
        selkd_gymnasium::register();
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../experiments");
        let mut seen = 0;
        for entry in std::fs::read_dir(&root).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let exp = Experiment::load(&path).unwrap_or_else(|e| panic!("{e:#}"));
                let runs = exp
                    .resolve(Path::new("/nonexistent"), 1)
                    .unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
                assert_eq!(
                    runs.len(),
                    exp.methods.len() * exp.tasks.len() * exp.seeds.len()
                );
                for r in &runs {
                    let method = exp
                        .methods
                        .iter()
                        .find(|m| r.id.starts_with(&format!("{}/", m.name)))
                        .unwrap();
                    match exp.budget(method) {
                        Budget::EnvSteps(n) => assert_eq!(r.config.run.total_env_steps, n),
                        Budget::Rounds(n) => assert_eq!(
                            r.config.run.total_env_steps,
                            n * r.config.algo.actors as u64
                        ),
                    }
                    assert_eq!(r.id.split('/').nth(1), Some(r.config.run.env.as_str()));
                }
                // The written form reads back as the same experiment (the report reads it).
                let back: Experiment = toml::from_str(&exp.to_toml()).unwrap();
                assert_eq!(back, exp);
                seen += 1;
            }
        }
        assert!(seen >= 3, "found {seen} experiments");
    }
}
