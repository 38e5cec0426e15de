//! `selkd config [CONFIG] [--set k=v ...]` and `selkd config --defaults`: the resolved config,
//! every key with its value and its one-line doc (from `selkd_learner::config::docs`), printed
//! as TOML that `selkd train --config` reads back.

use anyhow::{bail, Context, Result};
use clap::Args;
use selkd_learner::config::docs::KEY_DOCS;
use selkd_learner::config::Config;
use std::io::Write;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ConfigArgs {
    /// A config file, or a run directory (its config.toml). Default: configs/quick.toml, what
    /// `selkd train` runs without --config.
    config: Option<PathBuf>,
    /// Override a key as `selkd train` does, e.g. `--set algo.actors=5` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// The built-in defaults (the paper's Table 1) instead of a config file.
    #[arg(long, conflicts_with_all = ["config", "set"])]
    defaults: bool,
}

pub fn run(args: ConfigArgs) -> Result<()> {
    let (cfg, source) = resolve(&args)?;
    let text = render(&cfg, &source);
    // A closed pipe (`selkd config | head`) is not an error worth a panic.
    let _ = std::io::stdout().lock().write_all(text.as_bytes());
    Ok(())
}

fn resolve(args: &ConfigArgs) -> Result<(Config, String)> {
    if args.defaults {
        return Ok((Config::default(), "the built-in defaults".into()));
    }
    let (text, source) = match &args.config {
        None => (
            crate::train::QUICK_CONFIG.to_string(),
            "configs/quick.toml (selkd train's default)".to_string(),
        ),
        Some(p) => {
            let file = if p.is_dir() {
                p.join("config.toml")
            } else {
                p.clone()
            };
            if p.is_dir() && !file.exists() {
                bail!(
                    "{} is a directory without config.toml; pass a config file or a run directory",
                    p.display()
                );
            }
            let text = std::fs::read_to_string(&file).with_context(|| {
                format!(
                    "reading config {} (pass an existing config file or run directory)",
                    file.display()
                )
            })?;
            (text, file.display().to_string())
        }
    };
    let cfg = Config::from_toml_with_overrides(&text, &args.set)
        .with_context(|| format!("in {source}"))?;
    let source = if args.set.is_empty() {
        source
    } else {
        format!("{source} with --set {}", args.set.join(" --set "))
    };
    Ok((cfg, source))
}

/// Every key of `cfg` in [`KEY_DOCS`]' order, as TOML with each doc as a trailing comment;
/// keys without a value (optional ones left out) are shown commented out.
pub fn render(cfg: &Config, source: &str) -> String {
    let table: toml::Table = toml::from_str(&cfg.to_toml()).expect("a config serialises to TOML");
    let mut lines = vec![format!("# selkd config: {source}")];
    let mut section = "";
    for (key, doc) in KEY_DOCS {
        if *key == "env_options" {
            lines.push(String::new());
            lines.push(format!("# {doc}"));
            lines.push("[env_options]".into());
            if let Some(t) = table.get("env_options").and_then(|v| v.as_table()) {
                for (k, v) in t {
                    lines.push(format!("{k} = {v}"));
                }
            }
            continue;
        }
        let (sec, name) = key.split_once('.').expect("section.key");
        if sec != section {
            section = sec;
            lines.push(String::new());
            lines.push(format!("[{sec}]"));
        }
        let value = table.get(sec).and_then(|s| s.get(name));
        let assignment = match value {
            Some(v) => format!("{name} = {v}"),
            None => format!("# {name} (unset)"),
        };
        lines.push(format!("{assignment:<32} # {doc}"));
    }
    lines.push(String::new());
    lines.join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Config {
        Config::from_toml_with_overrides(text, &[]).unwrap()
    }

    #[test]
    fn the_printout_reads_back_as_the_same_config_with_every_key_documented() {
        let sets = [
            "algo.actors=7",
            "algo.fixed_alpha=0.2",
            "algo.hidden=[32, 16]",
            "env_options.g=9.81",
        ]
        .map(String::from);
        let cfg = Config::from_toml_with_overrides("", &sets).unwrap();
        let text = render(&cfg, "test");
        assert_eq!(parse(&text), cfg, "{text}");
        assert!(text.contains("actors = 7 "), "{text}");
        assert!(text.contains("fixed_alpha = 0.2 "), "{text}");
        assert!(text.contains("hidden = [32, 16] "), "{text}");
        assert!(text.contains("[env_options]\ng = 9.81"), "{text}");
        // Unset optional keys are listed, commented out, so that a reader sees they exist.
        assert!(text.contains("# target_entropy (unset)"), "{text}");
        for (key, doc) in KEY_DOCS {
            assert!(text.contains(doc), "no doc line for {key}");
        }
        // 42 key lines + 5 section headers + the env_options doc line.
        let assignments = text
            .lines()
            .filter(|l| l.contains(" # ") && !l.starts_with("# selkd"))
            .count();
        assert_eq!(assignments, KEY_DOCS.len() - 1);
    }

    #[test]
    fn defaults_are_the_built_in_ones_and_conflict_with_a_file() {
        let args = ConfigArgs {
            config: None,
            set: vec![],
            defaults: true,
        };
        let (cfg, _) = resolve(&args).unwrap();
        assert_eq!(
            (cfg.algo.actors, cfg.algo.critics, cfg.algo.utd),
            (5, 10, 20)
        );
        let (quick, _) = resolve(&ConfigArgs {
            defaults: false,
            ..args
        })
        .unwrap();
        assert_eq!(
            quick.run.total_env_steps, 12_000,
            "configs/quick.toml's budget"
        );
    }

    #[test]
    fn bad_input_is_one_line_naming_what_to_change() {
        let err = |config: Option<&str>, set: &[&str]| {
            let e = resolve(&ConfigArgs {
                config: config.map(PathBuf::from),
                set: set.iter().map(|s| s.to_string()).collect(),
                defaults: false,
            })
            .unwrap_err();
            format!("{e:#}")
        };
        let e = err(Some("/no/such.toml"), &[]);
        assert!(e.contains("/no/such.toml") && !e.contains('\n'), "{e}");
        let e = err(None, &["algo.subset=99"]);
        assert!(e.contains("algo.subset") && !e.contains('\n'), "{e}");
        let e = err(Some("/"), &[]);
        assert!(e.contains("without config.toml"), "{e}");
    }
}
