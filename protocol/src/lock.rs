//! Who owns a run: an exclusive lock on a file, holding the owner's pid. The kernel releases it
//! when the owner exits, however it exits, so a lock left by a dead process is simply free.
//!
//! Lock files live only where the run's owner alone can write: inside the run directory, or in
//! this user's private lock directory ([`user_lock_dir`], mode 0700). A lock file is opened with
//! `O_NOFOLLOW` and must be a regular file owned by this user, so a symbolic link planted by
//! someone else can never make us write through it; the file is removed when its holder lets go.

use std::fs::File;
use std::io::{Read, Write};
use std::os::unix::fs::{DirBuilderExt, MetadataExt, OpenOptionsExt};
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another live process holds the lock; its pid as written in the file.
    #[error("held by pid {0}")]
    Held(String),
    /// The path is a symbolic link, or not a regular file of this user's: never written through.
    #[error("{path} is {what}, not a lock file of this user's; remove it")]
    Unsafe { path: PathBuf, what: String },
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// A held lock: the file stays open (and locked) until this is dropped, which removes it.
#[derive(Debug)]
pub struct PidLock {
    _file: File,
    path: PathBuf,
}

impl PidLock {
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for PidLock {
    fn drop(&mut self) {
        // Removed while still held: a process that opened it meanwhile finds, once it holds the
        // lock, that the name is gone and starts over on a new file (see `pid_lock`).
        let _ = std::fs::remove_file(&self.path);
    }
}

fn euid() -> u32 {
    unsafe { libc::geteuid() }
}

/// Takes the lock on `path` (created, mode 0600, if missing) and writes this pid into it; the
/// lock lasts as long as the returned guard lives. Refuses a symbolic link, a file of another
/// user's and anything that is not a regular file.
pub fn pid_lock(path: &Path) -> Result<PidLock, LockError> {
    // The name may be removed (by a holder letting go) between our open and our flock; then the
    // lock we hold is on a file nobody else can find, so start again on the new name.
    for _ in 0..100 {
        let mut file = match std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .mode(0o600)
            .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC | libc::O_NONBLOCK)
            .open(path)
        {
            Ok(f) => f,
            Err(e) if e.raw_os_error() == Some(libc::ELOOP) => {
                return Err(LockError::Unsafe {
                    path: path.to_path_buf(),
                    what: "a symbolic link".into(),
                })
            }
            // A FIFO or device opened for writing, or a directory.
            Err(e) if e.raw_os_error() == Some(libc::EISDIR) => {
                return Err(LockError::Unsafe {
                    path: path.to_path_buf(),
                    what: "a directory".into(),
                })
            }
            Err(e) => return Err(e.into()),
        };
        let meta = file.metadata()?;
        if !meta.file_type().is_file() {
            return Err(LockError::Unsafe {
                path: path.to_path_buf(),
                what: "not a regular file".into(),
            });
        }
        if meta.uid() != euid() {
            return Err(LockError::Unsafe {
                path: path.to_path_buf(),
                what: format!("owned by uid {}", meta.uid()),
            });
        }
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            return Err(LockError::Held(holder.trim().to_string()));
        }
        match std::fs::symlink_metadata(path) {
            Ok(now) if now.dev() == meta.dev() && now.ino() == meta.ino() => {}
            Ok(_) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e.into()),
        }
        file.set_len(0)?;
        write!(file, "{}", std::process::id())?;
        file.flush()?;
        return Ok(PidLock {
            _file: file,
            path: path.to_path_buf(),
        });
    }
    Err(std::io::Error::other(format!(
        "{} kept being replaced while it was locked",
        path.display()
    ))
    .into())
}

/// This user's private directory for locks that belong to no run directory (one learner per run
/// id): `$XDG_RUNTIME_DIR/selkd` where the session has one, else `locks` in the per-user cache
/// (`SELKD_CACHE`, else `$XDG_CACHE_HOME/selkd`, else `~/.cache/selkd`), else
/// `<tmp>/selkd-<uid>`. Created 0700; refused unless it is a real directory of this user's that
/// nobody else can write.
pub fn user_lock_dir() -> Result<PathBuf, LockError> {
    let var = |k: &str| {
        std::env::var_os(k)
            .map(PathBuf::from)
            .filter(|p| p.is_absolute())
    };
    let dir = if let Some(rt) = var("XDG_RUNTIME_DIR") {
        rt.join("selkd")
    } else if let Some(cache) = var("SELKD_CACHE")
        .or_else(|| var("XDG_CACHE_HOME").map(|c| c.join("selkd")))
        .or_else(|| var("HOME").map(|h| h.join(".cache/selkd")))
    {
        cache.join("locks")
    } else {
        std::env::temp_dir().join(format!("selkd-{}", euid()))
    };
    private_dir(&dir)?;
    Ok(dir)
}

