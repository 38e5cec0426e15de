//! The actor network shared by the learner and the workers: its layout as one flat `f32` vector
//! (what travels over shared memory and what checkpoints hold), and a forward pass in plain Rust,
//! so that a worker acts without libtorch.
//!
//! An actor is an MLP `obs → hidden… → 2·act` with ReLU; the output splits into the mean `μ` and
//! `log σ` (clamped to [`LOG_STD_MIN`], [`LOG_STD_MAX`]) of a diagonal Gaussian over the pre-tanh
//! action `u`; the action is `tanh(u)`. Each layer is stored as its weight `[in][out]` (row-major)
//! followed by its bias `[out]`, layers in order.

pub mod evaluation;

use rand::Rng;
use rand_distr::StandardNormal;

pub const LOG_STD_MIN: f32 = -20.0;
pub const LOG_STD_MAX: f32 = 2.0;

/// The shape of an actor network.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ActorLayout {
    pub obs_dim: usize,
    pub act_dim: usize,
    pub hidden: Vec<usize>,
}

impl ActorLayout {
    pub fn new(obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Self {
        Self {
            obs_dim,
            act_dim,
            hidden: hidden.to_vec(),
        }
    }

    /// `(in, out)` of every linear layer, the output head last.
    pub fn layers(&self) -> Vec<(usize, usize)> {
        let mut dims = vec![self.obs_dim];
        dims.extend(&self.hidden);
        dims.push(2 * self.act_dim);
        dims.windows(2).map(|w| (w[0], w[1])).collect()
    }

    /// Length of the flat parameter vector.
    pub fn num_params(&self) -> usize {
        self.layers().iter().map(|(i, o)| i * o + o).sum()
    }
}

#[derive(Debug, thiserror::Error)]
#[error("actor weights have {got} values, but an actor with obs {obs}, act {act}, hidden {hidden:?} needs {want}")]
pub struct LayoutMismatch {
    got: usize,
    want: usize,
    obs: usize,
    act: usize,
    hidden: Vec<usize>,
}

/// One actor's policy, evaluated on single observations.
#[derive(Clone, Debug)]
pub struct Actor {
    layout: ActorLayout,
    params: Vec<f32>,
}

impl Actor {
    pub fn from_flat(layout: ActorLayout, params: Vec<f32>) -> Result<Self, LayoutMismatch> {
        let want = layout.num_params();
        if params.len() != want {
            return Err(LayoutMismatch {
                got: params.len(),
                want,
                obs: layout.obs_dim,
                act: layout.act_dim,
                hidden: layout.hidden.clone(),
            });
        }
        Ok(Self { layout, params })
    }

    pub fn layout(&self) -> &ActorLayout {
        &self.layout
    }

    /// The flat parameter vector (layout in the crate doc).
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// Replaces the weights in place (same layout), keeping the allocation.
    pub fn set_params(&mut self, params: &[f32]) -> Result<(), LayoutMismatch> {
        if params.len() != self.params.len() {
            return Err(LayoutMismatch {
                got: params.len(),
                want: self.params.len(),
                obs: self.layout.obs_dim,
                act: self.layout.act_dim,
                hidden: self.layout.hidden.clone(),
            });
        }
        self.params.copy_from_slice(params);
        Ok(())
    }

