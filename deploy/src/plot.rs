//! `selkd plot RUN_DIR...`: learning curves from `metrics.csv` as an SVG (no plotting library:
//! the picture is simple enough to write by hand, and an SVG opens in any browser).
//!
//! One run: every actor's evaluation return per epoch, the best of them in bold. Several runs
//! (e.g. seeds): the mean over runs of the best actor's return, with a ±½ standard-deviation band,
//! as the paper draws its curves. `--metric success` draws the evaluation success rate instead
//! (tasks with a success criterion, such as the assembly task).

use anyhow::{bail, Context, Result};
use std::fmt::Write as _;
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
    fn column_prefix(self) -> &'static str {
        match self {
            Metric::Return => "eval_return_",
            Metric::Success => "eval_success_",
        }
    }
    fn label(self) -> &'static str {
        match self {
            Metric::Return => "evaluation return",
            Metric::Success => "evaluation success rate",
        }
    }
    fn file_name(self) -> &'static str {
        match self {
            Metric::Return => "returns.svg",
            Metric::Success => "success.svg",
        }
    }
}

struct Curve {
    steps: Vec<f64>,
    /// `[actor][epoch]`
    actors: Vec<Vec<f64>>,
}

fn read(run: &Path, metric: Metric) -> Result<Curve> {
    let path = run.join("metrics.csv");
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!(
            "reading {} (is {} a run directory?)",
            path.display(),
            run.display()
        )
    })?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .context("metrics.csv is empty")?
        .split(',')
        .collect();
    let steps_col = header
        .iter()
        .position(|h| *h == "env_steps")
        .context("metrics.csv has no env_steps column")?;
    let eval_cols: Vec<usize> = header
        .iter()
        .enumerate()
        .filter(|(_, h)| h.starts_with(metric.column_prefix()))
        .map(|(i, _)| i)
        .collect();
    if eval_cols.is_empty() {
        bail!(
            "{} has no {}* columns (written by an older selkd?)",
            path.display(),
            metric.column_prefix()
        );
    }
    let mut c = Curve {
        steps: Vec::new(),
        actors: vec![Vec::new(); eval_cols.len()],
    };
    for l in lines {
        let v: Vec<f64> = l
            .split(',')
            .map(|x| x.parse().unwrap_or(f64::NAN))
            .collect();
        c.steps.push(v[steps_col]);
        for (a, &col) in eval_cols.iter().enumerate() {
            c.actors[a].push(v[col]);
        }
    }
    if c.steps.is_empty() {
        bail!("{} has no epochs yet", path.display());
    }
    if c.actors.iter().flatten().all(|v| !v.is_finite()) {
        bail!(
            "{} has no {} values (for --metric success, the task must report success)",
            path.display(),
            metric.label()
        );
    }
    Ok(c)
}

fn best(c: &Curve) -> Vec<f64> {
    (0..c.steps.len())
        .map(|e| {
            c.actors
                .iter()
                .map(|a| a[e])
                .filter(|v| v.is_finite())
                .fold(f64::NAN, f64::max)
        })
        .collect()
}

