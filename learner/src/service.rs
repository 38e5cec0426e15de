//! The learner process: talks to the actor workers over iceoryx2, fills the replay buffer, runs
//! SELKD's rounds in lockstep (sync) or rate-limited (async), publishes weights, control and the
//! ranking, and writes metrics, progress and checkpoints.

use crate::checkpoint::{self, TrainingState};
use crate::config::{Config, Mode};
use crate::metrics::{self, Intake, MetricsRow, Progress};
use crate::ranking::Ranking;
use crate::rate_limit::RateLimiter;
use crate::replay::ReplayBuffer;
use crate::rollout::Pending;
use crate::selkd::{RoundStats, Selkd};
use crate::tensorboard::EventWriter;
use crate::workers::{Workers, GONE_CHECK};
use anyhow::{anyhow, bail, Context, Result};
use selkd_protocol::{
    self as proto, services, Control, Handshake, LearnerPorts, ReportKind, Services,
    TransitionHeader, TransitionRow, MAX_ACTORS, MAX_HIDDEN_LAYERS,
};
use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tch::Device;

/// How the run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The env-step budget was reached.
    Finished,
    /// Asked to stop (SIGINT/SIGTERM); a checkpoint was written.
    Interrupted,
}

pub fn parse_device(s: &str) -> Result<Device> {
    let device = match s {
        "cpu" => return Ok(Device::Cpu),
        "cuda" => Device::Cuda(0),
        other => Device::Cuda(
            other
                .strip_prefix("cuda:")
                .and_then(|n| n.parse().ok())
                .ok_or_else(|| anyhow!("device `{other}`: use cpu, cuda or cuda:N"))?,
        ),
    };
    if !tch::Cuda::is_available() {
        bail!("run.device = {s}, but libtorch sees no CUDA device here; use --set run.device=cpu");
    }
    Ok(device)
}

/// The learner process's state: the training itself (SELKD, its replay buffer, the ranking and
/// the rate limiter), then the rest in named parts, each holding what one concern needs.
pub struct Learner {
    cfg: Config,
    /// The learner's side of the handshake, announced in every [`Control`]: the env's name and
    /// sizes, and the fingerprint of this build's variant of it (options and physics), the one
    /// the run trains on from here. Fixed for the run, so made once.
    handshake: Handshake,
    /// The number of actors, and of workers (one per actor).
    k: usize,
    /// How a transition's values split into s, a, r, s', terminated, truncated.
    row: TransitionRow,
    selkd: Selkd,
    replay: ReplayBuffer,
    ranking: Ranking,
    limiter: RateLimiter,
    /// The worker connections: rollout records, accepted processes, cursors, grants, watchdog.
    workers: Workers,
    /// The evaluation epochs and which of them have their metrics row.
    epochs: Epochs,
    /// The counters and the latest round's numbers.
    stats: Stats,
    /// The run directory, metrics file, TensorBoard events, wall clock and checkpoint schedule.
    out: Outputs,
    /// The env the run trained on, stretch by stretch (into every checkpoint).
    env: Vec<checkpoint::EnvStretch>,
}

/// Where a resumed run continues from.
pub struct Resume<'a> {
    /// A complete checkpoint directory (`RUN/checkpoints/NAME`).
    pub checkpoint: &'a Path,
    /// Continue even if this build's env differs from the one the run trained on
    /// ([`checkpoint::continue_env_history`]).
    pub accept_env_change: bool,
}

/// What the run has done so far: the learner's counters and the latest round's numbers. All of
/// it goes into checkpoints, so a resumed run carries on counting.
struct Stats {
    /// Env steps stored (or held out, or dropped as non-finite): the budget counts these.
    inserted: u64,
    lockstep_rounds: u64,
    weights_version: u64,
    /// Dropped transitions and the policy lag of those stored.
    intake: Intake,
    /// What the latest round measured: the next metrics row and `live/` scalars report it.
    last_round: RoundStats,
}

impl Stats {
    fn from_resumed(resumed: Option<&TrainingState>) -> Self {
        Self {
            inserted: resumed.map_or(0, |s| s.inserted),
            lockstep_rounds: resumed.map_or(0, |s| s.lockstep_rounds),
            weights_version: resumed.map_or(1, |s| s.weights_version),
            intake: resumed.map_or_else(Intake::default, |s| {
                Intake::restore(s.dropped, s.policy_lag)
            }),
            last_round: resumed
                .and_then(|s| s.last_round.as_ref())
                .map_or_else(RoundStats::default, RoundStats::from),
        }
    }
}

/// The evaluation epochs: the one workers are asked to evaluate, what each worker reported, and
/// which epochs have their metrics row. A row waits for every worker's evaluation of its epoch,
/// so it is written after the epoch ended, with the env steps at which it ended.
struct Epochs {
    /// The latest epoch that ended (the workers evaluate it).
    eval_epoch: u64,
    /// (epoch, env steps at which it ended) for every epoch whose row is not written yet. An
    /// epoch ends at the first round boundary at or past each multiple of `eval.epoch_env_steps`.
    epoch_ends: VecDeque<(u64, u64)>,
    /// Per actor: the latest epoch it reported an evaluation of.
    eval_reported: Vec<u64>,
    /// Per actor: (epoch, success rate) of its latest evaluation; NaN for tasks without success.
    eval_success: Vec<(u64, f64)>,
    /// Epochs whose metrics row is written.
    epochs_logged: u64,
}

impl Epochs {
    fn from_resumed(resumed: Option<&TrainingState>, k: usize) -> Self {
        // Epochs whose row was written when the checkpoint was taken; the evaluation of any later
        // epoch was in flight and is asked for again.
        let epochs_logged = resumed.map_or(0, |s| s.epochs_logged.unwrap_or(s.eval_epoch));
        Self {
            eval_epoch: resumed.map_or(0, |s| s.eval_epoch),
            epoch_ends: resumed
                .map_or_else(VecDeque::new, |s| s.epoch_ends.iter().copied().collect()),
            eval_reported: vec![epochs_logged; k],
            eval_success: vec![(0, f64::NAN); k],
            epochs_logged,
        }
    }

    /// Whether every actor's evaluation of the latest epoch is in.
    fn evals_in(&self) -> bool {
        self.eval_reported.iter().all(|&e| e >= self.eval_epoch)
    }

    /// Worker `w` reported its evaluation of `epoch`. Returns false for one already counted.
    fn evaluation(&mut self, w: usize, epoch: u64, success_rate: f64) -> bool {
        if epoch <= self.eval_reported[w] {
            return false;
        }
        self.eval_reported[w] = epoch;
        self.eval_success[w] = (epoch, success_rate);
        true
    }

    /// The next epoch whose evaluations are all in but whose row is not written, with the env
    /// steps at which it ended (a multiple of `epoch_env_steps` if not on record); it counts as
    /// logged from here on.
    fn next_to_log(&mut self, epoch_env_steps: u64) -> Option<(u64, u64)> {
        let complete = *self.eval_reported.iter().min().unwrap_or(&0);
        if self.epochs_logged >= complete.min(self.eval_epoch) {
            return None;
        }
        self.epochs_logged += 1;
        let e = self.epochs_logged;
        while self.epoch_ends.front().is_some_and(|&(epoch, _)| epoch < e) {
            self.epoch_ends.pop_front();
        }
        let env_steps = match self.epoch_ends.front() {
            Some(&(epoch, steps)) if epoch == e => steps,
            _ => e * epoch_env_steps,
        };
        Some((e, env_steps))
    }
}

/// Where the run's results go: its directory (checkpoints), `metrics.csv`, TensorBoard events,
/// the wall clock they carry (continued across resumes), and when the next periodic checkpoint
/// is due.
struct Outputs {
    run_dir: PathBuf,
    metrics: std::fs::File,
    /// TensorBoard events (`RUN/tb/`); `None` if the file could not be made (logged).
    tb: Option<EventWriter>,
    started: Instant,
    /// The wall seconds of the runs this one resumes.
    wall_offset: f64,
    next_checkpoint: u64,
}

impl Outputs {
    /// Opens `metrics.csv` for appending. A resumed run drops the rows written after its
    /// checkpoint (by the run that was stopped or killed): this one writes them again, so each
    /// epoch has one row.
    fn open_metrics(
        run_dir: &Path,
        resumed: bool,
        epochs_logged: u64,
        k: usize,
    ) -> Result<std::fs::File> {
        let metrics_path = run_dir.join("metrics.csv");
        if resumed && metrics_path.exists() {
            truncate_metrics(&metrics_path, epochs_logged)?;
        }
        let fresh_metrics = !resumed || !metrics_path.exists();
        let mut metrics = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&metrics_path)
            .with_context(|| format!("opening {}", metrics_path.display()))?;
        if fresh_metrics {
            writeln!(metrics, "{}", MetricsRow::header(k))?;
        }
        Ok(metrics)
    }

    /// The outputs around `metrics`; TensorBoard events start at `inserted`, and the next
    /// periodic checkpoint is the next multiple of `checkpoint_every` past it.
    fn new(
        run_dir: &Path,
        metrics: std::fs::File,
        inserted: u64,
        checkpoint_every: u64,
        resumed: Option<&TrainingState>,
    ) -> Self {
        Self {
            next_checkpoint: inserted
                .checked_div(checkpoint_every)
                .map_or(0, |n| (n + 1) * checkpoint_every),
            started: Instant::now(),
            wall_offset: resumed.map_or(0.0, |s| s.wall_seconds),
            metrics,
            tb: EventWriter::create(&run_dir.join("tb"), inserted)
                .map_err(|e| tracing::warn!("no TensorBoard events for this run: {e:#}"))
                .ok(),
            run_dir: run_dir.to_path_buf(),
        }
    }

    fn wall(&self) -> f64 {
        self.wall_offset + self.started.elapsed().as_secs_f64()
    }

    /// Writes `values` at `step` and flushes; after a failed write (a full disk) the run goes on
    /// without TensorBoard events.
    fn write_scalars(&mut self, step: u64, values: &[(String, f64)]) {
        let Some(tb) = self.tb.as_mut() else {
            return;
        };
        let written: Result<()> = values
            .iter()
            .try_for_each(|(tag, v)| tb.scalar(tag, step, *v))
            .and_then(|()| tb.flush());
        if let Err(e) = written {
            tracing::warn!("TensorBoard events stop here: {e:#}");
            self.tb = None;
        }
    }
}

/// What `run`'s loop keeps from one pass to the next: what it last sent, when it last did its
/// periodic chores, and the rates it last measured.
struct Pass {
    /// A pass that trained does not wait for a wake: more rounds may be due.
    trained_last: bool,
    last_control: Option<Control>,
    ranking_version: u64,
    last_progress: Instant,
    last_live: Instant,
    last_connect: Instant,
    last_gone_check: Instant,
    /// (since, env steps, critic updates) at the start of the rates' window.
    window: (Instant, u64, u64),
    /// (critic updates, env steps) per second over the last window.
    rates: (f64, f64),
    /// When the budget was reached (the final evaluations are waited for).
    finishing_since: Option<Instant>,
}

impl Pass {
    fn new(inserted: u64, critic_updates: u64) -> Self {
        Self {
            trained_last: false,
            last_control: None,
            ranking_version: u64::MAX,
            last_progress: Instant::now(),
            last_live: Instant::now(),
            last_connect: Instant::now(),
            last_gone_check: Instant::now(),
            window: (Instant::now(), inserted, critic_updates),
            rates: (0.0, 0.0),
            finishing_since: None,
        }
    }

