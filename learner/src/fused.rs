//! Fused CPU kernels for the ensembles' element-wise work, over f32 or bf16 activations.
//!
//! libtorch runs each element-wise step of a layer as its own pass, and with bf16 slowly
//! (0.3–0.9 ms per step on a critic layer's `[10, 256, 256]` at one thread on a Xeon, where the
//! pass itself needs tens of microseconds). These kernels do a layer's bias and ReLU, or a
//! backward's mask, product and sums, in one pass over contiguous CPU memory, compiled for
//! AVX-512 or AVX2 where the CPU has them. Each one checks its tensors and does nothing where it
//! does not apply (another device, layout or element type, or an output that autograd tracks):
//! the caller then takes the tensor operations, which compute the same thing.
//!
//! bf16 rounding is libtorch's: to nearest, ties to even (and NaN to a NaN). Sums run in f32.

use tch::{Device, Kind, Tensor};

/// An element type the kernels read and write.
pub trait Elem: Copy + Send + Sync {
    const KIND: Kind;
    fn load(self) -> f32;
    fn store(x: f32) -> Self;
}

impl Elem for f32 {
    const KIND: Kind = Kind::Float;
    #[inline(always)]
    fn load(self) -> f32 {
        self
    }
    #[inline(always)]
    fn store(x: f32) -> Self {
        x
    }
}

/// A bfloat16, as its bits: the upper half of an f32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(transparent)]
pub struct Bf16(pub u16);

impl Elem for Bf16 {
    const KIND: Kind = Kind::BFloat16;
    #[inline(always)]
    fn load(self) -> f32 {
        f32::from_bits((self.0 as u32) << 16)
    }
    #[inline(always)]
    fn store(x: f32) -> Self {
        let bits = x.to_bits();
        // Round to nearest, ties to even: add just under half of the dropped part's unit, plus
        // one where the kept part is odd. Branch-free, so that the loops vectorise.
        let rounded = (bits.wrapping_add(0x7FFF + ((bits >> 16) & 1)) >> 16) as u16;
        Bf16(if x.is_nan() { 0x7FC0 } else { rounded })
    }
}

/// `t`'s elements, if it is a contiguous CPU tensor of `T` with `n` elements.
///
/// SAFETY: the caller makes sure that no two slices it holds at once that share storage are
/// written, and that nothing else uses the storage meanwhile.
// The slice borrows the tensor's storage, not the `Tensor` handle (a shared reference to that
// storage, as libtorch's in-place operations take it); the aliasing rule is the caller's, above.
#[allow(clippy::mut_from_ref)]
unsafe fn elems<'a, T: Elem>(t: &'a Tensor, n: usize) -> Option<&'a mut [T]> {
    let fits =
        t.device() == Device::Cpu && t.kind() == T::KIND && t.is_contiguous() && t.numel() == n;
    fits.then(|| std::slice::from_raw_parts_mut(t.data_ptr() as *mut T, n))
}

/// Whether the kernels may compute from `inputs` behind autograd's back: a result of theirs
/// would not be tracked now (grad mode off, or none of them needs a gradient).
pub(crate) fn untracked(inputs: &[&Tensor]) -> bool {
    !grad_mode() || inputs.iter().all(|t| !t.requires_grad())
}

/// Whether autograd records operations on this thread now (tch has no query for it: setting
/// the mode returns the one before, which is put back at once).
pub fn grad_mode() -> bool {
    // SAFETY: plain calls into libtorch's thread-local grad mode, which is left as it was.
    unsafe {
        let before = torch_sys::at_grad_set_enabled(0);
        torch_sys::at_grad_set_enabled(before);
        before != 0
    }
}

/// `[E, B, O]` of a three-dimensional tensor.
fn dims3(t: &Tensor) -> Option<(usize, usize, usize)> {
    match t.size()[..] {
        [e, b, o] => Some((e as usize, b as usize, o as usize)),
        _ => None,
    }
}

