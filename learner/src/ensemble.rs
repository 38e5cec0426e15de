//! Stacked MLP ensembles: E networks of one shape held as weights `[E, in, out]` and biases
//! `[E, 1, out]`, evaluated for all members at once with batched matmuls.

use crate::matmul::{self, CpuGemm};
use crate::{fused, threads};
use rand::Rng;
use rand_pcg::Pcg64;
use tch::{Device, Kind, Tensor};

/// Rows (over all members) from which a forward without autograd is worth splitting over
/// threads: waking a thread costs tens of microseconds, a 256-wide layer about 0.2 µs a row.
pub const SPLIT_ROWS: i64 = 1024;

/// ε of the layer normalisation, PyTorch's `nn.LayerNorm` default.
pub const LAYER_NORM_EPS: f64 = 1e-5;

/// One stacked linear layer.
pub struct StackedLinear {
    pub weight: Tensor,
    pub bias: Tensor,
}

impl StackedLinear {
    /// Whether the layer has one output (a critic's Q), which is computed as a product and a
    /// row sum rather than a batched matmul: libtorch runs that matmul at about 1 GFLOP/s, three
    /// times slower.
    fn one_column(&self) -> bool {
        self.weight.size()[2] == 1
    }
}

/// E MLPs with ReLU between layers and a linear output.
pub struct Ensemble {
    pub layers: Vec<StackedLinear>,
    /// Element type the matmuls run in: `Float`, or `BFloat16` (bf16 inputs, fp32 accumulation
    /// and fp32 master weights) where the CPU or GPU has fast bf16 units.
    pub matmul: Kind,
    /// Who multiplies fp32 matrices on CPU where autograd is not recording ([`matmul`]);
    /// libtorch unless set. Where autograd records, libtorch multiplies whatever this says, so
    /// `Gemm` suits an ensemble none of whose evaluations autograd records (the critics), and
    /// an ensemble evaluated both ways keeps `Libtorch`, whose values are then the same both
    /// ways (an actor's KL to itself stays exactly 0).
    pub cpu_gemm: CpuGemm,
    /// AVTD's layer-norm variants: `[E, 1, 1]` booleans, true for the members whose hidden layers
    /// are normalised (before each ReLU, no learned scale or shift); `None`: no member is.
    pub layer_norm: Option<Tensor>,
}

impl Ensemble {
    /// `dims` = `[in, hidden…, out]`. Weights and biases start as PyTorch's `nn.Linear` does,
    /// `U(±1/√in)`, drawn from `rng` so that a seed fixes every member.
    pub fn new(members: usize, dims: &[usize], device: Device, rng: &mut Pcg64) -> Self {
        let layers = dims
            .windows(2)
            .map(|w| {
                let (n_in, n_out) = (w[0], w[1]);
                let bound = 1.0 / (n_in as f32).sqrt();
                let mut draw = |n: usize| -> Vec<f32> {
                    (0..n).map(|_| rng.gen_range(-bound..bound)).collect()
                };
                let wv = draw(members * n_in * n_out);
                let bv = draw(members * n_out);
                StackedLinear {
                    weight: param(&wv, &[members, n_in, n_out], device),
                    bias: param(&bv, &[members, 1, n_out], device),
                }
            })
            .collect();
        Self {
            layers,
            matmul: Kind::Float,
            cpu_gemm: CpuGemm::Libtorch,
            layer_norm: None,
        }
    }

    /// Normalises the hidden layers of the members flagged in `members` (see [`Self::layer_norm`]).
    pub fn with_layer_norm(mut self, members: &[bool]) -> Self {
        let device = self.layers[0].weight.device();
        self.layer_norm = members.contains(&true).then(|| {
            Tensor::from_slice(members)
                .view([-1, 1, 1])
                .to_device(device)
        });
        self
    }

