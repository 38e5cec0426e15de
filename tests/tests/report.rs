//! `selkd experiment report` on real runs: 2 methods (K = 1 and K = 2 actors) × 2 seeds of tiny
//! Pendulum runs. The test recomputes Table 2 (from each run's fresh_eval.json, with its own
//! mean and sample std) and a point of Figure 3 (from metrics.csv, with its own interpolation)
//! and checks that the report says the same.

mod common;
use common::*;
use std::path::Path;

const BUDGET: u64 = 2000;

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Sample standard deviation (n − 1), as the report documents.
fn sample_std(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// The ranked actor's in-run return at env step `x`, interpolated linearly between epochs.
fn ranked_at(run: &Path, x: f64) -> f64 {
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

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
}

#[test]
fn report_recomputes_table_2_and_figure_3_from_the_runs() {
    let dir = temp_dir("report");
    let methods = [("k1", "algo.actors=1"), ("k2", "algo.actors=2")];
    let mut children = Vec::new();
    for (m, set) in methods {
        for seed in [1, 2] {
            let run = dir.join(format!("{m}/pendulum/seed-{seed}"));
            let sets = small_run(&[
                set,
                "eval.epoch_env_steps=500",
                &format!("run.total_env_steps={BUDGET}"),
                &format!("run.seed={seed}"),
                "run.checkpoint_every=0",
            ]);
            children.push((run.clone(), spawn(train(&run, &sets))));
        }
    }
    for (run, child) in children {
        let out = child.wait_with_output().unwrap();
        assert_success(&out, &run);
    }
    std::fs::write(
        dir.join("experiment.toml"),
        "[[figure]]\ntitle = \"K = 2 only\"\nmethods = [\"k2\"]\n",
    )
    .unwrap();
    let mut c = std::process::Command::new(bin("selkd"));
    c.args(["experiment", "report"])
        .arg(&dir)
        .args(["--episodes", "3"]);
    let out = run(c);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    let table = csv_rows(&dir.join("table2.csv"));
    let curves = csv_rows(&dir.join("figures/curves-pendulum.csv"));
    assert!(
        md.contains("E = 3 fresh episodes") && md.contains("sample"),
        "{md}"
    );
    for (m, _) in methods {
        // Table 2: each seed's mean return over its fresh episodes, then mean ± sample std.
        let scores: Vec<f64> = [1, 2]
            .iter()
            .map(|s| {
                let f: serde_json::Value = serde_json::from_str(
                    &std::fs::read_to_string(
                        dir.join(format!("{m}/pendulum/seed-{s}/fresh_eval.json")),
                    )
                    .unwrap(),
                )
                .unwrap();
                let r: Vec<f64> = f["returns"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                assert_eq!(r.len(), 3);
                mean(&r)
            })
            .collect();
        let (sm, ss) = (mean(&scores), sample_std(&scores));
        let row = table
            .iter()
            .find(|r| r[0] == "pendulum" && r[1] == m)
            .unwrap();
        assert_eq!(row[3], "2");
        let (tm, ts): (f64, f64) = (row[4].parse().unwrap(), row[5].parse().unwrap());
        assert!(
            close(tm, sm) && close(ts, ss),
            "{m}: table {tm} ± {ts}, recomputed {sm} ± {ss}"
        );
        assert!(
            md.contains(&format!("{sm:.1} ± {ss:.1}")),
            "{m}: {sm:.1} ± {ss:.1} not in\n{md}"
        );
        // Figure 3 at 1000 env steps (a grid point: every seed covers 500..2000 in 500s).
        let runs: Vec<_> = [1, 2]
            .iter()
            .map(|s| dir.join(format!("{m}/pendulum/seed-{s}")))
            .collect();
        let at: Vec<f64> = runs.iter().map(|r| ranked_at(r, 1000.0)).collect();
        let point = curves.iter().find(|r| r[0] == m && r[1] == "1000").unwrap();
        let (pm, ps): (f64, f64) = (point[3].parse().unwrap(), point[4].parse().unwrap());
        assert!(
            close(pm, mean(&at)) && close(ps, sample_std(&at)),
            "{m}: curve {pm} ± {ps} vs {at:?}"
        );
    }
    for f in [
        "fig3-pendulum",
        "fig4-pendulum",
        "fig5-pendulum",
        "fig6-pendulum",
    ] {
        assert!(dir.join(format!("figures/{f}.svg")).exists(), "{f}.svg");
        let png = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(dir.join(format!("figures/{f}.png"))).unwrap(),
        ));
        let info = png.read_info().unwrap();
        assert!(info.info().width >= 800, "{f}.png");
        assert!(md.contains(&format!("figures/{f}.png")), "{f} not linked");
    }
    // Re-reporting uses the cache: the fresh evaluations are not rewritten.
    let cache = dir.join("k1/pendulum/seed-1/fresh_eval.json");
    let before = std::fs::metadata(&cache).unwrap().modified().unwrap();
    let mut c = std::process::Command::new(bin("selkd"));
    c.args(["experiment", "report"])
        .arg(&dir)
        .args(["--episodes", "3"]);
    assert!(run(c).status.success());
    assert_eq!(
        std::fs::metadata(&cache).unwrap().modified().unwrap(),
        before
    );
    let _ = std::fs::remove_dir_all(&dir);
}
