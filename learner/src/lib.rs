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
pub mod fused;
pub mod matmul;
pub mod metrics;
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
pub mod threads;
pub mod workers;

/// Sets two things that the C libraries underneath read only once, when the process starts, then
/// executes the program again, once; a setting already in the environment is left alone:
/// - `OMP_WAIT_POLICY=PASSIVE`: libtorch's OpenMP threads sleep, not spin, when they wait. With
///   the spinning default, a learner whose threads share cores with workers or another job
///   collapses (3 updates/s against 13 at one thread, measured with another job on the machine).
/// - `GLIBC_TUNABLES=glibc.malloc.hugetlb=1`: glibc backs the heap that holds the tensors with
///   transparent huge pages where the kernel allows them (`madvise` mode). An update's tensors
///   (tens of MB) outgrow what the TLB covers in 4 KiB pages; measured 8% more critic updates/s
///   (32.3 against 29.8, one thread, four runs each, interleaved).
pub fn restart_with_runtime_settings() {
    let mut set = vec![];
    for (key, value) in [
        ("OMP_WAIT_POLICY", "PASSIVE"),
        ("GLIBC_TUNABLES", "glibc.malloc.hugetlb=1"),
    ] {
        if std::env::var_os(key).is_none() {
            std::env::set_var(key, value);
            set.push(format!("{key}={value}"));
        }
    }
    if set.is_empty() {
        return;
    }
    let exe = std::env::current_exe().unwrap_or_else(|_| "/proc/self/exe".into());
    let err = std::os::unix::process::CommandExt::exec(
        std::process::Command::new(exe).args(std::env::args_os().skip(1)),
    );
    // Only reached if exec failed: go on with the libraries' defaults.
    eprintln!(
        "note: could not restart with {} ({err}); going on with the libraries' defaults",
        set.join(" ")
    );
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
