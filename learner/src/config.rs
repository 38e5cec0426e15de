//! The run configuration: data (TOML), validated once at the edge with errors that say what to change.

pub mod docs;

use crate::targets::Formation;
use serde::{Deserialize, Serialize};

/// Everything a run needs, as written in a config file. Sections mirror the keys users `--set`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub run: RunConfig,
    pub algo: AlgoConfig,
    pub eval: EvalConfig,
    #[serde(rename = "async")]
    pub asynchronous: AsyncConfig,
    /// Options of `run.env` (each env documents its own; most have none).
    pub env_options: toml::Table,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Registry name of the environment.
    pub env: String,
    pub seed: u64,
    /// Budget: transitions from all actors together. Resolved from `total_rounds` when that is set.
    pub total_env_steps: u64,
    /// Budget in rounds (Algorithm 1's time-steps: each of the K actors takes one step), 0 = unset.
    /// When set, `total_env_steps` becomes rounds × K at validation, so everything downstream
    /// counts env steps as before; kept in the written config so a report can say which unit the
    /// run's budget was set in. Left out of the TOML when unset, so configs written before it
    /// existed compare equal to new ones.
    #[serde(skip_serializing_if = "is_zero")]
    pub total_rounds: u64,
    pub mode: Mode,
    /// `cpu` or `cuda` (or `cuda:N`), for the learner.
    pub device: String,
    /// Threads for the learner (0 = one per core); see `threads`.
    pub threads: usize,
    /// Who multiplies the critics' fp32 matrices on CPU; see `matmul`.
    pub cpu_gemm: crate::matmul::CpuGemm,
    /// Write a checkpoint every this many env steps (0 = only at the end).
    pub checkpoint_every: u64,
    /// Include the replay buffer in checkpoints (large; lets a resumed run continue exactly).
    pub checkpoint_replay: bool,
    /// Periodic checkpoints kept (the newest ones; `final` is always kept).
    pub keep_checkpoints: usize,
    /// Seconds a worker the run waits on (for a transition or an evaluation) may send nothing
    /// before it is reported, and `selkd train` kills and restarts it.
    pub worker_timeout: f64,
    /// Permissions of a run directory this run creates (checkpoints of a private task are
    /// data: by default only the owner may read them).
    pub dir_mode: DirMode,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// A directory's permission bits, written in a config as an octal string (`"0700"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirMode(pub u32);

impl Default for DirMode {
    fn default() -> Self {
        DirMode(0o700)
    }
}

impl std::fmt::Display for DirMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:04o}", self.0)
    }
}

impl std::str::FromStr for DirMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bits = u32::from_str_radix(s, 8).ok().filter(|b| *b <= 0o777);
        match bits {
            // The owner must be able to list, enter and write it: the run writes there.
            Some(b) if b & 0o700 == 0o700 => Ok(DirMode(b)),
            Some(_) => Err(format!(
                "run.dir_mode = \"{s}\" takes the owner's own access away; the owner needs rwx (\"07xx\", e.g. \"0700\" or \"0750\")"
            )),
            None => Err(format!(
                "run.dir_mode = \"{s}\" is not an octal mode; write it like \"0700\" (owner only) or \"0750\" (group may read)"
            )),
        }
    }
}

impl Serialize for DirMode {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for DirMode {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Makes a run directory (and missing parents) and, where it did not exist, gives it exactly
/// `mode`, whatever the umask; an existing directory keeps the permissions its owner chose.
pub fn create_run_dir(dir: &std::path::Path, mode: DirMode) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    if dir.is_dir() {
        return Ok(());
    }
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    match std::fs::create_dir(dir) {
        Ok(()) => std::fs::set_permissions(dir, std::fs::Permissions::from_mode(mode.0)),
        // Made meanwhile by another process (two array tasks of one experiment).
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && dir.is_dir() => Ok(()),
        Err(e) => Err(e),
    }
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Algorithm 1's lockstep rounds; reproducible on CPU with fixed seeds.
    Sync,
    /// Workers step freely; the learner holds the update-to-insert ratio at G per K transitions.
    Async,
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Sharing {
    /// One mini-batch and one critic subset per update, all N critics trained on the same y (REDQ).
    PerUpdate,
    /// Algorithm 1 as printed: a mini-batch and subset for each critic (N× the target rows).
    PerCritic,
}

/// `algo.backbone` as a file names it; [`AlgoKeys::backbone`] adds TD3's own keys.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum BackboneName {
    Sac,
    Td3,
}

/// The off-policy algorithm SELKD is built on (paper section 7.1), with the settings only it has.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Backbone {
    /// Stochastic tanh-Gaussian actors with entropy bonus; KD is the KL to the best actor.
    Sac,
    /// Deterministic actors with target actors and target policy smoothing; KD is the mean-squared
    /// action distance to the best actor; no temperature.
    Td3 {
        /// Std of the Gaussian noise added to the workers' actions.
        exploration_noise: f64,
        /// Std of the target policy smoothing noise, and where it is clipped.
        target_noise: f64,
        target_noise_clip: f64,
    },
}

impl Backbone {
    /// TD3 with Fujimoto et al.'s noise (0.1; 0.2 clipped to ± 0.5), the keys' defaults.
    pub const TD3: Backbone = Backbone::Td3 {
        exploration_noise: 0.1,
        target_noise: 0.2,
        target_noise_clip: 0.5,
    };

    pub fn is_td3(&self) -> bool {
        matches!(self, Backbone::Td3 { .. })
    }

    /// The std of the noise the workers add to their actions (none for SAC, which samples).
    pub fn exploration_noise(&self) -> f64 {
        match self {
            Backbone::Sac => 0.0,
            Backbone::Td3 {
                exploration_noise, ..
            } => *exploration_noise,
        }
    }
}

/// `[algo]` as written in a config file (and in every run's config.toml and checkpoint): flat
/// keys, one per setting. [`AlgoConfig`] reads and writes itself through it, so files of every
/// earlier version keep their meaning; [`AlgoKeys::method`] turns the method's keys into a
/// [`Method`], the one place where they are read.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct AlgoKeys {
    pub backbone: BackboneName,
    /// TD3: std of the Gaussian exploration noise added to the workers' actions.
    pub exploration_noise: f64,
    /// TD3: std of the target policy smoothing noise, and where it is clipped.
    pub target_noise: f64,
    pub target_noise_clip: f64,
    /// K actors.
    pub actors: usize,
    /// N critics.
    pub critics: usize,
    /// M: size of the random critic subset in the target.
    pub subset: usize,
    /// G: critic updates per round (per K transitions).
    pub utd: usize,
    /// U: updates of every actor (and its temperature) per round. Algorithm 1 has 1, after the
    /// G critic updates; U > 1 is a departure from it (the ablation that gives SELKD's actors
    /// REDQ's update count): an actor update follows each of the last U critic updates.
    pub actor_updates_per_round: usize,
    pub batch_size: usize,
    pub hidden: Vec<usize>,
    pub lr: f64,
    pub gamma: f64,
    /// ρ in `Q̄ ← ρ Q̄ + (1 − ρ) Q`.
    pub polyak: f64,
    pub replay_capacity: usize,
    /// Uniform-random transitions (all actors together) before the first update.
    pub warmup_steps: u64,
    pub target: Formation,
    pub sharing: Sharing,
    /// λ_KD, weight of the distillation term.
    pub kd_weight: f64,
    /// The DPD baseline: actor i owns N/K critics (its target is the min over its own, no max over
    /// actors) and distils toward its peer (actor i+1) instead of the best.
    pub paired_critics: bool,
    /// Ablation "SELKD w/o RL": only actor 0 optimises the RL objective; the others only distil.
    pub without_rl: bool,
    /// Which actors have a distillation term (0-based); absent: every actor. The ablation "SELKD
    /// w/o KD" sets `[0]`: one actor learns with RL + KD, the others with RL only.
    pub kd_actors: Option<Vec<usize>>,
    /// How an actor's objective reduces the critics' values of its action: `mean` over the N
    /// critics (SELKD's eq. 7, REDQ), or `min` (SAC's clipped double Q, as Haarnoja et al., SB3
    /// and CleanRL maximise min(Q1, Q2)).
    pub actor_q: ActorQ,
    /// `target = "max-aqe"`: how many of the highest subset values AQE drops.
    pub aqe_drop: usize,
    /// Fixed temperature; when absent, each actor's α is tuned automatically.
    pub fixed_alpha: Option<f64>,
    pub alpha_lr: f64,
    /// Target entropy for the automatic temperature; default −|A|.
    pub target_entropy: Option<f64>,
    /// Element type of the critics' matmuls: `fp32` (exact) or `bf16` (about twice the matmul
    /// throughput on CPUs with AVX-512 BF16 and on GPUs; fp32 weights, optimiser and accumulation).
    pub critic_matmul: Precision,
    /// DNS: each critic update trains only this many critics (k), drawn by a k-DPP over the
    /// critics' similarity on the batch (`dpp`); the others keep their weights and optimiser
    /// state. Absent: all N.
    pub trained_critics: Option<usize>,
    /// AVTD: regularisation variants of the agent trained side by side on the shared data, each
    /// a whole agent (its actor, its N critics, its α); the variant whose critics have the lowest
    /// TD error on held-out validation transitions acts and is evaluated. Empty: no AVTD.
    pub variants: Vec<Regulariser>,
    /// AVTD: every this-many-th transition received is held out for validation (never trained on).
    pub validation_every: u64,
    /// AVTD's `weight-decay` variant: c in the ½ c ‖W‖² added to each critic's loss (weights, not biases).
    pub weight_decay: f64,
}

