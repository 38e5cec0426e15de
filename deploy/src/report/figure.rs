//! Charts as SVG, written by hand (the pictures are simple), and their PNG through resvg.
//!
//! Readability rules every chart follows: labelled axes, tick values that are round (1, 2 or
//! 5 × 10^k, written with k/M for thousands/millions), rates drawn on [0, 1], and the legend
//! below the plot area, one entry a row, so that it always lies inside the picture whatever the
//! labels' lengths. Text is DejaVu Sans, embedded in the binary for the PNG (a CI machine may
//! have no system fonts); an SVG viewer falls back to any sans-serif.

use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Colours by method index (matplotlib's tab10), the same method the same colour in every figure.
pub const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
    "#bcbd22", "#17becf",
];

pub fn colour(i: usize) -> String {
    PALETTE[i % PALETTE.len()].to_string()
}

/// One line of a chart.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    /// A shaded band `(x, low, high)`, e.g. mean ± ½ std.
    pub band: Option<Vec<(f64, f64, f64)>>,
    pub colour: String,
    pub width: f64,
    pub dashed: bool,
}

impl Series {
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>, colour: String) -> Series {
        Series {
            label: label.into(),
            points,
            band: None,
            colour,
            width: 2.0,
            dashed: false,
        }
    }
}

pub struct LineChart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// A fixed y range (rates: `(0, 1)`); otherwise from the data, widened to round ticks.
    pub y_range: Option<(f64, f64)>,
    /// The y axis starts at 0 (a spread, which cannot be negative).
    pub from_zero: bool,
}

pub struct BarChart {
    pub title: String,
    pub y_label: String,
    /// `(label, value, colour)`; a NaN value is drawn as "n/a".
    pub bars: Vec<(String, f64, String)>,
}

const W: f64 = 900.0;
const PLOT_H: f64 = 420.0;
const LEFT: f64 = 90.0;
const RIGHT: f64 = 30.0;
const TOP: f64 = 46.0;
const ROW: f64 = 20.0;

/// A round step (1, 2 or 5 × 10^k) giving about `target` intervals over `span`.
pub fn nice_step(span: f64, target: usize) -> f64 {
    let raw = (span / target as f64).max(1e-12);
    let mag = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw * (1.0 - 1e-9))
        .unwrap_or(10.0 * mag)
}

/// `(low, high, step)`: the range widened to multiples of a round step.
pub fn nice_range(lo: f64, hi: f64, target: usize) -> (f64, f64, f64) {
    let (lo, hi) = if hi - lo < 1e-12 {
        (lo - 1.0, hi + 1.0)
    } else {
        (lo, hi)
    };
    let step = nice_step(hi - lo, target);
    (
        // The tolerance snaps a value a rounding error off a multiple onto it, not past it.
        (lo / step + 1e-9).floor() * step,
        (hi / step - 1e-9).ceil() * step,
        step,
    )
}

/// A tick value with as many decimals as its step needs, thousands as k and millions as M.
pub fn tick_label(v: f64, step: f64) -> String {
    let (div, suffix) = if step >= 1e6 - 0.5 || (v.abs() >= 1e6 && step >= 1e5) {
        (1e6, "M")
    } else if step >= 1e3 - 0.5 || (v.abs() >= 1e4 && step >= 100.0) {
        (1e3, "k")
    } else {
        (1.0, "")
    };
    let s = step / div;
    let decimals = if s >= 1.0 {
        0
    } else {
        (-s.log10().floor()) as usize
    };
    let v = v / div;
    // -0 prints as 0.
    let v = if v.abs() < s * 1e-6 { 0.0 } else { v };
    format!("{v:.decimals$}{suffix}")
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// At most this many characters a line of the x-axis label: about 840 px of DejaVu Sans at 14 px,
/// the width a line centred on the plot has before the image's left edge cuts it.
const LABEL_CHARS: usize = 100;
/// The distance between two lines of the x-axis label, px.
const LABEL_LINE: f64 = 18.0;

/// `text` broken into lines of at most `max` characters: between its `; `-separated clauses where
/// they fit (a method's budget stays on one line), else at spaces (a longer word stands alone).
fn wrap(text: &str, max: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let len = |s: &str| s.chars().count();
    // Appends `piece` to the last line if it fits there, else starts a line with it.
    let put = |lines: &mut Vec<String>, piece: &str| match lines.last_mut() {
        Some(l) if len(l) + 1 + len(piece) <= max => {
            l.push(' ');
            l.push_str(piece);
        }
        _ => lines.push(piece.to_string()),
    };
    for clause in text.split_inclusive("; ").map(str::trim_end) {
        if len(clause) <= max {
            put(&mut lines, clause);
        } else {
            for word in clause.split(' ') {
                put(&mut lines, word);
            }
        }
    }
    lines
}

fn header(svg: &mut String, h: f64, title: &str) {
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" viewBox="0 0 {W} {h}" font-family="DejaVu Sans, sans-serif" font-size="14">"#
    );
    let _ = writeln!(
        svg,
        r#"<rect width="{W}" height="{h}" fill="white"/><text x="{}" y="26" font-size="16" text-anchor="middle">{}</text>"#,
        W / 2.0,
        escape(title)
    );
}