    /// The rates over the window, which restarts once it is a second or longer.
    fn rates(&mut self, inserted: u64, critic_updates: u64) -> (f64, f64) {
        let dt = self.window.0.elapsed().as_secs_f64();
        if dt >= 1.0 {
            self.rates = (
                (critic_updates - self.window.2) as f64 / dt,
                (inserted - self.window.1) as f64 / dt,
            );
            self.window = (Instant::now(), inserted, critic_updates);
        }
        self.rates
    }
}

impl Learner {
    pub fn new(cfg: Config, run_dir: &Path, resume: Option<Resume>) -> Result<Self> {
        // One env for its spec and its record: a `gymnasium:` env is a `gymnasium.make` in Python.
        let mut made = selkd_envs::make_with(&cfg.run.env, &cfg.env_options)?;
        let spec = made.spec().clone();
        let env_now = selkd_envs::EnvRecord::of_env(&cfg.run.env, &cfg.env_options, made.as_mut());
        let handshake = Handshake::ours(
            spec.id,
            selkd_envs::variant_fingerprint(&env_now.options, env_now.physics),
            spec.obs_dim,
            spec.act_dim,
        );
        let device = parse_device(&cfg.run.device)?;
        crate::threads::set(cfg.run.threads);
        crate::matmul::set(cfg.run.cpu_gemm);
        let k = cfg.algo.actors;
        if k > MAX_ACTORS || cfg.algo.hidden.len() > MAX_HIDDEN_LAYERS {
            bail!("this build supports at most {MAX_ACTORS} actors and {MAX_HIDDEN_LAYERS} hidden layers");
        }
        let mut selkd = Selkd::new(&cfg.algo, spec.obs_dim, spec.act_dim, device, cfg.run.seed);
        check_matmul(cfg.algo.critic_matmul, device)?;
        let mut replay =
            ReplayBuffer::new(cfg.algo.replay_capacity, spec.obs_dim, spec.act_dim, device);
        crate::config::create_run_dir(run_dir, cfg.run.dir_mode)
            .and_then(|()| std::fs::create_dir_all(run_dir.join("checkpoints")))
            .with_context(|| format!("creating {}", run_dir.display()))?;
        let (resumed, env) = match resume {
            Some(Resume {
                checkpoint: dir,
                accept_env_change,
            }) => {
                let state = checkpoint::load(dir, &mut selkd, &mut replay)
                    .with_context(|| format!("resuming from {}", dir.display()))?;
                let (env, note) =
                    checkpoint::continue_env_history(&state, &env_now, accept_env_change)?;
                if let Some(note) = note {
                    tracing::warn!("{note}");
                }
                tracing::info!(
                    env_steps = state.inserted,
                    version = state.weights_version,
                    "resumed from {}",
                    dir.display()
                );
                (Some(state), env)
            }
            None => (
                None,
                vec![checkpoint::EnvStretch {
                    from_env_step: 0,
                    record: env_now,
                }],
            ),
        };
        let resumed = resumed.as_ref();
        let epochs = Epochs::from_resumed(resumed, k);
        let metrics = Outputs::open_metrics(run_dir, resumed.is_some(), epochs.epochs_logged, k)?;
        let stats = Stats::from_resumed(resumed);
        let limiter = rate_limiter(&cfg, resumed.is_some() && replay.is_empty(), &stats, &selkd);
        let every = cfg.run.checkpoint_every;
        Ok(Self {
            ranking: resumed.map_or_else(
                || Ranking::new(k, cfg.eval.score_window),
                |s| s.ranking.clone(),
            ),
            row: TransitionRow {
                obs_dim: spec.obs_dim,
                act_dim: spec.act_dim,
            },
            handshake,
            limiter,
            k,
            workers: Workers::new(k, Duration::from_secs_f64(cfg.run.worker_timeout), resumed),
            epochs,
            out: Outputs::new(run_dir, metrics, stats.inserted, every, resumed),
            stats,
            selkd,
            replay,
            cfg,
            env,
        })
    }

    /// Runs until the budget is reached or `stop` is raised.
    pub fn run(&mut self, run_id: &str, stop: Arc<AtomicBool>) -> Result<Outcome> {
        selkd_protocol::stale::clean_up();
        let node = services::node(&proto::learner_node_name(run_id))
            .map_err(|e| anyhow!("starting the iceoryx2 node: {e}"))?;
        let ports = LearnerPorts::open(
            &node,
            &Services::new(run_id),
            self.k,
            self.selkd.actor_weights(0).len(),
        )
        .map_err(|e| anyhow!("{e}"))?;
        self.publish_weights(&ports)?;
        let mut pass = Pass::new(self.stats.inserted, self.selkd.critic_updates);
        let outcome = loop {
            // Wake on any worker message (or every 50 ms to keep progress, checkpoints and stop
            // handling responsive).
            if !pass.trained_last {
                selkd_protocol::wait_for_wake(&ports.wake, Duration::from_millis(50))?;
            }
            while let Some(r) = ports.reports.receive()? {
                self.on_report(r.payload());
            }
            while let Some(t) = ports.transitions.receive()? {
                self.on_transition(*t.user_header(), t.payload());
            }
            self.workers.send_due_cursors(&ports)?;
            let trained = match self.cfg.run.mode {
                Mode::Sync => self.advance_sync()?,
                Mode::Async => self.advance_async()?,
            };
            if trained {
                self.publish_weights(&ports)?;
            }
            pass.trained_last = trained;
            self.log_epochs()?;
            self.periodic_checkpoint()?;
            let interrupted = stop.load(Ordering::Relaxed);
            let done = self.finished(&mut pass.finishing_since) || interrupted;
            if gone_check_due(self.cfg.run.mode, pass.last_gone_check) {
                pass.last_gone_check = Instant::now();
                self.workers.take_back_grants_of_gone_workers(run_id);
            }
            self.broadcast(&ports, &mut pass, done)?;
            self.report_progress(&mut pass, done);
            if done {
                break if interrupted {
                    Outcome::Interrupted
                } else {
                    Outcome::Finished
                };
            }
        };
        self.finish(outcome)
    }

    fn publish_weights(&self, ports: &LearnerPorts) -> Result<()> {
        ports
            .publish_weights(self.stats.weights_version, |i| self.selkd.actor_weights(i))
            .map_err(|e| anyhow!("publishing weights: {e}"))
    }

    /// A periodic checkpoint that fails (a full disk) is not the end of the run: the next one
    /// tries again. Only the final one must succeed, and non-finite weights end the run.
    fn periodic_checkpoint(&mut self) -> Result<()> {
        let inserted = self.stats.inserted;
        if self.cfg.run.checkpoint_every > 0
            && inserted >= self.out.next_checkpoint
            && inserted < self.cfg.run.total_env_steps
        {
            if let Err(e) = self.checkpoint(&format!("step-{inserted}")) {
                if e.downcast_ref::<checkpoint::NonFinite>().is_some() {
                    return Err(e.context(format!("at {inserted} env steps")));
                }
                tracing::error!("checkpoint at {inserted} env steps failed: {e:#}; training goes on, the next checkpoint tries again");
            }
            self.out.next_checkpoint += self.cfg.run.checkpoint_every;
        }
        Ok(())
    }

    /// Whether the budget is reached and the final evaluations are in, so the last epoch is
    /// scored; they are waited for a bounded time (from `finishing_since`, set here).
    fn finished(&self, finishing_since: &mut Option<Instant>) -> bool {
        let budget_reached = self.stats.inserted >= self.cfg.run.total_env_steps;
        if budget_reached && finishing_since.is_none() {
            *finishing_since = Some(Instant::now());
        }
        budget_reached
            && (self.epochs.evals_in()
                || finishing_since.is_some_and(|t| t.elapsed() > Duration::from_secs(120)))
    }

    /// Sends the control when it changed (and reports workers the run waits on in vain), lets
    /// late subscribers connect, and sends the ranking when it changed.
    fn broadcast(&mut self, ports: &LearnerPorts, pass: &mut Pass, done: bool) -> Result<()> {
        let control = self.control(done);
        self.watch(&control);
        if pass
            .last_control
            .as_ref()
            .map(|c: &Control| !same_control(c, &control))
            .unwrap_or(true)
        {
            ports.control.send_copy(control)?;
            ports.to_workers.notify()?;
            pass.last_control = Some(control);
        }
        // Late (or restarted) subscribers get the latest control, ranking and weights from the
        // publishers' history only once the publisher looks for new connections.
        if pass.last_connect.elapsed() >= Duration::from_millis(50) {
            pass.last_connect = Instant::now();
            ports
                .connect_latecomers()
                .map_err(|e| anyhow!("connecting late workers: {e}"))?;
        }
        if self.ranking.version != pass.ranking_version {
            pass.ranking_version = self.ranking.version;
            ports.ranking.send_copy(self.ranking_message())?;
        }
        Ok(())
    }

    /// The progress line every second and the `live/` scalars every 5 s (both at the end).
    fn report_progress(&mut self, pass: &mut Pass, done: bool) {
        if pass.last_progress.elapsed() >= Duration::from_secs(1) || done {
            let rates = pass.rates(self.stats.inserted, self.selkd.critic_updates);
            self.progress(rates);
            if pass.last_live.elapsed() >= Duration::from_secs(5) || done {
                self.live_scalars(rates);
                pass.last_live = Instant::now();
            }
            pass.last_progress = Instant::now();
        }
    }

    /// After the loop: the last rows and the final checkpoint, which must be written (or the
    /// error names the latest complete one to resume from).
    fn finish(&mut self, outcome: Outcome) -> Result<Outcome> {
        self.log_epochs()?;
        if let Err(e) = self.checkpoint("final") {
            if e.downcast_ref::<checkpoint::NonFinite>().is_some() {
                return Err(e);
            }
            let checkpoints = self.out.run_dir.join("checkpoints");
            let latest = std::fs::read_to_string(checkpoints.join("latest"))
                .map_or("none".to_string(), |n| {
                    checkpoints.join(n.trim()).display().to_string()
                });
            return Err(e.context(format!(
                "writing the final checkpoint (the latest complete one: {latest}; free space, then `selkd train --resume {}` continues from it)",
                self.out.run_dir.display()
            )));
        }
        // Give workers a moment to read the stop order before the node (and its history) goes away.
        std::thread::sleep(Duration::from_millis(200));
        tracing::info!(
            env_steps = self.stats.inserted,
            critic_updates = self.selkd.critic_updates,
            dropped_nonfinite = self.stats.intake.dropped_nonfinite,
            dropped_stale = self.stats.intake.dropped_stale,
            "learner done ({outcome:?})"
        );
        Ok(outcome)
    }

