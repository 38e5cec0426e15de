//! `selkd experiment report DIR`: the paper's Table 2 and Figures 3–9 from the run directories
//! of an experiment (`DIR/<method>/<task>/seed-<s>/`, each an ordinary `selkd train` run),
//! written to `DIR/report.md`, `DIR/table2.csv` and `DIR/figures/` (SVG and PNG).
//!
//! - [`runs`]: reading run and experiment directories; refusing runs that must not be averaged.
//! - [`align`]: curves of several seeds lined up on env steps, mean and sample std (shared with
//!   `selkd plot`).
//! - [`fresh`]: the scores, the ranked actor re-evaluated on fresh episodes (cached per run).
//! - [`table`]: Table 2 as Markdown and CSV.
//! - [`stats`]: the exact Mann-Whitney test; [`pairwise`]: its tables over Table 2's methods.
//! - [`published`]: other papers' numbers at the same budget, set beside Table 2.
//! - [`figure`]: line and bar charts as SVG, rasterised to PNG.
//!
//! Only finished runs (the final checkpoint reached `run.total_env_steps`) are averaged; a run
//! that stopped short is named in a footnote, never averaged as if complete.

pub mod align;
pub mod figure;
pub(crate) mod fresh;
mod pairwise;
pub mod published;
pub mod runs;
pub mod stats;
mod table;

use align::{second_half_mean, Aligned};
use anyhow::{bail, Context, Result};
use clap::Args;
use figure::{colour, BarChart, LineChart, Series};
use runs::{check_same_config, Metric, Run, XAxis};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use table::Row;

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// The experiment directory (holds `<method>/<task>/seed-<s>/` run directories).
    pub dir: PathBuf,
    /// Fresh evaluation episodes per run for Table 2's scores.
    #[arg(long, default_value_t = 20)]
    pub episodes: usize,
    /// What the curves are drawn against (a `[[figure]]` with its own `x` keeps it). Other
    /// than env-steps, the report is DIR/report-<x>.md and its figures' names end in -<x>.
    #[arg(long, value_enum, default_value = "env-steps")]
    pub x: XAxis,
}

/// The runs of one method on one task.
struct Group<'a> {
    method: String,
    /// Index of the method among all methods (its colour).
    index: usize,
    finished: Vec<&'a Run>,
    short: Vec<&'a Run>,
}

/// One task's groups, and whether it is scored by success rate.
struct Task<'a> {
    name: String,
    /// Its runs' env (one per task: [`check_same_task`]).
    env: String,
    rate: bool,
    groups: Vec<Group<'a>>,
}

/// A `[[figure]]` of experiment.toml: a title and the methods to draw together.
struct FigureGroup {
    title: String,
    methods: Vec<String>,
    /// Its own x axis (`x = "rounds"`), else the report's `--x`.
    x: Option<XAxis>,
}

fn figure_groups(dir: &Path) -> Result<Vec<FigureGroup>> {
    let path = dir.join("experiment.toml");
    if !path.exists() {
        return Ok(Vec::new());
    }
    let t: toml::Table = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {}", path.display()))?
        .parse()
        .with_context(|| format!("reading {}", path.display()))?;
    let Some(figs) = t.get("figure") else {
        return Ok(Vec::new());
    };
    let figs = figs
        .as_array()
        .with_context(|| format!("{}: `figure` must be [[figure]] tables", path.display()))?;
    figs.iter()
        .enumerate()
        .map(|(i, f)| {
            let methods = f
                .get("methods")
                .and_then(|m| m.as_array())
                .with_context(|| {
                    format!(
                        "{}: [[figure]] {} has no methods = [..]",
                        path.display(),
                        i + 1
                    )
                })?
                .iter()
                .map(|m| m.as_str().map(str::to_string))
                .collect::<Option<Vec<_>>>()
                .with_context(|| {
                    format!(
                        "{}: [[figure]] {}: methods must be strings",
                        path.display(),
                        i + 1
                    )
                })?;
            let title = f
                .get("title")
                .and_then(|t| t.as_str())
                .map_or_else(|| format!("Figure {}", 6 + i), str::to_string);
            let x = match f.get("x") {
                None => None,
                Some(v) => Some(v.as_str().and_then(XAxis::parse).with_context(|| {
                    format!(
                        "{}: [[figure]] {}: x = {v} is not an axis; choose one of: {}",
                        path.display(),
                        i + 1,
                        crate::experiment::spec::X_AXES.join(", ")
                    )
                })?),
            };
            Ok(FigureGroup { title, methods, x })
        })
        .collect()
}