/// Y axis: grid lines, tick labels, the label.
fn y_axis(svg: &mut String, y0: f64, y1: f64, step: f64, y_label: &str) {
    let sy = |y: f64| TOP + (y1 - y) / (y1 - y0) * PLOT_H;
    let n = ((y1 - y0) / step).round() as i64;
    for i in 0..=n {
        let v = y0 + i as f64 * step;
        let _ = writeln!(
            svg,
            r##"<line x1="{LEFT}" x2="{}" y1="{y:.1}" y2="{y:.1}" stroke="#ddd"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
            W - RIGHT,
            LEFT - 8.0,
            sy(v) + 5.0,
            tick_label(v, step),
            y = sy(v)
        );
    }
    let _ = writeln!(
        svg,
        r#"<text transform="translate(22,{}) rotate(-90)" text-anchor="middle">{}</text>"#,
        TOP + PLOT_H / 2.0,
        escape(y_label)
    );
    let _ = writeln!(
        svg,
        r##"<rect x="{LEFT}" y="{TOP}" width="{}" height="{PLOT_H}" fill="none" stroke="#444"/>"##,
        W - LEFT - RIGHT
    );
}

impl LineChart {
    pub fn svg(&self) -> String {
        let pts = self
            .series
            .iter()
            .flat_map(|s| {
                s.points.iter().copied().chain(
                    s.band
                        .iter()
                        .flatten()
                        .flat_map(|b| [(b.0, b.1), (b.0, b.2)]),
                )
            })
            .filter(|p| p.0.is_finite() && p.1.is_finite());
        let (mut xmax, mut ymin, mut ymax) = (f64::MIN, f64::MAX, f64::MIN);
        for (x, y) in pts {
            xmax = xmax.max(x);
            ymin = ymin.min(y);
            ymax = ymax.max(y);
        }
        if ymin > ymax {
            (xmax, ymin, ymax) = (1.0, 0.0, 1.0);
        }
        let (x0, x1, xstep) = nice_range(0.0, xmax.max(1.0), 8);
        let (y0, y1, ystep) = match self.y_range {
            Some((a, b)) => (a, b, nice_step(b - a, 5)),
            None if self.from_zero => nice_range(0.0, ymax.max(0.0), 6),
            None => nice_range(ymin, ymax, 6),
        };
        let sx = |x: f64| LEFT + (x - x0) / (x1 - x0) * (W - LEFT - RIGHT);
        let sy = |y: f64| TOP + (y1 - y) / (y1 - y0) * PLOT_H;
        // The label names every method's budget and can be long: wrapped, it pushes the legend down.
        let x_label = wrap(&self.x_label, LABEL_CHARS);
        let legend_top = TOP + PLOT_H + 64.0 + LABEL_LINE * (x_label.len() as f64 - 1.0);
        let h = legend_top + ROW * self.series.len() as f64 + 10.0;
        let mut svg = String::new();
        header(&mut svg, h, &self.title);
        y_axis(&mut svg, y0, y1, ystep, &self.y_label);
        let n = ((x1 - x0) / xstep).round() as i64;
        for i in 0..=n {
            let v = x0 + i as f64 * xstep;
            let _ = writeln!(
                svg,
                r##"<line x1="{x:.1}" x2="{x:.1}" y1="{}" y2="{}" stroke="#444"/><text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"##,
                TOP + PLOT_H,
                TOP + PLOT_H + 5.0,
                TOP + PLOT_H + 22.0,
                tick_label(v, xstep),
                x = sx(v)
            );
        }
        for (i, line) in x_label.iter().enumerate() {
            let _ = writeln!(
                svg,
                r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
                LEFT + (W - LEFT - RIGHT) / 2.0,
                TOP + PLOT_H + 46.0 + LABEL_LINE * i as f64,
                escape(line)
            );
        }
        // Clip to the plot area: a band may reach past a fixed [0, 1] range.
        let _ = writeln!(
            svg,
            r#"<clipPath id="plot"><rect x="{LEFT}" y="{TOP}" width="{}" height="{PLOT_H}"/></clipPath><g clip-path="url(#plot)">"#,
            W - LEFT - RIGHT
        );
        for s in &self.series {
            if let Some(band) = &s.band {
                let band: Vec<_> = band
                    .iter()
                    .filter(|b| b.1.is_finite() && b.2.is_finite())
                    .collect();
                if band.len() >= 2 {
                    let up: Vec<String> = band
                        .iter()
                        .map(|b| format!("{:.1},{:.1}", sx(b.0), sy(b.2)))
                        .collect();
                    let down: Vec<String> = band
                        .iter()
                        .rev()
                        .map(|b| format!("{:.1},{:.1}", sx(b.0), sy(b.1)))
                        .collect();
                    let _ = writeln!(
                        svg,
                        r#"<polygon points="{} {}" fill="{}" fill-opacity="0.2"/>"#,
                        up.join(" "),
                        down.join(" "),
                        s.colour
                    );
                }
            }
        }
        for s in &self.series {
            let p: Vec<String> = s
                .points
                .iter()
                .filter(|p| p.1.is_finite())
                .map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1)))
                .collect();
            let dash = if s.dashed {
                r#" stroke-dasharray="8 5""#
            } else {
                ""
            };
            let _ = writeln!(
                svg,
                r#"<polyline points="{}" fill="none" stroke="{}" stroke-width="{}"{dash}/>"#,
                p.join(" "),
                s.colour,
                s.width
            );
            if p.len() == 1 {
                // A single point draws no line: mark it.
                let (x, y) = p[0].split_once(',').unwrap();
                let _ = writeln!(
                    svg,
                    r#"<circle cx="{x}" cy="{y}" r="4" fill="{}"/>"#,
                    s.colour
                );
            }
        }
        let _ = writeln!(svg, "</g>");
        for (i, s) in self.series.iter().enumerate() {
            let y = legend_top + ROW * i as f64;
            let dash = if s.dashed {
                r#" stroke-dasharray="8 5""#
            } else {
                ""
            };
            let _ = writeln!(
                svg,
                r#"<line x1="{LEFT}" x2="{}" y1="{y}" y2="{y}" stroke="{}" stroke-width="{}"{dash}/><text x="{}" y="{}">{}</text>"#,
                LEFT + 36.0,
                s.colour,
                s.width,
                LEFT + 44.0,
                y + 5.0,
                escape(&s.label)
            );
        }
        svg.push_str("</svg>\n");
        svg
    }
}

