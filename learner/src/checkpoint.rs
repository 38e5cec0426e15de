//! Checkpoints: a directory holding `model.safetensors` (actors, critics, target critics, log α,
//! and the Adam moments, all named so other tools can load them), `state.json` (step counters,
//! the learner's RNG state, the ranking, the config) and optionally `replay.safetensors` (the
//! replay buffer's rows, and AVTD's held-out validation rows).
//!
//! Actor tensors are stacked `[K, in, out]` / `[K, 1, out]`; actor i's layer l is
//! `actors.{l}.weight[i]`, its output splits into μ (first half) and log σ (second half).

use crate::config::Config;
use crate::ranking::Ranking;
use crate::replay::ReplayBuffer;
use crate::rollout::{Pending, Rollout};
use crate::selkd::{RoundStats, Selkd};
use anyhow::{bail, Context, Result};
use selkd_envs::EnvRecord;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;
use tch::Tensor;

/// Everything besides tensors that a resumed run needs.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainingState {
    pub config: Config,
    pub rng: rand_pcg::Pcg64,
    pub critic_updates: u64,
    pub actor_updates: u64,
    pub adam_steps: [i64; 3],
    /// DNS: each critic's own Adam step count (its optimiser steps only when it is trained).
    #[serde(default)]
    pub critic_member_steps: Vec<i64>,
    /// Transitions received from each actor.
    pub received: Vec<u64>,
    /// Where each actor's rollout stands: the resumed run's workers continue from it exactly.
    /// (Absent in older checkpoints: their workers start new episodes.)
    #[serde(default)]
    pub rollouts: Vec<Rollout>,
    /// Sync mode: transitions received but not yet stored (their round was incomplete).
    #[serde(default)]
    pub pending: Vec<Vec<Pending>>,
    /// What the last round measured: the next metrics row reports it.
    #[serde(default)]
    pub last_round: Option<LastRound>,
    /// Transitions dropped so far: non-finite, malformed, stale.
    #[serde(default)]
    pub dropped: [u64; 3],
    /// Policy lag of the transitions received so far: sum, count, max.
    #[serde(default)]
    pub policy_lag: (f64, u64, u64),
    /// Transitions stored, all actors.
    pub inserted: u64,
    /// Sync mode: completed lockstep rounds (steps per actor).
    pub lockstep_rounds: u64,
    pub weights_version: u64,
    pub eval_epoch: u64,
    /// Epochs whose metrics row is written; later epochs up to `eval_epoch` had their evaluation
    /// in flight, and a resumed run asks for it again. (Absent in older checkpoints: then
    /// `eval_epoch`.)
    #[serde(default)]
    pub epochs_logged: Option<u64>,
    /// Env steps (all actors) at which each epoch after `epochs_logged` ended.
    #[serde(default)]
    pub epoch_ends: Vec<(u64, u64)>,
    pub ranking: Ranking,
    pub wall_seconds: f64,
    /// AVTD: the variant that acts (actor `selected_variant` of the stacked actors).
    #[serde(default)]
    pub selected_variant: usize,
    /// The env the run trained on, stretch by stretch: one entry from its start, another for
    /// each resume that accepted a changed env (`--accept-env-change`). (Absent in checkpoints
    /// from before the records: the first resume records the env from then on.)
    #[serde(default)]
    pub env: Vec<EnvStretch>,
}

/// From which env step (all actors) a run trained on `record`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvStretch {
    pub from_env_step: u64,
    pub record: EnvRecord,
}