    fn on_report(&mut self, r: &proto::Report) {
        let w = r.worker as usize;
        if w >= self.k {
            tracing::warn!(
                "report from worker {w}, but the run has {} actors; ignored",
                self.k
            );
            return;
        }
        self.workers.heard(w);
        match r.kind {
            ReportKind::Hello => {
                if let Err(e) = proto::check_peer(&self.handshake, &r.handshake()) {
                    tracing::error!("worker {w}: {e}");
                    return;
                }
                if self.workers.accepting[w] != Some(r.incarnation)
                    && self.workers.cursor_due[w].is_none()
                {
                    let c = &self.workers.rollouts[w];
                    tracing::info!(
                        "worker {w} joined (generation {}) holding weights version {}; learner at version {}; it continues at transition {} (episode {}, step {})",
                        r.generation, r.weights_version, self.stats.weights_version, c.sent, c.episode, c.step
                    );
                }
                self.workers.cursor_due[w] = Some(r.incarnation);
            }
            ReportKind::Evaluation => {
                if self.epochs.evaluation(w, r.epoch, r.success_rate) {
                    self.ranking.evaluation(w, r.epoch, r.mean_return);
                    tracing::debug!(
                        worker = w,
                        epoch = r.epoch,
                        mean_return = r.mean_return,
                        "evaluation"
                    );
                }
            }
        }
    }

    fn on_transition(&mut self, h: TransitionHeader, row: &[f32]) {
        let w = h.worker as usize;
        if w >= self.k
            || h.obs_dim as usize != self.row.obs_dim
            || h.act_dim as usize != self.row.act_dim
            || row.len() != self.row.len()
        {
            self.stats.intake.dropped_malformed += 1;
            if self.stats.intake.dropped_malformed == 1 {
                tracing::error!("dropped a transition that does not fit the run (worker {w}, obs {}, act {}, {} values); counting further ones", h.obs_dim, h.act_dim, row.len());
            }
            return;
        }
        if self.workers.accepting[w] != Some(h.incarnation) {
            self.stats.intake.dropped_stale += 1;
            tracing::warn!(
                worker = w,
                total = self.stats.intake.dropped_stale,
                "dropped a transition from a replaced process of worker {w} (generation {}); its successor sends that step itself",
                h.generation
            );
            return;
        }
        if self.cfg.run.mode == Mode::Async
            && self.workers.rollouts[w].sent >= self.workers.granted[w]
        {
            // Beyond its grant: sent by a process whose grant was taken back as it died (the
            // run's total would be passed); its successor sends that step itself.
            self.stats.intake.dropped_stale += 1;
            tracing::warn!(
                worker = w,
                total = self.stats.intake.dropped_stale,
                "dropped a transition of worker {w} beyond its grant; its successor sends that step itself"
            );
            return;
        }
        self.workers.heard(w);
        let (_, action, _, _, terminated, truncated) = self.row.split(row);
        if !self.workers.rollouts[w].record(h.episode, h.step, action, terminated || truncated) {
            tracing::error!(
                worker = w,
                "transition of episode {} step {} is not the next one on record; a restart of this worker will not continue it exactly",
                h.episode,
                h.step
            );
        }
        let finite = row.iter().all(|v| v.is_finite());
        if !finite {
            self.stats.intake.dropped_nonfinite += 1;
            let dropped = self.stats.intake.dropped_nonfinite;
            if dropped == 1 || dropped.is_power_of_two() {
                tracing::warn!(
                    worker = w,
                    total = dropped,
                    field = self
                        .row
                        .field_of(row.iter().position(|v| !v.is_finite()).unwrap_or(0)),
                    "dropped a transition with a NaN or infinite value (never stored)"
                );
            }
        }
        if h.policy_version > 0 {
            self.stats
                .intake
                .policy_lag(self.stats.weights_version.saturating_sub(h.policy_version));
        }
        let p = Pending {
            worker: w,
            episode_return: h.episode_return.is_finite().then_some(h.episode_return),
            row: finite.then(|| row.to_vec()),
        };
        match self.cfg.run.mode {
            Mode::Sync => self.workers.pending[w].push_back(p),
            Mode::Async => self.store(p),
        }
    }

    fn store(&mut self, p: Pending) {
        if let Some(row) = &p.row {
            let (s, a, r, s2, terminated, _truncated) = self.row.split(row);
            match self.selkd.held_out(self.stats.inserted + 1) {
                Some(validation) => validation.push(s, a, r, s2, terminated),
                None => self.replay.push(s, a, r, s2, terminated),
            }
        }
        self.stats.inserted += 1;
        if let Some(episode_return) = p.episode_return {
            self.ranking.training_episode(p.worker, episode_return);
        }
        let epoch = self.stats.inserted / self.cfg.eval.epoch_env_steps;
        if epoch > self.epochs.eval_epoch {
            self.epochs.eval_epoch = epoch;
            // Sync: the evaluation runs after this round (rounds store K steps), so the epoch ends
            // at the round's end; async: now.
            let end = match self.cfg.run.mode {
                Mode::Sync => self.stats.inserted.div_ceil(self.k as u64) * self.k as u64,
                Mode::Async => self.stats.inserted,
            };
            self.epochs.epoch_ends.push_back((epoch, end));
        }
    }

    /// Algorithm 1's lockstep: once every actor's step of this round is in (and every requested
    /// evaluation is back), store them in actor order and train. Returns whether weights changed.
    fn advance_sync(&mut self) -> Result<bool> {
        let mut trained = false;
        loop {
            let evals_in = self.epochs.evals_in();
            if evals_in {
                // An epoch's row records the learner as it was when the epoch ended: write it
                // before the next round, whose transitions may already be waiting (otherwise the
                // row would depend on message timing, and sync runs would not reproduce).
                self.log_epochs()?;
            }
            if !evals_in
                || self.workers.pending.iter().any(|q| q.is_empty())
                || self.stats.inserted >= self.cfg.run.total_env_steps
            {
                return Ok(trained);
            }
            for w in 0..self.k {
                let p = self.workers.pending[w]
                    .pop_front()
                    .expect("checked non-empty");
                self.store(p);
            }
            self.stats.lockstep_rounds += 1;
            if self.limiter.warmed_up(self.stats.inserted) {
                self.train_round()?;
                trained = true;
                // Hand the new weights out before the next round (the caller publishes them).
                return Ok(trained);
            }
        }
    }

    /// At most one round per pass, and only when the inserted data pays for it (never ahead of
    /// it). One round per pass means the new weights and control go out before the next round, so
    /// a worker's behaviour policy trails by at most `max_policy_lag` plus the round in flight.
    fn advance_async(&mut self) -> Result<bool> {
        if self.selkd.actor_updates < self.limiter.rounds_due(self.stats.inserted) {
            self.train_round()?;
            return Ok(true);
        }
        Ok(false)
    }

    /// One round; a non-finite loss (the networks diverged) ends the run with an error before
    /// the weights are published or checkpointed, so the last checkpoint stays a good one.
    fn train_round(&mut self) -> Result<()> {
        let best = self.ranking.best();
        self.stats.last_round = self.selkd.train_round(&mut self.replay, best);
        let st = &self.stats.last_round;
        // Checked on the round's own statistics: a weight that became NaN or infinite in this
        // round shows in them, so the broadcast and the checkpoint never carry it (any one
        // number counts: `diverged`).
        if diverged(st) {
            bail!(
                "training diverged in round {} ({} env steps): critic loss {}, actor losses {:?}; nothing after the last checkpoint is kept (lower algo.lr, or check the env's rewards)",
                self.selkd.actor_updates,
                self.stats.inserted,
                st.critic_loss,
                st.actor_loss
            );
        }
        self.stats.weights_version += 1;
        Ok(())
    }

    fn control(&mut self, stop: bool) -> Control {
        let ours = self.handshake;
        let per_actor_cap = self.cfg.steps_per_actor();
        let mut budget = [0u64; MAX_ACTORS];
        match self.cfg.run.mode {
            Mode::Sync => {
                // Warm-up (or refill) steps need no new weights: grant them at once; then one
                // step per round.
                let b = (self.limiter.warmup_end() / self.k as u64)
                    .max(self.stats.lockstep_rounds + 1)
                    .min(per_actor_cap);
                budget[..self.k].iter_mut().for_each(|x| *x = b);
            }
            Mode::Async => {
                // No per-worker cap: a share a worker cannot use (it is dead, stopped or busy)
                // goes to the others, within the limiter's allowance and the run's total.
                let allowance = self
                    .limiter
                    .insert_allowance(self.stats.inserted, self.selkd.actor_updates);
                let granted = self
                    .workers
                    .top_up_grants(allowance, self.cfg.run.total_env_steps);
                budget[..self.k].copy_from_slice(granted);
            }
        }
        let mut hidden = [0u32; MAX_HIDDEN_LAYERS];
        for (h, &v) in hidden.iter_mut().zip(&self.cfg.algo.hidden) {
            *h = v as u32;
        }
        Control {
            protocol_version: ours.protocol_version,
            actors: self.k as u32,
            env: ours.env,
            env_options: ours.env_options,
            obs_dim: ours.obs_dim,
            act_dim: ours.act_dim,
            seed: self.cfg.run.seed,
            hidden,
            hidden_layers: self.cfg.algo.hidden.len() as u32,
            warmup_steps: self.cfg.warmup_per_actor(),
            weights_version: self.stats.weights_version,
            max_policy_lag: match self.cfg.run.mode {
                Mode::Sync => 0,
                Mode::Async => self.cfg.asynchronous.max_policy_lag,
            },
            eval_epoch: self.epochs.eval_epoch,
            eval_episodes: self.cfg.eval.episodes as u32,
            exploration_noise: self.cfg.algo.backbone.exploration_noise() as f32,
            stop: stop as u32,
            budget,
        }
    }

    /// Reports workers the run waits on that have been silent for `run.worker_timeout`: one
    /// `STALLED {json}` line on stdout each (the launcher kills and restarts the worker).
    fn watch(&mut self, control: &Control) {
        let owes = self.waited_on(control);
        for (w, silent) in self.workers.watchdog.late(&owes, Instant::now()) {
            tracing::warn!(
                "worker {w} has sent nothing for {:.0} s while the run waits on it (run.worker_timeout = {}); it is hung or stopped: restart it",
                silent.as_secs_f64(),
                self.cfg.run.worker_timeout
            );
            let mut out = std::io::stdout().lock();
            let line = serde_json::json!({ "worker": w, "silent_s": silent.as_secs_f64() });
            let _ = writeln!(out, "STALLED {line}").and_then(|()| out.flush());
        }
    }

    /// Per worker, whether the run waits on it under `control`: for a step of its budget (in a
    /// sync run only while its step of the round is not in), an evaluation, or its joining.
    /// Nothing once the run is stopping.
    fn waited_on(&self, control: &Control) -> Vec<bool> {
        (0..self.k)
            .map(|w| {
                let owes_step = self.workers.rollouts[w].sent < control.budget[w]
                    && (self.cfg.run.mode == Mode::Async || self.workers.pending[w].is_empty());
                let owes_eval = self.epochs.eval_reported[w] < self.epochs.eval_epoch;
                control.stop == 0 && (owes_step || owes_eval || self.workers.accepting[w].is_none())
            })
            .collect()
    }

    /// The latest round's numbers in TensorBoard (`live/`), every few seconds.
    fn live_scalars(&mut self, rates: (f64, f64)) {
        if self.out.tb.is_none() {
            return;
        }
        let values = metrics::live_scalars(&self.stats.last_round, rates, self.selkd.selection());
        self.out.write_scalars(self.stats.inserted, &values);
    }