/// The runs `experiment.toml` names (`<method>/<task>/seed-<s>`), when the directory has one: the
/// report says which of them are not (yet) finished, so a partial table reads as partial.
fn expected_runs(dir: &Path) -> Result<Option<Vec<String>>> {
    let path = dir.join("experiment.toml");
    if !path.exists() {
        return Ok(None);
    }
    let t: toml::Table = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {}", path.display()))?
        .parse()
        .with_context(|| format!("reading {}", path.display()))?;
    let strings = |v: Option<&toml::Value>| -> Vec<String> {
        v.and_then(|v| v.as_array())
            .map(|a| {
                a.iter()
                    .filter_map(|x| {
                        x.as_str()
                            .map(str::to_string)
                            .or_else(|| x.as_integer().map(|i| i.to_string()))
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    let methods: Vec<String> = t
        .get("method")
        .and_then(|m| m.as_array())
        .map(|a| {
            a.iter()
                .filter_map(|m| m.get("name").and_then(|n| n.as_str()).map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    let (tasks, seeds) = (strings(t.get("tasks")), strings(t.get("seeds")));
    let mut ids = Vec::new();
    for seed in &seeds {
        for task in &tasks {
            for method in &methods {
                ids.push(format!("{method}/{task}/seed-{seed}"));
            }
        }
    }
    Ok((!ids.is_empty()).then_some(ids))
}

/// Refuses a task whose runs (across methods) differ in env or env options.
fn check_same_task(task: &str, runs: &[&Run]) -> Result<()> {
    let key = |r: &Run| {
        (
            r.env.clone(),
            r.config.get("env_options").map(|v| v.to_string()),
        )
    };
    if runs.iter().any(|r| key(r) != key(runs[0])) {
        let list: Vec<String> = runs
            .iter()
            .map(|r| {
                let opts = r.config.get("env_options").map_or(String::new(), |v| {
                    format!(" {}", v.to_string().replace('\n', " ").trim())
                });
                format!("{} ({}{opts})", r.dir.display(), r.env)
            })
            .collect();
        bail!("task `{task}` holds runs of different envs or env options, which cannot be compared: {}", list.join(", "));
    }
    Ok(())
}

/// Removes the figures and curve data of tasks the report no longer holds (their runs were moved
/// out of its directory): a published report's `figures/` must not keep showing runs that are
/// gone. Only the report's own kinds of file (`figN-TASK…` and `curves-TASK…`, as PNG, SVG or
/// CSV); a task still here keeps every one of its files, those of another `--x` included.
fn remove_stale_figures(figdir: &Path, tasks: &[&str]) -> Result<()> {
    let slugs: Vec<String> = tasks.iter().map(|t| slug(t)).collect();
    let listing =
        std::fs::read_dir(figdir).with_context(|| format!("reading {}", figdir.display()))?;
    for entry in listing {
        let path = entry
            .with_context(|| format!("reading {}", figdir.display()))?
            .path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        let Some(task_part) = figure_task_part(name) else {
            continue;
        };
        let current = slugs.iter().any(|s| {
            task_part
                .strip_prefix(s.as_str())
                .is_some_and(|r| r.starts_with(['-', '.']))
        });
        if !current {
            std::fs::remove_file(&path)
                .with_context(|| format!("removing the stale {}", path.display()))?;
        }
    }
    Ok(())
}

/// `name` without its `figN-` or `curves-` prefix, if it is one of the report's figure files.
fn figure_task_part(name: &str) -> Option<&str> {
    if ![".png", ".svg", ".csv"].iter().any(|e| name.ends_with(e)) {
        return None;
    }
    if let Some(rest) = name.strip_prefix("curves-") {
        return Some(rest);
    }
    let rest = name.strip_prefix("fig")?;
    let number = rest.len() - rest.trim_start_matches(|c: char| c.is_ascii_digit()).len();
    if number == 0 {
        return None;
    }
    rest[number..].strip_prefix('-')
}

fn slug(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect()
}

/// The ranked actor's curve and the actors' mean, per seed, on one grid of `x`.
fn curves(runs: &[&Run], metric: Metric, x: XAxis) -> Result<(Aligned, Aligned)> {
    let ranked: Vec<Vec<f64>> = runs.iter().map(|r| r.metrics.ranked(metric)).collect();
    let means: Vec<Vec<f64>> = runs.iter().map(|r| r.metrics.actor_mean(metric)).collect();
    let xs = runs.iter().map(|r| r.xs(x)).collect::<Result<Vec<_>>>()?;
    let pairs = |v: &[Vec<f64>]| -> Vec<(Vec<f64>, Vec<f64>)> {
        xs.iter().cloned().zip(v.iter().cloned()).collect()
    };
    let align = |p: Vec<(Vec<f64>, Vec<f64>)>| {
        let refs: Vec<(&[f64], &[f64])> = p.iter().map(|(x, y)| (&x[..], &y[..])).collect();
        Aligned::new(&refs)
    };
    let names: Vec<String> = runs.iter().map(|r| r.dir.display().to_string()).collect();
    let ctx = || format!("lining up {}", names.join(", "));
    Ok((
        align(pairs(&ranked)).with_context(ctx)?,
        align(pairs(&means)).with_context(ctx)?,
    ))
}

/// Where the second half of training begins on axis `x`, for the stability measure: half the
/// budget in env steps or rounds; on critic updates and wall-clock, which have no budget of
/// their own, half the range all seeds cover (`end`, the grid's last point).
fn half_budget(run: &Run, x: XAxis, end: f64) -> f64 {
    match x {
        XAxis::EnvSteps => run.budget as f64,
        XAxis::Rounds => run.budget as f64 / run.actors as f64,
        XAxis::CriticUpdates | XAxis::WallClock => end,
    }
}

/// A figure's file stem: `fig3-hopper` against env steps, `fig3-hopper-rounds` against rounds.
fn stem_for(stem: &str, x: XAxis) -> String {
    if x == XAxis::EnvSteps {
        stem.to_string()
    } else {
        format!("{stem}-{}", x.name())
    }
}

/// Figures 3, 4 and 5 (or a `[[figure]]` group's) for one task: returns the Markdown that links them.
fn task_figures(
    task: &Task,
    methods: Option<&[String]>,
    label: &str,
    stem: &str,
    figdir: &Path,
    x: XAxis,
) -> Result<String> {
    let stem = &stem_for(stem, x);
    let metric = if task.rate {
        Metric::Success
    } else {
        Metric::Return
    };
    let groups: Vec<&Group> = task
        .groups
        .iter()
        .filter(|g| methods.is_none_or(|m| m.contains(&g.method)))
        .filter(|g| !g.finished.is_empty())
        .collect();
    if groups.is_empty() {
        return Ok(format!(
            "{label}, `{}`: no finished run of these methods.\n\n",
            task.name
        ));
    }
    let mut lines = Vec::new();
    // Figure 3's and 4's numbers, for whoever wants to check or redraw them.
    let mut data = format!("method,{},seeds,mean,std,actors_mean\n", x.column());
    let mut stds = Vec::new();
    let mut bars = Vec::new();
    for g in &groups {
        let (ranked, mean) = curves(&g.finished, metric, x)?;
        let (m, sd) = (ranked.mean(), ranked.std());
        let n = g.finished.len();
        let seeds = if n == 1 {
            "1 seed, no std".to_string()
        } else {
            format!("{n} seeds")
        };
        let am = mean.mean();
        for (i, at) in ranked.grid.iter().enumerate() {
            // The actors' mean has its own grid only if a run lacks some actor's column; both
            // come from the same steps, so they match.
            let a = mean
                .grid
                .iter()
                .position(|g| g == at)
                .map_or(f64::NAN, |j| am[j]);
            let _ = writeln!(data, "{},{at},{n},{},{},{a}", g.method, m[i], sd[i]);
        }
        lines.push(Series {
            label: if n == 1 {
                format!("{} (1 seed)", g.method)
            } else {
                format!("{} (mean of {n} seeds, band ± ½ std)", g.method)
            },
            points: ranked.grid.iter().copied().zip(m.iter().copied()).collect(),
            band: Some(
                ranked
                    .grid
                    .iter()
                    .zip(m.iter().zip(&sd))
                    .map(|(x, (m, s))| (*x, m - s / 2.0, m + s / 2.0))
                    .collect(),
            ),
            colour: colour(g.index),
            width: 2.5,
            dashed: false,
        });
        if methods.is_none() {
            lines.push(Series {
                label: format!("{}: mean over its actors", g.method),
                points: mean.grid.iter().copied().zip(mean.mean()).collect(),
                band: None,
                colour: colour(g.index),
                width: 1.2,
                dashed: true,
            });
        }
        stds.push(Series::line(
            format!("{} ({seeds})", g.method),
            ranked
                .grid
                .iter()
                .copied()
                .zip(sd.iter().copied())
                .collect(),
            colour(g.index),
        ));
        bars.push((
            format!("{} ({seeds})", g.method),
            second_half_mean(
                &ranked.grid,
                &sd,
                half_budget(g.finished[0], x, ranked.grid.last().copied().unwrap_or(0.0)),
            ),
            colour(g.index),
        ));
    }
    let what = if task.rate { "success rate" } else { "return" };
    let y_range = task.rate.then_some((0.0, 1.0));
    // Methods with different budgets on one axis (SELKD at equal rounds beside a K = 1
    // baseline reaches K× its env steps): the axis label says so, the curves show it.
    let budgets: Vec<String> = groups
        .iter()
        .map(|g| format!("{}: {}", g.method, g.finished[0].budget_text()))
        .collect();
    let x_label = if groups.iter().all(|g| {
        g.finished[0].budget == groups[0].finished[0].budget
            && g.finished[0].actors == groups[0].finished[0].actors
    }) {
        format!(
            "{}; budget {}",
            x.label(),
            groups[0].finished[0].budget_text()
        )
    } else {
        format!("{}; budgets differ: {}", x.label(), budgets.join("; "))
    };
    let mut md = String::new();
    let curve = LineChart {
        title: format!(
            "{label}: {}, ranked actor's in-run evaluation {what}",
            task.name
        ),
        x_label: x_label.clone(),
        y_label: format!("ranked actor's in-run evaluation {what}"),
        series: lines,
        y_range,
        from_zero: false,
    };
    figure::write(&curve.svg(), &figdir.join(stem))?;
    let _ = writeln!(
        md,
        "![{label}: {}](figures/{stem}.png) ([SVG](figures/{stem}.svg))\n",
        task.name
    );
    if methods.is_none() {
        let name = stem_for(&format!("curves-{}", slug(&task.name)), x);
        let c = figdir.join(format!("{name}.csv"));
        std::fs::write(&c, &data).with_context(|| format!("writing {}", c.display()))?;
        let _ = writeln!(
            md,
            "Curve data (Figures 3 and 4, against {}): [{name}.csv](figures/{name}.csv)\n",
            x.column()
        );
        let std_chart = LineChart {
            title: format!(
                "Figure 4: {}, std across seeds of the ranked actor's {what}",
                task.name
            ),
            x_label,
            y_label: format!("sample std across seeds ({what})"),
            series: stds,
            y_range: None,
            from_zero: true,
        };
        let s4 = stem_for(&format!("fig4-{}", slug(&task.name)), x);
        figure::write(&std_chart.svg(), &figdir.join(&s4))?;
        let bar = BarChart {
            title: format!(
                "Figure 5: {}, mean std across seeds over the second half of training",
                task.name
            ),
            y_label: format!("mean sample std ({what})"),
            bars,
        };
        let s5 = stem_for(&format!("fig5-{}", slug(&task.name)), x);
        figure::write(&bar.svg(), &figdir.join(&s5))?;
        let _ = writeln!(
            md,
            "Figure 4, `{}`: ![Figure 4](figures/{s4}.png) ([SVG](figures/{s4}.svg))\n",
            task.name
        );
        let _ = writeln!(
            md,
            "Figure 5, `{}`: ![Figure 5](figures/{s5}.png) ([SVG](figures/{s5}.svg))\n",
            task.name
        );
    }
    Ok(md)
}

fn rows(
    task: &Task,
    fresh: &BTreeMap<PathBuf, fresh::FreshEval>,
    methods: Option<&[String]>,
) -> Vec<Row> {
    let metric = if task.rate {
        Metric::Success
    } else {
        Metric::Return
    };
    task.groups
        .iter()
        .filter(|g| methods.is_none_or(|m| m.contains(&g.method)))
        .map(|g| Row {
            method: g.method.clone(),
            scores: g
                .finished
                .iter()
                .map(|r| fresh[&r.dir].score(task.rate))
                .collect(),
            in_run: g
                .finished
                .iter()
                .map(|r| r.metrics.ranked(metric).last().copied().unwrap_or(f64::NAN))
                .collect(),
            late: g
                .finished
                .iter()
                .map(|r| r.metrics.late_ranked(metric, r.budget))
                .collect(),
            short: g
                .short
                .iter()
                .map(|r| (r.seed, r.env_steps(), r.budget))
                .collect(),
            budget: {
                let r = g.finished.first().or(g.short.first()).copied();
                r.map_or(
                    table::Budget {
                        env_steps: 0,
                        rounds: 0,
                        actors: 1,
                        in_rounds: false,
                    },
                    |r| table::Budget {
                        env_steps: r.budget,
                        rounds: r.budget.div_ceil(r.actors),
                        actors: r.actors,
                        in_rounds: r.budget_rounds > 0,
                    },
                )
            },
        })
        .collect()
}

/// Writes the report; returns the path of report.md.
pub fn run(args: &ReportArgs) -> Result<PathBuf> {
    let dir = &args.dir;
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let all = runs::discover(dir)?;
    if all.is_empty() {
        bail!(
            "no run directories under {} (expected {0}/<method>/<task>/seed-<s>/config.toml)",
            dir.display()
        );
    }
    if !all.iter().any(|(_, _, r)| r.finished()) {
        bail!(
            "no finished run under {} ({} runs, none whose checkpoints/final/state.json reached its run.total_env_steps)",
            dir.display(),
            all.len()
        );
    }
    let figures = figure_groups(dir)?;
    let methods: Vec<String> = {
        let mut m: Vec<String> = all.iter().map(|(m, _, _)| m.clone()).collect();
        m.dedup();
        m
    };
    let mut by_task: BTreeMap<String, BTreeMap<String, Vec<&Run>>> = BTreeMap::new();
    for (m, t, r) in &all {
        by_task
            .entry(t.clone())
            .or_default()
            .entry(m.clone())
            .or_default()
            .push(r);
    }
    let mut tasks = Vec::new();
    for (name, by_method) in &by_task {
        let every: Vec<&Run> = by_method.values().flatten().copied().collect();
        check_same_task(name, &every)?;
        let mut groups = Vec::new();
        for (method, runs) in by_method {
            check_same_config(runs).with_context(|| format!("method `{method}`, task `{name}`"))?;
            groups.push(Group {
                method: method.clone(),
                index: methods.iter().position(|m| m == method).unwrap_or(0),
                finished: runs.iter().copied().filter(|r| r.finished()).collect(),
                short: runs.iter().copied().filter(|r| !r.finished()).collect(),
            });
        }
        tasks.push(Task {
            name: name.clone(),
            env: every.first().map_or_else(String::new, |r| r.env.clone()),
            rate: every.iter().any(|r| r.metrics.has_success()),
            groups,
        });
    }
    let finished: Vec<&Run> = tasks
        .iter()
        .flat_map(|t| t.groups.iter().flat_map(|g| g.finished.iter().copied()))
        .collect();
    let evals = fresh::fresh_evals(&finished, args.episodes)?;
    let fresh: BTreeMap<PathBuf, fresh::FreshEval> =
        finished.iter().map(|r| r.dir.clone()).zip(evals).collect();

    let figdir = dir.join("figures");
    std::fs::create_dir_all(&figdir).with_context(|| format!("creating {}", figdir.display()))?;
    let names: Vec<&str> = tasks.iter().map(|t| t.name.as_str()).collect();
    remove_stale_figures(&figdir, &names)?;
    let mut md = String::new();
    let _ = writeln!(md, "# Experiment report: `{}`\n", dir.display());
    if let Some(expected) = expected_runs(dir)? {
        let done: BTreeSet<String> = all
            .iter()
            .filter(|(_, _, r)| r.finished())
            .map(|(m, t, r)| format!("{m}/{t}/seed-{}", r.seed))
            .collect();
        let missing: Vec<&String> = expected.iter().filter(|id| !done.contains(*id)).collect();
        if !missing.is_empty() {
            let _ = writeln!(
                md,
                "**Partial: {} of the experiment's {} runs are finished.** Not yet in these tables and curves: {}.\n",
                expected.len() - missing.len(),
                expected.len(),
                missing
                    .iter()
                    .map(|id| format!("`{id}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    let budgets: Vec<String> = tasks
        .iter()
        .flat_map(|t| {
            t.groups.iter().map(move |g| {
                let b = g
                    .finished
                    .first()
                    .or(g.short.first())
                    .map_or_else(String::new, |r| r.budget_text());
                format!("{} on `{}`: {b}", g.method, t.name)
            })
        })
        .collect();
    let seeds: Vec<String> = tasks
        .iter()
        .flat_map(|t| {
            t.groups.iter().map(move |g| {
                format!(
                    "{} on `{}`: {} finished{}",
                    g.method,
                    t.name,
                    g.finished.len(),
                    if g.short.is_empty() {
                        String::new()
                    } else {
                        format!(", {} short", g.short.len())
                    }
                )
            })
        })
        .collect();
    let _ = writeln!(
        md,
        "- **Budget** (`run.total_env_steps`, env steps: transitions of all actors together; or `run.total_rounds`, rounds: each of the K actors takes one step, so env steps = rounds × K; at equal env steps SELKD's actors get K× fewer updates, at equal rounds SELKD gets K× the data): {}.",
        budgets.join("; ")
    );
    let _ = writeln!(md, "- **Seeds**: {}.", seeds.join("; "));
    let _ = writeln!(md, "- **Score** (Table 2): the actor that the final checkpoint's ranking picks (the actor SELKD executes), re-evaluated with deterministic actions on **E = {} fresh episodes** (`fresh_seed(0..{})`: the same episodes for every method and seed, none played during training, so the pick's luck does not inflate the score), on the run's env and `[env_options]`. The score is the mean undiscounted return, or the success rate for tasks that report success. Each run's episodes are in `RUN/fresh_eval.json`.", args.episodes, args.episodes);
    let _ = writeln!(md, "- **Last fifth** (Table 2's last column): each seed's mean of its ranked actor's in-run evaluations at the epochs past 0.8 × its budget, then mean ± std over seeds; steadier than the final epoch alone, whose few episodes can swing a run by thousands on Hopper.");
    let _ = writeln!(md, "- **mean ± std** is over seeds; std is the **sample** standard deviation (divisor n − 1; n/a for one seed). Only finished runs (final checkpoint at the budget) are averaged; a † marks a method with runs that stopped short (footnotes give their env steps).");
    let _ = writeln!(md, "- **Curves** (Figures 3, 4, 6–9), drawn against **{}** unless a figure names its own axis: each seed's in-run evaluation of its ranked actor (the `best` column of metrics.csv picks the actor per epoch) interpolated linearly onto a common grid of that axis (every multiple of the shortest epoch length within the range all seeds cover), then mean ± ½ std over seeds; dashed: the mean over a method's actors. Figure 5: the mean, over grid points in the second half of the budget (on critic updates and wall-clock: of the range all seeds cover), of the std across seeds (the paper's stability measure; lower is more stable).", args.x.label());
    let _ = writeln!(md, "- **Pairwise tests**: under each task's Table 2, an exact two-sided Mann-Whitney test of the scores of every pair of methods with finished seeds, with the least p its seed counts allow.");
    let _ = writeln!(md, "- **Published numbers**: for Gymnasium MuJoCo tasks, other papers' returns at the same env-step budget, where one was published, cited under the table; not the same experiment as ours (Gym v4, their network sizes and update ratios).\n");
    let _ = writeln!(md, "## Table 2: final scores, at each method's budget (the budget column; the heading says when all are equal)\n");
    let (published_rows, published_notes) = published::parse(published::CSV);
    let mut csv_tasks = Vec::new();
    for t in &tasks {
        let r = rows(t, &fresh, None);
        md.push_str(&table::markdown(&t.name, &r, t.rate, args.episodes));
        md.push('\n');
        // Published returns stand beside returns only: no success rates were published.
        if !t.rate {
            let ours: Vec<(String, u64)> = r
                .iter()
                .filter(|r| r.budget.env_steps > 0)
                .map(|r| (r.method.clone(), r.budget.env_steps))
                .collect();
            md.push_str(&published::markdown(
                &t.env,
                &ours,
                &published_rows,
                &published_notes,
            ));
        }
        md.push_str(&pairwise::markdown(&r, t.rate));
        csv_tasks.push((t.name.clone(), t.rate, r));
    }
    let csv_path = dir.join("table2.csv");
    std::fs::write(&csv_path, table::csv(&csv_tasks))
        .with_context(|| format!("writing {}", csv_path.display()))?;
    let pairs_path = dir.join("pairwise.csv");
    std::fs::write(&pairs_path, pairwise::csv(&csv_tasks))
        .with_context(|| format!("writing {}", pairs_path.display()))?;
    let _ = writeln!(
        md,
        "The same numbers at full precision: [table2.csv](table2.csv); the pairwise tests: [pairwise.csv](pairwise.csv).\n"
    );
    let _ = writeln!(md, "## Figures 3–5: learning curves and stability\n");
    for t in &tasks {
        let _ = writeln!(md, "### `{}`\n", t.name);
        let stem = format!("fig3-{}", slug(&t.name));
        md.push_str(&task_figures(t, None, "Figure 3", &stem, &figdir, args.x)?);
    }
    for (i, f) in figures.iter().enumerate() {
        let n = 6 + i;
        let _ = writeln!(md, "## Figure {n}: {}\n", f.title);
        let missing: Vec<&String> = f.methods.iter().filter(|m| !methods.contains(m)).collect();
        if !missing.is_empty() {
            let _ = writeln!(
                md,
                "No runs of: {}.\n",
                missing
                    .iter()
                    .map(|m| format!("`{m}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        for t in &tasks {
            let stem = format!("fig{n}-{}", slug(&t.name));
            md.push_str(&task_figures(
                t,
                Some(&f.methods),
                &format!("Figure {n}"),
                &stem,
                &figdir,
                f.x.unwrap_or(args.x),
            )?);
            let r = rows(t, &fresh, Some(&f.methods));
            if !r.is_empty() {
                md.push_str(&table::markdown(&t.name, &r, t.rate, args.episodes));
                md.push('\n');
            }
        }
    }
    let out = dir.join(match args.x {
        XAxis::EnvSteps => "report.md".to_string(),
        x => format!("report-{}.md", x.name()),
    });
    std::fs::write(&out, md).with_context(|| format!("writing {}", out.display()))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::runs::tests::{config, fake_run, METRICS};
    use super::*;

    #[test]
    fn figures_of_tasks_no_longer_in_the_report_are_removed_and_the_rest_kept() {
        let d = std::env::temp_dir().join(format!("selkd-report-stale-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        let files = [
            "fig3-walker2d.png",
            "fig7-walker2d-rounds.svg",
            "curves-walker2d.csv",
            "fig3-ant.png",
            "fig3-hopper.png",
            "fig4-hopper-rounds.svg",
            "curves-hopper-rounds.csv",
            "fig3-ant-contacts.svg",
            "curves-gymnasium-hopper-v5.csv",
            "notes.md",
            "figure-walker2d.png",
            "fig-walker2d.png",
        ];
        for f in files {
            std::fs::write(d.join(f), "x").unwrap();
        }
        remove_stale_figures(&d, &["hopper", "ant-contacts", "gymnasium:Hopper-v5"]).unwrap();
        let mut left: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        assert_eq!(
            left,
            [
                "curves-gymnasium-hopper-v5.csv",
                "curves-hopper-rounds.csv",
                "fig-walker2d.png",
                "fig3-ant-contacts.svg",
                "fig3-hopper.png",
                "fig4-hopper-rounds.svg",
                "figure-walker2d.png",
                "notes.md",
            ]
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_directory_without_a_finished_run_is_one_line_error() {
        let d = std::env::temp_dir().join(format!("selkd-report-none-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        fake_run(
            &d.join("m/pendulum/seed-1"),
            &config("pendulum", 1, 2),
            METRICS,
            Some(1000),
        );
        let e = run(&ReportArgs {
            dir: d.clone(),
            episodes: 2,
            x: XAxis::EnvSteps,
        })
        .unwrap_err();
        let e = format!("{e:#}");
        assert!(e.contains("no finished run") && !e.contains('\n'), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    /// The report's error for `d`, as the user reads it.
    fn refusal(d: &Path) -> String {
        format!(
            "{:#}",
            run(&ReportArgs {
                dir: d.to_path_buf(),
                episodes: 2,
                x: XAxis::EnvSteps,
            })
            .unwrap_err()
        )
    }

    #[test]
    fn a_method_whose_seeds_differ_in_config_is_refused() {
        let d = std::env::temp_dir().join(format!("selkd-report-cfg-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        fake_run(
            &d.join("m/pendulum/seed-1"),
            &config("pendulum", 1, 2),
            METRICS,
            Some(2000),
        );
        fake_run(
            &d.join("m/pendulum/seed-2"),
            &config("pendulum", 2, 3),
            METRICS,
            Some(2000),
        );
        let e = refusal(&d);
        assert!(
            e.contains("different configs") && e.contains("seed-1") && e.contains("seed-2"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_task_whose_methods_ran_different_envs_is_refused() {
        let d = std::env::temp_dir().join(format!("selkd-report-env-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        fake_run(
            &d.join("a/task/seed-1"),
            &config("pendulum", 1, 2),
            METRICS,
            Some(2000),
        );
        fake_run(
            &d.join("b/task/seed-1"),
            &config("hopper", 1, 2),
            METRICS,
            Some(2000),
        );
        let e = refusal(&d);
        assert!(
            e.contains("different envs") && e.contains("(pendulum") && e.contains("(hopper"),
            "{e}"
        );
        assert!(!e.contains('\n'), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
