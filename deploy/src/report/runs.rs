//! Reading run directories (`metrics.csv`, `config.toml`, the final checkpoint's `state.json`)
//! and an experiment directory (`DIR/<method>/<task>/seed-<s>/`), and the checks that keep
//! runs that must not be averaged apart: runs of different envs, or of configs that differ in
//! anything but `run.seed`, `run.threads`, `run.cpu_gemm`, `run.device` and `run.dir_mode`
//! (which change neither the task nor the algorithm).

use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What the curves show.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Metric {
    /// Undiscounted evaluation return (`eval_return_i`).
    Return,
    /// Evaluation success rate (`eval_success_i`), for tasks that report success.
    Success,
}

impl Metric {
    pub fn label(self) -> &'static str {
        match self {
            Metric::Return => "evaluation return",
            Metric::Success => "evaluation success rate",
        }
    }
}

/// What the curves are drawn against (`--x`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum XAxis {
    /// Transitions of all actors together (metrics.csv's `env_steps`).
    EnvSteps,
    /// Algorithm 1's time-steps: env steps / K (each of the K actors takes one step a round).
    Rounds,
    /// Critic-ensemble updates (metrics.csv's `critic_updates`).
    CriticUpdates,
    /// Seconds of training, resumed runs included (metrics.csv's `wall_s`).
    WallClock,
}

impl XAxis {
    /// The axis label.
    pub fn label(self) -> &'static str {
        match self {
            XAxis::EnvSteps => "env steps (transitions of all actors together)",
            XAxis::Rounds => "rounds (each of the K actors takes one step; env steps / K)",
            XAxis::CriticUpdates => "critic updates",
            XAxis::WallClock => "wall-clock seconds of training",
        }
    }

    /// Its name on the command line and in `[[figure]] x`.
    pub fn name(self) -> &'static str {
        match self {
            XAxis::EnvSteps => "env-steps",
            XAxis::Rounds => "rounds",
            XAxis::CriticUpdates => "critic-updates",
            XAxis::WallClock => "wall-clock",
        }
    }

    /// Its column name in the curve data CSVs.
    pub fn column(self) -> &'static str {
        match self {
            XAxis::EnvSteps => "env_steps",
            XAxis::Rounds => "rounds",
            XAxis::CriticUpdates => "critic_updates",
            XAxis::WallClock => "wall_s",
        }
    }

    pub fn parse(name: &str) -> Option<XAxis> {
        [
            XAxis::EnvSteps,
            XAxis::Rounds,
            XAxis::CriticUpdates,
            XAxis::WallClock,
        ]
        .into_iter()
        .find(|x| x.name() == name)
    }
}

/// `metrics.csv`: one row per epoch.
#[derive(Clone, Debug, Default)]
pub struct Metrics {
    /// Env steps, all actors together.
    pub steps: Vec<f64>,
    /// The ranking's best actor per epoch (`best`), when the file has that column.
    pub best: Option<Vec<f64>>,
    /// `critic_updates` and `wall_s` per epoch, when the file has those columns.
    pub critic_updates: Option<Vec<f64>>,
    pub wall_s: Option<Vec<f64>>,
    /// `eval_return_i`, `[actor][epoch]`.
    pub returns: Vec<Vec<f64>>,
    /// `eval_success_i`, `[actor][epoch]` (NaN for tasks without success).
    pub successes: Vec<Vec<f64>>,
}

