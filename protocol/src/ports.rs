//! The ports each side of a run opens, in one place: [`WorkerPorts`] and [`LearnerPorts`]. Each
//! service is opened through [`services`](crate::services), so both sides ask iceoryx2 for the
//! same settings.

use crate::services::{self, Error, Listener, Node, Notifier, Publisher, Subscriber};
use crate::{
    Control, CursorHeader, Ranking, Report, Services, TransitionHeader, WeightsHeader,
    TRANSITION_BUFFER,
};
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::AllocationStrategy;

/// Names the service in an error opening it.
fn opening(what: &'static str) -> impl Fn(Error) -> Error {
    move |e| format!("opening the {what} service: {e}").into()
}

/// A worker's ports. `control` is opened first, on its own ([`WorkerPorts::control`]): the
/// learner announces the run there, and the other services are sized by its number of actors.
pub struct WorkerPorts {
    /// The learner's standing orders (history 1: the current one arrives at once).
    pub control: Subscriber<Control>,
    /// This actor's weights.
    pub weights: Subscriber<[f32], WeightsHeader>,
    /// Where this actor's rollout continues; also tells the worker another process took over.
    pub cursor: Subscriber<[f32], CursorHeader>,
    pub transitions: Publisher<[f32], TransitionHeader>,
    pub reports: Publisher<Report>,
    /// Wakes the learner after a transition or a report.
    pub to_learner: Notifier,
    /// Woken by the learner's news (weights, control).
    pub wake: Listener,
}

impl WorkerPorts {
    /// The worker's first port: where it waits for the learner's [`Control`].
    pub fn control(node: &Node, svc: &Services) -> Result<Subscriber<Control>, Error> {
        Ok(services::control(node, svc)
            .map_err(opening("control"))?
            .subscriber_builder()
            .create()?)
    }

    /// The rest of worker `worker`'s ports, in a run of `actors` actors whose transition rows are
    /// `row_len` values long.
    pub fn open(
        node: &Node,
        svc: &Services,
        control: Subscriber<Control>,
        worker: usize,
        actors: usize,
        row_len: usize,
    ) -> Result<Self, Error> {
        Ok(Self {
            control,
            weights: services::weights(node, svc, worker)
                .map_err(opening("weights"))?
                .subscriber_builder()
                .create()?,
            transitions: services::transitions(node, svc, actors)
                .map_err(opening("transitions"))?
                .publisher_builder()
                .initial_max_slice_len(row_len)
                .create()?,
            reports: services::reports(node, svc, actors)
                .map_err(opening("reports"))?
                .publisher_builder()
                .create()?,
            to_learner: services::to_learner(node, svc, actors)
                .map_err(opening("to-learner"))?
                .notifier_builder()
                .create()?,
            wake: services::to_workers(node, svc)
                .map_err(opening("to-workers"))?
                .listener_builder()
                .create()?,
            cursor: services::cursor(node, svc, worker)
                .map_err(opening("cursor"))?
                .subscriber_builder()
                .create()?,
        })
    }
}

/// The learner's ports.
pub struct LearnerPorts {
    pub transitions: Subscriber<[f32], TransitionHeader>,
    pub reports: Subscriber<Report>,
    /// Woken by any worker's transition or report.
    pub wake: Listener,
    /// Wakes the workers after news (a cursor, control).
    pub to_workers: Notifier,
    pub control: Publisher<Control>,
    pub ranking: Publisher<Ranking>,
    /// Per actor.
    pub weights: Vec<Publisher<[f32], WeightsHeader>>,
    /// Per actor.
    pub cursors: Vec<Publisher<[f32], CursorHeader>>,
}

impl LearnerPorts {
    /// The ports of a run of `actors` actors whose flat weights are `weights_len` values long.
    pub fn open(
        node: &Node,
        svc: &Services,
        actors: usize,
        weights_len: usize,
    ) -> Result<Self, Error> {
        // In the order the learner has always opened them.
        let transitions = services::transitions(node, svc, actors)
            .map_err(opening("transitions"))?
            .subscriber_builder()
            .buffer_size(TRANSITION_BUFFER)
            .create()?;
        let reports = services::reports(node, svc, actors)
            .map_err(opening("reports"))?
            .subscriber_builder()
            .create()?;
        let wake = services::to_learner(node, svc, actors)
            .map_err(opening("to-learner"))?
            .listener_builder()
            .create()?;
        let to_workers = services::to_workers(node, svc)
            .map_err(opening("to-workers"))?
            .notifier_builder()
            .create()?;
        let control = services::control(node, svc)
            .map_err(opening("control"))?
            .publisher_builder()
            .create()?;
        let ranking = services::ranking(node, svc)
            .map_err(opening("ranking"))?
            .publisher_builder()
            .create()?;
        let weights = (0..actors)
            .map(|i| {
                Ok(services::weights(node, svc, i)
                    .map_err(opening("weights"))?
                    .publisher_builder()
                    .initial_max_slice_len(weights_len)
                    .create()?)
            })
            .collect::<Result<Vec<_>, Error>>()?;
        // A cursor holds an episode's actions so far: its length grows, so its samples do.
        let cursors = (0..actors)
            .map(|i| {
                Ok(services::cursor(node, svc, i)
                    .map_err(opening("cursor"))?
                    .publisher_builder()
                    .initial_max_slice_len(4096)
                    .allocation_strategy(AllocationStrategy::PowerOfTwo)
                    .create()?)
            })
            .collect::<Result<Vec<_>, Error>>()?;
        Ok(Self {
            transitions,
            reports,
            wake,
            to_workers,
            control,
            ranking,
            weights,
            cursors,
        })
    }

    /// Every actor's weights, `weights(i)` for actor `i`, as `version`.
    pub fn publish_weights(
        &self,
        version: u64,
        weights: impl Fn(usize) -> Vec<f32>,
    ) -> Result<(), Error> {
        for i in 0..self.weights.len() {
            self.publish_actor_weights(i, version, &weights(i))?;
        }
        Ok(())
    }

    /// Actor `actor`'s weights `w`, as `version`.
    pub fn publish_actor_weights(
        &self,
        actor: usize,
        version: u64,
        w: &[f32],
    ) -> Result<(), Error> {
        let mut sample = self.weights[actor].loan_slice_uninit(w.len())?;
        *sample.user_header_mut() = WeightsHeader {
            actor: actor as u32,
            version,
        };
        sample.write_from_slice(w).send()?;
        Ok(())
    }

    /// A worker's cursor and the actions of its episode so far, and the wake-up to read them.
    pub fn send_cursor(&self, cursor: CursorHeader, actions: &[f32]) -> Result<(), Error> {
        let p = &self.cursors[cursor.worker as usize];
        // The worker subscribed just before its hello: make sure the sample reaches it.
        p.update_connections()?;
        let mut sample = p.loan_slice_uninit(actions.len())?;
        *sample.user_header_mut() = cursor;
        sample.write_from_slice(actions).send()?;
        self.to_workers.notify()?;
        Ok(())
    }

    /// Late (or restarted) subscribers get the latest control, ranking and weights from the
    /// publishers' history only once a publisher looks for new connections.
    pub fn connect_latecomers(&self) -> Result<(), Error> {
        self.control.update_connections()?;
        self.ranking.update_connections()?;
        for p in &self.weights {
            p.update_connections()?;
        }
        Ok(())
    }
}
