//! `selkd plot RUN_DIR...`: learning curves from `metrics.csv` as an SVG.
//!
//! One run: every actor's evaluation return per epoch, and in bold the actor the ranking picked
//! at each epoch (the `best` column). Several runs (e.g. seeds): the mean over runs of the ranked
//! actor's return with a ±½ sample-standard-deviation band, as the paper draws its curves. Runs
//! are lined up on env steps (each interpolated onto one common grid, the same code as
//! `selkd experiment report`, [`crate::report::align`]), not by CSV row, and runs of different
//! envs or configs (anything but run.seed, run.threads, run.cpu_gemm, run.device, run.dir_mode) are refused,
//! naming them.
//! `--metric success` draws the evaluation success rate instead (tasks with a success criterion,
//! such as the assembly task).

use crate::report::align::Aligned;
use crate::report::figure::{colour, LineChart, Series};
pub use crate::report::runs::XAxis;
use crate::report::runs::{check_same_config, Metrics, Run};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

pub use crate::report::runs::Metric;

fn file_name(metric: Metric) -> &'static str {
    match metric {
        Metric::Return => "returns.svg",
        Metric::Success => "success.svg",
    }
}

fn read(run: &Path, metric: Metric) -> Result<Metrics> {
    let m = Metrics::read(run)?;
    if m.steps.is_empty() {
        bail!("{} has no epochs yet", run.join("metrics.csv").display());
    }
    if m.actors(metric).is_empty() || m.actors(metric).iter().flatten().all(|v| !v.is_finite()) {
        bail!(
            "{} has no {} values (for --metric success, the task must report success)",
            run.join("metrics.csv").display(),
            metric.label()
        );
    }
    Ok(m)
}

/// K of a run, from its config.toml: only the rounds axis needs it, so a lone metrics.csv can
/// still be drawn against the others.
fn actors(run: &Path, x: XAxis) -> Result<u64> {
    if x != XAxis::Rounds {
        return Ok(1);
    }
    if !run.join("config.toml").exists() {
        bail!(
            "--x rounds needs {} (its algo.actors, K: rounds = env steps / K)",
            run.join("config.toml").display()
        );
    }
    Ok(Run::load(run)?.actors)
}

