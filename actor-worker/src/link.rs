//! The worker's side of the run over iceoryx2: the learner's announcement, this actor's
//! weights, the cursor that says where its rollout continues, and what it sends back.

use crate::rollout::{mix, Taken};
use crate::{Args, CannotJoin};
use anyhow::{bail, Context, Result};
use iceoryx2::prelude::*;
use selkd_policy::{Actor, ActorLayout};
use selkd_protocol::services::Node;
use selkd_protocol::{
    check_peer, Control, CursorHeader, Handshake, Report, ReportKind, Services, TransitionHeader,
    TransitionRow, WorkerPorts,
};
use std::time::{Duration, Instant};

/// A worker joined to its run: its ports, the learner's latest [`Control`], its actor.
pub struct Link<'a> {
    args: &'a Args,
    ports: WorkerPorts,
    /// The learner's standing orders, as last received.
    pub control: Control,
    layout: ActorLayout,
    actor: Option<Actor>,
    pub weights_version: u64,
    /// Tells the learner this process from an earlier (or a duplicate) one of the same actor.
    incarnation: u64,
    ours: Handshake,
}

impl<'a> Link<'a> {
    /// Waits for the learner's announcement (history 1), checks that this worker fits the run
    /// (`ours`: its env, options and sizes), opens its ports and waits for its actor's weights.
    pub fn join(args: &'a Args, node: &Node, svc: &Services, ours: Handshake) -> Result<Self> {
        let control_sub = WorkerPorts::control(node, svc).map_err(|e| anyhow::anyhow!("{e}"))?;
        let deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
        let control: Control = loop {
            if let Some(s) = control_sub.receive()? {
                break *s.payload();
            }
            if Instant::now() > deadline {
                bail!("no learner for run `{}` answered within {} s; start `learner` first (or use `selkd train`)", args.run_id, args.connect_timeout);
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        check_peer(&control.handshake(), &ours)?;
        if args.worker >= control.actors as usize {
            let msg = format!(
                "--worker {} is out of range: the run has {} actors (0..{})",
                args.worker,
                control.actors,
                control.actors - 1
            );
            return Err(CannotJoin(msg).into());
        }
        let hidden: Vec<usize> = control.hidden[..control.hidden_layers as usize]
            .iter()
            .map(|&h| h as usize)
            .collect();
        let row = TransitionRow {
            obs_dim: ours.obs_dim as usize,
            act_dim: ours.act_dim as usize,
        };
        let ports = WorkerPorts::open(
            node,
            svc,
            control_sub,
            args.worker,
            control.actors as usize,
            row.len(),
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?;
        let mut link = Self {
            args,
            ports,
            control,
            layout: ActorLayout::new(row.obs_dim, row.act_dim, &hidden),
            actor: None,
            weights_version: 0,
            incarnation: new_incarnation(),
            ours,
        };
        // Rejoin with the latest weights before doing anything else (they are in the history).
        let deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
        while link.actor.is_none() {
            link.receive_weights()?;
            if Instant::now() > deadline {
                bail!(
                    "the learner announced the run but sent no weights for actor {} within {} s",
                    args.worker,
                    args.connect_timeout
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(link)
    }

    /// Says hello until the learner answers with this process's cursor: where its record of
    /// this actor's rollout ends, with the current episode's actions so far.
    pub fn wait_for_cursor(&self) -> Result<(CursorHeader, Vec<f32>)> {
        let deadline = Instant::now() + Duration::from_secs_f64(self.args.connect_timeout);
        let mut last_hello: Option<Instant> = None;
        loop {
            // Hello again now and then: a learner that was busy (or just started) may have missed it.
            if last_hello.is_none_or(|t| t.elapsed() > Duration::from_secs(1)) {
                self.report(ReportKind::Hello, 0, 0, f64::NAN, f64::NAN)?;
                last_hello = Some(Instant::now());
            }
            if let Some(c) = self.latest_cursor()? {
                return Ok(c);
            }
            if Instant::now() > deadline {
                bail!(
                    "the learner of run `{}` did not answer actor {}'s hello within {} s",
                    self.args.run_id,
                    self.args.worker,
                    self.args.connect_timeout
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The actor, with the newest weights received.
    pub fn policy(&self) -> &Actor {
        self.actor
            .as_ref()
            .expect("join waits for the first weights")
    }

    /// Takes in what the learner sent since the last call: weights, then orders.
    pub fn receive(&mut self) -> Result<()> {
        self.receive_weights()?;
        while let Some(s) = self.ports.control.receive()? {
            self.control = *s.payload();
        }
        Ok(())
    }

    fn receive_weights(&mut self) -> Result<()> {
        while let Some(s) = self.ports.weights.receive()? {
            match &mut self.actor {
                Some(a) => a.set_params(s.payload())?,
                None => {
                    self.actor = Some(Actor::from_flat(self.layout.clone(), s.payload().to_vec())?)
                }
            }
            self.weights_version = s.user_header().version;
        }
        Ok(())
    }

    /// A report to the learner (a hello, or an evaluation's result), and its wake-up.
    pub fn report(
        &self,
        kind: ReportKind,
        epoch: u64,
        episodes: u32,
        mean_return: f64,
        success_rate: f64,
    ) -> Result<()> {
        let from = Report::hello(
            self.ours,
            self.args.worker as u32,
            self.args.generation,
            self.incarnation,
        );
        self.ports.reports.send_copy(Report {
            kind,
            weights_version: self.weights_version,
            epoch,
            episodes,
            mean_return,
            success_rate,
            ..from
        })?;
        self.ports.to_learner.notify()?;
        Ok(())
    }

    /// One transition (`row`, at `taken`'s place) to the learner, and its wake-up.
    pub fn publish(&self, taken: &Taken, row: &[f32]) -> Result<()> {
        let mut sample = self.ports.transitions.loan_slice_uninit(row.len())?;
        *sample.user_header_mut() = TransitionHeader {
            worker: self.args.worker as u32,
            generation: self.args.generation,
            incarnation: self.incarnation,
            episode: taken.episode,
            step: taken.step,
            policy_version: if taken.warmup {
                0
            } else {
                self.weights_version
            },
            obs_dim: self.ours.obs_dim,
            act_dim: self.ours.act_dim,
            episode_return: taken.episode_return,
        };
        sample.write_from_slice(row).send()?;
        self.ports.to_learner.notify()?;
        Ok(())
    }

    /// Sleeps until the learner says something, or `timeout`.
    pub fn wait(&self, timeout: Duration) -> Result<()> {
        selkd_protocol::wait_for_wake(&self.ports.wake, timeout)?;
        Ok(())
    }

    /// The newest cursor the learner published for this process, with its actions.
    fn latest_cursor(&self) -> Result<Option<(CursorHeader, Vec<f32>)>> {
        let mut found = None;
        while let Some(s) = self.ports.cursor.receive()? {
            if s.user_header().incarnation == self.incarnation {
                found = Some((*s.user_header(), s.payload().to_vec()));
            }
        }
        Ok(found)
    }

    /// The incarnation of a cursor published for another process of this actor, if any: the
    /// learner has handed the actor to it.
    pub fn newer_cursor(&self) -> Result<Option<u64>> {
        let mut other = None;
        while let Some(s) = self.ports.cursor.receive()? {
            let i = s.user_header().incarnation;
            other = (i != self.incarnation).then_some(i);
        }
        Ok(other)
    }
}

/// Random for each process: tells the learner this process from an earlier (or a duplicate) one.
fn new_incarnation() -> u64 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    mix(&[std::process::id() as u64, nanos])
}

/// Whether a live `learner` node exists (dead ones are cleaned up by iceoryx2 as it lists them).
pub fn learner_alive(run_id: &str) -> Result<bool> {
    let name = selkd_protocol::learner_node_name(run_id);
    let mut alive = false;
    Node::list(Config::global_config(), |state| {
        if let NodeState::Alive(view) = state {
            use iceoryx2::node::NodeView;
            if view
                .details()
                .as_ref()
                .is_some_and(|d| d.name().to_string() == name)
            {
                alive = true;
            }
        }
        CallbackProgression::Continue
    })
    .context("listing iceoryx2 nodes")?;
    Ok(alive)
}

#[cfg(test)]
mod tests {
    //! The worker's side against the learner's real ports (iceoryx2, in this process): what it
    //! takes from the learner and what it sends back, field by field.
    use super::*;
    use selkd_protocol::{services, LearnerPorts, Name, ProtocolError};

    const LAYOUT: (usize, usize, [usize; 1]) = (3, 1, [4]);

    fn args(run_id: &str, worker: usize, connect_timeout: f64) -> Args {
        Args {
            run_id: run_id.into(),
            worker,
            env: "pendulum".into(),
            env_options: "{}".into(),
            generation: 3,
            connect_timeout,
        }
    }

    fn control(actors: u32, stop: u32) -> Control {
        let mut hidden = [0; selkd_protocol::MAX_HIDDEN_LAYERS];
        hidden[0] = LAYOUT.2[0] as u32;
        Control {
            actors,
            env: Name::new("pendulum"),
            env_options: 7,
            obs_dim: LAYOUT.0 as u32,
            act_dim: LAYOUT.1 as u32,
            seed: 1,
            hidden,
            hidden_layers: 1,
            max_policy_lag: 1,
            eval_episodes: 1,
            stop,
            ..Default::default()
        }
    }

    fn ours() -> Handshake {
        Handshake::ours("pendulum", 7, LAYOUT.0, LAYOUT.1)
    }

    fn num_params() -> usize {
        ActorLayout::new(LAYOUT.0, LAYOUT.1, &LAYOUT.2).num_params()
    }

    /// Distinct values per version, so a test sees which weights the worker holds.
    fn params(version: u64) -> Vec<f32> {
        (0..num_params())
            .map(|i| version as f32 + i as f32 * 1e-3)
            .collect()
    }

    fn send_weights(ports: &LearnerPorts, actor: usize, version: u64) {
        ports
            .publish_actor_weights(actor, version, &params(version))
            .unwrap();
    }

    /// The learner's node and ports for a run of 2 actors, its control announced.
    fn learner(test: &str) -> (Services, Node, LearnerPorts) {
        let svc = Services::new(&format!("w{}-{test}", std::process::id()));
        let node = services::node(&selkd_protocol::learner_node_name(&svc.run_id)).unwrap();
        let ports = LearnerPorts::open(&node, &svc, 2, num_params()).unwrap();
        ports.control.send_copy(control(2, 0)).unwrap();
        (svc, node, ports)
    }

    /// What the worker (in its own thread: iceoryx2's ports stay in the thread that made them)
    /// tells the test.
    #[derive(Debug)]
    enum Seen {
        Weights(u64, Vec<f32>, Box<Control>),
        Done,
        Takeover(Option<u64>, Option<u64>),
        Cursor(CursorHeader, Vec<f32>),
        Waited(Duration),
    }

    /// Plays the learner's part while waiting for the worker's next word: it connects late
    /// subscribers (they get the control and weights from the publishers' history), as the
    /// learner's loop does.
    fn next(ports: &LearnerPorts, from: &std::sync::mpsc::Receiver<Seen>) -> Seen {
        let start = Instant::now();
        loop {
            ports.connect_latecomers().unwrap();
            match from.recv_timeout(Duration::from_millis(10)) {
                Ok(seen) => return seen,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    assert!(
                        start.elapsed() < Duration::from_secs(30),
                        "the worker is stuck"
                    )
                }
                Err(e) => panic!("the worker thread failed: {e}"),
            }
        }
    }

    /// Joins worker `worker` of the run in a thread and returns its error, classified.
    fn join_error(ports: &LearnerPorts, svc: &Services, worker: usize, ours: Handshake) -> String {
        worker_error(ports, svc, worker, ours, 0.3, |_| Ok(()))
    }

    /// Joins worker `worker` of the run in a thread with `connect_timeout`, then does `then`;
    /// returns the first error, classified ("joined" if there was none).
    fn worker_error(
        ports: &LearnerPorts,
        svc: &Services,
        worker: usize,
        ours: Handshake,
        connect_timeout: f64,
        then: impl FnOnce(&Link) -> Result<()> + Send + 'static,
    ) -> String {
        let run_id = svc.run_id.clone();
        let t = std::thread::spawn(move || {
            let svc = Services::new(&run_id);
            let args = args(&run_id, worker, connect_timeout);
            let node = services::node(&format!("wj-{worker}-{run_id}")).unwrap();
            match Link::join(&args, &node, &svc, ours).and_then(|link| then(&link)) {
                Ok(()) => "joined".to_string(),
                Err(e) if e.downcast_ref::<ProtocolError>().is_some() => format!("protocol: {e}"),
                Err(e) if e.downcast_ref::<CannotJoin>().is_some() => format!("cannot join: {e}"),
                Err(e) => format!("other: {e}"),
            }
        });
        let start = Instant::now();
        while !t.is_finished() {
            ports.connect_latecomers().unwrap();
            assert!(
                start.elapsed() < Duration::from_secs(10 + connect_timeout as u64),
                "the worker waits past its connect timeout"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        t.join().unwrap()
    }

    #[test]
    fn a_worker_takes_the_learners_orders_and_weights_and_sends_back_what_it_did() {
        let (svc, _learner_node, ports) = learner("link");
        send_weights(&ports, 0, 4);
        send_weights(&ports, 1, 5);
        let (to_test, from_worker) = std::sync::mpsc::channel();
        let (go, wait_go) = std::sync::mpsc::channel::<()>();
        let run_id = svc.run_id.clone();
        let worker = std::thread::spawn(move || {
            let svc = Services::new(&run_id);
            let args = args(&run_id, 1, 5.0);
            let node = services::node(&selkd_protocol::worker_node_name(&run_id, 1)).unwrap();
            let mut link = Link::join(&args, &node, &svc, ours()).unwrap();
            let held = |link: &Link| {
                Seen::Weights(
                    link.weights_version,
                    link.policy().params().to_vec(),
                    Box::new(link.control),
                )
            };
            to_test.send(held(&link)).unwrap();
            wait_go.recv().unwrap();
            link.receive().unwrap();
            to_test.send(held(&link)).unwrap();
            link.report(ReportKind::Evaluation, 4, 5, 1.5, 0.25)
                .unwrap();
            let row: Vec<f32> = (0..9).map(|v| v as f32).collect();
            for warmup in [false, true] {
                let taken = Taken {
                    episode: 2,
                    step: 7,
                    warmup,
                    episode_return: -3.5,
                };
                link.publish(&taken, &row).unwrap();
            }
            to_test.send(Seen::Done).unwrap();
            wait_go.recv().unwrap();
            let first = link.newer_cursor().unwrap();
            to_test
                .send(Seen::Takeover(first, link.newer_cursor().unwrap()))
                .unwrap();
            wait_go.recv().unwrap();
            let (h, actions) = link.wait_for_cursor().unwrap();
            to_test.send(Seen::Cursor(h, actions)).unwrap();
        });

        // It joins with its own actor's latest weights (not another actor's) and the orders.
        let Seen::Weights(version, p, c) = next(&ports, &from_worker) else {
            panic!()
        };
        assert_eq!((version, p), (5, params(5)));
        assert_eq!((c.actors, c.stop), (2, 0));

        // News (new weights, a stop), taken in by `receive`.
        send_weights(&ports, 1, 6);
        ports.control.send_copy(control(2, 1)).unwrap();
        go.send(()).unwrap();
        let Seen::Weights(version, p, c) = next(&ports, &from_worker) else {
            panic!()
        };
        assert_eq!((version, p), (6, params(6)));
        assert_eq!(c.stop, 1);

        // A report carries the worker's identity, its handshake and the evaluation; a transition
        // the row as given, its place and the policy that chose its action (0 for a warm-up
        // draw). Each wakes the learner.
        assert!(matches!(next(&ports, &from_worker), Seen::Done));
        let r = *ports
            .reports
            .receive()
            .unwrap()
            .expect("a report")
            .payload();
        assert_eq!(r.kind, ReportKind::Evaluation);
        assert_eq!((r.worker, r.generation), (1, 3));
        assert_ne!(r.incarnation, 0);
        assert_eq!(r.handshake(), ours());
        assert_eq!((r.weights_version, r.epoch, r.episodes), (6, 4, 5));
        assert_eq!((r.mean_return, r.success_rate), (1.5, 0.25));
        for warmup in [false, true] {
            let s = ports.transitions.receive().unwrap().expect("a transition");
            let h = *s.user_header();
            assert_eq!(
                s.payload(),
                &(0..9).map(|v| v as f32).collect::<Vec<_>>()[..]
            );
            assert_eq!(
                (h.worker, h.generation, h.incarnation),
                (1, 3, r.incarnation)
            );
            assert_eq!((h.episode, h.step, h.episode_return), (2, 7, -3.5));
            assert_eq!(h.policy_version, if warmup { 0 } else { 6 });
            assert_eq!((h.obs_dim, h.act_dim), (3, 1));
        }
        let mut wakes = 0;
        ports.wake.try_wait(|_| wakes += 1).unwrap();
        assert!(wakes > 0, "the learner is woken");

        // A cursor for another process of this actor is news of a takeover (once).
        let cursor = |incarnation| CursorHeader {
            worker: 1,
            incarnation,
            sent: 12,
            episode: 1,
            step: 2,
        };
        ports
            .send_cursor(cursor(r.incarnation + 1), &[0.5])
            .unwrap();
        go.send(()).unwrap();
        let Seen::Takeover(first, second) = next(&ports, &from_worker) else {
            panic!()
        };
        assert_eq!((first, second), (Some(r.incarnation + 1), None));
        // Its own cursor ends the wait (a hello is said meanwhile).
        ports
            .send_cursor(cursor(r.incarnation), &[0.25, -0.75])
            .unwrap();
        go.send(()).unwrap();
        let Seen::Cursor(h, actions) = next(&ports, &from_worker) else {
            panic!()
        };
        assert_eq!(
            (h.incarnation, h.sent, h.episode, h.step),
            (r.incarnation, 12, 1, 2)
        );
        assert_eq!(actions, vec![0.25, -0.75]);
        let hello = *ports.reports.receive().unwrap().expect("a hello").payload();
        assert_eq!(
            (hello.kind, hello.worker, hello.incarnation),
            (ReportKind::Hello, 1, r.incarnation)
        );
        worker.join().unwrap();

        assert!(learner_alive(&svc.run_id).unwrap());
        assert!(!learner_alive(&format!("{}-other", svc.run_id)).unwrap());
    }

    /// Worker 0 of the run joins in a thread (connect timeout 10 s) and does `body`, telling
    /// the test what it sees.
    fn worker_0(
        svc: &Services,
        body: impl FnOnce(&Link, &std::sync::mpsc::Sender<Seen>) + Send + 'static,
    ) -> (std::thread::JoinHandle<()>, std::sync::mpsc::Receiver<Seen>) {
        let (to_test, from_worker) = std::sync::mpsc::channel();
        let run_id = svc.run_id.clone();
        let worker = std::thread::spawn(move || {
            let svc = Services::new(&run_id);
            let args = args(&run_id, 0, 10.0);
            let node = services::node(&selkd_protocol::worker_node_name(&run_id, 0)).unwrap();
            let link = Link::join(&args, &node, &svc, ours()).unwrap();
            body(&link, &to_test);
        });
        (worker, from_worker)
    }

    #[test]
    fn a_waiting_worker_sleeps_until_the_learner_says_something() {
        let (svc, _learner_node, ports) = learner("wait");
        send_weights(&ports, 0, 1);
        let (worker, from_worker) = worker_0(&svc, |link, to_test| {
            for timeout in [0.3, 20.0] {
                let start = Instant::now();
                link.wait(Duration::from_secs_f64(timeout)).unwrap();
                to_test.send(Seen::Waited(start.elapsed())).unwrap();
            }
        });
        // Nothing said: it sleeps its whole timeout (not a loop that spins a core).
        let Seen::Waited(quiet) = next(&ports, &from_worker) else {
            panic!()
        };
        assert!(quiet >= Duration::from_millis(290), "woke after {quiet:?}");
        // The learner's wake-up call ends the wait at once.
        std::thread::sleep(Duration::from_millis(200));
        ports.to_workers.notify().unwrap();
        let Seen::Waited(woken) = next(&ports, &from_worker) else {
            panic!()
        };
        assert!(woken < Duration::from_secs(10), "woke after {woken:?}");
        worker.join().unwrap();
    }

    #[test]
    fn a_hello_the_learner_missed_is_said_again_and_one_never_answered_ends_the_wait() {
        // A learner that was busy (or not yet connected) when the first hello came answers a
        // later one: the worker says hello about once a second until it has its cursor.
        let (svc, _learner_node, ports) = learner("hello");
        send_weights(&ports, 0, 1);
        let (worker, from_worker) = worker_0(&svc, |link, to_test| {
            to_test.send(Seen::Done).unwrap();
            let (h, actions) = link.wait_for_cursor().unwrap();
            to_test.send(Seen::Cursor(h, actions)).unwrap();
        });
        assert!(matches!(next(&ports, &from_worker), Seen::Done));

        // Hellos go unanswered until the second.
        let start = Instant::now();
        let mut hellos = Vec::new();
        while hellos.len() < 2 {
            ports.connect_latecomers().unwrap();
            while let Some(r) = ports.reports.receive().unwrap() {
                let r = *r.payload();
                if r.kind == ReportKind::Hello {
                    hellos.push((start.elapsed(), r.incarnation));
                }
            }
            assert!(
                start.elapsed() < Duration::from_secs(5),
                "hellos in 5 s: {hellos:?}"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
        // About a second apart (less by however late this loop saw the first on a busy
        // machine); not a burst.
        let gap = hellos[1].0 - hellos[0].0;
        assert!(gap >= Duration::from_millis(300), "hellos {gap:?} apart");

        let cursor = CursorHeader {
            worker: 0,
            incarnation: hellos[1].1,
            sent: 3,
            episode: 0,
            step: 3,
        };
        ports.send_cursor(cursor, &[0.5]).unwrap();
        let Seen::Cursor(h, actions) = next(&ports, &from_worker) else {
            panic!()
        };
        assert_eq!((h.sent, actions), (3, vec![0.5]));
        worker.join().unwrap();

        // A learner that never answers: the worker gives up after its connect timeout.
        send_weights(&ports, 1, 1);
        let e = worker_error(&ports, &svc, 1, ours(), 0.5, |link| {
            link.wait_for_cursor().map(|_| ())
        });
        assert!(
            e.contains("did not answer actor 1's hello within 0.5 s"),
            "{e}"
        );
    }

    #[test]
    fn a_worker_that_cannot_join_says_why() {
        // No learner at all.
        let svc = Services::new(&format!("w{}-none", std::process::id()));
        let args = args(&svc.run_id, 0, 0.2);
        let node = services::node(&format!("wj-{}", svc.run_id)).unwrap();
        let e = Link::join(&args, &node, &svc, ours())
            .err()
            .expect("no learner");
        assert!(e.to_string().contains("no learner for run"), "{e}");

        let (svc, _node, ports) = learner("refuse");
        // Another env's worker: the handshake's error, naming both sides.
        let e = join_error(&ports, &svc, 0, Handshake::ours("hopper", 7, 11, 3));
        assert!(e.starts_with("protocol:") && e.contains("hopper"), "{e}");
        // An index past the run's actors.
        let e = join_error(&ports, &svc, 2, ours());
        assert!(
            e.starts_with("cannot join:") && e.contains("the run has 2 actors (0..1)"),
            "{e}"
        );
        // Announced, but no weights for this actor.
        send_weights(&ports, 0, 1);
        let e = join_error(&ports, &svc, 1, ours());
        assert!(
            e.starts_with("other:") && e.contains("sent no weights for actor 1"),
            "{e}"
        );
        let e = join_error(&ports, &svc, 0, ours());
        assert_eq!(e, "joined");
    }
}
