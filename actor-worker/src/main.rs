//! `actor-worker`: one SELKD actor. It rolls out its actor's current policy in its own seeded env,
//! publishes every transition to the learner over iceoryx2, swaps in new weights as they arrive,
//! and runs the deterministic evaluation episodes the learner asks for. A worker started again
//! with the same run id and index rejoins the run with the learner's latest weights.

mod link;
mod rollout;

use anyhow::{bail, Result};
use clap::Parser;
use link::{learner_alive, Link};
use rollout::{env_failed, Rollout};
use selkd_policy::evaluation;
use selkd_protocol::{services, Control, Handshake, ReportKind, Services};
use std::time::{Duration, Instant};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "One SELKD actor: steps its env with its policy and streams transitions to the learner"
)]
pub struct Args {
    /// Run id shared with the learner (keeps runs on one host apart).
    #[arg(long)]
    pub run_id: String,
    /// Which actor this worker runs, 0-based.
    #[arg(long)]
    pub worker: usize,
    /// Env to run; must be the learner's.
    #[arg(long)]
    env: String,
    /// The run's `[env_options]` as JSON (must be the learner's).
    #[arg(long, default_value = "{}")]
    env_options: String,
    /// How many earlier processes ran this worker (the launcher counts restarts); varies the seeds.
    #[arg(long, default_value_t = 0)]
    pub generation: u32,
    /// Give up if no learner answers within this many seconds.
    #[arg(long, default_value_t = 60.0)]
    pub connect_timeout: f64,
}

fn main() {
    // `gymnasium:` envs step in an embedded Python.
    selkd_gymnasium::register();
    selkd_protocol::init_tracing();
    let args = Args::parse();
    match run(&args) {
        Ok(()) => {}
        Err(e) => {
            eprintln!("actor-worker {}: error: {e:#}", args.worker);
            std::process::exit(exit_code(&e));
        }
    }
}

/// `EXIT_CANNOT_JOIN` where this worker cannot work with the run (another env or build, an
/// index past the actors, env options the env refuses): the launcher then stops the run
/// instead of restarting the worker. Any other failure is 1, worth a restart.
fn exit_code(e: &anyhow::Error) -> i32 {
    let mismatch = e.downcast_ref::<selkd_protocol::ProtocolError>().is_some()
        || e.downcast_ref::<CannotJoin>().is_some()
        || e.downcast_ref::<selkd_envs::EnvError>().is_some();
    if mismatch {
        selkd_protocol::EXIT_CANNOT_JOIN
    } else {
        1
    }
}

/// This worker's arguments cannot work with this run (retrying would not help).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct CannotJoin(pub String);

fn run(args: &Args) -> Result<()> {
    let env_options: selkd_envs::EnvOptions =
        serde_json::from_str(&args.env_options).map_err(|e| {
            CannotJoin(format!(
                "--env-options is not a JSON object of options: {e}"
            ))
        })?;
    let env = selkd_envs::make_with(&args.env, &env_options)?;
    let spec = env.spec().clone();
    let fingerprint = selkd_envs::variant_fingerprint(&env_options, env.physics());
    let ours = Handshake::ours(spec.id, fingerprint, spec.obs_dim, spec.act_dim);
    selkd_protocol::stale::clean_up();
    // Named after the run: the learner looks for it to tell a gone worker from a quiet one.
    let node = services::node(&selkd_protocol::worker_node_name(&args.run_id, args.worker))
        .map_err(|e| anyhow::anyhow!("starting iceoryx2 node: {e}"))?;
    let mut link = Link::join(args, &node, &Services::new(&args.run_id), ours)?;
    let (cursor, recorded_actions) = link.wait_for_cursor()?;
    let seed = link.control.seed;
    let mut rollout = Rollout::resume(env, args.worker, seed, &cursor, &recorded_actions)?;
    let (sent, episode, step) = rollout.place();
    let (generation, weights_version) = (args.generation, link.weights_version);
    let worker = args.worker;
    tracing::info!(
        worker,
        generation,
        weights_version,
        sent,
        episode,
        step,
        "joined run {}",
        args.run_id
    );

    // A restarted worker redoes the current evaluation: its predecessor may have died before reporting
    // it (the learner ignores an epoch it already has).
    let mut evaluated = 0u64;
    let mut eval_env = selkd_envs::make_with(&args.env, &env_options)?;
    let mut last_learner_check = Instant::now();
    loop {
        link.receive()?;
        let control = link.control;
        let next = next_move(
            &control,
            worker,
            link.weights_version,
            evaluated,
            rollout.sent,
        );
        if next == Next::Stop {
            tracing::info!(worker, sent = rollout.sent, "learner asked to stop");
            return Ok(());
        }
        if let Some(other) = link.newer_cursor()? {
            tracing::warn!(
                worker,
                sent = rollout.sent,
                "another process (incarnation {other:x}) took over actor {worker}; this one stops"
            );
            return Ok(());
        }
        match next {
            Next::Evaluate => {
                evaluate(&mut *eval_env, &link, seed)?;
                evaluated = control.eval_epoch;
                continue;
            }
            Next::Step => {
                rollout.step(link.policy(), &control, |taken, row| {
                    link.publish(taken, row)
                })?;
                continue;
            }
            Next::Stop | Next::Wait => {}
        }
        // Nothing allowed yet: sleep until the learner says something.
        link.wait(Duration::from_millis(200))?;
        if last_learner_check.elapsed() > Duration::from_secs(2) {
            last_learner_check = Instant::now();
            if !learner_alive(&args.run_id)? {
                bail!("the learner of run `{}` is gone; stopping", args.run_id);
            }
        }
    }
}

