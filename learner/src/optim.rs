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
    /// Steps taken by each ensemble member, when members step separately ([`Adam::step_members`],
    /// DNS); empty otherwise.
    pub member_steps: Vec<i64>,
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
            member_steps: vec![],
            exp_avg: params.iter().map(|p| p.zeros_like()).collect(),
            exp_avg_sq: params.iter().map(|p| p.zeros_like()).collect(),
        }
    }

    /// One step from the gradients accumulated in `params`, then clears them.
    pub fn step(&mut self, params: &[&Tensor]) {
        self.step_then_average(params, None);
    }

    /// [`Self::step`], then Polyak averaging of `targets` (one per parameter, of its shape)
    /// toward the stepped parameters, `target ← ρ·target + (1 − ρ)·p`: on CPU in the step's own
    /// pass over the weights, which saves a pass over both.
    pub fn step_and_average(&mut self, params: &[&Tensor], targets: &[&Tensor], rho: f64) {
        assert_eq!(params.len(), targets.len(), "one target per parameter");
        self.step_then_average(params, Some((targets, (1.0 - rho) as f32)));
    }

    /// The step, and with `average = (targets, 1 − ρ)` the targets' averaging.
    fn step_then_average(&mut self, params: &[&Tensor], average: Option<(&[&Tensor], f32)>) {
        self.step += 1;
        let c = self.constants(self.step);
        if self.step_in_parts(params, average, &c) {
            return;
        }
        let mut targets = average.map(|(t, weight)| (t.iter(), weight));
        self.each_param(params, |p, g, m, v| {
            let target = targets
                .as_mut()
                .map(|(t, weight)| (*t.next().expect("a target"), *weight));
            // The one-pass step clears the gradient as it goes.
            if target.is_some() && fused_step_in_place(p, g, m, v, target, &c) {
                return true;
            }
            let cleared = fused_step_in_place(p, g, m, v, None, &c) || {
                tensor_step(&mut p.shallow_clone(), g, m, v, &c);
                false
            };
            if let Some((t, w)) = target {
                let _ = t.shallow_clone().lerp_(p, w as f64);
            }
            cleared
        });
    }

    /// [`Self::step`] split by ensemble members over the learner's threads (see `threads`): Adam
    /// is element-wise, so each thread steps its members' slice of every parameter. Only where
    /// every parameter is stacked `[E, …]` over the same E members and takes the one-pass step
    /// (CPU, f32, contiguous, with a gradient), and there is enough of it; returns false, having
    /// done nothing, otherwise.
    fn step_in_parts(
        &self,
        params: &[&Tensor],
        average: Option<(&[&Tensor], f32)>,
        c: &Constants,
    ) -> bool {
        let Some(members) = params.first().map(|p| p.size()[0]) else {
            return false;
        };
        let parts = crate::threads::member_parts(members.max(1) as usize);
        let total: i64 = params.iter().map(|p| p.numel() as i64).sum();
        if parts.len() < 2 || total < SPLIT_FROM {
            return false;
        }
        let grads: Vec<Tensor> = params.iter().map(|p| p.grad()).collect();
        let fits =
            |t: &Tensor| t.defined() && takes_one_pass(t) && t.dim() > 0 && t.size()[0] == members;
        let targets = average.map_or(&[][..], |(t, _)| t);
        let all: Vec<&Tensor> = params
            .iter()
            .copied()
            .chain(&grads)
            .chain(&self.exp_avg)
            .chain(&self.exp_avg_sq)
            .chain(targets.iter().copied())
            .collect();
        if !all.iter().all(|t| fits(t)) {
            return false;
        }
        let weight = average.map(|(_, w)| w);
        type Job = (Vec<([Tensor; 4], Option<Tensor>)>, Option<f32>, Constants);
        let jobs: Vec<Job> = parts
            .iter()
            .map(|&(start, len)| {
                let part = |t: &Tensor| t.detach().narrow(0, start as i64, len as i64);
                let quads = (0..params.len())
                    .map(|i| {
                        let quad = [
                            part(params[i]),
                            part(&grads[i]),
                            part(&self.exp_avg[i]),
                            part(&self.exp_avg_sq[i]),
                        ];
                        (quad, targets.get(i).map(|t| part(t)))
                    })
                    .collect();
                (quads, weight, c.clone())
            })
            .collect();
        crate::threads::run_parts(jobs, |(quads, weight, c)| {
            for ([p, g, m, v], target) in &quads {
                let target = target.as_ref().zip(weight);
                // Each fits (checked above), so the one-pass step applies and clears `g`.
                let stepped = fused_step_in_place(p, g, m, v, target, &c);
                debug_assert!(stepped);
            }
        });
        true
    }

    /// Runs `update(p, g, m, v)` without autograd on every parameter that has a gradient, with
    /// its moments; clears the gradient afterwards unless `update` says it already has.
    fn each_param(
        &mut self,
        params: &[&Tensor],
        mut update: impl FnMut(&Tensor, &Tensor, &mut Tensor, &mut Tensor) -> bool,
    ) {
        tch::no_grad(|| {
            for ((p, m), v) in params
                .iter()
                .zip(&mut self.exp_avg)
                .zip(&mut self.exp_avg_sq)
            {
                let mut p = p.shallow_clone();
                let g = p.grad();
                if g.defined() && !update(&p, &g, m, v) {
                    p.zero_grad();
                }
            }
        });
    }
}

