//! Published numbers beside ours: for a Gymnasium MuJoCo task (`gymnasium:Hopper-v5`), the
//! returns other papers' authors report for SAC, REDQ, DroQ, CrossQ, BRO, SimbaV2 and MR.Q at the
//! same env-step budget, so a reader sees whether our baselines are as strong as everyone else's.
//!
//! The numbers are `docs/results/published/gym-mujoco-v4.csv`, compiled into the binary: a report
//! regenerated from a clone, or on a machine without the repository, sets the same numbers beside
//! ours. Where it comes from, and why its tasks are v4, is in the README beside it; [`CITATION`]
//! says the same in the report (a test keeps the two in step).

use super::table::pm;
use std::collections::BTreeSet;
use std::fmt::Write as _;

/// The committed summaries (see `docs/results/published/README.md`).
pub const CSV: &str = include_str!("../../../docs/results/published/gym-mujoco-v4.csv");

/// Where the numbers come from and how far they compare, printed under each table.
pub const CITATION: &str = "Published numbers: `docs/results/published/gym-mujoco-v4.csv` (compiled into `selkd`; its README says how it was made), each row a summary over seeds (sample std) of the authors' own per-seed curves at the evaluation nearest the budget (the last column), from [dojeon-ai/SimbaV2](https://github.com/dojeon-ai/SimbaV2) `results/baseline/*.csv` at commit `14fafb27e6f78f0b65d19b8873b4433547a2193c` (Lee et al., \"Hyperspherical Normalization for Scalable Deep Reinforcement Learning\", 2025: SAC, REDQ, DroQ, CrossQ, BRO, SimbaV2) and [facebookresearch/MRQ](https://github.com/facebookresearch/MRQ) `results/gym_results.txt` at commit `8a44a7d4b1cf117e5da4bf8214d35b02aa68d68b` (Fujimoto et al., \"Towards General-Purpose Model-Free Reinforcement Learning\", 2025: MR.Q). **Not the same experiment as ours:** they ran Gym's **v4** tasks, ours are Gymnasium's v5 (the same models with small fixes: the same task to within noise, not exactly), and with their papers' network sizes and update-to-data ratios (for example 256-wide networks, REDQ with N = 10 and G = 20, the UTD in each name), not ours; their scores are their own evaluations, not our 20 fresh episodes. They say whether our baselines are about as strong as other people's at this budget, not what our settings would reach.";

/// One row of the CSV: a method's return on a task at a budget, over seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct Published {
    pub source: String,
    pub method: String,
    /// Gym's task name without version: `Hopper`.
    pub task: String,
    pub budget: u64,
    /// The env step of the evaluation nearest the budget.
    pub env_step: u64,
    pub seeds: u64,
    pub mean: f64,
    pub std: f64,
    pub min: f64,
    pub max: f64,
}

/// The rows of `text`, and a note for each line that could not be read (skipped, not fatal: the
/// rest still stand beside ours).
pub fn parse(text: &str) -> (Vec<Published>, Vec<String>) {
    let mut lines = text.lines().enumerate();
    let Some((_, header)) = lines.next() else {
        return (Vec::new(), vec!["the published CSV is empty".to_string()]);
    };
    let header: Vec<&str> = header.split(',').map(str::trim).collect();
    let (mut rows, mut notes) = (Vec::new(), Vec::new());
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let field = |name: &str| -> Result<&str, String> {
            header
                .iter()
                .position(|h| *h == name)
                .and_then(|c| fields.get(c).copied())
                .filter(|f| !f.is_empty())
                .ok_or_else(|| format!("no `{name}`"))
        };
        let int = |name: &str| -> Result<u64, String> {
            field(name)?
                .parse()
                .map_err(|_| format!("`{name}` is not a whole number"))
        };
        let num = |name: &str| -> Result<f64, String> {
            field(name)?
                .parse()
                .map_err(|_| format!("`{name}` is not a number"))
        };
        let row = (|| -> Result<Published, String> {
            Ok(Published {
                source: field("source")?.to_string(),
                method: field("method")?.to_string(),
                task: field("task")?.to_string(),
                budget: int("budget_env_steps")?,
                env_step: int("env_step")?,
                seeds: int("seeds")?,
                mean: num("mean")?,
                std: num("std")?,
                min: num("min")?,
                max: num("max")?,
            })
        })();
        match row {
            Ok(r) => rows.push(r),
            Err(why) => notes.push(format!("line {} skipped ({why})", i + 1)),
        }
    }
    (rows, notes)
}