/// The learner's settings as the program holds them: the settings every method has, and the
/// [`Method`] with the settings only it has. Read from and written as [`AlgoKeys`].
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(try_from = "AlgoKeys", into = "AlgoKeys")]
pub struct AlgoConfig {
    /// SELKD, DNS, DPD or AVTD, with its own settings.
    pub method: Method,
    /// SAC, or TD3 with its noise.
    pub backbone: Backbone,
    /// K actors.
    pub actors: usize,
    /// N critics.
    pub critics: usize,
    /// M: size of the random critic subset in the target.
    pub subset: usize,
    /// G: critic updates per round (per K transitions).
    pub utd: usize,
    /// U: updates of every actor (and its temperature) per round (see [`AlgoKeys`]).
    pub actor_updates_per_round: usize,
    pub batch_size: usize,
    pub hidden: Vec<usize>,
    pub lr: f64,
    pub gamma: f64,
    /// ρ in `Q̄ ← ρ Q̄ + (1 − ρ) Q`.
    pub polyak: f64,
    pub replay_capacity: usize,
    /// Uniform-random transitions (all actors together) before the first update.
    pub warmup_steps: u64,
    /// λ_KD, weight of the distillation term.
    pub kd_weight: f64,
    /// How an actor's objective reduces the critics' values of its action.
    pub actor_q: ActorQ,
    /// Fixed temperature; when absent, each actor's α is tuned automatically.
    pub fixed_alpha: Option<f64>,
    pub alpha_lr: f64,
    /// Target entropy for the automatic temperature; default −|A|.
    pub target_entropy: Option<f64>,
    /// Element type of the critics' matmuls.
    pub critic_matmul: Precision,
}

impl AlgoConfig {
    /// A lower bound of the bytes the K actors and N critics take (of every AVTD variant): per
    /// parameter its value, its gradient and Adam's two moments, plus the target critics (and
    /// TD3's target actors), for an env of these sizes.
    pub fn network_bytes(&self, obs_dim: usize, act_dim: usize) -> u64 {
        let (obs, act) = (obs_dim as u128, act_dim as u128);
        let variants = self.method.variants().len().max(1) as u128;
        // Weights and biases of one member of a stacked ensemble with these layer sizes.
        let params = |input: u128, output: u128| -> u128 {
            let dims: Vec<u128> = std::iter::once(input)
                .chain(self.hidden.iter().map(|&h| h as u128))
                .chain(std::iter::once(output))
                .collect();
            dims.windows(2)
                .map(|w| w[0].saturating_mul(w[1]).saturating_add(w[1]))
                .fold(0u128, u128::saturating_add)
        };
        let actors = (self.actors as u128) * variants;
        let critics = (self.critics as u128) * variants;
        // value + gradient + Adam's m and v; targets are one more copy.
        let actor_copies = if self.backbone.is_td3() { 5 } else { 4 };
        let actor_floats = params(obs, 2 * act)
            .saturating_mul(actors)
            .saturating_mul(actor_copies)
            // log α per actor, with its gradient and moments
            .saturating_add(4 * actors);
        let critic_floats = params(obs + act, 1)
            .saturating_mul(critics)
            .saturating_mul(5);
        float_bytes(actor_floats.saturating_add(critic_floats))
    }
}

/// Bytes of `floats` f32 values, saturating at `u64::MAX`.
fn float_bytes(floats: u128) -> u64 {
    floats.saturating_mul(4).min(u64::MAX as u128) as u64
}

/// The method: which critics an actor's target and objective use, which critics a critic
/// update trains, and whom an actor distils toward. Each variant carries the settings only it
/// has, so a combination that no method is cannot be held. REDQ, Maxmin, Average-DQN, REM, AQE,
/// SAC and TASAC are [`Method::Selkd`] with their K, N, M, target and `actor_q`.
#[derive(Clone, Debug, PartialEq)]
pub enum Method {
    /// Algorithm 1: K actors share N critics; y is `target`'s reduction of every actor's next
    /// action through a random subset of M critics (`algo.target`, `algo.sharing`).
    Selkd {
        target: Formation,
        /// `target = "max-aqe"`: how many of the highest subset values AQE drops.
        aqe_drop: usize,
        sharing: Sharing,
        distillation: Distillation,
    },
    /// DNS (`algo.trained_critics`): SELKD's shared target on one batch per update, but each
    /// update trains only `trained_critics` (k) of the N critics, drawn by a k-DPP over how alike
    /// their values on the batch are (`dpp`); the others keep their weights and Adam state.
    Dns {
        target: Formation,
        aqe_drop: usize,
        trained_critics: usize,
        distillation: Distillation,
    },
    /// DPD (`algo.paired_critics`): actor i owns N/K critics; its target is the min over its
    /// own (no max over actors), it is judged by them, and it distils toward actor i+1.
    Dpd {
        /// Ablation w/o RL: only actor 0 optimises the RL objective.
        without_rl: bool,
    },
    /// AVTD (`algo.variants`): one whole agent per regularisation variant (its actor, its N
    /// critics, its α) trained side by side on the shared data; the variant whose critics have
    /// the lowest TD error on held-out transitions acts and is evaluated.
    Avtd {
        variants: Vec<Regulariser>,
        /// Every this-many-th transition received is held out for validation (never trained on).
        validation_every: u64,
        /// The `weight-decay` variant's c in the ½ c ‖W‖² added to each critic's loss.
        weight_decay: f64,
    },
}

/// SELKD's and DNS's distillation: which actors distil toward the best and which learn by RL.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Distillation {
    /// Actors with a distillation term (the best never has one); `None`: every actor. The
    /// ablation "w/o KD" sets `[0]`.
    pub kd_actors: Option<Vec<usize>>,
    /// Ablation "w/o RL": only actor 0 optimises the RL objective; the others only distil.
    pub without_rl: bool,
}

impl Default for Method {
    /// Algorithm 1 with the paper's max-min target.
    fn default() -> Self {
        Method::Selkd {
            target: Formation::MaxMin,
            aqe_drop: 1,
            sharing: Sharing::PerUpdate,
            distillation: Distillation::default(),
        }
    }
}

impl Method {
    /// SELKD with another target formation (REDQ, Maxmin, the ensemble baselines).
    pub fn selkd(target: Formation) -> Self {
        Method::Selkd {
            target,
            aqe_drop: 1,
            sharing: Sharing::PerUpdate,
            distillation: Distillation::default(),
        }
    }

    /// How a critic update's mini-batches are drawn: per critic only where SELKD is set to.
    pub fn sharing(&self) -> Sharing {
        match self {
            Method::Selkd { sharing, .. } => *sharing,
            _ => Sharing::PerUpdate,
        }
    }

    /// AVTD's variants; empty for every other method.
    pub fn variants(&self) -> &[Regulariser] {
        match self {
            Method::Avtd { variants, .. } => variants,
            _ => &[],
        }
    }
}