/// `vectorised! { fn name<T>(args) { body } }` (`<T>`, an [`Elem`], optional) defines `name`,
/// which runs `body` compiled for AVX-512 where the CPU has it (its loops then run sixteen lanes
/// wide: 1.2× the whole bf16 update at two threads on a Xeon, against AVX2), else for AVX2
/// (eight), else as it is; without FMA, so that every CPU rounds alike. (A body passed as a
/// closure is not reliably inlined into a `#[target_feature]` function, and compiled on its own
/// it gets no AVX2.)
macro_rules! vectorised {
    ($(fn $name:ident $(<$t:ident>)? ($($arg:ident: $ty:ty),* $(,)?) $body:block)*) => {$(
        fn $name $(<$t: $crate::fused::Elem>)? ($($arg: $ty),*) {
            #[inline(always)]
            fn body $(<$t: $crate::fused::Elem>)? ($($arg: $ty),*) $body
            #[cfg(target_arch = "x86_64")]
            if $crate::fused::may_use($crate::fused::Isa::Avx512)
                && std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
            {
                #[target_feature(enable = "avx512f,avx512bw")]
                unsafe fn avx512 $(<$t: $crate::fused::Elem>)? ($($arg: $ty),*) {
                    body $(::<$t>)? ($($arg),*)
                }
                // SAFETY: the CPU has AVX-512 F and BW.
                return unsafe { avx512 $(::<$t>)? ($($arg),*) };
            }
            #[cfg(target_arch = "x86_64")]
            if $crate::fused::may_use($crate::fused::Isa::Avx2)
                && std::arch::is_x86_feature_detected!("avx2")
            {
                #[target_feature(enable = "avx2")]
                unsafe fn avx2 $(<$t: $crate::fused::Elem>)? ($($arg: $ty),*) {
                    body $(::<$t>)? ($($arg),*)
                }
                // SAFETY: the CPU has AVX2.
                return unsafe { avx2 $(::<$t>)? ($($arg),*) };
            }
            body $(::<$t>)? ($($arg),*)
        }
    )*};
}
pub(crate) use vectorised;

/// The instruction sets [`vectorised!`] compiles its bodies for, narrowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Isa {
    #[allow(dead_code)] // named by the tests only
    Plain,
    Avx2,
    Avx512,
}

/// Whether the kernels may run their `isa` variant (where the CPU has it): always, but in tests,
/// which pin narrower variants ([`with_widest`]) to check that all of them compute the same bits.
#[inline(always)]
pub(crate) fn may_use(isa: Isa) -> bool {
    #[cfg(test)]
    return WIDEST.with(|w| w.get()) >= isa;
    #[cfg(not(test))]
    {
        let _ = isa;
        true
    }
}

#[cfg(test)]
thread_local! {
    static WIDEST: std::cell::Cell<Isa> = const { std::cell::Cell::new(Isa::Avx512) };
}

/// Runs `f` with the kernels on this thread held to `isa` and narrower.
#[cfg(test)]
pub(crate) fn with_widest<R>(isa: Isa, f: impl FnOnce() -> R) -> R {
    let before = WIDEST.with(|w| w.replace(isa));
    let r = f();
    WIDEST.with(|w| w.set(before));
    r
}

/// `z ← relu(z + bias)` in place (the ReLU only if `relu`), rounded once to `z`'s element type.
/// `z` is `[E, B, O]` (f32 or bf16), `bias` f32 `[E, 1, O]`. Returns false, having done nothing,
/// where it does not apply.
pub fn bias_relu_(z: &Tensor, bias: &Tensor, relu: bool) -> bool {
    match z.kind() {
        Kind::BFloat16 => bias_relu_of::<Bf16>(z, bias, relu),
        Kind::Float => bias_relu_of::<f32>(z, bias, relu),
        _ => false,
    }
}

fn bias_relu_of<T: Elem>(z: &Tensor, bias: &Tensor, relu: bool) -> bool {
    let Some((e, b, o)) = dims3(z) else {
        return false;
    };
    if !untracked(&[z, bias]) {
        return false;
    }
    // SAFETY: `z` and `bias` are distinct tensors (different element types or shapes, or a
    // parameter and a fresh result), and only `z` is written.
    let (Some(z), Some(bias)) = (unsafe { elems::<T>(z, e * b * o) }, unsafe {
        elems::<f32>(bias, e * o)
    }) else {
        return false;
    };
    bias_relu_loop::<T>(z, bias, b, o, relu);
    true
}

vectorised! {
    fn bias_relu_loop<T>(z: &mut [T], bias: &[f32], b: usize, o: usize, relu: bool) {
        for (member, bias) in z.chunks_exact_mut(b * o).zip(bias.chunks_exact(o)) {
            for row in member.chunks_exact_mut(o) {
                for (x, &c) in row.iter_mut().zip(bias) {
                    let v = x.load() + c;
                    // `v < 0` is false for NaN, which passes through as torch's ReLU lets it.
                    *x = T::store(if relu && v < 0.0 { 0.0 } else { v });
                }
            }
        }
    }
}