/// The env history a run resumed from `state` goes on with, given this build's record `now`
/// of its env, and a line to say where that history gained an entry. A record that differs from
/// the checkpoint's last is an error unless `accept_change`: a run trained on one physics and
/// continued on another mixes two tasks in one curve.
pub fn continue_env_history(
    state: &TrainingState,
    now: &EnvRecord,
    accept_change: bool,
) -> Result<(Vec<EnvStretch>, Option<String>)> {
    let mut history = state.env.clone();
    let stretch = EnvStretch {
        from_env_step: state.inserted,
        record: now.clone(),
    };
    let Some(last) = history.last() else {
        history.push(stretch);
        return Ok((
            history,
            Some(format!(
                "the checkpoint records no env (it predates env records); this build's env is recorded from {} env steps on",
                state.inserted
            )),
        ));
    };
    let changed = last.record.differences(now);
    if changed.is_empty() {
        return Ok((history, None));
    }
    let what = changed.join("; ");
    if !accept_change {
        bail!(
            "this build's env `{}` is not the one the run trained on since {} env steps ({what}): resume it with the build that began it, start a new run directory, or pass --accept-env-change to continue on this env (recorded in the checkpoints)",
            now.env,
            last.from_env_step
        );
    }
    history.push(stretch);
    Ok((
        history,
        Some(format!(
            "the env changed at {} env steps, accepted ({what})",
            state.inserted
        )),
    ))
}

/// [`RoundStats`] in JSON, which has no NaN (`None` stands for it).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LastRound {
    critic_loss: Option<f64>,
    q_mean: Option<f64>,
    actor_loss: Vec<Option<f64>>,
    alpha: Vec<Option<f64>>,
    kl_to_best: Vec<Option<f64>>,
    entropy: Vec<Option<f64>>,
}

impl From<&RoundStats> for LastRound {
    fn from(s: &RoundStats) -> Self {
        // Rounds are only kept when finite (a diverged one ends the run), so None is NaN.
        let o = |v: f64| v.is_finite().then_some(v);
        let all = |v: &[f64]| v.iter().map(|&x| o(x)).collect();
        Self {
            critic_loss: o(s.critic_loss),
            q_mean: o(s.q_mean),
            actor_loss: all(&s.actor_loss),
            alpha: all(&s.alpha),
            kl_to_best: all(&s.kl_to_best),
            entropy: all(&s.entropy),
        }
    }
}

impl From<&LastRound> for RoundStats {
    fn from(r: &LastRound) -> Self {
        let f = |v: Option<f64>| v.unwrap_or(f64::NAN);
        let all = |v: &[Option<f64>]| v.iter().map(|&x| f(x)).collect();
        Self {
            critic_loss: f(r.critic_loss),
            q_mean: f(r.q_mean),
            actor_loss: all(&r.actor_loss),
            alpha: all(&r.alpha),
            kl_to_best: all(&r.kl_to_best),
            entropy: all(&r.entropy),
        }
    }
}

impl TrainingState {
    /// The actor that represents the run: the best by the ranking, or for AVTD the selected
    /// variant's (its actors are the variants, of which one acts).
    pub fn best_actor(&self) -> usize {
        if self.config.algo.method.variants().is_empty() {
            self.ranking.best()
        } else {
            self.selected_variant
        }
    }

    /// Actor `index`'s score by the ranking, if it has one yet. The ranking scores the acting
    /// actors; AVTD's only acting actor is its selected variant, so only that one has a score.
    pub fn score_of(&self, index: usize) -> Option<f64> {
        let scores = self.ranking.scores();
        if self.config.algo.method.variants().is_empty() {
            scores.get(index).copied().flatten()
        } else {
            (index == self.selected_variant)
                .then(|| scores[0])
                .flatten()
        }
    }

    /// Each actor's rollout record; for a checkpoint without one, fresh episodes numbered far
    /// from any the run had (so their seeds are new) after the transitions received.
    pub fn rollouts(&self) -> Vec<Rollout> {
        if self.rollouts.len() == self.received.len() {
            return self.rollouts.clone();
        }
        self.received
            .iter()
            .map(|&sent| Rollout {
                sent,
                episode: (1 << 40) + sent,
                ..Rollout::default()
            })
            .collect()
    }
}

fn tensors(s: &Selkd) -> Vec<(String, &Tensor)> {
    let mut out = s.actors.named_params("actors");
    out.extend(s.critics.named_params("critics"));
    out.extend(s.target_critics.named_params("target_critics"));
    if let Some(t) = &s.target_actors {
        out.extend(t.named_params("target_actors"));
    }
    out.push(("log_alpha".into(), &s.log_alpha));
    for (name, opt) in [
        ("actor", &s.actor_opt),
        ("critic", &s.critic_opt),
        ("alpha", &s.alpha_opt),
    ] {
        for (i, (m, v)) in opt.exp_avg.iter().zip(&opt.exp_avg_sq).enumerate() {
            out.push((format!("adam.{name}.{i}.exp_avg"), m));
            out.push((format!("adam.{name}.{i}.exp_avg_sq"), v));
        }
    }
    out
}

