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
}