pub fn run(runs: &[PathBuf], out: Option<PathBuf>, metric: Metric) -> Result<PathBuf> {
    if runs.is_empty() {
        bail!("name at least one run directory");
    }
    let curves = runs
        .iter()
        .map(|r| read(r, metric))
        .collect::<Result<Vec<_>>>()?;
    let out = out.unwrap_or_else(|| runs[0].join(metric.file_name()));
    // Series: (points, stroke width, colour) and an optional band.
    let palette = [
        "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
        "#bcbd22", "#17becf",
    ];
    // (points, stroke width, colour, legend label)
    type Line = (Vec<(f64, f64)>, f64, String, String);
    let mut lines: Vec<Line> = Vec::new();
    let mut band: Vec<(f64, f64, f64)> = Vec::new();
    let title = if curves.len() == 1 {
        let c = &curves[0];
        for (a, ys) in c.actors.iter().enumerate() {
            lines.push((
                c.steps.iter().copied().zip(ys.iter().copied()).collect(),
                1.2,
                palette[a % palette.len()].into(),
                format!("actor {a}"),
            ));
        }
        lines.push((
            c.steps.iter().copied().zip(best(c)).collect(),
            3.0,
            "#000".into(),
            "best actor".into(),
        ));
        format!("{}: {} per actor", runs[0].display(), metric.label())
    } else {
        let n = curves.iter().map(|c| c.steps.len()).min().unwrap();
        let mut mean_line = Vec::new();
        for e in 0..n {
            let vals: Vec<f64> = curves
                .iter()
                .map(|c| best(c)[e])
                .filter(|v| v.is_finite())
                .collect();
            let mean = vals.iter().sum::<f64>() / vals.len().max(1) as f64;
            let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
                / vals.len().max(1) as f64)
                .sqrt();
            mean_line.push((curves[0].steps[e], mean));
            band.push((curves[0].steps[e], mean - sd / 2.0, mean + sd / 2.0));
        }
        lines.push((
            mean_line,
            2.5,
            palette[0].into(),
            format!("best actor, mean of {} runs (band ±½ sd)", curves.len()),
        ));
        format!(
            "{} runs: {} of the best actor",
            curves.len(),
            metric.label()
        )
    };
    let pts = lines
        .iter()
        .flat_map(|l| l.0.iter().copied())
        .chain(band.iter().flat_map(|b| [(b.0, b.1), (b.0, b.2)]))
        .filter(|p| p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (0.0f64, f64::MIN, f64::MAX, f64::MIN);
    for (x, y) in pts {
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if y1 <= y0 {
        y0 -= 1.0;
        y1 += 1.0;
    }
    let pad = (y1 - y0) * 0.05;
    (y0, y1) = (y0 - pad, y1 + pad);
    x0 = x0.min(0.0);
    let (w, h, l, r, t, b) = (900.0, 540.0, 80.0, 220.0, 40.0, 60.0);
    let sx = |x: f64| l + (x - x0) / (x1 - x0).max(1e-9) * (w - l - r);
    let sy = |y: f64| t + (y1 - y) / (y1 - y0) * (h - t - b);
    let mut svg = String::new();
    writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="13">"#
    )?;
    writeln!(
        svg,
        r#"<rect width="100%" height="100%" fill="white"/><text x="{l}" y="24" font-size="15">{}</text>"#,
        escape(&title)
    )?;
    // Returns span hundreds; rates lie in [0, 1].
    let prec = if y1 - y0 < 10.0 { 2 } else { 0 };
    for i in 0..=5 {
        let yv = y0 + (y1 - y0) * i as f64 / 5.0;
        let xv = x0 + (x1 - x0) * i as f64 / 5.0;
        writeln!(
            svg,
            r##"<line x1="{l}" x2="{}" y1="{y}" y2="{y}" stroke="#ddd"/><text x="{}" y="{}" text-anchor="end">{yv:.prec$}</text>"##,
            w - r,
            l - 6.0,
            sy(yv) + 4.0,
            y = sy(yv)
        )?;
        writeln!(
            svg,
            r#"<text x="{}" y="{}" text-anchor="middle">{xv:.0}</text>"#,
            sx(xv),
            h - b + 18.0
        )?;
    }
    writeln!(
        svg,
        r#"<text x="{}" y="{}" text-anchor="middle">env steps (all actors together)</text>"#,
        (l + w - r) / 2.0,
        h - 14.0
    )?;
    writeln!(
        svg,
        r#"<text transform="translate(18,{}) rotate(-90)" text-anchor="middle">{}</text>"#,
        (t + h - b) / 2.0,
        match metric {
            Metric::Return => "undiscounted evaluation return",
            Metric::Success => "evaluation success rate",
        }
    )?;
    if !band.is_empty() {
        let upper: Vec<String> = band
            .iter()
            .map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.2)))
            .collect();
        let lower: Vec<String> = band
            .iter()
            .rev()
            .map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1)))
            .collect();
        writeln!(
            svg,
            r#"<polygon points="{} {}" fill="{}" fill-opacity="0.25"/>"#,
            upper.join(" "),
            lower.join(" "),
            palette[0]
        )?;
    }
    for (i, (points, width, colour, label)) in lines.iter().enumerate() {
        let p: Vec<String> = points
            .iter()
            .filter(|p| p.1.is_finite())
            .map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1)))
            .collect();
        writeln!(
            svg,
            r#"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="{width}"/>"#,
            p.join(" ")
        )?;
        let ly = t + 16.0 + 20.0 * i as f64;
        writeln!(
            svg,
            r#"<line x1="{}" x2="{}" y1="{ly}" y2="{ly}" stroke="{colour}" stroke-width="{width}"/><text x="{}" y="{}">{}</text>"#,
            w - r + 12.0,
            w - r + 36.0,
            w - r + 42.0,
            ly + 4.0,
            escape(label)
        )?;
    }
    writeln!(svg, "</svg>")?;
    std::fs::write(&out, svg).with_context(|| format!("writing {}", out.display()))?;
    Ok(out)
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
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
        let out = run(std::slice::from_ref(&dir), None, Metric::Success).unwrap();
        assert_eq!(out, dir.join("success.svg"));
        let svg = std::fs::read_to_string(&out).unwrap();
        assert!(svg.contains("evaluation success rate per actor"));
        assert_eq!(
            svg.matches("<polyline").count(),
            3,
            "two actors and the best"
        );
        // Ticks of a rate carry decimals.
        assert!(svg.contains(">0.12<"), "{svg}");
        let returns =
            std::fs::read_to_string(run(std::slice::from_ref(&dir), None, Metric::Return).unwrap());
        assert!(returns.unwrap().contains("evaluation return per actor"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_task_without_success_says_so() {
        let dir = run_dir(
            "nosuccess",
            "epoch,env_steps,eval_return_0,eval_success_0\n1,1000,-50.0,NaN\n",
        );
        let e = run(std::slice::from_ref(&dir), None, Metric::Success)
            .unwrap_err()
            .to_string();
        assert!(e.contains("must report success"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
