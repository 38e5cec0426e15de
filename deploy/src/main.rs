//! `selkd`: run SELKD on this host (`selkd train`), measure it (`selkd bench`), plot its
//! curves (`selkd plot`), report an experiment (`selkd experiment report`: the paper's Table 2
//! and Figures 3–9) and watch a policy act (`selkd render`).
//!
//! `selkd train` starts one `learner` and K `actor-worker` processes (the binaries next to this
//! one), shows a progress line, writes a run directory, restarts a worker that dies, and stops
//! everything cleanly on Ctrl-C or when the env-step budget is reached.

mod bench;
mod plot;
mod raycast;
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
    },
    /// Draw one episode of a trained actor (or of random actions) to a GIF or a PNG strip.
    Render(render::RenderArgs),
    /// Benchmarks (commands, not tests).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Experiments: many runs (methods × tasks × seeds) and their report.
    #[command(subcommand)]
    Experiment(ExperimentCommand),
}

#[derive(Subcommand, Debug)]
enum ExperimentCommand {
    /// Table 2 and Figures 3–9 from DIR/<method>/<task>/seed-<s>/ runs: DIR/report.md.
    Report(report::ReportArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Train(args) => train::run(args),
        Command::Bench(b) => bench::run(b).map(|()| 0),
        Command::Render(args) => render::run(args).map(|()| 0),
        Command::Experiment(ExperimentCommand::Report(args)) => report::run(&args).map(|p| {
            eprintln!("selkd: wrote {}", p.display());
            0
        }),
        Command::Plot { runs, out, metric } => plot::run(&runs, out, metric).map(|p| {
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
