//! The tanh-squashed diagonal Gaussian policy: sampling with the reparameterisation trick and its
//! log-density (SPEC "Objects").

use tch::{Kind, Tensor};

const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_8;

/// Splits an actor head `[…, 2A]` into `(μ, log σ)`, `log σ` clamped to `[-20, 2]`.
pub fn split_head(head: &Tensor) -> (Tensor, Tensor) {
    let a = head.size().last().copied().unwrap() / 2;
    let mu = head.narrow(-1, 0, a);
    let log_std = head.narrow(-1, a, a).clamp(
        selkd_policy::LOG_STD_MIN as f64,
        selkd_policy::LOG_STD_MAX as f64,
    );
    (mu, log_std)
}

/// `a = tanh(μ + σ·ε)` and `log π(a|s)` summed over action dimensions (shape `[…]`).
///
/// `log π = log N(u; μ, σ) − Σ_d log(1 − tanh(u_d)²)`, with the correction in the stable form
/// `2(log 2 − u − softplus(−2u))`.
pub fn sample(mu: &Tensor, log_std: &Tensor, eps: &Tensor) -> (Tensor, Tensor) {
    let u = mu + log_std.exp() * eps;
    let log_normal =
        (eps.square() * -0.5 - log_std - HALF_LOG_2PI).sum_dim_intlist(-1, false, Kind::Float);
    let correction = ((-&u * 2.0).softplus() + &u - std::f64::consts::LN_2).sum_dim_intlist(
        -1,
        false,
        Kind::Float,
    ) * -2.0;
    (u.tanh(), log_normal - correction)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plain reference: the textbook density with the un-stabilised `log(1 − tanh² + 1e-6)` term.
    #[test]
    fn log_prob_matches_the_textbook_formula() {
        let mu = [0.3f64, -1.1, 2.0];
        let ls = [-0.5f64, 0.2, -1.5];
        let eps = [0.7f64, -0.4, 1.3];
        let t = |v: &[f64]| Tensor::from_slice(v).to_kind(Kind::Float).view([1, 3]);
        let (a, logp) = sample(&t(&mu), &t(&ls), &t(&eps));
        let mut want = 0.0;
        for d in 0..3 {
            let sigma = ls[d].exp();
            let u = mu[d] + sigma * eps[d];
            let normal = -((u - mu[d]) / sigma).powi(2) / 2.0
                - ls[d]
                - (2.0 * std::f64::consts::PI).sqrt().ln();
            want += normal - (1.0 - u.tanh().powi(2) + 1e-6).ln();
            assert!((a.double_value(&[0, d as i64]) - u.tanh()).abs() < 1e-6);
        }
        assert!(
            (logp.double_value(&[0]) - want).abs() < 1e-3,
            "{} vs {want}",
            logp.double_value(&[0])
        );
    }

    #[test]
    fn log_prob_integrates_to_one_in_one_dimension() {
        // ∫ π(a) da over (-1, 1) by the midpoint rule, via u = atanh(a).
        let n = 20000;
        let (mu, ls) = (0.4f64, -0.3f64);
        let mut total = 0.0;
        for k in 0..n {
            let a = -1.0 + (k as f64 + 0.5) * 2.0 / n as f64;
            let u = a.atanh();
            let eps = (u - mu) / ls.exp();
            let t = |v: f64| Tensor::from_slice(&[v]).to_kind(Kind::Double).view([1, 1]);
            let (_, logp) = sample(&t(mu), &t(ls), &t(eps));
            total += logp.double_value(&[0]).exp() * 2.0 / n as f64;
        }
        assert!((total - 1.0).abs() < 1e-3, "{total}");
    }
}