    fn ranking_message(&self) -> proto::Ranking {
        let mut scores = [f64::NAN; MAX_ACTORS];
        for (s, v) in scores.iter_mut().zip(self.ranking.scores()) {
            *s = v.unwrap_or(f64::NAN);
        }
        proto::Ranking {
            version: self.ranking.version,
            actors: self.k as u32,
            best: self.ranking.best() as u32,
            scores,
        }
    }

    /// One `PROGRESS {json}` line on stdout per second: the launcher draws its progress line from it.
    fn progress(&self, (updates_per_s, env_steps_per_s): (f64, f64)) {
        let (updates_per_transition, target_updates_per_transition) = self
            .limiter
            .ratio(self.selkd.critic_updates, self.stats.inserted);
        let progress = Progress {
            best: self.ranking.best(),
            critic_updates: self.selkd.critic_updates,
            dropped_malformed: self.stats.intake.dropped_malformed,
            dropped_nonfinite: self.stats.intake.dropped_nonfinite,
            dropped_stale: self.stats.intake.dropped_stale,
            env_steps: self.stats.inserted,
            env_steps_per_s,
            policy_lag_max: self.stats.intake.lag_max,
            policy_lag_mean: self.stats.intake.policy_lag_mean(),
            scores: self.ranking.scores(),
            success: self
                .epochs
                .eval_success
                .iter()
                .map(|&(_, rate)| rate.is_finite().then_some(rate))
                .collect(),
            target_updates_per_transition,
            total_env_steps: self.cfg.run.total_env_steps,
            updates_per_s,
            updates_per_transition,
            wall_s: self.out.wall(),
            weights_version: self.stats.weights_version,
        };
        // The launcher may be gone (its stdout closed): progress is best effort, never a panic.
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "PROGRESS {}", progress.json()).and_then(|()| out.flush());
    }

    /// One metrics row per epoch whose evaluations are all in.
    fn log_epochs(&mut self) -> Result<()> {
        while let Some((e, env_steps)) = self.epochs.next_to_log(self.cfg.eval.epoch_env_steps) {
            let row = self.metrics_row(e, env_steps);
            writeln!(self.out.metrics, "{}", row.csv())?;
            self.out.metrics.flush()?;
            if self.out.tb.is_some() {
                self.out.write_scalars(env_steps, &row.scalars());
            }
            tracing::info!(
                epoch = e,
                env_steps,
                best = row.best,
                "evaluation returns {:?}",
                row.eval_return
            );
        }
        Ok(())
    }

    /// Epoch `epoch`'s row, ended at `env_steps`, as the learner stands now.
    fn metrics_row(&self, epoch: u64, env_steps: u64) -> MetricsRow {
        let wall_s = self.out.wall();
        let score: Vec<f64> = self
            .ranking
            .scores()
            .into_iter()
            .map(|s| s.unwrap_or(f64::NAN))
            .collect();
        // An actor whose latest evaluation is older than this epoch has no return for it.
        let eval_return = (0..self.k)
            .map(|i| {
                if self.ranking.last_eval_epoch(i) >= epoch {
                    score[i]
                } else {
                    f64::NAN
                }
            })
            .collect();
        // Tasks with a success criterion (the assembly task) report the evaluation's success
        // rate; others leave NaN.
        let eval_success = self
            .epochs
            .eval_success
            .iter()
            .map(|&(e, rate)| if e >= epoch { rate } else { f64::NAN })
            .collect();
        // Before the first round there are no per-actor statistics: NaN for every actor.
        let per_actor = |v: &[f64]| {
            if v.len() == self.k {
                v.to_vec()
            } else {
                vec![f64::NAN; self.k]
            }
        };
        let stats = &self.stats.last_round;
        MetricsRow {
            epoch,
            env_steps,
            wall_s,
            critic_updates: self.selkd.critic_updates,
            updates_per_s: self.selkd.critic_updates as f64 / wall_s.max(1e-9),
            env_steps_per_s: self.stats.inserted as f64 / wall_s.max(1e-9),
            critic_loss: stats.critic_loss,
            q_mean: stats.q_mean,
            best: self.ranking.best(),
            eval_return,
            score,
            alpha: per_actor(&stats.alpha),
            kl_to_best: per_actor(&stats.kl_to_best),
            policy_lag_mean: self.stats.intake.policy_lag_mean(),
            dropped: self.stats.intake.dropped(),
            eval_success,
        }
    }

    fn checkpoint(&mut self, name: &str) -> Result<()> {
        let dir = self.out.run_dir.join("checkpoints").join(name);
        let (dropped, policy_lag) = self.stats.intake.saved();
        let state = TrainingState {
            config: self.cfg.clone(),
            rng: self.selkd.rng.clone(),
            critic_updates: self.selkd.critic_updates,
            actor_updates: self.selkd.actor_updates,
            adam_steps: checkpoint::adam_steps(&self.selkd),
            critic_member_steps: self.selkd.critic_opt.member_steps.clone(),
            received: self.workers.rollouts.iter().map(|r| r.sent).collect(),
            rollouts: self.workers.rollouts.clone(),
            last_round: Some((&self.stats.last_round).into()),
            dropped,
            policy_lag,
            pending: self
                .workers
                .pending
                .iter()
                .map(|q| q.iter().cloned().collect())
                .collect(),
            inserted: self.stats.inserted,
            lockstep_rounds: self.stats.lockstep_rounds,
            weights_version: self.stats.weights_version,
            eval_epoch: self.epochs.eval_epoch,
            epochs_logged: Some(self.epochs.epochs_logged),
            epoch_ends: self.epochs.epoch_ends.iter().copied().collect(),
            ranking: self.ranking.clone(),
            wall_seconds: self.out.wall(),
            selected_variant: self.selkd.selection().map_or(0, |(v, _)| v),
            env: self.env.clone(),
        };
        let replay = self.cfg.run.checkpoint_replay.then_some(&mut self.replay);
        checkpoint::save(&dir, &mut self.selkd, replay, &state)?;
        checkpoint::write_atomically(
            &self.out.run_dir.join("checkpoints").join("latest"),
            &format!("{name}\n"),
        )?;
        tracing::info!(
            env_steps = self.stats.inserted,
            "checkpoint written to {}",
            dir.display()
        );
        prune_checkpoints(
            &self.out.run_dir.join("checkpoints"),
            self.cfg.run.keep_checkpoints,
        );
        Ok(())
    }
}

/// Removes all but the newest `keep` periodic checkpoints (`step-N`); others stay. Best effort:
/// a checkpoint that cannot be removed is only logged.
fn prune_checkpoints(dir: &Path, keep: usize) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut steps: Vec<(u64, PathBuf)> = entries
        .filter_map(|e| {
            let e = e.ok()?;
            let name = e.file_name().into_string().ok()?;
            let n = name.strip_prefix("step-")?.parse().ok()?;
            e.path().is_dir().then(|| (n, e.path()))
        })
        .collect();
    steps.sort();
    let old = steps.len().saturating_sub(keep);
    for (_, path) in &steps[..old] {
        if let Err(e) = std::fs::remove_dir_all(path) {
            tracing::warn!("removing old checkpoint {}: {e}", path.display());
        }
    }
}

/// Keeps the header and the rows of epochs 1..=`epochs` of `metrics.csv` (replaced atomically, so
/// a crash leaves the old or the new file, never half of one).
fn truncate_metrics(path: &Path, epochs: u64) -> Result<()> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut kept = String::new();
    for (i, line) in text.lines().enumerate() {
        let epoch = line.split(',').next().and_then(|v| v.parse::<u64>().ok());
        if i == 0 || epoch.is_some_and(|e| e <= epochs) {
            kept.push_str(line);
            kept.push('\n');
        }
    }
    checkpoint::write_atomically(path, &kept)
}

/// The rate limiter. A resumed run whose checkpoint holds no replay buffer (`without_replay`)
/// has nothing to sample from: training waits for another warm-up's worth of data.
fn rate_limiter(cfg: &Config, without_replay: bool, stats: &Stats, selkd: &Selkd) -> RateLimiter {
    let k = cfg.algo.actors;
    let warmup_total = cfg.warmup_per_actor() * k as u64;
    let mut limiter = RateLimiter::new(
        k,
        cfg.algo.utd,
        warmup_total,
        cfg.asynchronous.ratio_tolerance,
    );
    if without_replay {
        limiter.refill(stats.inserted, selkd.actor_updates);
        let why = if cfg.run.checkpoint_replay {
            "its replay.safetensors is missing although run.checkpoint_replay = true"
        } else {
            "run.checkpoint_replay = false"
        };
        tracing::warn!("the checkpoint holds no replay buffer ({why}): training resumes once {} new transitions (a warm-up's worth, from the current policies) refill it", limiter.warmup_end() - stats.inserted);
    }
    limiter
}

fn same_control(a: &Control, b: &Control) -> bool {
    a.weights_version == b.weights_version
        && a.eval_epoch == b.eval_epoch
        && a.stop == b.stop
        && a.budget == b.budget
}

/// Refuses bf16 critic matmuls on a CPU without native bf16: libtorch emulates them there, 12×
/// slower than fp32 (1.95 against 23.5 updates/s on an AMD EPYC with AVX2).
pub fn check_matmul(matmul: crate::config::Precision, device: Device) -> Result<()> {
    check_matmul_on(matmul, device, cpu_has_bf16())
}

/// `check_matmul` on a CPU that has native bf16 exactly when `cpu_bf16`: the answer is an
/// argument so that a test can give both on any machine.
fn check_matmul_on(matmul: crate::config::Precision, device: Device, cpu_bf16: bool) -> Result<()> {
    if matmul == crate::config::Precision::Bf16 && device == Device::Cpu && !cpu_bf16 {
        bail!("algo.critic_matmul = \"bf16\" needs a CPU that multiplies bf16 natively (AVX-512 BF16 or AMX); this one ({}) has neither, and libtorch would emulate it about 12× slower than fp32: use algo.critic_matmul = \"fp32\"", cpu_model());
    }
    Ok(())
}

/// The CPU's model name, from /proc/cpuinfo.
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into())
}

/// Whether this CPU multiplies bf16 natively (AVX-512 BF16, or AMX's bf16 tiles), where
/// `algo.critic_matmul = "bf16"` pays; elsewhere libtorch emulates it.
fn cpu_has_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        // AMX's feature test is not stable in Rust yet: read the kernel's flags for it.
        bf16_native(
            std::arch::is_x86_feature_detected!("avx512bf16"),
            &std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default(),
        )
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        true
    }
}

/// AVX-512 BF16 as the CPU reports it, or AMX's bf16 tiles as the kernel's flags (`cpuinfo`) do.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
fn bf16_native(avx512bf16: bool, cpuinfo: &str) -> bool {
    avx512bf16 || cpuinfo.split_whitespace().any(|f| f == "amx_bf16")
}

/// Whether to look for gone workers now: async only (a sync run grants nothing to take back),
/// at most every `GONE_CHECK` (the look lists the live iceoryx2 nodes).
fn gone_check_due(mode: Mode, last: Instant) -> bool {
    mode == Mode::Async && last.elapsed() >= GONE_CHECK
}