/// Why a checkpoint was not written: the training state holds a non-finite value.
#[derive(Debug)]
pub struct NonFinite(pub String);

impl std::fmt::Display for NonFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "training diverged: tensor `{}` holds non-finite values, so no checkpoint is written from this state; nothing after the last checkpoint is kept (lower algo.lr, or check the env's rewards)", self.0)
    }
}

impl std::error::Error for NonFinite {}

/// Checks that `dir` is a complete checkpoint without reading its tensors: `state.json` parses,
/// and `model.safetensors` (and `replay.safetensors`, when present) hold every byte their header
/// promises. Returns its `state.json`; the error is one line naming the file and what is wrong.
pub fn check_complete(dir: &Path) -> std::result::Result<TrainingState, String> {
    let state = dir.join("state.json");
    let text = match std::fs::read_to_string(&state) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!(
                "{} is not a checkpoint directory: it has no state.json",
                dir.display()
            ))
        }
        Err(e) => return Err(format!("{}: cannot be read ({e})", state.display())),
    };
    // Truncated, damaged, or written by a version whose state this one cannot read.
    let state: TrainingState = serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}: not a state.json this selkd can read ({e})",
            dir.join("state.json").display()
        )
    })?;
    check_safetensors(&dir.join("model.safetensors"))?;
    let replay = dir.join("replay.safetensors");
    if replay.exists() {
        check_safetensors(&replay)?;
    }
    Ok(state)
}

/// A safetensors file: an 8-byte little-endian header length, the JSON header, then the data,
/// whose extent the header's `data_offsets` give.
fn check_safetensors(path: &Path) -> std::result::Result<(), String> {
    use std::io::Read;
    let shown = path.display();
    let mut f = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!("{shown} is missing"))
        }
        Err(e) => return Err(format!("{shown}: cannot be read ({e})")),
    };
    let len = f
        .metadata()
        .map_err(|e| format!("{shown}: cannot be read ({e})"))?
        .len();
    let damaged = |what: &str| format!("{shown} is damaged: {what}");
    let mut n = [0u8; 8];
    if f.read_exact(&mut n).is_err() {
        return Err(damaged(&format!("{len} bytes, too short for a header")));
    }
    let header_len = u64::from_le_bytes(n);
    if header_len > len - 8 {
        return Err(damaged(&format!(
            "truncated: {len} bytes, its header alone needs {}",
            header_len.saturating_add(8)
        )));
    }
    let mut header = vec![0u8; header_len as usize];
    f.read_exact(&mut header)
        .map_err(|e| format!("{shown}: cannot be read ({e})"))?;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&header).map_err(|_| damaged("its header is not valid"))?;
    let data_end = header
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .filter_map(|(_, v)| v["data_offsets"][1].as_u64())
        .max()
        .unwrap_or(0);
    let have = len - 8 - header_len;
    if data_end > have {
        return Err(damaged(&format!(
            "truncated: {len} bytes, its header promises {}",
            8 + header_len + data_end
        )));
    }
    Ok(())
}

/// A safetensors file's tensors, with a one-line error naming the file.
fn read_tensors(path: &Path) -> Result<HashMap<String, Tensor>> {
    check_safetensors(path).map_err(anyhow::Error::msg)?;
    Ok(Tensor::read_safetensors(path)
        .map_err(|e| anyhow::anyhow!("{} cannot be loaded: {e}", path.display()))?
        .into_iter()
        .collect())
}