impl Metrics {
    pub fn read(run: &Path) -> Result<Metrics> {
        let path = run.join("metrics.csv");
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "reading {} (is {} a run directory?)",
                path.display(),
                run.display()
            )
        })?;
        Self::parse(&text).with_context(|| format!("reading {}", path.display()))
    }

    pub fn parse(text: &str) -> Result<Metrics> {
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().context("empty file")?.split(',').collect();
        let col = |name: &str| header.iter().position(|h| *h == name);
        let prefixed = |prefix: &str| -> Vec<usize> {
            // eval_return_0, eval_return_1, ... in actor order.
            (0..).map_while(|i| col(&format!("{prefix}{i}"))).collect()
        };
        let steps_col = col("env_steps").context("no env_steps column")?;
        let best_col = col("best");
        let (updates_col, wall_col) = (col("critic_updates"), col("wall_s"));
        let (ret, suc) = (prefixed("eval_return_"), prefixed("eval_success_"));
        if ret.is_empty() {
            bail!("no eval_return_* columns (written by an older selkd?)");
        }
        let mut m = Metrics {
            best: best_col.map(|_| Vec::new()),
            critic_updates: updates_col.map(|_| Vec::new()),
            wall_s: wall_col.map(|_| Vec::new()),
            returns: vec![Vec::new(); ret.len()],
            successes: vec![Vec::new(); suc.len()],
            ..Metrics::default()
        };
        for (n, l) in lines.enumerate() {
            if l.trim().is_empty() {
                continue;
            }
            let v: Vec<f64> = l
                .split(',')
                .map(|x| x.trim().parse().unwrap_or(f64::NAN))
                .collect();
            if v.len() < header.len() {
                // A row cut short (the learner killed mid-write): the epochs before it stand.
                eprintln!(
                    "selkd: warning: metrics.csv row {} is incomplete; ignored",
                    n + 2
                );
                continue;
            }
            m.steps.push(v[steps_col]);
            for (out, c) in [
                (m.best.as_mut(), best_col),
                (m.critic_updates.as_mut(), updates_col),
                (m.wall_s.as_mut(), wall_col),
            ] {
                if let (Some(out), Some(c)) = (out, c) {
                    out.push(v[c]);
                }
            }
            for (a, &c) in ret.iter().enumerate() {
                m.returns[a].push(v[c]);
            }
            for (a, &c) in suc.iter().enumerate() {
                m.successes[a].push(v[c]);
            }
        }
        Ok(m)
    }

    /// Each epoch's position on `axis` (rounds need the run's K); `run` names the directory in
    /// the error when an older metrics.csv lacks the axis's column.
    pub fn xs(&self, axis: XAxis, actors: u64, run: &Path) -> Result<Vec<f64>> {
        let column = |c: &Option<Vec<f64>>| {
            c.clone().with_context(|| {
                format!(
                    "{} has no {} column (written by an older selkd?), so it cannot be drawn against {}; use --x env-steps or rounds",
                    run.join("metrics.csv").display(),
                    axis.column(),
                    axis.name()
                )
            })
        };
        match axis {
            XAxis::EnvSteps => Ok(self.steps.clone()),
            XAxis::Rounds => Ok(self
                .steps
                .iter()
                .map(|s| s / actors.max(1) as f64)
                .collect()),
            XAxis::CriticUpdates => column(&self.critic_updates),
            XAxis::WallClock => column(&self.wall_s),
        }
    }

    /// Whether the task reports success (some `eval_success_*` value is not NaN).
    pub fn has_success(&self) -> bool {
        self.successes.iter().flatten().any(|v| v.is_finite())
    }

    pub fn actors(&self, metric: Metric) -> &[Vec<f64>] {
        match metric {
            Metric::Return => &self.returns,
            Metric::Success => &self.successes,
        }
    }

    /// Per epoch, the in-run evaluation of the actor the ranking picked at that epoch (the
    /// `best` column); files without that column fall back to the best evaluation of the epoch.
    pub fn ranked(&self, metric: Metric) -> Vec<f64> {
        let actors = self.actors(metric);
        (0..self.steps.len())
            .map(|e| match &self.best {
                Some(b) if b[e].is_finite() && (b[e] as usize) < actors.len() => {
                    actors[b[e] as usize][e]
                }
                _ => actors
                    .iter()
                    .map(|a| a[e])
                    .filter(|v| v.is_finite())
                    .fold(f64::NAN, f64::max),
            })
            .collect()
    }

    /// The mean of the ranked actor's in-run evaluations (as [`Metrics::ranked`]) at the epochs
    /// in the last fifth of `budget` env steps (past 0.8 × budget): one epoch's 5 episodes
    /// swing widely on tasks such as Hopper (a run at 2 990 at 95k env steps evaluated 274 at
    /// 100k), so Table 2 shows this beside the final evaluation. NaN without such an epoch.
    pub fn late_ranked(&self, metric: Metric, budget: u64) -> f64 {
        let ranked = self.ranked(metric);
        let late: Vec<f64> = self
            .steps
            .iter()
            .zip(&ranked)
            .filter(|(s, _)| **s * 5.0 > budget as f64 * 4.0)
            .map(|(_, v)| *v)
            .collect();
        super::align::mean(&late)
    }

    /// Per epoch, the mean over actors.
    pub fn actor_mean(&self, metric: Metric) -> Vec<f64> {
        let actors = self.actors(metric);
        (0..self.steps.len())
            .map(|e| super::align::mean(&actors.iter().map(|a| a[e]).collect::<Vec<_>>()))
            .collect()
    }
}

