//! One line of documentation for every config key: the single source that `selkd config` prints
//! beside each value (a unit test checks that every key of [`super::Config`] has one).

/// `(key, doc)` in the order `selkd config` prints them, sections as in a config file.
pub const KEY_DOCS: &[(&str, &str)] = &[
    ("run.env", "env registry name: pendulum, hopper, walker2d, halfcheetah, ant, ant-contacts, humanoid, fpc-assembly (or a Gymnasium alias such as Hopper-v5), or gymnasium:<id> for any Gymnasium env (gymnasium:Hopper-v5 is Gymnasium's own MuJoCo task)"),
    ("run.seed", "seeds the networks, the learner's sampling and every worker's env and actions"),
    ("run.total_env_steps", "budget: transitions of all actors together (K = 5 at 300000 is 60000 per actor); set from run.total_rounds when that is set"),
    ("run.total_rounds", "budget in rounds instead (Algorithm 1's time-steps: each of the K actors takes one step; env steps = rounds × K); unset or 0: run.total_env_steps is the budget; set only one"),
    ("run.mode", "sync: Algorithm 1's lockstep rounds, reproducible on CPU; async: workers step freely, the learner holds G updates per K transitions"),
    ("run.device", "the learner's device: cpu, cuda or cuda:N"),
    ("run.threads", "threads for the learner (0 = one per core): its critics' members split over them, libtorch on one each"),
    ("run.cpu_gemm", "who multiplies the critics' fp32 matrices on CPU: auto (libtorch's MKL on Intel CPUs, the gemm crate on others, where MKL is slower), libtorch, gemm"),
    ("run.checkpoint_every", "env steps between checkpoints (0 = only the final one)"),
    ("run.checkpoint_replay", "also store the replay buffer, so a resumed run trains on the data it had"),
    ("run.keep_checkpoints", "periodic checkpoints kept, the newest (final is always kept)"),
    ("run.worker_timeout", "seconds a worker the run waits on may send nothing before it is killed and restarted"),
    ("run.dir_mode", "permissions of a run directory the run creates, octal: \"0700\" (only its owner: checkpoints are data) or e.g. \"0750\""),
    ("algo.backbone", "sac (stochastic actors, entropy bonus, KL distillation) or td3 (deterministic actors, squared action distance)"),
    ("algo.exploration_noise", "td3: std of the Gaussian noise on the workers' actions"),
    ("algo.target_noise", "td3: std of the target policy smoothing noise"),
    ("algo.target_noise_clip", "td3: the smoothing noise is clipped to ± this"),
    ("algo.actors", "K, the number of actors"),
    ("algo.critics", "N, the number of critics"),
    ("algo.subset", "M, the size of the random critic subset in the target"),
    ("algo.utd", "G, critic updates per round (per K transitions)"),
    ("algo.actor_updates_per_round", "U: updates of every actor and temperature per round; 1 is Algorithm 1, U > 1 (at most G) a departure: an actor update after each of the last U critic updates"),
    ("algo.batch_size", "mini-batch size of every update"),
    ("algo.hidden", "hidden layer sizes of every actor and critic MLP"),
    ("algo.lr", "Adam learning rate of actors and critics"),
    ("algo.gamma", "discount γ"),
    ("algo.polyak", "ρ in Q̄ ← ρ Q̄ + (1 − ρ) Q, after every critic update"),
    ("algo.replay_capacity", "transitions the shared FIFO replay buffer holds"),
    ("algo.warmup_steps", "uniform-random transitions (all actors together) before the first update"),
    ("algo.target", "target formation, outer over actors and inner over the subset: max-min (SELKD), min-min, min-max, max-max, max-mean, max-rem, max-aqe (SELKD and DNS; DPD and AVTD have their own)"),
    ("algo.sharing", "per-update: one batch and subset for all N critics (REDQ); per-critic: one each (Algorithm 1, N× the cost; SELKD only)"),
    ("algo.kd_weight", "λ_KD, the weight of the distillation term toward the best actor"),
    ("algo.paired_critics", "the method DPD: actor i owns N/K critics and distils toward actor i+1"),
    ("algo.without_rl", "ablation w/o RL (SELKD, DNS, DPD): only actor 0 optimises the RL objective, the others only distil"),
    ("algo.kd_actors", "which actors (0-based) have the distillation term; unset: all (w/o KD sets [0]; SELKD and DNS)"),
    ("algo.actor_q", "the actor objective's reduction over the critics: mean (SELKD, REDQ) or min (SAC)"),
    ("algo.aqe_drop", "max-aqe (SELKD, DNS): how many of the highest subset values AQE drops"),
    ("algo.fixed_alpha", "a fixed temperature α; unset: tuned automatically per actor"),
    ("algo.alpha_lr", "Adam learning rate of the temperatures"),
    ("algo.target_entropy", "target entropy of the automatic temperature; unset: −|A|"),
    ("algo.trained_critics", "the method DNS: critics trained per update (k), drawn by a k-DPP over their similarity on the batch; absent: all N"),
    ("algo.variants", "the method AVTD: the regularisation variants trained side by side (none, layer-norm, weight-decay), each with its own actor and N critics; the one with the lowest validation TD error acts; empty: no AVTD"),
    ("algo.validation_every", "AVTD: every n-th transition is held out for validation and never trained on"),
    ("algo.weight_decay", "AVTD's weight-decay variant: c in ½ c ‖W‖² on each critic's weights"),
    ("algo.critic_matmul", "element type of the critics' matmuls: fp32, or bf16 (fast only on CPUs/GPUs with native bf16)"),
    ("eval.epoch_env_steps", "env steps (all actors together) per epoch; every actor is evaluated after each"),
    ("eval.episodes", "deterministic evaluation episodes per actor per epoch"),
    ("eval.score_window", "before its first evaluation an actor's score is the mean of this many latest training episodes"),
    ("async.ratio_tolerance", "async: critic updates the workers may run ahead of or behind G per K transitions"),
    ("async.max_policy_lag", "async: weight versions a worker's behaviour policy may lag"),
    ("env_options", "the env's own options (checked by the env; unknown keys are errors), e.g. env_options.g = 9.81 for Pendulum"),
];

