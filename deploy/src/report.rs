//! `selkd experiment report`: a stub until the report lands (written on another branch; the
//! merge replaces this file with it).

use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// The experiment's directory (holds experiment.toml and the runs).
    pub dir: PathBuf,
}

pub fn run(args: ReportArgs) -> anyhow::Result<i32> {
    anyhow::bail!(
        "selkd experiment report {}: not built yet",
        args.dir.display()
    )
}
