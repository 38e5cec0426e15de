//! Adam (Kingma & Ba), exactly as `torch.optim.Adam` with default betas, over stacked tensors.
//!
//! Written out rather than taken from `tch::nn` so that its moments can be checkpointed. Adam is
//! element-wise, so one Adam over an ensemble's stacked weights is N independent Adams.

use tch::Tensor;

pub struct Adam {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    pub step: i64,
    pub exp_avg: Vec<Tensor>,
    pub exp_avg_sq: Vec<Tensor>,
}

impl Adam {
    pub fn new(params: &[&Tensor], lr: f64) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            step: 0,
            exp_avg: params.iter().map(|p| p.zeros_like()).collect(),
            exp_avg_sq: params.iter().map(|p| p.zeros_like()).collect(),
        }
    }

    /// One step from the gradients accumulated in `params`, then clears them.
    pub fn step(&mut self, params: &[&Tensor]) {
        self.step += 1;
        let bias1 = 1.0 - self.beta1.powi(self.step as i32);
        let bias2 = 1.0 - self.beta2.powi(self.step as i32);
        tch::no_grad(|| {
            for ((p, m), v) in params
                .iter()
                .zip(&mut self.exp_avg)
                .zip(&mut self.exp_avg_sq)
            {
                let mut p = p.shallow_clone();
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                // torch's p −= lr/b1 · m / (√v/√b2 + ε), rewritten as
                // p −= (lr·√b2/b1) · m / (√v + ε·√b2) to need fewer temporaries.
                let _ = m.lerp_(&g, 1.0 - self.beta1);
                // β₂·v + (1 − β₂)·g², as PyTorch writes it: once a huge gradient has made v
                // infinite, the next one keeps it infinite (the update goes to 0), where
                // lerp's v + w·(g² − v) would give inf − inf = NaN and poison the weights.
                let _ = v.g_mul_scalar_(self.beta2);
                let _ = v.addcmul_(&g, &(&g * (1.0 - self.beta2)));
                let mut denom = v.sqrt();
                let _ = denom.g_add_scalar_(self.eps * bias2.sqrt());
                let mut update = &*m / &denom;
                let _ = update.g_mul_scalar_(self.lr * bias2.sqrt() / bias1);
                let _ = p.g_sub_(&update);
                p.zero_grad();
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam written out in scalar arithmetic, step by step, as the paper and torch define it.
    #[test]
    fn matches_a_scalar_reference_over_several_steps() {
        let p = Tensor::from_slice(&[0.5f32, -1.0, 2.0]).set_requires_grad(true);
        let mut opt = Adam::new(&[&p], 0.1);
        let (mut x, mut m, mut v) = ([0.5f64, -1.0, 2.0], [0.0f64; 3], [0.0f64; 3]);
        for t in 1..=5 {
            // loss = Σ x³ → grad 3x²
            let loss = p.pow_tensor_scalar(3).sum(tch::Kind::Float);
            loss.backward();
            opt.step(&[&p]);
            for k in 0..3 {
                let g = 3.0 * x[k] * x[k];
                m[k] = 0.9 * m[k] + 0.1 * g;
                v[k] = 0.999 * v[k] + 0.001 * g * g;
                let mh = m[k] / (1.0 - 0.9f64.powi(t));
                let vh = v[k] / (1.0 - 0.999f64.powi(t));
                x[k] -= 0.1 * mh / (vh.sqrt() + 1e-8);
            }
        }
        let got = Vec::<f32>::try_from(&p.detach()).unwrap();
        for k in 0..3 {
            assert!((got[k] as f64 - x[k]).abs() < 1e-5, "{got:?} vs {x:?}");
        }
    }

    /// ε matters where gradients are as small as ε itself: a first step is −lr·g/(|g| + ε), so
    /// g = ε takes half a step and g = ε/10 a tenth of one, where without ε every coordinate would
    /// take a full step of lr. Checked against the same scalar reference over a few steps.
    #[test]
    fn epsilon_damps_the_steps_of_tiny_gradients() {
        let coef = [1e-9f64, 1e-8, 1e-2];
        let p = Tensor::from_slice(&[0.0f32; 3]).set_requires_grad(true);
        let c = Tensor::from_slice(&coef.map(|v| v as f32));
        let mut opt = Adam::new(&[&p], 0.1);
        let (mut x, mut m, mut v) = ([0.0f64; 3], [0.0f64; 3], [0.0f64; 3]);
        for t in 1..=3 {
            // loss = Σ c·x → constant gradient c
            (&p * &c).sum(tch::Kind::Float).backward();
            opt.step(&[&p]);
            for k in 0..3 {
                let g = coef[k] as f32 as f64;
                m[k] = 0.9 * m[k] + 0.1 * g;
                v[k] = 0.999 * v[k] + 0.001 * g * g;
                let mh = m[k] / (1.0 - 0.9f64.powi(t));
                let vh = v[k] / (1.0 - 0.999f64.powi(t));
                x[k] -= 0.1 * mh / (vh.sqrt() + 1e-8);
            }
            if t == 1 {
                let got = Vec::<f32>::try_from(&p.detach()).unwrap();
                assert!((got[0] as f64 + 0.1 / 11.0).abs() < 1e-6, "{got:?}");
                assert!((got[1] as f64 + 0.05).abs() < 1e-6, "{got:?}");
            }
        }
        let got = Vec::<f32>::try_from(&p.detach()).unwrap();
        for k in 0..3 {
            assert!((got[k] as f64 - x[k]).abs() < 1e-6, "{got:?} vs {x:?}");
        }
    }

    /// Gradients so large that g² overflows f32 (the KD term toward a best actor whose σ sits
    /// at the clamp can give them) must not turn the weights into NaN: the second moment stays
    /// infinite and the step goes to zero, as in PyTorch.
    #[test]
    fn overflowing_gradients_do_not_make_nan() {
        let p = Tensor::from_slice(&[1.0f32, 1.0]).set_requires_grad(true);
        let mut opt = Adam::new(&[&p], 0.1);
        let scale = Tensor::from_slice(&[1e30f32, 1.0]);
        for _ in 0..3 {
            (&p * &scale).sum(tch::Kind::Float).backward();
            opt.step(&[&p]);
        }
        let got = Vec::<f32>::try_from(&p.detach()).unwrap();
        assert!(got.iter().all(|x| x.is_finite()), "{got:?}");
        // The ordinary coordinate still learns: three steps of about lr each.
        assert!((got[1] - 0.7).abs() < 1e-3, "{got:?}");
    }
}
