//! Node entries iceoryx2 cannot clean up: those of a process killed while it created its node.
//!
//! iceoryx2 0.10 makes a node in two steps: first the directory `nodes/<id>/` with its details
//! file (executable, pid, name), then the monitor files `nodes/iox2_<id>.node_monitor{,_context,
//! _owner_lock}`, finished by making the context file readable. A process killed between or
//! during those steps leaves a node that `Node::list` never reports (no monitor file, or a
//! context file still in its "starting" mode reads as "does not exist"), or reports as
//! `Undefined` (monitor files inconsistent), so its dead-node cleanup never removes it.
//!
//! Such an entry is removed here only when all of these hold, which make it garbage:
//! - iceoryx2 does not report it `Alive`, `Dead` or `Inaccessible` (complete nodes are its own
//!   business: it removes dead ones whenever a node is created);
//! - every file of it belongs to this user (another user's are none of ours);
//! - it has no service or port tags: a half-made node never opened a service, while a complete
//!   node with damaged monitor files may still be registered inside services' shared memory,
//!   which only iceoryx2's own cleanup (that needs the monitor) can undo; those are only reported;
//! - its details name one of our nodes (`learner-…`, `actor-worker-…`), or are not written yet;
//! - no process holds any of its files open: the creator keeps every file it made open for as
//!   long as it lives (the details and the three monitor files), so an open file means a node
//!   being made right now (its files are mode 0600 or less: only this user's processes, whose
//!   open files we can see in /proc, can hold them);
//! - a directory with no file at all (the creator was between `mkdir` and creating the details
//!   file, which holds no descriptor) is older than [`EMPTY_DIR_AGE`].

use std::collections::HashSet;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use iceoryx2::prelude::*;

/// An empty node directory younger than this may be a node being made this very moment.
pub const EMPTY_DIR_AGE: Duration = Duration::from_secs(10);

/// What a clean-up found.
#[derive(Debug, Default)]
pub struct Report {
    /// Entries removed, as their node directory (or monitor file) paths.
    pub removed: Vec<PathBuf>,
    /// Entries of this user's left in place, each with why.
    pub left: Vec<(PathBuf, String)>,
}

/// One node id's files.
#[derive(Default)]
struct Entry {
    dir: Option<PathBuf>,
    monitor: Vec<PathBuf>,
}

/// What each process does at start (the learner and every worker, a restarted one too, since
/// its predecessor may have died making its node): [`remove_half_made_nodes`], best effort,
/// each entry removed or left said in the log.
pub fn clean_up() {
    match remove_half_made_nodes() {
        Ok(r) => {
            for p in &r.removed {
                tracing::info!(
                    "removed the half-made iceoryx2 node entry {} (its process died while making it)",
                    p.display()
                );
            }
            for (p, why) in &r.left {
                tracing::warn!("left the iceoryx2 node entry {}: {why}", p.display());
            }
        }
        Err(e) => tracing::warn!("looking for half-made iceoryx2 node entries: {e}"),
    }
}

