//! The SELKD learner: it holds the N critics and the K actors' training copies, stores every
//! worker's transitions in one replay buffer, computes the in-target max-min targets, trains, and
//! hands back weights and the Monte-Carlo ranking that picks the actor everyone distils toward.
//!
//! The algorithm itself reads top to bottom in [`selkd`]; each concept it uses has its own module.

pub mod bench;
pub mod checkpoint;
pub mod config;
pub mod distillation;
pub mod dpp;
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
pub mod tensorboard;

/// Makes libtorch's OpenMP threads sleep, not spin, when they wait: with the default (spinning)
/// policy, a learner whose threads share cores with workers or another job collapses (3 updates/s
/// against 13 at one thread, measured with another job on the machine). libgomp reads the policy
/// once, when it is loaded, before `main`: so without `OMP_WAIT_POLICY` in the environment this sets
/// it and executes the program again, once. A user's own setting is left alone.
pub fn passive_openmp() {
    if std::env::var_os("OMP_WAIT_POLICY").is_some() {
        return;
    }
    std::env::set_var("OMP_WAIT_POLICY", "PASSIVE");
    let exe = std::env::current_exe().unwrap_or_else(|_| "/proc/self/exe".into());
    let err = std::os::unix::process::CommandExt::exec(
        std::process::Command::new(exe).args(std::env::args_os().skip(1)),
    );
    // Only reached if exec failed: go on with the spinning default.
    eprintln!("note: could not restart with OMP_WAIT_POLICY=PASSIVE ({err}); libtorch threads spin while waiting");
}

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