impl AlgoKeys {
    /// The method these keys select: `paired_critics` is DPD, a non-empty `variants` AVTD,
    /// `trained_critics` DNS, and otherwise SELKD. A combination no method has is a one-line
    /// error; keys a method does not read (`target`, `sharing` and `aqe_drop` under DPD and
    /// AVTD, which have targets of their own) are left out of it, as they always were ignored.
    /// The backbone, with TD3's noise keys when it is TD3 (SAC has none: they are ignored).
    pub fn backbone(&self) -> Backbone {
        match self.backbone {
            BackboneName::Sac => Backbone::Sac,
            BackboneName::Td3 => Backbone::Td3 {
                exploration_noise: self.exploration_noise,
                target_noise: self.target_noise,
                target_noise_clip: self.target_noise_clip,
            },
        }
    }

    pub fn method(&self) -> Result<Method, String> {
        let per_update = self.sharing == Sharing::PerUpdate;
        if self.paired_critics && !per_update {
            return Err(paired_critics_needs(self.critics, self.actors));
        }
        if self.trained_critics.is_some() && (self.paired_critics || !per_update) {
            return Err("algo.trained_critics (DNS) compares the critics on one batch: it needs sharing = \"per-update\" and no paired_critics".into());
        }
        if !self.variants.is_empty()
            && (self.paired_critics
                || self.trained_critics.is_some()
                || self.without_rl
                || self.kd_actors.is_some()
                || !per_update)
        {
            return Err(AVTD_NEEDS.into());
        }
        if self.paired_critics && self.kd_actors.is_some() {
            return Err("algo.kd_actors cannot be combined with algo.paired_critics (DPD's actors all distil toward their peer)".into());
        }
        let distillation = Distillation {
            kd_actors: self.kd_actors.clone(),
            without_rl: self.without_rl,
        };
        Ok(if self.paired_critics {
            Method::Dpd {
                without_rl: self.without_rl,
            }
        } else if !self.variants.is_empty() {
            Method::Avtd {
                variants: self.variants.clone(),
                validation_every: self.validation_every,
                weight_decay: self.weight_decay,
            }
        } else if let Some(k) = self.trained_critics {
            Method::Dns {
                target: self.target,
                aqe_drop: self.aqe_drop,
                trained_critics: k,
                distillation,
            }
        } else {
            Method::Selkd {
                target: self.target,
                aqe_drop: self.aqe_drop,
                sharing: self.sharing,
                distillation,
            }
        })
    }
}

impl Method {
    /// The method's own settings against the sizes they need, with a one-line error.
    fn check(&self, a: &AlgoConfig) -> Result<(), String> {
        match self {
            Method::Selkd {
                target, aqe_drop, ..
            }
            | Method::Dns {
                target, aqe_drop, ..
            } => {
                if let Method::Dns {
                    trained_critics: k, ..
                } = self
                {
                    if *k == 0 || *k > a.critics {
                        return Err(format!(
                            "algo.trained_critics (k = {k}) must be between 1 and algo.critics (N = {}), or absent to train all",
                            a.critics
                        ));
                    }
                }
                if *target == Formation::MaxAqe && *aqe_drop >= a.subset {
                    return Err(format!("algo.aqe_drop ({aqe_drop}) must be below algo.subset (M = {}) so AQE keeps at least one value", a.subset));
                }
            }
            Method::Dpd { .. } => {
                if a.actors < 2 || !a.critics.is_multiple_of(a.actors) {
                    return Err(paired_critics_needs(a.critics, a.actors));
                }
            }
            Method::Avtd {
                variants,
                validation_every,
                weight_decay,
            } => {
                if variants.len() > 8 {
                    return Err(format!(
                        "algo.variants lists {} variants; AVTD here trains at most 8",
                        variants.len()
                    ));
                }
                if a.actors != 1 {
                    return Err(AVTD_NEEDS.into());
                }
                if *validation_every < 2 {
                    return Err(format!("algo.validation_every = {validation_every} must be at least 2 (every n-th transition is held out for validation; 10 holds out 10%)"));
                }
                if !(*weight_decay >= 0.0 && weight_decay.is_finite()) {
                    return Err(format!("algo.weight_decay = {weight_decay} must be ≥ 0"));
                }
            }
        }
        Ok(())
    }

    /// SELKD's and DNS's `kd_actors`, when set.
    fn kd_actors(&self) -> Option<&[usize]> {
        match self {
            Method::Selkd { distillation, .. } | Method::Dns { distillation, .. } => {
                distillation.kd_actors.as_deref()
            }
            _ => None,
        }
    }
}

fn paired_critics_needs(critics: usize, actors: usize) -> String {
    format!("algo.paired_critics needs at least 2 actors, algo.critics ({critics}) a multiple of algo.actors ({actors}), and sharing = \"per-update\"")
}

const AVTD_NEEDS: &str = "algo.variants (AVTD) trains one agent per variant and lets the best act: it needs algo.actors = 1, sharing = \"per-update\", and no paired_critics, trained_critics, without_rl or kd_actors";

impl TryFrom<AlgoKeys> for AlgoConfig {
    type Error = String;
    fn try_from(k: AlgoKeys) -> Result<Self, String> {
        Ok(AlgoConfig {
            method: k.method()?,
            backbone: k.backbone(),
            actors: k.actors,
            critics: k.critics,
            subset: k.subset,
            utd: k.utd,
            actor_updates_per_round: k.actor_updates_per_round,
            batch_size: k.batch_size,
            hidden: k.hidden,
            lr: k.lr,
            gamma: k.gamma,
            polyak: k.polyak,
            replay_capacity: k.replay_capacity,
            warmup_steps: k.warmup_steps,
            kd_weight: k.kd_weight,
            actor_q: k.actor_q,
            fixed_alpha: k.fixed_alpha,
            alpha_lr: k.alpha_lr,
            target_entropy: k.target_entropy,
            critic_matmul: k.critic_matmul,
        })
    }
}

impl From<AlgoConfig> for AlgoKeys {
    /// The method's keys as a file states them; a key the method does not have is written at
    /// its default.
    fn from(c: AlgoConfig) -> Self {
        let mut k = AlgoKeys {
            backbone: BackboneName::Sac,
            actors: c.actors,
            critics: c.critics,
            subset: c.subset,
            utd: c.utd,
            actor_updates_per_round: c.actor_updates_per_round,
            batch_size: c.batch_size,
            hidden: c.hidden,
            lr: c.lr,
            gamma: c.gamma,
            polyak: c.polyak,
            replay_capacity: c.replay_capacity,
            warmup_steps: c.warmup_steps,
            kd_weight: c.kd_weight,
            actor_q: c.actor_q,
            fixed_alpha: c.fixed_alpha,
            alpha_lr: c.alpha_lr,
            target_entropy: c.target_entropy,
            critic_matmul: c.critic_matmul,
            ..AlgoKeys::default()
        };
        if let Backbone::Td3 {
            exploration_noise,
            target_noise,
            target_noise_clip,
        } = c.backbone
        {
            k.backbone = BackboneName::Td3;
            k.exploration_noise = exploration_noise;
            k.target_noise = target_noise;
            k.target_noise_clip = target_noise_clip;
        }
        let set_distillation = |k: &mut AlgoKeys, d: Distillation| {
            k.kd_actors = d.kd_actors;
            k.without_rl = d.without_rl;
        };
        match c.method {
            Method::Selkd {
                target,
                aqe_drop,
                sharing,
                distillation,
            } => {
                (k.target, k.aqe_drop, k.sharing) = (target, aqe_drop, sharing);
                set_distillation(&mut k, distillation);
            }
            Method::Dns {
                target,
                aqe_drop,
                trained_critics,
                distillation,
            } => {
                (k.target, k.aqe_drop) = (target, aqe_drop);
                k.trained_critics = Some(trained_critics);
                set_distillation(&mut k, distillation);
            }
            Method::Dpd { without_rl } => {
                k.paired_critics = true;
                k.without_rl = without_rl;
            }
            Method::Avtd {
                variants,
                validation_every,
                weight_decay,
            } => {
                (k.variants, k.validation_every, k.weight_decay) =
                    (variants, validation_every, weight_decay);
            }
        }
        k
    }
}

/// How an AVTD variant regularises its critics (the actors are never regularised).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Regulariser {
    /// No regularisation: REDQ as configured.
    None,
    /// Layer normalisation (no learned scale or shift) after every hidden linear layer, before the ReLU.
    LayerNorm,
    /// L2 on the critics' weight matrices, `algo.weight_decay`.
    WeightDecay,
}

