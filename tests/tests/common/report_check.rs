//! An independent check of `selkd experiment report`: Table 2 recomputed from each run's
//! `fresh_eval.json`, one Figure 3 point from the runs' `metrics.csv`, with plain code here.

use super::{column, metrics};
use std::path::Path;

pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Sample standard deviation (n − 1), as the report documents.
pub fn sample_std(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// The ranked actor's in-run return at env step `x`, interpolated linearly between epochs.
pub fn ranked_at(run: &Path, x: f64) -> f64 {
    let (h, rows) = metrics(run);
    let steps = column(&h, &rows, "env_steps");
    let best = column(&h, &rows, "best");
    let y: Vec<f64> = rows
        .iter()
        .zip(&best)
        .map(|(r, b)| {
            column(
                &h,
                std::slice::from_ref(r),
                &format!("eval_return_{}", *b as usize),
            )[0]
        })
        .collect();
    let i = steps.iter().rposition(|s| *s <= x).unwrap();
    if steps[i] == x {
        return y[i];
    }
    y[i] + (x - steps[i]) / (steps[i + 1] - steps[i]) * (y[i + 1] - y[i])
}

pub fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

pub fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
}

/// Checks `DIR/report.md`, `table2.csv` and `figures/curves-<task>.csv` against numbers
/// recomputed here: per method, the mean ± sample std over `seeds` of each run's mean fresh
/// return (`episodes` of them), and the curve's mean ± std at env step `at`.
pub fn check_report(
    dir: &Path,
    task: &str,
    methods: &[&str],
    seeds: &[u64],
    episodes: usize,
    at: f64,
) {
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    let table = csv_rows(&dir.join("table2.csv"));
    let curves = csv_rows(&dir.join(format!("figures/curves-{task}.csv")));
    assert!(
        md.contains(&format!("E = {episodes} fresh episodes")) && md.contains("sample"),
        "{md}"
    );
    let mut all_scores = Vec::new();
    for &m in methods {
        let runs: Vec<_> = seeds
            .iter()
            .map(|s| dir.join(format!("{m}/{task}/seed-{s}")))
            .collect();
        let scores: Vec<f64> = runs
            .iter()
            .map(|run| {
                let f: serde_json::Value = serde_json::from_str(
                    &std::fs::read_to_string(run.join("fresh_eval.json")).unwrap(),
                )
                .unwrap();
                let r: Vec<f64> = f["returns"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                assert_eq!(r.len(), episodes);
                mean(&r)
            })
            .collect();
        all_scores.push(scores.clone());
        let (sm, ss) = (mean(&scores), sample_std(&scores));
        let row = table.iter().find(|r| r[0] == task && r[1] == m).unwrap();
        assert_eq!(row[3], seeds.len().to_string());
        let (tm, ts): (f64, f64) = (row[4].parse().unwrap(), row[5].parse().unwrap());
        assert!(
            close(tm, sm) && close(ts, ss),
            "{m}: table {tm} ± {ts}, recomputed {sm} ± {ss}"
        );
        assert!(
            md.contains(&format!("{sm:.1} ± {ss:.1}")),
            "{m}: {sm:.1} ± {ss:.1} not in\n{md}"
        );
        let ys: Vec<f64> = runs.iter().map(|r| ranked_at(r, at)).collect();
        let point = curves
            .iter()
            .find(|r| r[0] == m && r[1].parse::<f64>().ok() == Some(at))
            .unwrap_or_else(|| panic!("{m}: no curve point at {at}"));
        let (pm, ps): (f64, f64) = (point[3].parse().unwrap(), point[4].parse().unwrap());
        assert!(
            close(pm, mean(&ys)) && close(ps, sample_std(&ys)),
            "{m}: curve {pm} ± {ps} vs {ys:?}"
        );
    }
    check_pairwise(dir, task, methods, &all_scores, &md);
}

/// U of `a` over `b`: pairs where a is higher, ties ½.
fn u_of(a: &[f64], b: &[f64]) -> f64 {
    let mut u = 0.0;
    for x in a {
        for y in b {
            u += if x > y {
                1.0
            } else if x == y {
                0.5
            } else {
                0.0
            };
        }
    }
    u
}

/// The exact two-sided Mann-Whitney p by listing every split of the pooled values.
fn listed_p(a: &[f64], b: &[f64]) -> f64 {
    let pooled: Vec<f64> = a.iter().chain(b).copied().collect();
    let centre = (a.len() * b.len()) as f64 / 2.0;
    let observed = (u_of(a, b) - centre).abs();
    let (mut far, mut all) = (0.0, 0.0);
    for mask in 0u32..(1 << pooled.len()) {
        if mask.count_ones() as usize != a.len() {
            continue;
        }
        let x: Vec<f64> = (0..pooled.len())
            .filter(|i| mask >> i & 1 == 1)
            .map(|i| pooled[i])
            .collect();
        let y: Vec<f64> = (0..pooled.len())
            .filter(|i| mask >> i & 1 == 0)
            .map(|i| pooled[i])
            .collect();
        all += 1.0;
        if (u_of(&x, &y) - centre).abs() >= observed - 1e-9 {
            far += 1.0;
        }
    }
    far / all
}

/// `pairwise.csv` and the report's pairwise table against U and p recomputed here.
fn check_pairwise(dir: &Path, task: &str, methods: &[&str], scores: &[Vec<f64>], md: &str) {
    let rows = csv_rows(&dir.join("pairwise.csv"));
    for i in 0..methods.len() {
        for j in i + 1..methods.len() {
            let (a, b) = (&scores[i], &scores[j]);
            let row = rows
                .iter()
                .find(|r| r[0] == task && r[2] == methods[i] && r[3] == methods[j])
                .unwrap_or_else(|| panic!("no pair {} {} in pairwise.csv", methods[i], methods[j]));
            let (u, p) = (u_of(a, b), listed_p(a, b));
            assert_eq!(row[6].parse::<f64>().unwrap(), u, "{row:?}");
            assert_eq!(row[7], (a.len() * b.len()).to_string(), "{row:?}");
            assert!(close(row[8].parse().unwrap(), p), "{row:?}: p {p}");
            let line = format!(
                "| {} | {} | {} + {} | {u} of {} |",
                methods[i],
                methods[j],
                a.len(),
                b.len(),
                a.len() * b.len()
            );
            assert!(md.contains(&line), "{line} not in\n{md}");
        }
    }
}