/// What a worker does next under the learner's `control`.
#[derive(Debug, PartialEq, Eq)]
enum Next {
    /// The learner asked the run to stop.
    Stop,
    /// Evaluate the epoch the learner announced: one not yet evaluated (`evaluated` is the
    /// latest done), and only with the weights of that epoch's end or newer.
    Evaluate,
    /// Take one env step: within this worker's budget, with weights at most `max_policy_lag`
    /// versions behind the learner's.
    Step,
    /// Nothing allowed yet.
    Wait,
}

fn next_move(
    control: &Control,
    worker: usize,
    weights_version: u64,
    evaluated: u64,
    sent: u64,
) -> Next {
    if control.stop != 0 {
        return Next::Stop;
    }
    if control.eval_epoch > evaluated && weights_version >= control.weights_version {
        return Next::Evaluate;
    }
    let fresh = weights_version + control.max_policy_lag >= control.weights_version;
    if sent < control.budget[worker] && fresh {
        Next::Step
    } else {
        Next::Wait
    }
}

/// The deterministic evaluation the learner asked for, of the current weights on the worker's
/// own env; every actor plays the same episode seeds this epoch (common random numbers).
fn evaluate(env: &mut dyn selkd_envs::Env, link: &Link, seed: u64) -> Result<()> {
    let (epoch, episodes) = (link.control.eval_epoch, link.control.eval_episodes);
    let seeds = (0..episodes as u64).map(|e| evaluation::epoch_seed(seed, epoch, e));
    let result = evaluation::evaluate(env, link.policy(), seeds);
    env_failed(env)?;
    link.report(
        ReportKind::Evaluation,
        epoch,
        episodes,
        result.mean_return(),
        result.success_rate(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_worker_that_cannot_join_says_so_in_its_exit_code() {
        let cannot = selkd_protocol::EXIT_CANNOT_JOIN;
        assert_ne!(cannot, 1);
        let name = selkd_protocol::ProtocolError::Name("a b".into(), "a space".into());
        let unknown = selkd_envs::EnvError::Unknown {
            name: "hoper".into(),
            known: "hopper".into(),
        };
        for (e, want) in [
            (anyhow::Error::new(name), cannot),
            (anyhow::Error::new(CannotJoin("--worker 5".into())), cannot),
            (anyhow::Error::new(unknown), cannot),
            // Through the context a caller adds.
            (
                anyhow::Error::new(CannotJoin("--worker 5".into())).context("joining"),
                cannot,
            ),
            (anyhow::anyhow!("the learner of run `r` is gone"), 1),
        ] {
            assert_eq!(exit_code(&e), want, "{e:#}");
        }
    }

    /// Orders: learner at weights version 5, epoch 2 announced, lag 1, worker 1 may step to 100.
    fn control() -> Control {
        let mut budget = [0; selkd_protocol::MAX_ACTORS];
        budget[1] = 100;
        Control {
            actors: 2,
            env: selkd_protocol::Name::new("pendulum"),
            obs_dim: 3,
            act_dim: 1,
            seed: 1,
            weights_version: 5,
            max_policy_lag: 1,
            eval_epoch: 2,
            eval_episodes: 1,
            budget,
            ..Default::default()
        }
    }

    #[test]
    fn a_worker_stops_evaluates_steps_or_waits_as_the_orders_say() {
        let c = control();
        // (weights held, epoch evaluated, transitions sent) → what it does.
        assert_eq!(next_move(&c, 1, 5, 1, 0), Next::Evaluate, "epoch 2 is new");
        assert_eq!(next_move(&c, 1, 6, 1, 0), Next::Evaluate);
        assert_eq!(next_move(&c, 1, 5, 2, 0), Next::Step, "epoch 2 is done");
        assert_eq!(next_move(&c, 1, 5, 3, 0), Next::Step);
        // Not with weights older than the epoch's end: it steps meanwhile (one version behind is
        // within the lag), and waits when two behind.
        assert_eq!(next_move(&c, 1, 4, 1, 0), Next::Step);
        assert_eq!(next_move(&c, 1, 3, 2, 0), Next::Wait);
        let lag2 = Control {
            max_policy_lag: 2,
            ..c
        };
        assert_eq!(next_move(&lag2, 1, 3, 2, 0), Next::Step);
        // Its own budget: 100 for worker 1, none for worker 0.
        assert_eq!(next_move(&c, 1, 5, 2, 99), Next::Step);
        assert_eq!(next_move(&c, 1, 5, 2, 100), Next::Wait);
        assert_eq!(next_move(&c, 0, 5, 2, 0), Next::Wait);
        // A stop overrides everything.
        let stop = Control { stop: 1, ..c };
        assert_eq!(next_move(&stop, 1, 5, 1, 0), Next::Stop);
        assert_eq!(next_move(&stop, 1, 5, 2, 0), Next::Stop);
    }
}