/// The actor objective's reduction over critics.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum ActorQ {
    Mean,
    Min,
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Precision {
    Fp32,
    Bf16,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// An epoch: this many env steps (all actors together) between evaluations.
    pub epoch_env_steps: u64,
    /// Deterministic evaluation episodes per actor per epoch.
    pub episodes: usize,
    /// Before the first evaluation, an actor's score is the mean of this many latest training episodes.
    pub score_window: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct AsyncConfig {
    /// How far (in critic updates) the update count may run ahead of or behind G/K per transition
    /// before the side that is ahead waits.
    pub ratio_tolerance: f64,
    /// Most learner weight versions a worker's behaviour policy may lag behind.
    pub max_policy_lag: u64,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            run: RunConfig::default(),
            algo: AlgoConfig::default(),
            eval: EvalConfig::default(),
            asynchronous: AsyncConfig::default(),
            env_options: toml::Table::new(),
        }
    }
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            env: "pendulum".into(),
            seed: 1,
            total_env_steps: 300_000,
            total_rounds: 0,
            mode: Mode::Sync,
            device: "cpu".into(),
            threads: 0,
            cpu_gemm: crate::matmul::CpuGemm::Auto,
            checkpoint_every: 50_000,
            checkpoint_replay: false,
            keep_checkpoints: 3,
            // Ten 1000-step humanoid evaluation episodes take about 20 s on a busy core (480
            // env steps/s measured with another run beside it); six times that covers slower
            // machines.
            worker_timeout: 120.0,
            dir_mode: DirMode::default(),
        }
    }
}

/// Paper Table 1.
impl Default for AlgoConfig {
    fn default() -> Self {
        AlgoConfig::try_from(AlgoKeys::default()).expect("Table 1 is SELKD")
    }
}

/// Paper Table 1, as keys.
impl Default for AlgoKeys {
    fn default() -> Self {
        Self {
            backbone: BackboneName::Sac,
            exploration_noise: 0.1,
            target_noise: 0.2,
            target_noise_clip: 0.5,
            actors: 5,
            critics: 10,
            subset: 2,
            utd: 20,
            actor_updates_per_round: 1,
            batch_size: 256,
            hidden: vec![256, 256],
            lr: 3e-4,
            gamma: 0.99,
            polyak: 0.995,
            replay_capacity: 100_000,
            warmup_steps: 5000,
            target: Formation::MaxMin,
            sharing: Sharing::PerUpdate,
            kd_weight: 1.0,
            paired_critics: false,
            without_rl: false,
            kd_actors: None,
            actor_q: ActorQ::Mean,
            aqe_drop: 1,
            fixed_alpha: None,
            alpha_lr: 3e-4,
            target_entropy: None,
            critic_matmul: Precision::Fp32,
            trained_critics: None,
            variants: Vec::new(),
            validation_every: 10,
            weight_decay: 1e-4,
        }
    }
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            epoch_env_steps: 1000,
            episodes: 10,
            score_window: 10,
        }
    }
}

impl Default for AsyncConfig {
    fn default() -> Self {
        Self {
            ratio_tolerance: 100.0,
            max_policy_lag: 4,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("config: {0}")]
    Invalid(String),
    #[error("config: cannot parse: {0}")]
    Parse(String),
}

impl Config {
    /// Parses TOML text, then applies `key=value` overrides (`algo.critics=4`), then validates.
    pub fn from_toml_with_overrides(text: &str, overrides: &[String]) -> Result<Self, ConfigError> {
        let mut value: toml::Table =
            toml::from_str(text).map_err(|e| ConfigError::Parse(one_line(&e.to_string())))?;
        for o in overrides {
            apply_override(&mut value, o)?;
        }
        restate_budget(&mut value, overrides)?;
        let steps_given = value
            .get("run")
            .and_then(|r| r.get("total_env_steps"))
            .is_some();
        // The method's keys make one method or a config error (not a parse error) naming them.
        let keys = value
            .get("algo")
            .cloned()
            .map(toml::Value::try_into::<AlgoKeys>);
        if let Some(Ok(keys)) = keys {
            keys.method().map_err(ConfigError::Invalid)?;
        }
        let mut cfg: Config = toml::Value::Table(value)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse(one_line(&e.to_string())))?;
        cfg.resolve_budget(steps_given)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// A budget in rounds becomes `run.total_env_steps` = rounds × K, once, here; a config that
    /// also gives env steps must agree with it (every run's written config.toml states both).
    fn resolve_budget(&mut self, steps_given: bool) -> Result<(), ConfigError> {
        let (rounds, k) = (self.run.total_rounds, self.algo.actors as u64);
        if rounds == 0 || k == 0 {
            return Ok(()); // no rounds budget, or K = 0, which validate() reports
        }
        let Some(steps) = rounds.checked_mul(k) else {
            return Err(ConfigError::Invalid(format!(
                "run.total_rounds = {rounds} × algo.actors = {k} overflows; choose a smaller budget"
            )));
        };
        if steps_given && self.run.total_env_steps != steps {
            return Err(ConfigError::Invalid(format!(
                "run.total_env_steps = {} and run.total_rounds = {rounds} both set the budget and disagree ({rounds} rounds of K = {k} actors are {steps} env steps); set only one",
                self.run.total_env_steps
            )));
        }
        self.run.total_env_steps = steps;
        Ok(())
    }

    /// The unit the budget was set in, for reports: `rounds` or `env steps`.
    pub fn budget_unit(&self) -> &'static str {
        if self.run.total_rounds > 0 {
            "rounds"
        } else {
            "env steps"
        }
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("config serialises")
    }