/// A one-output layer, `q[e, r] = Σ_k h[e, r, k] · w[e, k] + bias[e]`, in f32: `h` is
/// `[E, B, K]` (f32 or bf16), `w` f32 `[E, K, 1]`, `bias` f32 `[E, 1, 1]`; returns `[E, B, 1]`
/// f32, or `None` where it does not apply.
pub fn one_output(h: &Tensor, w: &Tensor, bias: &Tensor) -> Option<Tensor> {
    match h.kind() {
        Kind::BFloat16 => one_output_of::<Bf16>(h, w, bias),
        Kind::Float => one_output_of::<f32>(h, w, bias),
        _ => None,
    }
}

/// Lanes of the dot product's partial sums: four AVX2 registers (two AVX-512 ones), enough to hide
/// the adds' latency.
const DOT_LANES: usize = 32;

fn one_output_of<T: Elem>(h: &Tensor, w: &Tensor, bias: &Tensor) -> Option<Tensor> {
    let (e, b, k) = dims3(h)?;
    if !untracked(&[h, w, bias]) {
        return None;
    }
    let out = Tensor::empty([e as i64, b as i64, 1], (Kind::Float, Device::Cpu));
    // SAFETY: `out` is fresh and the only one written; the others are only read.
    let (h, w, bias, q) = unsafe {
        (
            elems::<T>(h, e * b * k)?,
            elems::<f32>(w, e * k)?,
            elems::<f32>(bias, e)?,
            elems::<f32>(&out, e * b)?,
        )
    };
    one_output_loop::<T>(h, w, bias, q, b, k);
    Some(out)
}

vectorised! {
    fn one_output_loop<T>(h: &[T], w: &[f32], bias: &[f32], q: &mut [f32], b: usize, k: usize) {
        for (m, (q, w)) in q.chunks_exact_mut(b).zip(w.chunks_exact(k)).enumerate() {
            for (q, row) in q.iter_mut().zip(h[m * b * k..(m + 1) * b * k].chunks_exact(k)) {
                *q = dot(row, w) + bias[m];
            }
        }
    }
}

/// `Σ_k x[k] · w[k]` in f32, in [`DOT_LANES`] interleaved partial sums.
#[inline(always)]
fn dot<T: Elem>(x: &[T], w: &[f32]) -> f32 {
    let mut acc = [0f32; DOT_LANES];
    let (xc, wc) = (x.chunks_exact(DOT_LANES), w.chunks_exact(DOT_LANES));
    let tail: f32 = xc
        .remainder()
        .iter()
        .zip(wc.remainder())
        .map(|(x, w)| x.load() * w)
        .sum();
    for (xc, wc) in xc.zip(wc) {
        for j in 0..DOT_LANES {
            acc[j] += xc[j].load() * wc[j];
        }
    }
    // Pairwise, as the registers fold.
    let mut width = DOT_LANES;
    while width > 1 {
        width /= 2;
        for j in 0..width {
            acc[j] += acc[j + width];
        }
    }
    acc[0] + tail
}

/// The backward of [`one_output`] below a ReLU layer, given `dq = ∂L/∂q` (`[E, B, 1]` f32):
/// adds `Σ_r h[e, r, k] · dq[e, r]` to `dw` (`[E, K, 1]`) and `Σ_r dq[e, r]` to `db` (`[E, 1, 1]`),
/// and returns the gradient at the layer below's pre-activation, `dz[e, r, k] = dq[e, r] · w[e, k]`
/// where `h[e, r, k] > 0`, else 0, in `h`'s element type, having added its row sums
/// (`Σ_r dz[e, r, k]`, `[E, 1, K]`) to `db_below`, that layer's bias gradient. `h` is the ReLU's
/// output, positive exactly where its input was. `None`, having done nothing, where it does not
/// apply.
pub fn one_output_backward(
    dq: &Tensor,
    h: &Tensor,
    w: &Tensor,
    dw: &Tensor,
    db: &Tensor,
    db_below: &Tensor,
) -> Option<Tensor> {
    match h.kind() {
        Kind::BFloat16 => one_output_backward_of::<Bf16>(dq, h, w, dw, db, db_below),
        Kind::Float => one_output_backward_of::<f32>(dq, h, w, dw, db, db_below),
        _ => None,
    }
}