pub fn run(runs: &[PathBuf], out: Option<PathBuf>, metric: Metric, x: XAxis) -> Result<PathBuf> {
    if runs.is_empty() {
        bail!("name at least one run directory");
    }
    let out = out.unwrap_or_else(|| runs[0].join(file_name(metric)));
    let y_range = (metric == Metric::Success).then_some((0.0, 1.0));
    let y_label = match metric {
        Metric::Return => "undiscounted evaluation return",
        Metric::Success => "evaluation success rate",
    };
    let chart = if runs.len() == 1 {
        let m = read(&runs[0], metric)?;
        let xs = m.xs(x, actors(&runs[0], x)?, &runs[0])?;
        let mut series: Vec<Series> = m
            .actors(metric)
            .iter()
            .enumerate()
            .map(|(a, ys)| {
                let mut s = Series::line(
                    format!("actor {a}"),
                    xs.iter().copied().zip(ys.iter().copied()).collect(),
                    colour(a),
                );
                s.width = 1.2;
                s
            })
            .collect();
        let label = if m.best.is_some() {
            "ranked actor (the ranking's pick per epoch)"
        } else {
            "best actor (highest evaluation per epoch)"
        };
        let mut best = Series::line(
            label,
            xs.iter().copied().zip(m.ranked(metric)).collect(),
            "#000".into(),
        );
        best.width = 3.0;
        series.push(best);
        LineChart {
            title: format!("{}: {} per actor", runs[0].display(), metric.label()),
            x_label: x.label().into(),
            y_label: y_label.into(),
            series,
            y_range,
            from_zero: false,
        }
    } else {
        let loaded = runs
            .iter()
            .map(|r| {
                read(r, metric)?;
                Run::load(r)
            })
            .collect::<Result<Vec<_>>>()?;
        let refs: Vec<&Run> = loaded.iter().collect();
        check_same_config(&refs)?;
        let ranked: Vec<Vec<f64>> = loaded.iter().map(|r| r.metrics.ranked(metric)).collect();
        let xs = loaded.iter().map(|r| r.xs(x)).collect::<Result<Vec<_>>>()?;
        let curves: Vec<(&[f64], &[f64])> = xs
            .iter()
            .zip(&ranked)
            .map(|(xs, y)| (&xs[..], &y[..]))
            .collect();
        let a =
            Aligned::new(&curves).with_context(|| format!("lining the runs up on {}", x.name()))?;
        let (mean, sd) = (a.mean(), a.std());
        let mut s = Series::line(
            format!(
                "ranked actor, mean of {} runs (band ± ½ sample std), aligned on {}",
                runs.len(),
                x.name()
            ),
            a.grid.iter().copied().zip(mean.iter().copied()).collect(),
            colour(0),
        );
        s.width = 2.5;
        s.band = Some(
            a.grid
                .iter()
                .zip(mean.iter().zip(&sd))
                .map(|(x, (m, s))| (*x, m - s / 2.0, m + s / 2.0))
                .collect(),
        );
        LineChart {
            title: format!(
                "{} runs of {}: {} of the ranked actor",
                runs.len(),
                loaded[0].env,
                metric.label()
            ),
            x_label: format!("{}; budget {}", x.label(), loaded[0].budget_text()),
            y_label: y_label.into(),
            series: vec![s],
            y_range,
            from_zero: false,
        }
    };
    std::fs::write(&out, chart.svg()).with_context(|| format!("writing {}", out.display()))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_dir(name: &str, metrics: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("selkd-plot-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("metrics.csv"), metrics).unwrap();
        dir
    }

    #[test]
    fn success_curves_come_from_the_success_columns() {
        let dir = run_dir(
            "success",
            "epoch,env_steps,eval_return_0,eval_return_1,eval_success_0,eval_success_1\n\
             1,1000,-50.0,-40.0,0.0,0.1\n\
             2,2000,-20.0,-30.0,0.4,0.7\n",
        );
        let out = run(
            std::slice::from_ref(&dir),
            None,
            Metric::Success,
            XAxis::EnvSteps,
        )
        .unwrap();
        assert_eq!(out, dir.join("success.svg"));
        let svg = std::fs::read_to_string(&out).unwrap();
        assert!(svg.contains("evaluation success rate per actor"));
        assert_eq!(
            svg.matches("<polyline").count(),
            3,
            "two actors and the best"
        );
        // Rates are drawn on [0, 1] with round ticks.
        assert!(svg.contains(">0.2<") && svg.contains(">1.0<"), "{svg}");
        let returns = std::fs::read_to_string(
            run(
                std::slice::from_ref(&dir),
                None,
                Metric::Return,
                XAxis::EnvSteps,
            )
            .unwrap(),
        );
        assert!(returns.unwrap().contains("evaluation return per actor"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Returns such as -1234.5 … -151.2 get ticks at round values (multiples of 1, 2 or 5 × 10^k)
    /// and every legend entry lies inside the picture.
    #[test]
    fn return_ticks_are_round_and_the_legend_is_inside_the_picture() {
        let dir = run_dir(
            "ticks",
            "epoch,env_steps,best,eval_return_0,eval_return_1,eval_return_2\n\
             1,1000,0,-1234.5,-1311.7,-1290.2\n\
             2,2000,2,-801.3,-977.9,-655.0\n\
             3,3000,2,-402.8,-530.1,-151.2\n",
        );
        let svg = std::fs::read_to_string(
            run(
                std::slice::from_ref(&dir),
                None,
                Metric::Return,
                XAxis::EnvSteps,
            )
            .unwrap(),
        )
        .unwrap();
        let attr = |line: &str, name: &str| -> f64 {
            let at = line.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
            line[at..].split('"').next().unwrap().parse().unwrap()
        };
        // Y tick labels: right-aligned texts left of the plot area.
        let ticks: Vec<f64> = svg
            .lines()
            .filter(|l| l.contains(r#"text-anchor="end">"#))
            .map(|l| {
                l.rsplit("\">")
                    .next()
                    .unwrap()
                    .trim_end_matches("</text>")
                    .parse()
                    .unwrap()
            })
            .collect();
        assert!(ticks.len() >= 4, "{ticks:?}");
        let step = (ticks[1] - ticks[0]).abs();
        let mantissa = step / 10f64.powf(step.log10().floor());
        assert!(
            [1.0, 2.0, 5.0].iter().any(|m| (m - mantissa).abs() < 1e-9),
            "step {step}"
        );
        for t in &ticks {
            assert!(
                (t / step - (t / step).round()).abs() < 1e-9,
                "{t} is not a multiple of {step}"
            );
        }
        assert!(ticks.iter().cloned().fold(f64::MAX, f64::min) <= -1311.7);
        assert!(ticks.iter().cloned().fold(f64::MIN, f64::max) >= -151.2);
        // The legend: one entry per actor plus the ranked actor, all within the picture's height.
        let height = attr(svg.lines().next().unwrap(), "height");
        let legend: Vec<f64> = svg
            .lines()
            .filter(|l| l.starts_with("<line") && l.contains("<text") && !l.contains("text-anchor"))
            .map(|l| attr(l, "y1"))
            .collect();
        assert_eq!(legend.len(), 4, "{svg}");
        assert!(
            legend.iter().all(|&y| y > 0.0 && y + 10.0 <= height),
            "{legend:?} in {height}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_task_without_success_says_so() {
        let dir = run_dir(
            "nosuccess",
            "epoch,env_steps,eval_return_0,eval_success_0\n1,1000,-50.0,NaN\n",
        );
        let e = run(
            std::slice::from_ref(&dir),
            None,
            Metric::Success,
            XAxis::EnvSteps,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("must report success"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[cfg(test)]
mod aligned {
    use super::*;
    use crate::report::runs::tests::{config, fake_run};

    #[test]
    fn plot_refuses_runs_of_different_envs_and_aligns_runs_of_different_lengths() {
        let d = std::env::temp_dir().join(format!("selkd-plot-align-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        // Seed 1 evaluates every 500 env steps, seed 2 every 1000.
        fake_run(&d.join("a"), &config("pendulum", 1, 2),
            "epoch,env_steps,best,eval_return_0,eval_return_1\n1,500,0,-400,-900\n2,1000,0,-300,-900\n3,1500,1,-900,-200\n4,2000,1,-900,-100\n", None);
        fake_run(&d.join("b"), &config("pendulum", 2, 2),
            "epoch,env_steps,best,eval_return_0,eval_return_1\n1,1000,1,-900,-500\n2,2000,1,-900,-100\n", None);
        fake_run(
            &d.join("c"),
            &config("hopper", 3, 2),
            "epoch,env_steps,best,eval_return_0,eval_return_1\n1,1000,1,-900,-500\n",
            None,
        );
        let e = run(
            &[d.join("a"), d.join("c")],
            None,
            Metric::Return,
            XAxis::EnvSteps,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("different envs") && e.contains("a (pendulum)") && e.contains("c (hopper)"),
            "{e}"
        );
        let out = run(
            &[d.join("a"), d.join("b")],
            Some(d.join("x.svg")),
            Metric::Return,
            XAxis::EnvSteps,
        )
        .unwrap();
        let svg = std::fs::read_to_string(out).unwrap();
        // Common range [1000, 2000] on a's 500-step grid: 1000, 1500, 2000 (b interpolated to
        // -300 at 1500); pairing by CSV row would have given two points, a's 500 with b's 1000.
        let line = svg.lines().find(|l| l.starts_with("<polyline")).unwrap();
        assert_eq!(line.matches(',').count(), 3, "{line}");
        assert!(svg.contains("mean of 2 runs"), "{svg}");
        // Against rounds (K = 2): the same points at 500, 750 and 1000 rounds, and the axis
        // says so.
        let out = run(
            &[d.join("a"), d.join("b")],
            Some(d.join("r.svg")),
            Metric::Return,
            XAxis::Rounds,
        )
        .unwrap();
        let svg = std::fs::read_to_string(out).unwrap();
        assert!(
            svg.contains("rounds (each of the K actors takes one step"),
            "{svg}"
        );
        assert!(
            svg.contains("budget 2000 env steps = 1000 rounds of K = 2"),
            "{svg}"
        );
        // The x axis ends at 1 000 rounds (against env steps it would be 2 000, "2.0k").
        assert_eq!(
            x_ticks(&svg).last().map(String::as_str),
            Some("1000"),
            "{:?}",
            x_ticks(&svg)
        );
        // These metrics.csv files have no critic_updates column: a one-line error naming it.
        let e = run(
            &[d.join("a"), d.join("b")],
            Some(d.join("u.svg")),
            Metric::Return,
            XAxis::CriticUpdates,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("no critic_updates column") && !e.contains('\n'),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    /// The x axis's tick labels, left to right.
    fn x_ticks(svg: &str) -> Vec<String> {
        // A tick is a grid line and its label on one line of the SVG.
        svg.lines()
            .filter(|l| l.starts_with("<line") && l.contains(r#"text-anchor="middle">"#))
            .filter_map(|l| {
                l.rsplit("\">")
                    .next()?
                    .strip_suffix("</text>")
                    .map(str::to_string)
            })
            .collect()
    }

    /// One run against each axis: its points' x come from env_steps / K, critic_updates and
    /// wall_s (values picked by hand).
    #[test]
    fn one_run_is_drawn_against_each_axis_from_its_own_columns() {
        let d = std::env::temp_dir().join(format!("selkd-plot-axes-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        fake_run(&d, &config("pendulum", 1, 4),
            "epoch,env_steps,wall_s,critic_updates,best,eval_return_0\n1,4000,30.5,600,0,-400\n2,8000,61.0,1200,0,-300\n", None);
        let m = Metrics::read(&d).unwrap();
        assert_eq!(m.xs(XAxis::Rounds, 4, &d).unwrap(), vec![1000.0, 2000.0]);
        assert_eq!(
            m.xs(XAxis::CriticUpdates, 4, &d).unwrap(),
            vec![600.0, 1200.0]
        );
        assert_eq!(m.xs(XAxis::WallClock, 4, &d).unwrap(), vec![30.5, 61.0]);
        for (x, label, last) in [
            (XAxis::EnvSteps, "env steps (transitions", "8k"),
            (XAxis::Rounds, "rounds (each", "2000"),
            (XAxis::CriticUpdates, "critic updates", "1200"),
            (XAxis::WallClock, "wall-clock seconds", "70"),
        ] {
            let svg = std::fs::read_to_string(
                run(
                    std::slice::from_ref(&d),
                    Some(d.join("p.svg")),
                    Metric::Return,
                    x,
                )
                .unwrap(),
            )
            .unwrap();
            assert!(svg.contains(label), "{x:?}: {svg}");
            assert_eq!(
                x_ticks(&svg).last().map(String::as_str),
                Some(last),
                "{x:?}: {:?}",
                x_ticks(&svg)
            );
        }
        let _ = std::fs::remove_dir_all(&d);
    }
}
