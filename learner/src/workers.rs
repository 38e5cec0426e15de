//! The learner's side of its K worker connections. A worker's process may die and be restarted
//! at any time: this is what lets its successor continue exactly where the record stands (its
//! cursor), drops what a replaced process still sends, notices a worker the run waits on that
//! went silent, and (async) hands out how far each worker may step, taking a gone worker's unused
//! grant back so the others can finish the run.

use crate::checkpoint::TrainingState;
use crate::rollout::{Pending, Rollout, Watchdog};
use anyhow::{anyhow, Result};
use selkd_protocol::{self as proto, LearnerPorts};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Async: a worker holding an unused grant that has sent nothing for this long is not a taker
/// of new grants, and is looked for among the live iceoryx2 nodes (at most every `GONE_CHECK`).
pub const QUIET: Duration = Duration::from_secs(1);
pub const GONE_CHECK: Duration = Duration::from_millis(250);

/// Per worker (one per actor, indexed alike): its rollout record, which of its processes is
/// accepted, whether one waits for its cursor, when it was last heard from, its async grant,
/// and its sync transitions waiting for their round.
pub struct Workers {
    /// Per worker: where its rollout stands, as received.
    pub rollouts: Vec<Rollout>,
    /// Per worker: the process (incarnation) whose transitions are taken; `None` until one has
    /// its cursor.
    pub accepting: Vec<Option<u64>>,
    /// Per worker: a process that said hello and waits for its cursor.
    pub cursor_due: Vec<Option<u64>>,
    pub watchdog: Watchdog,
    /// Async: per worker, how far it may step (see `rate_limit::top_up`).
    pub granted: Vec<u64>,
    /// Per worker: when the learner last heard from its accepted process.
    pub last_heard: Vec<Instant>,
    /// Async: per worker, its grant was taken back (its process is gone); it gets no new one
    /// until it is heard from again.
    pub benched: Vec<bool>,
    /// Async: where the next top-up's round-robin starts (it turns each time, so remainders do
    /// not always go to worker 0).
    pub grant_turn: usize,
    /// Sync: per worker, its transitions waiting for their lockstep round.
    pub pending: Vec<VecDeque<Pending>>,
}

impl Workers {
    /// `k` workers, continuing a resumed run's records (none has a process accepted yet).
    pub fn new(k: usize, worker_timeout: Duration, resumed: Option<&TrainingState>) -> Self {
        Self {
            rollouts: resumed.map_or_else(|| vec![Rollout::default(); k], |s| s.rollouts()),
            accepting: vec![None; k],
            cursor_due: vec![None; k],
            watchdog: Watchdog::new(k, worker_timeout, Instant::now()),
            granted: resumed.map_or_else(
                || vec![0; k],
                |s| s.rollouts().iter().map(|r| r.sent).collect(),
            ),
            last_heard: vec![Instant::now(); k],
            benched: vec![false; k],
            grant_turn: 0,
            pending: match resumed.filter(|s| s.pending.len() == k) {
                Some(s) => s
                    .pending
                    .iter()
                    .map(|q| q.iter().cloned().collect())
                    .collect(),
                None => (0..k).map(|_| VecDeque::new()).collect(),
            },
        }
    }

    /// Worker `w`'s accepted process sent something.
    pub fn heard(&mut self, w: usize) {
        let now = Instant::now();
        self.watchdog.heard(w, now);
        self.last_heard[w] = now;
        self.benched[w] = false;
    }

    /// A worker that said hello gets its cursor once every transition of its predecessor that
    /// arrived is counted; the predecessor's later ones (if it still lives) are not.
    pub fn send_due_cursors(&mut self, ports: &LearnerPorts) -> Result<()> {
        for w in 0..self.cursor_due.len() {
            if let Some(incarnation) = self.cursor_due[w].take() {
                let r = &self.rollouts[w];
                let cursor = proto::CursorHeader {
                    worker: w as u32,
                    incarnation,
                    sent: r.sent,
                    episode: r.episode,
                    step: r.step,
                };
                ports
                    .send_cursor(cursor, &r.actions)
                    .map_err(|e| anyhow!("sending worker {w}'s cursor: {e}"))?;
                self.accepting[w] = Some(incarnation);
            }
        }
        Ok(())
    }

    /// Async: tops the grants up within the limiter's `allowance` and the run's `total`, and
    /// returns them. No per-worker cap: a share a worker cannot use (it is dead, stopped or busy)
    /// goes to the others.
    pub fn top_up_grants(&mut self, allowance: u64, total: u64) -> &[u64] {
        let k = self.accepting.len();
        let sent: Vec<u64> = self.rollouts.iter().map(|r| r.sent).collect();
        let takers: Vec<bool> = (0..k)
            .map(|w| {
                !self.benched[w]
                    && (self.granted[w] <= sent[w] || self.last_heard[w].elapsed() < QUIET)
            })
            .collect();
        crate::rate_limit::top_up(
            &mut self.granted,
            &sent,
            &takers,
            allowance,
            total,
            self.grant_turn,
        );
        self.grant_turn = (self.grant_turn + 1) % k;
        &self.granted
    }

    /// Async: a worker that holds an unused grant, has been quiet for `QUIET` and has no live
    /// iceoryx2 node is gone (killed; the launcher restarts it after a back-off): its grant goes
    /// back to the pool, so the others can finish the run without waiting for its successor.
    /// A stopped (SIGSTOP) or busy worker's node is alive: its grant stays, and the others
    /// still take its share of the allowance.
    pub fn take_back_grants_of_gone_workers(&mut self, run_id: &str) {
        let k = self.accepting.len();
        let quiet: Vec<usize> = (0..k)
            .filter(|&w| {
                // Only a worker that had joined: one still starting has no node yet.
                self.accepting[w].is_some()
                    && !self.benched[w]
                    && self.granted[w] > self.rollouts[w].sent
                    && self.last_heard[w].elapsed() >= QUIET
            })
            .collect();
        if quiet.is_empty() {
            return;
        }
        let alive = match live_workers(run_id, k) {
            Ok(a) => a,
            Err(e) => {
                tracing::warn!("{e:#}; grants of gone workers stay theirs");
                return;
            }
        };
        for w in quiet.into_iter().filter(|&w| !alive[w]) {
            tracing::info!(
                worker = w,
                "worker {w} is gone with {} env steps of its grant unused; they go to the other workers",
                self.granted[w] - self.rollouts[w].sent
            );
            self.granted[w] = self.rollouts[w].sent;
            self.benched[w] = true;
        }
    }
}

/// Per worker of this run, whether a live iceoryx2 node of its exists.
fn live_workers(run_id: &str, k: usize) -> Result<Vec<bool>> {
    use iceoryx2::node::{NodeState, NodeView};
    use iceoryx2::prelude::{ipc, CallbackProgression, Config as IoxConfig, Node};
    let names: Vec<String> = (0..k).map(|w| proto::worker_node_name(run_id, w)).collect();
    let mut alive = vec![false; k];
    Node::<ipc::Service>::list(IoxConfig::global_config(), |state| {
        if let NodeState::Alive(view) = state {
            if let Some(d) = view.details() {
                let name = d.name().to_string();
                if let Some(w) = names.iter().position(|n| *n == name) {
                    alive[w] = true;
                }
            }
        }
        CallbackProgression::Continue
    })
    .map_err(|e| anyhow!("listing iceoryx2 nodes: {e:?}"))?;
    Ok(alive)
}
