//! SELKD's training step, read alongside the paper's Algorithm 1 and SPEC.md.
//!
//! Lines 3–6 of Algorithm 1 (each actor takes a step and stores it) happen in the actor-worker
//! processes and reach [`ReplayBuffer`] through the learner service. Everything from line 7 on is
//! here, top to bottom, in [`Selkd::train_round`]:
//!
//! ```text
//!  7: for G updates:
//!  8-10:  sample mini-batch(es) B and critic subset(s) 𝓜            (per-update: one; per-critic: N)
//!  11:    y = r + γ(1 − terminated) · max_i [ min_{m∈𝓜} Q̄_m(s', ã'_i) − α_i log π_i(ã'_i|s') ]
//!  12:    minimise Σ_j mean_B ½ (Q_j(s, a) − y)²
//!  13:    Q̄_j ← ρ Q̄_j + (1 − ρ) Q_j
//!  16: for each actor i (all at once, each on its own mini-batch):
//!  18:    J_i = KL(π_i(·|s) ‖ π_best(·|s))                               (0 for the best actor)
//!  19:    maximise mean_s [ (1/N) Σ_j Q_j(s, ã_i) − α_i log π_i(ã_i|s) − λ_KD J_i ]
//!         and tune α_i toward the target entropy.
//! ```

use crate::config::{AlgoConfig, Sharing};
use crate::distillation::gaussian_kl;
use crate::ensemble::Ensemble;
use crate::optim::Adam;
use crate::replay::ReplayBuffer;
use crate::squashed_gaussian::{sample, split_head};
use crate::targets::critic_target;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64;
use tch::{Device, Kind, Tensor};

/// K actors, N critics and N target critics, their optimisers and temperatures.
pub struct Selkd {
    pub cfg: AlgoConfig,
    pub obs_dim: usize,
    pub act_dim: usize,
    pub device: Device,
    /// K actors, stacked: `obs → hidden… → 2·act` (μ and log σ).
    pub actors: Ensemble,
    /// N critics, stacked: `obs + act → hidden… → 1`.
    pub critics: Ensemble,
    pub target_critics: Ensemble,
    /// `log α_i`, shape `[K]`.
    pub log_alpha: Tensor,
    pub actor_opt: Adam,
    pub critic_opt: Adam,
    pub alpha_opt: Adam,
    /// Every random draw of the learner (batches, subsets, noise) comes from here, so a seed and
    /// this state fix a run.
    pub rng: Pcg64,
    pub critic_updates: u64,
    pub actor_updates: u64,
}

/// What one round measured, for metrics.
#[derive(Clone, Debug, Default)]
pub struct RoundStats {
    pub critic_loss: f64,
    pub q_mean: f64,
    pub actor_loss: Vec<f64>,
    pub alpha: Vec<f64>,
    pub kl_to_best: Vec<f64>,
    pub entropy: Vec<f64>,
}

impl Selkd {
    pub fn new(
        cfg: &AlgoConfig,
        obs_dim: usize,
        act_dim: usize,
        device: Device,
        seed: u64,
    ) -> Self {
        // Line 1: random, independent initialisation of every actor and critic; targets copy critics.
        let mut rng = Pcg64::seed_from_u64(seed);
        let dims = |input: usize, out: usize| [vec![input], cfg.hidden.clone(), vec![out]].concat();
        let actors = Ensemble::new(cfg.actors, &dims(obs_dim, 2 * act_dim), device, &mut rng);
        let critics = Ensemble::new(cfg.critics, &dims(obs_dim + act_dim, 1), device, &mut rng);
        let target_critics = critics.copy();
        let log_alpha =
            Tensor::zeros([cfg.actors as i64], (Kind::Float, device)).set_requires_grad(true);
        Self {
            actor_opt: Adam::new(&actors.params(), cfg.lr),
            critic_opt: Adam::new(&critics.params(), cfg.lr),
            alpha_opt: Adam::new(&[&log_alpha], cfg.alpha_lr),
            cfg: cfg.clone(),
            obs_dim,
            act_dim,
            device,
            actors,
            critics,
            target_critics,
            log_alpha,
            rng,
            critic_updates: 0,
            actor_updates: 0,
        }
    }

