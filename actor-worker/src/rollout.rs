//! The worker's env side: its seeded episodes, the replay that continues one mid-way, and one
//! step of the policy. Nothing here knows of iceoryx2: a step hands its transition to a closure.

use crate::CannotJoin;
use anyhow::Result;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use selkd_envs::{Env, EnvSpec};
use selkd_policy::Actor;
use selkd_protocol::{Control, CursorHeader, TransitionRow};

/// One 64-bit seed from several parts (SplitMix64's finaliser over each in turn): nearby inputs
/// give unrelated seeds.
pub fn mix(parts: &[u64]) -> u64 {
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

/// An env that failed (a Python exception in a Gymnasium env) fails the worker with its
/// message; a restart would only fail again the same way, so it counts as "cannot join".
pub fn env_failed(env: &dyn Env) -> Result<()> {
    match env.failure() {
        Some(why) => Err(selkd_envs::EnvError::Failed(why).into()),
        None => Ok(()),
    }
}

/// Where one transition sits in the rollout, as its header tells the learner.
pub struct Taken {
    pub episode: u64,
    pub step: u64,
    /// A uniform draw of the warm-up, not the policy's.
    pub warmup: bool,
    /// The episode's return when this transition ends it, else NaN.
    pub episode_return: f64,
}

/// Actor `worker`'s rollout: its env mid-episode and its place in the run.
pub struct Rollout {
    env: Box<dyn Env>,
    spec: EnvSpec,
    worker: usize,
    seed: u64,
    /// Transitions taken so far; the next one is number `sent`.
    pub sent: u64,
    episode: u64,
    /// The step within the episode.
    t: u64,
    obs: Vec<f32>,
    episode_return: f64,
    row: TransitionRow,
    /// The row being written, reused from step to step.
    buf: Vec<f32>,
}

impl Rollout {
    /// Continues the rollout where the learner's record of it ends (`cursor`): the episode's
    /// recorded actions replayed on its seed leave the env exactly where the last transition the
    /// learner has left it (the env is deterministic given seed and actions).
    pub fn resume(
        mut env: Box<dyn Env>,
        worker: usize,
        seed: u64,
        cursor: &CursorHeader,
        recorded_actions: &[f32],
    ) -> Result<Self> {
        let spec = env.spec().clone();
        let (episode, t) = (cursor.episode, cursor.step);
        let mut obs = env.reset(Some(episode_seed(seed, worker, episode)));
        let mut episode_return = 0.0f64;
        if recorded_actions.len() as u64 != t * spec.act_dim as u64 {
            return Err(CannotJoin(format!(
                "the learner's cursor for actor {worker} holds {} action values for {t} steps of {}",
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
        let row = TransitionRow {
            obs_dim: spec.obs_dim,
            act_dim: spec.act_dim,
        };
        Ok(Self {
            env,
            spec,
            buf: Vec::with_capacity(row.len()),
            row,
            worker,
            seed,
            sent: cursor.sent,
            episode,
            t,
            obs,
            episode_return,
        })
    }

    /// One step: the warm-up's uniform draw or the policy's action (`control` says which, and
    /// with what noise), its transition written as one row and handed to `publish`; then the
    /// next state, or a new episode when this one ended.
    pub fn step(
        &mut self,
        policy: &Actor,
        control: &Control,
        publish: impl FnOnce(&Taken, &[f32]) -> Result<()>,
    ) -> Result<()> {
        let warmup = self.sent < control.warmup_steps;
        let mut action_rng = step_rng(self.seed, self.worker, self.episode, self.t);
        let action: Vec<f32> = if warmup {
            (0..self.spec.act_dim)
                .map(|_| action_rng.gen_range(-1.0f32..=1.0))
                .collect()
        } else if control.exploration_noise > 0.0 {
            policy.noisy_mean_action(&self.obs, control.exploration_noise, &mut action_rng)
        } else {
            policy.sample_action(&self.obs, &mut action_rng)
        };
        let step = self.env.step(&action);
        env_failed(&*self.env)?;
        self.episode_return += step.reward;
        let done = step.terminated || step.truncated;
        self.row.write(
            &mut self.buf,
            &self.obs,
            &action,
            step.reward as f32,
            &step.obs,
            step.terminated,
            step.truncated,
        );
        let taken = Taken {
            episode: self.episode,
            step: self.t,
            warmup,
            episode_return: if done { self.episode_return } else { f64::NAN },
        };
        publish(&taken, &self.buf)?;
        self.sent += 1;
        self.t += 1;
        if done {
            self.episode += 1;
            self.obs = self
                .env
                .reset(Some(episode_seed(self.seed, self.worker, self.episode)));
            env_failed(&*self.env)?;
            self.t = 0;
            self.episode_return = 0.0;
        } else {
            self.obs = step.obs;
        }
        Ok(())
    }

    /// Where the rollout is, for the log: (sent, episode, step).
    pub fn place(&self) -> (u64, u64, u64) {
        (self.sent, self.episode, self.t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The seeds are part of a run's files: a run resumed (or a worker restarted) by another
    /// build replays the recorded episode on its seed, so `mix` must never change. The values were
    /// computed outside this code (the same SplitMix64 steps in Python's integers, mod 2^64).
    #[test]
    fn seeds_are_pinned_across_builds() {
        assert_eq!(mix(&[]), 0x5e1d_0000_0000_0000);
        assert_eq!(mix(&[0]), 0x15ce_f833_2d3d_3e4a);
        assert_eq!(mix(&[1]), 0x1dd2_f92c_c8e1_590e);
        assert_eq!(episode_seed(7, 0, 3), 0x47d2_5944_9022_689c);
        assert_eq!(episode_seed(7, 1, 3), 0x2987_660a_119a_9dd7);
        assert_eq!(mix(&[42, 2, 0, 5, 1]), 0x9c0a_7e7c_c937_82bc);
    }

    /// Worker 0's cursor `step` steps into its first episode.
    fn cursor(step: u64) -> CursorHeader {
        CursorHeader {
            worker: 0,
            incarnation: 1,
            sent: step,
            episode: 0,
            step,
        }
    }

    /// A record whose actions end the episode when replayed (another env build, or an env that
    /// does not repeat itself) must refuse the join, not go on from a finished episode.
    #[test]
    fn a_record_that_ends_its_episode_on_replay_is_refused() {
        let env = || selkd_envs::make("hopper").unwrap();
        // Full torque on every joint for 300 steps: the hopper falls long before.
        let actions = vec![1.0f32; 300 * 3];
        let err = Rollout::resume(env(), 0, 9, &cursor(300), &actions)
            .err()
            .expect("a replay that ends its episode must fail");
        let why = err
            .downcast_ref::<CannotJoin>()
            .expect("CannotJoin")
            .0
            .clone();
        assert!(why.contains("ended it at step"), "{why}");
        // The first few of those steps are still inside the episode: resumed fine.
        assert!(Rollout::resume(env(), 0, 9, &cursor(3), &actions[..9]).is_ok());
    }

    /// A worker restarted mid-episode replays the recorded steps and goes on: the rows it sends
    /// after the cursor and the episode's return (what ranks the actors) must be those of a
    /// worker that was never interrupted, including the reward of the replayed steps.
    #[test]
    fn a_resumed_rollout_continues_the_episode_exactly() {
        let env = || selkd_envs::make("pendulum").unwrap();
        let spec = env().spec().clone();
        let layout = selkd_policy::ActorLayout::new(spec.obs_dim, spec.act_dim, &[4]);
        let n = layout.num_params();
        // Small non-zero weights: the policy's actions depend on the state.
        let params = (0..n)
            .map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.05)
            .collect();
        let policy = Actor::from_flat(layout, params).unwrap();
        let control = |warmup_steps| Control {
            protocol_version: 0,
            actors: 1,
            env: selkd_protocol::Name::new("pendulum"),
            obs_dim: spec.obs_dim as u32,
            act_dim: spec.act_dim as u32,
            seed: 5,
            warmup_steps,
            ..Default::default()
        };

        // 20 warm-up steps, then the policy's, to the end of the 200-step episode.
        let play = |mut r: Rollout, steps| {
            let (mut rows, mut warmup) = (Vec::new(), Vec::new());
            let mut ret = f64::NAN;
            for _ in 0..steps {
                r.step(&policy, &control(20), |taken, row| {
                    rows.push(row.to_vec());
                    warmup.push(taken.warmup);
                    ret = taken.episode_return;
                    Ok(())
                })
                .unwrap();
            }
            (rows, ret, warmup)
        };
        let (rows, whole, warmup) =
            play(Rollout::resume(env(), 0, 5, &cursor(0), &[]).unwrap(), 200);
        // Uniform draws for exactly the first `warmup_steps` transitions, the policy after.
        let expected: Vec<bool> = (0..200).map(|i| i < 20).collect();
        assert_eq!(warmup, expected, "which steps are warm-up");
        // ... and the warm-up's draws cover the action box [−1, 1] (Pendulum has one action).
        let row = TransitionRow {
            obs_dim: spec.obs_dim,
            act_dim: spec.act_dim,
        };
        let drawn: Vec<f32> = rows[..20].iter().map(|r| row.split(r).1[0]).collect();
        let (lo, hi) = drawn
            .iter()
            .fold((1f32, -1f32), |(l, h), &a| (l.min(a), h.max(a)));
        assert!(
            lo >= -1.0 && hi <= 1.0 && lo < -0.5 && hi > 0.5,
            "warm-up draws {drawn:?}"
        );
        // After it, SAC's workers (no exploration noise) sample from the policy: not its mean.
        let off_mean = rows[20..]
            .iter()
            .filter(|r| {
                let (obs, action, ..) = row.split(r);
                (action[0] - policy.mean_action(obs)[0]).abs() > 1e-3
            })
            .count();
        assert!(
            off_mean > 100,
            "{off_mean} of 180 sampled actions differ from the mean action"
        );
        assert!(
            whole.is_finite() && whole < 0.0,
            "pendulum's return: {whole}"
        );
        let at = 60;
        let actions: Vec<f32> = rows[..at]
            .iter()
            .flat_map(|r| row.split(r).1.to_vec())
            .collect();
        let resumed = Rollout::resume(env(), 0, 5, &cursor(at as u64), &actions).unwrap();
        let (rest, resumed_return, _) = play(resumed, 200 - at);
        assert_eq!(rest, rows[at..], "the rows after the cursor");
        assert_eq!(
            resumed_return, whole,
            "the episode's return counts the replayed steps"
        );
    }
}
