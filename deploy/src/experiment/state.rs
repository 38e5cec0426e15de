//! What a run directory holds, judged from its checkpoints alone: finished, to resume, or fresh.
//!
//! Checkpoints, not logs or exit codes, decide, so the answer is the same whoever ran the run
//! (this host's runner, a Slurm array task, a `selkd train` by hand) and however it ended.

use std::path::{Path, PathBuf};

/// What a run directory holds, judged from its checkpoints.
#[derive(Debug, PartialEq)]
pub enum State {
    /// `checkpoints/final` reached the budget.
    Finished,
    /// A checkpoint to continue from (`checkpoints/latest` names it).
    Resume(PathBuf),
    /// Nothing to continue from.
    Fresh,
}

/// `inserted` of a checkpoint's `state.json` (`TrainingState::inserted`: transitions stored).
fn inserted(checkpoint: &Path) -> Option<u64> {
    #[derive(serde::Deserialize)]
    struct Counters {
        inserted: u64,
    }
    let text = std::fs::read_to_string(checkpoint.join("state.json")).ok()?;
    serde_json::from_str::<Counters>(&text)
        .ok()
        .map(|c| c.inserted)
}

pub fn state(dir: &Path, budget: u64) -> State {
    let checkpoints = dir.join("checkpoints");
    // A run stopped by a signal also writes `final`, below the budget: that one is resumed.
    if inserted(&checkpoints.join("final")).is_some_and(|n| n >= budget) {
        return State::Finished;
    }
    match std::fs::read_to_string(checkpoints.join("latest")) {
        Ok(name) if inserted(&checkpoints.join(name.trim())).is_some() => {
            State::Resume(checkpoints.join(name.trim()))
        }
        _ => State::Fresh,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checkpoint(dir: &Path, name: &str, inserted: u64) {
        let c = dir.join("checkpoints").join(name);
        std::fs::create_dir_all(&c).unwrap();
        std::fs::write(
            c.join("state.json"),
            format!("{{\"inserted\": {inserted}}}"),
        )
        .unwrap();
        std::fs::write(dir.join("checkpoints").join("latest"), format!("{name}\n")).unwrap();
    }

    #[test]
    fn a_run_is_finished_only_when_its_final_checkpoint_reaches_the_budget() {
        let dir = std::env::temp_dir().join(format!("selkd-exp-state-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(state(&dir, 1000), State::Fresh);
        checkpoint(&dir, "step-500", 500);
        assert_eq!(
            state(&dir, 1000),
            State::Resume(dir.join("checkpoints/step-500"))
        );
        // Stopped by a signal: `final` below the budget is resumed, not skipped.
        checkpoint(&dir, "final", 700);
        assert_eq!(
            state(&dir, 1000),
            State::Resume(dir.join("checkpoints/final"))
        );
        checkpoint(&dir, "final", 1000);
        assert_eq!(state(&dir, 1000), State::Finished);
        // A raised budget makes it a run to continue.
        assert_eq!(
            state(&dir, 2000),
            State::Resume(dir.join("checkpoints/final"))
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
