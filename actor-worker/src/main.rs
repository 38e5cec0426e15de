//! `actor-worker`: one SELKD actor. It rolls out its actor's current policy in its own seeded env,
//! publishes every transition to the learner over iceoryx2, swaps in new weights as they arrive,
//! and runs the deterministic evaluation episodes the learner asks for. A worker started again
//! with the same run id and index rejoins the run with the learner's latest weights.

use anyhow::{bail, Context, Result};
use clap::Parser;
use iceoryx2::prelude::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use selkd_policy::{evaluation, Actor, ActorLayout};
use selkd_protocol::{
    check_peer, services, Control, CursorHeader, Handshake, Report, ReportKind, Services,
    TransitionHeader, TransitionRow, WorkerPorts,
};
use std::time::{Duration, Instant};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "One SELKD actor: steps its env with its policy and streams transitions to the learner"
)]
struct Args {
    /// Run id shared with the learner (keeps runs on one host apart).
    #[arg(long)]
    run_id: String,
    /// Which actor this worker runs, 0-based.
    #[arg(long)]
    worker: usize,
    /// Env to run; must be the learner's.
    #[arg(long)]
    env: String,
    /// The run's `[env_options]` as JSON (must be the learner's).
    #[arg(long, default_value = "{}")]
    env_options: String,
    /// How many earlier processes ran this worker (the launcher counts restarts); varies the seeds.
    #[arg(long, default_value_t = 0)]
    generation: u32,
    /// Give up if no learner answers within this many seconds.
    #[arg(long, default_value_t = 60.0)]
    connect_timeout: f64,
}

fn main() {
    // `gymnasium:` envs step in an embedded Python.
    selkd_gymnasium::register();
    selkd_protocol::init_tracing();
    let args = Args::parse();
    match run(&args) {
        Ok(()) => {}
        Err(e) => {
            let mismatch = e.downcast_ref::<selkd_protocol::ProtocolError>().is_some()
                || e.downcast_ref::<CannotJoin>().is_some()
                || e.downcast_ref::<selkd_envs::EnvError>().is_some();
            eprintln!("actor-worker {}: error: {e:#}", args.worker);
            std::process::exit(if mismatch {
                selkd_protocol::EXIT_CANNOT_JOIN
            } else {
                1
            });
        }
    }
}

/// This worker's arguments cannot work with this run (retrying would not help).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
struct CannotJoin(String);

/// One 64-bit seed from several parts (SplitMix64's finaliser over each in turn): nearby inputs
/// give unrelated seeds.
fn mix(parts: &[u64]) -> u64 {
    let mut h = 0x5e1d_0000_0000_0000u64;
    for &p in parts {
        h = (h ^ p).wrapping_add(0x9e37_79b9_7f4a_7c15);
        h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        h ^= h >> 31;
    }
    h
}

/// The reset seed of this worker's `episode`-th episode. Seeds follow from where a step sits in
/// the rollout, never from when or in which process it runs: a worker that continues from its
/// cursor (after a restart, or in a resumed run) takes exactly the steps its predecessor would have.
fn episode_seed(seed: u64, worker: usize, episode: u64) -> u64 {
    mix(&[seed, worker as u64, episode, 2])
}

/// The random numbers of one step's action (warm-up draw or policy sample).
fn step_rng(seed: u64, worker: usize, episode: u64, step: u64) -> Pcg64 {
    Pcg64::seed_from_u64(mix(&[seed, worker as u64, episode, step, 1]))
}

/// Random for each process: tells the learner this process from an earlier (or a duplicate) one.
fn new_incarnation() -> u64 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    mix(&[std::process::id() as u64, nanos])
}

