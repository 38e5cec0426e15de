//! The SELKD learner: it holds the N critics and the K actors' training copies, stores every
//! worker's transitions in one replay buffer, computes the in-target max-min targets, trains, and
//! hands back weights and the Monte-Carlo ranking that picks the actor everyone distils toward.
//!
//! The algorithm itself reads top to bottom in [`selkd`]; each concept it uses has its own module.

pub mod bench;
pub mod checkpoint;
pub mod config;
pub mod distillation;
pub mod ensemble;
pub mod optim;
pub mod ranking;
pub mod rate_limit;
pub mod replay;
pub mod rollout;
pub mod selkd;
pub mod service;
pub mod squashed_gaussian;
pub mod targets;

/// Keeps freed tensor memory in the process instead of returning it to the kernel: without this,
/// glibc serves every large tensor with a fresh `mmap`, and the page faults of refilling those
/// pages cost about a tenth of a training step on CPU.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}