    /// Checks every value once, with a message that says what to change. (Method keys that no
    /// method combines never get here: [`AlgoKeys::method`] refuses them.)
    pub fn validate(&self) -> Result<(), ConfigError> {
        let a = &self.algo;
        let bad = |m: String| Err(ConfigError::Invalid(m));
        if self.run.env.len() > selkd_protocol::NAME_BYTES {
            return bad(format!(
                "run.env = \"{}\" is {} bytes; the processes' messages carry at most {}",
                self.run.env,
                self.run.env.len(),
                selkd_protocol::NAME_BYTES
            ));
        }
        match self.env_spec() {
            Err(selkd_envs::EnvError::Unknown { .. }) => {
                return bad(format!(
                    "run.env = \"{}\" is not a known env; choose one of: {}",
                    self.run.env,
                    selkd_envs::names().join(", ")
                ))
            }
            Err(e) => return bad(one_line(&e.to_string())),
            Ok(_) => {}
        }
        if a.actors == 0 || a.actors > selkd_protocol::MAX_ACTORS {
            return bad(format!(
                "algo.actors (K = {}) must be between 1 and {}",
                a.actors,
                selkd_protocol::MAX_ACTORS
            ));
        }
        if a.critics == 0 {
            return bad("algo.critics (N) must be at least 1".into());
        }
        if a.subset == 0 || a.subset > a.critics {
            return bad(format!(
                "algo.subset (M = {}) must be between 1 and algo.critics (N = {})",
                a.subset, a.critics
            ));
        }
        if a.utd == 0 || a.batch_size == 0 || a.replay_capacity == 0 {
            return bad(
                "algo.utd, algo.batch_size and algo.replay_capacity must be at least 1".into(),
            );
        }
        if a.actor_updates_per_round == 0 || a.actor_updates_per_round > a.utd {
            return bad(format!(
                "algo.actor_updates_per_round = {} must be between 1 and algo.utd (G = {}): \
                 an actor update follows a critic update",
                a.actor_updates_per_round, a.utd
            ));
        }
        if a.hidden.is_empty()
            || a.hidden.contains(&0)
            || a.hidden.len() > selkd_protocol::MAX_HIDDEN_LAYERS
        {
            return bad(format!(
                "algo.hidden = {:?} needs 1 to {} layers, each of size ≥ 1",
                a.hidden,
                selkd_protocol::MAX_HIDDEN_LAYERS
            ));
        }
        if self.run.keep_checkpoints == 0 {
            return bad("run.keep_checkpoints must be at least 1 (the default is 3)".into());
        }
        if !(self.run.worker_timeout >= 1.0 && self.run.worker_timeout.is_finite()) {
            return bad(format!(
                "run.worker_timeout = {} must be at least 1 (seconds)",
                self.run.worker_timeout
            ));
        }
        if a.batch_size > a.replay_capacity {
            return bad(format!(
                "algo.batch_size ({}) must not exceed algo.replay_capacity ({})",
                a.batch_size, a.replay_capacity
            ));
        }
        if !(a.lr > 0.0 && a.lr.is_finite() && a.alpha_lr > 0.0 && a.alpha_lr.is_finite()) {
            return bad("algo.lr and algo.alpha_lr must be positive numbers".into());
        }
        if !(0.0..=1.0).contains(&a.gamma) {
            return bad(format!("algo.gamma = {} must be in [0, 1]", a.gamma));
        }
        if !(0.0..1.0).contains(&a.polyak) {
            return bad(format!("algo.polyak (ρ) = {} must be in [0, 1)", a.polyak));
        }
        if let Err(m) = a.method.check(a) {
            return bad(m);
        }
        if let Backbone::Td3 {
            exploration_noise,
            target_noise,
            target_noise_clip,
        } = a.backbone
        {
            for (key, v) in [
                ("exploration_noise", exploration_noise),
                ("target_noise", target_noise),
                ("target_noise_clip", target_noise_clip),
            ] {
                if !(v >= 0.0 && v.is_finite()) {
                    return bad(format!("algo.{key} = {v} must be ≥ 0"));
                }
            }
        }
        if !(a.kd_weight >= 0.0 && a.kd_weight.is_finite()) {
            return bad(format!("algo.kd_weight = {} must be ≥ 0", a.kd_weight));
        }
        if let Some(alpha) = a.fixed_alpha {
            if !(alpha >= 0.0 && alpha.is_finite()) {
                return bad(format!(
                    "algo.fixed_alpha = {alpha} must be ≥ 0 (or leave it out for automatic tuning)"
                ));
            }
        }
        if a.warmup_steps < a.batch_size as u64 {
            return bad(format!("algo.warmup_steps ({}) must be at least algo.batch_size ({}) so the first batch can be drawn", a.warmup_steps, a.batch_size));
        }
        if self.run.total_env_steps == 0 {
            return bad("run.total_env_steps must be at least 1".into());
        }
        let rounds = self.run.total_rounds;
        if rounds > 0 {
            let k = a.actors as u64;
            if rounds.checked_mul(k) != Some(self.run.total_env_steps) {
                return bad(format!("run.total_rounds = {rounds} with K = {k} actors is {} env steps, but run.total_env_steps = {}; set only one", rounds.saturating_mul(k), self.run.total_env_steps));
            }
            // A budget in rounds says "this much learner work"; one spent inside the warm-up
            // would do none, which is never what a rounds budget means.
            let warmup_rounds = self.warmup_per_actor();
            if rounds < warmup_rounds {
                return bad(format!("run.total_rounds = {rounds} ends within the warm-up (algo.warmup_steps = {} env steps are {warmup_rounds} rounds of K = {k} actors), so no critic update would happen; raise run.total_rounds to at least {warmup_rounds} or lower algo.warmup_steps", a.warmup_steps));
            }
        }
        // Each actor plays its episodes every epoch; beyond this an epoch's evaluation outlasts
        // any training it measures (1e9 held the run in evaluation for good).
        if self.eval.episodes > MAX_EVAL_EPISODES {
            return bad(format!(
                "eval.episodes = {} is more than {MAX_EVAL_EPISODES} evaluation episodes per actor per epoch; lower it",
                self.eval.episodes
            ));
        }
        if self.eval.epoch_env_steps == 0 || self.eval.episodes == 0 || self.eval.score_window == 0
        {
            return bad(
                "eval.epoch_env_steps, eval.episodes and eval.score_window must be at least 1"
                    .into(),
            );
        }
        // An epoch ends at the first round boundary at or past each multiple of epoch_env_steps,
        // so any K works, as long as one round does not span two epochs.
        if self.eval.epoch_env_steps < a.actors as u64 {
            return bad(format!("eval.epoch_env_steps ({}) must be at least algo.actors ({}): one round (K env steps) may not span two epochs", self.eval.epoch_env_steps, a.actors));
        }
        if let Some(list) = a.method.kd_actors() {
            if let Some(&i) = list.iter().find(|&&i| i >= a.actors) {
                return bad(format!("algo.kd_actors names actor {i}, but the run has algo.actors = {} (actors 0..{})", a.actors, a.actors - 1));
            }
        }
        let dev = self.run.device.as_str();
        if !(dev == "cpu"
            || dev == "cuda"
            || dev
                .strip_prefix("cuda:")
                .is_some_and(|n| n.parse::<usize>().is_ok()))
        {
            return bad(format!(
                "run.device = \"{dev}\" must be cpu, cuda or cuda:N"
            ));
        }
        let tolerance = self.asynchronous.ratio_tolerance;
        if tolerance.is_nan() || tolerance < 1.0 {
            return bad("async.ratio_tolerance must be at least 1 (critic updates)".into());
        }
        if self.asynchronous.max_policy_lag == 0 {
            return bad("async.max_policy_lag must be at least 1".into());
        }
        // Last, on a config that is otherwise sound: a run that cannot fit is refused here, not by
        // an allocation failing (a libtorch abort) once the processes are up.
        if dev == "cpu" {
            if let Some(physical) = physical_memory() {
                self.check_memory(physical)?;
            }
        }
        Ok(())
    }

    /// A lower bound of the bytes the learner holds for this config: the replay buffer (and
    /// AVTD's validation rows), and per parameter of the K actors and N critics its value, its
    /// gradient and Adam's two moments, plus the target critics (and TD3's target actors).
    /// Activations and libtorch's workspace come on top, so a config above the machine's
    /// memory surely fails.
    pub fn memory_estimate(&self) -> Result<MemoryEstimate, ConfigError> {
        let spec = self
            .env_spec()
            .map_err(|e| ConfigError::Invalid(one_line(&e.to_string())))?;
        let a = &self.algo;
        let (obs, act) = (spec.obs_dim as u128, spec.act_dim as u128);
        let row = 2 * obs + act + 2;
        let mut rows = a.replay_capacity as u128;
        if let Method::Avtd {
            validation_every, ..
        } = a.method
        {
            rows += (a.replay_capacity as u128 / validation_every.max(1) as u128).max(1);
        }
        Ok(MemoryEstimate {
            replay: float_bytes(rows.saturating_mul(row)),
            networks: a.network_bytes(spec.obs_dim, spec.act_dim),
        })
    }

    /// Refuses a config whose [`Self::memory_estimate`] exceeds `available` bytes, naming the key
    /// that takes the most.
    pub fn check_memory(&self, available: u64) -> Result<(), ConfigError> {
        let m = self.memory_estimate()?;
        if m.total() <= available {
            return Ok(());
        }
        let what = if m.replay >= m.networks {
            format!(
                "algo.replay_capacity = {} takes {} of it",
                self.algo.replay_capacity,
                bytes(m.replay)
            )
        } else {
            format!(
                "the networks (algo.hidden = {:?}, algo.actors = {}, algo.critics = {}) with their gradients and Adam state take {}",
                self.algo.hidden,
                self.algo.actors,
                self.algo.critics,
                bytes(m.networks)
            )
        };
        Err(ConfigError::Invalid(format!(
            "this run needs at least {} of memory, more than this machine's {}: {what}; lower it",
            bytes(m.total()),
            bytes(available)
        )))
    }

    pub fn warmup_per_actor(&self) -> u64 {
        self.algo.warmup_steps.div_ceil(self.algo.actors as u64)
    }

    pub fn steps_per_actor(&self) -> u64 {
        self.run.total_env_steps.div_ceil(self.algo.actors as u64)
    }

    /// The critic updates a run makes in its budget: G per round, from the round whose
    /// transitions complete the warm-up (the learner's `RateLimiter::rounds_due`: one round when
    /// the warm-up's last transition is stored, then one per K more) to the budget's last.
    pub fn critic_updates_in_budget(&self) -> u64 {
        let (rounds, warmup) = (self.steps_per_actor(), self.warmup_per_actor());
        if rounds < warmup {
            return 0;
        }
        (rounds - warmup + 1) * self.algo.utd as u64
    }

    /// The spec of `run.env` built with `[env_options]` (options may change its sizes).
    pub fn env_spec(&self) -> Result<selkd_envs::EnvSpec, selkd_envs::EnvError> {
        selkd_envs::make_with(&self.run.env, &self.env_options).map(|e| e.spec().clone())
    }
}

