//! How the learner uses a CPU's cores: the critics' members split over threads of its own, each
//! running libtorch on one thread, rather than libtorch's threads inside every operation.
//!
//! An update is hundreds of small operations; with libtorch's threads each one is a parallel
//! region whose threads must be woken (OpenMP's passive wait, which keeps a loaded machine from
//! collapsing) or spin (which collapses it: 49–80 updates/s at two threads with another process
//! holding a core, against 87–193 passive). Splitting the critics' members instead costs one
//! wake-up per update and leaves each thread a long, independent run of work; a thread that
//! shares its core with another process slows its own half only.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Mutex};

static THREADS: AtomicUsize = AtomicUsize::new(1);

/// Uses `n` threads (0: one per core): libtorch on one thread, and up to `n` threads of our own
/// for the parts of an update that split by ensemble member.
pub fn set(n: usize) {
    let n = if n == 0 { cores() } else { n };
    flush_subnormals();
    THREADS.store(n, Ordering::Relaxed);
    tch::set_num_threads(1);
}

/// From now on, this thread reads and writes subnormal floats as zero (x86's FTZ and DAZ modes,
/// what `torch.set_flush_denormal(True)` sets). In training, values decaying toward zero (Adam's
/// first moment shrinks by β₁ = 0.9 a step where a gradient is zero; gradients and activations
/// of nearly dead units) pass through the subnormal range, where every operation on them costs a
/// microcode assist of ~100 cycles on Intel CPUs: Adam alone took 46% of a hopper run's learner
/// time, against 4% on the benchmark's random data. A subnormal value is below 1.2e-38, so
/// flushing it moves no result above float32 round-off.
pub fn flush_subnormals() {
    #[cfg(target_arch = "x86_64")]
    #[allow(deprecated)] // the MXCSR intrinsics: deprecated in favour of inline assembly
    {
        use std::arch::x86_64::{_mm_getcsr, _mm_setcsr};
        const FTZ_DAZ: u32 = 0x8040;
        // SAFETY: sets two mode bits of this thread's SSE control register.
        unsafe { _mm_setcsr(_mm_getcsr() | FTZ_DAZ) };
    }
}

/// The cores this process may run on.
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The threads [`set`] asked for.
pub fn get() -> usize {
    THREADS.load(Ordering::Relaxed)
}

/// `members` split into at most [`get`] contiguous parts of near-equal size, each `(start, len)`.
pub fn member_parts(members: usize) -> Vec<(usize, usize)> {
    split(members, PARTS.with(|p| p.get()).unwrap_or_else(get))
}

thread_local! {
    /// A test's own number of parts, for this thread only (tests run side by side).
    static PARTS: std::cell::Cell<Option<usize>> = const { std::cell::Cell::new(None) };
}

/// Runs `f` with the members split in `parts` parts on this thread.
#[cfg(test)]
pub(crate) fn with_parts<R>(parts: usize, f: impl FnOnce() -> R) -> R {
    PARTS.with(|p| p.set(Some(parts)));
    let r = f();
    PARTS.with(|p| p.set(None));
    r
}

fn split(members: usize, parts: usize) -> Vec<(usize, usize)> {
    let parts = parts.min(members).max(1);
    (0..parts)
        .map(|p| {
            let start = p * members / parts;
            (start, (p + 1) * members / parts - start)
        })
        .collect()
}