/// `gymnasium:Hopper-v5` (or `-v4`) → `Hopper`: the tasks the published numbers can stand beside.
pub fn gym_name(env: &str) -> Option<&str> {
    let (name, version) = env.strip_prefix("gymnasium:")?.rsplit_once("-v")?;
    (matches!(version, "4" | "5") && !name.is_empty()).then_some(name)
}

/// The published rows for `task` (Gym's name) at exactly `budget` env steps.
pub fn lookup<'a>(rows: &'a [Published], task: &str, budget: u64) -> Vec<&'a Published> {
    rows.iter()
        .filter(|r| r.task == task && r.budget == budget)
        .collect()
}

/// The budgets published for `task`, ascending.
pub fn budgets(rows: &[Published], task: &str) -> BTreeSet<u64> {
    rows.iter()
        .filter(|r| r.task == task)
        .map(|r| r.budget)
        .collect()
}

fn list(v: impl IntoIterator<Item = String>) -> String {
    v.into_iter().collect::<Vec<_>>().join(", ")
}

/// The "Published at the same budget" part for one task of ours: `env` its env, `ours` each
/// method with its budget in env steps. Empty for tasks the published numbers are not about.
pub fn markdown(env: &str, ours: &[(String, u64)], rows: &[Published], notes: &[String]) -> String {
    let Some(name) = gym_name(env) else {
        return String::new();
    };
    let mut s = String::new();
    let have = budgets(rows, name);
    if have.is_empty() {
        let tasks: BTreeSet<&str> = rows.iter().map(|r| r.task.as_str()).collect();
        let _ = writeln!(
            s,
            "Published at the same budget: none; `docs/results/published/gym-mujoco-v4.csv` has no {name} (it has {}).\n",
            list(tasks.iter().map(|t| t.to_string()))
        );
        return s;
    }
    let ours_budgets: BTreeSet<u64> = ours.iter().map(|(_, b)| *b).collect();
    let methods_at = |b: u64| list(ours.iter().filter(|(_, x)| *x == b).map(|(m, _)| m.clone()));
    let mut any = false;
    for &b in &ours_budgets {
        let found = lookup(rows, name, b);
        if found.is_empty() {
            continue;
        }
        any = true;
        let _ = writeln!(
            s,
            "##### Published at the same budget: {name} at {b} env steps (beside ours: {})\n",
            methods_at(b)
        );
        let _ = writeln!(
            s,
            "| method | source | seeds | return, mean ± std | min–max | evaluated at env step |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|");
        for r in found {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {:.1} – {:.1} | {} |",
                r.method,
                r.source,
                r.seeds,
                pm(r.mean, r.std, false),
                r.min,
                r.max,
                r.env_step
            );
        }
        s.push('\n');
    }
    let missing: Vec<u64> = ours_budgets
        .iter()
        .copied()
        .filter(|b| lookup(rows, name, *b).is_empty())
        .collect();
    if !missing.is_empty() {
        let _ = writeln!(
            s,
            "{}No published {name} numbers at {} (published budgets: {} env steps).\n",
            if any {
                ""
            } else {
                "Published at the same budget: none. "
            },
            list(
                missing
                    .iter()
                    .map(|b| format!("{b} env steps ({})", methods_at(*b)))
            ),
            list(have.iter().map(|b| b.to_string()))
        );
    }
    if any {
        let _ = writeln!(s, "{CITATION}\n");
    }
    if !notes.is_empty() {
        let _ = writeln!(
            s,
            "Lines of the published CSV not read: {}.\n",
            notes.join("; ")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_committed_csv_reads_whole() {
        let (rows, notes) = parse(CSV);
        assert!(notes.is_empty(), "{notes:?}");
        // 7 methods × 5 tasks × 4 budgets, less SimbaV2's 30k (it evaluates every 50 000).
        assert_eq!(rows.len(), 135);
    }

    #[test]
    fn lookup_finds_the_budget_and_only_it() {
        let (rows, _) = parse(CSV);
        assert_eq!(gym_name("gymnasium:Hopper-v5"), Some("Hopper"));
        assert_eq!(gym_name("gymnasium:Walker2d-v4"), Some("Walker2d"));
        assert_eq!(gym_name("gymnasium:Pendulum-v1"), None);
        assert_eq!(gym_name("hopper"), None);
        let hop = lookup(&rows, "Hopper", 100_000);
        assert_eq!(hop.len(), 7);
        // The CSV's line for REDQ on Hopper at 100k.
        let redq = hop.iter().find(|r| r.method == "REDQ (UTD 20)").unwrap();
        assert_eq!(
            (
                redq.env_step,
                redq.seeds,
                redq.mean,
                redq.std,
                redq.min,
                redq.max
            ),
            (99_996, 10, 2749.7, 971.7, 1236.6, 3612.8)
        );
        assert!(lookup(&rows, "Hopper", 20_000).is_empty());
        assert_eq!(
            budgets(&rows, "Walker2d").into_iter().collect::<Vec<_>>(),
            vec![30_000, 50_000, 100_000, 300_000]
        );
    }

    #[test]
    fn the_table_stands_beside_matching_budgets_and_names_the_others() {
        let (rows, notes) = parse(CSV);
        let ours = vec![
            ("sac".to_string(), 100_000),
            ("redq".to_string(), 100_000),
            ("selkd-rounds".to_string(), 500_000),
        ];
        let md = markdown("gymnasium:Hopper-v5", &ours, &rows, &notes);
        assert!(
            md.contains("##### Published at the same budget: Hopper at 100000 env steps (beside ours: sac, redq)"),
            "{md}"
        );
        assert!(
            md.contains("| SAC | SimbaV2 repo results/baseline/sac.csv | 10 | 1103.4 ± 387.7 | 408.3 – 1717.4 | 99996 |"),
            "{md}"
        );
        assert!(
            md.contains("No published Hopper numbers at 500000 env steps (selkd-rounds) (published budgets: 30000, 50000, 100000, 300000 env steps)"),
            "{md}"
        );
        assert!(md.contains("14fafb27e6f78f0b65d19b8873b4433547a2193c") && md.contains("**v4**"));
        // No budget matches: no table, no citation, the budgets that exist.
        let md = markdown("gymnasium:Hopper-v5", &ours[2..], &rows, &notes);
        assert!(!md.contains("#####") && !md.contains("Lee et al."), "{md}");
        assert!(
            md.starts_with("Published at the same budget: none. "),
            "{md}"
        );
        // A task the file has not, and one the published numbers are not about.
        let md = markdown("gymnasium:Swimmer-v5", &ours, &rows, &notes);
        assert!(
            md.contains("has no Swimmer (it has Ant, HalfCheetah, Hopper, Humanoid, Walker2d)"),
            "{md}"
        );
        assert_eq!(markdown("pendulum", &ours, &rows, &notes), "");
    }

    #[test]
    fn a_bad_line_is_skipped_with_a_note() {
        let text = "source,method,task,budget_env_steps,env_step,seeds,mean,std,min,max\n\
            s,SAC,Hopper,30000,33332,10,403.9,295.8,25.4,971.6\n\
            s,REDQ,Hopper,30000,33332,10,,1.0,0.0,2.0\n\
            s,DroQ,Hopper,lots\n";
        let (rows, notes) = parse(text);
        assert_eq!(rows.len(), 1);
        assert_eq!(
            notes,
            vec![
                "line 3 skipped (no `mean`)",
                "line 4 skipped (`budget_env_steps` is not a whole number)"
            ]
        );
        let md = markdown(
            "gymnasium:Hopper-v5",
            &[("sac".into(), 30_000)],
            &rows,
            &notes,
        );
        assert!(
            md.contains("Lines of the published CSV not read: line 3 skipped (no `mean`)"),
            "{md}"
        );
    }

    #[test]
    fn the_citation_matches_the_readme() {
        let readme = include_str!("../../../docs/results/published/README.md");
        for commit in [
            "14fafb27e6f78f0b65d19b8873b4433547a2193c",
            "8a44a7d4b1cf117e5da4bf8214d35b02aa68d68b",
        ] {
            assert!(
                readme.contains(commit) && CITATION.contains(commit),
                "{commit}"
            );
        }
    }
}