/// The doc of `key` (`section.name`, or `env_options`).
pub fn doc(key: &str) -> Option<&'static str> {
    KEY_DOCS.iter().find(|(k, _)| *k == key).map(|(_, d)| *d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    /// Every key a `Config` serialises to (optional keys filled in so that they appear), as
    /// `section.key`; `env_options` counts as one key.
    fn config_keys() -> Vec<String> {
        let mut c = Config::default();
        c.algo.method = crate::config::Method::Dns {
            target: crate::targets::Formation::MaxMin,
            aqe_drop: 1,
            trained_critics: 3,
            distillation: crate::config::Distillation {
                kd_actors: Some(vec![0]),
                without_rl: false,
            },
        };
        c.algo.fixed_alpha = Some(0.1);
        c.algo.target_entropy = Some(-1.0);
        c.run.total_rounds = 1000;
        let table: toml::Table = toml::from_str(&c.to_toml()).unwrap();
        let mut keys = vec![];
        for (section, v) in &table {
            match v.as_table() {
                Some(t) if section != "env_options" => {
                    keys.extend(t.keys().map(|k| format!("{section}.{k}")))
                }
                _ => keys.push(section.clone()),
            }
        }
        keys
    }

    #[test]
    fn every_config_key_has_a_doc_and_every_doc_a_key() {
        let keys = config_keys();
        assert!(keys.len() > 40, "{keys:?}");
        for k in &keys {
            assert!(doc(k).is_some(), "config key {k} has no line in KEY_DOCS");
        }
        for (k, d) in KEY_DOCS {
            assert!(
                keys.contains(&k.to_string()),
                "KEY_DOCS names {k}, which Config does not have"
            );
            assert!(!d.is_empty() && !d.contains('\n'), "{k}: one line");
        }
        let mut unique: Vec<&str> = KEY_DOCS.iter().map(|(k, _)| *k).collect();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), KEY_DOCS.len(), "a key documented twice");
    }
}