/// Runs `job` on each item, the first on this thread and the others on the learner's worker
/// threads (started once and kept: a thread started per call would also start libtorch's and
/// oneDNN's per-thread state afresh each time), and returns the results in order. A panic in a
/// job is raised here.
pub fn run_parts<J, R>(jobs: Vec<J>, job: fn(J) -> R) -> Vec<R>
where
    J: Send + 'static,
    R: Send + 'static,
{
    let mut jobs = jobs.into_iter();
    let Some(first) = jobs.next() else {
        return vec![];
    };
    let (done, results) = mpsc::channel();
    let mut sent = 0;
    {
        let mut workers = WORKERS.lock().unwrap_or_else(|e| e.into_inner());
        for (i, j) in jobs.enumerate() {
            if workers.len() <= i {
                workers.push(Worker::start());
            }
            let done = done.clone();
            let task: Task = Box::new(move || {
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| job(j)));
                let _ = done.send((i, r));
            });
            workers[i]
                .tasks
                .send(task)
                .expect("learner worker thread gone");
            sent += 1;
        }
    }
    let first = job(first);
    let mut others: Vec<Option<R>> = (0..sent).map(|_| None).collect();
    for _ in 0..sent {
        let (i, r) = receive(&results).expect("learner worker thread gone");
        match r {
            Ok(r) => others[i] = Some(r),
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }
    std::iter::once(first)
        .chain(others.into_iter().map(|r| r.expect("every part answered")))
        .collect()
}

/// The next message, or `None` once every sender is gone. It polls for a little while before
/// it sleeps: parts of one update arrive tens of microseconds apart, and a sleeping thread takes
/// about as long to wake; the polling is short enough to cost little where another process holds
/// the core.
fn receive<T>(from: &mpsc::Receiver<T>) -> Option<T> {
    let start = std::time::Instant::now();
    while start.elapsed() < POLL_FOR {
        match from.try_recv() {
            Ok(message) => return Some(message),
            Err(mpsc::TryRecvError::Disconnected) => return None,
            Err(mpsc::TryRecvError::Empty) => std::hint::spin_loop(),
        }
    }
    from.recv().ok()
}

const POLL_FOR: std::time::Duration = std::time::Duration::from_micros(50);

type Task = Box<dyn FnOnce() + Send>;

/// A thread that runs the tasks it is sent, one after another, with autograd off.
struct Worker {
    tasks: mpsc::Sender<Task>,
}

impl Worker {
    fn start() -> Self {
        let (tasks, inbox) = mpsc::channel::<Task>();
        std::thread::Builder::new()
            .name("selkd-learner-part".into())
            .spawn(move || {
                flush_subnormals();
                let _no_grad = tch::no_grad_guard();
                while let Some(task) = receive(&inbox) {
                    task();
                }
            })
            .expect("could not start a learner thread");
        Self { tasks }
    }
}

static WORKERS: Mutex<Vec<Worker>> = Mutex::new(Vec::new());

#[cfg(test)]
mod tests {
    use super::*;

    /// On a thread of its own, so that the other tests keep the default mode.
    #[test]
    fn subnormals_read_and_write_as_zero_after_flush_subnormals() {
        let sub = f32::MIN_POSITIVE / 4.0;
        assert!(sub > 0.0 && !sub.is_normal());
        std::thread::spawn(move || {
            let (x, one) = (std::hint::black_box(sub), std::hint::black_box(1.0f32));
            assert_eq!(x * one, x, "subnormals are kept by default");
            flush_subnormals();
            let tiny = std::hint::black_box(f32::MIN_POSITIVE);
            assert_eq!(x * one, 0.0, "a subnormal input reads as zero");
            assert_eq!(
                tiny * std::hint::black_box(0.25f32),
                0.0,
                "a subnormal result is zero"
            );
            assert_eq!(tiny * one, tiny, "normal numbers are untouched");
        })
        .join()
        .unwrap();
    }

    #[test]
    fn parts_cover_the_members_once_in_order() {
        assert_eq!(split(10, 3), vec![(0, 3), (3, 3), (6, 4)]);
        assert_eq!(split(2, 3), vec![(0, 1), (1, 1)]);
        assert_eq!(split(10, 1), vec![(0, 10)]);
        assert_eq!(split(10, 0), vec![(0, 10)]);
        let squares = run_parts(vec![1, 2, 3, 4], |x: i32| x * x);
        assert_eq!(squares, vec![1, 4, 9, 16]);
    }
}