impl BarChart {
    pub fn svg(&self) -> String {
        let vals = self.bars.iter().map(|b| b.1).filter(|v| v.is_finite());
        let ymax = vals.fold(0.0f64, f64::max);
        let (y0, y1, ystep) = nice_range(0.0, if ymax > 0.0 { ymax } else { 1.0 }, 5);
        let sy = |y: f64| TOP + (y1 - y) / (y1 - y0) * PLOT_H;
        let legend_top = TOP + PLOT_H + 30.0;
        let h = legend_top + ROW * self.bars.len() as f64 + 10.0;
        let mut svg = String::new();
        header(&mut svg, h, &self.title);
        y_axis(&mut svg, y0, y1, ystep, &self.y_label);
        let slot = (W - LEFT - RIGHT) / self.bars.len().max(1) as f64;
        for (i, (label, v, colour)) in self.bars.iter().enumerate() {
            let x = LEFT + slot * (i as f64 + 0.2);
            if v.is_finite() {
                let _ = writeln!(
                    svg,
                    r#"<rect x="{x:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{colour}"/>"#,
                    sy(*v),
                    slot * 0.6,
                    sy(0.0) - sy(*v)
                );
            }
            // About three significant digits: 152.7, 3.14, 0.123.
            let text = match v.abs() {
                a if !a.is_finite() => "n/a".to_string(),
                a if a >= 100.0 => format!("{v:.1}"),
                a if a >= 1.0 => format!("{v:.2}"),
                _ => format!("{v:.3}"),
            };
            let ty = if v.is_finite() {
                sy(*v) - 6.0
            } else {
                sy(0.0) - 6.0
            };
            let _ = writeln!(
                svg,
                r#"<text x="{:.1}" y="{ty:.1}" text-anchor="middle">{text}</text>"#,
                x + slot * 0.3
            );
            let y = legend_top + ROW * i as f64;
            let _ = writeln!(
                svg,
                r#"<rect x="{LEFT}" y="{}" width="28" height="12" fill="{colour}"/><text x="{}" y="{}">{}</text>"#,
                y - 6.0,
                LEFT + 40.0,
                y + 5.0,
                escape(label)
            );
        }
        svg.push_str("</svg>\n");
        svg
    }
}

