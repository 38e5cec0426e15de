//! Knowledge distillation toward the best actor (SPEC "Actor objective", eq. 8): the closed-form KL
//! between two diagonal Gaussians over the pre-tanh action. tanh is the same bijection for both
//! policies, so the KL of the squashed policies equals this one.

use tch::{Kind, Tensor};

/// `KL(N(μ_i, σ_i) ‖ N(μ_b, σ_b))` summed over the last (action) dimension:
/// `Σ_d [log σ_b − log σ_i + (σ_i² + (μ_i − μ_b)²) / (2σ_b²) − ½]`.
pub fn gaussian_kl(mu_i: &Tensor, log_std_i: &Tensor, mu_b: &Tensor, log_std_b: &Tensor) -> Tensor {
    let var_i = (log_std_i * 2.0).exp();
    let var_b = (log_std_b * 2.0).exp();
    let per_dim = log_std_b - log_std_i + (var_i + (mu_i - mu_b).square()) / (var_b * 2.0) - 0.5;
    per_dim.sum_dim_intlist(-1, false, Kind::Float)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// KL = E_{x~p}[log p(x) − log q(x)], estimated by Monte Carlo on tanh-squashed samples (the
    /// Jacobian terms cancel, which is the point of the claim that tanh leaves the KL unchanged).
    #[test]
    fn closed_form_matches_monte_carlo_of_squashed_policies() {
        let (mu_i, ls_i, mu_b, ls_b) = (
            [0.2f64, -0.5],
            [-0.3f64, 0.1],
            [0.6f64, -0.1],
            [-0.6f64, 0.3],
        );
        let t = |v: &[f64]| Tensor::from_slice(v).to_kind(Kind::Double);
        let closed = gaussian_kl(&t(&mu_i), &t(&ls_i), &t(&mu_b), &t(&ls_b)).double_value(&[]);

        let log_squashed = |a: f64, mu: f64, ls: f64| {
            let u = a.atanh();
            let z = (u - mu) / ls.exp();
            -0.5 * z * z - ls - 0.5 * (2.0 * std::f64::consts::PI).ln() - (1.0 - a * a).ln()
        };
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let n = 400_000;
        let mut sum = 0.0;
        for _ in 0..n {
            let mut diff = 0.0;
            for d in 0..2 {
                let u = Normal::new(mu_i[d], ls_i[d].exp())
                    .unwrap()
                    .sample(&mut rng);
                let a = u.tanh();
                if a.abs() >= 1.0 {
                    continue;
                }
                diff += log_squashed(a, mu_i[d], ls_i[d]) - log_squashed(a, mu_b[d], ls_b[d]);
            }
            sum += diff;
        }
        let mc = sum / n as f64;
        assert!((closed - mc).abs() < 0.01, "closed {closed} vs MC {mc}");
        assert!(closed > 0.1);
    }

    #[test]
    fn is_zero_for_identical_policies() {
        let mu = Tensor::from_slice(&[0.3f32, 1.0]);
        let ls = Tensor::from_slice(&[-1.0f32, 0.5]);
        assert!(gaussian_kl(&mu, &ls, &mu, &ls).double_value(&[]).abs() < 1e-7);
    }
}