    /// Lines 7–20 of Algorithm 1: G critic updates, then one update of every actor.
    pub fn train_round(&mut self, replay: &mut ReplayBuffer, best: usize) -> RoundStats {
        let mut stats = RoundStats::default();
        for _ in 0..self.cfg.utd {
            let (loss, q) = self.update_critics(replay);
            stats.critic_loss += loss / self.cfg.utd as f64;
            stats.q_mean += q / self.cfg.utd as f64;
        }
        self.update_actors(replay, best, &mut stats);
        stats
    }

    /// One critic update (lines 8–13). Returns (loss, mean Q).
    pub fn update_critics(&mut self, replay: &mut ReplayBuffer) -> (f64, f64) {
        let (n, m, b) = (self.cfg.critics, self.cfg.subset, self.cfg.batch_size);
        // Lines 9–10. per-update: one batch and subset for all N critics (REDQ's code);
        // per-critic: critic j gets its own batch and subset, as Algorithm 1 prints it.
        let groups = match self.cfg.sharing {
            Sharing::PerUpdate => 1,
            Sharing::PerCritic => n,
        };
        let batch = replay.sample(groups, b, &mut self.rng);
        let subsets: Vec<i64> = (0..groups)
            .flat_map(|_| {
                rand::seq::index::sample(&mut self.rng, n, m)
                    .into_iter()
                    .map(|j| j as i64)
                    .collect::<Vec<_>>()
            })
            .collect();
        // Line 11: the in-target max-min value, without gradient.
        let y = tch::no_grad(|| {
            self.target(
                &batch.reward,
                &batch.terminated,
                &batch.next_obs,
                &subsets,
                groups,
            )
        });
        // Line 12: every critic regresses on its y (all N at once; the loss sums the N critics'
        // losses, so each critic's gradient is its own).
        let x = Tensor::cat(&[&batch.obs, &batch.act], -1).expand([n as i64, b as i64, -1], false);
        let q = self.critics.forward(&x).squeeze_dim(-1);
        let loss = ((&q - &y).square() * 0.5)
            .mean_dim(1, false, Kind::Float)
            .sum(Kind::Float);
        loss.backward();
        self.critic_opt.step(&self.critics.params());
        // Line 13: Polyak averaging of the target critics after every critic update.
        self.target_critics
            .polyak_toward(&self.critics, self.cfg.polyak);
        self.critic_updates += 1;
        (
            loss.double_value(&[]) / n as f64,
            q.mean(Kind::Float).double_value(&[]),
        )
    }

    /// y for `groups` groups of next states `[groups, B, obs]`, each with its own subset of M
    /// critics (`subsets`, groups × M indices). Returns `[groups, B]`.
    fn target(
        &mut self,
        reward: &Tensor,
        terminated: &Tensor,
        next_obs: &Tensor,
        subsets: &[i64],
        groups: usize,
    ) -> Tensor {
        let (k, m, b) = (
            self.cfg.actors as i64,
            self.cfg.subset as i64,
            self.cfg.batch_size as i64,
        );
        let g = groups as i64;
        // ã'_i ~ π_i(·|s') for every actor i on every next state.
        let s2 = next_obs
            .reshape([1, g * b, -1])
            .expand([k, g * b, -1], false);
        let (mu, log_std) = split_head(&self.actors.forward(&s2));
        let eps = self.noise(&[k, g * b, self.act_dim as i64]);
        let (a2, logp2) = sample(&mu, &log_std, &eps);
        // Rows of group gi: (actor, row) pairs; each goes through that group's M target critics.
        let x2 = Tensor::cat(&[&s2, &a2], -1)
            .view([k, g, b, -1])
            .permute([1, 0, 2, 3])
            .reshape([g, 1, k * b, -1]);
        let x2 = x2
            .expand([g, m, k * b, -1], false)
            .reshape([g * m, k * b, -1]);
        let index = Tensor::from_slice(subsets).to_device(self.device);
        let q_next = self
            .target_critics
            .select(&index)
            .forward(&x2)
            .view([g, m, k, b]);
        let logp2 = logp2.view([k, g, b]).permute([1, 0, 2]);
        critic_target(
            reward,
            terminated,
            &q_next,
            &logp2,
            &self.alpha(),
            self.cfg.gamma,
            self.cfg.target,
        )
    }

