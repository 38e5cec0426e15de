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

#[cfg(test)]
mod tests {
    use super::*;
    use selkd_protocol::{services, Services};

    fn run_id(test: &str) -> String {
        format!("l{}-{test}", std::process::id())
    }

    #[test]
    fn a_gone_worker_gives_its_unused_grant_back_and_the_others_keep_theirs() {
        let run = run_id("gone");
        let mut ws = Workers::new(5, Duration::from_secs(10), None);
        let long_ago = Instant::now() - 2 * QUIET;
        // 0: quiet, unused grant, node alive (stopped or busy): keeps it.
        // 1: quiet, unused grant, no node (killed): gives it back.
        // 2: quiet, no node, but its grant is used up: nothing to give.
        // 3: no node, unused grant, but heard just now: not quiet.
        // 4: quiet, no node, unused grant, but never joined (still starting): not looked at.
        ws.accepting = vec![Some(10), Some(11), Some(12), Some(13), None];
        ws.granted = vec![100; 5];
        for (w, sent) in [40, 40, 100, 40, 40].into_iter().enumerate() {
            ws.rollouts[w].sent = sent;
        }
        ws.last_heard = vec![long_ago, long_ago, long_ago, Instant::now(), long_ago];
        let _alive = services::node(&selkd_protocol::worker_node_name(&run, 0)).unwrap();
        ws.take_back_grants_of_gone_workers(&run);
        assert_eq!(ws.granted, vec![100, 40, 100, 100, 100]);
        assert_eq!(ws.benched, vec![false, true, false, false, false]);
        // Heard from again (its successor joined): no longer benched.
        ws.heard(1);
        assert!(!ws.benched[1]);
        assert!(ws.last_heard[1].elapsed() < QUIET);
    }

    /// The grants' arithmetic is `rate_limit::top_up`'s; here, who takes: not a benched worker,
    /// nor a quiet one holding an unused grant. Expected values worked out by hand.
    #[test]
    fn grants_go_to_the_workers_that_can_take_them() {
        let mut ws = Workers::new(3, Duration::from_secs(10), None);
        ws.benched[1] = true;
        // Takers 0 and 2 share an allowance of 10: 5 each.
        assert_eq!(ws.top_up_grants(10, 1000), &[5, 0, 5]);
        assert_eq!(ws.grant_turn, 1);
        // Worker 0 used its 5 and waits for more, quiet as a waiting worker is; worker 2 holds
        // its 5 and went quiet: only worker 0 takes, up to the allowance less what worker 2
        // holds.
        ws.rollouts[0].sent = 5;
        ws.last_heard[0] = Instant::now() - 2 * QUIET;
        ws.last_heard[2] = Instant::now() - 2 * QUIET;
        assert_eq!(ws.top_up_grants(10, 1000), &[10, 0, 5]);
        assert_eq!(ws.grant_turn, 2);
        // Workers heard from recently take even while they hold some of their grant: all three
        // take. Held 5, 0, 5 (10 outstanding), so 20 of the 30 are free; each taker's share is
        // (20 + 10) / 3 = 10, topped up from worker 2 (the turn) on: 2 gets 5 (to 10), 0 gets 5
        // (10 + 5 = 15), 1 gets 10.
        ws.heard(0);
        ws.heard(2);
        ws.benched[1] = false;
        assert_eq!(ws.top_up_grants(30, 1000), &[15, 10, 10]);
        assert_eq!(ws.grant_turn, 0, "the round-robin's start turns");
    }

    #[test]
    fn a_worker_waiting_for_its_cursor_gets_the_records_end_and_is_accepted() {
        let svc = Services::new(&run_id("cursor"));
        let node = services::node(&proto::learner_node_name(&svc.run_id)).unwrap();
        let ports = LearnerPorts::open(&node, &svc, 2, 4).unwrap();
        let worker = services::node(&proto::worker_node_name(&svc.run_id, 1)).unwrap();
        let cursors = services::cursor(&worker, &svc, 1)
            .unwrap()
            .subscriber_builder()
            .create()
            .unwrap();
        let mut ws = Workers::new(2, Duration::from_secs(10), None);
        ws.rollouts[1] = Rollout {
            sent: 7,
            episode: 2,
            step: 3,
            actions: vec![0.5, -0.5, 0.25],
        };
        ws.cursor_due[1] = Some(42);
        ws.send_due_cursors(&ports).unwrap();
        let s = cursors.receive().unwrap().expect("worker 1's cursor");
        let h = *s.user_header();
        assert_eq!((h.worker, h.incarnation), (1, 42));
        assert_eq!((h.sent, h.episode, h.step), (7, 2, 3));
        assert_eq!(s.payload(), &[0.5, -0.5, 0.25]);
        assert_eq!(ws.accepting, vec![None, Some(42)]);
        assert_eq!(ws.cursor_due, vec![None, None]);
    }
}
