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
//!  12:    minimise Σ_j mean_B ½ (Q_j(s, a) − y)²                 (DNS: only j ∈ a k-DPP draw)
//!  13:    Q̄_j ← ρ Q̄_j + (1 − ρ) Q_j
//!  16: for each actor i (all at once, each on its own mini-batch):
//!  18:    J_i = KL(π_i(·|s) ‖ π_best(·|s))                               (0 for the best actor)
//!  19:    maximise mean_s [ (1/N) Σ_j Q_j(s, ã_i) − α_i log π_i(ã_i|s) − λ_KD J_i ]   (SAC: min_j)
//!         and tune α_i toward the target entropy.
//! ```
//!
//! The method ([`Method`]: SELKD, DNS, DPD or AVTD) is resolved once, in [`Selkd::new`], into
//! three small choices that the lines above then follow without asking which method runs:
//! [`TargetPlan`] (line 11: whose next actions go through which target critics), [`CriticStep`]
//! (lines 12–13: every critic, or a k-DPP's draw) and [`ActorObjective`] (lines 18–19: which
//! critics judge an actor, whom it distils toward, whether it learns by RL). AVTD's V agents side
//! by side are V actors, each with its own N critics; its held-out transitions and the choice of
//! the variant that acts are its own state, [`Avtd`].

use crate::config::{ActorQ, AlgoConfig, Backbone, Distillation, Method, Regulariser, Sharing};
use crate::distillation::gaussian_kl;
use crate::dpp;
use crate::ensemble::{half_mean_square, Ensemble};
use crate::optim::Adam;
use crate::replay::{Batch, ReplayBuffer};
use crate::squashed_gaussian::{sample, split_head};
use crate::targets::{critic_target, Formation, InnerOptions};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64;
use tch::{Device, Kind, Tensor};

/// K actors, N critics and N target critics, their optimisers and temperatures.
pub struct Selkd {
    /// The algorithm as trained. For AVTD this is the whole of what is trained: `actors` = V
    /// (one actor per variant, of which one acts) and `critics` = V × the config's N.
    pub cfg: AlgoConfig,
    pub obs_dim: usize,
    pub act_dim: usize,
    pub device: Device,
    /// K actors, stacked: `obs → hidden… → 2·act` (μ and log σ).
    pub actors: Ensemble,
    /// N critics, stacked: `obs + act → hidden… → 1`.
    pub critics: Ensemble,
    pub target_critics: Ensemble,
    /// TD3 backbone only: Polyak-averaged copies of the actors, for the target.
    pub target_actors: Option<Ensemble>,
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
    /// Off (`None`) in training. When `Some`, every random draw is appended to it, so that a test
    /// can replay the same rounds in an independent implementation (`learner/tests/crosscheck.rs`).
    pub draws: Option<Vec<Draw>>,
    /// Lines 10–11 of the method.
    target_plan: TargetPlan,
    /// Lines 12–13 of the method.
    critic_step: CriticStep,
    /// Lines 18–19 of the method.
    objective: ActorObjective,
    /// AVTD's held-out transitions and selection; `None` for every other method.
    pub avtd: Option<Avtd>,
}

/// Lines 10–11, resolved from the method: whose next actions go through which target critics.
enum TargetPlan {
    /// Every actor's next action through each group's random M of the N critics, reduced by
    /// `formation` (inner over the subset, outer over the actors); one group of rows per update,
    /// or one per critic (`per-critic`). SELKD, DNS, and the methods that are SELKD with settings.
    Shared {
        groups: usize,
        formation: Formation,
        aqe_drop: usize,
    },
    /// Actor i's next action through `per_actor` critics of its own only, their min (no max over
    /// actors); critic j regresses on its owner's y. `drawn`: AVTD takes a fresh M of its
    /// variant's N every update; DPD takes all N/K it owns (line 10 still draws M of N, unused,
    /// as it always has, so that runs and the recorded draws stay the same).
    Own { per_actor: usize, drawn: bool },
}

/// Lines 12–13, resolved from the method: which critics step on their loss.
enum CriticStep {
    /// All N, with Polyak averaging in the optimiser's pass; `decay`: AVTD's weight-decay
    /// variants' critics (member indices) and c, whose ½ c ‖W‖² joins their loss.
    All { decay: Option<(Tensor, f64)> },
    /// DNS: only k critics, drawn by a k-DPP over how alike their values on the batch are; the
    /// others keep their weights and Adam state.
    Dpp { k: usize },
}

/// Lines 18–19, resolved from the method: what each actor optimises.
struct ActorObjective {
    /// Whose critics judge actor i's action: all N (SELKD, DNS), or only its own (DPD, AVTD).
    own_critics: bool,
    /// Whom actor i distils toward.
    reference: Reference,
    /// Which actors have the distillation term.
    distils: Distils,
    /// Per actor: 1 if it optimises the RL objective, 0 if it only distils (w/o RL: all but 0).
    rl: Vec<f32>,
}

enum Reference {
    /// The best actor by the ranking (SELKD).
    Best,
    /// Actor i+1 (DPD).
    Peer,
}

enum Distils {
    /// Every actor but the best, or (w/o KD) only the listed ones, the best never.
    AllButBest(Option<Vec<usize>>),
    /// Every actor (DPD: each toward its peer).
    All,
    /// None (AVTD's variants are independent agents).
    None,
}

impl ActorObjective {
    fn selkd(d: &Distillation, actors: usize) -> Self {
        ActorObjective {
            own_critics: false,
            reference: Reference::Best,
            distils: Distils::AllButBest(d.kd_actors.clone()),
            rl: rl_mask(actors, d.without_rl),
        }
    }
}

/// 1 for every actor that optimises the RL objective: all, or (w/o RL) actor 0 alone.
fn rl_mask(actors: usize, without_rl: bool) -> Vec<f32> {
    (0..actors)
        .map(|i| if without_rl && i > 0 { 0.0 } else { 1.0 })
        .collect()
}

/// AVTD's own state: the transitions it holds out and the variant that acts.
pub struct Avtd {
    /// Each variant's regulariser.
    pub variants: Vec<Regulariser>,
    /// The held-out validation transitions (every `validation_every`-th received), never
    /// trained on.
    pub validation: ReplayBuffer,
    validation_every: u64,
    /// The variant that acts: its actor's weights are what workers get.
    pub selected: usize,
    /// Each variant's TD error on the last validation batch.
    pub validation_td: Vec<f64>,
}

/// AVTD re-selects its acting variant every this many rounds (our choice: often enough to follow
/// the data, rarely enough to cost little: the validation batch is 4 mini-batches).
pub const SELECT_EVERY_ROUNDS: u64 = 10;