/// Removes the half-made node entries (see the module's doc) from iceoryx2's node directory.
pub fn remove_half_made_nodes() -> std::io::Result<Report> {
    let cfg = Config::global_config();
    let root = PathBuf::from(cfg.global.root_path().to_string());
    let nodes = root.join(cfg.global.node.directory.to_string());
    let prefix = cfg.global.prefix.to_string();
    let monitor_suffix = cfg.global.node.monitor_suffix.to_string();
    let mut report = Report::default();
    let listing = match std::fs::read_dir(&nodes) {
        Ok(l) => l,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(report),
        Err(e) => return Err(e),
    };
    let mut entries: std::collections::BTreeMap<u128, Entry> = Default::default();
    for item in listing {
        let item = item?;
        let name = item.file_name().to_string_lossy().to_string();
        if let Ok(id) = name.parse::<u128>() {
            entries.entry(id).or_default().dir = Some(item.path());
        } else if let Some(id) = name
            .strip_prefix(&prefix)
            .and_then(|rest| rest.split_once(&monitor_suffix))
            .and_then(|(id, _)| id.parse::<u128>().ok())
        {
            entries.entry(id).or_default().monitor.push(item.path());
        }
    }
    if entries.is_empty() {
        return Ok(report);
    }
    // Complete nodes, alive or dead, are iceoryx2's.
    let mut complete = HashSet::new();
    Node::<ipc::Service>::list(cfg, |state| {
        if !matches!(state, NodeState::Undefined(_)) {
            complete.insert(state.node_id().value());
        }
        CallbackProgression::Continue
    })
    .map_err(|e| std::io::Error::other(format!("listing iceoryx2 nodes: {e:?}")))?;
    entries.retain(|id, _| !complete.contains(id));
    if entries.is_empty() {
        return Ok(report);
    }
    let euid = unsafe { libc::geteuid() };
    let open = open_files_under(&nodes);
    for (id, entry) in entries {
        let shown = entry
            .dir
            .clone()
            .unwrap_or_else(|| nodes.join(id.to_string()));
        let mut files = entry.monitor.clone();
        let mut tags = false;
        if let Some(dir) = &entry.dir {
            for f in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                let n = f.file_name().to_string_lossy().to_string();
                tags |= n.ends_with("_tag");
                files.push(f.path());
            }
        }
        let meta: Vec<_> = files
            .iter()
            .chain(&entry.dir)
            .filter_map(|p| std::fs::symlink_metadata(p).ok())
            .collect();
        if meta.iter().any(|m| m.uid() != euid) {
            continue; // another user's
        }
        let details = entry
            .dir
            .as_ref()
            .and_then(|d| std::fs::read_to_string(d.join(format!("{prefix}node.details"))).ok())
            .and_then(|t| details_name(&t));
        if details
            .as_deref()
            .is_some_and(|n| !n.starts_with("learner-") && !n.starts_with("actor-worker-"))
        {
            continue; // another program's
        }
        if tags {
            report.left.push((
                shown,
                "it has service or port tags (a complete node with damaged monitor files); iceoryx2 cannot clean it and removing its files would leave it registered in its services".into(),
            ));
            continue;
        }
        if files.iter().any(|f| open.contains(f)) {
            continue; // being made right now
        }
        if files.is_empty()
            && meta
                .first()
                .and_then(|m| m.modified().ok())
                .and_then(|t| t.elapsed().ok())
                .is_none_or(|age| age < EMPTY_DIR_AGE)
        {
            continue;
        }
        // Files first, then the directory; one already gone (another cleaner) is fine.
        let mut failed = None;
        for r in files
            .iter()
            .map(std::fs::remove_file)
            .chain(entry.dir.iter().map(std::fs::remove_dir))
        {
            match r {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => failed = failed.or(Some(e)),
                _ => {}
            }
        }
        match failed {
            None => report.removed.push(shown),
            Some(e) => report
                .left
                .push((shown, format!("removing it failed: {e}"))),
        }
    }
    Ok(report)
}

/// The `name = "…"` of a node details file (TOML, written by iceoryx2).
fn details_name(text: &str) -> Option<String> {
    text.lines()
        .find_map(|l| l.trim().strip_prefix("name = "))
        .map(|v| v.trim().trim_matches('"').to_string())
}

/// Every file under `dir` that some process (of those whose descriptors we may read) has open.
fn open_files_under(dir: &Path) -> HashSet<PathBuf> {
    let mut open = HashSet::new();
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return open;
    };
    for p in procs.flatten() {
        let Ok(fds) = std::fs::read_dir(p.path().join("fd")) else {
            continue;
        };
        for fd in fds.flatten() {
            if let Ok(target) = std::fs::read_link(fd.path()) {
                if target.starts_with(dir) {
                    open.insert(target);
                }
            }
        }
    }
    open
}