    /// Lines 16–20, all K actors at once, each on its own mini-batch.
    fn update_actors(&mut self, replay: &mut ReplayBuffer, best: usize, stats: &mut RoundStats) {
        let (k, n, b) = (
            self.cfg.actors as i64,
            self.cfg.critics as i64,
            self.cfg.batch_size as i64,
        );
        let batch = replay.sample(self.cfg.actors, self.cfg.batch_size, &mut self.rng); // line 17
        let s = &batch.obs;
        let (mu, log_std) = split_head(&self.actors.forward(s));
        let eps = self.noise(&[k, b, self.act_dim as i64]);
        let (a, logp) = sample(&mu, &log_std, &eps);
        // (1/N) Σ_j Q_j(s, ã_i(s)): the critics are fixed here, only the actor moves.
        let x = Tensor::cat(&[s, &a], -1)
            .reshape([1, k * b, -1])
            .expand([n, k * b, -1], false);
        let q = self
            .critics
            .detached()
            .forward(&x)
            .mean_dim(0, false, Kind::Float)
            .view([k, b]);
        // Line 18: distillation toward the best actor, held fixed, on actor i's own states.
        let best_head = self
            .actors
            .member(best as i64)
            .forward(&s.reshape([1, k * b, -1]))
            .view([k, b, -1]);
        let (mu_best, log_std_best) = split_head(&best_head);
        let kl = gaussian_kl(&mu, &log_std, &mu_best, &log_std_best);
        let mut kd = vec![self.cfg.kd_weight as f32; self.cfg.actors];
        kd[best] = 0.0;
        let kd = Tensor::from_slice(&kd).to_device(self.device).view([k, 1]);
        // Line 19 (as a loss to minimise).
        let alpha = self.alpha().view([k, 1]);
        let per_actor = (&alpha * &logp - &q + &kd * &kl).mean_dim(1, false, Kind::Float);
        per_actor.sum(Kind::Float).backward();
        self.actor_opt.step(&self.actors.params());
        // Temperature: minimise −log α_i · (log π_i + target entropy), detached from the actor.
        if self.cfg.fixed_alpha.is_none() {
            let target_entropy = self.cfg.target_entropy.unwrap_or(-(self.act_dim as f64));
            let alpha_loss = -(&self.log_alpha.view([k, 1]) * (logp.detach() + target_entropy))
                .mean_dim(1, false, Kind::Float)
                .sum(Kind::Float);
            alpha_loss.backward();
            self.alpha_opt.step(&[&self.log_alpha]);
        }
        self.actor_updates += 1;
        stats.actor_loss = Vec::<f64>::try_from(per_actor.detach().to_kind(Kind::Double)).unwrap();
        stats.alpha = Vec::<f64>::try_from(self.alpha().to_kind(Kind::Double)).unwrap();
        stats.kl_to_best =
            Vec::<f64>::try_from(kl.detach().mean_dim(1, false, Kind::Double)).unwrap();
        stats.entropy =
            Vec::<f64>::try_from(-logp.detach().mean_dim(1, false, Kind::Double)).unwrap();
    }

    /// α_i for every actor, `[K]`, without gradient.
    pub fn alpha(&self) -> Tensor {
        match self.cfg.fixed_alpha {
            Some(a) => Tensor::full([self.cfg.actors as i64], a, (Kind::Float, self.device)),
            None => self.log_alpha.detach().exp(),
        }
    }

    /// Standard normal noise from the learner's own generator.
    fn noise(&mut self, shape: &[i64]) -> Tensor {
        let count: i64 = shape.iter().product();
        let v: Vec<f32> = (0..count)
            .map(|_| StandardNormal.sample(&mut self.rng))
            .collect();
        Tensor::from_slice(&v).view(shape).to_device(self.device)
    }

    /// Actor `i`'s weights in the flat layout workers use.
    pub fn actor_weights(&self, i: usize) -> Vec<f32> {
        self.actors.member_flat(i as i64)
    }
}