/// One random draw of the learner, in the order it was drawn.
pub enum Draw {
    /// A critic update's mini-batch (`groups` × B rows) and subsets (`groups` × M indices).
    CriticBatch(Batch, Vec<i64>),
    /// The actor update's mini-batch, K × B rows (row block i for actor i).
    ActorBatch(Batch),
    /// Standard normal noise, in the shape it was used.
    Normal(Tensor),
    /// REM's mixture draws `[G, M]`, before normalisation.
    Uniform(Tensor),
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
        // AVTD: V agents, each with the config's actor and N critics, stacked variant by variant.
        let variants = cfg.method.variants().to_vec();
        let per_variant = cfg.critics;
        let cfg = &AlgoConfig {
            actors: cfg.actors * variants.len().max(1),
            critics: cfg.critics * variants.len().max(1),
            ..cfg.clone()
        };
        let regulariser_of_critic = |j: usize| variants[j / per_variant];
        // Line 1: random, independent initialisation of every actor and critic; targets copy critics.
        let mut rng = Pcg64::seed_from_u64(seed);
        let dims = |input: usize, out: usize| [vec![input], cfg.hidden.clone(), vec![out]].concat();
        let actors = Ensemble::new(cfg.actors, &dims(obs_dim, 2 * act_dim), device, &mut rng);
        let mut critics = Ensemble::new(cfg.critics, &dims(obs_dim + act_dim, 1), device, &mut rng);
        let (n, k) = (cfg.critics, cfg.actors);
        let (target_plan, critic_step, objective, avtd) = match &cfg.method {
            Method::Selkd {
                target,
                aqe_drop,
                sharing,
                distillation,
            } => (
                TargetPlan::Shared {
                    groups: match sharing {
                        Sharing::PerUpdate => 1,
                        Sharing::PerCritic => n,
                    },
                    formation: *target,
                    aqe_drop: *aqe_drop,
                },
                CriticStep::All { decay: None },
                ActorObjective::selkd(distillation, k),
                None,
            ),
            Method::Dns {
                target,
                aqe_drop,
                trained_critics,
                distillation,
            } => (
                TargetPlan::Shared {
                    groups: 1,
                    formation: *target,
                    aqe_drop: *aqe_drop,
                },
                CriticStep::Dpp {
                    k: *trained_critics,
                },
                ActorObjective::selkd(distillation, k),
                None,
            ),
            Method::Dpd { without_rl } => (
                TargetPlan::Own {
                    per_actor: n / k,
                    drawn: false,
                },
                CriticStep::All { decay: None },
                ActorObjective {
                    own_critics: true,
                    reference: Reference::Peer,
                    distils: Distils::All,
                    rl: rl_mask(k, *without_rl),
                },
                None,
            ),
            Method::Avtd {
                variants,
                validation_every,
                weight_decay,
            } => {
                let of = |r: Regulariser| -> Vec<bool> {
                    (0..n).map(|j| regulariser_of_critic(j) == r).collect()
                };
                critics = critics.with_layer_norm(&of(Regulariser::LayerNorm));
                let decayed: Vec<i64> = (0..n)
                    .filter(|&j| regulariser_of_critic(j) == Regulariser::WeightDecay)
                    .map(|j| j as i64)
                    .collect();
                let decay = (!decayed.is_empty() && *weight_decay > 0.0).then(|| {
                    (
                        Tensor::from_slice(&decayed).to_device(device),
                        *weight_decay,
                    )
                });
                // The validation rows: the same FIFO, their share of the capacity.
                let capacity = (cfg.replay_capacity as u64 / validation_every).max(1);
                (
                    TargetPlan::Own {
                        per_actor: per_variant,
                        drawn: true,
                    },
                    CriticStep::All { decay },
                    ActorObjective {
                        own_critics: true,
                        reference: Reference::Best,
                        distils: Distils::None,
                        rl: rl_mask(k, false),
                    },
                    Some(Avtd {
                        variants: variants.clone(),
                        validation: ReplayBuffer::new(capacity as usize, obs_dim, act_dim, device),
                        validation_every: *validation_every,
                        selected: 0,
                        validation_td: vec![f64::NAN; variants.len()],
                    }),
                )
            }
        };
        if cfg.critic_matmul == crate::config::Precision::Bf16 {
            critics.matmul = Kind::BFloat16;
        }
        // `run.cpu_gemm` for critics that autograd never records (see `Ensemble::cpu_gemm`).
        if critics.has_hand_backward() {
            critics.cpu_gemm = crate::matmul::chosen();
        }
        let target_critics = critics.copy();
        let target_actors = cfg.backbone.is_td3().then(|| actors.copy());
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
            target_actors,
            log_alpha,
            rng,
            critic_updates: 0,
            actor_updates: 0,
            draws: None,
            target_plan,
            critic_step,
            objective,
            avtd,
        }
    }

    /// Lines 7–20 of Algorithm 1: G critic updates, then one update of every actor. With
    /// `actor_updates_per_round` = U > 1 (not Algorithm 1), the actors are updated after each of
    /// the last U critic updates; their statistics are the last update's. AVTD then reports its
    /// acting variant's figures and may choose another to act.
    pub fn train_round(&mut self, replay: &mut ReplayBuffer, best: usize) -> RoundStats {
        let mut stats = RoundStats::default();
        let g = self.cfg.utd;
        for update in 0..g {
            let (loss, q) = self.update_critics(replay);
            stats.critic_loss += loss / g as f64;
            stats.q_mean += q / g as f64;
            if update + self.cfg.actor_updates_per_round >= g {
                self.update_actors(replay, best, &mut stats);
            }
        }
        if let Some(avtd) = &self.avtd {
            // Per-actor figures are the acting actor's: the variant that acts.
            for v in [
                &mut stats.actor_loss,
                &mut stats.alpha,
                &mut stats.kl_to_best,
                &mut stats.entropy,
            ] {
                *v = vec![v[avtd.selected]];
            }
            self.select_variant();
        }
        stats
    }

    /// One critic update (lines 8–13). Returns (loss, mean Q).
    pub fn update_critics(&mut self, replay: &mut ReplayBuffer) -> (f64, f64) {
        // Lines 9–10. per-update: one batch and subset for all N critics (REDQ's code);
        // per-critic: critic j gets its own batch and subset, as Algorithm 1 prints it.
        let groups = match self.target_plan {
            TargetPlan::Shared { groups, .. } => groups,
            TargetPlan::Own { .. } => 1,
        };
        let batch = replay.sample(groups, self.cfg.batch_size, &mut self.rng);
        let subsets = self.draw_subsets(groups);
        self.record(|| Draw::CriticBatch(batch.shallow_clone(), subsets.clone()));
        self.update_critics_on(&batch, &subsets)
    }

    /// Line 10: `groups` random subsets of M of the N critics (`groups` × M indices); AVTD: M of
    /// each variant's own N (V × M).
    fn draw_subsets(&mut self, groups: usize) -> Vec<i64> {
        let (n, m) = (self.cfg.critics, self.cfg.subset);
        let (blocks, per_block, offset) = match self.target_plan {
            TargetPlan::Own {
                per_actor,
                drawn: true,
            } => (self.cfg.actors, per_actor, per_actor),
            _ => (groups, n, 0),
        };
        (0..blocks)
            .flat_map(|i| {
                rand::seq::index::sample(&mut self.rng, per_block, m)
                    .into_iter()
                    .map(move |j| (i * offset + j) as i64)
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// Lines 11–13 on a drawn mini-batch (`groups` × B rows) and its subsets (`groups` × M indices).
    pub fn update_critics_on(&mut self, batch: &Batch, subsets: &[i64]) -> (f64, f64) {
        let n = self.cfg.critics;
        // Line 11: the target, without gradient.
        let y = tch::no_grad(|| self.target(batch, subsets));
        // Line 12: every critic regresses on its y (all N at once; each critic's gradient is
        // its own loss's).
        let (q, per_critic) = self.critics.regress(&self.critic_inputs(batch), &y);
        let loss = per_critic.sum(Kind::Float);
        self.step_critics(&q);
        self.critic_updates += 1;
        (
            loss.double_value(&[]) / n as f64,
            q.mean(Kind::Float).double_value(&[]),
        )
    }

    /// Line 12's step on the critics' gradients and line 13's Polyak averaging of the targets.
    /// `q`: the critics' values on the batch, `[N, rows]`, which DNS's draw compares.
    fn step_critics(&mut self, q: &Tensor) {
        match &self.critic_step {
            CriticStep::All { decay } => {
                // AVTD's weight-decay variants: ½ c ‖W‖² over their critics' weight matrices
                // in the loss, added as its gradient c·W (as torch.optim.Adam's weight_decay).
                if let Some((members, c)) = decay {
                    tch::no_grad(|| {
                        for layer in &self.critics.layers {
                            let decay = layer.weight.index_select(0, members) * *c;
                            let _ = layer.weight.grad().index_add_(0, members, &decay);
                        }
                    });
                }
                // Line 13 with it: Polyak averaging of the target critics toward the stepped
                // critics, in the optimiser's pass over the weights.
                self.critic_opt.step_and_average(
                    &self.critics.params(),
                    &self.target_critics.params(),
                    self.cfg.polyak,
                );
            }
            &CriticStep::Dpp { k } => {
                let flat = Vec::<f64>::try_from(
                    &q.detach()
                        .reshape([-1])
                        .to(Device::Cpu)
                        .to_kind(Kind::Double),
                )
                .expect("f64 values");
                let values: Vec<Vec<f64>> = flat
                    .chunks(self.cfg.batch_size)
                    .map(<[f64]>::to_vec)
                    .collect();
                let trained = dpp::sample_k_dpp(&dpp::linear_cka(&values), k, &mut self.rng);
                // Every critic has its gradient; only the drawn ones step on it.
                self.critic_opt
                    .step_members(&self.critics.params(), &trained, self.cfg.critics);
                // Line 13: Polyak averaging of the target critics after every critic update.
                self.target_critics
                    .polyak_toward(&self.critics, self.cfg.polyak);
            }
        }
    }

    /// The next actions `ã'_i` for states `[K, R, obs]` (row block i for actor i) and their log-probs
    /// `[K, R]`: sampled from π_i (SAC), or the target actor's action with clipped smoothing noise
    /// and no entropy term (TD3).
    fn next_actions(&mut self, s2: &Tensor) -> (Tensor, Tensor) {
        let (k, rows) = (s2.size()[0], s2.size()[1]);
        let eps = self.noise(&[k, rows, self.act_dim as i64]);
        match (&self.target_actors, self.cfg.backbone) {
            (
                Some(target_actors),
                Backbone::Td3 {
                    target_noise,
                    target_noise_clip: clip,
                    ..
                },
            ) => {
                let (mu, _) = split_head(&target_actors.forward(s2));
                let smoothing = (eps * target_noise).clamp(-clip, clip);
                (
                    (mu.tanh() + smoothing).clamp(-1.0, 1.0),
                    Tensor::zeros([k, rows], (Kind::Float, self.device)),
                )
            }
            _ => {
                let (mu, log_std) = split_head(&self.actors.forward(s2));
                sample(&mu, &log_std, &eps)
            }
        }
    }

    /// Line 11 for `batch` (G groups of B rows) and line 10's `subsets`, as the method's
    /// [`TargetPlan`] says: `y = r + γ(1 − d) · outer_i [inner_m Q̄_m(s', ã'_i) − α_i log π_i(ã'_i|s')]`.
    /// Returns `[G, B]` (shared critics: group g's y for the critics trained on group g), or y per
    /// critic `[N, B]` (own critics: its owner's y).
    fn target(&mut self, batch: &Batch, subsets: &[i64]) -> Tensor {
        let (k, n) = (self.cfg.actors as i64, self.cfg.critics as i64);
        let (g, b) = (batch.next_obs.size()[0], batch.next_obs.size()[1]);
        // ã'_i for every actor i on every next state.
        let s2 = batch
            .next_obs
            .reshape([1, g * b, -1])
            .expand([k, g * b, -1], false);
        let (a2, logp2) = self.next_actions(&s2);
        let x2 = Tensor::cat(&[&s2, &a2], -1);
        // Heads: the rows of y before they reach the critics. Shared: one per group, every
        // actor's next actions through the group's subset; own: one per actor (G = 1), its next
        // actions through its critics.
        let own = matches!(self.target_plan, TargetPlan::Own { .. });
        let (critics, formation, aqe_drop) = match self.target_plan {
            TargetPlan::Shared {
                formation,
                aqe_drop,
                ..
            } => (subsets.to_vec(), formation, aqe_drop),
            TargetPlan::Own { drawn: true, .. } => (subsets.to_vec(), Formation::MaxMin, 0),
            TargetPlan::Own { drawn: false, .. } => ((0..n).collect(), Formation::MaxMin, 0),
        };
        let (heads, actors_per_head) = if own { (k, 1) } else { (g, k) };
        let m = critics.len() as i64 / heads;
        let x2 = if own {
            x2.view([k, 1, b, -1])
        } else {
            x2.view([k, g, b, -1])
                .permute([1, 0, 2, 3])
                .reshape([g, 1, k * b, -1])
        };
        let rows = actors_per_head * b;
        let x2 = x2
            .expand([heads, m, rows, -1], false)
            .reshape([heads * m, rows, -1]);
        let index = Tensor::from_slice(&critics).to_device(self.device);
        let q_next =
            self.target_critics
                .select(&index)
                .forward(&x2)
                .view([heads, m, actors_per_head, b]);
        let (logp2, alpha) = if own {
            (logp2.view([k, 1, b]), self.alpha().view([k, 1, 1]))
        } else {
            (
                logp2.view([k, g, b]).permute([1, 0, 2]),
                self.alpha().view([1, k, 1]),
            )
        };
        // REM's mixture: uniform weights, normalised, fresh for every group and update.
        let rem_weights = (formation == Formation::MaxRem).then(|| {
            let w: Vec<f32> = (0..heads * m)
                .map(|_| self.rng.gen_range(0.0f32..1.0))
                .collect();
            let w = Tensor::from_slice(&w)
                .view([heads, m])
                .to_device(self.device);
            self.record(|| Draw::Uniform(w.shallow_clone()));
            &w / w.sum_dim_intlist(1, true, Kind::Float)
        });
        let opts = InnerOptions {
            rem_weights: rem_weights.as_ref(),
            aqe_drop,
        };
        let y = critic_target(
            &batch.reward,
            &batch.terminated,
            &q_next,
            &logp2,
            &alpha,
            self.cfg.gamma,
            formation,
            &opts,
        );
        if own {
            y.index_select(0, &self.critic_owners())
        } else {
            y
        }
    }

    /// Every critic's values on `batch`'s (s, a) (one group of rows), `[N, rows]`, and its TD error
    /// against its target `y`, `mean_rows ½ (Q_j(s, a) − y_j)²`, `[N]`.
    fn td_errors(&self, batch: &Batch, y: &Tensor) -> (Tensor, Tensor) {
        let q = self
            .critics
            .forward(&self.critic_inputs(batch))
            .squeeze_dim(-1);
        let per_critic = half_mean_square(&q, y);
        (q, per_critic)
    }

    /// The critics' inputs (s, a) for `batch`'s rows (one group), `[N, rows, obs + act]`.
    fn critic_inputs(&self, batch: &Batch) -> Tensor {
        let (n, rows) = (self.cfg.critics as i64, batch.obs.size()[1]);
        Tensor::cat(&[&batch.obs, &batch.act], -1).expand([n, rows, -1], false)
    }

    /// Own critics (DPD, AVTD): which actor owns each critic (⌊j·K/N⌋), `[N]` indices.
    fn critic_owners(&self) -> Tensor {
        let (k, n) = (self.cfg.actors as i64, self.cfg.critics as i64);
        let owner: Vec<i64> = (0..n).map(|j| j * k / n).collect();
        Tensor::from_slice(&owner).to_device(self.device)
    }

    /// AVTD's selection: each variant's TD error on a batch of held-out validation transitions
    /// (its critics' mean of ½ (Q_j(s, a) − y_j)², y as in training), and the variant with the
    /// lowest acts from now on. Runs every [`SELECT_EVERY_ROUNDS`] rounds once the validation
    /// rows hold a mini-batch. Returns whether the acting variant changed.
    pub fn select_variant(&mut self) -> bool {
        let Some(avtd) = &mut self.avtd else {
            return false;
        };
        if avtd.validation.len() < self.cfg.batch_size
            || !self.actor_updates.is_multiple_of(SELECT_EVERY_ROUNDS)
        {
            return false;
        }
        let batch = avtd
            .validation
            .sample(1, 4 * self.cfg.batch_size, &mut self.rng);
        let subsets = self.draw_subsets(1);
        self.record(|| Draw::CriticBatch(batch.shallow_clone(), subsets.clone()));
        let td = tch::no_grad(|| {
            let y = self.target(&batch, &subsets);
            let (_, per_critic) = self.td_errors(&batch, &y);
            let per_variant =
                per_critic
                    .view([self.cfg.actors as i64, -1])
                    .mean_dim(1, false, Kind::Double);
            Vec::<f64>::try_from(per_variant.to_device(Device::Cpu)).expect("f64 errors")
        });
        let avtd = self.avtd.as_mut().expect("AVTD");
        let before = avtd.selected;
        avtd.selected = (0..td.len())
            .min_by(|&a, &b| td[a].total_cmp(&td[b]))
            .expect("at least one variant");
        avtd.validation_td = td;
        let v = avtd.selected;
        if v != before {
            // Debug level: with close variants the selection can change every few rounds.
            tracing::debug!(
                round = self.actor_updates,
                "AVTD: variant {v} ({:?}) acts now; validation TD errors {:?}",
                avtd.variants[v],
                avtd.validation_td
            );
        }
        v != before
    }

    /// Where transition `n` (1-based, in arrival order, so sync runs reproduce) is stored:
    /// AVTD's validation rows for every `validation_every`-th, else (`None`) the replay buffer.
    pub fn held_out(&mut self, n: u64) -> Option<&mut ReplayBuffer> {
        self.avtd
            .as_mut()
            .filter(|a| n.is_multiple_of(a.validation_every))
            .map(|a| &mut a.validation)
    }

    /// Lines 16–20, all K actors at once, each on its own mini-batch.
    pub fn update_actors(
        &mut self,
        replay: &mut ReplayBuffer,
        best: usize,
        stats: &mut RoundStats,
    ) {
        let k = self.cfg.actors as i64;
        let batch = replay.sample(self.cfg.actors, self.cfg.batch_size, &mut self.rng); // line 17
        self.record(|| Draw::ActorBatch(batch.shallow_clone()));
        let s = &batch.obs;
        let (mu, log_std) = split_head(&self.actors.forward(s));
        let (a, logp) = self.actions(&mu, &log_std);
        let q = self.judged_value(s, &a);
        let kl = self.distance_to_reference(s, &a, &mu, &log_std, best); // line 18
        let kd = self.on_device(&self.kd_weights(best)).view([k, 1]);
        let alpha = match self.cfg.backbone {
            Backbone::Td3 { .. } => Tensor::zeros([k, 1], (Kind::Float, self.device)),
            Backbone::Sac => self.alpha().view([k, 1]),
        };
        let rl = self.on_device(&self.objective.rl).view([k, 1]);
        // Line 19 (as a loss to minimise).
        let per_actor = (&rl * (&alpha * &logp - &q) + &kd * &kl).mean_dim(1, false, Kind::Float);
        per_actor.sum(Kind::Float).backward();
        self.actor_opt.step(&self.actors.params());
        self.after_actor_step(&logp);
        self.actor_updates += 1;
        stats.actor_loss = Vec::<f64>::try_from(per_actor.detach().to_kind(Kind::Double)).unwrap();
        stats.alpha = Vec::<f64>::try_from(self.alpha().to_kind(Kind::Double)).unwrap();
        stats.kl_to_best =
            Vec::<f64>::try_from(kl.detach().mean_dim(1, false, Kind::Double)).unwrap();
        stats.entropy =
            Vec::<f64>::try_from(-logp.detach().mean_dim(1, false, Kind::Double)).unwrap();
    }

    /// Each actor's action on its states and its log-prob, `[K, B, act]` and `[K, B]`: sampled
    /// from π_i (SAC), or the deterministic action with no entropy term (TD3).
    fn actions(&mut self, mu: &Tensor, log_std: &Tensor) -> (Tensor, Tensor) {
        let (k, b) = (mu.size()[0], mu.size()[1]);
        match self.cfg.backbone {
            Backbone::Td3 { .. } => (mu.tanh(), Tensor::zeros([k, b], (Kind::Float, self.device))),
            Backbone::Sac => {
                let eps = self.noise(&[k, b, self.act_dim as i64]);
                sample(mu, log_std, &eps)
            }
        }
    }

    /// Line 19's value of actor i's action `a` on its states `s`, `[K, B]`: the critics' mean
    /// `(1/N) Σ_j Q_j(s, ã_i(s))` (or, SAC's actor, min_j), over all N critics or (DPD, AVTD)
    /// only the N/K it owns, so each critic sees only its owner's states. The critics are fixed
    /// here, only the actor moves.
    fn judged_value(&self, s: &Tensor, a: &Tensor) -> Tensor {
        let (k, n, b) = (
            self.cfg.actors as i64,
            self.cfg.critics as i64,
            self.cfg.batch_size as i64,
        );
        let reduce = |q: &Tensor, dim: i64| match self.cfg.actor_q {
            ActorQ::Mean => q.mean_dim(dim, false, Kind::Float),
            ActorQ::Min => q.amin(dim, false),
        };
        if self.objective.own_critics {
            let x = Tensor::cat(&[s, a], -1).index_select(0, &self.critic_owners());
            reduce(&self.critics.forward_fixed(&x).view([k, n / k, b]), 1)
        } else {
            let x = Tensor::cat(&[s, a], -1)
                .reshape([1, k * b, -1])
                .expand([n, k * b, -1], false);
            reduce(&self.critics.forward_fixed(&x).view([n, k, b]), 0)
        }
    }

    /// Line 18: each actor's distance to its reference actor (the best, or DPD's peer), held
    /// fixed, on its own states, `[K, B]`. SAC: the KL of the two policies; TD3: the
    /// mean-squared distance of the two deterministic actions (SPEC, TD3 backbone: the mean over
    /// action dimensions).
    fn distance_to_reference(
        &self,
        s: &Tensor,
        a: &Tensor,
        mu: &Tensor,
        log_std: &Tensor,
        best: usize,
    ) -> Tensor {
        let k = self.cfg.actors as i64;
        let reference: Vec<i64> = (0..k)
            .map(|i| match self.objective.reference {
                Reference::Best => best as i64,
                Reference::Peer => (i + 1) % k,
            })
            .collect();
        let reference_head = self
            .actors
            .select(&Tensor::from_slice(&reference).to_device(self.device))
            .forward(s);
        let (mu_ref, log_std_ref) = split_head(&reference_head);
        match self.cfg.backbone {
            Backbone::Td3 { .. } => (a - mu_ref.tanh())
                .square()
                .mean_dim(-1, false, Kind::Float),
            Backbone::Sac => gaussian_kl(mu, log_std, &mu_ref, &log_std_ref),
        }
    }

    /// λ_KD for every actor that distils, 0 for the others (the best never distils toward
    /// itself; w/o KD: only `kd_actors`; AVTD: none).
    fn kd_weights(&self, best: usize) -> Vec<f32> {
        (0..self.cfg.actors)
            .map(|i| {
                let distils = match &self.objective.distils {
                    Distils::AllButBest(only) => {
                        i != best && only.as_ref().is_none_or(|l| l.contains(&i))
                    }
                    Distils::All => true,
                    Distils::None => false,
                };
                if distils {
                    self.cfg.kd_weight as f32
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// After the actors' step: TD3's target actors follow them (Polyak); SAC's temperatures
    /// minimise −log α_i · (log π_i + target entropy), detached from the actor, unless α is fixed.
    fn after_actor_step(&mut self, logp: &Tensor) {
        let k = self.cfg.actors as i64;
        if let Some(target_actors) = &mut self.target_actors {
            target_actors.polyak_toward(&self.actors, self.cfg.polyak);
        } else if self.cfg.fixed_alpha.is_none() {
            let target_entropy = self.cfg.target_entropy.unwrap_or(-(self.act_dim as f64));
            let alpha_loss = -(&self.log_alpha.view([k, 1]) * (logp.detach() + target_entropy))
                .mean_dim(1, false, Kind::Float)
                .sum(Kind::Float);
            alpha_loss.backward();
            self.alpha_opt.step(&[&self.log_alpha]);
        }
    }

    fn on_device(&self, v: &[f32]) -> Tensor {
        Tensor::from_slice(v).to_device(self.device)
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
        let eps = Tensor::from_slice(&v).view(shape).to_device(self.device);
        self.record(|| Draw::Normal(eps.shallow_clone()));
        eps
    }

    /// Appends a draw when recording is on (see [`Selkd::draws`]).
    fn record(&mut self, draw: impl FnOnce() -> Draw) {
        if let Some(draws) = &mut self.draws {
            draws.push(draw());
        }
    }

    /// Acting actor `i`'s weights in the flat layout workers use (AVTD: the selected variant's).
    pub fn actor_weights(&self, i: usize) -> Vec<f32> {
        let member = self.avtd.as_ref().map_or(i, |a| a.selected);
        self.actors.member_flat(member as i64)
    }

    /// AVTD's selection (the acting variant, each variant's validation TD error), for metrics.
    pub fn selection(&self) -> Option<(usize, &[f64])> {
        self.avtd
            .as_ref()
            .map(|a| (a.selected, a.validation_td.as_slice()))
    }
}

#[cfg(test)]
// The reference computations index like the formulas they check.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::config::Sharing;
    use crate::targets::Formation;
    use rand::Rng;

    /// SELKD with these settings (the rest as Algorithm 1).
    fn selkd_with(target: Formation, sharing: Sharing, distillation: Distillation) -> Method {
        Method::Selkd {
            target,
            aqe_drop: 1,
            sharing,
            distillation,
        }
    }

    fn small(k: usize, n: usize, m: usize) -> AlgoConfig {
        AlgoConfig {
            actors: k,
            critics: n,
            subset: m,
            utd: 2,
            batch_size: 8,
            hidden: vec![16, 16],
            ..AlgoConfig::default()
        }
    }

    fn filled_replay(obs: usize, act: usize, rows: usize) -> ReplayBuffer {
        let mut rng = Pcg64::seed_from_u64(5);
        let mut rb = ReplayBuffer::new(1000, obs, act, Device::Cpu);
        for i in 0..rows {
            let mut v =
                |n: usize| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect() };
            let (s, a, s2) = (v(obs), v(act), v(obs));
            rb.push(&s, &a, rng.gen_range(-2.0..2.0), &s2, i % 7 == 0);
        }
        rb
    }

    /// A plain one-network MLP forward on a single row, from member `i`'s stacked weights.
    fn mlp(ens: &Ensemble, i: i64, x: &[f32]) -> Vec<f64> {
        let mut h: Vec<f64> = x.iter().map(|&v| v as f64).collect();
        let last = ens.layers.len() - 1;
        for (l, layer) in ens.layers.iter().enumerate() {
            let w = layer.weight.get(i);
            let bias = layer.bias.get(i);
            let (n_in, n_out) = (w.size()[0], w.size()[1]);
            let mut out = vec![0.0; n_out as usize];
            for o in 0..n_out {
                let mut acc = bias.double_value(&[0, o]);
                for k in 0..n_in {
                    acc += h[k as usize] * w.double_value(&[k, o]);
                }
                out[o as usize] = if l < last { acc.max(0.0) } else { acc };
            }
            h = out;
        }
        h
    }

    /// Q ≡ 0: the critics' last layer zeroed, so only a KD term can move an actor (with α = 0).
    fn silence_critics(s: &Selkd) {
        tch::no_grad(|| {
            let last = s.critics.layers.last().unwrap();
            let _ = last.weight.shallow_clone().zero_();
            let _ = last.bias.shallow_clone().zero_();
        });
    }

    fn row(t: &Tensor, g: i64, b: i64) -> Vec<f32> {
        Vec::<f32>::try_from(t.get(g).get(b).contiguous()).unwrap()
    }

    /// The in-target max-min update, by hand: `y = r + γ(1−d) max_i (min_{j∈𝓜} Q̄_j(s', ã'_i) − α_i log π_i)`.
    /// K = 1 is REDQ (M = 2 of N) and Maxmin Q-learning (M = N); `per-critic` is Algorithm 1's
    /// literal form. The target and each
    /// critic's loss are recomputed here row by row with plain loops over separate networks. One
    /// update then moves each critic by Adam's first step (at most lr) and the targets by Polyak.
    /// With the TD3 backbone the same check runs on `ã'_i = clip(tanh(μ̄_i(s')) + clip(0.2ε, ±0.5), ±1)`
    /// from the target actors, without the entropy term.
    /// With `paired` (the DPD baseline) critic j's target is its owner actor's min over the owner's
    /// critics, with no max over actors.
    fn check_critic_update(k: usize, sharing: Sharing, m: usize, backbone: Backbone, paired: bool) {
        let (obs, act) = (3, 2);
        let n = if paired { 2 * k } else { 5 };
        let cfg = AlgoConfig {
            method: if paired {
                Method::Dpd { without_rl: false }
            } else {
                selkd_with(Formation::MaxMin, sharing, Distillation::default())
            },
            backbone,
            ..small(k, n, m)
        };
        let b_size = cfg.batch_size as i64;
        let mut s = Selkd::new(&cfg, obs, act, Device::Cpu, 3);
        let mut rb = filled_replay(obs, act, 200);
        let td3 = backbone.is_td3();
        if td3 {
            // Move the actors once so that the target actors differ from them.
            s.update_actors(&mut rb, 0, &mut RoundStats::default());
        }
        let groups = if sharing == Sharing::PerCritic { n } else { 1 };
        let batch = rb.sample(groups, cfg.batch_size, &mut Pcg64::seed_from_u64(9));
        let subsets: Vec<Vec<i64>> = (0..groups)
            .map(|g| (0..m).map(|i| ((g + 3 * i + 4) % n) as i64).collect())
            .collect();
        // The noise update_critics_on will draw: the learner's next K·groups·B·A normals.
        let mut peek = s.rng.clone();
        let eps: Vec<f32> = (0..k * groups * cfg.batch_size * act)
            .map(|_| StandardNormal.sample(&mut peek))
            .collect();
        let before: Vec<Vec<f32>> = (0..n as i64).map(|j| s.critics.member_flat(j)).collect();
        let (critics_before, target_before) = (s.critics.copy(), s.target_critics.copy());
        let alpha = 1.0; // log α starts at 0
                         // y[g][b][j]: critic j's target on row b of group g.
        let mut y = vec![vec![vec![0.0; n]; cfg.batch_size]; groups];
        for g in 0..groups {
            for b in 0..b_size {
                let s2 = row(&batch.next_obs, g as i64, b);
                let (r, d) = (
                    batch.reward.double_value(&[g as i64, b]),
                    batch.terminated.double_value(&[g as i64, b]),
                );
                // Every actor's next action, its log-prob, and every target critic's value of it.
                let mut soft: Vec<(Vec<f64>, f64)> = Vec::new();
                for i in 0..k {
                    let policy = if td3 {
                        s.target_actors.as_ref().unwrap()
                    } else {
                        &s.actors
                    };
                    let head = mlp(policy, i as i64, &s2);
                    let (mut a2, mut logp) = (Vec::new(), 0.0);
                    for d in 0..act {
                        let (mu, ls) = (head[d], head[act + d].clamp(-20.0, 2.0));
                        let e =
                            eps[((i * groups + g) * cfg.batch_size + b as usize) * act + d] as f64;
                        if td3 {
                            a2.push(
                                (mu.tanh() + (0.2 * e).clamp(-0.5, 0.5)).clamp(-1.0, 1.0) as f32
                            );
                            continue;
                        }
                        let u = mu + ls.exp() * e;
                        logp += -0.5 * e * e
                            - ls
                            - 0.5 * (2.0 * std::f64::consts::PI).ln()
                            - (1.0 - u.tanh().powi(2) + 1e-6).ln();
                        a2.push(u.tanh() as f32);
                    }
                    let x2: Vec<f32> = s2.iter().chain(&a2).copied().collect();
                    let q: Vec<f64> = (0..n as i64)
                        .map(|j| mlp(&target_before, j, &x2)[0])
                        .collect();
                    soft.push((q, if td3 { 0.0 } else { alpha * logp }));
                }
                let value = |i: usize, members: &[i64]| {
                    members
                        .iter()
                        .map(|&j| soft[i].0[j as usize])
                        .fold(f64::INFINITY, f64::min)
                        - soft[i].1
                };
                for j in 0..n {
                    let v = if paired {
                        let owner = j * k / n;
                        let own: Vec<i64> = (0..n as i64)
                            .filter(|&c| c as usize * k / n == owner)
                            .collect();
                        value(owner, &own)
                    } else {
                        // max over actors of the soft value under the subset's min.
                        (0..k)
                            .map(|i| value(i, &subsets[g]))
                            .fold(f64::NEG_INFINITY, f64::max)
                    };
                    y[g][b as usize][j] = r + 0.99 * (1.0 - d) * v;
                }
            }
        }
        let flat_subsets: Vec<i64> = subsets.concat();
        let (loss, _) = s.update_critics_on(&batch, &flat_subsets);
        // The reported loss: mean over critics of mean_B ½(Q_j(s, a) − y)², critic j on its own group.
        let mut want = 0.0;
        for j in 0..n {
            let g = if groups == 1 { 0 } else { j };
            for b in 0..b_size {
                let x: Vec<f32> = row(&batch.obs, g as i64, b)
                    .into_iter()
                    .chain(row(&batch.act, g as i64, b))
                    .collect();
                want += 0.5 * (mlp(&critics_before, j as i64, &x)[0] - y[g][b as usize][j]).powi(2);
            }
        }
        want /= (n * cfg.batch_size) as f64;
        assert!(
            (loss - want).abs() < 1e-4 * want.max(1.0),
            "K={k} {sharing:?} M={m}: loss {loss} vs hand-computed {want}"
        );
        for j in 0..n as i64 {
            let after = s.critics.member_flat(j);
            let moved = after
                .iter()
                .zip(&before[j as usize])
                .filter(|(a, b)| (*a - *b).abs() > 0.5 * cfg.lr as f32)
                .count();
            assert!(after
                .iter()
                .zip(&before[j as usize])
                .all(|(a, b)| (a - b).abs() <= cfg.lr as f32 * 1.001));
            assert!(
                moved > after.len() / 5,
                "critic {j}: weights with a gradient take a full first Adam step"
            );
            // Line 13: Polyak after the update.
            let (t_before, t_after) = (
                target_before.member_flat(j),
                s.target_critics.member_flat(j),
            );
            for q in 0..t_before.len() {
                assert!((t_after[q] - (0.995 * t_before[q] + 0.005 * after[q])).abs() < 1e-6);
            }
        }
        // The update's direction: critic j's gradient is that of its own hand-computed loss
        // mean_B ½(Q_j(s, a) − y)² (central differences in f64, y held fixed), and Adam's first
        // step moves each weight by −lr·g/(|g| + ε) against it.
        let c_dims = [vec![obs + act], cfg.hidden.clone(), vec![1]].concat();
        for j in 0..n {
            let g = if groups == 1 { 0 } else { j };
            let xs: Vec<Vec<f64>> = (0..b_size)
                .map(|b| {
                    let x = row(&batch.obs, g as i64, b).into_iter();
                    f64s(x.chain(row(&batch.act, g as i64, b)).collect())
                })
                .collect();
            let critic_loss = |theta: &[f64]| {
                let sq = (0..xs.len())
                    .map(|b| (flat_mlp(&c_dims, theta, &xs[b])[0] - y[g][b][j]).powi(2));
                0.5 * sq.sum::<f64>() / xs.len() as f64
            };
            let theta = f64s(before[j].clone());
            let learner = first_step_gradient(&s.critic_opt, j as i64);
            let after = s.critics.member_flat(j as i64);
            for p in 0..theta.len() {
                let want = central_difference(&critic_loss, &theta, p);
                assert!(
                    (learner[p] - want).abs() <= 1e-3 * want.abs() + 1e-6,
                    "critic {j} parameter {p}: gradient {} vs hand-computed {want}",
                    learner[p]
                );
                let step = after[p] as f64 - theta[p];
                let adam = -cfg.lr * want / (want.abs() + 1e-8);
                if want.abs() > 1e-5 {
                    assert!(
                        (step - adam).abs() < 0.01 * cfg.lr,
                        "critic {j} parameter {p}: moved {step} with gradient {want}"
                    );
                }
            }
        }
    }

    /// A parameter's gradient as the learner computed it, from Adam's first moment after its first
    /// step (m₁ = (1 − β₁)·g), for member `i` in `member_flat`'s layout.
    fn first_step_gradient(opt: &Adam, i: i64) -> Vec<f64> {
        assert_eq!(opt.step, 1);
        let parts: Vec<Tensor> = opt.exp_avg.iter().map(|m| m.get(i).reshape([-1])).collect();
        let m = Vec::<f32>::try_from(Tensor::cat(&parts, 0)).unwrap();
        m.iter().map(|&v| v as f64 / (1.0 - opt.beta1)).collect()
    }

    /// ∂f/∂θ_p by central differences (f64; h small against the weights, large against round-off).
    fn central_difference(f: &impl Fn(&[f64]) -> f64, theta: &[f64], p: usize) -> f64 {
        let h = 1e-6;
        let mut t = theta.to_vec();
        t[p] = theta[p] + h;
        let up = f(&t);
        t[p] = theta[p] - h;
        (up - f(&t)) / (2.0 * h)
    }

    fn f64s(v: Vec<f32>) -> Vec<f64> {
        v.into_iter().map(f64::from).collect()
    }

    /// A plain MLP forward (ReLU between layers, linear output) from one member's flat f64
    /// parameters in `member_flat`'s layout: per layer the weight `[in][out]` row-major, then the bias.
    fn flat_mlp(dims: &[usize], theta: &[f64], x: &[f64]) -> Vec<f64> {
        let mut h = x.to_vec();
        let mut at = 0;
        for (l, w) in dims.windows(2).enumerate() {
            let (n_in, n_out) = (w[0], w[1]);
            let (weight, bias) = (&theta[at..at + n_in * n_out], &theta[at + n_in * n_out..]);
            at += n_in * n_out + n_out;
            h = (0..n_out)
                .map(|o| {
                    let acc =
                        bias[o] + (0..n_in).map(|k| h[k] * weight[k * n_out + o]).sum::<f64>();
                    if l + 2 < dims.len() {
                        acc.max(0.0)
                    } else {
                        acc
                    }
                })
                .collect();
        }
        assert_eq!(at, theta.len());
        h
    }

    /// Rows of a `[G, B, D]` tensor, group `g`, as f64.
    fn rows_of(t: &Tensor, g: i64) -> Vec<Vec<f64>> {
        (0..t.size()[1]).map(|b| f64s(row(t, g, b))).collect()
    }

    /// The learner's draws of one `update_actors`: actor i's states `[K][B][obs]` and, for SAC, its
    /// noise `[K][B][A]`.
    #[allow(clippy::type_complexity)]
    fn actor_draws(draws: Vec<Draw>, k: usize) -> (Vec<Vec<Vec<f64>>>, Option<Vec<Vec<Vec<f64>>>>) {
        let mut it = draws.into_iter();
        let Some(Draw::ActorBatch(batch)) = it.next() else {
            panic!("the actor update draws its mini-batch first")
        };
        let states = (0..k as i64).map(|i| rows_of(&batch.obs, i)).collect();
        let eps = it.next().map(|d| match d {
            Draw::Normal(e) => (0..k as i64).map(|i| rows_of(&e, i)).collect(),
            _ => panic!("then its noise"),
        });
        assert!(it.next().is_none());
        (states, eps)
    }

    /// One actor's sampled action and log π by the textbook formulas (SPEC "Objects"):
    /// u = μ + σε, a = tanh(u), log π = Σ_d [log N(u; μ, σ) − log(1 − tanh²u)], written with
    /// log(1 − tanh²u) = −2 log cosh u (exact, no 1e-6).
    fn hand_sample(head: &[f64], eps: &[f64]) -> (Vec<f64>, f64) {
        let act = eps.len();
        let mut logp = 0.0;
        let a = (0..act)
            .map(|d| {
                let (mu, ls) = (head[d], head[act + d].clamp(-20.0, 2.0));
                let u = mu + ls.exp() * eps[d];
                let z = (u - mu) / ls.exp();
                logp += -0.5 * z * z - ls - 0.5 * (2.0 * std::f64::consts::PI).ln()
                    + 2.0 * u.cosh().ln();
                u.tanh()
            })
            .collect();
        (a, logp)
    }

    /// KL(N(μ, σ) ‖ N(μ_b, σ_b)) of two actor heads, summed over action dimensions (SPEC).
    fn hand_kl(head: &[f64], best: &[f64]) -> f64 {
        let act = head.len() / 2;
        (0..act)
            .map(|d| {
                let (mu, ls) = (head[d], head[act + d].clamp(-20.0, 2.0));
                let (mu_b, ls_b) = (best[d], best[act + d].clamp(-20.0, 2.0));
                let (var, var_b) = ((2.0 * ls).exp(), (2.0 * ls_b).exp());
                ls_b - ls + (var + (mu - mu_b).powi(2)) / (2.0 * var_b) - 0.5
            })
            .sum()
    }

    /// The actor objective (SPEC eq. 7–9) for one actor, by hand, value and gradient: actor i's
    /// loss mean_s [α_i log π_i − (1/N) Σ_j Q_j(s, ã_i) + λ_KD KL(π_i ‖ π_best)] (TD3: no entropy,
    /// a = tanh μ, KD the mean over dimensions of (a − a_best)²; w/o RL: actors ≠ 0 keep only the
    /// KD term; w/o KD: only `kd_actors` have it; the best never does) is recomputed in f64 from
    /// the drawn states and noise; the learner's reported loss must equal it and the learner's
    /// gradient (Adam's first moment) must equal its central differences.
    fn check_actor_update(backbone: Backbone, without_rl: bool, kd_actors: Option<Vec<usize>>) {
        let (k, n, obs, act, best, lambda) = (3, 3, 3, 2, 1, 0.7);
        let cfg = AlgoConfig {
            backbone,
            method: selkd_with(
                Formation::MaxMin,
                Sharing::PerUpdate,
                Distillation {
                    kd_actors: kd_actors.clone(),
                    without_rl,
                },
            ),
            kd_weight: lambda,
            ..small(k, n, 2)
        };
        let td3 = backbone.is_td3();
        let mut s = Selkd::new(&cfg, obs, act, Device::Cpu, 21);
        let mut rb = filled_replay(obs, act, 100);
        // Some temperatures away from 1, so that α_i visibly scales the entropy term.
        tch::no_grad(|| {
            s.log_alpha
                .shallow_clone()
                .copy_(&Tensor::from_slice(&[-0.5f32, 0.3, 0.0]));
        });
        let alpha = f64s(Vec::<f32>::try_from(s.alpha()).unwrap());
        let actors: Vec<Vec<f64>> = (0..k).map(|i| f64s(s.actor_weights(i))).collect();
        let critics: Vec<Vec<f64>> = (0..n as i64)
            .map(|j| f64s(s.critics.member_flat(j)))
            .collect();
        s.draws = Some(Vec::new());
        let mut stats = RoundStats::default();
        s.update_actors(&mut rb, best, &mut stats);
        let (states, eps) = actor_draws(s.draws.take().unwrap(), k);
        assert_eq!(eps.is_none(), td3, "TD3's actions are deterministic");
        let a_dims = [vec![obs], cfg.hidden.clone(), vec![2 * act]].concat();
        let c_dims = [vec![obs + act], cfg.hidden.clone(), vec![1]].concat();
        for i in 0..k {
            let rl = !without_rl || i == 0;
            let distils = i != best && kd_actors.as_ref().is_none_or(|l| l.contains(&i));
            let loss = |theta: &[f64]| {
                let per_state = (0..cfg.batch_size).map(|b| {
                    let st = &states[i][b];
                    let head = flat_mlp(&a_dims, theta, st);
                    let best_head = flat_mlp(&a_dims, &actors[best], st);
                    let (a, logp, kd) = match &eps {
                        None => {
                            let a: Vec<f64> = head[..act].iter().map(|m| m.tanh()).collect();
                            let d2: f64 =
                                (0..act).map(|d| (a[d] - best_head[d].tanh()).powi(2)).sum();
                            (a, 0.0, d2 / act as f64)
                        }
                        Some(eps) => {
                            let (a, logp) = hand_sample(&head, &eps[i][b]);
                            (a, logp, hand_kl(&head, &best_head))
                        }
                    };
                    let x: Vec<f64> = st.iter().copied().chain(a).collect();
                    let q = critics
                        .iter()
                        .map(|c| flat_mlp(&c_dims, c, &x)[0])
                        .sum::<f64>();
                    let mut l = 0.0;
                    if rl {
                        l += alpha[i] * logp - q / n as f64;
                    }
                    if distils {
                        l += lambda * kd;
                    }
                    l
                });
                per_state.sum::<f64>() / cfg.batch_size as f64
            };
            let want = loss(&actors[i]);
            assert!(
                (stats.actor_loss[i] - want).abs() < 1e-5 * want.abs().max(1.0),
                "{backbone:?} w/o RL {without_rl} actor {i}: loss {} vs hand-computed {want}",
                stats.actor_loss[i]
            );
            let learner = first_step_gradient(&s.actor_opt, i as i64);
            let mut largest = 0.0f64;
            for p in 0..actors[i].len() {
                let want = central_difference(&loss, &actors[i], p);
                largest = largest.max(want.abs());
                assert!(
                    (learner[p] - want).abs() <= 1e-3 * want.abs() + 1e-6,
                    "{backbone:?} w/o RL {without_rl} actor {i} parameter {p}: gradient {} vs hand-computed {want}",
                    learner[p]
                );
            }
            // An actor with a loss term has a gradient; one without has none (and stays put).
            assert_eq!(
                largest > 1e-3,
                rl || distils,
                "actor {i}: largest gradient {largest}"
            );
        }
    }

    #[test]
    fn sac_actor_loss_and_gradient_match_a_hand_computation() {
        check_actor_update(Backbone::Sac, false, None);
    }

    #[test]
    fn td3_actor_loss_and_gradient_match_a_hand_computation() {
        check_actor_update(Backbone::TD3, false, None);
    }

    /// w/o RL with λ_KD > 0: actors 1 and 2 learn only by distilling toward the best (actor 1 is
    /// the best, so it has no loss at all); actor 0 keeps RL and KD.
    #[test]
    fn without_rl_the_other_actors_only_distil() {
        check_actor_update(Backbone::Sac, true, None);
        check_actor_update(Backbone::TD3, true, None);
    }

    #[test]
    fn without_kd_only_the_listed_actors_have_the_kd_term_in_their_gradient() {
        check_actor_update(Backbone::Sac, false, Some(vec![2]));
    }

    /// The temperature (SPEC: minimise −log α_i · (log π_i + target entropy), log π detached):
    /// its gradient −mean_s(log π_i + H) by hand from the drawn noise, Adam's first step against
    /// it, and what that means: α falls while the policy's entropy is above the target and rises
    /// while it is below. H defaults to −|A|.
    fn check_temperature(target_entropy: Option<f64>, alpha_rises: bool) {
        let (k, obs, act) = (3, 3, 2);
        let cfg = AlgoConfig {
            target_entropy,
            alpha_lr: 0.01,
            ..small(k, 2, 2)
        };
        let mut s = Selkd::new(&cfg, obs, act, Device::Cpu, 23);
        let mut rb = filled_replay(obs, act, 100);
        let actors: Vec<Vec<f64>> = (0..k).map(|i| f64s(s.actor_weights(i))).collect();
        s.draws = Some(Vec::new());
        let mut stats = RoundStats::default();
        s.update_actors(&mut rb, 0, &mut stats);
        let (states, eps) = actor_draws(s.draws.take().unwrap(), k);
        let eps = eps.unwrap();
        let h = target_entropy.unwrap_or(-(act as f64));
        let a_dims = [vec![obs], cfg.hidden.clone(), vec![2 * act]].concat();
        let log_alpha = Vec::<f32>::try_from(&s.log_alpha.detach()).unwrap();
        let moment = Vec::<f32>::try_from(&s.alpha_opt.exp_avg[0]).unwrap();
        for i in 0..k {
            let logp: Vec<f64> = (0..cfg.batch_size)
                .map(|b| hand_sample(&flat_mlp(&a_dims, &actors[i], &states[i][b]), &eps[i][b]).1)
                .collect();
            let mean_logp = logp.iter().sum::<f64>() / logp.len() as f64;
            assert!((stats.entropy[i] + mean_logp).abs() < 1e-4 * mean_logp.abs().max(1.0));
            let grad = -(mean_logp + h);
            assert!(
                (moment[i] as f64 / 0.1 - grad).abs() < 1e-4 * grad.abs().max(1.0),
                "actor {i}: α gradient {} vs hand-computed {grad}",
                moment[i] as f64 / 0.1
            );
            let want = -0.01 * grad / (grad.abs() + 1e-8);
            assert!(
                (log_alpha[i] as f64 - want).abs() < 1e-6,
                "actor {i}: log α {} vs {want}",
                log_alpha[i]
            );
            assert_eq!(
                log_alpha[i] > 0.0,
                alpha_rises,
                "entropy {} vs target {h}",
                -mean_logp
            );
            assert!((stats.alpha[i] - want.exp()).abs() < 1e-6);
        }
    }

    #[test]
    fn temperature_falls_while_entropy_is_above_the_default_target() {
        // Untrained actors (σ ≈ 1) have entropy far above −|A| = −2.
        check_temperature(None, false);
    }

    #[test]
    fn temperature_rises_while_entropy_is_below_the_target() {
        check_temperature(Some(10.0), true);
    }

    /// Lines 9–10: each subset is M distinct critics drawn uniformly, so over many updates every
    /// critic serves equally often, and (per-critic) each critic's group gets its own subset.
    #[test]
    fn critic_subsets_are_uniform_draws_without_replacement() {
        for sharing in [Sharing::PerUpdate, Sharing::PerCritic] {
            let (n, m, updates) = (5, 2, 300);
            let cfg = AlgoConfig {
                method: selkd_with(Formation::MaxMin, sharing, Distillation::default()),
                hidden: vec![4],
                ..small(1, n, m)
            };
            let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 24);
            let mut rb = filled_replay(3, 2, 100);
            s.draws = Some(Vec::new());
            for _ in 0..updates {
                s.update_critics(&mut rb);
            }
            let mut count = vec![0usize; n];
            let mut pairs = std::collections::BTreeSet::new();
            let mut subsets = 0;
            for d in s.draws.take().unwrap() {
                if let Draw::CriticBatch(_, flat) = d {
                    for sub in flat.chunks(m) {
                        assert_ne!(sub[0], sub[1], "{sharing:?}: drawn without replacement");
                        pairs.insert((sub[0].min(sub[1]), sub[0].max(sub[1])));
                        sub.iter().for_each(|&j| count[j as usize] += 1);
                        subsets += 1;
                    }
                }
            }
            let groups = if sharing == Sharing::PerCritic { n } else { 1 };
            assert_eq!(subsets, updates * groups);
            let expected = (subsets * m) as f64 / n as f64;
            for (j, &c) in count.iter().enumerate() {
                assert!(
                    (c as f64 - expected).abs() < 0.25 * expected,
                    "{sharing:?}: critic {j} in {c} subsets, expected about {expected}"
                );
            }
            assert_eq!(
                pairs.len(),
                n * (n - 1) / 2,
                "{sharing:?}: every pair occurs"
            );
        }
    }

    #[test]
    fn one_actor_is_redq() {
        check_critic_update(1, Sharing::PerUpdate, 2, Backbone::Sac, false);
    }

    #[test]
    fn one_actor_with_the_full_subset_is_maxmin() {
        check_critic_update(1, Sharing::PerUpdate, 5, Backbone::Sac, false);
    }

    #[test]
    fn per_critic_sharing_gives_each_critic_its_own_batch_and_subset() {
        check_critic_update(1, Sharing::PerCritic, 2, Backbone::Sac, false);
    }

    #[test]
    fn several_actors_take_the_max_over_actors_of_the_subset_min() {
        check_critic_update(3, Sharing::PerUpdate, 2, Backbone::Sac, false);
        check_critic_update(2, Sharing::PerCritic, 3, Backbone::Sac, false);
    }

    #[test]
    fn paired_critics_are_dpds_own_critic_targets() {
        check_critic_update(2, Sharing::PerUpdate, 2, Backbone::Sac, true);
        check_critic_update(3, Sharing::PerUpdate, 2, Backbone::TD3, true);
    }

    #[test]
    fn td3_backbone_targets_use_smoothed_target_actors_and_no_entropy() {
        check_critic_update(3, Sharing::PerUpdate, 2, Backbone::TD3, false);
        check_critic_update(2, Sharing::PerCritic, 2, Backbone::TD3, false);
    }

    /// Both sharing modes and every formation run, and per-critic draws N batches per update.
    #[test]
    fn every_mode_trains_and_stays_finite() {
        for sharing in [Sharing::PerUpdate, Sharing::PerCritic] {
            for target in [
                Formation::MaxMin,
                Formation::MinMin,
                Formation::MinMax,
                Formation::MaxMax,
            ] {
                let cfg = AlgoConfig {
                    method: selkd_with(target, sharing, Distillation::default()),
                    ..small(3, 4, 2)
                };
                let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 1);
                let mut rb = filled_replay(3, 2, 100);
                let stats = s.train_round(&mut rb, 1);
                assert!(
                    stats.critic_loss.is_finite() && stats.actor_loss.iter().all(|v| v.is_finite())
                );
                assert_eq!(stats.kl_to_best.len(), 3);
                assert_eq!((s.critic_updates, s.actor_updates), (2, 1));
            }
        }
    }

    #[test]
    fn actors_are_updated_u_times_per_round() {
        for (g, u) in [(3, 1), (3, 2), (3, 3)] {
            let cfg = AlgoConfig {
                utd: g,
                actor_updates_per_round: u,
                ..small(2, 3, 2)
            };
            let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 1);
            let mut rb = filled_replay(3, 2, 100);
            s.train_round(&mut rb, 0);
            s.train_round(&mut rb, 1);
            assert_eq!(
                (s.critic_updates, s.actor_updates),
                (2 * g as u64, 2 * u as u64)
            );
            assert_eq!(s.actor_opt.step, 2 * u as i64);
        }
    }

    /// Line 18 in isolation: with the critics' signal and the entropy term switched off (Q ≡ 0,
    /// α = 0), only the KD term moves the actors. The best actor then stays put and every other
    /// actor's KL to it falls toward 0.
    #[test]
    fn distillation_pulls_actors_toward_the_best() {
        check_distillation(Backbone::Sac);
    }

    /// TD3 backbone: KD is the mean-squared distance to the best actor's deterministic action.
    #[test]
    fn td3_distillation_pulls_actions_toward_the_best() {
        check_distillation(Backbone::TD3);
    }

    fn check_distillation(backbone: Backbone) {
        let cfg = AlgoConfig {
            backbone,
            kd_weight: 1.0,
            fixed_alpha: Some(0.0),
            lr: 1e-2,
            ..small(3, 2, 2)
        };
        let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 2);
        silence_critics(&s);
        let mut rb = filled_replay(3, 2, 100);
        let best_before = s.actor_weights(2);
        let mut stats = RoundStats::default();
        s.update_actors(&mut rb, 2, &mut stats);
        let first = stats.kl_to_best.clone();
        for _ in 0..100 {
            s.update_actors(&mut rb, 2, &mut stats);
        }
        assert_eq!(
            s.actor_weights(2),
            best_before,
            "the best actor has no KD term and (here) no other loss"
        );
        assert!(stats.kl_to_best[2].abs() < 1e-6);
        for i in 0..2 {
            assert!(
                stats.kl_to_best[i] < 0.1 * first[i],
                "{backbone:?} actor {i}: distance to the best {} → {}",
                first[i],
                stats.kl_to_best[i]
            );
        }
    }

    /// The actor objective's reduction over critics, by hand: every replay row holds the same
    /// state, so whatever the batch draws, actor i's loss (TD3: deterministic action, no entropy;
    /// λ_KD = 0) is −reduce_j Q_j(s0, tanh(μ_i(s0))), recomputed here with separate plain MLPs.
    /// `mean` is SELKD's eq. 7 and REDQ's; `min` is SAC's clipped double Q. With paired critics
    /// (DPD) the reduction runs over the actor's own critics only.
    #[test]
    fn actor_loss_reduces_the_critics_by_mean_or_min() {
        for (paired, actor_q) in [
            (false, ActorQ::Mean),
            (false, ActorQ::Min),
            (true, ActorQ::Mean),
            (true, ActorQ::Min),
        ] {
            let (k, n) = (2usize, 4usize);
            let cfg = AlgoConfig {
                backbone: Backbone::TD3,
                kd_weight: 0.0,
                method: if paired {
                    Method::Dpd { without_rl: false }
                } else {
                    Method::default()
                },
                actor_q,
                ..small(k, n, 2)
            };
            let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 8);
            let s0 = [0.4f32, -0.7, 0.2];
            let mut rb = ReplayBuffer::new(100, 3, 2, Device::Cpu);
            for _ in 0..20 {
                rb.push(&s0, &[0.1, 0.2], 0.5, &s0, false);
            }
            let critics_before = s.critics.copy();
            let actors_before = s.actors.copy();
            let mut stats = RoundStats::default();
            s.update_actors(&mut rb, 0, &mut stats);
            for i in 0..k {
                let head = mlp(&actors_before, i as i64, &s0);
                let x: Vec<f32> = s0
                    .iter()
                    .copied()
                    .chain((0..2).map(|d| head[d].tanh() as f32))
                    .collect();
                let judges: Vec<usize> = if paired {
                    (0..n).filter(|j| j * k / n == i).collect()
                } else {
                    (0..n).collect()
                };
                let qs: Vec<f64> = judges
                    .iter()
                    .map(|&j| mlp(&critics_before, j as i64, &x)[0])
                    .collect();
                let want = -match actor_q {
                    ActorQ::Mean => qs.iter().sum::<f64>() / qs.len() as f64,
                    ActorQ::Min => qs.iter().copied().fold(f64::INFINITY, f64::min),
                };
                assert!(
                    (stats.actor_loss[i] - want).abs() < 1e-5 * want.abs().max(1.0),
                    "paired {paired} {actor_q:?} actor {i}: loss {} vs hand-computed {want}",
                    stats.actor_loss[i]
                );
            }
        }
    }

    /// Ablation "w/o KD" (`kd_actors = [0]`): with Q ≡ 0 and α = 0 only a KD term can move an
    /// actor, so exactly actor 0 moves (toward the best, actor 2) and actor 1, which has no KD
    /// term, stays put, as does the best actor.
    #[test]
    fn without_kd_only_the_listed_actor_distils() {
        let cfg = AlgoConfig {
            method: selkd_with(
                Formation::MaxMin,
                Sharing::PerUpdate,
                Distillation {
                    kd_actors: Some(vec![0]),
                    without_rl: false,
                },
            ),
            kd_weight: 1.0,
            fixed_alpha: Some(0.0),
            lr: 1e-2,
            ..small(3, 2, 2)
        };
        let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 2);
        silence_critics(&s);
        let mut rb = filled_replay(3, 2, 100);
        let before: Vec<Vec<f32>> = (0..3).map(|i| s.actor_weights(i)).collect();
        let mut stats = RoundStats::default();
        s.update_actors(&mut rb, 2, &mut stats);
        let first = stats.kl_to_best.clone();
        for _ in 0..50 {
            s.update_actors(&mut rb, 2, &mut stats);
        }
        assert_ne!(s.actor_weights(0), before[0], "actor 0 distils");
        assert!(stats.kl_to_best[0] < 0.2 * first[0]);
        assert_eq!(s.actor_weights(1), before[1], "actor 1 has no KD term");
        assert_eq!(
            s.actor_weights(2),
            before[2],
            "the best actor has no KD term"
        );
    }

    /// DPD: with paired critics every actor distils toward its peer, so two actors with nothing
    /// else to learn (Q ≡ 0, α = 0) both move and meet.
    #[test]
    fn paired_actors_distil_toward_each_other() {
        let cfg = AlgoConfig {
            method: Method::Dpd { without_rl: false },
            fixed_alpha: Some(0.0),
            lr: 1e-2,
            ..small(2, 4, 2)
        };
        let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 2);
        silence_critics(&s);
        let mut rb = filled_replay(3, 2, 100);
        let before = [s.actor_weights(0), s.actor_weights(1)];
        let mut stats = RoundStats::default();
        s.update_actors(&mut rb, 0, &mut stats);
        let first = stats.kl_to_best.clone();
        for _ in 0..100 {
            s.update_actors(&mut rb, 0, &mut stats);
        }
        for i in 0..2 {
            assert_ne!(s.actor_weights(i), before[i], "actor {i} distils too");
            assert!(
                stats.kl_to_best[i] < 0.1 * first[i],
                "actor {i}: KL to its peer {} → {}",
                first[i],
                stats.kl_to_best[i]
            );
        }
    }

    /// DNS: every update trains exactly k critics (their weights and Adam moments move) and
    /// leaves the other N − k bit for bit as they were, moments included; each critic's Adam
    /// counts only its own steps; over many updates every critic gets its turn.
    #[test]
    fn dns_trains_only_the_drawn_critics() {
        let (n, k) = (5usize, 2usize);
        let cfg = AlgoConfig {
            method: Method::Dns {
                target: Formation::MaxMin,
                aqe_drop: 1,
                trained_critics: k,
                distillation: Distillation::default(),
            },
            ..small(1, n, 2)
        };
        let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 4);
        let mut rb = filled_replay(3, 2, 100);
        let moments = |s: &Selkd, j: i64| -> Vec<f32> {
            s.critic_opt
                .exp_avg
                .iter()
                .chain(&s.critic_opt.exp_avg_sq)
                .flat_map(|m| Vec::<f32>::try_from(&m.get(j).reshape([-1])).unwrap())
                .collect()
        };
        let mut counts = vec![0i64; n];
        for _ in 0..30 {
            let before: Vec<(Vec<f32>, Vec<f32>)> = (0..n as i64)
                .map(|j| (s.critics.member_flat(j), moments(&s, j)))
                .collect();
            let (loss, _) = s.update_critics(&mut rb);
            assert!(loss.is_finite());
            let mut trained = 0;
            for j in 0..n {
                let now = (s.critics.member_flat(j as i64), moments(&s, j as i64));
                if now.0 != before[j].0 {
                    assert_ne!(now.1, before[j].1, "critic {j} moved without its moments");
                    counts[j] += 1;
                    trained += 1;
                } else {
                    assert_eq!(now.1, before[j].1, "untrained critic {j}'s moments moved");
                }
            }
            assert_eq!(trained, k, "an update trains k critics");
        }
        assert_eq!(s.critic_opt.member_steps, counts);
        assert!(
            counts.iter().all(|&c| c > 0),
            "every critic gets trained: {counts:?}"
        );
        assert_eq!(s.critic_opt.step, 30);
    }

    /// The ensemble baselines' targets (Average-DQN, REM, AQE; K = 1, M = N) train and stay finite.
    #[test]
    fn baseline_targets_train() {
        for target in [Formation::MaxMean, Formation::MaxRem, Formation::MaxAqe] {
            let cfg = AlgoConfig {
                method: Method::selkd(target),
                ..small(1, 4, 4)
            };
            let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 1);
            let mut rb = filled_replay(3, 2, 100);
            let stats = s.train_round(&mut rb, 0);
            assert!(stats.critic_loss.is_finite(), "{target:?}");
        }
    }

    /// Ablation "w/o RL": with λ_KD = 0 too, only actor 0 has a loss, so only actor 0 moves.
    #[test]
    fn without_rl_only_actor_zero_optimises_the_rl_objective() {
        let cfg = AlgoConfig {
            method: selkd_with(
                Formation::MaxMin,
                Sharing::PerUpdate,
                Distillation {
                    kd_actors: None,
                    without_rl: true,
                },
            ),
            kd_weight: 0.0,
            ..small(3, 2, 2)
        };
        let mut s = Selkd::new(&cfg, 3, 2, Device::Cpu, 6);
        let mut rb = filled_replay(3, 2, 100);
        let before: Vec<Vec<f32>> = (0..3).map(|i| s.actor_weights(i)).collect();
        s.update_actors(&mut rb, 1, &mut RoundStats::default());
        assert_ne!(s.actor_weights(0), before[0]);
        assert_eq!(s.actor_weights(1), before[1]);
        assert_eq!(s.actor_weights(2), before[2]);
    }

    /// A checkpoint restores networks, optimiser moments, temperatures and the RNG exactly: the
    /// resumed learner's next round equals the original's.
    #[test]
    fn checkpoint_round_trip_continues_identically() {
        for backbone in [Backbone::Sac, Backbone::TD3] {
            check_checkpoint_round_trip(backbone);
        }
    }

    fn check_checkpoint_round_trip(backbone: Backbone) {
        use crate::checkpoint::{self, TrainingState};
        let cfg = AlgoConfig {
            backbone,
            ..small(2, 3, 2)
        };
        let mut a = Selkd::new(&cfg, 3, 2, Device::Cpu, 4);
        let mut rb = filled_replay(3, 2, 100);
        for _ in 0..3 {
            a.train_round(&mut rb, 0);
        }
        let dir = std::env::temp_dir().join(format!(
            "selkd-ckpt-test-{}-{backbone:?}",
            std::process::id()
        ));
        let state = TrainingState {
            config: crate::config::Config::default(),
            rng: a.rng.clone(),
            critic_updates: a.critic_updates,
            actor_updates: a.actor_updates,
            adam_steps: checkpoint::adam_steps(&a),
            critic_member_steps: a.critic_opt.member_steps.clone(),
            received: vec![0; 2],
            rollouts: vec![],
            pending: vec![],
            last_round: None,
            dropped: [0; 3],
            policy_lag: (0.0, 0, 0),
            inserted: 0,
            lockstep_rounds: 0,
            weights_version: 0,
            eval_epoch: 0,
            epochs_logged: Some(0),
            epoch_ends: vec![],
            ranking: crate::ranking::Ranking::new(2, 1),
            wall_seconds: 0.0,
            selected_variant: 0,
            env: vec![],
        };
        checkpoint::save(&dir, &mut a, Some(&mut rb), &state).unwrap();
        let mut b = Selkd::new(&cfg, 3, 2, Device::Cpu, 99);
        let mut rb2 = ReplayBuffer::new(1000, 3, 2, Device::Cpu);
        checkpoint::load(&dir, &mut b, &mut rb2).unwrap();
        assert_eq!(rb2.len(), rb.len());
        // One actor, loaded for acting (`selkd render`): its own weights; the best by default.
        let one = checkpoint::load_actor(&dir, Some(1)).unwrap();
        assert_eq!((one.index, one.actors), (1, 2));
        let layout = one.actor.layout().clone();
        let direct = selkd_policy::Actor::from_flat(layout, a.actor_weights(1)).unwrap();
        let obs = [0.3, -0.2, 0.5];
        assert_eq!(one.actor.mean_action(&obs), direct.mean_action(&obs));
        assert_eq!(checkpoint::load_actor(&dir, None).unwrap().index, 0);
        let e = checkpoint::load_actor(&dir, Some(2))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("2 actors"), "{e}");
        a.train_round(&mut rb, 1);
        b.train_round(&mut rb2, 1);
        for i in 0..2 {
            assert_eq!(a.actor_weights(i), b.actor_weights(i));
        }
        assert_eq!(
            a.target_critics.member_flat(2),
            b.target_critics.member_flat(2)
        );
        assert_eq!(
            Vec::<f32>::try_from(a.alpha()).unwrap(),
            Vec::<f32>::try_from(b.alpha()).unwrap()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn avtd(variants: Vec<Regulariser>, n: usize) -> AlgoConfig {
        avtd_decayed(variants, n, 1e-4)
    }

    fn avtd_decayed(variants: Vec<Regulariser>, n: usize, weight_decay: f64) -> AlgoConfig {
        AlgoConfig {
            method: Method::Avtd {
                variants,
                validation_every: 10,
                weight_decay,
            },
            ..small(1, n, 2)
        }
    }

    /// AVTD's target by hand: variant v's y is REDQ's with v's own actor, α and subset of its own
    /// critics; every critic regresses on its variant's y.
    #[test]
    fn avtd_targets_are_each_variants_own_redq_target() {
        let (obs, act, per) = (3, 2, 3);
        let cfg = avtd(vec![Regulariser::None, Regulariser::WeightDecay], per);
        let mut s = Selkd::new(&cfg, obs, act, Device::Cpu, 4);
        assert_eq!((s.cfg.actors, s.cfg.critics), (2, 6));
        // Different α per variant, so that using the wrong one shows.
        tch::no_grad(|| {
            s.log_alpha
                .shallow_clone()
                .copy_(&Tensor::from_slice(&[0.0f32, -1.0]));
        });
        let mut rb = filled_replay(obs, act, 200);
        // A mini-batch with terminal and non-terminal rows, so that (1 − d) is seen both ways.
        let batch = (0..100)
            .map(|seed| rb.sample(1, cfg.batch_size, &mut Pcg64::seed_from_u64(seed)))
            .find(|b| {
                let d = Vec::<f32>::try_from(b.terminated.flatten(0, -1)).unwrap();
                d.contains(&1.0) && d.contains(&0.0)
            })
            .expect("a mini-batch with terminal and non-terminal rows among 100 draws");
        let subsets = [2i64, 0, 3, 5]; // variant 0: critics 2, 0; variant 1: critics 3, 5
        let mut peek = s.rng.clone();
        let b_size = cfg.batch_size;
        let eps: Vec<f64> = (0..2 * b_size * act)
            .map(|_| StandardNormal.sample(&mut peek))
            .map(|e: f32| e as f64)
            .collect();
        let y = tch::no_grad(|| s.target(&batch, &subsets));
        assert_eq!(y.size(), [6, b_size as i64]);
        let alphas = [1.0, (-1.0f64).exp()];
        for b in 0..b_size {
            let s2 = row(&batch.next_obs, 0, b as i64);
            let (r, d) = (
                batch.reward.double_value(&[0, b as i64]),
                batch.terminated.double_value(&[0, b as i64]),
            );
            for j in 0..6 {
                let v = j / per;
                let head = mlp(&s.actors, v as i64, &s2);
                let e = &eps[(v * b_size + b) * act..(v * b_size + b + 1) * act];
                let (mut a2, mut logp) = (Vec::new(), 0.0);
                for dim in 0..act {
                    let (mu, ls) = (head[dim], head[act + dim].clamp(-20.0, 2.0));
                    let u = mu + ls.exp() * e[dim];
                    logp += -0.5 * e[dim] * e[dim]
                        - ls
                        - 0.5 * (2.0 * std::f64::consts::PI).ln()
                        - (1.0 - u.tanh().powi(2) + 1e-6).ln();
                    a2.push(u.tanh() as f32);
                }
                let x2: Vec<f32> = s2.iter().chain(&a2).copied().collect();
                let min = subsets[2 * v..2 * v + 2]
                    .iter()
                    .map(|&m| mlp(&s.target_critics, m, &x2)[0])
                    .fold(f64::INFINITY, f64::min);
                let want = r + 0.99 * (1.0 - d) * (min - alphas[v] * logp);
                let got = y.double_value(&[j as i64, b as i64]);
                assert!(
                    (got - want).abs() < 1e-4 * want.abs().max(1.0),
                    "critic {j} row {b}: {got} vs {want}"
                );
            }
        }
    }

    /// With γ = 0 and every critic weight zero, variant v's critics all say Q = b_v (their last
    /// bias), so its validation TD error is mean ½(b_v − r)², known by hand; the lowest acts.
    #[test]
    fn avtd_selects_the_variant_with_the_lowest_validation_td_error() {
        let cfg = AlgoConfig {
            gamma: 0.0,
            ..avtd(
                vec![
                    Regulariser::None,
                    Regulariser::LayerNorm,
                    Regulariser::WeightDecay,
                ],
                2,
            )
        };
        let mut s = Selkd::new(&cfg, 3, 1, Device::Cpu, 6);
        let set_biases = |s: &Selkd, b: [f32; 3]| {
            tch::no_grad(|| {
                for layer in &s.critics.layers {
                    let _ = layer.weight.shallow_clone().zero_();
                    let _ = layer.bias.shallow_clone().zero_();
                }
                let per_critic: Vec<f32> = b.iter().flat_map(|&v| [v, v]).collect();
                let last = s.critics.layers.last().unwrap();
                last.bias
                    .shallow_clone()
                    .copy_(&Tensor::from_slice(&per_critic).view([6, 1, 1]));
            });
        };
        let validation = &mut s.avtd.as_mut().unwrap().validation;
        for t in 0..50 {
            let x = t as f32 / 50.0;
            validation.push(&[x, -x, 0.5], &[0.1], 1.0, &[x, x, x], t % 9 == 0);
        }
        set_biases(&s, [0.0, 0.9, 3.0]);
        s.draws = Some(Vec::new());
        assert!(s.select_variant(), "variant 1 replaces variant 0");
        assert_eq!(s.selection().unwrap().0, 1);
        // Drawn from 4·B validation rows.
        let draws = s.draws.take().unwrap();
        let Some(Draw::CriticBatch(drawn, _)) = draws.first() else {
            panic!("the validation batch is recorded");
        };
        assert_eq!(drawn.obs.size(), [1, 4 * cfg.batch_size as i64, 3]);
        let (_, td) = s.selection().unwrap();
        for (got, want) in td.iter().zip([0.5, 0.005, 2.0]) {
            assert!((got - want).abs() < 1e-6, "{td:?}");
        }
        assert_eq!(
            s.actor_weights(0),
            s.actors.member_flat(1),
            "the selected variant acts"
        );
        // Only every SELECT_EVERY_ROUNDS rounds.
        set_biases(&s, [0.0, 0.9, 1.0]);
        s.actor_updates = 3;
        assert!(!s.select_variant());
        s.actor_updates = 2 * SELECT_EVERY_ROUNDS;
        assert!(s.select_variant());
        assert_eq!(s.selection().unwrap().0, 2);
        // Never from fewer validation rows than a mini-batch; from exactly one, yes.
        let few = |s: &mut Selkd, rows: usize| {
            let mut v = ReplayBuffer::new(100, 3, 1, Device::Cpu);
            for _ in 0..rows {
                v.push(&[0.0; 3], &[0.0], 0.0, &[0.0; 3], false);
            }
            s.avtd.as_mut().unwrap().validation = v;
        };
        set_biases(&s, [1.0, 0.0, 0.0]);
        few(&mut s, cfg.batch_size - 1);
        assert!(!s.select_variant());
        few(&mut s, cfg.batch_size);
        assert!(s.select_variant());
        assert_eq!(s.selection().unwrap().0, 1);
    }

    /// The weight-decay variant's critics get ½ c ‖W‖² added to their loss: their gradient (Adam's
    /// first moment after one step, (1 − β1) g) exceeds the plain one by exactly (1 − β1) c W on
    /// weights; biases and the other variant's critics are untouched.
    #[test]
    fn avtd_weight_decay_adds_c_w_to_the_decayed_critics_gradient_only() {
        let c = 0.5;
        let variants = vec![Regulariser::None, Regulariser::WeightDecay];
        let with = avtd_decayed(variants.clone(), 2, c);
        let without = avtd_decayed(variants, 2, 0.0);
        let (mut a, mut b) = (
            Selkd::new(&with, 3, 2, Device::Cpu, 7),
            Selkd::new(&without, 3, 2, Device::Cpu, 7),
        );
        let weights_before: Vec<Tensor> = a
            .critics
            .layers
            .iter()
            .map(|l| l.weight.detach().copy())
            .collect();
        a.update_critics(&mut filled_replay(3, 2, 100));
        b.update_critics(&mut filled_replay(3, 2, 100));
        for (l, w) in weights_before.iter().enumerate() {
            let diff = &a.critic_opt.exp_avg[2 * l] - &b.critic_opt.exp_avg[2 * l];
            for j in 0..4 {
                let want = if j >= 2 {
                    w.get(j) * (0.1 * c)
                } else {
                    w.get(j).zeros_like()
                };
                let err = (diff.get(j) - want).abs().max().double_value(&[]);
                assert!(err < 1e-6, "layer {l} critic {j}: off by {err}");
            }
            let bias = (&a.critic_opt.exp_avg[2 * l + 1] - &b.critic_opt.exp_avg[2 * l + 1])
                .abs()
                .max()
                .double_value(&[]);
            assert!(bias < 1e-7, "biases are not decayed");
        }
    }

    /// Each variant's subset: M distinct critics of its own N, uniform over them.
    #[test]
    fn avtd_subsets_are_uniform_draws_from_each_variants_own_critics() {
        let (per, m, draws) = (4, 2, 4000);
        let mut s = Selkd::new(&avtd(vec![Regulariser::None; 3], per), 3, 1, Device::Cpu, 8);
        let mut count = vec![0usize; 3 * per];
        for _ in 0..draws {
            let subsets = s.draw_subsets(1);
            assert_eq!(subsets.len(), 3 * m);
            for (v, pair) in subsets.chunks(m).enumerate() {
                assert_ne!(pair[0], pair[1]);
                for &j in pair {
                    assert_eq!(j as usize / per, v, "{subsets:?}");
                    count[j as usize] += 1;
                }
            }
        }
        let expected = (draws * m / per) as f64; // 2000
        for c in count {
            assert!(
                (c as f64 - expected).abs() < 5.0 * (expected * 0.5).sqrt(),
                "{c} of {expected}"
            );
        }
    }
}