/// Makes `dir` (and missing parents, 0700) and checks that only this user can write in it.
pub fn private_dir(dir: &Path) -> Result<(), LockError> {
    match std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
    {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(e) => {
            return Err(
                std::io::Error::new(e.kind(), format!("creating {}: {e}", dir.display())).into(),
            )
        }
    }
    let meta = std::fs::symlink_metadata(dir)?;
    let unsafe_because = if meta.file_type().is_symlink() {
        Some("a symbolic link".to_string())
    } else if !meta.is_dir() {
        Some("not a directory".to_string())
    } else if meta.uid() != euid() {
        Some(format!("owned by uid {}", meta.uid()))
    } else if meta.mode() & 0o022 != 0 {
        Some(format!(
            "writable by others (mode {:o})",
            meta.mode() & 0o777
        ))
    } else {
        None
    };
    match unsafe_because {
        Some(what) => Err(LockError::Unsafe {
            path: dir.to_path_buf(),
            what,
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("selkd-lock-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_second_holder_is_refused_with_the_first_ones_pid_and_a_released_lock_is_free() {
        let dir = scratch("held");
        let path = dir.join("l.lock");
        let first = pid_lock(&path).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            std::process::id().to_string()
        );
        match pid_lock(&path) {
            Err(LockError::Held(pid)) => assert_eq!(pid, std::process::id().to_string()),
            other => panic!("expected Held, got {other:?}"),
        }
        drop(first);
        assert!(!path.exists(), "the holder removes its lock file");
        assert!(pid_lock(&path).is_ok(), "free once the holder lets go");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_symlink_is_never_followed_and_its_target_is_untouched() {
        let dir = scratch("symlink");
        let victim = dir.join("victim");
        std::fs::write(&victim, "precious").unwrap();
        let path = dir.join("l.lock");
        std::os::unix::fs::symlink(&victim, &path).unwrap();
        match pid_lock(&path) {
            Err(e @ LockError::Unsafe { .. }) => {
                assert!(e.to_string().contains("symbolic link"), "{e}")
            }
            other => panic!("expected Unsafe, got {other:?}"),
        }
        // A dangling one would otherwise be created through.
        let dangling = dir.join("d.lock");
        std::os::unix::fs::symlink(dir.join("made-through-link"), &dangling).unwrap();
        assert!(pid_lock(&dangling).is_err());
        assert!(!dir.join("made-through-link").exists());
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_directory_and_a_fifo_are_refused() {
        let dir = scratch("kinds");
        std::fs::create_dir(dir.join("d")).unwrap();
        assert!(matches!(
            pid_lock(&dir.join("d")),
            Err(LockError::Unsafe { .. })
        ));
        let fifo = dir.join("f");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        assert!(matches!(pid_lock(&fifo), Err(LockError::Unsafe { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_private_dir_is_made_0700_and_one_others_can_write_is_refused() {
        use std::os::unix::fs::PermissionsExt;
        let dir = scratch("private");
        let p = dir.join("a/b");
        private_dir(&p).unwrap();
        let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode & 0o077, 0, "mode {mode:o}");
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o777)).unwrap();
        let e = private_dir(&p).unwrap_err().to_string();
        assert!(e.contains("writable by others"), "{e}");
        let link = dir.join("link");
        std::os::unix::fs::symlink(&p, &link).unwrap();
        let e = private_dir(&link).unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_directory_or_file_of_another_user_is_refused() {
        if euid() != 0 {
            eprintln!("skipped: needs root to give a file to another user");
            return;
        }
        let dir = scratch("other");
        let (d, f) = (dir.join("d"), dir.join("f.lock"));
        std::fs::create_dir(&d).unwrap();
        std::fs::write(&f, "").unwrap();
        std::os::unix::fs::chown(&d, Some(65534), Some(65534)).unwrap();
        std::os::unix::fs::chown(&f, Some(65534), Some(65534)).unwrap();
        let e = private_dir(&d).unwrap_err().to_string();
        assert!(e.contains("owned by uid 65534"), "{e}");
        let e = pid_lock(&f).unwrap_err().to_string();
        assert!(e.contains("owned by uid 65534"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