    /// `x` is `[E, B, in]`; returns `[E, B, out]`.
    ///
    /// Without autograd and on CPU, a forward of at least [`SPLIT_ROWS`] rows in all is split by
    /// members over the learner's threads (as the targets' next actions and target critics at
    /// K = 5 are).
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let rows = self.layers[0].weight.size()[0] * x.size()[1];
        if rows < SPLIT_ROWS || fused::grad_mode() {
            return self.forward_taped(x).0;
        }
        let parts = self.parts();
        if parts.len() == 1 {
            return self.forward_taped(x).0;
        }
        let results = threads::run_parts(self.split(&parts, &[x]), |(part, x)| {
            tch::no_grad(|| part.forward_taped(&x[0]).0)
        });
        Tensor::cat(&results, 0)
    }

    /// [`Self::forward`], also returning what [`Self::backward`] needs: each layer's input.
    ///
    /// With bf16 matmuls the hidden activations stay bf16 from one matmul to the next (each
    /// matmul's bf16 output gets its bias and ReLU in place), since the next matmul would round
    /// them to bf16 anyway; a one-column output layer (a critic's Q) runs in fp32 on them, so
    /// that Q, and with it the TD error, keeps fp32's precision.
    pub fn forward_taped(&self, x: &Tensor) -> (Tensor, Tape) {
        let last = self.layers.len() - 1;
        let mut inputs = Vec::with_capacity(self.layers.len());
        let mut weights = Vec::with_capacity(self.layers.len());
        let mut h = self.in_matmul_kind(x);
        for (l, layer) in self.layers.iter().enumerate() {
            let w = self.matmul_weight(layer);
            let hidden = l < last;
            // The ReLU goes with the bias where no layer norm comes between them.
            let (z, rectified) = self.affine(&h, layer, &w, hidden && self.layer_norm.is_none());
            inputs.push(h);
            weights.push(w);
            h = z;
            if hidden {
                if let Some(flags) = &self.layer_norm {
                    // libtorch's fused layer norm, on the flagged members only.
                    let members = flags.view([-1]).nonzero().view([-1]);
                    let width = h.size()[2];
                    let norm = |t: &Tensor| {
                        t.layer_norm(
                            [width],
                            None::<Tensor>,
                            None::<Tensor>,
                            LAYER_NORM_EPS,
                            false,
                        )
                    };
                    if members.size()[0] == h.size()[0] {
                        h = norm(&h);
                    } else if members.size()[0] > 0 {
                        h = h.index_copy(0, &members, &norm(&h.index_select(0, &members)));
                    }
                }
                if !rectified {
                    // In place: `h` is a fresh result whose producer's backward does not need it.
                    let _ = h.relu_();
                }
            }
        }
        (h, Tape { inputs, weights })
    }

    /// The layer's weight in the matmuls' element type (itself for fp32, and for a one-column
    /// layer, which runs in fp32).
    fn matmul_weight(&self, layer: &StackedLinear) -> Tensor {
        if self.matmul == Kind::Float || layer.one_column() {
            layer.weight.shallow_clone()
        } else {
            self.in_matmul_kind(&layer.weight)
        }
    }

    /// `t` in the matmuls' element type (itself where it is already).
    fn in_matmul_kind(&self, t: &Tensor) -> Tensor {
        if self.matmul == Kind::BFloat16 && t.kind() == Kind::Float {
            if let Some(rounded) = fused::to_bf16(t) {
                return rounded;
            }
        }
        t.to_kind(self.matmul)
    }

    /// `h·W + b` for every member, and with `relu` where it can, its ReLU; `w` is the layer's
    /// weight from [`Self::matmul_weight`]. A hidden layer's output is in the matmuls' element
    /// type, a one-column output in fp32. Returns the output and whether the ReLU was applied.
    fn affine(&self, h: &Tensor, layer: &StackedLinear, w: &Tensor, relu: bool) -> (Tensor, bool) {
        if layer.one_column() {
            if let Some(q) = fused::one_output(h, w, &layer.bias) {
                return (q, false);
            }
            // With bf16 `h`, the product promotes to fp32.
            let q = (h * w.transpose(1, 2)).sum_dim_intlist(-1, true, Kind::Float) + &layer.bias;
            return (q, false);
        }
        // The bias and ReLU in one pass over the product (`baddbmm` would first copy the bias
        // into every row, and the ReLU be a third pass).
        let mut z = matmul::bmm(self.cpu_gemm, h, w);
        if fused::bias_relu_(&z, &layer.bias, relu) {
            return (z, relu);
        }
        let _ = z.g_add_(&layer.bias);
        (z, false)
    }

    /// Whether [`Self::backward`] can differentiate this ensemble by hand: no layer norm (an
    /// ensemble with it goes through autograd).
    pub fn has_hand_backward(&self) -> bool {
        self.layer_norm.is_none()
    }

    /// Adds to each parameter's `.grad` the gradient of a loss whose gradient with respect to
    /// the output of [`Self::forward_taped`] is `d_out` (`[E, B, out]`). By hand rather than by
    /// autograd: each layer's backward is its two matmuls, a row sum and the ReLU's mask, with no
    /// graph to build or walk (at the paper's sizes, fp32 on CPU, about as fast as autograd,
    /// since the matmuls dominate; with bf16 it skips autograd's casts, 11.5 against 13.8 ms per
    /// critic forward and backward on a Xeon with AMX; on a GPU what it saves is per-operation
    /// overhead, which is what bounds small updates there). Needs [`Self::has_hand_backward`].
    pub fn backward(&self, tape: &Tape, d_out: &Tensor) {
        self.backward_into(tape, d_out, Some(&self.grads()), false);
    }

    /// Each layer's (weight, bias) gradient tensors, created as zeros where none exists yet.
    fn grads(&self) -> Vec<(Tensor, Tensor)> {
        self.layers
            .iter()
            .map(|l| (grad_of(&l.weight), grad_of(&l.bias)))
            .collect()
    }

    /// [`Self::backward`], adding onto the given gradient tensors (`grads`, one (weight, bias)
    /// pair per layer, shaped as the parameters), or with `None` leaving the parameters'
    /// gradients alone; with `input`, also returns the gradient at the ensemble's input.
    fn backward_into(
        &self,
        tape: &Tape,
        d_out: &Tensor,
        grads: Option<&[(Tensor, Tensor)]>,
        input: bool,
    ) -> Option<Tensor> {
        assert!(
            self.has_hand_backward(),
            "no hand backward for this ensemble"
        );
        let train = grads.is_some();
        // Without parameter gradients the fused kernels still add their bias sums (and a
        // one-column layer's weight gradient) somewhere: small scratch tensors.
        let scratch: Vec<(Tensor, Tensor)> = if train {
            vec![]
        } else {
            tch::no_grad(|| {
                self.layers
                    .iter()
                    .map(|l| {
                        let dw = if l.one_column() {
                            l.weight.zeros_like()
                        } else {
                            Tensor::new()
                        };
                        (dw, l.bias.zeros_like())
                    })
                    .collect()
            })
        };
        let grads = grads.unwrap_or(&scratch);
        tch::no_grad(|| {
            let mut dz = d_out.shallow_clone();
            // Whether `dz`'s row sums are already in the layer's bias gradient (the fused
            // kernels add them as they produce `dz`).
            let mut bias_done = false;
            for (l, layer) in self.layers.iter().enumerate().rev() {
                let (input_l, w) = (&tape.inputs[l], &tape.weights[l]);
                let (dw, db) = &grads[l];
                let (mut dw, mut db) = (dw.shallow_clone(), db.shallow_clone());
                let one_column = layer.one_column();
                if one_column && l > 0 {
                    let db_below = &grads[l - 1].1;
                    if let Some(dz_below) =
                        fused::one_output_backward(&dz, input_l, w, &dw, &db, db_below)
                    {
                        (dz, bias_done) = (dz_below, true);
                        continue;
                    }
                }
                if !bias_done {
                    let _ = db.g_add_(&dz.sum_dim_intlist(1, true, Kind::Float));
                }
                if !one_column {
                    // bf16 operands (a no-op for fp32, and for a `dz` already bf16).
                    dz = self.in_matmul_kind(&dz);
                }
                if one_column {
                    // fp32, as in the forward (with bf16 `input_l`, the product promotes).
                    let _ = dw.g_add_(
                        &(input_l * &dz)
                            .sum_dim_intlist(1, true, Kind::Float)
                            .transpose(1, 2),
                    );
                } else if train && self.matmul == Kind::Float {
                    matmul::baddbmm_(self.cpu_gemm, &dw, &input_l.transpose(1, 2), &dz);
                } else if train {
                    // The bf16 product is added onto the fp32 gradient.
                    let product = input_l.transpose(1, 2).bmm(&dz);
                    if !fused::add_bf16_(&dw, &product) {
                        let _ = dw.g_add_(&product);
                    }
                }
                bias_done = false;
                if l > 0 || input {
                    let w_t = w.transpose(1, 2);
                    let dh = if one_column {
                        // In the element type of the layer's input, which the mask below keeps.
                        dz.to_kind(input_l.kind()) * w_t.to_kind(input_l.kind())
                    } else {
                        matmul::bmm(self.cpu_gemm, &dz, &w_t)
                    };
                    if l == 0 {
                        return Some(dh.to_kind(Kind::Float));
                    }
                    // `input_l` is the previous layer's ReLU output: positive exactly where its
                    // pre-activation was.
                    if fused::relu_backward_(&dh, input_l, &grads[l - 1].1) {
                        (dz, bias_done) = (dh, true);
                    } else {
                        dz = input_l.threshold_backward(&dh, 0.0);
                    }
                }
            }
            None
        })
    }

    /// The outputs on `x` (`[E, R, in]`) of members held fixed: no gradient reaches their
    /// parameters, but autograd reaches `x` (critics judging an actor's actions). By hand where
    /// [`Self::has_hand_backward`] and the output is one column (each output row depends on its
    /// own input row only, so one backward of ones gives every row's ∂q/∂x, and
    /// `q + Σ (x − x̄)·∂q/∂x`, with x̄ = x held constant, has q's value and that gradient);
    /// through autograd otherwise.
    pub fn forward_fixed(&self, x: &Tensor) -> Tensor {
        if !self.has_hand_backward() || !self.layers.last().is_some_and(|l| l.one_column()) {
            return self.detached().forward(x);
        }
        let results = threads::run_parts(self.split(&self.parts(), &[&x.detach()]), |(part, x)| {
            tch::no_grad(|| {
                let (q, tape) = part.forward_taped(&x[0]);
                let dq_dx = part.backward_into(&tape, &q.ones_like(), None, true);
                (q, dq_dx.expect("the input's gradient"))
            })
        });
        let (q, dq_dx) = cat_parts(results);
        q + ((x - x.detach()) * dq_dx).sum_dim_intlist(-1, true, Kind::Float)
    }

    /// Every member's regression loss against its own targets `y` (`[E, B]`),
    /// `mean_rows ½ (out − y)²` (`[E]`), with its gradient added to the parameters' `.grad`
    /// (by hand where [`Self::has_hand_backward`], else by autograd). `x` is `[E, B, in]` and the
    /// output one column wide; returns the outputs `[E, B]` and the losses, both without graph.
    pub fn regress(&self, x: &Tensor, y: &Tensor) -> (Tensor, Tensor) {
        if !self.has_hand_backward() {
            let q = self.forward(x).squeeze_dim(-1);
            let loss = half_mean_square(&q, y);
            loss.sum(Kind::Float).backward();
            return (q.detach(), loss.detach());
        }
        self.regress_in_parts(x, y, &self.parts())
    }

    /// How the members split over the learner's threads (see `threads`): on CPU, in parts;
    /// elsewhere whole.
    fn parts(&self) -> Vec<(usize, usize)> {
        let members = self.layers[0].weight.size()[0] as usize;
        if self.layers[0].weight.device() == Device::Cpu {
            threads::member_parts(members)
        } else {
            vec![(0, members)]
        }
    }

    /// [`Self::regress`] by hand, the members in `parts` (`(start, len)`, covering them all in
    /// order) each regressing on its own thread on its own rows, adding into its own slice of
    /// the gradients.
    fn regress_in_parts(
        &self,
        x: &Tensor,
        y: &Tensor,
        parts: &[(usize, usize)],
    ) -> (Tensor, Tensor) {
        let mut tensors = vec![x, y];
        let grads = self.grads();
        tensors.extend(grads.iter().flat_map(|(w, b)| [w, b]));
        let results = threads::run_parts(self.split(parts, &tensors), |(part, t)| {
            tch::no_grad(|| {
                let (x, y) = (&t[0], &t[1]);
                let grads: Vec<(Tensor, Tensor)> = t[2..]
                    .chunks(2)
                    .map(|wb| (wb[0].shallow_clone(), wb[1].shallow_clone()))
                    .collect();
                let (q, tape) = part.forward_taped(x);
                let q = q.squeeze_dim(-1);
                let rows = q.size()[1] as f64;
                // d/dq of Σ_e mean_rows ½ (q − y)²: member e's own loss alone reaches its weights.
                let d_q = ((&q - y) / rows).unsqueeze(-1);
                part.backward_into(&tape, &d_q, Some(&grads), false);
                let loss = half_mean_square(&q, y);
                (q, loss)
            })
        });
        cat_parts(results)
    }

    /// For each part (`(start, len)` of the members), the sub-ensemble of those members (no
    /// gradient) and each of `tensors` narrowed to them; a tensor one member wide is meant for
    /// every member (broadcast) and goes to every part whole.
    fn split(&self, parts: &[(usize, usize)], tensors: &[&Tensor]) -> Vec<(Ensemble, Vec<Tensor>)> {
        parts
            .iter()
            .map(|&(start, len)| {
                let part = |t: &Tensor| t.detach().narrow(0, start as i64, len as i64);
                let narrowed = tensors
                    .iter()
                    .map(|t| {
                        if t.size()[0] == 1 {
                            t.shallow_clone()
                        } else {
                            part(t)
                        }
                    })
                    .collect();
                (self.map(part), narrowed)
            })
            .collect()
    }

    /// The same members with gradients cut (for a loss that must not train this ensemble).
    pub fn detached(&self) -> Ensemble {
        self.map(|t| t.detach())
    }

    /// A sub-ensemble of the members at `index` (a 1-D int64 tensor; repeats allowed), no gradient.
    pub fn select(&self, index: &Tensor) -> Ensemble {
        self.map(|t| t.detach().index_select(0, index))
    }

    /// Member `i` alone, as a one-member ensemble without gradient.
    pub fn member(&self, i: i64) -> Ensemble {
        self.map(|t| t.detach().narrow(0, i, 1))
    }

    /// A deep copy with no gradient tracking (e.g. the target critics).
    pub fn copy(&self) -> Ensemble {
        self.map(|t| t.detach().copy())
    }

    fn map(&self, f: impl Fn(&Tensor) -> Tensor) -> Ensemble {
        Ensemble {
            layers: self
                .layers
                .iter()
                .map(|l| StackedLinear {
                    weight: f(&l.weight),
                    bias: f(&l.bias),
                })
                .collect(),
            matmul: self.matmul,
            cpu_gemm: self.cpu_gemm,
            // The flags follow the members (`f` selects, narrows or copies along dimension 0).
            layer_norm: self.layer_norm.as_ref().map(&f),
        }
    }

    pub fn params(&self) -> Vec<&Tensor> {
        self.layers
            .iter()
            .flat_map(|l| [&l.weight, &l.bias])
            .collect()
    }

    pub fn named_params(&self, prefix: &str) -> Vec<(String, &Tensor)> {
        self.layers
            .iter()
            .enumerate()
            .flat_map(|(i, l)| {
                [
                    (format!("{prefix}.{i}.weight"), &l.weight),
                    (format!("{prefix}.{i}.bias"), &l.bias),
                ]
            })
            .collect()
    }

    /// Member `i`'s parameters as one flat vector, in `selkd_policy`'s layout
    /// (each layer's weight `[in][out]` row-major, then its bias).
    pub fn member_flat(&self, i: i64) -> Vec<f32> {
        let parts: Vec<Tensor> = self
            .params()
            .iter()
            .map(|t| t.detach().get(i).reshape([-1]))
            .collect();
        let flat = Tensor::cat(&parts, 0)
            .to_device(Device::Cpu)
            .to_kind(Kind::Float);
        Vec::<f32>::try_from(&flat).expect("f32 parameters")
    }

    /// `self ← ρ·self + (1 − ρ)·online`, member by member (Polyak averaging).
    /// On CPU, split by members over the learner's threads.
    pub fn polyak_toward(&mut self, online: &Ensemble, rho: f64) {
        // Each part's members are views of this ensemble's parameters: `lerp_` writes them.
        let jobs: Vec<((Ensemble, Vec<Tensor>), f64)> = self
            .split(&self.parts(), &online.params())
            .into_iter()
            .map(|job| (job, 1.0 - rho))
            .collect();
        threads::run_parts(jobs, |((part, online), weight)| {
            tch::no_grad(|| {
                for (t, o) in part.params().into_iter().zip(&online) {
                    let _ = t.shallow_clone().lerp_(o, weight);
                }
            })
        });
    }
}