/// Whether a round's statistics say the networks diverged: a non-finite critic loss, Q mean or
/// any actor's loss.
fn diverged(st: &RoundStats) -> bool {
    !st.critic_loss.is_finite()
        || !st.q_mean.is_finite()
        || st.actor_loss.iter().any(|v| !v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `workers.rs`' tests check the look itself; the run's loop asks this first, and an async
    /// run that never asked would keep a dead worker's grant (the others would then wait out
    /// its restart's back-off at the end of the budget).
    #[test]
    fn only_an_async_run_looks_for_gone_workers_and_at_most_every_gone_check() {
        let long_ago = Instant::now() - GONE_CHECK - Duration::from_millis(1);
        assert!(gone_check_due(Mode::Async, long_ago));
        assert!(!gone_check_due(Mode::Async, Instant::now()));
        assert!(!gone_check_due(Mode::Sync, long_ago));
        assert!(!gone_check_due(Mode::Sync, Instant::now()));
    }

    fn learner(mode: Mode) -> (Learner, PathBuf) {
        learner_with(mode, |_| {})
    }

    /// A 2-actor learner on Pendulum, its config changed by `set` before it is made.
    fn learner_with(mode: Mode, set: impl FnOnce(&mut Config)) -> (Learner, PathBuf) {
        // A directory per call: the tests run in parallel.
        static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "selkd-service-test-{}-{:?}-{}",
            std::process::id(),
            mode,
            CALLS.fetch_add(1, Ordering::Relaxed)
        ));
        let mut cfg = Config::default();
        cfg.run.mode = mode;
        cfg.algo.actors = 2;
        set(&mut cfg);
        let mut l = Learner::new(cfg, &dir, None).unwrap();
        l.workers.accepting = vec![Some(7); 2];
        l.workers.granted = vec![u64::MAX; 2];
        (l, dir)
    }

    fn header(worker: u32) -> TransitionHeader {
        TransitionHeader {
            worker,
            obs_dim: 3,
            act_dim: 1,
            episode_return: f64::NAN,
            policy_version: 1,
            incarnation: 7,
            ..Default::default()
        }
    }

    /// A finite Pendulum transition as a worker sends it: s (3), a (1), r, s' (3), terminated,
    /// truncated.
    const ROW: [f32; 10] = [0.1, 0.2, 0.3, 0.5, -1.0, 0.4, 0.5, 0.6, 0.0, 0.0];

    /// `s` seconds ago.
    fn ago(s: u64) -> Instant {
        Instant::now()
            .checked_sub(Duration::from_secs(s))
            .expect("uptime")
    }

    #[test]
    fn non_finite_and_malformed_transitions_are_counted_and_never_stored() {
        for mode in [Mode::Sync, Mode::Async] {
            let (mut l, dir) = learner(mode);
            let good = ROW;
            let mut nan = good;
            nan[4] = f32::NAN;
            let mut inf = good;
            inf[6] = f32::INFINITY;
            l.on_transition(header(0), &nan);
            l.on_transition(header(1), &inf);
            l.on_transition(header(0), &good[..9]); // one value short
            l.on_transition(header(7), &good); // no such worker
            assert_eq!(
                (
                    l.stats.intake.dropped_nonfinite,
                    l.stats.intake.dropped_malformed
                ),
                (2, 2)
            );
            // The dropped steps still count as the workers' steps (a lockstep round must not wait
            // for them forever), but nothing of them is stored.
            l.on_transition(header(1), &good);
            if mode == Mode::Sync {
                l.advance_sync().unwrap(); // one round: actor 0's NaN step and actor 1's Inf step
                assert_eq!(
                    l.workers.pending[1].len(),
                    1,
                    "actor 1's good step waits for actor 0's next"
                );
            }
            assert_eq!(l.stats.inserted, if mode == Mode::Sync { 2 } else { 3 });
            l.replay.flush();
            let stored = if mode == Mode::Sync { 0 } else { 1 };
            assert_eq!(
                l.replay.len(),
                stored,
                "only the finite transition is stored"
            );
            let _ = std::fs::remove_dir_all(dir);
        }
    }

    /// What `f` logs, as text: a subscriber of this thread only, so tests running beside it
    /// add nothing.
    fn logged(f: impl FnOnce()) -> String {
        #[derive(Clone, Default)]
        struct Text(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);
        impl std::io::Write for Text {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                self.0.lock().unwrap().extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let text = Text::default();
        let writer = text.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(move || writer.clone())
            .with_ansi(false)
            .finish();
        tracing::subscriber::with_default(subscriber, || {
            // A callsite first reached by another test's thread while this subscriber was being
            // registered can keep that moment's "no one listens" (tracing caches it per
            // callsite): ask every callsite again now.
            tracing::callsite::rebuild_interest_cache();
            f()
        });
        let bytes = text.0.lock().unwrap().clone();
        String::from_utf8(bytes).unwrap()
    }

    /// A worker that keeps sending bad transitions must not flood the log: a malformed one is
    /// reported once, a non-finite one at the 1st, 2nd, 4th, 8th, … (the counts go on).
    #[test]
    fn bad_transitions_are_logged_once_or_at_powers_of_two() {
        let (mut l, dir) = learner(Mode::Async);
        let good = ROW;
        let mut nan = good;
        nan[4] = f32::NAN;
        let log = logged(|| {
            for _ in 0..3 {
                l.on_transition(header(0), &good[..9]);
            }
            for _ in 0..9 {
                l.on_transition(header(1), &nan);
            }
        });
        let count = |what: &str| log.lines().filter(|line| line.contains(what)).count();
        assert_eq!(count("does not fit the run"), 1, "{log}");
        assert_eq!(
            count("NaN or infinite"),
            4,
            "the 1st, 2nd, 4th and 8th: {log}"
        );
        assert_eq!(
            (
                l.stats.intake.dropped_malformed,
                l.stats.intake.dropped_nonfinite
            ),
            (3, 9)
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    /// A worker's steps are checked against the record a restart continues from: the next step,
    /// or step 0 of the next episode after a terminated or truncated one; anything else is
    /// logged as a gap.
    #[test]
    fn a_step_that_does_not_follow_the_record_is_logged_and_one_that_does_is_not() {
        let (mut l, dir) = learner(Mode::Async);
        // (episode, step, terminated, truncated): in order, across both kinds of episode end.
        let in_order = [
            (0, 0, 0.0, 0.0),
            (0, 1, 1.0, 0.0),
            (1, 0, 0.0, 0.0),
            (1, 1, 0.0, 1.0),
            (2, 0, 0.0, 0.0),
        ];
        let step = |l: &mut Learner, (episode, step, terminated, truncated)| {
            let mut row = ROW;
            (row[8], row[9]) = (terminated, truncated);
            l.on_transition(
                TransitionHeader {
                    episode,
                    step,
                    ..header(0)
                },
                &row,
            );
        };
        let log = logged(|| in_order.into_iter().for_each(|s| step(&mut l, s)));
        assert!(!log.contains("not the next one on record"), "{log}");
        let log = logged(|| step(&mut l, (2, 5, 0.0, 0.0)));
        assert_eq!(
            log.matches("not the next one on record").count(),
            1,
            "{log}"
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The policy lag counts the steps a policy chose, by how many weight versions it trailed;
    /// warm-up steps (policy version 0: uniform actions) have none.
    #[test]
    fn policy_lag_counts_policy_steps_only() {
        let (mut l, dir) = learner(Mode::Async);
        l.stats.weights_version = 5;
        let step = |l: &mut Learner, step, policy_version| {
            let h = TransitionHeader {
                policy_version,
                step,
                ..header(0)
            };
            l.on_transition(h, &ROW);
        };
        step(&mut l, 0, 0); // a warm-up draw
        assert_eq!(
            (l.stats.intake.lag_max, l.stats.intake.policy_lag_mean()),
            (0, 0.0)
        );
        step(&mut l, 1, 3);
        step(&mut l, 2, 5);
        assert_eq!(
            (l.stats.intake.lag_max, l.stats.intake.policy_lag_mean()),
            (2, 1.0)
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    /// A transition is dropped as malformed when any one of its worker index, observation
    /// width, action width or length does not fit the run, and as stale when it comes from a
    /// process that is not the accepted one or, in an async run, beyond its worker's grant (in a
    /// sync run the rounds pace the workers and grants do not apply); each drop is counted
    /// once, and nothing of a dropped transition counts as the worker's step.
    #[test]
    fn a_transition_is_dropped_exactly_when_it_does_not_fit_or_is_not_the_accepted_processes() {
        for mode in [Mode::Sync, Mode::Async] {
            let (mut l, dir) = learner(mode);
            for misfit in [
                TransitionHeader {
                    worker: 2, // the run has actors 0 and 1
                    ..header(0)
                },
                TransitionHeader {
                    obs_dim: 4,
                    ..header(0)
                },
                TransitionHeader {
                    act_dim: 2,
                    ..header(0)
                },
            ] {
                l.on_transition(misfit, &ROW);
            }
            l.on_transition(header(0), &[&ROW[..], &[0.0]].concat()); // one value too many
            assert_eq!(l.stats.intake.dropped_malformed, 4, "{mode:?}");
            l.on_transition(
                TransitionHeader {
                    incarnation: 8, // the accepted process of worker 0 is incarnation 7
                    ..header(0)
                },
                &ROW,
            );
            l.workers.accepting[1] = None; // none accepted yet
            l.on_transition(header(1), &ROW);
            assert_eq!(l.stats.intake.dropped_stale, 2, "{mode:?}");
            // Worker 0 is granted two steps; its third is beyond the grant in an async run.
            l.workers.granted[0] = 2;
            for step in 0..3 {
                l.on_transition(TransitionHeader { step, ..header(0) }, &ROW);
            }
            let (stale, taken) = match mode {
                Mode::Sync => (2, 3),
                Mode::Async => (3, 2),
            };
            assert_eq!(
                (
                    l.stats.intake.dropped_stale,
                    l.workers.rollouts[0].sent,
                    l.workers.rollouts[1].sent
                ),
                (stale, taken, 0),
                "{mode:?}"
            );
            assert_eq!(
                (
                    l.stats.intake.dropped_malformed,
                    l.stats.intake.dropped_nonfinite
                ),
                (4, 0),
                "{mode:?}"
            );
            match mode {
                Mode::Sync => assert_eq!(l.workers.pending[0].len(), 3),
                Mode::Async => assert_eq!(l.stats.inserted, 2),
            }
            let _ = std::fs::remove_dir_all(dir);
        }
    }

    /// Divergence is any one non-finite number of a round's statistics, alone.
    #[test]
    fn a_round_diverged_when_any_one_of_its_losses_or_its_q_mean_is_not_finite() {
        let healthy = RoundStats {
            critic_loss: 0.5,
            q_mean: -3.0,
            actor_loss: vec![1.0, 2.0],
            ..Default::default()
        };
        assert!(!diverged(&healthy));
        assert!(!diverged(&RoundStats::default()), "before any round");
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let one = [
                RoundStats {
                    critic_loss: bad,
                    ..healthy.clone()
                },
                RoundStats {
                    q_mean: bad,
                    ..healthy.clone()
                },
                RoundStats {
                    actor_loss: vec![1.0, bad],
                    ..healthy.clone()
                },
            ];
            for st in one {
                assert!(diverged(&st), "{st:?}");
            }
        }
    }

    /// A healthy round is one new weights version; a learning rate of 1e30 diverges within a
    /// few rounds, and the run stops with the round's error without counting a version for it.
    #[test]
    fn a_round_is_one_weights_version_and_a_diverged_one_an_error() {
        for lr in [3e-4, 1e30] {
            let (mut l, dir) = learner_with(Mode::Async, |c| {
                tiny(c);
                c.algo.lr = lr;
            });
            for step in 0..8 {
                l.on_transition(
                    TransitionHeader {
                        step: step / 2,
                        ..header(step as u32 % 2)
                    },
                    &ROW,
                );
            }
            l.replay.flush();
            let first = l.stats.weights_version;
            let mut healthy = 0;
            let err = loop {
                match l.train_round() {
                    Ok(()) => healthy += 1,
                    Err(e) => break Some(e.to_string()),
                }
                if healthy == 5 {
                    break None;
                }
            };
            assert_eq!(l.stats.weights_version, first + healthy);
            match err {
                None => assert_eq!(lr, 3e-4, "no divergence in 5 rounds at lr {lr}"),
                Some(err) => {
                    assert_eq!(lr, 1e30, "{err}");
                    assert!(err.contains("training diverged in round"), "{err}");
                }
            }
            let _ = std::fs::remove_dir_all(dir);
        }
    }

    /// A worker's first hello is logged as a join; a second hello before its cursor is sent, or
    /// from the process already accepted, is not.
    #[test]
    fn a_worker_joining_is_logged_once() {
        let (mut l, dir) = learner(Mode::Async);
        let ours = l.handshake;
        let hello = |worker, incarnation| proto::Report::hello(ours, worker, 0, incarnation);
        l.workers.accepting[1] = None;
        let joined = |log: &str| log.matches("worker 1 joined").count();
        let log = logged(|| l.on_report(&hello(1, 9)));
        assert_eq!(joined(&log), 1, "{log}");
        let log = logged(|| l.on_report(&hello(1, 9)));
        assert_eq!(joined(&log), 0, "its cursor is due already: {log}");
        l.workers.cursor_due[1] = None;
        l.workers.accepting[1] = Some(9);
        let log = logged(|| l.on_report(&hello(1, 9)));
        assert_eq!(joined(&log), 0, "accepted already: {log}");
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn only_the_newest_periodic_checkpoints_are_kept() {
        let dir = std::env::temp_dir().join(format!("selkd-prune-{}", std::process::id()));
        for name in [
            "step-900",
            "step-10000",
            "step-2000",
            "step-3000",
            "final",
            "step-x",
        ] {
            std::fs::create_dir_all(dir.join(name)).unwrap();
        }
        std::fs::write(dir.join("latest"), "step-10000\n").unwrap();
        prune_checkpoints(&dir, 2);
        let mut left: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        // Numeric order, not text order: step-10000 is the newest.
        assert_eq!(
            left,
            ["final", "latest", "step-10000", "step-3000", "step-x"]
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn avtd_holds_out_every_nth_transition_and_never_trains_on_it() {
        let dir = std::env::temp_dir().join(format!("selkd-avtd-split-{}", std::process::id()));
        let mut cfg = Config::default();
        cfg.run.mode = Mode::Async;
        cfg.algo.actors = 1;
        cfg.algo.method = crate::config::Method::Avtd {
            variants: vec![crate::config::Regulariser::None; 2],
            validation_every: 4,
            weight_decay: 1e-4,
        };
        cfg.algo.warmup_steps = 1_000_000; // no training: only the split is under test
        cfg.validate().unwrap();
        let mut l = Learner::new(cfg, &dir, None).unwrap();
        l.workers.accepting = vec![Some(7)];
        l.workers.granted = vec![u64::MAX];
        // Transition t (1-based) carries t in its first observation entry.
        for t in 1..=40 {
            let row = [t as f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
            l.on_transition(header(0), &row);
        }
        l.replay.flush();
        let validation = &mut l.selkd.avtd.as_mut().expect("AVTD").validation;
        validation.flush();
        let first = |b: &mut ReplayBuffer| -> Vec<f32> {
            let mut v = Vec::<f32>::try_from(b.export().select(1, 0)).unwrap();
            v.sort_by(f32::total_cmp);
            v
        };
        let held: Vec<f32> = (1..=10).map(|i| (4 * i) as f32).collect();
        assert_eq!(first(validation), held, "the 4th, 8th, … transitions");
        let trained = first(&mut l.replay);
        assert_eq!(trained.len(), 30);
        assert!(
            trained.iter().all(|t| !held.contains(t)),
            "a held-out transition is in the replay buffer: {trained:?}"
        );
        assert_eq!(
            l.stats.inserted, 40,
            "held-out transitions count as env steps"
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn sync_rounds_store_one_transition_per_actor_in_actor_order() {
        let (mut l, dir) = learner(Mode::Sync);
        let row = |v: f32| [v, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        // Worker 1 runs ahead by two steps; nothing is stored until worker 0's step arrives.
        l.on_transition(header(1), &row(10.0));
        l.on_transition(header(1), &row(11.0));
        l.advance_sync().unwrap();
        assert_eq!(l.stats.inserted, 0);
        l.on_transition(header(0), &row(0.0));
        l.advance_sync().unwrap();
        assert_eq!((l.stats.inserted, l.stats.lockstep_rounds), (2, 1));
        let stored = Vec::<f32>::try_from(l.replay.export().select(1, 0)).unwrap();
        assert_eq!(stored, vec![0.0, 10.0], "actor 0's step, then actor 1's");
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn an_epochs_row_waits_for_every_actors_evaluation_and_carries_the_steps_it_ended_at() {
        let mut e = Epochs::from_resumed(None, 2);
        assert!(e.evals_in());
        e.eval_epoch = 2;
        e.epoch_ends = VecDeque::from([(1, 1003), (2, 2005)]);
        assert!(!e.evals_in());
        assert!(e.evaluation(0, 1, f64::NAN));
        assert!(!e.evaluation(0, 1, f64::NAN), "counted once");
        assert!(!e.evaluation(0, 0, f64::NAN), "an older epoch");
        assert_eq!(
            e.next_to_log(1000),
            None,
            "actor 1 has not reported epoch 1"
        );
        assert!(e.evaluation(1, 2, 0.5));
        assert_eq!(e.eval_success[1], (2, 0.5));
        assert_eq!(e.next_to_log(1000), Some((1, 1003)));
        assert_eq!(e.next_to_log(1000), None, "epoch 2 waits for actor 0");
        assert!(!e.evals_in());
        assert!(e.evaluation(0, 2, f64::NAN));
        assert!(e.evals_in());
        assert_eq!(e.next_to_log(1000), Some((2, 2005)));
        assert_eq!(e.next_to_log(1000), None);
        // An epoch whose end is not on record: its multiple of the epoch length.
        e.eval_epoch = 3;
        e.evaluation(0, 3, f64::NAN);
        e.evaluation(1, 3, f64::NAN);
        assert_eq!(e.next_to_log(1000), Some((3, 3000)));
        // ... also when a later epoch's end is on record: that one is not its end.
        e.eval_epoch = 5;
        e.epoch_ends = VecDeque::from([(5, 5007)]);
        e.evaluation(0, 5, f64::NAN);
        e.evaluation(1, 5, f64::NAN);
        assert_eq!(e.next_to_log(1000), Some((4, 4000)));
        assert_eq!(e.next_to_log(1000), Some((5, 5007)));
    }

    #[test]
    fn a_hello_asks_for_a_cursor_an_evaluation_scores_its_actor_and_strangers_are_ignored() {
        let (mut l, dir) = learner(Mode::Async);
        let ours = l.handshake;
        let hello =
            |worker, h: Handshake, incarnation| proto::Report::hello(h, worker, 0, incarnation);
        l.workers.benched[1] = true;
        l.on_report(&hello(1, ours, 9));
        assert_eq!(l.workers.cursor_due, vec![None, Some(9)]);
        assert!(!l.workers.benched[1], "heard from");
        // Another env's worker gets no cursor; nor does a worker index past the run's actors.
        l.on_report(&hello(
            0,
            Handshake::ours("hopper", ours.env_options, 11, 3),
            5,
        ));
        l.on_report(&hello(2, ours, 4));
        assert_eq!(l.workers.cursor_due, vec![None, Some(9)]);
        // An evaluation scores its actor, once per epoch.
        let eval = proto::Report {
            kind: ReportKind::Evaluation,
            epoch: 1,
            mean_return: -150.0,
            success_rate: 0.25,
            ..hello(0, ours, 7)
        };
        l.on_report(&eval);
        assert_eq!(l.ranking.scores()[0], Some(-150.0));
        assert_eq!(l.epochs.eval_reported, vec![1, 0]);
        assert_eq!(l.epochs.eval_success[0], (1, 0.25));
        l.on_report(&proto::Report {
            mean_return: 99.0,
            ..eval
        });
        assert_eq!(l.ranking.scores()[0], Some(-150.0), "the same epoch again");
        l.on_report(&proto::Report {
            epoch: 2,
            mean_return: -120.0,
            ..eval
        });
        assert_eq!(l.ranking.scores()[0], Some(-120.0));
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn rates_are_the_counts_over_a_window_of_a_second_or_more() {
        let mut pass = Pass::new(100, 10);
        // Under a second: no rate yet, and the window stays.
        assert_eq!(pass.rates(400, 70), (0.0, 0.0));
        // A window that started 2 s ago with 100 env steps and 10 critic updates: 300 more env
        // steps and 60 more updates by now are 30 updates/s and 150 env steps/s.
        pass.window = (Instant::now() - Duration::from_secs(2), 100, 10);
        let (updates_per_s, env_steps_per_s) = pass.rates(400, 70);
        assert!((updates_per_s - 30.0).abs() < 0.3, "{updates_per_s}");
        assert!((env_steps_per_s - 150.0).abs() < 1.5, "{env_steps_per_s}");
        // The window restarted at (400, 70): within the next second the rates stay as measured.
        assert_eq!(pass.window.1, 400);
        assert_eq!(pass.window.2, 70);
        assert_eq!(pass.rates(500, 80), (updates_per_s, env_steps_per_s));
    }

    #[test]
    fn control_is_resent_exactly_when_a_field_that_changes_during_a_run_changed() {
        let (mut l, dir) = learner(Mode::Async);
        let c = l.control(false);
        assert!(same_control(&c, &c.clone()));
        let changed: [(&str, fn(&mut Control)); 5] = [
            ("weights_version", |c| c.weights_version += 1),
            ("eval_epoch", |c| c.eval_epoch += 1),
            ("stop", |c| c.stop = 1),
            ("budget of actor 0", |c| c.budget[0] += 1),
            ("budget of actor 1", |c| c.budget[1] += 1),
        ];
        for (what, change) in changed {
            let mut d = c;
            change(&mut d);
            assert!(
                !same_control(&c, &d),
                "{what} changed but the control is not resent"
            );
            assert!(
                !same_control(&d, &c),
                "{what} changed but the control is not resent"
            );
        }
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The kernel's CPU flags in `cpuinfo`, read here as the reference (the code asks the CPU
    /// itself).
    fn kernel_says_bf16(cpuinfo: &str) -> bool {
        cpuinfo
            .lines()
            .filter(|l| l.starts_with("flags"))
            .flat_map(|l| l.split_whitespace())
            .any(|f| f == "avx512_bf16" || f == "amx_bf16")
    }

    #[test]
    fn bf16_matmuls_are_refused_exactly_on_a_cpu_without_them_and_name_the_fix() {
        use crate::config::Precision::{Bf16, Fp32};
        for cpu_bf16 in [false, true] {
            for device in [Device::Cpu, Device::Cuda(0)] {
                for matmul in [Fp32, Bf16] {
                    // The one refusal: bf16 on a CPU without it.
                    let refused = (matmul, device, cpu_bf16) == (Bf16, Device::Cpu, false);
                    let got = check_matmul_on(matmul, device, cpu_bf16);
                    assert_eq!(got.is_err(), refused, "{matmul:?} {device:?} {cpu_bf16}");
                    if let Err(e) = got {
                        let e = e.to_string();
                        assert!(
                            e.contains(&cpu_model())
                                && e.contains("use algo.critic_matmul = \"fp32\""),
                            "{e}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
    fn this_cpus_bf16_is_the_one_its_kernel_reports() {
        use crate::config::Precision;
        let info = std::fs::read_to_string("/proc/cpuinfo").unwrap();
        assert!(check_matmul(Precision::Fp32, Device::Cpu).is_ok());
        assert!(check_matmul(Precision::Bf16, Device::Cuda(0)).is_ok());
        let bf16 = check_matmul(Precision::Bf16, Device::Cpu);
        assert_eq!(bf16.is_ok(), kernel_says_bf16(&info), "{bf16:?}");
        // The model named is the one /proc/cpuinfo names.
        let model = cpu_model();
        assert!(!model.is_empty() && model != "unknown CPU", "{model:?}");
        assert!(
            info.lines()
                .any(|l| l.starts_with("model name")
                    && l.trim_end().ends_with(&format!(": {model}"))),
            "{model:?}"
        );
    }

    #[test]
    fn periodic_checkpoints_fall_at_each_multiple_and_never_at_the_budget() {
        let dir = std::env::temp_dir().join(format!("selkd-periodic-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut cfg = Config::default();
        cfg.run.mode = Mode::Async;
        cfg.algo.actors = 1;
        cfg.run.checkpoint_every = 10;
        cfg.run.total_env_steps = 30;
        cfg.run.keep_checkpoints = 10;
        cfg.run.checkpoint_replay = false;
        let mut l = Learner::new(cfg, &dir, None).unwrap();
        assert_eq!(l.out.next_checkpoint, 10);
        let written = |dir: &Path| {
            let mut names: Vec<String> = std::fs::read_dir(dir.join("checkpoints"))
                .unwrap()
                .map(|e| e.unwrap().file_name().into_string().unwrap())
                .filter(|n| n.starts_with("step-"))
                .collect();
            names.sort();
            names
        };
        for (inserted, expected, next) in [
            (9, vec![], 10),
            (10, vec!["step-10"], 20),
            (15, vec!["step-10"], 20),
            // Late (a pass that stored several transitions): written now, then due at the next
            // multiple of 10 after the one missed.
            (25, vec!["step-10", "step-25"], 30),
            (29, vec!["step-10", "step-25"], 30),
            // The budget: the final checkpoint is written instead.
            (30, vec!["step-10", "step-25"], 30),
        ] {
            l.stats.inserted = inserted;
            l.periodic_checkpoint().unwrap();
            assert_eq!(written(&dir), expected, "at {inserted} env steps");
            assert_eq!(l.out.next_checkpoint, next, "at {inserted} env steps");
        }
        // A resumed run's first periodic checkpoint is the next multiple past its steps.
        let file = |n: &str| std::fs::File::create(dir.join(n)).unwrap();
        assert_eq!(
            Outputs::new(&dir, file("m1"), 25, 10, None).next_checkpoint,
            30
        );
        assert_eq!(
            Outputs::new(&dir, file("m2"), 30, 10, None).next_checkpoint,
            40
        );
        assert_eq!(
            Outputs::new(&dir, file("m3"), 0, 10, None).next_checkpoint,
            10
        );
        assert_eq!(
            Outputs::new(&dir, file("m4"), 25, 0, None).next_checkpoint,
            0
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The test above checks the flags on this CPU only (one with AVX-512 BF16 here): the
    /// kernel's AMX flag, read by hand, on CPUs described in text.
    #[test]
    fn amx_bf16_in_the_kernels_flags_counts_as_native_bf16() {
        let amx = "model name\t: Xeon\nflags\t\t: fpu avx2 amx_tile amx_bf16 amx_int8\n";
        let avx2 = "model name\t: EPYC\nflags\t\t: fpu avx2 avx512f amx_bf16x\n";
        assert!(bf16_native(false, amx));
        assert!(
            !bf16_native(false, avx2),
            "no amx_bf16 flag, only a longer name"
        );
        assert!(bf16_native(true, avx2), "AVX-512 BF16");
        assert!(!bf16_native(false, ""), "no /proc/cpuinfo");
    }

    /// An epoch's row: the rates over the run's wall clock, an actor's return and success only
    /// from an evaluation of this epoch or later, per-actor statistics only once a round has
    /// them (expectations by hand).
    #[test]
    fn an_epochs_row_holds_the_runs_rates_and_only_this_epochs_evaluations() {
        let (mut l, dir) = learner(Mode::Async);
        let ours = l.handshake;
        let before = l.metrics_row(1, 1000);
        assert!(
            before
                .alpha
                .iter()
                .chain(&before.kl_to_best)
                .all(|v| v.is_nan()),
            "{before:?}"
        );
        assert!(before.eval_return.iter().all(|v| v.is_nan()));
        l.out.wall_offset = 50.0;
        l.selkd.critic_updates = 600;
        l.stats.inserted = 300;
        l.stats.last_round.alpha = vec![0.2, 0.3];
        l.stats.last_round.kl_to_best = vec![0.0, 1.5];
        let eval = |worker, epoch, mean_return, success_rate| proto::Report {
            kind: ReportKind::Evaluation,
            epoch,
            mean_return,
            success_rate,
            ..proto::Report::hello(ours, worker, 0, 7)
        };
        l.on_report(&eval(0, 2, -150.0, 0.25));
        l.on_report(&eval(1, 1, 80.0, 0.5));
        let row = l.metrics_row(2, 2000);
        assert!((50.0..60.0).contains(&row.wall_s), "{}", row.wall_s);
        assert_eq!(row.updates_per_s, 600.0 / row.wall_s);
        assert_eq!(row.env_steps_per_s, 300.0 / row.wall_s);
        assert!(
            (11.0..12.0).contains(&row.updates_per_s),
            "{}",
            row.updates_per_s
        );
        assert_eq!(row.alpha, vec![0.2, 0.3]);
        assert_eq!(row.kl_to_best, vec![0.0, 1.5]);
        // Actor 1's latest evaluation is of epoch 1: none for epoch 2.
        assert_eq!(row.eval_return[0], -150.0);
        assert!(row.eval_return[1].is_nan(), "{:?}", row.eval_return);
        assert_eq!(row.eval_success[0], 0.25);
        assert!(row.eval_success[1].is_nan(), "{:?}", row.eval_success);
        let first = l.metrics_row(1, 1000);
        assert_eq!((first.eval_return[1], first.eval_success[1]), (80.0, 0.5));
        let _ = std::fs::remove_dir_all(dir);
    }

    /// A run ends at its budget once the final evaluations are in, or 120 s after it reached
    /// the budget without them (a worker that died at the end must not hang the run); that wait
    /// starts at the budget, once.
    #[test]
    fn a_run_ends_at_its_budget_with_its_evaluations_or_120_s_after_without_them() {
        let (mut l, dir) = learner(Mode::Async);
        let total = l.cfg.run.total_env_steps;
        l.epochs.eval_epoch = 1;
        assert!(!l.epochs.evals_in(), "both actors owe epoch 1");
        let mut since = None;
        l.stats.inserted = total - 1;
        assert!(!l.finished(&mut since));
        assert_eq!(since, None, "the wait starts at the budget, not before");
        l.stats.inserted = total;
        assert!(!l.finished(&mut since), "evaluations owed");
        let started = since.expect("the wait starts at the budget");
        assert!(!l.finished(&mut since));
        assert_eq!(since, Some(started), "started once, not again each pass");
        assert!(
            !l.finished(&mut Some(ago(100))),
            "still waiting after 100 s"
        );
        assert!(l.finished(&mut Some(ago(121))), "gave up after 120 s");
        assert!(l.epochs.evaluation(0, 1, f64::NAN) && l.epochs.evaluation(1, 1, f64::NAN));
        assert!(l.finished(&mut Some(Instant::now())), "evaluations in");
        l.stats.inserted = total - 1;
        assert!(!l.finished(&mut Some(ago(121))), "below the budget");
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The progress line goes out once a second and the live scalars every 5 s, both at the
    /// end too (the times each was last written show it).
    #[test]
    fn progress_goes_out_every_second_live_scalars_every_5_s_and_both_at_the_end() {
        let (mut l, dir) = learner(Mode::Async);
        let mut pass = Pass::new(0, 0);
        let just_now = Instant::now();
        std::thread::sleep(Duration::from_millis(2));
        let written = |pass: &mut Pass, l: &mut Learner, progress, live, done| {
            (pass.last_progress, pass.last_live) = (progress, live);
            l.report_progress(pass, done);
            (pass.last_progress != progress, pass.last_live != live)
        };
        assert_eq!(
            written(&mut pass, &mut l, just_now, just_now, false),
            (false, false)
        );
        assert_eq!(
            written(&mut pass, &mut l, ago(2), ago(2), false),
            (true, false)
        );
        assert_eq!(
            written(&mut pass, &mut l, ago(2), ago(6), false),
            (true, true)
        );
        assert_eq!(
            written(&mut pass, &mut l, just_now, ago(6), false),
            (false, false)
        );
        assert_eq!(
            written(&mut pass, &mut l, just_now, just_now, true),
            (true, true),
            "the end"
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The watchdog reports only workers the run waits on: a worker that has sent its whole
    /// grant and owes no evaluation is idle, not hung (reporting it would get a healthy worker
    /// killed while the learner trains); a sync worker whose step of the round is in waits too.
    #[test]
    fn the_run_waits_on_a_worker_for_a_step_of_its_budget_an_evaluation_or_its_joining() {
        for mode in [Mode::Sync, Mode::Async] {
            let (mut l, dir) = learner(mode);
            let mut control = l.control(false);
            control.budget[..2].copy_from_slice(&[3, 3]);
            l.workers.rollouts[0].sent = 2;
            l.workers.rollouts[1].sent = 3;
            assert_eq!(
                l.waited_on(&control),
                [true, false],
                "{mode:?}: owed a step, done"
            );
            l.workers.rollouts[1].sent = 4;
            assert_eq!(
                l.waited_on(&control),
                [true, false],
                "{mode:?}: past its budget"
            );
            l.workers.pending[0].push_back(Pending {
                worker: 0,
                episode_return: None,
                row: None,
            });
            // A sync worker whose step is in waits for the round; an async one steps on.
            assert_eq!(
                l.waited_on(&control),
                [mode == Mode::Async, false],
                "{mode:?}"
            );
            l.workers.rollouts[0].sent = 3;
            l.workers.pending[0].clear();
            assert_eq!(l.waited_on(&control), [false, false], "{mode:?}: both done");
            l.epochs.eval_epoch = 1;
            l.epochs.eval_reported = vec![1, 0];
            assert_eq!(
                l.waited_on(&control),
                [false, true],
                "{mode:?}: owes an evaluation"
            );
            l.epochs.eval_reported = vec![1, 1];
            l.workers.accepting[0] = None;
            assert_eq!(l.waited_on(&control), [true, false], "{mode:?}: not joined");
            l.workers.rollouts[0].sent = 0;
            l.epochs.eval_reported = vec![0, 0];
            control.stop = 1;
            assert_eq!(l.waited_on(&control), [false, false], "{mode:?}: stopping");
            let _ = std::fs::remove_dir_all(dir);
        }
    }

    #[test]
    fn the_wall_clock_continues_from_the_resumed_runs() {
        let (mut l, dir) = learner(Mode::Sync);
        l.out.wall_offset = 100.0;
        std::thread::sleep(Duration::from_millis(20));
        let wall = l.out.wall();
        assert!((100.02..110.0).contains(&wall), "{wall}");
        let _ = std::fs::remove_dir_all(dir);
    }

    /// What the control tells the workers, worked out by hand from the config: in a sync run
    /// (K = 2, a 5 000-step warm-up, 300 000 env steps) the warm-up's 2 500 steps an actor at once,
    /// then one step per round up to the actor's 150 000; in an async run the grants, with the
    /// configured policy lag. The run's shape and the stop order ride along.
    #[test]
    fn the_control_grants_a_sync_run_its_warm_up_at_once_then_one_step_per_round() {
        let (mut l, dir) = learner(Mode::Sync);
        assert_eq!(
            (l.cfg.algo.warmup_steps, l.cfg.run.total_env_steps),
            (5000, 300_000)
        );
        let c = l.control(false);
        assert_eq!(&c.budget[..3], &[2500, 2500, 0], "the warm-up at once");
        l.stats.lockstep_rounds = 2600;
        assert_eq!(
            &l.control(false).budget[..3],
            &[2601, 2601, 0],
            "one more round"
        );
        l.stats.lockstep_rounds = 149_999;
        assert_eq!(&l.control(false).budget[..2], &[150_000, 150_000]);
        l.stats.lockstep_rounds = 150_000;
        assert_eq!(
            &l.control(false).budget[..2],
            &[150_000, 150_000],
            "the actor's share"
        );
        assert_eq!((c.actors, c.obs_dim, c.act_dim), (2, 3, 1), "Pendulum");
        assert_eq!(
            (c.env, c.env_options),
            (l.handshake.env, l.handshake.env_options)
        );
        assert_eq!(c.protocol_version, l.handshake.protocol_version);
        assert_eq!((c.seed, c.warmup_steps, c.eval_episodes), (1, 2500, 10));
        assert_eq!((&c.hidden[..3], c.hidden_layers), (&[256, 256, 0][..], 2));
        assert_eq!((c.max_policy_lag, c.exploration_noise, c.stop), (0, 0.0, 0));
        l.stats.weights_version = 7;
        l.epochs.eval_epoch = 3;
        let c = l.control(true);
        assert_eq!((c.weights_version, c.eval_epoch, c.stop), (7, 3, 1));
        let _ = std::fs::remove_dir_all(dir);

        let (mut l, dir) = learner(Mode::Async);
        l.workers.granted = vec![40, 0];
        let c = l.control(false);
        assert_eq!(c.max_policy_lag, 4);
        assert_eq!(
            &c.budget[..2],
            &l.workers.granted[..],
            "the grants, topped up"
        );
        assert!(c.budget[0] >= 40 && c.budget[2..].iter().all(|&b| b == 0));
        let _ = std::fs::remove_dir_all(dir);
    }

    /// An epoch ends at its multiple of `eval.epoch_env_steps`: in a sync run at the end of the
    /// round that reaches it (the evaluation runs after the round), in an async run at once; a
    /// transition that ends an episode scores its actor with the episode's return.
    #[test]
    fn an_epoch_ends_at_its_round_in_a_sync_run_and_at_its_step_in_an_async_one() {
        for (mode, end) in [(Mode::Sync, 4), (Mode::Async, 3)] {
            let (mut l, dir) = learner(mode);
            l.cfg.eval.epoch_env_steps = 3;
            let pending = |worker, episode_return| Pending {
                worker,
                episode_return,
                row: None,
            };
            l.store(pending(0, None));
            l.store(pending(1, Some(-5.0)));
            assert_eq!((l.epochs.eval_epoch, l.epochs.epoch_ends.len()), (0, 0));
            l.store(pending(0, None));
            assert_eq!(l.epochs.eval_epoch, 1, "{mode:?}");
            assert_eq!(
                Vec::from(l.epochs.epoch_ends.clone()),
                vec![(1, end)],
                "{mode:?}"
            );
            l.store(pending(1, Some(-3.0)));
            l.store(pending(0, None));
            assert_eq!(l.epochs.epoch_ends.len(), 1, "epoch 2 ends at 6");
            l.store(pending(1, None));
            assert_eq!(
                Vec::from(l.epochs.epoch_ends.clone()),
                vec![(1, end), (2, 6)]
            );
            assert_eq!(l.stats.inserted, 6);
            assert_eq!(
                l.ranking.scores(),
                vec![None, Some(-4.0)],
                "the mean of -5 and -3"
            );
            let _ = std::fs::remove_dir_all(dir);
        }
    }

    /// A small run: a 4-step warm-up (2 steps an actor), 6 env steps in all, small networks.
    fn tiny(cfg: &mut Config) {
        cfg.algo.warmup_steps = 4;
        cfg.algo.batch_size = 4;
        cfg.algo.hidden = vec![8, 8];
        cfg.run.total_env_steps = 6;
    }

    /// Algorithm 1's lockstep: nothing is stored while an evaluation is out, a round is stored
    /// once both actors' steps are in, the round that completes the warm-up trains and hands
    /// the weights out before the next round is stored, and nothing is stored past the budget.
    #[test]
    fn a_sync_round_is_stored_when_every_actor_is_in_and_trains_once_warmed_up() {
        let (mut l, dir) = learner_with(Mode::Sync, tiny);
        for _ in 0..4 {
            l.on_transition(header(0), &ROW);
            l.on_transition(header(1), &ROW);
        }
        l.epochs.eval_epoch = 1;
        assert!(!l.advance_sync().unwrap());
        assert_eq!(l.stats.inserted, 0, "an evaluation is out");
        l.epochs.evaluation(0, 1, f64::NAN);
        l.epochs.evaluation(1, 1, f64::NAN);
        assert!(
            l.advance_sync().unwrap(),
            "the second round completes the warm-up"
        );
        // Epoch 1's row is written as the learner stood when its evaluations came in, before
        // the round that trained (a row written after it would depend on message timing).
        let metrics = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
        let rows: Vec<Vec<&str>> = metrics.lines().map(|l| l.split(',').collect()).collect();
        let updates = rows[0].iter().position(|&c| c == "critic_updates").unwrap();
        assert_eq!(rows.len(), 2, "{metrics}");
        assert_eq!((rows[1][0], rows[1][updates]), ("1", "0"), "{metrics}");
        assert_eq!((l.stats.inserted, l.stats.lockstep_rounds), (4, 2));
        assert_eq!(
            (l.stats.weights_version, l.selkd.actor_updates),
            (2, 1),
            "version 1: the initial weights"
        );
        assert_eq!(
            l.workers
                .pending
                .iter()
                .map(|q| q.len())
                .collect::<Vec<_>>(),
            [2, 2]
        );
        assert!(l.advance_sync().unwrap(), "one round, one training round");
        assert_eq!((l.stats.inserted, l.stats.weights_version), (6, 3));
        assert!(!l.advance_sync().unwrap(), "the budget is spent");
        assert_eq!((l.stats.inserted, l.stats.lockstep_rounds), (6, 3));
        assert_eq!(l.workers.pending[0].len(), 1);
        let _ = std::fs::remove_dir_all(dir);
    }

    /// Async: a training round once the warm-up's 4 transitions are in, then one per K = 2
    /// more, never ahead of the data.
    #[test]
    fn an_async_run_trains_one_round_per_k_transitions_after_the_warm_up() {
        let (mut l, dir) = learner_with(Mode::Async, tiny);
        let mut trained = vec![];
        for step in 0..6 {
            l.on_transition(header(step % 2), &ROW);
            trained.push(l.advance_async().unwrap());
            trained.push(l.advance_async().unwrap());
        }
        assert_eq!(l.stats.inserted, 6);
        assert_eq!(
            trained,
            [false, false, false, false, false, false, true, false, false, false, true, false]
        );
        assert_eq!((l.selkd.actor_updates, l.stats.weights_version), (2, 3));
        let _ = std::fs::remove_dir_all(dir);
    }

    /// The ranking as broadcast: every score slot past the actors, and an actor without a score,
    /// NaN.
    #[test]
    fn the_ranking_message_carries_the_scores_the_best_and_the_version() {
        let (mut l, dir) = learner(Mode::Sync);
        assert!(l.ranking.evaluation(1, 1, 42.0));
        let m = l.ranking_message();
        assert_eq!((m.version, m.actors, m.best), (1, 2, 1));
        assert!(m.scores[0].is_nan() && m.scores[2..].iter().all(|s| s.is_nan()));
        assert_eq!(m.scores[1], 42.0);
        let _ = std::fs::remove_dir_all(dir);
    }

    /// A resumed run's metrics.csv keeps its header and the rows of the epochs its checkpoint had
    /// logged; later rows (written after that checkpoint) go, and so does anything not a row.
    #[test]
    fn a_resumed_runs_metrics_keep_the_header_and_the_epochs_logged() {
        let dir = std::env::temp_dir().join(format!("selkd-truncate-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("metrics.csv");
        std::fs::write(
            &path,
            "epoch,env_steps\n1,1000\n2,2000\n3,3000\n4,4\nhalf a li",
        )
        .unwrap();
        truncate_metrics(&path, 2).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "epoch,env_steps\n1,1000\n2,2000\n"
        );
        truncate_metrics(&path, 0).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "epoch,env_steps\n");
        let e = truncate_metrics(&dir.join("absent.csv"), 1).unwrap_err();
        assert!(format!("{e:#}").contains("absent.csv"), "{e:#}");
        let _ = std::fs::remove_dir_all(dir);
    }

    /// `run.device`: "cpu", or CUDA where libtorch sees it; otherwise a one-line error that says
    /// what to write instead (on this CPU-only CI the CUDA branch is the error).
    #[test]
    fn devices_parse_and_cuda_without_a_gpu_is_a_clear_error() {
        assert!(matches!(parse_device("cpu").unwrap(), Device::Cpu));
        for s in ["cuda", "cuda:0"] {
            match parse_device(s) {
                Ok(d) => assert!(tch::Cuda::is_available() && d == Device::Cuda(0), "{s}"),
                Err(e) => {
                    assert!(!tch::Cuda::is_available(), "{s}: {e}");
                    assert!(e.to_string().contains("use --set run.device=cpu"), "{e}");
                }
            }
        }
        let e = parse_device("gpu").unwrap_err().to_string();
        assert!(
            e.contains("use cpu, cuda or cuda:N") && !e.contains('\n'),
            "{e}"
        );
    }
}
