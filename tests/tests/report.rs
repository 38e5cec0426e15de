//! `selkd experiment report` on real runs: 2 methods (K = 1 and K = 2 actors) × 2 seeds of tiny
//! Pendulum runs. The test recomputes Table 2 (from each run's fresh_eval.json, with its own
//! mean and sample std) and a point of Figure 3 (from metrics.csv, with its own interpolation)
//! and checks that the report says the same.

mod common;
use common::report_check::check_report;
use common::*;

const BUDGET: u64 = 2000;

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
    check_report(&dir, "pendulum", &["k1", "k2"], &[1, 2], 3, 1000.0);
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
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