fn one_output_backward_of<T: Elem>(
    dq: &Tensor,
    h: &Tensor,
    w: &Tensor,
    dw: &Tensor,
    db: &Tensor,
    db_below: &Tensor,
) -> Option<Tensor> {
    let (e, b, k) = dims3(h)?;
    if !untracked(&[dq, h, w, dw, db, db_below]) {
        return None;
    }
    let out = Tensor::empty([e as i64, b as i64, k as i64], (T::KIND, Device::Cpu));
    // SAFETY: the written tensors (`out`, fresh, and three gradients, of different sizes or
    // layers) are distinct from each other and from the ones only read.
    let (dq, h, w, dw, db, db_below, dz) = unsafe {
        (
            elems::<f32>(dq, e * b)?,
            elems::<T>(h, e * b * k)?,
            elems::<f32>(w, e * k)?,
            elems::<f32>(dw, e * k)?,
            elems::<f32>(db, e)?,
            elems::<f32>(db_below, e * k)?,
            elems::<T>(&out, e * b * k)?,
        )
    };
    one_output_backward_loop::<T>(dq, h, w, dw, db, db_below, dz, b, k);
    Some(out)
}

vectorised! {
    fn one_output_backward_loop<T>(
        dq: &[f32],
        h: &[T],
        w: &[f32],
        dw: &mut [f32],
        db: &mut [f32],
        db_below: &mut [f32],
        dz: &mut [T],
        b: usize,
        k: usize,
    ) {
        let members = dw.chunks_exact_mut(k).zip(db_below.chunks_exact_mut(k)).zip(w.chunks_exact(k));
        for (m, ((dw, db_below), w)) in members.enumerate() {
            let rows = m * b..(m + 1) * b;
            let (h, dz) = (&h[rows.start * k..rows.end * k], &mut dz[rows.start * k..rows.end * k]);
            for ((&d, h), dz) in dq[rows].iter().zip(h.chunks_exact(k)).zip(dz.chunks_exact_mut(k)) {
                db[m] += d;
                for ((((x, dz), dw), s), w) in h.iter().zip(dz).zip(dw.iter_mut()).zip(db_below.iter_mut()).zip(w) {
                    let x = x.load();
                    *dw += x * d;
                    let g = T::store(if x > 0.0 { d * w } else { 0.0 });
                    *dz = g;
                    *s += g.load();
                }
            }
        }
    }
}

/// A ReLU's backward in place: `dh ← dh` where `act > 0`, else 0, `act` being the ReLU's
/// output; adds the result's row sums (`[E, 1, K]`) to `db`, the bias gradient of the layer that
/// fed the ReLU. `dh` and `act` are `[E, B, K]` of one element type. Returns false, having done
/// nothing, where it does not apply.
pub fn relu_backward_(dh: &Tensor, act: &Tensor, db: &Tensor) -> bool {
    match (dh.kind(), act.kind()) {
        (Kind::BFloat16, Kind::BFloat16) => relu_backward_of::<Bf16>(dh, act, db),
        (Kind::Float, Kind::Float) => relu_backward_of::<f32>(dh, act, db),
        _ => false,
    }
}

fn relu_backward_of<T: Elem>(dh: &Tensor, act: &Tensor, db: &Tensor) -> bool {
    let Some((e, b, k)) = dims3(dh) else {
        return false;
    };
    if act.size() != dh.size() || !untracked(&[dh, act, db]) {
        return false;
    }
    // SAFETY: `dh` (a fresh gradient) and `db` (a parameter's gradient) are written; `act`, an
    // activation, is only read.
    let (Some(dh), Some(act), Some(db)) = (
        unsafe { elems::<T>(dh, e * b * k) },
        unsafe { elems::<T>(act, e * b * k) },
        unsafe { elems::<f32>(db, e * k) },
    ) else {
        return false;
    };
    relu_backward_loop::<T>(dh, act, db, b, k);
    true
}

vectorised! {
    fn relu_backward_loop<T>(dh: &mut [T], act: &[T], db: &mut [f32], b: usize, k: usize) {
        for ((dh, act), db) in dh
            .chunks_exact_mut(b * k)
            .zip(act.chunks_exact(b * k))
            .zip(db.chunks_exact_mut(k))
        {
            for (dh, act) in dh.chunks_exact_mut(k).zip(act.chunks_exact(k)) {
                for ((g, a), s) in dh.iter_mut().zip(act).zip(db.iter_mut()) {
                    let v = if a.load() > 0.0 { g.load() } else { 0.0 };
                    *g = T::store(v);
                    *s += v;
                }
            }
        }
    }
}