/// Two results per part of the members, each joined along the members.
fn cat_parts(results: Vec<(Tensor, Tensor)>) -> (Tensor, Tensor) {
    let (a, b): (Vec<Tensor>, Vec<Tensor>) = results.into_iter().unzip();
    if a.len() == 1 {
        return (a[0].shallow_clone(), b[0].shallow_clone());
    }
    (Tensor::cat(&a, 0), Tensor::cat(&b, 0))
}

/// What [`Ensemble::forward_taped`] keeps for [`Ensemble::backward`]: the input of every layer,
/// and its weight as the matmul used it (bf16 weights are converted once per forward).
pub struct Tape {
    inputs: Vec<Tensor>,
    weights: Vec<Tensor>,
}

/// `mean_rows ½ (q − y)²` per member of `[E, B]` values and targets, `[E]`.
pub fn half_mean_square(q: &Tensor, y: &Tensor) -> Tensor {
    ((q - y).square() * 0.5).mean_dim(1, false, Kind::Float)
}

/// `p`'s gradient tensor, defined as zeros if no backward has reached `p` yet (tch has no
/// setter for `.grad`; a zero backward is how to create it).
fn grad_of(p: &Tensor) -> Tensor {
    if !p.grad().defined() {
        (p * 0.0).sum(Kind::Float).backward();
    }
    p.grad()
}