/// Most evaluation episodes per actor per epoch (`eval.episodes`).
pub const MAX_EVAL_EPISODES: usize = 1000;

/// What [`Config::memory_estimate`] counts, in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryEstimate {
    pub replay: u64,
    pub networks: u64,
}

impl MemoryEstimate {
    pub fn total(&self) -> u64 {
        self.replay.saturating_add(self.networks)
    }
}

/// This machine's physical memory (`MemTotal` of /proc/meminfo), if it can be read. Physical, not
/// what is free now: a run that fits the machine may wait for memory others hold, one that does
/// not fit can never run.
pub fn physical_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb: u64 = text
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))?
        .trim()
        .strip_suffix("kB")?
        .trim()
        .parse()
        .ok()?;
    Some(kb.saturating_mul(1024))
}

/// Bytes for people: `36.0 TB`, `512.0 MB`.
pub fn bytes(n: u64) -> String {
    let units = ["B", "kB", "MB", "GB", "TB", "PB", "EB"];
    let mut v = n as f64;
    let mut i = 0;
    while v >= 1000.0 && i + 1 < units.len() {
        v /= 1000.0;
        i += 1;
    }
    if i == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", units[i])
    }
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// An override of one budget key restates the budget: it replaces the other key from the config
/// file (`--set run.total_rounds=20000` on a config that sets `total_env_steps`, or a raised
/// `run.total_env_steps` on a resumed rounds run). Overrides that set both are a mistake.
fn restate_budget(table: &mut toml::Table, overrides: &[String]) -> Result<(), ConfigError> {
    let set = |key: &str| -> Option<&str> {
        overrides.iter().rev().find_map(|o| {
            let (k, v) = o.split_once('=')?;
            (k.trim() == key).then_some(v.trim())
        })
    };
    let (steps, rounds) = (set("run.total_env_steps"), set("run.total_rounds"));
    let rounds_unset = rounds.is_some_and(|v| v == "0");
    let run = table.get_mut("run").and_then(|r| r.as_table_mut());
    match (steps, rounds, run) {
        (Some(s), Some(r), _) if !rounds_unset => Err(ConfigError::Invalid(format!(
            "--set run.total_env_steps={s} and --set run.total_rounds={r} both set the budget; set only one (rounds = env steps / K)"
        ))),
        (Some(_), None, Some(run)) => {
            run.remove("total_rounds");
            Ok(())
        }
        (None, Some(_), Some(run)) if !rounds_unset => {
            run.remove("total_env_steps");
            Ok(())
        }
        _ => Ok(()),
    }
}

