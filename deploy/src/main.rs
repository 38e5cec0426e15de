//! `selkd`: run SELKD on this host (`selkd train`) and measure it (`selkd bench`).
//!
//! `selkd train` starts one `learner` and K `actor-worker` processes (the binaries next to this
//! one), shows a progress line, writes a run directory, restarts a worker that dies, and stops
//! everything cleanly on Ctrl-C or when the env-step budget is reached.

mod bench;
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
    /// Benchmarks (commands, not tests).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Train(args) => train::run(args),
        Command::Bench(b) => bench::run(b).map(|()| 0),
    };
    match result {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("selkd: error: {e:#}");
            std::process::exit(2);
        }
    }
}