fn param(values: &[f32], shape: &[usize], device: Device) -> Tensor {
    let shape: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
    Tensor::from_slice(values)
        .view(shape.as_slice())
        .to_device(device)
        .set_requires_grad(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use selkd_policy::{Actor, ActorLayout};

    #[test]
    fn each_member_is_an_independent_mlp_matching_the_plain_forward() {
        let mut rng = Pcg64::seed_from_u64(3);
        let ens = Ensemble::new(3, &[4, 8, 8, 2 * 2], Device::Cpu, &mut rng);
        let obs: Vec<f32> = vec![0.3, -1.2, 0.7, 2.0];
        let x = Tensor::from_slice(&obs)
            .view([1, 1, 4])
            .expand([3, 1, 4], false);
        let out = ens.forward(&x);
        for i in 0..3 {
            let actor =
                Actor::from_flat(ActorLayout::new(4, 2, &[8, 8]), ens.member_flat(i)).unwrap();
            let (mu, ls) = actor.mean_log_std(&obs);
            let row = Vec::<f32>::try_from(out.get(i).reshape([-1])).unwrap();
            for d in 0..2 {
                assert!((row[d] - mu[d]).abs() < 1e-5);
                assert!((row[2 + d].clamp(-20.0, 2.0) - ls[d]).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn bf16_matmuls_stay_close_to_fp32_and_train_fp32_weights() {
        let mut rng = Pcg64::seed_from_u64(5);
        let mut ens = Ensemble::new(4, &[12, 64, 64, 1], Device::Cpu, &mut rng);
        let x = Tensor::randn([4, 32, 12], (Kind::Float, Device::Cpu));
        let exact = ens.forward(&x);
        ens.matmul = Kind::BFloat16;
        let fast = ens.forward(&x);
        assert_eq!(fast.kind(), Kind::Float);
        let rel =
            ((&fast - &exact).abs().max().double_value(&[])) / exact.abs().max().double_value(&[]);
        assert!(rel < 2e-2, "bf16 forward strays {rel} from fp32");
        // ... and is bf16: its rounding shows (an fp32 forward would match to about 1e-7).
        assert!(
            rel > 1e-4,
            "bf16 forward equals fp32's ({rel}): not run in bf16"
        );
        fast.sum(Kind::Float).backward();
        assert_eq!(ens.layers[0].weight.grad().kind(), Kind::Float);
    }

    /// Layer norm against a plain f64 computation: normalised (mean 0, variance 1 with ε, no
    /// scale or shift) before each hidden ReLU for the flagged member only; a selection of
    /// members keeps each member's flag.
    #[test]
    fn layer_norm_normalises_the_hidden_layers_of_flagged_members_only() {
        let mut rng = Pcg64::seed_from_u64(8);
        let ens =
            Ensemble::new(2, &[3, 5, 4, 1], Device::Cpu, &mut rng).with_layer_norm(&[true, false]);
        let x: Vec<f32> = vec![0.4, -1.5, 2.2];
        let plain = |i: i64, normalise: bool| -> f64 {
            let mut h: Vec<f64> = x.iter().map(|&v| v as f64).collect();
            let last = ens.layers.len() - 1;
            for (l, layer) in ens.layers.iter().enumerate() {
                let (w, b) = (layer.weight.get(i), layer.bias.get(i));
                let (n_in, n_out) = (w.size()[0], w.size()[1]);
                let mut out: Vec<f64> = (0..n_out)
                    .map(|o| {
                        b.double_value(&[0, o])
                            + (0..n_in)
                                .map(|k| h[k as usize] * w.double_value(&[k, o]))
                                .sum::<f64>()
                    })
                    .collect();
                if l < last {
                    if normalise {
                        let n = out.len() as f64;
                        let mean = out.iter().sum::<f64>() / n;
                        let var = out.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
                        out.iter_mut()
                            .for_each(|v| *v = (*v - mean) / (var + LAYER_NORM_EPS).sqrt());
                    }
                    out.iter_mut().for_each(|v| *v = v.max(0.0));
                }
                h = out;
            }
            h[0]
        };
        let input = Tensor::from_slice(&x)
            .view([1, 1, 3])
            .expand([2, 1, 3], false);
        let out = Vec::<f32>::try_from(ens.forward(&input).reshape([-1])).unwrap();
        for (i, normalise) in [(0, true), (1, false)] {
            let want = plain(i, normalise);
            assert!(
                (out[i as usize] as f64 - want).abs() < 1e-5,
                "member {i}: {} vs {want}",
                out[i as usize]
            );
        }
        // The unnormalised answer differs, so the check above can tell the two apart.
        assert!((plain(0, false) - plain(0, true)).abs() > 1e-3);
        // Selecting members [1, 0] carries their flags along.
        let swapped = ens.select(&Tensor::from_slice(&[1i64, 0]));
        let out = Vec::<f32>::try_from(swapped.forward(&input).reshape([-1])).unwrap();
        assert!((out[0] as f64 - plain(1, false)).abs() < 1e-5);
        assert!((out[1] as f64 - plain(0, true)).abs() < 1e-5);
    }

    /// Every parameter's gradient from [`Ensemble::backward`] against libtorch's autograd on the
    /// same forward: one- and two-column outputs, inputs shared by every member (expanded, as
    /// the critics get them) or each member's own, and added onto gradients already there; with
    /// the hand path's products by libtorch and by the `gemm` crate (autograd's by libtorch).
    #[test]
    fn the_hand_backward_matches_autograd() {
        for (dims, shared, cpu_gemm) in [
            (vec![5, 16, 12, 1], true, CpuGemm::Libtorch),
            (vec![5, 16, 12, 1], false, CpuGemm::Libtorch),
            (vec![3, 8, 2], false, CpuGemm::Libtorch),
            (vec![5, 16, 12, 1], true, CpuGemm::Gemm),
            (vec![5, 16, 12, 1], false, CpuGemm::Gemm),
            (vec![3, 8, 2], false, CpuGemm::Gemm),
        ] {
            let mut rng = Pcg64::seed_from_u64(11);
            let mut ens = Ensemble::new(3, &dims, Device::Cpu, &mut rng);
            ens.cpu_gemm = cpu_gemm;
            let x = if shared {
                Tensor::randn([1, 7, dims[0] as i64], (Kind::Float, Device::Cpu))
                    .expand([3, 7, dims[0] as i64], false)
            } else {
                Tensor::randn([3, 7, dims[0] as i64], (Kind::Float, Device::Cpu))
            };
            let out_width = *dims.last().unwrap() as i64;
            let d_out = Tensor::randn([3, 7, out_width], (Kind::Float, Device::Cpu));
            let by_autograd: Vec<Tensor> = {
                (ens.forward(&x) * &d_out).sum(Kind::Float).backward();
                ens.params().iter().map(|p| p.grad().copy()).collect()
            };
            // Twice by hand: the gradients add up.
            let (out, tape) = tch::no_grad(|| ens.forward_taped(&x));
            ens.backward(&tape, &d_out);
            ens.backward(&tape, &d_out);
            assert!(out.allclose(&ens.forward(&x), 1e-6, 1e-6, false));
            for (l, (p, want)) in ens.params().iter().zip(&by_autograd).enumerate() {
                let got = p.grad();
                let err = (&got - want * 3.0).abs().max().double_value(&[]);
                let scale = want.abs().max().double_value(&[]);
                assert!(scale > 1e-3, "parameter {l} has no gradient to compare");
                assert!(
                    err <= 1e-5 * scale,
                    "{dims:?} shared {shared} {cpu_gemm:?}: parameter {l} off by {err} (scale {scale})"
                );
            }
        }
    }

    /// bf16 matmuls: the hand backward against autograd on the same bf16 forward (both round
    /// their matmuls' operands to bf16, so they agree to bf16's precision, not fp32's).
    #[test]
    fn the_bf16_hand_backward_matches_autograd() {
        let mut rng = Pcg64::seed_from_u64(13);
        let mut ens = Ensemble::new(3, &[5, 32, 24, 1], Device::Cpu, &mut rng);
        ens.matmul = Kind::BFloat16;
        let x = Tensor::randn([3, 16, 5], (Kind::Float, Device::Cpu));
        let d_out = Tensor::randn([3, 16, 1], (Kind::Float, Device::Cpu));
        (ens.forward(&x) * &d_out).sum(Kind::Float).backward();
        let by_autograd: Vec<Tensor> = ens.params().iter().map(|p| p.grad().copy()).collect();
        for p in ens.params() {
            let _ = p.grad().zero_();
        }
        let (out, tape) = tch::no_grad(|| ens.forward_taped(&x));
        assert_eq!(out.kind(), Kind::Float);
        ens.backward(&tape, &d_out);
        for (l, (p, want)) in ens.params().iter().zip(&by_autograd).enumerate() {
            let got = p.grad();
            assert_eq!(got.kind(), Kind::Float);
            let err = (&got - want).abs().max().double_value(&[]);
            let scale = want.abs().max().double_value(&[]);
            assert!(scale > 1e-3, "parameter {l} has no gradient to compare");
            assert!(
                err <= 2e-2 * scale,
                "parameter {l} off by {err} (scale {scale})"
            );
        }
    }

    /// `regress`'s losses against a plain loop, and its gradients against autograd's of the
    /// same loss; an ensemble with layer norm takes the autograd path and gets the same answer.
    #[test]
    fn regress_gives_each_members_squared_error_and_its_gradient() {
        for (layer_norm, cpu_gemm) in [
            (false, CpuGemm::Libtorch),
            (true, CpuGemm::Libtorch),
            (false, CpuGemm::Gemm),
        ] {
            let mut rng = Pcg64::seed_from_u64(12);
            let mut ens = Ensemble::new(2, &[4, 10, 10, 1], Device::Cpu, &mut rng);
            ens.cpu_gemm = cpu_gemm;
            if layer_norm {
                ens = ens.with_layer_norm(&[true, false]);
            }
            let x = Tensor::randn([2, 6, 4], (Kind::Float, Device::Cpu));
            let y = Tensor::randn([2, 6], (Kind::Float, Device::Cpu));
            let (q, loss) = ens.regress(&x, &y);
            let grads: Vec<Tensor> = ens.params().iter().map(|p| p.grad().copy()).collect();
            let (qv, yv) = (
                Vec::<f32>::try_from(q.reshape([-1])).unwrap(),
                Vec::<f32>::try_from(y.reshape([-1])).unwrap(),
            );
            let lv = Vec::<f32>::try_from(&loss).unwrap();
            for e in 0..2 {
                let want: f64 = (0..6)
                    .map(|r| 0.5 * ((qv[e * 6 + r] - yv[e * 6 + r]) as f64).powi(2))
                    .sum::<f64>()
                    / 6.0;
                assert!((lv[e] as f64 - want).abs() < 1e-5 * want.max(1.0));
            }
            for p in ens.params() {
                let _ = p.grad().zero_();
            }
            let q = ens.forward(&x).squeeze_dim(-1);
            (((&q - &y).square() * 0.5).mean_dim(1, false, Kind::Float))
                .sum(Kind::Float)
                .backward();
            for (g, p) in grads.iter().zip(ens.params()) {
                assert!(g.allclose(&p.grad(), 1e-5, 1e-6, false));
            }
        }
    }

    /// The members split over threads give what one thread gives: outputs, losses and every
    /// gradient, fp32 and bf16, with inputs and targets shared by every member or each member's own.
    #[test]
    fn regress_split_over_threads_matches_one_thread() {
        for (matmul, shared) in [
            (Kind::Float, true),
            (Kind::Float, false),
            (Kind::BFloat16, true),
        ] {
            let mut rng = Pcg64::seed_from_u64(21);
            let mut ens = Ensemble::new(5, &[6, 32, 32, 1], Device::Cpu, &mut rng);
            ens.matmul = matmul;
            // Shared: one batch expanded to every member (as the critics get it) and one target
            // row broadcast to all (as `per-update` sharing gives it).
            let rows = if shared { 1 } else { 5 };
            let x =
                Tensor::randn([rows, 20, 6], (Kind::Float, Device::Cpu)).expand([5, 20, 6], false);
            let y = Tensor::randn([rows, 20], (Kind::Float, Device::Cpu));
            let mut answers = vec![];
            for parts in [vec![(0, 5)], vec![(0, 2), (2, 1), (3, 2)]] {
                for p in ens.params() {
                    if p.grad().defined() {
                        let _ = p.grad().zero_();
                    }
                }
                let (q, loss) = ens.regress_in_parts(&x, &y, &parts);
                let grads: Vec<Tensor> = ens.params().iter().map(|p| p.grad().copy()).collect();
                answers.push((q, loss, grads));
            }
            let ((q1, l1, g1), (q3, l3, g3)) = (&answers[0], &answers[1]);
            assert_eq!(q3.size(), [5, 20]);
            assert!(
                q1.allclose(q3, 1e-6, 1e-6, false),
                "{matmul:?}: outputs differ"
            );
            assert!(
                l1.allclose(l3, 1e-6, 1e-6, false),
                "{matmul:?}: losses differ"
            );
            for (l, (a, b)) in g1.iter().zip(g3).enumerate() {
                assert!(
                    a.abs().max().double_value(&[]) > 1e-4,
                    "parameter {l}: no gradient"
                );
                assert!(
                    a.allclose(b, 1e-5, 1e-6, false),
                    "{matmul:?}: parameter {l} differs"
                );
            }
        }
    }

    /// A forward without autograd, split over threads, gives what the whole ensemble's does.
    #[test]
    fn a_forward_split_over_threads_matches_one_thread() {
        let mut rng = Pcg64::seed_from_u64(41);
        let ens = Ensemble::new(5, &[6, 32, 4], Device::Cpu, &mut rng);
        let x = Tensor::randn([5, 256, 6], (Kind::Float, Device::Cpu));
        assert!(5 * 256 >= SPLIT_ROWS);
        let whole = tch::no_grad(|| ens.forward_taped(&x).0);
        let split = crate::threads::with_parts(3, || tch::no_grad(|| ens.forward(&x)));
        assert_eq!(split.size(), [5, 256, 4]);
        assert!(split.allclose(&whole, 1e-6, 1e-6, false));
    }

    /// `forward_fixed` against autograd through the detached members: the same values, the same
    /// gradient at the input (here through a function of it, as an actor's action reaches the
    /// critics), and none at the members' parameters; fp32 and bf16, one part and three.
    #[test]
    fn forward_fixed_is_differentiable_in_the_input_only() {
        for (matmul, parts) in [
            (Kind::Float, 1),
            (Kind::Float, 3),
            (Kind::BFloat16, 1),
            (Kind::BFloat16, 3),
        ] {
            let mut rng = Pcg64::seed_from_u64(31);
            let mut ens = Ensemble::new(5, &[6, 32, 32, 1], Device::Cpu, &mut rng);
            ens.matmul = matmul;
            let source =
                Tensor::randn([1, 20, 6], (Kind::Float, Device::Cpu)).set_requires_grad(true);
            let d_out = Tensor::randn([5, 20, 1], (Kind::Float, Device::Cpu));
            let x = || (&source * 1.5).tanh().expand([5, 20, 6], false);
            let want = ens.detached().forward(&x());
            (&want * &d_out).sum(Kind::Float).backward();
            let want_grad = source.grad().copy();
            let _ = source.grad().zero_();
            let got = if parts == 1 {
                ens.forward_fixed(&x())
            } else {
                crate::threads::with_parts(parts, || ens.forward_fixed(&x()))
            };
            (&got * &d_out).sum(Kind::Float).backward();
            let got_grad = source.grad();
            let tol = if matmul == Kind::Float { 1e-5 } else { 2e-2 };
            let scale = want.abs().max().double_value(&[]);
            let err = (&got - &want).abs().max().double_value(&[]);
            assert!(
                err <= tol * scale,
                "{matmul:?} {parts}: values off by {err}"
            );
            let scale = want_grad.abs().max().double_value(&[]);
            let err = (&got_grad - &want_grad).abs().max().double_value(&[]);
            assert!(scale > 1e-3);
            assert!(
                err <= tol * scale,
                "{matmul:?} {parts}: input gradient off by {err} (scale {scale})"
            );
            for p in ens.params() {
                assert!(!p.grad().defined(), "a parameter got a gradient");
            }
        }
    }

    #[test]
    fn polyak_moves_targets_by_one_minus_rho() {
        let mut rng = Pcg64::seed_from_u64(4);
        let online = Ensemble::new(2, &[3, 5, 1], Device::Cpu, &mut rng);
        let mut target = Ensemble::new(2, &[3, 5, 1], Device::Cpu, &mut rng).copy();
        let before = target.member_flat(1);
        // Split over threads as the learner runs it.
        crate::threads::with_parts(2, || target.polyak_toward(&online, 0.995));
        let after = target.member_flat(1);
        let on = online.member_flat(1);
        for k in 0..before.len() {
            let want = 0.995 * before[k] + 0.005 * on[k];
            assert!((after[k] - want).abs() < 1e-6);
        }
    }
}