/// `t` rounded to bf16 (a fresh tensor of its shape): the matmuls' operands. `None` where it
/// does not apply (not contiguous f32 on the CPU, or tracked by autograd).
pub fn to_bf16(t: &Tensor) -> Option<Tensor> {
    let n = t.numel();
    if !untracked(&[t]) {
        return None;
    }
    let out = Tensor::empty(t.size(), (Kind::BFloat16, Device::Cpu));
    // SAFETY: `out` is fresh and the only one written.
    let (src, dst) = unsafe { (elems::<f32>(t, n)?, elems::<Bf16>(&out, n)?) };
    round_loop::<Bf16>(dst, src);
    Some(out)
}

vectorised! {
    fn round_loop<T>(dst: &mut [T], src: &[f32]) {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = T::store(s);
        }
    }
}

/// `dst += src`, an f32 tensor and a bf16 one of the same number of elements (a gradient and a
/// bf16 matmul's product). Returns false, having done nothing, where it does not apply.
pub fn add_bf16_(dst: &Tensor, src: &Tensor) -> bool {
    let n = dst.numel();
    if !untracked(&[dst, src]) || src.size() != dst.size() {
        return false;
    }
    // SAFETY: two distinct tensors (their element types differ); only `dst` is written.
    let (Some(dst), Some(src)) = (unsafe { elems::<f32>(dst, n) }, unsafe {
        elems::<Bf16>(src, n)
    }) else {
        return false;
    };
    add_loop::<Bf16>(dst, src);
    true
}