/// One `selkd train` run directory.
#[derive(Clone, Debug)]
pub struct Run {
    pub dir: PathBuf,
    /// `config.toml`, the resolved config.
    pub config: toml::Table,
    pub env: String,
    pub seed: u64,
    /// `run.total_env_steps`.
    pub budget: u64,
    /// `algo.actors`, K.
    pub actors: u64,
    /// `run.total_rounds` when the budget was set in rounds (0: set in env steps, or a config
    /// written before rounds existed).
    pub budget_rounds: u64,
    /// Env steps the final checkpoint reached (`inserted`), if there is one.
    pub reached: Option<u64>,
    /// Empty when the run wrote no metrics.csv yet.
    pub metrics: Metrics,
}

/// `table.section.key` as a string, or None.
fn get<'a>(t: &'a toml::Table, section: &str, key: &str) -> Option<&'a toml::Value> {
    t.get(section)?.as_table()?.get(key)
}

impl Run {
    pub fn load(dir: &Path) -> Result<Run> {
        let cfg_path = dir.join("config.toml");
        let config: toml::Table = std::fs::read_to_string(&cfg_path)
            .with_context(|| {
                format!(
                    "reading {} (is {} a run directory?)",
                    cfg_path.display(),
                    dir.display()
                )
            })?
            .parse()
            .with_context(|| format!("reading {}", cfg_path.display()))?;
        let env = get(&config, "run", "env")
            .and_then(|v| v.as_str())
            .with_context(|| format!("{} has no run.env", cfg_path.display()))?
            .to_string();
        let budget = get(&config, "run", "total_env_steps")
            .and_then(|v| v.as_integer())
            .with_context(|| format!("{} has no run.total_env_steps", cfg_path.display()))?
            as u64;
        let int = |section: &str, key: &str| {
            get(&config, section, key)
                .and_then(|v| v.as_integer())
                .map(|v| v as u64)
        };
        // A config.toml always has algo.actors (written whole); the default is Table 1's K.
        let actors = int("algo", "actors").unwrap_or(5).max(1);
        let budget_rounds = int("run", "total_rounds").unwrap_or(0);
        let seed = get(&config, "run", "seed")
            .and_then(|v| v.as_integer())
            .unwrap_or(0) as u64;
        // A published run (`selkd experiment publish`) keeps the final checkpoint's state.json,
        // without the weights, beside its config.
        let state = [
            dir.join("checkpoints/final/state.json"),
            dir.join("state.json"),
        ]
        .into_iter()
        .find(|p| p.exists())
        .unwrap_or_else(|| dir.join("checkpoints/final/state.json"));
        let reached = if state.exists() {
            let v: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(&state)
                    .with_context(|| format!("reading {}", state.display()))?,
            )
            .with_context(|| format!("reading {}", state.display()))?;
            Some(
                v.get("inserted")
                    .and_then(|i| i.as_u64())
                    .with_context(|| format!("{} has no `inserted`", state.display()))?,
            )
        } else {
            None
        };
        let metrics = if dir.join("metrics.csv").exists() {
            Metrics::read(dir)?
        } else {
            Metrics::default()
        };
        Ok(Run {
            dir: dir.to_path_buf(),
            config,
            env,
            seed,
            budget,
            actors,
            budget_rounds,
            reached,
            metrics,
        })
    }

    /// The final checkpoint reached the budget.
    pub fn finished(&self) -> bool {
        self.reached.is_some_and(|r| r >= self.budget)
    }

    /// Each epoch's position on `axis`, or an error naming the column an older metrics.csv lacks.
    pub fn xs(&self, axis: XAxis) -> Result<Vec<f64>> {
        self.metrics.xs(axis, self.actors, &self.dir)
    }

    /// The budget in words: `6000 env steps (2000 rounds of K = 3, set in rounds)`.
    pub fn budget_text(&self) -> String {
        let rounds = self.budget.div_ceil(self.actors);
        let unit = if self.budget_rounds > 0 {
            "set in rounds"
        } else {
            "set in env steps"
        };
        format!(
            "{} env steps = {} rounds of K = {} ({unit})",
            self.budget, rounds, self.actors
        )
    }

    /// Env steps the run got to: the final checkpoint's, else the last epoch's.
    pub fn env_steps(&self) -> u64 {
        self.reached
            .unwrap_or_else(|| self.metrics.steps.last().copied().unwrap_or(0.0) as u64)
    }
}

/// `config` read by this build, every key written out (defaults included); None where this build
/// cannot read it (a key since removed).
fn resolved(config: &toml::Table) -> Option<toml::Table> {
    let cfg =
        selkd_learner::config::Config::from_toml_with_overrides(&config.to_string(), &[]).ok()?;
    cfg.to_toml().parse().ok()
}