fn run(args: &Args) -> Result<()> {
    let env_options: selkd_envs::EnvOptions =
        serde_json::from_str(&args.env_options).map_err(|e| {
            CannotJoin(format!(
                "--env-options is not a JSON object of options: {e}"
            ))
        })?;
    let mut env = selkd_envs::make_with(&args.env, &env_options)?;
    let spec = env.spec().clone();
    let options_fingerprint = selkd_envs::options_fingerprint(&env_options);
    // A predecessor killed while it made its node left an entry iceoryx2 cannot clean.
    match selkd_protocol::stale::remove_half_made_nodes() {
        Ok(r) => {
            for p in &r.removed {
                tracing::info!(
                    "removed the half-made iceoryx2 node entry {} (its process died while making it)",
                    p.display()
                );
            }
            for (p, why) in &r.left {
                tracing::warn!("left the iceoryx2 node entry {}: {why}", p.display());
            }
        }
        Err(e) => tracing::warn!("looking for half-made iceoryx2 node entries: {e}"),
    }
    // Named after the run: the learner looks for it to tell a gone worker from a quiet one.
    let node = services::node(&selkd_protocol::worker_node_name(&args.run_id, args.worker))
        .map_err(|e| anyhow::anyhow!("starting iceoryx2 node: {e}"))?;
    let svc = Services::new(&args.run_id);

    // The learner announces the run on `control` (history 1): wait for it, then check we fit.
    let control_sub = WorkerPorts::control(&node, &svc).map_err(|e| anyhow::anyhow!("{e}"))?;
    let deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
    let mut control: Control = loop {
        if let Some(s) = control_sub.receive()? {
            break *s.payload();
        }
        if Instant::now() > deadline {
            bail!("no learner for run `{}` answered within {} s; start `learner` first (or use `selkd train`)", args.run_id, args.connect_timeout);
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let ours = Handshake::ours(spec.id, options_fingerprint, spec.obs_dim, spec.act_dim);
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
    let k = control.actors as usize;
    let hidden: Vec<usize> = control.hidden[..control.hidden_layers as usize]
        .iter()
        .map(|&h| h as usize)
        .collect();
    let layout = ActorLayout::new(spec.obs_dim, spec.act_dim, &hidden);

    let row = TransitionRow {
        obs_dim: spec.obs_dim,
        act_dim: spec.act_dim,
    };
    let WorkerPorts {
        control: control_sub,
        weights: weights_sub,
        cursor: cursor_sub,
        transitions: publisher,
        reports,
        to_learner,
        wake,
    } = WorkerPorts::open(&node, &svc, control_sub, args.worker, k, row.len())
        .map_err(|e| anyhow::anyhow!("{e}"))?;

    let mut actor: Option<Actor> = None;
    let mut weights_version = 0u64;
    let receive_weights = |actor: &mut Option<Actor>, version: &mut u64| -> Result<()> {
        while let Some(s) = weights_sub.receive()? {
            match actor {
                Some(a) => a.set_params(s.payload())?,
                None => *actor = Some(Actor::from_flat(layout.clone(), s.payload().to_vec())?),
            }
            *version = s.user_header().version;
        }
        Ok(())
    };
    // Rejoin with the latest weights before doing anything else (they are in the history).
    let deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
    while actor.is_none() {
        receive_weights(&mut actor, &mut weights_version)?;
        if Instant::now() > deadline {
            bail!(
                "the learner announced the run but sent no weights for actor {} within {} s",
                args.worker,
                args.connect_timeout
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let incarnation = new_incarnation();
    let hello = |kind, version, epoch, episodes, mean_return, success_rate| Report {
        kind,
        worker: args.worker as u32,
        generation: args.generation,
        incarnation,
        protocol_version: ours.protocol_version,
        env: ours.env,
        env_options: ours.env_options,
        obs_dim: ours.obs_dim,
        act_dim: ours.act_dim,
        weights_version: version,
        epoch,
        episodes,
        mean_return,
        success_rate,
    };

    // Say hello and wait for the cursor: where the learner's record of this actor's rollout ends.
    let deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
    let mut last_hello: Option<Instant> = None;
    let (cursor, recorded_actions) = loop {
        // Hello again now and then: a learner that was busy (or just started) may have missed it.
        if last_hello.is_none_or(|t| t.elapsed() > Duration::from_secs(1)) {
            reports.send_copy(hello(
                ReportKind::Hello,
                weights_version,
                0,
                0,
                f64::NAN,
                f64::NAN,
            ))?;
            to_learner.notify()?;
            last_hello = Some(Instant::now());
        }
        if let Some(c) = latest_cursor(&cursor_sub, incarnation)? {
            break c;
        }
        if Instant::now() > deadline {
            bail!(
                "the learner of run `{}` did not answer actor {}'s hello within {} s",
                args.run_id,
                args.worker,
                args.connect_timeout
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let seed = control.seed;
    let mut sent = cursor.sent;
    let mut episode = cursor.episode;
    let mut t = cursor.step;
    // Replay the episode's recorded actions on its seed: the env ends up exactly where the last
    // transition the learner has left it (the env is deterministic given seed and actions).
    let mut obs = env.reset(Some(episode_seed(seed, args.worker, episode)));
    let mut episode_return = 0.0f64;
    if recorded_actions.len() as u64 != t * spec.act_dim as u64 {
        return Err(CannotJoin(format!(
            "the learner's cursor for actor {} holds {} action values for {t} steps of {}",
            args.worker,
            recorded_actions.len(),
            spec.act_dim
        ))
        .into());
    }
    env_failed(&*env)?;
    for (i, action) in recorded_actions.chunks(spec.act_dim.max(1)).enumerate() {
        let step = env.step(action);
        env_failed(&*env)?;
        if step.terminated || step.truncated {
            return Err(CannotJoin(format!(
                "replaying episode {episode}'s {t} recorded steps ended it at step {i}: the env does not repeat its episodes (is this actor-worker built from the same source as the learner?)"
            ))
            .into());
        }
        episode_return += step.reward;
        obs = step.obs;
    }
    tracing::info!(
        worker = args.worker,
        generation = args.generation,
        weights_version,
        sent,
        episode,
        step = t,
        "joined run {}",
        args.run_id
    );

    // A restarted worker redoes the current evaluation: its predecessor may have died before reporting
    // it (the learner ignores an epoch it already has).
    let mut evaluated = 0u64;
    let mut eval_env = selkd_envs::make_with(&args.env, &env_options)?;
    let mut buf = Vec::with_capacity(row.len());
    let mut last_learner_check = Instant::now();

    loop {
        receive_weights(&mut actor, &mut weights_version)?;
        while let Some(s) = control_sub.receive()? {
            control = *s.payload();
        }
        if control.stop != 0 {
            tracing::info!(worker = args.worker, sent, "learner asked to stop");
            return Ok(());
        }
        if let Some(other) = newer_cursor(&cursor_sub, incarnation)? {
            tracing::warn!(
                worker = args.worker,
                sent,
                "another process (incarnation {other:x}) took over actor {}; this one stops",
                args.worker
            );
            return Ok(());
        }
        let policy = actor.as_ref().expect("weights received above");
        let fresh = weights_version + control.max_policy_lag >= control.weights_version;
        if control.eval_epoch > evaluated && weights_version >= control.weights_version {
            // Deterministic evaluation of the current weights, on its own env and seeds.
            let epoch = control.eval_epoch;
            // Every actor plays the same episode seeds this epoch (common random numbers).
            let result = evaluation::evaluate(
                &mut *eval_env,
                policy,
                (0..control.eval_episodes as u64).map(|e| evaluation::epoch_seed(seed, epoch, e)),
            );
            env_failed(&*eval_env)?;
            let (mean_return, success_rate) = (result.mean_return(), result.success_rate());
            reports.send_copy(hello(
                ReportKind::Evaluation,
                weights_version,
                epoch,
                control.eval_episodes,
                mean_return,
                success_rate,
            ))?;
            to_learner.notify()?;
            evaluated = epoch;
            continue;
        }
        if sent < control.budget[args.worker] && fresh {
            let warmup = sent < control.warmup_steps;
            let mut action_rng = step_rng(seed, args.worker, episode, t);
            let action: Vec<f32> = if warmup {
                (0..spec.act_dim)
                    .map(|_| action_rng.gen_range(-1.0f32..=1.0))
                    .collect()
            } else {
                if control.exploration_noise > 0.0 {
                    policy.noisy_mean_action(&obs, control.exploration_noise, &mut action_rng)
                } else {
                    policy.sample_action(&obs, &mut action_rng)
                }
            };
            let step = env.step(&action);
            env_failed(&*env)?;
            episode_return += step.reward;
            let done = step.terminated || step.truncated;
            row.write(
                &mut buf,
                &obs,
                &action,
                step.reward as f32,
                &step.obs,
                step.terminated,
                step.truncated,
            );
            let mut sample = publisher.loan_slice_uninit(row.len())?;
            *sample.user_header_mut() = TransitionHeader {
                worker: args.worker as u32,
                generation: args.generation,
                incarnation,
                episode,
                step: t,
                policy_version: if warmup { 0 } else { weights_version },
                obs_dim: spec.obs_dim as u32,
                act_dim: spec.act_dim as u32,
                episode_return: if done { episode_return } else { f64::NAN },
            };
            sample.write_from_slice(&buf).send()?;
            to_learner.notify()?;
            sent += 1;
            t += 1;
            if done {
                episode += 1;
                obs = env.reset(Some(episode_seed(seed, args.worker, episode)));
                env_failed(&*env)?;
                t = 0;
                episode_return = 0.0;
            } else {
                obs = step.obs;
            }
            continue;
        }
        // Nothing allowed yet: sleep until the learner says something.
        selkd_protocol::wait_for_wake(&wake, Duration::from_millis(200))?;
        if last_learner_check.elapsed() > Duration::from_secs(2) {
            last_learner_check = Instant::now();
            if !learner_alive(&args.run_id)? {
                bail!("the learner of run `{}` is gone; stopping", args.run_id);
            }
        }
    }
}

/// An env that failed (a Python exception in a Gymnasium env) fails the worker with its
/// message; a restart would only fail again the same way, so it counts as "cannot join".
fn env_failed(env: &dyn selkd_envs::Env) -> Result<()> {
    match env.failure() {
        Some(why) => Err(selkd_envs::EnvError::Failed(why).into()),
        None => Ok(()),
    }
}

/// The newest cursor the learner published for `incarnation`, with its actions.
fn latest_cursor(
    sub: &services::Subscriber<[f32], CursorHeader>,
    incarnation: u64,
) -> Result<Option<(CursorHeader, Vec<f32>)>> {
    let mut found = None;
    while let Some(s) = sub.receive()? {
        if s.user_header().incarnation == incarnation {
            found = Some((*s.user_header(), s.payload().to_vec()));
        }
    }
    Ok(found)
}

/// The incarnation of a cursor published for another process of this actor, if any: the learner
/// has handed the actor to it.
fn newer_cursor(
    sub: &services::Subscriber<[f32], CursorHeader>,
    incarnation: u64,
) -> Result<Option<u64>> {
    let mut other = None;
    while let Some(s) = sub.receive()? {
        let i = s.user_header().incarnation;
        other = (i != incarnation).then_some(i);
    }
    Ok(other)
}

/// Whether a live `learner` node exists (dead ones are cleaned up by iceoryx2 as it lists them).
fn learner_alive(run_id: &str) -> Result<bool> {
    let name = selkd_protocol::learner_node_name(run_id);
    let mut alive = false;
    Node::<ipc::Service>::list(Config::global_config(), |state| {
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