impl Adam {
    /// One step's scalars at step count `step`. torch's p −= lr/b1 · m / (√v/√b2 + ε), rewritten
    /// as p −= (lr·√b2/b1) · m / (√v + ε·√b2) to need fewer temporaries.
    fn constants(&self, step: i64) -> Constants {
        let bias1 = 1.0 - self.beta1.powi(step as i32);
        let bias2 = 1.0 - self.beta2.powi(step as i32);
        Constants {
            one_minus_beta1: (1.0 - self.beta1) as f32,
            beta2: self.beta2 as f32,
            one_minus_beta2: (1.0 - self.beta2) as f32,
            eps_hat: (self.eps * bias2.sqrt()) as f32,
            step_size: (self.lr * bias2.sqrt() / bias1) as f32,
        }
    }

    /// One step of only the listed ensemble members (`params` stacked `[members, …]`), each
    /// with its own step count: exactly what one `torch.optim.Adam` per member would do if only
    /// the listed members' optimisers stepped (DNS). The other members' weights and moments stay
    /// as they are, whatever their gradients; every gradient is cleared.
    pub fn step_members(&mut self, params: &[&Tensor], members: &[usize], total: usize) {
        if self.member_steps.len() != total {
            self.member_steps = vec![self.step; total];
        }
        self.step += 1;
        for &j in members {
            self.member_steps[j] += 1;
        }
        let consts: Vec<Constants> = members
            .iter()
            .map(|&j| self.constants(self.member_steps[j]))
            .collect();
        self.each_param(params, |p, g, m, v| {
            for (&j, c) in members.iter().zip(&consts) {
                let j = j as i64;
                let (mut pj, gj, mut mj, mut vj) = (p.get(j), g.get(j), m.get(j), v.get(j));
                if !fused_step_in_place(&pj, &gj, &mj, &vj, None, c) {
                    tensor_step(&mut pj, &gj, &mut mj, &mut vj, c);
                }
            }
            false // the unlisted members' gradients are still there
        });
    }
}

/// One step's scalars, in f32 as libtorch applies them to f32 tensors.
#[derive(Clone)]
struct Constants {
    one_minus_beta1: f32,
    beta2: f32,
    one_minus_beta2: f32,
    eps_hat: f32,
    step_size: f32,
}

/// Adam in tensor operations (any device): about ten passes over each parameter.
fn tensor_step(p: &mut Tensor, g: &Tensor, m: &mut Tensor, v: &mut Tensor, c: &Constants) {
    let _ = m.lerp_(g, c.one_minus_beta1 as f64);
    // β₂·v + (1 − β₂)·g², as PyTorch writes it: once a huge gradient has made v infinite, the
    // next one keeps it infinite (the update goes to 0), where lerp's v + w·(g² − v) would give
    // inf − inf = NaN and poison the weights.
    let _ = v.g_mul_scalar_(c.beta2 as f64);
    let _ = v.addcmul_(g, &(g * c.one_minus_beta2 as f64));
    let mut denom = v.sqrt();
    let _ = denom.g_add_scalar_(c.eps_hat as f64);
    let mut update = &*m / &denom;
    let _ = update.g_mul_scalar_(c.step_size as f64);
    let _ = p.g_sub_(&update);
}