/// `section.key=value`; the value is read as TOML (number, bool, array) or else as a string.
fn apply_override(table: &mut toml::Table, item: &str) -> Result<(), ConfigError> {
    let (key, raw) = item.split_once('=').ok_or_else(|| {
        ConfigError::Invalid(format!(
            "--set {item}: expected key=value, e.g. --set algo.critics=4"
        ))
    })?;
    let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let parts: Vec<&str> = key.trim().split('.').collect();
    let (last, path) = parts.split_last().unwrap();
    let mut cur = table;
    for p in path {
        cur = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(Default::default()))
            .as_table_mut()
            .ok_or_else(|| ConfigError::Invalid(format!("--set {item}: `{p}` is not a section")))?;
    }
    cur.insert(last.to_string(), value);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str, sets: &[&str]) -> String {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        Config::from_toml_with_overrides(text, &sets)
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn defaults_are_the_papers_table_1_and_valid() {
        let c = Config::from_toml_with_overrides("", &[]).unwrap();
        assert_eq!(
            (
                c.algo.actors,
                c.algo.critics,
                c.algo.subset,
                c.algo.utd,
                c.algo.batch_size
            ),
            (5, 10, 2, 20, 256)
        );
        assert_eq!(
            (
                c.algo.lr,
                c.algo.gamma,
                c.algo.polyak,
                c.algo.replay_capacity
            ),
            (3e-4, 0.99, 0.995, 100_000)
        );
        let back = Config::from_toml_with_overrides(&c.to_toml(), &[]).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn bad_values_get_one_line_errors_naming_the_key() {
        assert!(err("", &["algo.subset=11"]).contains("algo.subset"));
        assert!(err("", &["algo.actors=0"]).contains("algo.actors"));
        for u in ["0", "21"] {
            assert!(err("", &[&format!("algo.actor_updates_per_round={u}")])
                .contains("must be between 1 and algo.utd (G = 20)"));
        }
        assert!(err("", &["run.env=walker"]).contains("pendulum"));
        assert!(err("", &["algo.batch_size=-3"]).contains("batch_size"));
        assert!(err("[algo]\ncritcs = 3\n", &[]).contains("critcs"));
        assert!(err("", &["algo.target=\"max-median\""]).contains("max-min"));
        assert!(err("", &["nonsense"]).contains("key=value"));
        assert!(err("", &["algo.target=\"max-aqe\"", "algo.aqe_drop=2"]).contains("algo.aqe_drop"));
        for k in ["0", "11"] {
            let e = err("", &[&format!("algo.trained_critics={k}")]);
            assert!(
                e.contains(&format!(
                    "algo.trained_critics (k = {k}) must be between 1 and algo.critics (N = 10)"
                )),
                "{e}"
            );
        }
        let e = err(
            "",
            &["algo.trained_critics=3", "algo.sharing=\"per-critic\""],
        );
        assert!(e.contains("per-update"), "{e}");
        // AVTD: one acting actor, and nothing that changes which critics an actor owns.
        let avtd = "algo.variants=[\"none\", \"layer-norm\"]";
        for (extra, says) in [
            ("algo.actors=2", "algo.actors = 1"),
            ("algo.trained_critics=2", "trained_critics"),
            ("algo.validation_every=1", "at least 2"),
            ("algo.weight_decay=-1", "algo.weight_decay"),
        ] {
            let e = err("", &[avtd, "algo.actors=1", extra]);
            assert!(e.contains(says) && !e.contains('\n'), "{extra}: {e}");
        }
        let e = err("", &["algo.actors=1", "algo.variants=[\"dropout\"]"]);
        assert!(e.contains("dropout") && e.contains("layer-norm"), "{e}");
        Config::from_toml_with_overrides("", &[avtd.to_string(), "algo.actors=1".to_string()])
            .unwrap();
        let e = err("", &["env_options.gravity=3"]);
        assert!(
            e.contains("env_options for `pendulum`") && e.contains("gravity"),
            "{e}"
        );
        let e = err("", &["run.env=hopper", "env_options.g=3"]);
        assert!(
            e.contains("`hopper`") && e.contains("unknown field `g`"),
            "{e}"
        );
        for e in [
            err("", &["algo.subset=11"]),
            err("[algo]\ncritcs = 3\n", &[]),
            err("", &["env_options.gravity=3"]),
        ] {
            assert!(!e.contains('\n'), "one line: {e}");
        }
    }

    #[test]
    fn a_run_dir_mode_is_octal_keeps_the_owners_access_and_is_applied_despite_the_umask() {
        use std::os::unix::fs::PermissionsExt;
        let mode = |s: &str| {
            Config::from_toml_with_overrides("", &[format!("run.dir_mode=\"{s}\"")])
                .map(|c| c.run.dir_mode.0)
        };
        assert_eq!(Config::default().run.dir_mode.0, 0o700);
        assert_eq!(mode("0700").unwrap(), 448);
        assert_eq!(mode("0750").unwrap(), 488);
        assert_eq!(mode("755").unwrap(), 493);
        for (bad, says) in [
            ("0600", "owner needs rwx"),
            ("0500", "owner needs rwx"),
            ("0800", "not an octal mode"),
            ("1777", "not an octal mode"),
            ("rwx", "not an octal mode"),
        ] {
            let e = mode(bad).unwrap_err().to_string();
            assert!(e.contains(says) && !e.contains('\n'), "{bad}: {e}");
        }
        let c = Config::from_toml_with_overrides("", &["run.dir_mode=\"0750\"".into()]).unwrap();
        assert!(
            c.to_toml().contains("dir_mode = \"0750\""),
            "{}",
            c.to_toml()
        );
        let root = std::env::temp_dir().join(format!("selkd-dir-mode-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        // A umask that would leave group and others write access must not matter.
        let old = unsafe { libc::umask(0) };
        let made = create_run_dir(&root.join("a/run"), DirMode(0o700));
        unsafe { libc::umask(old) };
        made.unwrap();
        let bits = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(bits(&root.join("a/run")), 0o700);
        // An existing directory keeps what its owner chose.
        std::fs::set_permissions(&root.join("a/run"), std::fs::Permissions::from_mode(0o755))
            .unwrap();
        create_run_dir(&root.join("a/run"), DirMode(0o700)).unwrap();
        assert_eq!(bits(&root.join("a/run")), 0o755);
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn every_shipped_config_is_valid() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let mut seen = 0;
        for dir in [root.clone(), root.join("baselines")] {
            for entry in std::fs::read_dir(dir).unwrap() {
                let path = entry.unwrap().path();
                if path.extension().is_some_and(|e| e == "toml") {
                    let text = std::fs::read_to_string(&path).unwrap();
                    Config::from_toml_with_overrides(&text, &[])
                        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                    seen += 1;
                }
            }
        }
        assert!(seen >= 10, "found {seen} configs");
    }

    /// Counted by hand: the paper's 300 000 env steps over K = 5 actors are 60 000 rounds, 1 000 of
    /// them (5 000 env steps) warm-up; the 1 000th round, whose transitions complete the warm-up,
    /// trains, and so does every later one: (60 000 − 1 000 + 1) × G = 20. A budget inside the
    /// warm-up makes none. (The end-to-end test `budgets_in_rounds_and_env_steps_…` checks such a
    /// count against a real run's metrics.csv.)
    #[test]
    fn the_budget_counts_g_updates_per_round_past_the_warm_up() {
        let budget = |sets: &[&str]| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            Config::from_toml_with_overrides("", &sets)
                .unwrap()
                .critic_updates_in_budget()
        };
        let paper = [
            "run.total_env_steps=300000",
            "algo.actors=5",
            "algo.utd=20",
            "algo.warmup_steps=5000",
        ];
        assert_eq!(budget(&paper), 1_180_020);
        // K = 3: 12 000 / 3 = 4 000 rounds, training from round 500 (1 500 / 3): 3 501 × 3.
        assert_eq!(
            budget(&[
                "run.total_env_steps=12000",
                "algo.actors=3",
                "algo.utd=3",
                "algo.warmup_steps=1500",
                "algo.batch_size=128",
            ]),
            10_503
        );
        // Uneven shares round up: 1 001 env steps over 2 actors are 501 each, warm-up 300 → 150:
        // rounds 150 to 501.
        assert_eq!(
            budget(&[
                "run.total_env_steps=1001",
                "algo.actors=2",
                "algo.utd=1",
                "algo.warmup_steps=300",
            ]),
            352
        );
        assert_eq!(
            budget(&["run.total_env_steps=4000", "algo.warmup_steps=5000"]),
            0
        );
    }

    /// Counted by hand: a rounds budget is each actor's step count, so it gives the same critic
    /// updates as the env-step budget of rounds × K, and K = 1 makes the two units equal.
    #[test]
    fn a_budget_in_rounds_is_env_steps_times_k_with_the_same_critic_updates() {
        let cfg = |sets: &[&str]| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            Config::from_toml_with_overrides("", &sets).unwrap()
        };
        // The paper's 60 000 rounds of K = 5: 300 000 env steps; 1 000 rounds of warm-up;
        // (60 000 − 1 000 + 1) × 20 = 1 180 020, as the env-step budget of 300 000 above.
        let c = cfg(&[
            "run.total_rounds=60000",
            "algo.actors=5",
            "algo.utd=20",
            "algo.warmup_steps=5000",
        ]);
        assert_eq!(c.run.total_env_steps, 300_000);
        assert_eq!(c.steps_per_actor(), 60_000);
        assert_eq!(c.critic_updates_in_budget(), 1_180_020);
        assert_eq!(c.budget_unit(), "rounds");
        // K = 3, 4 000 rounds: 12 000 env steps; warm-up 1 500 / 3 = 500 rounds; 3 501 × 3.
        let c = cfg(&[
            "run.total_rounds=4000",
            "algo.actors=3",
            "algo.utd=3",
            "algo.warmup_steps=1500",
            "algo.batch_size=128",
        ]);
        assert_eq!(
            (c.run.total_env_steps, c.critic_updates_in_budget()),
            (12_000, 10_503)
        );
        // K = 2, warm-up 301 env steps rounds up to 151 rounds: (400 − 151 + 1) × 2 = 500.
        let c = cfg(&[
            "run.total_rounds=400",
            "algo.actors=2",
            "algo.utd=2",
            "algo.warmup_steps=301",
        ]);
        assert_eq!(
            (c.run.total_env_steps, c.critic_updates_in_budget()),
            (800, 500)
        );
        // K = 1: rounds are env steps; warm-up 5 000: (7 000 − 5 000 + 1) × 20.
        let c = cfg(&["run.total_rounds=7000", "algo.actors=1", "algo.utd=20"]);
        assert_eq!(
            (c.run.total_env_steps, c.critic_updates_in_budget()),
            (7_000, 40_020)
        );
        // The written config states both, reads back equal, and a config without the key
        // (written before it existed) has no `total_rounds` line at all.
        let c = cfg(&["run.total_rounds=2000", "algo.actors=5"]);
        let text = c.to_toml();
        assert!(
            text.contains("total_rounds = 2000") && text.contains("total_env_steps = 10000"),
            "{text}"
        );
        assert_eq!(Config::from_toml_with_overrides(&text, &[]).unwrap(), c);
        assert!(!Config::default().to_toml().contains("total_rounds"));
        // Resuming it with a raised env-step budget restates the budget in env steps, and the
        // other way round.
        let raised =
            Config::from_toml_with_overrides(&text, &["run.total_env_steps=20000".into()]).unwrap();
        assert_eq!(
            (raised.run.total_env_steps, raised.run.total_rounds),
            (20_000, 0)
        );
        let file = "[run]\ntotal_env_steps = 50000\n";
        let r = Config::from_toml_with_overrides(file, &["run.total_rounds=3000".into()]).unwrap();
        assert_eq!((r.run.total_env_steps, r.run.total_rounds), (15_000, 3000));
        // 0 unsets it.
        let r = Config::from_toml_with_overrides(&text, &["run.total_rounds=0".into()]).unwrap();
        assert_eq!((r.run.total_env_steps, r.run.total_rounds), (10_000, 0));
    }

    #[test]
    fn two_budgets_or_a_rounds_budget_inside_the_warm_up_are_one_line_errors() {
        let e = err("[run]\ntotal_env_steps = 50000\ntotal_rounds = 2000\n", &[]);
        assert!(
            e.contains("run.total_env_steps = 50000")
                && e.contains("run.total_rounds = 2000")
                && e.contains("10000 env steps")
                && e.contains("set only one")
                && !e.contains('\n'),
            "{e}"
        );
        let e = err("", &["run.total_env_steps=5000", "run.total_rounds=1000"]);
        assert!(
            e.contains("run.total_env_steps=5000")
                && e.contains("run.total_rounds=1000")
                && !e.contains('\n'),
            "{e}"
        );
        // 5 000 warm-up env steps over K = 5 are 1 000 rounds: 999 rounds do nothing (the
        // 1 000th, which completes the warm-up, trains).
        let e = err("", &["run.total_rounds=999", "algo.warmup_steps=5000"]);
        assert!(
            e.contains("run.total_rounds = 999")
                && e.contains("1000 rounds")
                && e.contains("raise run.total_rounds to at least 1000")
                && !e.contains('\n'),
            "{e}"
        );
        Config::from_toml_with_overrides(
            "",
            &[
                "run.total_rounds=1000".into(),
                "algo.warmup_steps=5000".into(),
            ],
        )
        .unwrap();
        let e = err("", &["run.total_rounds=9223372036854775807"]);
        assert!(e.contains("overflows"), "{e}");
    }

    /// Counted by hand for Pendulum (obs 3, act 1), hidden [8], K = 2, N = 3, 100 replay rows:
    /// an actor is 3·8+8 + 8·2+2 = 50 parameters, ×2 actors ×4 (value, gradient, m, v) = 400,
    /// plus log α 2×4 = 8; a critic is 4·8+8 + 8·1+1 = 49, ×3 critics ×5 (and the target) = 735;
    /// a row is 3+1+1+3+1 = 9 floats, ×100 = 900. Floats are 4 bytes.
    #[test]
    fn the_memory_estimate_counts_replay_networks_and_adam_state() {
        let c = Config::from_toml_with_overrides(
            "",
            &[
                "algo.hidden=[8]",
                "algo.actors=2",
                "algo.critics=3",
                "algo.replay_capacity=100",
                "algo.batch_size=10",
                "algo.warmup_steps=10",
            ]
            .map(String::from),
        )
        .unwrap();
        let m = c.memory_estimate().unwrap();
        assert_eq!(m.replay, 900 * 4);
        assert_eq!(m.networks, (400 + 8 + 735) * 4);
        assert!(c.check_memory(m.total()).is_ok());
        let e = c.check_memory(m.total() - 1).unwrap_err().to_string();
        // 4 572 bytes of networks outweigh 3 600 of replay: the networks' keys are named.
        assert!(
            e.contains("needs at least 8.2 kB")
                && e.contains("algo.hidden = [8]")
                && e.contains("take 4.6 kB"),
            "{e}"
        );
    }

    #[test]
    fn configs_the_machine_cannot_hold_are_refused_naming_the_key() {
        // 1e12 rows of 9 floats: 36 TB of replay.
        let e = err("", &["algo.replay_capacity=1000000000000"]);
        assert!(
            e.contains("algo.replay_capacity = 1000000000000 takes 36.0 TB"),
            "{e}"
        );
        // Ten critics of 65536² weights are 172 GB each with their Adam state.
        let e = err("", &["algo.hidden=[65536, 65536]"]);
        assert!(
            e.contains("algo.hidden = [65536, 65536]") && !e.contains('\n'),
            "{e}"
        );
        let e = err("", &["eval.episodes=1000000000"]);
        assert!(e.contains("eval.episodes = 1000000000"), "{e}");
    }

    /// The method keys of every shipped baseline make the method they name, and a config
    /// writes them back as the same keys (config.toml, state.json), so files and checkpoints of
    /// earlier versions read the same.
    #[test]
    fn td3_noise_keys_belong_to_the_td3_backbone() {
        let read = |sets: &[&str]| {
            Config::from_toml_with_overrides(
                "",
                &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
            )
        };
        let td3 = read(&[
            "algo.backbone=\"td3\"",
            "algo.exploration_noise=0.3",
            "algo.target_noise=0.4",
            "algo.target_noise_clip=0.6",
        ])
        .unwrap();
        assert_eq!(
            td3.algo.backbone,
            Backbone::Td3 {
                exploration_noise: 0.3,
                target_noise: 0.4,
                target_noise_clip: 0.6
            }
        );
        assert_eq!(td3.algo.backbone.exploration_noise(), 0.3);
        let written: toml::Table = toml::from_str(&td3.to_toml()).unwrap();
        for (k, v) in [
            ("exploration_noise", 0.3),
            ("target_noise", 0.4),
            ("target_noise_clip", 0.6),
        ] {
            assert_eq!(written["algo"][k].as_float(), Some(v), "algo.{k}");
        }
        assert_eq!(written["algo"]["backbone"].as_str(), Some("td3"));
        assert_eq!(
            Config::from_toml_with_overrides(&td3.to_toml(), &[]).unwrap(),
            td3
        );
        // The keys' defaults are Fujimoto et al.'s.
        assert_eq!(
            read(&["algo.backbone=\"td3\""]).unwrap().algo.backbone,
            Backbone::TD3
        );
        assert_eq!(
            Backbone::TD3,
            Backbone::Td3 {
                exploration_noise: 0.1,
                target_noise: 0.2,
                target_noise_clip: 0.5
            }
        );
        // SAC samples its exploration: no noise, whatever the (TD3-only) keys say.
        let sac = read(&["algo.exploration_noise=0.3"]).unwrap();
        assert_eq!(sac.algo.backbone, Backbone::Sac);
        assert_eq!(sac.algo.backbone.exploration_noise(), 0.0);
        let err = read(&["algo.backbone=\"td3\"", "algo.target_noise=-1"])
            .unwrap_err()
            .to_string();
        assert!(err.contains("algo.target_noise = -1 must be ≥ 0"), "{err}");
    }

    #[test]
    fn method_keys_make_one_method_and_are_written_back_unchanged() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/baselines");
        let read = |name: &str| {
            let text = std::fs::read_to_string(root.join(name)).unwrap();
            Config::from_toml_with_overrides(&text, &[]).unwrap()
        };
        let selkd = |d: Distillation| Method::Selkd {
            target: Formation::MaxMin,
            aqe_drop: 1,
            sharing: Sharing::PerUpdate,
            distillation: d,
        };
        for (file, method) in [
            ("redq.toml", selkd(Distillation::default())),
            (
                "selkd-without-kd.toml",
                selkd(Distillation {
                    kd_actors: Some(vec![0]),
                    without_rl: false,
                }),
            ),
            (
                "selkd-without-rl.toml",
                selkd(Distillation {
                    kd_actors: None,
                    without_rl: true,
                }),
            ),
            ("aqe.toml", Method::selkd(Formation::MaxAqe)),
            (
                "dns.toml",
                Method::Dns {
                    target: Formation::MaxMin,
                    aqe_drop: 1,
                    trained_critics: 3,
                    distillation: Distillation::default(),
                },
            ),
            ("dpd.toml", Method::Dpd { without_rl: false }),
            (
                "avtd.toml",
                Method::Avtd {
                    variants: vec![
                        Regulariser::None,
                        Regulariser::LayerNorm,
                        Regulariser::WeightDecay,
                    ],
                    validation_every: 10,
                    weight_decay: 1e-4,
                },
            ),
        ] {
            let c = read(file);
            assert_eq!(c.algo.method, method, "{file}");
            // The written config states the file's own keys and reads back equal.
            let text = c.to_toml();
            let file_keys: toml::Table =
                toml::from_str(&std::fs::read_to_string(root.join(file)).unwrap()).unwrap();
            let written: toml::Table = toml::from_str(&text).unwrap();
            for (k, v) in file_keys["algo"].as_table().unwrap() {
                assert_eq!(written["algo"].get(k), Some(v), "{file}: algo.{k}");
            }
            assert_eq!(Config::from_toml_with_overrides(&text, &[]).unwrap(), c);
            let json = serde_json::to_string(&c).unwrap();
            assert_eq!(serde_json::from_str::<Config>(&json).unwrap(), c, "{file}");
        }
        // DPD with w/o RL is a combination the keys have always allowed.
        let c = Config::from_toml_with_overrides(
            "",
            &[
                "algo.paired_critics=true",
                "algo.without_rl=true",
                "algo.actors=2",
                "algo.critics=4",
            ]
            .map(String::from),
        )
        .unwrap();
        assert_eq!(c.algo.method, Method::Dpd { without_rl: true });
        // Combinations no method has are one-line config errors naming the keys.
        for (sets, says) in [
            (
                &["algo.paired_critics=true", "algo.sharing=\"per-critic\""][..],
                "algo.paired_critics needs",
            ),
            (
                &["algo.paired_critics=true", "algo.kd_actors=[0]", "algo.actors=2", "algo.critics=4"][..],
                "algo.kd_actors cannot be combined with algo.paired_critics",
            ),
            (
                &["algo.paired_critics=true", "algo.actors=3", "algo.critics=4"][..],
                "algo.paired_critics needs at least 2 actors, algo.critics (4) a multiple of algo.actors (3)",
            ),
            (
                &["algo.variants=[\"none\"]", "algo.actors=1", "algo.without_rl=true"][..],
                "algo.variants (AVTD)",
            ),
        ] {
            let e = err("", sets);
            assert!(
                e.starts_with("config: ")
                    && !e.contains("cannot parse")
                    && e.contains(says)
                    && !e.contains('\n'),
                "{sets:?}: {e}"
            );
        }
    }

    #[test]
    fn overrides_parse_numbers_lists_and_strings() {
        let sets = [
            "algo.hidden=[64, 64]",
            "run.mode=async",
            "algo.kd_weight=0.5",
            "algo.sharing=per-critic",
        ]
        .map(String::from);
        let c = Config::from_toml_with_overrides("", &sets).unwrap();
        assert_eq!(c.algo.hidden, vec![64, 64]);
        assert_eq!(c.run.mode, Mode::Async);
        assert_eq!(c.algo.kd_weight, 0.5);
        assert_eq!(c.algo.method.sharing(), Sharing::PerCritic);
    }
}
