//! `selkd`: run SELKD on this host (`selkd train`), measure it (`selkd bench`), plot its
//! curves (`selkd plot`), watch a policy act (`selkd render`), and run and report experiments
//! (`selkd experiment run|plan|report`: methods × tasks × seeds, the paper's Table 2 and
//! Figures 3–9).
//!
//! `selkd train` starts one `learner` and K `actor-worker` processes (the binaries next to this
//! one), shows a progress line, writes a run directory, restarts a worker that dies, and stops
//! everything cleanly on Ctrl-C or when the env-step budget is reached.

mod bench;
mod config_cmd;
mod eval;
mod experiment;
mod export;
mod plot;
mod progress;
mod render;
mod report;
mod train;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "SELKD: skill enhancement learning with knowledge distillation, on one host"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Train: a learner and K actor workers on this host.
    Train(train::TrainArgs),
    /// Learning curves of one run (every actor) or several (mean ± ½ sd of the best actor) as SVG.
    Plot {
        /// Run directories (each holds metrics.csv).
        runs: Vec<std::path::PathBuf>,
        /// Output file (default: FIRST_RUN/returns.svg, or success.svg for --metric success).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// What to draw: the evaluation return, or the success rate (tasks with success).
        #[arg(long, value_enum, default_value = "return")]
        metric: plot::Metric,
        /// What to draw against: env steps (all actors), rounds (env steps / K), critic
        /// updates, or wall-clock seconds.
        #[arg(long, value_enum, default_value = "env-steps")]
        x: plot::XAxis,
    },
    /// Print the resolved config: every key, its value and what it does (TOML).
    Config(config_cmd::ConfigArgs),
    /// Evaluate a run's actors: mean ± std return (and success rate) of the deterministic policy.
    Eval(eval::EvalArgs),
    /// Export one trained actor as a bundle for PyTorch (`selkd.load_policy`), optionally ONNX.
    Export(export::ExportArgs),
    /// Draw one episode of a trained actor (or of random actions) to a GIF or a PNG strip.
    Render(render::RenderArgs),
    /// Experiments: every (method, task, seed) of an experiment file (experiments/*.toml).
    #[command(subcommand)]
    Experiment(experiment::ExperimentCommand),
    /// Benchmarks (commands, not tests).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}

fn main() {
    // Before anything else: it may execute selkd again (its children inherit the setting).
    selkd_learner::restart_with_runtime_settings();
    // `gymnasium:` envs step in an embedded Python.
    selkd_gymnasium::register();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => usage_error(e),
    };
    let result = match cli.command {
        Command::Train(args) => train::run(args),
        Command::Experiment(e) => experiment::run(e),
        Command::Bench(b) => bench::run(b).map(|()| 0),
        Command::Config(args) => config_cmd::run(args).map(|()| 0),
        Command::Eval(args) => eval::run(args).map(|()| 0),
        Command::Export(args) => export::run(args).map(|()| 0),
        Command::Render(args) => render::run(args).map(|()| 0),
        Command::Plot {
            runs,
            out,
            metric,
            x,
        } => plot::run(&runs, out, metric, x).map(|p| {
            eprintln!("selkd: wrote {}", p.display());
            0
        }),
    };
    match result {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("selkd: error: {e:#}");
            std::process::exit(2);
        }
    }
}

/// Help and version print as clap writes them; a usage error is one line (clap's own message,
/// without its usage block), pointing at `--help`, and exits 2.
fn usage_error(e: clap::Error) -> ! {
    use clap::error::ErrorKind;
    if matches!(
        e.kind(),
        ErrorKind::DisplayHelp
            | ErrorKind::DisplayVersion
            | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
    ) {
        e.exit();
    }
    let text = e.render().to_string();
    // clap's message is its first line, or (for "… not provided:") that line and the indented
    // names below it.
    let mut lines = text.lines();
    let mut first = lines
        .next()
        .unwrap_or("bad arguments")
        .trim_start_matches("error: ")
        .to_string();
    if first.ends_with(':') {
        let names: Vec<&str> = lines
            .take_while(|l| !l.trim().is_empty())
            .map(str::trim)
            .collect();
        first = format!("{first} {}", names.join(", "));
    }
    // The subcommand the user typed, so the hint names its help.
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut sub: Vec<&str> = vec![];
    if let Some(first) = args.first().filter(|a| !a.starts_with('-')) {
        sub.push(first);
        // Commands with their own subcommands: `selkd experiment run`, `selkd bench env`.
        if matches!(first.as_str(), "experiment" | "bench") {
            sub.extend(
                args.get(1)
                    .filter(|a| !a.starts_with('-'))
                    .map(String::as_str),
            );
        }
    }
    if e.kind() == ErrorKind::InvalidSubcommand {
        sub.clear();
    }
    let help = if sub.is_empty() {
        "selkd --help".to_string()
    } else {
        format!("selkd {} --help", sub.join(" "))
    };
    eprintln!("selkd: error: {first} (see `{help}`)");
    std::process::exit(2);
}
