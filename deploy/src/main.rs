//! `selkd`: run SELKD on this host (`selkd train`), measure it (`selkd bench`), plot its
//! curves (`selkd plot`), watch a policy act (`selkd render`), and run and report experiments
//! (`selkd experiment run|plan|report`: methods × tasks × seeds, the paper's Table 2 and
//! Figures 3–9).
//!
//! `selkd train` starts one `learner` and K `actor-worker` processes (the binaries next to this
//! one), shows a progress line, writes a run directory, restarts a worker that dies, and stops
//! everything cleanly on Ctrl-C or when the env-step budget is reached.

mod bench;
mod experiment;
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
    /// Experiments: every (method, task, seed) of an experiment file (experiments/*.toml).
    #[command(subcommand)]
    Experiment(experiment::ExperimentCommand),
    /// Benchmarks (commands, not tests).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}

fn main() {
    // Before anything else: it may execute selkd again (its children inherit the setting).
    selkd_learner::passive_openmp();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Train(args) => train::run(args),
        Command::Experiment(e) => experiment::run(e),
        Command::Bench(b) => bench::run(b).map(|()| 0),
        Command::Render(args) => render::run(args).map(|()| 0),
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