/// Writes a checkpoint to `dir` (via a temporary directory, so a crash never leaves half of one);
/// with `replay`, its rows and AVTD's validation rows too.
pub fn save(
    dir: &Path,
    selkd: &mut Selkd,
    replay: Option<&mut ReplayBuffer>,
    state: &TrainingState,
) -> Result<()> {
    let tmp = dir.with_extension("partial");
    let _ = std::fs::remove_dir_all(&tmp);
    // A failed write (a full disk) leaves nothing behind: the space goes back to the run.
    if let Err(e) = write_into(&tmp, selkd, replay, state) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    replace_dir(&tmp, dir)?;
    if let Some(parent) = dir.parent() {
        fsync(parent)?;
    }
    Ok(())
}

/// The files of a checkpoint, written and fsynced into the fresh directory `tmp`.
fn write_into(
    tmp: &Path,
    selkd: &mut Selkd,
    replay: Option<&mut ReplayBuffer>,
    state: &TrainingState,
) -> Result<()> {
    let named: Vec<(String, Tensor)> = tensors(selkd)
        .into_iter()
        .map(|(n, t)| (n, t.detach().to_device(tch::Device::Cpu).contiguous()))
        .collect();
    // A state with an infinite or NaN value (an Adam moment that overflowed while the losses
    // still looked finite) is never written: resuming from it only diverges again.
    for (name, t) in &named {
        if t.isfinite().all().int64_value(&[]) == 0 {
            return Err(NonFinite(name.clone()).into());
        }
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    Tensor::write_safetensors(&named, tmp.join("model.safetensors"))
        .context("writing model.safetensors")?;
    if let Some(replay) = replay {
        let cpu = |b: &mut ReplayBuffer| b.export().to_device(tch::Device::Cpu).contiguous();
        let mut entries = vec![("rows", cpu(replay))];
        if let Some(avtd) = &mut selkd.avtd {
            entries.push(("validation", cpu(&mut avtd.validation)));
        }
        Tensor::write_safetensors(&entries, tmp.join("replay.safetensors"))
            .context("writing replay.safetensors")?;
    }
    std::fs::write(tmp.join("state.json"), serde_json::to_string_pretty(state)?)
        .context("writing state.json")?;
    for f in ["model.safetensors", "replay.safetensors", "state.json"] {
        if tmp.join(f).exists() {
            fsync(&tmp.join(f))?;
        }
    }
    fsync(&tmp)?;
    Ok(())
}

/// Puts directory `new` in the place of `dir` in one step: a crash leaves the old checkpoint
/// or the new one, never neither (Linux `renameat2(RENAME_EXCHANGE)` swaps the two; the old one,
/// now at `new`, is then removed).
fn replace_dir(new: &Path, dir: &Path) -> Result<()> {
    use std::os::unix::ffi::OsStrExt;
    let moving = || format!("moving checkpoint into {}", dir.display());
    if !dir.exists() {
        return std::fs::rename(new, dir).with_context(moving);
    }
    let c = |p: &Path| std::ffi::CString::new(p.as_os_str().as_bytes()).expect("no NUL in paths");
    let (a, b) = (c(new), c(dir));
    let swapped = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            a.as_ptr(),
            libc::AT_FDCWD,
            b.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    } == 0;
    if swapped {
        let _ = std::fs::remove_dir_all(new);
        return Ok(());
    }
    // A filesystem without RENAME_EXCHANGE: move the old one aside first.
    let old = dir.with_extension("old");
    let _ = std::fs::remove_dir_all(&old);
    std::fs::rename(dir, &old).with_context(moving)?;
    std::fs::rename(new, dir).with_context(moving)?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// Writes `text` to `path` through a temporary file renamed over it (never half a file).
pub fn write_atomically(path: &Path, text: &str) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    fsync(&tmp)?;
    std::fs::rename(&tmp, path).with_context(|| format!("replacing {}", path.display()))?;
    Ok(())
}

fn fsync(path: &Path) -> Result<()> {
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .with_context(|| format!("syncing {}", path.display()))
}