/// Every `section.key = value` of a config but those that may differ between seeds of one method.
fn comparable(config: &toml::Table) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for (section, v) in config {
        match v.as_table() {
            Some(t) => {
                for (k, v) in t {
                    out.insert(format!("{section}.{k}"), v.to_string());
                }
            }
            None => {
                out.insert(section.clone(), v.to_string());
            }
        }
    }
    for k in [
        "run.seed",
        "run.threads",
        "run.cpu_gemm",
        "run.device",
        "run.dir_mode",
    ] {
        out.remove(k);
    }
    out
}

/// Refuses runs of different envs, naming each run with its env.
pub fn check_same_env(runs: &[&Run]) -> Result<()> {
    if runs.iter().any(|r| r.env != runs[0].env) {
        let list: Vec<String> = runs
            .iter()
            .map(|r| format!("{} ({})", r.dir.display(), r.env))
            .collect();
        bail!(
            "runs of different envs cannot be averaged: {}",
            list.join(", ")
        );
    }
    Ok(())
}

/// Refuses runs whose configs differ in anything but run.seed, run.threads, run.cpu_gemm,
/// run.device and run.dir_mode, naming the keys and, for each, the runs' values.
/// Configs are compared as this build reads them when it reads them all, so a key that a run
/// made by an older build did not write compares equal to the same key at its default.
pub fn check_same_config(runs: &[&Run]) -> Result<()> {
    check_same_env(runs)?;
    let configs: Vec<toml::Table> = runs
        .iter()
        .map(|r| resolved(&r.config))
        .collect::<Option<_>>()
        .unwrap_or_else(|| runs.iter().map(|r| r.config.clone()).collect());
    let first = comparable(&configs[0]);
    let mut keys: Vec<String> = Vec::new();
    let all: Vec<BTreeMap<String, String>> = configs.iter().map(comparable).collect();
    for c in &all {
        for k in first.keys().chain(c.keys()) {
            if first.get(k) != c.get(k) && !keys.contains(k) {
                keys.push(k.clone());
            }
        }
    }
    if keys.is_empty() {
        return Ok(());
    }
    keys.sort();
    let list: Vec<String> = runs
        .iter()
        .zip(&all)
        .map(|(r, c)| {
            let vals: Vec<String> = keys
                .iter()
                .map(|k| format!("{k} = {}", c.get(k).map_or("(unset)", |v| v.as_str())))
                .collect();
            format!("{} ({})", r.dir.display(), vals.join(", "))
        })
        .collect();
    bail!(
        "runs with different configs cannot be averaged (only run.seed, run.threads, run.cpu_gemm, run.device and run.dir_mode may differ): {}",
        list.join("; ")
    )
}

