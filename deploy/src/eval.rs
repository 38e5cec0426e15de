//! `selkd eval RUN|CHECKPOINT`: the deterministic policy (`tanh(μ)`) of a checkpoint's actors
//! on the run's env and `[env_options]`, a few episodes each: mean ± std return, and the success
//! rate on tasks that have one. A table, or JSON with `--json`.
//!
//! `--env-options` changes some of the run's options for the replay (`substeps = 50` plays the
//! policy integrated 10× finer than a 5-substep robot trained: issue 32's learned-policy check).
//!
//! Episodes use the re-evaluation seeds `selkd experiment report` uses (`fresh_seed`), none of
//! which any in-run evaluation played, unless `--seed S` asks for `S, S + 1, …`.

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use selkd_learner::checkpoint::load_actor;
use selkd_learner::config::Config;
use selkd_policy::evaluation::{evaluate, fresh_seed, Evaluation};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A run directory (its latest checkpoint) or a checkpoint directory (RUN/checkpoints/NAME).
    path: PathBuf,
    /// Which actor: `best` (by the checkpoint's ranking), `all`, or an index.
    #[arg(long, default_value = "best")]
    actor: String,
    /// Episodes per actor.
    #[arg(long, default_value_t = 10)]
    episodes: usize,
    /// Play seeds S, S + 1, … (default: the fresh re-evaluation seeds no training run played).
    #[arg(long)]
    seed: Option<u64>,
    /// Replace some of the run's `[env_options]` for these episodes, as JSON (`{"substeps": 50}`)
    /// or TOML (`substeps = 50`); the run's other options stay.
    #[arg(long)]
    env_options: Option<String>,
    /// JSON on stdout instead of a table.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Which {
    Best,
    All,
    One(usize),
}

fn parse_actor(s: &str) -> Result<Which> {
    match s {
        "best" => Ok(Which::Best),
        "all" => Ok(Which::All),
        _ => s
            .parse()
            .map(Which::One)
            .map_err(|_| anyhow!("--actor {s}: expected best, all or an actor index (0, 1, …)")),
    }
}