/// Loads a checkpoint into an already built `selkd` (same config) and, when it holds them, the
/// replay buffer and AVTD's validation rows.
pub fn load(dir: &Path, selkd: &mut Selkd, replay: &mut ReplayBuffer) -> Result<TrainingState> {
    let state = check_complete(dir).map_err(anyhow::Error::msg)?;
    let stored = read_tensors(&dir.join("model.safetensors"))?;
    tch::no_grad(|| -> Result<()> {
        for (name, t) in tensors(selkd) {
            let src = stored
                .get(&name)
                .with_context(|| format!("checkpoint lacks tensor `{name}`"))?;
            if src.size() != t.size() {
                bail!("checkpoint tensor `{name}` has shape {:?}, this config needs {:?}; resume with the checkpoint's own config", src.size(), t.size());
            }
            let mut t = t.shallow_clone();
            t.copy_(src);
        }
        Ok(())
    })?;
    selkd.rng = state.rng.clone();
    selkd.critic_updates = state.critic_updates;
    selkd.actor_updates = state.actor_updates;
    for (opt, steps) in [
        &mut selkd.actor_opt,
        &mut selkd.critic_opt,
        &mut selkd.alpha_opt,
    ]
    .into_iter()
    .zip(state.adam_steps)
    {
        opt.step = steps;
    }
    selkd.critic_opt.member_steps = state.critic_member_steps.clone();
    if let Some(avtd) = &mut selkd.avtd {
        avtd.selected = state.selected_variant;
    }
    let replay_file = dir.join("replay.safetensors");
    if replay_file.exists() {
        let stored = read_tensors(&replay_file)?;
        let rows = stored
            .get("rows")
            .context("replay.safetensors lacks its `rows`")?;
        replay.import(rows);
        if let (Some(avtd), Some(rows)) = (&mut selkd.avtd, stored.get("validation")) {
            avtd.validation.import(rows);
        }
    }
    Ok(state)
}

pub fn adam_steps(s: &Selkd) -> [i64; 3] {
    [s.actor_opt.step, s.critic_opt.step, s.alpha_opt.step]
}

/// One actor of a checkpoint, ready to act without libtorch.
pub struct LoadedActor {
    pub actor: selkd_policy::Actor,
    /// Which actor of the ensemble it is.
    pub index: usize,
    /// Actors in the checkpoint.
    pub actors: usize,
    /// The checkpoint's `state.json` (its config, ranking, counters), when `path` was a
    /// checkpoint directory.
    pub state: Option<TrainingState>,
}

/// Loads actor `actor` (default: the checkpoint's [`TrainingState::best_actor`], or 0 for a bare
/// `model.safetensors`) from a checkpoint directory or a `model.safetensors` file. The network's
/// shape is read from the tensors themselves. Act with [`selkd_policy::Actor::mean_action`]
/// (`tanh(μ)`, as in evaluation).
pub fn load_actor(path: &Path, actor: Option<usize>) -> Result<LoadedActor> {
    let (model, state) = if path.is_dir() {
        let state = path.join("state.json");
        let state: Option<TrainingState> = if state.exists() {
            let text = std::fs::read_to_string(&state)
                .with_context(|| format!("reading {}", state.display()))?;
            Some(
                serde_json::from_str(&text)
                    .with_context(|| format!("reading {}", state.display()))?,
            )
        } else {
            None
        };
        (path.join("model.safetensors"), state)
    } else {
        (path.to_path_buf(), None)
    };
    if !model.exists() {
        bail!(
            "{} is not a checkpoint: no model.safetensors there; pass a directory under RUN/checkpoints/ or a model.safetensors file",
            path.display()
        );
    }
    let stored = read_tensors(&model)?;
    let mut layers = Vec::new();
    while let (Some(w), Some(b)) = (
        stored.get(&format!("actors.{}.weight", layers.len())),
        stored.get(&format!("actors.{}.bias", layers.len())),
    ) {
        layers.push((w, b));
    }
    if layers.is_empty() {
        bail!(
            "{} holds no actor (no tensor `actors.0.weight`)",
            model.display()
        );
    }
    let k = layers[0].0.size()[0] as usize;
    let index = match actor {
        Some(i) => i,
        None => state.as_ref().map_or(0, TrainingState::best_actor),
    };
    if index >= k {
        bail!(
            "--actor {index}: the checkpoint has {}",
            match k {
                1 => "one actor (0)".to_string(),
                _ => format!("{k} actors (0 to {})", k - 1),
            }
        );
    }
    let dims: Vec<usize> = std::iter::once(layers[0].0.size()[1] as usize)
        .chain(layers.iter().map(|(w, _)| w.size()[2] as usize))
        .collect();
    let out = *dims.last().expect("at least one layer");
    let layout = selkd_policy::ActorLayout::new(dims[0], out / 2, &dims[1..dims.len() - 1]);
    let parts: Vec<Tensor> = layers
        .iter()
        .flat_map(|(w, b)| {
            [
                w.get(index as i64).reshape([-1]),
                b.get(index as i64).reshape([-1]),
            ]
        })
        .collect();
    let flat = Tensor::cat(&parts, 0)
        .to_device(tch::Device::Cpu)
        .to_kind(tch::Kind::Float);
    let params = Vec::<f32>::try_from(&flat).context("actor weights as f32")?;
    let actor = selkd_policy::Actor::from_flat(layout, params)?;
    Ok(LoadedActor {
        actor,
        index,
        actors: k,
        state,
    })
}

