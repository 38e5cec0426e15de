//! fp32 batched matrix products on CPU: libtorch's (Intel's MKL), or the `gemm` crate's.
//!
//! libtorch multiplies fp32 matrices with MKL, whose fastest code paths run on Intel CPUs only.
//! On an AMD EPYC (Zen 4, AVX-512; one thread, runs interleaved, a noisy host) a critic layer's
//! `[10, 256, 256]` products (forward, weight and input gradients) ran at 60–91 GFLOP/s in MKL
//! and 78–100 in the pure-Rust `gemm` crate (AVX-512, or AVX2 and FMA, chosen at run time on
//! any vendor's CPU), and with 1280 rows (the K = 5 target's) at 59–90 against 87–108: a whole
//! update 1.09–1.14× faster. `run.cpu_gemm` chooses; its default, [`CpuGemm::Auto`], takes MKL
//! on Intel CPUs, where it runs near the core's peak, and `gemm` on the others (on AMD CPUs
//! without AVX-512, Zen 3 and older, this choice has not been measured).
//! Both compute the same products, summed in other orders, so results agree to float32
//! round-off, not bit for bit; one choice on one machine is reproducible.
//!
//! Only where autograd is not recording (the critics' hand forward and backward, the forwards
//! without gradient): elsewhere, and for bf16 or on a GPU, libtorch multiplies.

use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU8, Ordering};
use tch::{Device, Kind, Tensor};

/// Who multiplies fp32 matrices on CPU where autograd is not recording (`run.cpu_gemm`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CpuGemm {
    /// `libtorch` on Intel CPUs, `gemm` on the others.
    Auto,
    /// libtorch's `bmm` and `baddbmm_` (MKL).
    Libtorch,
    /// The `gemm` crate, one member's product at a time.
    Gemm,
}

impl CpuGemm {
    /// The choice `Auto` stands for on this CPU; the others as they are.
    pub fn resolved(self) -> Self {
        match self {
            CpuGemm::Auto if cpu_is_intel() => CpuGemm::Libtorch,
            CpuGemm::Auto => CpuGemm::Gemm,
            chosen => chosen,
        }
    }

    /// What a user reads: the library that multiplies.
    pub fn describe(self) -> &'static str {
        match self.resolved() {
            CpuGemm::Gemm => "the gemm crate",
            _ => "libtorch (MKL)",
        }
    }
}

static DEFAULT: AtomicU8 = AtomicU8::new(CpuGemm::Auto as u8);

/// Ensembles made from now on in this process multiply as `choice` says (a process runs one
/// configuration, as with [`crate::threads::set`]).
pub fn set(choice: CpuGemm) {
    DEFAULT.store(choice as u8, Ordering::Relaxed);
}

/// The choice [`set`] made ([`CpuGemm::Auto`] if none), resolved for this CPU.
pub fn chosen() -> CpuGemm {
    // Decoded by the variants' own discriminants, which `set` stored.
    match DEFAULT.load(Ordering::Relaxed) {
        x if x == CpuGemm::Libtorch as u8 => CpuGemm::Libtorch,
        x if x == CpuGemm::Gemm as u8 => CpuGemm::Gemm,
        _ => CpuGemm::Auto,
    }
    .resolved()
}

fn cpu_is_intel() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        let r = std::arch::x86_64::__cpuid(0);
        let mut vendor = [0u8; 12];
        vendor[..4].copy_from_slice(&r.ebx.to_le_bytes());
        vendor[4..8].copy_from_slice(&r.edx.to_le_bytes());
        vendor[8..].copy_from_slice(&r.ecx.to_le_bytes());
        &vendor == b"GenuineIntel"
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// `a · b` for `[E, M, K]` and `[E, K, N]` (any strides, a member stride of 0 too): by `gemm`
/// where `how` resolves to it and it applies (fp32 CPU tensors that autograd does not track),
/// else by libtorch.
pub fn bmm(how: CpuGemm, a: &Tensor, b: &Tensor) -> Tensor {
    if applies(how, &[a, b]) {
        let (e, m, _) = dims(a);
        let c = Tensor::empty([e, m, dims(b).2], (Kind::Float, Device::Cpu));
        products(&c, a, b, false);
        return c;
    }
    a.bmm(b)
}

/// `c += a · b` in place, `c` a contiguous `[E, M, N]`; by `gemm` or libtorch as in [`bmm`].
pub fn baddbmm_(how: CpuGemm, c: &Tensor, a: &Tensor, b: &Tensor) {
    if applies(how, &[c, a, b]) && c.is_contiguous() {
        products(c, a, b, true);
        return;
    }
    let _ = c.shallow_clone().baddbmm_(a, b);
}

