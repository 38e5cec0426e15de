//! Who owns a run: an exclusive lock on a file, holding the owner's pid. The kernel releases it
//! when the owner exits, however it exits, so a lock left by a dead process is simply free.

use std::fs::File;
use std::io::Write;
use std::os::unix::io::AsRawFd;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another live process holds the lock; its pid as written in the file.
    #[error("held by pid {0}")]
    Held(String),
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// Takes the lock on `path` (created if missing) and writes this pid into it; the lock lasts as
/// long as the returned file is open.
pub fn pid_lock(path: &Path) -> Result<File, LockError> {
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .read(true)
        .write(true)
        .open(path)?;
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
        let holder = std::fs::read_to_string(path).unwrap_or_default();
        return Err(LockError::Held(holder.trim().to_string()));
    }
    file.set_len(0)?;
    write!(file, "{}", std::process::id())?;
    file.flush()?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_with_the_first_ones_pid_and_a_released_lock_is_free() {
        let path = std::env::temp_dir().join(format!("selkd-lock-test-{}", std::process::id()));
        let first = pid_lock(&path).unwrap();
        match pid_lock(&path) {
            Err(LockError::Held(pid)) => assert_eq!(pid, std::process::id().to_string()),
            other => panic!("expected Held, got {other:?}"),
        }
        drop(first);
        assert!(pid_lock(&path).is_ok(), "free once the holder lets go");
        let _ = std::fs::remove_file(&path);
    }
}