vectorised! {
    fn add_loop<T>(dst: &mut [f32], src: &[T]) {
        for (d, s) in dst.iter_mut().zip(src) {
            *d += s.load();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits(t: &Tensor) -> Vec<i16> {
        Vec::<i16>::try_from(t.contiguous().view_dtype(Kind::Int16).reshape([-1])).unwrap()
    }

    fn floats(t: &Tensor) -> Vec<f32> {
        Vec::<f32>::try_from(t.to_kind(Kind::Float).reshape([-1])).unwrap()
    }

    fn randn(shape: &[i64]) -> Tensor {
        Tensor::randn(shape, (Kind::Float, Device::Cpu))
    }

    /// Rounding to bf16 bit for bit as libtorch's conversion (any NaN for a NaN), ties,
    /// infinities, subnormals and values that round up into the next binade included.
    #[test]
    fn bf16_rounding_is_libtorchs() {
        let mut values: Vec<f32> = vec![
            0.0,
            -0.0,
            1.0,
            f32::from_bits(0x3F80_8000), // a tie, kept part even: stays
            f32::from_bits(0x3F81_8000), // a tie, kept part odd: rounds up
            f32::from_bits(0x3F80_8001),
            f32::from_bits(0x3F80_7FFF),
            f32::from_bits(0x3FFF_FFFF), // rounds up into the next binade
            f32::MAX,                    // rounds to infinity
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x0000_0001), // smallest subnormal
            f32::from_bits(0x0040_8000),
        ];
        values.extend(floats(&(randn(&[1000]) * 1e3)));
        let ours: Vec<i16> = values.iter().map(|&x| Bf16::store(x).0 as i16).collect();
        let torch = bits(&Tensor::from_slice(&values).to_kind(Kind::BFloat16));
        // And through the vectorised conversion (the values again, in a tensor's shape).
        let tensor = to_bf16(&Tensor::from_slice(&values).view([1, -1])).unwrap();
        assert_eq!(tensor.size(), [1, values.len() as i64]);
        let nan = |b: i16| (b as u16 & 0x7F80) == 0x7F80 && (b as u16 & 0x7F) != 0;
        for ours in [ours, bits(&tensor)] {
            for (i, (&a, &b)) in ours.iter().zip(&torch).enumerate() {
                // libtorch's vector and scalar conversions write different NaNs.
                assert!(
                    a == b || (nan(a) && nan(b)),
                    "value {i} ({:e}): {a:#x} against {b:#x}",
                    values[i]
                );
            }
        }
        // And back: every bf16 widens exactly.
        let t = Tensor::from_slice(&values).to_kind(Kind::BFloat16);
        let widened: Vec<f32> = bits(&t).iter().map(|&b| Bf16(b as u16).load()).collect();
        for (a, b) in widened.iter().zip(floats(&t)) {
            assert!(a == &b || (a.is_nan() && b.is_nan()));
        }
    }

    /// Against libtorch's own add and ReLU: bit for bit, since both round the same f32 sum once.
    #[test]
    fn bias_relu_matches_libtorchs_add_and_relu() {
        for kind in [Kind::BFloat16, Kind::Float] {
            for relu in [true, false] {
                let z = randn(&[3, 5, 7]).to_kind(kind);
                let bias = randn(&[3, 1, 7]);
                let mut want = z.to_kind(Kind::Float) + &bias;
                if relu {
                    want = want.relu();
                }
                let want = want.to_kind(kind);
                assert!(bias_relu_(&z, &bias, relu));
                assert_eq!(
                    bits(&z.to_kind(Kind::Float)),
                    bits(&want.to_kind(Kind::Float))
                );
            }
        }
    }

    #[test]
    fn one_output_matches_a_product_and_row_sum() {
        for kind in [Kind::BFloat16, Kind::Float] {
            // 70 columns: two full blocks of partial sums and a tail.
            let h = randn(&[4, 9, 70]).to_kind(kind);
            let (w, bias) = (randn(&[4, 70, 1]), randn(&[4, 1, 1]));
            let q = one_output(&h, &w, &bias).unwrap();
            let want = (h.to_kind(Kind::Double) * w.to_kind(Kind::Double).transpose(1, 2))
                .sum_dim_intlist(-1, true, Kind::Double)
                + bias.to_kind(Kind::Double);
            assert_eq!(q.size(), [4, 9, 1]);
            assert!(q.to_kind(Kind::Double).allclose(&want, 1e-5, 1e-5, false));
        }
    }

    #[test]
    fn one_output_backward_matches_tensor_ops() {
        for kind in [Kind::BFloat16, Kind::Float] {
            // A ReLU's output: about half of it zero.
            let h = randn(&[3, 6, 40]).relu().to_kind(kind);
            let (w, dq) = (randn(&[3, 40, 1]), randn(&[3, 6, 1]));
            let (dw0, db0, db_below0) = (randn(&[3, 40, 1]), randn(&[3, 1, 1]), randn(&[3, 1, 40]));
            let (dw, db, db_below) = (dw0.copy(), db0.copy(), db_below0.copy());
            let dz = one_output_backward(&dq, &h, &w, &dw, &db, &db_below).unwrap();
            let hf = h.to_kind(Kind::Float);
            let want_dw = &dw0
                + (&hf * &dq)
                    .sum_dim_intlist(1, true, Kind::Float)
                    .transpose(1, 2);
            let want_db = &db0 + dq.sum_dim_intlist(1, true, Kind::Float);
            let want_dz = hf
                .threshold_backward(&(&dq * w.transpose(1, 2)), 0.0)
                .to_kind(kind);
            let want_db_below = &db_below0
                + want_dz
                    .to_kind(Kind::Float)
                    .sum_dim_intlist(1, true, Kind::Float);
            assert!(dw.allclose(&want_dw, 1e-5, 1e-5, false));
            assert!(db.allclose(&want_db, 1e-5, 1e-5, false));
            assert_eq!(dz.kind(), kind);
            assert_eq!(bits(&dz), bits(&want_dz));
            assert!(db_below.allclose(&want_db_below, 1e-5, 1e-5, false));
        }
    }

    #[test]
    fn relu_backward_masks_and_sums_rows_as_tensor_ops() {
        for kind in [Kind::BFloat16, Kind::Float] {
            let act = randn(&[2, 5, 9]).relu().to_kind(kind);
            let dh = randn(&[2, 5, 9]).to_kind(kind);
            let db0 = randn(&[2, 1, 9]);
            let db = db0.copy();
            let want = act.threshold_backward(&dh, 0.0);
            let want_db = &db0
                + want
                    .to_kind(Kind::Float)
                    .sum_dim_intlist(1, true, Kind::Float);
            assert!(relu_backward_(&dh, &act, &db));
            assert_eq!(bits(&dh), bits(&want));
            assert!(db.allclose(&want_db, 1e-5, 1e-5, false));
        }
    }

    #[test]
    fn add_bf16_adds_exactly() {
        let dst0 = randn(&[2, 3, 4]);
        let src = randn(&[2, 3, 4]).to_kind(Kind::BFloat16);
        let dst = dst0.copy();
        assert!(add_bf16_(&dst, &src));
        assert_eq!(bits(&dst), bits(&(&dst0 + src.to_kind(Kind::Float))));
    }

    /// Every compiled variant of every kernel (AVX-512, AVX2, plain, as far as this CPU has
    /// them) gives the same bits: the same arithmetic in the same order, without FMA. (Each
    /// variant's results against libtorch are the other tests'; this one makes them all count.)
    #[test]
    fn every_instruction_set_computes_the_same_bits() {
        let run = |isa: Isa| -> Vec<Vec<i16>> {
            // Values of their own (libtorch's generator is shared with tests running beside).
            use rand::{Rng, SeedableRng};
            let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
            let mut randn = |shape: &[i64]| {
                let n = shape.iter().product::<i64>() as usize;
                let v: Vec<f32> = (0..n).map(|_| rng.gen_range(-2.0f32..2.0)).collect();
                Tensor::from_slice(&v).view(shape)
            };
            with_widest(isa, || {
                let mut out = vec![];
                for kind in [Kind::BFloat16, Kind::Float] {
                    // Odd widths, so that every loop has a remainder.
                    let z = randn(&[3, 5, 37]).to_kind(kind);
                    assert!(bias_relu_(&z, &randn(&[3, 1, 37]), true));
                    let (w, bias) = (randn(&[3, 37, 1]), randn(&[3, 1, 1]));
                    let q = one_output(&z, &w, &bias).unwrap();
                    let (dw, db, db_below) =
                        (randn(&[3, 37, 1]), randn(&[3, 1, 1]), randn(&[3, 1, 37]));
                    let dz = one_output_backward(&q, &z, &w, &dw, &db, &db_below).unwrap();
                    let dh = randn(&[3, 5, 37]).to_kind(kind);
                    let db1 = randn(&[3, 1, 37]);
                    assert!(relu_backward_(&dh, &z, &db1));
                    out.extend([z, q, dw, db, db_below, dz, dh, db1]);
                }
                let sum = randn(&[2, 41]);
                assert!(add_bf16_(&sum, &randn(&[2, 41]).to_kind(Kind::BFloat16)));
                out.extend([sum.shallow_clone(), to_bf16(&(sum * 1e3)).unwrap()]);
                out.iter().map(bits).collect()
            })
        };
        let widest = run(Isa::Avx512);
        for isa in [Isa::Avx2, Isa::Plain] {
            let other = run(isa);
            for (i, (a, b)) in other.iter().zip(&widest).enumerate() {
                let first = a.iter().zip(b).position(|(x, y)| x != y);
                assert!(first.is_none(), "{isa:?}: tensor {i} differs at {first:?}");
            }
        }
    }

    /// Where a kernel does not apply it leaves everything as it was and says so.
    #[test]
    fn the_kernels_refuse_what_they_cannot_do() {
        let z = randn(&[2, 3, 4]);
        let before = z.copy();
        // A transposed (non-contiguous) output, a bias of the wrong size, an integer tensor, a
        // tensor autograd tracks.
        assert!(!bias_relu_(&z.transpose(1, 2), &randn(&[2, 1, 3]), true));
        assert!(!bias_relu_(&z, &randn(&[2, 1, 5]), true));
        assert!(!bias_relu_(&z.to_kind(Kind::Int), &randn(&[2, 1, 4]), true));
        assert!(!bias_relu_(
            &z.copy().set_requires_grad(true),
            &randn(&[2, 1, 4]),
            true
        ));
        assert_eq!(bits(&z), bits(&before));
        assert!(one_output(&z.transpose(1, 2), &randn(&[2, 3, 1]), &randn(&[2, 1, 1])).is_none());
        assert!(!relu_backward_(
            &z,
            &z.to_kind(Kind::BFloat16),
            &randn(&[2, 1, 4])
        ));
        assert!(!add_bf16_(&z, &z));
        assert_eq!(bits(&z), bits(&before));
        // A parameter is used as it is where autograd is off, and left to autograd where it is on.
        let (w, bias) = (randn(&[2, 4, 1]).set_requires_grad(true), randn(&[2, 1, 1]));
        assert!(one_output(&z, &w, &bias).is_none());
        assert!(tch::no_grad(|| one_output(&z, &w, &bias)).is_some());
    }
}
