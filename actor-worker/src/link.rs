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
        let ours = &self.ours;
        self.ports.reports.send_copy(Report {
            kind,
            worker: self.args.worker as u32,
            generation: self.args.generation,
            incarnation: self.incarnation,
            protocol_version: ours.protocol_version,
            env: ours.env,
            env_options: ours.env_options,
            obs_dim: ours.obs_dim,
            act_dim: ours.act_dim,
            weights_version: self.weights_version,
            epoch,
            episodes,
            mean_return,
            success_rate,
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