/// The runs of an experiment directory: `[(method, task, run)]`, sorted by method, task, seed.
pub fn discover(dir: &Path) -> Result<Vec<(String, String, Run)>> {
    let subdirs = |d: &Path| -> Result<Vec<(String, PathBuf)>> {
        let mut v: Vec<(String, PathBuf)> = std::fs::read_dir(d)
            .with_context(|| format!("reading {}", d.display()))?
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_dir())
            .map(|e| (e.file_name().to_string_lossy().into_owned(), e.path()))
            .collect();
        v.sort();
        Ok(v)
    };
    let mut out = Vec::new();
    for (method, mdir) in subdirs(dir)? {
        for (task, tdir) in subdirs(&mdir)? {
            let mut seeds: Vec<(u64, PathBuf)> = subdirs(&tdir)?
                .into_iter()
                .filter_map(|(n, p)| Some((n.strip_prefix("seed-")?.parse().ok()?, p)))
                .filter(|(_, p)| p.join("config.toml").exists())
                .collect();
            seeds.sort();
            for (_, sdir) in seeds {
                out.push((method.clone(), task.clone(), Run::load(&sdir)?));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A hand-made run directory: config.toml from `config`, metrics.csv, and a final
    /// state.json with `inserted` when given.
    pub fn fake_run(dir: &Path, config: &str, metrics: &str, inserted: Option<u64>) {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("config.toml"), config).unwrap();
        std::fs::write(dir.join("metrics.csv"), metrics).unwrap();
        if let Some(i) = inserted {
            let ck = dir.join("checkpoints/final");
            std::fs::create_dir_all(&ck).unwrap();
            std::fs::write(ck.join("state.json"), format!("{{\"inserted\": {i}}}")).unwrap();
        }
    }

    pub fn config(env: &str, seed: u64, actors: u64) -> String {
        format!("[run]\nenv = \"{env}\"\nseed = {seed}\ntotal_env_steps = 2000\nthreads = {seed}\n\n[algo]\nactors = {actors}\n")
    }

    pub const METRICS: &str =
        "epoch,env_steps,best,eval_return_0,eval_return_1,eval_success_0,eval_success_1\n\
        1,1000,1,-50.0,-40.0,NaN,NaN\n\
        2,2000,0,-20.0,-30.0,NaN,NaN\n";

    fn temp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("selkd-runs-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn the_ranked_actor_is_the_best_column_s_actor() {
        let m = Metrics::parse(METRICS).unwrap();
        assert_eq!(m.ranked(Metric::Return), vec![-40.0, -20.0]);
        assert_eq!(m.actor_mean(Metric::Return), vec![-45.0, -25.0]);
        assert!(!m.has_success());
    }

    #[test]
    fn the_late_mean_takes_the_ranked_actor_past_four_fifths_of_the_budget() {
        // Epochs at 600..1000 of a 1000-step budget: only 900 and 1000 are past 800 (800
        // itself is not); the ranked actor there is actor 1 (30) then actor 0 (10): mean 20.
        let m = Metrics::parse(
            "epoch,env_steps,best,eval_return_0,eval_return_1\n\
            1,600,0,1000,0\n\
            2,800,1,0,1000\n\
            3,900,1,-5,30\n\
            4,1000,0,10,99\n",
        )
        .unwrap();
        assert_eq!(m.late_ranked(Metric::Return, 1000), 20.0);
        // A run whose epochs all lie before the last fifth has no late mean.
        assert!(m.late_ranked(Metric::Return, 10_000).is_nan());
    }

    #[test]
    fn runs_of_different_envs_or_configs_are_refused_by_name() {
        let d = temp("refuse");
        fake_run(&d.join("a"), &config("pendulum", 1, 2), METRICS, Some(2000));
        fake_run(&d.join("b"), &config("hopper", 2, 2), METRICS, Some(2000));
        fake_run(&d.join("c"), &config("pendulum", 3, 3), METRICS, Some(2000));
        fake_run(&d.join("d"), &config("pendulum", 4, 2), METRICS, Some(1500));
        let [a, b, c, dd] = ["a", "b", "c", "d"].map(|n| Run::load(&d.join(n)).unwrap());
        let e = check_same_config(&[&a, &b]).unwrap_err().to_string();
        assert!(
            e.contains("different envs") && e.contains("(pendulum)") && e.contains("(hopper)"),
            "{e}"
        );
        assert!(!e.contains('\n'));
        let e = check_same_config(&[&a, &c]).unwrap_err().to_string();
        assert!(
            e.contains("algo.actors = 2") && e.contains("algo.actors = 3"),
            "{e}"
        );
        // Seeds and threads may differ.
        check_same_config(&[&a, &dd]).unwrap();
        // A key the older run did not write is its default: equal to the default written out,
        // not to another value (G = 2 of algo.utd = 20 actor updates per round).
        let with = |v: u64| {
            format!(
                "{}actor_updates_per_round = {v}\n",
                config("pendulum", 5, 2)
            )
        };
        fake_run(&d.join("e"), &with(1), METRICS, Some(2000));
        fake_run(&d.join("f"), &with(2), METRICS, Some(2000));
        let [e1, f2] = ["e", "f"].map(|n| Run::load(&d.join(n)).unwrap());
        check_same_config(&[&a, &e1]).unwrap();
        let e = check_same_config(&[&a, &f2]).unwrap_err().to_string();
        assert!(
            e.contains("algo.actor_updates_per_round = 1")
                && e.contains("algo.actor_updates_per_round = 2"),
            "{e}"
        );
        // A config this build cannot read is compared key by key as written.
        fake_run(
            &d.join("g"),
            &format!("{}retired_key = 3\n", config("pendulum", 6, 2)),
            METRICS,
            Some(2000),
        );
        let g = Run::load(&d.join("g")).unwrap();
        let e = check_same_config(&[&a, &g]).unwrap_err().to_string();
        assert!(
            e.contains("algo.retired_key = 3") && e.contains("algo.retired_key = (unset)"),
            "{e}"
        );
        assert!(a.finished() && !dd.finished());
        assert_eq!(dd.env_steps(), 1500);
        let _ = std::fs::remove_dir_all(&d);
    }
}