/// The same step in one pass over contiguous f32 CPU memory (parameter, gradient, both moments,
/// and with `target = (t, 1 − ρ)` the parameter's Polyak average), clearing the gradient as it
/// goes: the optimiser's memory traffic is then what it must be, not ten passes with their
/// temporaries. Returns false where it does not apply (another device or layout); the caller
/// then takes the tensor path.
fn fused_step_in_place(
    p: &Tensor,
    g: &Tensor,
    m: &Tensor,
    v: &Tensor,
    target: Option<(&Tensor, f32)>,
    c: &Constants,
) -> bool {
    let n = p.numel();
    let tensors = [p, g, m, v].into_iter().chain(target.map(|(t, _)| t));
    if !tensors
        .into_iter()
        .all(|t| takes_one_pass(t) && t.numel() == n)
    {
        return false;
    }
    // SAFETY: distinct, contiguous f32 buffers of n elements each (a parameter, its gradient,
    // its two moments and its average never share storage), not used elsewhere during the step.
    let s = |t: &Tensor| unsafe { std::slice::from_raw_parts_mut(t.data_ptr() as *mut f32, n) };
    let (p, g, m, v) = (s(p), s(g), s(m), s(v));
    match target {
        None => adam_loop(p, g, m, v, c),
        Some((t, weight)) => adam_average_loop(p, g, m, v, s(t), weight, c),
    }
    true
}

/// Whether `t` is memory the one-pass step can go through: contiguous f32 on the CPU.
fn takes_one_pass(t: &Tensor) -> bool {
    t.device() == tch::Device::Cpu && t.kind() == tch::Kind::Float && t.is_contiguous()
}

/// Elements (of all parameters together) from which a step is worth splitting over threads:
/// waking one costs tens of microseconds, the step goes through about a thousand elements a
/// microsecond.
const SPLIT_FROM: i64 = 1 << 16;

/// Element by element, the arithmetic of [`tensor_step`] (no fused multiply-add, so every CPU
/// rounds alike).
#[inline(always)]
fn adam_element(p: &mut f32, g: &mut f32, m: &mut f32, v: &mut f32, c: &Constants) {
    let grad = *g;
    *m += c.one_minus_beta1 * (grad - *m);
    *v = *v * c.beta2 + grad * (grad * c.one_minus_beta2);
    *p -= *m / (v.sqrt() + c.eps_hat) * c.step_size;
    *g = 0.0;
}

