//! The critic target (SPEC "Critic target", paper eq. 6, "in-target max-min") and its variants.
//!
//! For every actor i: `v_i = inner_{m∈𝓜} Q̄_m(s', ã'_i) − α_i log π_i(ã'_i|s')`, then
//! `y = r + γ (1 − terminated) · outer_i v_i`. The default formation is inner = min, outer = max.

use serde::{Deserialize, Serialize};
use tch::Tensor;

/// Which reduction runs over actors (outer) and over the critic subset (inner).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Formation {
    /// outer max over actors, inner min over the subset (the paper's SELKD).
    MaxMin,
    MinMin,
    MinMax,
    MaxMax,
}

impl Formation {
    fn outer_is_max(self) -> bool {
        matches!(self, Formation::MaxMin | Formation::MaxMax)
    }
    fn inner_is_min(self) -> bool {
        matches!(self, Formation::MaxMin | Formation::MinMin)
    }
}

/// `y` for `G` groups of `B` transitions.
///
/// - `reward`, `terminated`: `[G, B]` (terminated as 0/1)
/// - `q_next`: target-critic values `Q̄_m(s', ã'_i)`, `[G, M, K, B]` (subset member, actor, row)
/// - `logp_next`: `log π_i(ã'_i|s')`, `[G, K, B]`
/// - `alpha`: temperatures `[K]`
pub fn critic_target(
    reward: &Tensor,
    terminated: &Tensor,
    q_next: &Tensor,
    logp_next: &Tensor,
    alpha: &Tensor,
    gamma: f64,
    formation: Formation,
) -> Tensor {
    let inner = if formation.inner_is_min() {
        q_next.amin(1, false)
    } else {
        q_next.amax(1, false)
    };
    let soft_value = inner - alpha.view([1, -1, 1]) * logp_next;
    let outer = if formation.outer_is_max() {
        soft_value.amax(1, false)
    } else {
        soft_value.amin(1, false)
    };
    reward + (1.0 - terminated) * gamma * outer
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Kind;

    fn t(v: &[f64], shape: &[i64]) -> Tensor {
        Tensor::from_slice(v).to_kind(Kind::Double).view(shape)
    }

    /// A plain loop over the definition for one (G=1) group.
    fn reference(
        r: &[f64],
        d: &[f64],
        q: &[Vec<Vec<f64>>],
        lp: &[Vec<f64>],
        alpha: &[f64],
        gamma: f64,
        f: Formation,
    ) -> Vec<f64> {
        let (m, k, b) = (q.len(), q[0].len(), q[0][0].len());
        (0..b)
            .map(|row| {
                let mut best: Option<f64> = None;
                for i in 0..k {
                    let mut inner: Option<f64> = None;
                    for j in 0..m {
                        let v = q[j][i][row];
                        inner = Some(match inner {
                            None => v,
                            Some(x) => {
                                if f.inner_is_min() {
                                    x.min(v)
                                } else {
                                    x.max(v)
                                }
                            }
                        });
                    }
                    let v = inner.unwrap() - alpha[i] * lp[i][row];
                    best = Some(match best {
                        None => v,
                        Some(x) => {
                            if f.outer_is_max() {
                                x.max(v)
                            } else {
                                x.min(v)
                            }
                        }
                    });
                }
                r[row] + gamma * (1.0 - d[row]) * best.unwrap()
            })
            .collect()
    }

    #[test]
    fn every_formation_matches_the_plain_definition() {
        // M = 3 subset members, K = 2 actors, B = 4 rows.
        let q = vec![
            vec![vec![1.0, 2.0, -3.0, 0.5], vec![0.0, 5.0, 1.0, -2.0]],
            vec![vec![2.0, -1.0, 4.0, 0.7], vec![3.0, 1.5, 2.0, -1.0]],
            vec![vec![0.5, 0.0, 1.0, 9.0], vec![-4.0, 2.5, 0.5, 3.0]],
        ];
        let lp = vec![vec![-1.0, 0.5, 2.0, -0.3], vec![0.2, -2.0, 1.0, 0.0]];
        let (r, d, alpha) = ([1.0, -0.5, 0.0, 2.0], [0.0, 1.0, 0.0, 0.0], [0.2, 0.7]);
        let qf: Vec<f64> = q.iter().flatten().flatten().copied().collect();
        let lpf: Vec<f64> = lp.iter().flatten().copied().collect();
        for f in [
            Formation::MaxMin,
            Formation::MinMin,
            Formation::MinMax,
            Formation::MaxMax,
        ] {
            let y = critic_target(
                &t(&r, &[1, 4]),
                &t(&d, &[1, 4]),
                &t(&qf, &[1, 3, 2, 4]),
                &t(&lpf, &[1, 2, 4]),
                &t(&alpha, &[2]),
                0.99,
                f,
            );
            let want = reference(&r, &d, &q, &lp, &alpha, 0.99, f);
            for row in 0..4 {
                assert!(
                    (y.double_value(&[0, row]) - want[row as usize]).abs() < 1e-12,
                    "{f:?} row {row}"
                );
            }
        }
    }

    /// K = 1 must be REDQ's target, `r + γ(1−d)(min_{m∈𝓜} Q̄_m − α log π)`, for every formation
    /// whose inner reduction is min (the outer reduction over one actor is the identity).
    #[test]
    fn one_actor_is_redq_and_two_of_two_is_sac() {
        let q = [[1.5, -0.5, 3.0], [0.5, 2.0, 2.5]]; // M = 2 subset members, B = 3
        let lp = [-0.4, 1.2, 0.3];
        let (r, d, alpha) = ([0.1, 0.2, 0.3], [0.0, 0.0, 1.0], 0.3);
        let qf: Vec<f64> = q.iter().flatten().copied().collect();
        for f in [Formation::MaxMin, Formation::MinMin] {
            let y = critic_target(
                &t(&r, &[1, 3]),
                &t(&d, &[1, 3]),
                &t(&qf, &[1, 2, 1, 3]),
                &t(&lp, &[1, 1, 3]),
                &t(&[alpha], &[1]),
                0.99,
                f,
            );
            for b in 0..3 {
                // With M = N = 2 this is SAC's clipped double-Q target.
                let want = r[b] + 0.99 * (1.0 - d[b]) * (q[0][b].min(q[1][b]) - alpha * lp[b]);
                assert!((y.double_value(&[0, b as i64]) - want).abs() < 1e-12);
            }
        }
    }
}