    /// `(μ, log σ)` of the pre-tanh Gaussian at `obs`, `log σ` clamped.
    pub fn mean_log_std(&self, obs: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let layers = self.layout.layers();
        let mut x = obs.to_vec();
        let mut offset = 0;
        for (l, &(n_in, n_out)) in layers.iter().enumerate() {
            let w = &self.params[offset..offset + n_in * n_out];
            let b = &self.params[offset + n_in * n_out..offset + n_in * n_out + n_out];
            offset += n_in * n_out + n_out;
            let mut y = b.to_vec();
            // Row-major [in][out]: accumulate one input's row at a time (vectorises over `out`).
            for (xi, row) in x.iter().zip(w.chunks_exact(n_out)) {
                for (yo, wo) in y.iter_mut().zip(row) {
                    *yo += xi * wo;
                }
            }
            if l + 1 < layers.len() {
                y.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            x = y;
        }
        let a = self.layout.act_dim;
        let log_std = x[a..]
            .iter()
            .map(|v| v.clamp(LOG_STD_MIN, LOG_STD_MAX))
            .collect();
        x.truncate(a);
        (x, log_std)
    }

    /// The deterministic (evaluation) action `tanh(μ)`.
    pub fn mean_action(&self, obs: &[f32]) -> Vec<f32> {
        self.mean_log_std(obs)
            .0
            .into_iter()
            .map(f32::tanh)
            .collect()
    }

    /// A sampled (behaviour) action `tanh(μ + σ·ε)`, `ε ~ N(0, I)`.
    pub fn sample_action(&self, obs: &[f32], rng: &mut impl Rng) -> Vec<f32> {
        let (mu, log_std) = self.mean_log_std(obs);
        mu.iter()
            .zip(&log_std)
            .map(|(m, ls)| {
                let eps: f32 = rng.sample(StandardNormal);
                (m + ls.exp() * eps).tanh()
            })
            .collect()
    }
}

impl Actor {
    /// A deterministic action with Gaussian exploration noise, `clip(tanh(μ) + σ·ε, −1, 1)` (TD3).
    pub fn noisy_mean_action(&self, obs: &[f32], std: f32, rng: &mut impl Rng) -> Vec<f32> {
        self.mean_action(obs)
            .into_iter()
            .map(|a| {
                let eps: f32 = rng.sample(StandardNormal);
                (a + std * eps).clamp(-1.0, 1.0)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noisy_mean_action_adds_clipped_exploration_noise() {
        use rand::SeedableRng;
        let l = ActorLayout::new(2, 3, &[4]);
        let actor = Actor::from_flat(
            l.clone(),
            (0..l.num_params())
                .map(|i| ((i % 7) as f32 - 3.0) * 0.1)
                .collect(),
        )
        .unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let obs = [0.5, -0.2];
        let mean = actor.mean_action(&obs);
        assert_eq!(
            actor.noisy_mean_action(&obs, 0.0, &mut rng),
            mean,
            "no noise, no change"
        );
        let noisy: Vec<Vec<f32>> = (0..200)
            .map(|_| actor.noisy_mean_action(&obs, 0.5, &mut rng))
            .collect();
        assert!(noisy.iter().flatten().all(|a| (-1.0..=1.0).contains(a)));
        let spread = noisy.iter().map(|a| (a[0] - mean[0]).abs()).sum::<f32>() / 200.0;
        assert!(
            spread > 0.1,
            "exploration noise is applied: mean |Δ| {spread}"
        );
    }

    #[test]
    fn layout_counts_every_weight_and_bias() {
        let l = ActorLayout::new(3, 1, &[4, 5]);
        assert_eq!(l.layers(), vec![(3, 4), (4, 5), (5, 2)]);
        assert_eq!(l.num_params(), 3 * 4 + 4 + 4 * 5 + 5 + 5 * 2 + 2);
        let err = Actor::from_flat(l, vec![0.0; 7]).unwrap_err().to_string();
        assert!(err.contains("7") && err.contains("53"), "{err}");
    }

    #[test]
    fn forward_matches_a_hand_computed_network() {
        // obs 2 → hidden 2 → 2·act(1); weights chosen so each unit is easy to follow.
        let l = ActorLayout::new(2, 1, &[2]);
        #[rustfmt::skip]
        let p = vec![
            1.0, -1.0,   // W1 row for obs[0]
            2.0, 0.5,    // W1 row for obs[1]
            0.1, -0.2,   // b1
            1.0, 3.0,    // W2 row for h[0] → (μ, log σ)
            -1.0, 30.0,  // W2 row for h[1]
            0.0, 0.0,    // b2
        ];
        let actor = Actor::from_flat(l, p).unwrap();
        let (mu, ls) = actor.mean_log_std(&[1.0, 2.0]);
        // h = relu([1 + 4 + 0.1, -1 + 1 - 0.2]) = [5.1, 0]
        assert!((mu[0] - 5.1).abs() < 1e-6);
        assert_eq!(ls[0], LOG_STD_MAX, "log σ = 15.3 must clamp to 2");
        assert!((actor.mean_action(&[1.0, 2.0])[0] - 5.1f32.tanh()).abs() < 1e-7);
    }
}