/// The checkpoint directory `path` names, and the run's config.
pub(crate) fn locate(path: &Path) -> Result<(PathBuf, Config)> {
    if path.is_file() {
        bail!(
            "{}: a bare file carries no env or config; pass its checkpoint directory (RUN/checkpoints/NAME) or the run directory",
            path.display()
        );
    }
    if !path.exists() {
        bail!("{}: no such run or checkpoint directory", path.display());
    }
    let checkpoint = if path.join("state.json").exists() {
        path.to_path_buf()
    } else if path.join("config.toml").exists() {
        latest_checkpoint(path).ok_or_else(|| {
            anyhow!(
                "{}: the run has no checkpoint yet (no checkpoints/latest or checkpoints/final); let it write one (run.checkpoint_every) or wait for it to finish",
                path.display()
            )
        })?
    } else {
        bail!(
            "{}: neither a run directory (config.toml) nor a checkpoint directory (state.json)",
            path.display()
        );
    };
    let state = checkpoint.join("state.json");
    let text =
        std::fs::read_to_string(&state).with_context(|| format!("reading {}", state.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", state.display()))?;
    let cfg: Config = serde_json::from_value(value["config"].clone())
        .with_context(|| format!("reading the config in {}", state.display()))?;
    Ok((checkpoint, cfg))
}

/// The checkpoint a run's `checkpoints/latest` names, else its `final`; `None` before the run
/// has written one. (`selkd render --run` uses it too.)
pub(crate) fn latest_checkpoint(run: &Path) -> Option<PathBuf> {
    let dir = run.join("checkpoints");
    let named = std::fs::read_to_string(dir.join("latest"))
        .ok()
        .map(|n| dir.join(n.trim()));
    named
        .into_iter()
        .chain([dir.join("final")])
        .find(|c| c.join("state.json").exists() && c.join("model.safetensors").exists())
}

/// One actor's episodes.
struct ActorResult {
    actor: usize,
    evaluation: Evaluation,
}

/// Sample standard deviation (n − 1), NaN for fewer than two values: what the reports use.
fn sample_std(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return f64::NAN;
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

pub fn run(args: EvalArgs) -> Result<()> {
    // Every error is one line that says what to change.
    run_inner(args).map_err(|e| anyhow!("{}", format!("{e:#}").replace('\n', " ")))
}

fn run_inner(args: EvalArgs) -> Result<()> {
    let which = parse_actor(&args.actor)?;
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let (checkpoint, mut cfg) = locate(&args.path)?;
    if let Some(text) = &args.env_options {
        let changed = crate::render::parse_env_options(text)?;
        cfg.env_options.extend(changed);
    }
    let best = load_actor(&checkpoint, None)?;
    let indices: Vec<usize> = match which {
        Which::Best => vec![best.index],
        Which::All => (0..best.actors).collect(),
        Which::One(i) => vec![i],
    };
    let seeds: Vec<u64> = (0..args.episodes as u64)
        .map(|e| {
            args.seed
                .map_or_else(|| fresh_seed(e), |s| s.wrapping_add(e))
        })
        .collect();
    let mut env = selkd_envs::make_with(&cfg.run.env, &cfg.env_options).with_context(|| {
        format!(
            "making the run's env `{}` with options `{}`",
            cfg.run.env,
            options_text(&cfg.env_options)
        )
    })?;
    let env_changes = env_changes_since_training(&checkpoint, &cfg, env.as_mut());
    if let Some(changes) = env_changes.as_ref().filter(|c| !c.is_empty()) {
        eprintln!(
            "selkd eval: note: this env is not the one the policy trained on ({})",
            changes.join("; ")
        );
    }
    let mut results = vec![];
    for &i in &indices {
        let loaded = load_actor(&checkpoint, Some(i))?;
        let layout = loaded.actor.layout();
        let spec = env.spec();
        if layout.obs_dim != spec.obs_dim || layout.act_dim != spec.act_dim {
            bail!(
                "the checkpoint's actor takes {} observations and gives {} actions, but the run's env `{}` has {} and {}",
                layout.obs_dim, layout.act_dim, spec.id, spec.obs_dim, spec.act_dim
            );
        }
        results.push(ActorResult {
            actor: i,
            evaluation: evaluate(env.as_mut(), &loaded.actor, seeds.iter().copied()),
        });
    }
    let text = if args.json {
        json(
            &checkpoint,
            &cfg,
            best.index,
            &seeds,
            &results,
            &env_changes,
        ) + "\n"
    } else {
        table(
            &checkpoint,
            &cfg,
            best.index,
            &seeds,
            args.seed.is_some(),
            &results,
        )
    };
    // A closed pipe is not worth a panic.
    let _ = std::io::stdout().lock().write_all(text.as_bytes());
    Ok(())
}

/// How `env`, evaluated here (this build's, with any `--env-options`), differs from the one the
/// checkpoint last trained on: `None` for a checkpoint from before env records. (Every episode
/// evaluated after this starts from a seeded reset, which the record's rollouts do not touch.)
fn env_changes_since_training(
    checkpoint: &Path,
    cfg: &Config,
    env: &mut dyn selkd_envs::Env,
) -> Option<Vec<String>> {
    let state = selkd_learner::checkpoint::check_complete(checkpoint).ok()?;
    let trained = &state.env.last()?.record;
    let now = selkd_envs::EnvRecord::of_env(&cfg.run.env, &cfg.env_options, env);
    Some(trained.differences(&now))
}

/// A run's `[env_options]` on one line: `g = 9.0, substeps = 50`.
fn options_text(options: &selkd_envs::EnvOptions) -> String {
    options
        .iter()
        .map(|(k, v)| format!("{k} = {v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn finite(v: f64) -> serde_json::Value {
    if v.is_finite() {
        v.into()
    } else {
        serde_json::Value::Null
    }
}

fn json(
    checkpoint: &Path,
    cfg: &Config,
    best: usize,
    seeds: &[u64],
    results: &[ActorResult],
    env_changes: &Option<Vec<String>>,
) -> String {
    let actors: Vec<serde_json::Value> = results
        .iter()
        .map(|r| {
            let e = &r.evaluation;
            serde_json::json!({
                "actor": r.actor,
                "best": r.actor == best,
                "mean_return": finite(e.mean_return()),
                "std_return": finite(sample_std(&e.returns)),
                "success_rate": finite(e.success_rate()),
                "mean_length": finite(e.mean_length()),
                "returns": e.returns,
                "successes": e.successes,
                "lengths": e.lengths,
            })
        })
        .collect();
    serde_json::json!({
        "checkpoint": checkpoint.display().to_string(),
        "env": cfg.run.env,
        "env_options": cfg.env_options,
        // What differs from the env the policy trained on (empty: nothing; null: not recorded).
        "env_changes_since_training": env_changes,
        "episodes": seeds.len(),
        "seeds": seeds,
        "best": best,
        "actors": actors,
    })
    .to_string()
}

fn table(
    checkpoint: &Path,
    cfg: &Config,
    best: usize,
    seeds: &[u64],
    own_seeds: bool,
    results: &[ActorResult],
) -> String {
    let with_success = results
        .iter()
        .any(|r| r.evaluation.success_rate().is_finite());
    let options = options_text(&cfg.env_options);
    let mut out = format!(
        "{}: env {}{}, {} deterministic episode{} per actor ({})\n",
        checkpoint.display(),
        cfg.run.env,
        if options.is_empty() {
            String::new()
        } else {
            format!(" ({options})")
        },
        seeds.len(),
        if seeds.len() == 1 { "" } else { "s" },
        if own_seeds {
            format!("seeds {}…", seeds[0])
        } else {
            "fresh seeds, none played in training".into()
        }
    );
    out += &format!(
        "{:<9} {:>22} {:>7}",
        "actor", "return (mean ± std)", "length"
    );
    if with_success {
        out += &format!(" {:>8}", "success");
    }
    out += "\n";
    for r in results {
        let e = &r.evaluation;
        let std = sample_std(&e.returns);
        let ret = if std.is_finite() {
            format!("{:.1} ± {:.1}", e.mean_return(), std)
        } else {
            format!("{:.1}", e.mean_return())
        };
        let name = format!(
            "{}{}",
            r.actor,
            if r.actor == best { " (best)" } else { "" }
        );
        out += &format!("{name:<9} {ret:>22} {:>7.0}", e.mean_length());
        if with_success {
            out += &format!(" {:>7.0}%", 100.0 * e.success_rate());
        }
        out += "\n";
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actor_choices_parse_and_bad_ones_say_what_is_expected() {
        assert_eq!(parse_actor("best").unwrap(), Which::Best);
        assert_eq!(parse_actor("all").unwrap(), Which::All);
        assert_eq!(parse_actor("3").unwrap(), Which::One(3));
        let e = parse_actor("worst").unwrap_err().to_string();
        assert!(e.contains("best, all or an actor index"), "{e}");
    }

    /// A task with success (the assembly task) gets a success column in the table and rates in
    /// the JSON; one episode has no std (n/a in the table, null in JSON).
    #[test]
    fn success_rates_appear_for_tasks_that_have_them() {
        let cfg = Config::default();
        let results = vec![
            ActorResult {
                actor: 0,
                evaluation: Evaluation {
                    returns: vec![1.0, 3.0, 2.0, 6.0],
                    successes: vec![Some(true), Some(false), Some(true), Some(true)],
                    lengths: vec![10, 20, 30, 41],
                },
            },
            ActorResult {
                actor: 1,
                evaluation: Evaluation {
                    returns: vec![-2.0],
                    successes: vec![Some(false)],
                    lengths: vec![7],
                },
            },
        ];
        let t = table(Path::new("ck"), &cfg, 1, &[5, 6, 7, 8], true, &results);
        let rows: Vec<&str> = t.lines().collect();
        assert!(rows[1].contains("success"), "{t}");
        // Actor 0: mean 3, sample std sqrt(14/3) = 2.16, mean length 101 / 4 = 25.25, 3 of 4
        // succeeded.
        assert!(
            rows[2].starts_with("0 ")
                && rows[2].contains("3.0 ± 2.2      25 ")
                && rows[2].ends_with("75%"),
            "{t}"
        );
        assert!(
            rows[3].starts_with("1 (best)")
                && rows[3].contains("-2.0")
                && !rows[3].contains('±')
                && rows[3].ends_with("0%"),
            "{t}"
        );
        let j: serde_json::Value = serde_json::from_str(&json(
            Path::new("ck"),
            &cfg,
            1,
            &[5, 6, 7, 8],
            &results,
            &None,
        ))
        .unwrap();
        assert_eq!(j["actors"][0]["success_rate"], 0.75);
        assert!(j["actors"][1]["std_return"].is_null());
        assert_eq!(j["actors"][1]["best"], true);
        assert_eq!(j["actors"][0]["successes"][1], false);
        assert_eq!(j["actors"][0]["mean_length"], 25.25);
        assert_eq!(j["actors"][1]["lengths"], serde_json::json!([7]));
    }

    #[test]
    fn std_is_the_sample_one() {
        // Values 1, 2, 3, 4: mean 2.5, squared deviations 5, divisor 3.
        assert!((sample_std(&[1.0, 2.0, 3.0, 4.0]) - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert!(sample_std(&[1.0]).is_nan());
    }
}