crate::fused::vectorised! {
    fn adam_loop(p: &mut [f32], g: &mut [f32], m: &mut [f32], v: &mut [f32], c: &Constants) {
        for (((p, g), m), v) in p.iter_mut().zip(g.iter_mut()).zip(m.iter_mut()).zip(v.iter_mut()) {
            adam_element(p, g, m, v, c);
        }
    }

    fn adam_average_loop(
        p: &mut [f32],
        g: &mut [f32],
        m: &mut [f32],
        v: &mut [f32],
        target: &mut [f32],
        weight: f32,
        c: &Constants,
    ) {
        let each = p.iter_mut().zip(g.iter_mut()).zip(m.iter_mut()).zip(v.iter_mut()).zip(target);
        for ((((p, g), m), v), t) in each {
            adam_element(p, g, m, v, c);
            // Polyak averaging toward the stepped weight, as libtorch's lerp for a small weight.
            *t += weight * (*p - *t);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam in scalar arithmetic as the paper and torch define it (lr 0.1, default betas and ε):
    /// step `t` of parameter `x` with gradient `g`.
    fn scalar_adam(x: &mut f64, m: &mut f64, v: &mut f64, g: f64, t: i32) {
        *m = 0.9 * *m + 0.1 * g;
        *v = 0.999 * *v + 0.001 * g * g;
        let mh = *m / (1.0 - 0.9f64.powi(t));
        let vh = *v / (1.0 - 0.999f64.powi(t));
        *x -= 0.1 * mh / (vh.sqrt() + 1e-8);
    }

    /// Adam written out in scalar arithmetic, step by step.
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
                scalar_adam(&mut x[k], &mut m[k], &mut v[k], g, t);
            }
        }
        let got = Vec::<f32>::try_from(&p.detach()).unwrap();
        for k in 0..3 {
            assert!((got[k] as f64 - x[k]).abs() < 1e-5, "{got:?} vs {x:?}");
        }
    }

    /// The one-pass step takes exactly the tensors it can run over as flat f32 memory: CPU,
    /// f32, contiguous (and all four the same size); anything else goes to the tensor path.
    #[test]
    fn the_fused_step_applies_to_contiguous_f32_cpu_tensors_only() {
        let c = Adam::new(&[], 0.1).constants(1);
        let t = |n: i64| Tensor::zeros([n, 3], (tch::Kind::Float, tch::Device::Cpu));
        let (p, g, m, v) = (t(4), t(4), t(4), t(4));
        assert!(fused_step_in_place(&p, &g, &m, &v, None, &c));
        let transposed =
            Tensor::zeros([3, 4], (tch::Kind::Float, tch::Device::Cpu)).transpose(0, 1);
        assert!(!transposed.is_contiguous());
        assert!(!fused_step_in_place(&transposed, &g, &m, &v, None, &c));
        assert!(!fused_step_in_place(&p, &transposed, &m, &v, None, &c));
        let double = t(4).to_kind(tch::Kind::Double);
        assert!(!fused_step_in_place(&p, &g, &double, &v, None, &c));
        assert!(!fused_step_in_place(&p, &g, &m, &t(5), None, &c));
    }

    /// Members stepping separately (DNS): three members of a stacked `[3, 2]` parameter, with
    /// members {0, 2}, then {1}, then {0, 1} stepping, against one scalar Adam per member that
    /// steps only when listed: an unlisted member keeps its weights and moments although its
    /// gradient is not zero, and a member's bias correction counts only its own steps.
    #[test]
    fn members_step_separately_as_one_adam_per_member() {
        let start = [0.5f64, -1.0, 2.0, 0.25, -0.75, 1.5];
        let p = Tensor::from_slice(&start.map(|x| x as f32))
            .reshape([3, 2])
            .set_requires_grad(true);
        let mut opt = Adam::new(&[&p], 0.1);
        let mut x = start;
        let (mut m, mut v, mut steps) = ([0.0f64; 6], [0.0f64; 6], [0i32; 3]);
        for members in [vec![0, 2], vec![1], vec![0, 1]] {
            // loss = Σ x³ over every member → grad 3x² everywhere, listed or not.
            p.pow_tensor_scalar(3).sum(tch::Kind::Float).backward();
            opt.step_members(&[&p], &members, 3);
            for &j in &members {
                steps[j] += 1;
                let t = steps[j];
                for k in 2 * j..2 * j + 2 {
                    let g = 3.0 * x[k] * x[k];
                    scalar_adam(&mut x[k], &mut m[k], &mut v[k], g, t);
                }
            }
            assert_eq!(p.grad().abs().sum(tch::Kind::Float).double_value(&[]), 0.0);
        }
        let got = Vec::<f32>::try_from(&p.detach().reshape([-1])).unwrap();
        for k in 0..6 {
            assert!((got[k] as f64 - x[k]).abs() < 1e-5, "{got:?} vs {x:?}");
        }
        let m_got = Vec::<f32>::try_from(&opt.exp_avg[0].reshape([-1])).unwrap();
        for k in 0..6 {
            assert!(
                (m_got[k] as f64 - m[k]).abs() < 1e-5,
                "moments {m_got:?} vs {m:?}"
            );
        }
        assert_eq!(opt.member_steps, vec![2, 2, 1]);
    }

    /// The one-pass CPU step and the tensor-operation step (what CUDA runs) agree to f32
    /// round-off over many steps of the same random gradients (of all scales, so that ε and
    /// the moments' bias corrections all matter), and both clear the gradient.
    #[test]
    fn the_fused_cpu_step_matches_the_tensor_step() {
        tch::manual_seed(3);
        let start = Tensor::randn([4, 33, 17], (tch::Kind::Float, tch::Device::Cpu));
        let (a, b) = (
            start.copy().set_requires_grad(true),
            start.copy().set_requires_grad(true),
        );
        let mut fused = Adam::new(&[&a], 1e-2);
        let mut plain = Adam::new(&[&b], 1e-2);
        for t in 0..50 {
            // Gradients spanning 1e-12 to 1e3: the smallest sit below ε.
            let scale = (Tensor::rand([4, 33, 17], (tch::Kind::Float, tch::Device::Cpu)) * 15.0
                - 12.0)
                * std::f64::consts::LN_10;
            let scale = scale.exp();
            let grad = Tensor::randn([4, 33, 17], (tch::Kind::Float, tch::Device::Cpu)) * scale;
            for p in [&a, &b] {
                (p * &grad).sum(tch::Kind::Float).backward();
            }
            let _ = t;
            fused.step(&[&a]);
            // The same step through the tensor path.
            plain.step += 1;
            let (b1, b2) = (
                1.0 - 0.9f64.powi(plain.step as i32),
                1.0 - 0.999f64.powi(plain.step as i32),
            );
            let c = Constants {
                one_minus_beta1: 0.1f64 as f32,
                beta2: 0.999,
                one_minus_beta2: (1.0f64 - 0.999) as f32,
                eps_hat: (1e-8 * b2.sqrt()) as f32,
                step_size: (1e-2 * b2.sqrt() / b1) as f32,
            };
            tch::no_grad(|| {
                let mut p = b.shallow_clone();
                tensor_step(
                    &mut p,
                    &b.grad(),
                    &mut plain.exp_avg[0],
                    &mut plain.exp_avg_sq[0],
                    &c,
                );
                p.zero_grad();
            });
            assert_eq!(a.grad().abs().sum(tch::Kind::Float).double_value(&[]), 0.0);
        }
        let moved = (&a - &start).abs().max().double_value(&[]);
        assert!(moved > 0.1, "the parameters moved ({moved})");
        for (x, y) in [
            (&a, &b),
            (&fused.exp_avg[0], &plain.exp_avg[0]),
            (&fused.exp_avg_sq[0], &plain.exp_avg_sq[0]),
        ] {
            // Relative to the tensor's scale: 50 steps of rounding, each at most an ulp or two.
            let rel = (x - y).abs().max().double_value(&[]) / y.abs().max().double_value(&[]);
            assert!(
                rel < 1e-6,
                "fused and tensor steps differ by {rel:e} (relative)"
            );
        }
    }

    /// Split over threads by members, the step is the whole step, bit for bit (element-wise
    /// arithmetic in the same order); every gradient is cleared.
    #[test]
    fn a_step_split_over_threads_is_the_whole_step() {
        tch::manual_seed(5);
        let shapes: [&[i64]; 2] = [&[5, 64, 256], &[5, 1, 256]];
        let make = || -> Vec<Tensor> {
            tch::manual_seed(6);
            shapes
                .iter()
                .map(|s| {
                    Tensor::randn(*s, (tch::Kind::Float, tch::Device::Cpu)).set_requires_grad(true)
                })
                .collect()
        };
        // A copy, not a second draw: another test may draw from libtorch's global generator
        // (or reseed it) between two draws of this thread.
        let whole = make();
        let split: Vec<Tensor> = whole
            .iter()
            .map(|t| t.detach().copy().set_requires_grad(true))
            .collect();
        let refs = |v: &[Tensor]| -> Vec<Tensor> { v.iter().map(|t| t.shallow_clone()).collect() };
        let (w, s) = (refs(&whole), refs(&split));
        let (w, s): (Vec<&Tensor>, Vec<&Tensor>) = (w.iter().collect(), s.iter().collect());
        let (mut a, mut b) = (Adam::new(&w, 1e-2), Adam::new(&s, 1e-2));
        assert!(5 * 65 * 256 >= SPLIT_FROM);
        for _ in 0..3 {
            let grads: Vec<Tensor> = shapes
                .iter()
                .map(|s| Tensor::randn(*s, (tch::Kind::Float, tch::Device::Cpu)))
                .collect();
            for params in [&whole, &split] {
                for (p, g) in params.iter().zip(&grads) {
                    (p * g).sum(tch::Kind::Float).backward();
                }
            }
            a.step(&w);
            // `step`'s split path, which must apply here.
            b.step += 1;
            let c = b.constants(b.step);
            assert!(crate::threads::with_parts(2, || b.step_in_parts(&s, None, &c)));
        }
        for (x, y) in whole.iter().zip(&split) {
            assert!(x.equal(y), "split and whole steps differ");
            assert_eq!(y.grad().abs().sum(tch::Kind::Float).double_value(&[]), 0.0);
        }
        assert!(a.exp_avg_sq[0].equal(&b.exp_avg_sq[0]));
    }

    /// `step_and_average` is the step, then `t ← ρ·t + (1 − ρ)·p` with the stepped `p`: checked
    /// against that formula in f64 on the one-pass path (whole and split over threads) and on
    /// the tensor path (a non-contiguous target), and the step itself against `step`.
    #[test]
    fn averaging_in_the_step_is_polyak_toward_the_stepped_weights() {
        let rho = 0.9;
        let shapes: [&[i64]; 2] = [&[4, 64, 256], &[4, 1, 256]];
        let fresh = |seed: i64| -> Vec<Tensor> {
            tch::manual_seed(seed);
            shapes
                .iter()
                .map(|s| Tensor::randn(*s, (tch::Kind::Float, tch::Device::Cpu)))
                .collect()
        };
        let floats = |t: &Tensor| -> Vec<f64> {
            Vec::<f32>::try_from(&t.detach().contiguous().reshape([-1]))
                .unwrap()
                .into_iter()
                .map(f64::from)
                .collect()
        };
        // (parts, whether the targets are transposed views: not one-pass memory)
        for (parts, strided) in [(1, false), (2, false), (1, true)] {
            // Copies, not two draws (see the test above).
            let params = fresh(1);
            let plain: Vec<Tensor> = params
                .iter()
                .map(|p| p.copy().set_requires_grad(true))
                .collect();
            let params: Vec<Tensor> = params
                .into_iter()
                .map(|p| p.set_requires_grad(true))
                .collect();
            let targets: Vec<Tensor> = fresh(2)
                .into_iter()
                .map(|t| {
                    if strided {
                        t.transpose(0, 2).contiguous().transpose(0, 2)
                    } else {
                        t
                    }
                })
                .collect();
            assert_eq!(targets[0].is_contiguous(), !strided);
            let p_refs: Vec<&Tensor> = params.iter().collect();
            let q_refs: Vec<&Tensor> = plain.iter().collect();
            let t_refs: Vec<&Tensor> = targets.iter().collect();
            let (mut a, mut b) = (Adam::new(&p_refs, 1e-2), Adam::new(&q_refs, 1e-2));
            for step in 0..3 {
                let before: Vec<Vec<f64>> = targets.iter().map(floats).collect();
                for (i, g) in fresh(10 + step).iter().enumerate() {
                    (&params[i] * g).sum(tch::Kind::Float).backward();
                    (&plain[i] * g).sum(tch::Kind::Float).backward();
                }
                crate::threads::with_parts(parts, || a.step_and_average(&p_refs, &t_refs, rho));
                b.step(&q_refs);
                for i in 0..shapes.len() {
                    assert!(params[i].equal(&plain[i]), "the step is not step()'s");
                    let (p, t) = (floats(&params[i]), floats(&targets[i]));
                    for ((t, t0), p) in t.iter().zip(&before[i]).zip(&p) {
                        let want = rho * t0 + (1.0 - rho) * p;
                        assert!(
                            (t - want).abs() <= 1e-6 * (1.0 + want.abs()),
                            "{t} vs {want}"
                        );
                    }
                    assert_eq!(
                        params[i]
                            .grad()
                            .abs()
                            .sum(tch::Kind::Float)
                            .double_value(&[]),
                        0.0
                    );
                }
            }
        }
    }

    /// The one-pass step (with and without averaging) gives the same bits in every compiled
    /// variant (AVX-512, AVX2, plain, as far as this CPU has them).
    #[test]
    fn every_instruction_set_steps_alike() {
        use crate::fused::{with_widest, Isa};
        let run = |isa: Isa| -> Vec<f32> {
            let v = |k: usize| -> Tensor {
                let x: Vec<f32> = (0..1001)
                    .map(|i| ((i * 7919 + k * 104729) % 2003) as f32 / 1000.0 - 1.0)
                    .collect();
                Tensor::from_slice(&x)
            };
            let (p, mut g, m, v2, t) = (v(1), v(2), v(3).abs(), v(4).abs(), v(5));
            let c = Adam::new(&[], 1e-2).constants(3);
            with_widest(isa, || {
                assert!(fused_step_in_place(&p, &g, &m, &v2, Some((&t, 0.005)), &c));
                let _ = g.copy_(&v(6));
                assert!(fused_step_in_place(&p, &g, &m, &v2, None, &c));
            });
            [p, m, v2, t]
                .iter()
                .flat_map(|x| Vec::<f32>::try_from(x).unwrap())
                .collect()
        };
        let widest = run(Isa::Avx512);
        for isa in [Isa::Avx2, Isa::Plain] {
            let other = run(isa);
            assert!(
                other
                    .iter()
                    .zip(&widest)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{isa:?} steps differently"
            );
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
