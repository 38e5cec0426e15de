//! The critic target (SPEC "Critic target", paper eq. 6, "in-target max-min") and its variants.
//!
//! For every actor i: `v_i = inner_{m∈𝓜} Q̄_m(s', ã'_i) − α_i log π_i(ã'_i|s')`, then
//! `y = r + γ (1 − terminated) · outer_i v_i`. The default formation is inner = min, outer = max.
//! The ensemble baselines of the paper's comparison are inner reductions too (run them with K = 1
//! and M = N): Average-DQN's mean, REM's random convex mixture, AQE's mean after dropping the
//! highest values.

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
    /// Average-DQN: the mean over the subset.
    MaxMean,
    /// REM: a random convex mixture over the subset, new weights for every group and update.
    MaxRem,
    /// AQE: the mean of the subset's values after dropping the `aqe_drop` highest.
    MaxAqe,
}

/// What the randomised and trimmed inner reductions need besides the values.
pub struct InnerOptions<'a> {
    /// REM's mixture weights, `[G, M]`, each row non-negative and summing to 1.
    pub rem_weights: Option<&'a Tensor>,
    /// AQE: how many of the highest values to drop (fewer than M).
    pub aqe_drop: usize,
}

impl Formation {
    fn outer_is_max(self) -> bool {
        !matches!(self, Formation::MinMin | Formation::MinMax)
    }
}

/// The inner reduction of `q_next` `[G, M, K, B]` over the subset (dim 1), giving `[G, K, B]`.
fn inner(q_next: &Tensor, formation: Formation, opts: &InnerOptions) -> Tensor {
    match formation {
        Formation::MaxMin | Formation::MinMin => q_next.amin(1, false),
        Formation::MinMax | Formation::MaxMax => q_next.amax(1, false),
        Formation::MaxMean => q_next.mean_dim(1, false, q_next.kind()),
        Formation::MaxRem => {
            let w = opts.rem_weights.expect("REM needs mixture weights");
            let (g, m) = (w.size()[0], w.size()[1]);
            (q_next * w.view([g, m, 1, 1])).sum_dim_intlist(1, false, q_next.kind())
        }
        Formation::MaxAqe => {
            let m = q_next.size()[1];
            let keep = m - opts.aqe_drop as i64;
            let (sorted, _) = q_next.sort(1, false);
            sorted.narrow(1, 0, keep).mean_dim(1, false, q_next.kind())
        }
    }
}

/// `y` for `G` groups of `B` transitions.
///
/// - `reward`, `terminated`: `[G, B]` (terminated as 0/1)
/// - `q_next`: target-critic values `Q̄_m(s', ã'_i)`, `[G, M, K, B]` (subset member, actor, row)
/// - `logp_next`: `log π_i(ã'_i|s')`, `[G, K, B]`
/// - `alpha`: temperatures, shaped to broadcast against `logp_next`: `[1, K, 1]`, or `[G, 1, 1]`
///   where each group holds one actor (K = 1 per group: DPD's and AVTD's own critics)
#[allow(clippy::too_many_arguments)] // the formula's inputs, each named as in SPEC.md
pub fn critic_target(
    reward: &Tensor,
    terminated: &Tensor,
    q_next: &Tensor,
    logp_next: &Tensor,
    alpha: &Tensor,
    gamma: f64,
    formation: Formation,
    opts: &InnerOptions,
) -> Tensor {
    let inner = inner(q_next, formation, opts);
    let soft_value = inner - alpha * logp_next;
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

    const REM: [f64; 3] = [0.2, 0.5, 0.3];

    /// A plain loop over the definition for one (G=1) group (REM weights `REM`, AQE drops 1).
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
                    let vals: Vec<f64> = (0..m).map(|j| q[j][i][row]).collect();
                    let inner = match f {
                        Formation::MaxMin | Formation::MinMin => {
                            vals.iter().copied().fold(f64::INFINITY, f64::min)
                        }
                        Formation::MinMax | Formation::MaxMax => {
                            vals.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                        }
                        Formation::MaxMean => vals.iter().sum::<f64>() / m as f64,
                        Formation::MaxRem => vals.iter().zip(REM).map(|(v, w)| v * w).sum(),
                        Formation::MaxAqe => {
                            let mut v = vals.clone();
                            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
                            v[..m - 1].iter().sum::<f64>() / (m - 1) as f64
                        }
                    };
                    let v = inner - alpha[i] * lp[i][row];
                    let outer_max = !matches!(f, Formation::MinMin | Formation::MinMax);
                    best = Some(match best {
                        None => v,
                        Some(x) if outer_max => x.max(v),
                        Some(x) => x.min(v),
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
        let rem = t(&REM, &[1, 3]);
        let opts = InnerOptions {
            rem_weights: Some(&rem),
            aqe_drop: 1,
        };
        use Formation::*;
        for f in [MaxMin, MinMin, MinMax, MaxMax, MaxMean, MaxRem, MaxAqe] {
            let y = critic_target(
                &t(&r, &[1, 4]),
                &t(&d, &[1, 4]),
                &t(&qf, &[1, 3, 2, 4]),
                &t(&lpf, &[1, 2, 4]),
                &t(&alpha, &[1, 2, 1]),
                0.99,
                f,
                &opts,
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
                &t(&[alpha], &[1, 1, 1]),
                0.99,
                f,
                &InnerOptions {
                    rem_weights: None,
                    aqe_drop: 0,
                },
            );
            for b in 0..3 {
                // With M = N = 2 this is SAC's clipped double-Q target.
                let want = r[b] + 0.99 * (1.0 - d[b]) * (q[0][b].min(q[1][b]) - alpha * lp[b]);
                assert!((y.double_value(&[0, b as i64]) - want).abs() < 1e-12);
            }
        }
    }
}