fn applies(how: CpuGemm, tensors: &[&Tensor]) -> bool {
    how.resolved() == CpuGemm::Gemm
        && tensors.iter().all(|t| {
            t.device() == Device::Cpu && t.kind() == Kind::Float && t.dim() == 3 && t.numel() > 0
        })
        && crate::fused::untracked(tensors)
}

fn dims(t: &Tensor) -> (i64, i64, i64) {
    let s = t.size();
    (s[0], s[1], s[2])
}

/// Each member's `c[e] (+)= a[e] · b[e]`, one single-threaded `gemm` call each (the learner
/// splits members over threads of its own, [`crate::threads`]).
fn products(c: &Tensor, a: &Tensor, b: &Tensor, accumulate: bool) {
    let ((e, m, k), (eb, kb, n), (ec, mc, nc)) = (dims(a), dims(b), dims(c));
    assert!(
        e == eb && e == ec && k == kb && m == mc && n == nc,
        "bmm of {:?} and {:?} into {:?}",
        a.size(),
        b.size(),
        c.size()
    );
    let (sa, sb, sc) = (a.stride(), b.stride(), c.stride());
    let (pa, pb, pc) = (
        a.data_ptr() as *const f32,
        b.data_ptr() as *const f32,
        c.data_ptr() as *mut f32,
    );
    for i in 0..e as isize {
        // SAFETY: every element addressed lies within its tensor (shapes checked above, strides
        // libtorch's; `data_ptr` includes the storage offset); `c` is contiguous, so its members
        // do not overlap, and it is not `a` or `b` (a fresh result, or a gradient); nothing else
        // uses these tensors meanwhile.
        unsafe {
            gemm::gemm(
                m as usize,
                n as usize,
                k as usize,
                pc.offset(i * sc[0] as isize),
                sc[2] as isize,
                sc[1] as isize,
                accumulate,
                pa.offset(i * sa[0] as isize),
                sa[2] as isize,
                sa[1] as isize,
                pb.offset(i * sb[0] as isize),
                sb[2] as isize,
                sb[1] as isize,
                1.0f32,
                1.0f32,
                false,
                false,
                false,
                gemm::Parallelism::None,
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random(shape: &[i64], rng: &mut rand_pcg::Pcg64) -> (Tensor, Vec<f32>) {
        let n: i64 = shape.iter().product();
        let v: Vec<f32> = (0..n).map(|_| rng.gen_range(-1.0..1.0)).collect();
        (Tensor::from_slice(&v).view(shape), v)
    }

    /// `a[e] · b[e]` in f64 by the textbook triple loop, reading through `at` (the logical
    /// element `[e, i, j]` of each operand).
    fn reference(
        (e, m, k, n): (usize, usize, usize, usize),
        a_at: impl Fn(usize, usize, usize) -> f64,
        b_at: impl Fn(usize, usize, usize) -> f64,
    ) -> Vec<f64> {
        let mut c = vec![0.0; e * m * n];
        for x in 0..e {
            for i in 0..m {
                for j in 0..n {
                    c[(x * m + i) * n + j] = (0..k).map(|p| a_at(x, i, p) * b_at(x, p, j)).sum();
                }
            }
        }
        c
    }

    fn assert_close(got: &Tensor, want: &[f64], what: &str) {
        let got = Vec::<f32>::try_from(got.contiguous().view([-1])).unwrap();
        assert_eq!(got.len(), want.len(), "{what}: sizes");
        for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
            // Sums of up to 40 products of numbers below 1 in magnitude: f32 round-off is ~1e-6.
            assert!(
                (g as f64 - w).abs() < 1e-4,
                "{what}: element {i} is {g}, the plain loop gives {w}"
            );
        }
    }

    #[test]
    fn gemm_products_match_a_plain_loop_through_any_strides() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let (e, m, k, n) = (3, 17, 40, 9);
        // Plain operands.
        let (a, av) = random(&[e, m, k], &mut rng);
        let (b, bv) = random(&[e, k, n], &mut rng);
        let (e_, m_, k_, n_) = (e as usize, m as usize, k as usize, n as usize);
        let a_at = |x: usize, i: usize, p: usize| av[(x * m_ + i) * k_ + p] as f64;
        let b_at = |x: usize, p: usize, j: usize| bv[(x * k_ + p) * n_ + j] as f64;
        let want = reference((e_, m_, k_, n_), a_at, b_at);
        assert_close(&bmm(CpuGemm::Gemm, &a, &b), &want, "plain");

        // Transposed operands (as the backward's `input^T · dz` and `dz · W^T` are).
        let (at, atv) = random(&[e, k, m], &mut rng);
        let (bt, btv) = random(&[e, n, k], &mut rng);
        let want_t = reference(
            (e_, m_, k_, n_),
            |x, i, p| atv[(x * k_ + p) * m_ + i] as f64,
            |x, p, j| btv[(x * n_ + j) * k_ + p] as f64,
        );
        let got = bmm(CpuGemm::Gemm, &at.transpose(1, 2), &bt.transpose(1, 2));
        assert_close(&got, &want_t, "transposed");

        // One input shared by every member (expanded: member stride 0), as the critics' batch.
        let (shared, sv) = random(&[1, m, k], &mut rng);
        let want_shared = reference((e_, m_, k_, n_), |_, i, p| sv[i * k_ + p] as f64, b_at);
        let got = bmm(CpuGemm::Gemm, &shared.expand([e, m, k], false), &b);
        assert_close(&got, &want_shared, "expanded");

        // A narrowed operand (a storage offset and a row stride wider than its rows).
        let a_wide = Tensor::cat(&[&a, &a], 2);
        let got = bmm(CpuGemm::Gemm, &a_wide.narrow(2, k, k), &b);
        assert_close(&got, &want, "narrowed");

        // Accumulation onto what `c` holds.
        let (c, cv) = random(&[e, m, n], &mut rng);
        baddbmm_(CpuGemm::Gemm, &c, &a, &b);
        let want_acc: Vec<f64> = want.iter().zip(&cv).map(|(w, &c)| w + c as f64).collect();
        assert_close(&c, &want_acc, "accumulated");
    }

    #[test]
    fn gemm_and_libtorch_agree_and_tracked_products_stay_with_libtorch() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
        let (a, _) = random(&[2, 256, 256], &mut rng);
        let (b, _) = random(&[2, 256, 256], &mut rng);
        let diff = (bmm(CpuGemm::Gemm, &a, &b) - bmm(CpuGemm::Libtorch, &a, &b))
            .abs()
            .max()
            .double_value(&[]);
        // Sums of 256 products of magnitude below 1 (about 9 in size): round-off only.
        assert!(diff < 1e-4, "gemm and libtorch differ by {diff}");

        // A product autograd must record goes to libtorch, and keeps its graph.
        let w = b.set_requires_grad(true);
        let out = bmm(CpuGemm::Gemm, &a, &w);
        assert!(out.requires_grad());
        out.sum(Kind::Float).backward();
        let want = a
            .sum_dim_intlist(1, false, Kind::Float)
            .unsqueeze(2)
            .expand([2, 256, 256], false);
        assert!((w.grad() - want).abs().max().double_value(&[]) < 1e-3);
    }

    /// `gemm`'s product of each member, called directly on contiguous copies, added onto `onto`.
    fn gemm_directly(a: &Tensor, b: &Tensor, onto: Option<&Tensor>) -> Tensor {
        let (e, m, k) = dims(a);
        let n = dims(b).2;
        let (a, b) = (a.contiguous(), b.contiguous());
        let (av, bv) = (
            Vec::<f32>::try_from(a.view([-1])).unwrap(),
            Vec::<f32>::try_from(b.view([-1])).unwrap(),
        );
        let mut cv = match onto {
            Some(c) => Vec::<f32>::try_from(c.contiguous().view([-1])).unwrap(),
            None => vec![0.0; (e * m * n) as usize],
        };
        let (m, k, n) = (m as usize, k as usize, n as usize);
        for x in 0..e as usize {
            // SAFETY: each member's slices are exactly m·k, k·n and m·n long, row-major.
            unsafe {
                gemm::gemm(
                    m,
                    n,
                    k,
                    cv[x * m * n..].as_mut_ptr(),
                    1,
                    n as isize,
                    onto.is_some(),
                    av[x * m * k..].as_ptr(),
                    1,
                    k as isize,
                    bv[x * k * n..].as_ptr(),
                    1,
                    n as isize,
                    1.0f32,
                    1.0f32,
                    false,
                    false,
                    false,
                    gemm::Parallelism::None,
                );
            }
        }
        Tensor::from_slice(&cv).view([e, m as i64, n as i64])
    }

    /// Each choice multiplies with its own library, bit for bit: `Libtorch` gives libtorch's
    /// products, `Gemm` the `gemm` crate's (called directly here); where `gemm` does not apply
    /// (bf16, an operand autograd records, an empty product), libtorch's whatever the choice.
    #[test]
    fn each_choice_multiplies_with_its_own_library() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        // The bits tell the libraries apart only where they sum in different orders. Short sums
        // can be one FMA chain in both (CI once drew such a CPU), so the sums lengthen until
        // the libraries split them into blocks of different sizes.
        let mut tried = None;
        for k in [300, 1500, 6000] {
            let (a, _) = random(&[2, 40, k], &mut rng);
            let (b, _) = random(&[2, k, 24], &mut rng);
            let (by_libtorch, by_gemm) = (a.bmm(&b), gemm_directly(&a, &b, None));
            let differ = !by_gemm.equal(&by_libtorch);
            tried = Some((a, b, by_libtorch, by_gemm));
            if differ {
                break;
            }
            eprintln!("gemm and libtorch gave the same bits for sums of {k} terms");
        }
        let (a, b, by_libtorch, by_gemm) = tried.unwrap();
        let (c0, _) = random(&[2, 40, 24], &mut rng);
        // Where even the longest sums agree bit for bit, which library ran cannot be seen, nor
        // does it matter there; what follows still holds each choice to its own library's bits.
        if by_gemm.equal(&by_libtorch) {
            eprintln!(
                "gemm and libtorch gave the same bits even for sums of {} terms: on this CPU \
                 the test cannot tell which library ran",
                a.size()[2]
            );
        }

        assert!(bmm(CpuGemm::Libtorch, &a, &b).equal(&by_libtorch));
        assert!(bmm(CpuGemm::Gemm, &a, &b).equal(&by_gemm));
        let c = c0.copy();
        baddbmm_(CpuGemm::Libtorch, &c, &a, &b);
        assert!(c.equal(&c0.baddbmm(&a, &b, 1, 1)));
        let c = c0.copy();
        baddbmm_(CpuGemm::Gemm, &c, &a, &b);
        assert!(c.equal(&gemm_directly(&a, &b, Some(&c0))));

        // bf16 operands.
        let (a16, b16) = (a.to_kind(Kind::BFloat16), b.to_kind(Kind::BFloat16));
        assert!(bmm(CpuGemm::Gemm, &a16, &b16).equal(&a16.bmm(&b16)));
        // An operand autograd records, with the product's graph kept.
        let w = b.copy().set_requires_grad(true);
        let out = bmm(CpuGemm::Gemm, &a, &w);
        assert!(out.requires_grad() && out.equal(&by_libtorch));
        let c = c0.copy();
        baddbmm_(CpuGemm::Gemm, &c, &a, &w);
        assert!(c.requires_grad() && c.equal(&c0.baddbmm(&a, &b, 1, 1)));
        // Empty products: no rows, and no terms (zeros).
        let none = Tensor::zeros([2, 0, a.size()[2]], (Kind::Float, Device::Cpu));
        assert_eq!(bmm(CpuGemm::Gemm, &none, &b).size(), [2, 0, 24]);
        let (a0, b0) = (
            Tensor::zeros([2, 40, 0], (Kind::Float, Device::Cpu)),
            Tensor::zeros([2, 0, 24], (Kind::Float, Device::Cpu)),
        );
        let c = c0.copy();
        baddbmm_(CpuGemm::Gemm, &c, &a0, &b0);
        assert!(c.equal(&c0));
        assert!(bmm(CpuGemm::Gemm, &a0, &b0).equal(&c0.zeros_like()));
    }

    #[test]
    fn each_choice_names_its_library() {
        assert_eq!(CpuGemm::Gemm.describe(), "the gemm crate");
        assert_eq!(CpuGemm::Libtorch.describe(), "libtorch (MKL)");
    }

    #[test]
    fn auto_takes_libtorch_on_intel_only() {
        assert_eq!(CpuGemm::Libtorch.resolved(), CpuGemm::Libtorch);
        assert_eq!(CpuGemm::Gemm.resolved(), CpuGemm::Gemm);
        let intel = std::fs::read_to_string("/proc/cpuinfo")
            .map(|t| t.contains("GenuineIntel"))
            .unwrap_or(false);
        let want = if intel {
            CpuGemm::Libtorch
        } else {
            CpuGemm::Gemm
        };
        assert_eq!(CpuGemm::Auto.resolved(), want);
    }
}