#[cfg(test)]
mod replace_tests {
    use super::*;

    /// Files made by hand in the safetensors layout: each fault is named in one line.
    #[test]
    fn damaged_safetensors_files_are_named_with_what_is_wrong() {
        let root = std::env::temp_dir().join(format!("selkd-check-st-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let file = |name: &str, header: &[u8], header_len: u64, data: usize| {
            let p = root.join(name);
            let mut bytes = header_len.to_le_bytes().to_vec();
            bytes.extend_from_slice(header);
            bytes.extend(std::iter::repeat_n(0u8, data));
            std::fs::write(&p, bytes).unwrap();
            p
        };
        // One f32 tensor of 2 values: 8 data bytes.
        let header = br#"{"t":{"dtype":"F32","shape":[2],"data_offsets":[0,8]}}"#;
        let n = header.len() as u64;
        assert_eq!(check_safetensors(&file("ok", header, n, 8)), Ok(()));
        let e = check_safetensors(&file("short-data", header, n, 4)).unwrap_err();
        assert!(
            e.ends_with(&format!(
                "short-data is damaged: truncated: {} bytes, its header promises {}",
                8 + n + 4,
                8 + n + 8
            )),
            "{e}"
        );
        let e = check_safetensors(&file("short-header", header, 1000, 0)).unwrap_err();
        assert!(
            e.contains("truncated") && e.contains("its header alone needs 1008"),
            "{e}"
        );
        let e = check_safetensors(&file("garbage", b"not json", 8, 0)).unwrap_err();
        assert!(
            e.ends_with("garbage is damaged: its header is not valid"),
            "{e}"
        );
        std::fs::write(root.join("tiny"), b"abc").unwrap();
        let e = check_safetensors(&root.join("tiny")).unwrap_err();
        assert!(e.contains("3 bytes, too short for a header"), "{e}");
        let e = check_safetensors(&root.join("absent")).unwrap_err();
        assert!(e.ends_with("absent is missing"), "{e}");
        let _ = std::fs::remove_dir_all(&root);
    }

    /// A checkpoint written over an older one replaces it whole, and leaves no temporary
    /// directory behind; `latest` is replaced the same way.
    #[test]
    fn a_new_checkpoint_replaces_the_old_one_whole() {
        let root = std::env::temp_dir().join(format!("selkd-replace-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let (dir, new) = (root.join("final"), root.join("final.partial"));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("state.json"), "old").unwrap();
        std::fs::write(dir.join("replay.safetensors"), "old replay").unwrap();
        std::fs::create_dir_all(&new).unwrap();
        std::fs::write(new.join("state.json"), "new").unwrap();
        replace_dir(&new, &dir).unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.join("state.json")).unwrap(),
            "new"
        );
        assert!(
            !dir.join("replay.safetensors").exists(),
            "nothing of the old one is left"
        );
        assert!(!new.exists() && !root.join("final.old").exists());
        write_atomically(&root.join("latest"), "final\n").unwrap();
        write_atomically(&root.join("latest"), "step-5\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(root.join("latest")).unwrap(),
            "step-5\n"
        );
        assert!(!root.join("latest.tmp").exists());
        let _ = std::fs::remove_dir_all(&root);
    }
}