/// DejaVu Sans (Bitstream Vera license, `deploy/assets/DejaVuSans-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// The SVG rasterised at its own size.
pub fn png(svg: &str) -> Result<Vec<u8>> {
    let mut opt = resvg::usvg::Options::default();
    opt.fontdb_mut().load_font_data(FONT.to_vec());
    opt.font_family = "DejaVu Sans".into();
    let tree = resvg::usvg::Tree::from_str(svg, &opt).context("parsing the SVG for the PNG")?;
    let size = tree.size().to_int_size();
    let mut pixmap =
        resvg::tiny_skia::Pixmap::new(size.width(), size.height()).context("allocating the PNG")?;
    resvg::render(
        &tree,
        resvg::tiny_skia::Transform::identity(),
        &mut pixmap.as_mut(),
    );
    pixmap.encode_png().context("encoding the PNG")
}

/// Writes `stem.svg` and `stem.png`; returns the SVG's path.
pub fn write(svg: &str, stem: &Path) -> Result<PathBuf> {
    let (s, p) = (stem.with_extension("svg"), stem.with_extension("png"));
    std::fs::write(&s, svg).with_context(|| format!("writing {}", s.display()))?;
    std::fs::write(&p, png(svg)?).with_context(|| format!("writing {}", p.display()))?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round() {
        assert_eq!(nice_range(0.0, 2730.0, 8), (0.0, 3000.0, 500.0));
        assert_eq!(nice_range(-1423.0, -151.0, 6), (-1500.0, 0.0, 500.0));
        assert_eq!(tick_label(1500.0, 500.0), "1500");
        assert_eq!(tick_label(15000.0, 5000.0), "15k");
        assert_eq!(tick_label(300000.0, 50000.0), "300k");
        assert_eq!(tick_label(-1600.0, 200.0), "-1600");
        assert_eq!(tick_label(0.4, 0.2), "0.4");
        assert_eq!(tick_label(2.0e6, 5e5), "2.0M");
    }

    #[test]
    fn a_long_axis_label_wraps_at_spaces_and_keeps_every_word() {
        assert_eq!(wrap("ab cd ef", 5), vec!["ab cd", "ef"]);
        assert_eq!(wrap("abcdefg hi", 5), vec!["abcdefg", "hi"]);
        assert_eq!(wrap("short", 100), vec!["short"]);
        // Clauses stay whole where they fit: not "a; b c" / "d" but "a;" / "b c d".
        assert_eq!(wrap("a; b c d", 6), vec!["a;", "b c d"]);
        assert_eq!(wrap("a; b; c", 6), vec!["a; b;", "c"]);
        // The evidence report's label, 223 characters: a line per method's budget.
        let label =
            "env steps (redq: 100000 env steps = 100000 rounds of K = 1 (set in env steps); \
            sac: 100000 env steps = 100000 rounds of K = 1 (set in env steps); selkd-env-steps: \
            100000 env steps = 20000 rounds of K = 5 (set in env steps))";
        let chart = LineChart {
            title: "t".into(),
            x_label: label.into(),
            y_label: "return".into(),
            series: vec![Series::line("a", vec![(0.0, 1.0), (10.0, 2.0)], colour(0))],
            y_range: None,
            from_zero: false,
        };
        let svg = chart.svg();
        let lines = wrap(label, LABEL_CHARS);
        assert_eq!(
            lines,
            vec![
                "env steps (redq: 100000 env steps = 100000 rounds of K = 1 (set in env steps);",
                "sac: 100000 env steps = 100000 rounds of K = 1 (set in env steps);",
                "selkd-env-steps: 100000 env steps = 20000 rounds of K = 5 (set in env steps))"
            ]
        );
        assert_eq!(lines.join(" "), label);
        for l in &lines {
            assert!(l.chars().count() <= LABEL_CHARS, "{l}");
            assert!(
                svg.contains(&format!(">{l}</text>")),
                "{l} is not a line of {svg}"
            );
        }
    }

    #[test]
    fn a_chart_rasterises_with_text() {
        let chart = LineChart {
            title: "t".into(),
            x_label: "env steps".into(),
            y_label: "return".into(),
            series: vec![Series::line("a", vec![(0.0, 1.0), (10.0, 2.0)], colour(0))],
            y_range: None,
            from_zero: false,
        };
        let png = png(&chart.svg()).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
