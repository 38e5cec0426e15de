//! Lining runs up on env steps (or rounds, critic updates, wall-clock: any increasing x), and the statistics over seeds: shared by `selkd experiment
//! report` and `selkd plot`, so that both draw the same curve from the same runs.
//!
//! Runs are never lined up by CSV row: two seeds (or two methods) need not have evaluated at the
//! same env steps (different `eval.epoch_env_steps`, a run that stopped early), and averaging
//! row i of one with row i of another would average different points of training. Each seed's
//! curve is interpolated linearly onto one common grid of env steps instead: every multiple of
//! the shortest epoch length within the range that all seeds cover (never extrapolated).
//!
//! The spread over seeds is the **sample** standard deviation (divisor n − 1), everywhere in the
//! report and in `selkd plot`; it is undefined (NaN) for a single seed.

use anyhow::{bail, Result};

/// Several seeds' curves on one grid of env steps.
#[derive(Clone, Debug, PartialEq)]
pub struct Aligned {
    /// Env steps (all actors together).
    pub grid: Vec<f64>,
    /// `[seed][grid point]`.
    pub seeds: Vec<Vec<f64>>,
}

impl Aligned {
    /// Interpolates each `(env_steps, values)` curve onto [`common_grid`].
    pub fn new(curves: &[(&[f64], &[f64])]) -> Result<Aligned> {
        let steps: Vec<&[f64]> = curves.iter().map(|c| c.0).collect();
        let grid = common_grid(&steps)?;
        let seeds = curves
            .iter()
            .map(|(x, y)| interpolate(x, y, &grid))
            .collect();
        Ok(Aligned { grid, seeds })
    }

    fn column(&self, g: usize) -> Vec<f64> {
        self.seeds.iter().map(|s| s[g]).collect()
    }

    /// Mean over seeds at each grid point.
    pub fn mean(&self) -> Vec<f64> {
        (0..self.grid.len())
            .map(|g| mean(&self.column(g)))
            .collect()
    }

    /// Sample standard deviation over seeds at each grid point.
    pub fn std(&self) -> Vec<f64> {
        (0..self.grid.len())
            .map(|g| sample_std(&self.column(g)))
            .collect()
    }
}

/// The shortest gap between consecutive env-step counts of a curve (its epoch length).
fn epoch_length(steps: &[f64]) -> Option<f64> {
    steps
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .min_by(f64::total_cmp)
}

/// The most grid points a curve is interpolated onto (a run of 300k env steps evaluated every
/// 1 000 has 300).
const MAX_POINTS: f64 = 2000.0;

/// Every multiple of the shortest epoch length (over all curves) in `[max first, min last]`:
/// the env steps that every curve covers. A single epoch per curve gives that one point.
pub fn common_grid(curves: &[&[f64]]) -> Result<Vec<f64>> {
    if curves.is_empty() || curves.iter().any(|c| c.is_empty()) {
        bail!("a run has no evaluated epochs to line up");
    }
    let lo = curves.iter().map(|c| c[0]).fold(f64::MIN, f64::max);
    let hi = curves
        .iter()
        .map(|c| *c.last().unwrap())
        .fold(f64::MAX, f64::min);
    if lo > hi {
        bail!("the runs cover no common range of env steps (one ends at {hi}, another starts at {lo})");
    }
    let Some(step) = curves
        .iter()
        .filter_map(|c| epoch_length(c))
        .min_by(f64::total_cmp)
    else {
        return Ok(vec![lo]);
    };
    // Wall-clock seconds (and async critic updates) have no common epoch length: two epochs
    // a fraction of a second apart would make a grid of millions of points. Beyond
    // MAX_POINTS, a round step of about (hi − lo) / MAX_POINTS is fine enough for any figure.
    let step = if (hi - lo) / step > MAX_POINTS {
        super::figure::nice_step(hi - lo, MAX_POINTS as usize)
    } else {
        step
    };
    // A small tolerance: env steps are integers, but lo / step need not divide exactly in f64.
    let first = (lo / step - 1e-9).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    let grid: Vec<f64> = (first..=last).map(|k| k as f64 * step).collect();
    Ok(if grid.is_empty() { vec![lo] } else { grid })
}

/// Piecewise-linear interpolation of `(xs, ys)` (xs increasing) at each point of `grid`;
/// NaN outside `[xs[0], xs[last]]` and where a neighbour is NaN (an epoch with no evaluation).
pub fn interpolate(xs: &[f64], ys: &[f64], grid: &[f64]) -> Vec<f64> {
    grid.iter()
        .map(|&g| {
            let Some(i) = xs.iter().rposition(|&x| x <= g) else {
                return f64::NAN;
            };
            if xs[i] == g {
                return ys[i];
            }
            if i + 1 >= xs.len() {
                return f64::NAN;
            }
            let t = (g - xs[i]) / (xs[i + 1] - xs[i]);
            ys[i] + t * (ys[i + 1] - ys[i])
        })
        .collect()
}

/// Mean of the finite values (NaN if none).
pub fn mean(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() {
        f64::NAN
    } else {
        f.iter().sum::<f64>() / f.len() as f64
    }
}

/// Sample standard deviation (divisor n − 1) of the finite values; NaN for fewer than two.
pub fn sample_std(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.len() < 2 {
        return f64::NAN;
    }
    let m = f.iter().sum::<f64>() / f.len() as f64;
    (f.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (f.len() - 1) as f64).sqrt()
}

/// The paper's stability measure: the mean, over the grid points in the second half of training
/// (env steps ≥ half the budget), of the std across seeds.
pub fn second_half_mean(grid: &[f64], values: &[f64], budget: f64) -> f64 {
    let half: Vec<f64> = grid
        .iter()
        .zip(values)
        .filter(|(x, _)| **x >= budget / 2.0)
        .map(|(_, v)| *v)
        .collect();
    mean(&half)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_of_different_epoch_lengths_meet_on_a_common_grid_interpolated_by_hand() {
        // Seed A evaluates every 500 env steps, seed B every 600 from 600 to 1800.
        let (ax, ay) = (
            vec![500.0, 1000.0, 1500.0, 2000.0],
            vec![0.0, 10.0, 20.0, 30.0],
        );
        let (bx, by) = (vec![600.0, 1200.0, 1800.0], vec![6.0, 12.0, 24.0]);
        let a = Aligned::new(&[(&ax, &ay), (&bx, &by)]).unwrap();
        // Shortest epoch 500; both cover [600, 1800]: the multiples 1000 and 1500.
        assert_eq!(a.grid, vec![1000.0, 1500.0]);
        assert_eq!(a.seeds[0], vec![10.0, 20.0]);
        // B at 1000: 6 + (400/600)·6 = 10; at 1500: 12 + (300/600)·12 = 18.
        assert!((a.seeds[1][0] - 10.0).abs() < 1e-12);
        assert!((a.seeds[1][1] - 18.0).abs() < 1e-12);
        assert_eq!(a.mean()[1], 19.0);
        // Sample std of {20, 18}: sqrt(((1)² + (1)²) / 1) = sqrt(2).
        assert!((a.std()[1] - 2f64.sqrt()).abs() < 1e-12);
        assert!(a.std()[0].abs() < 1e-12);
    }

    #[test]
    fn interpolation_is_nan_outside_the_curve_and_exact_on_its_points() {
        let v = interpolate(
            &[100.0, 200.0],
            &[1.0, f64::NAN],
            &[50.0, 100.0, 150.0, 250.0],
        );
        assert!(v[0].is_nan() && v[2].is_nan() && v[3].is_nan());
        assert_eq!(v[1], 1.0);
    }

    #[test]
    fn std_and_second_half_mean_by_hand() {
        // {1, 2, 3, 6}: mean 3, squares 4 + 1 + 0 + 9 = 14, sample var 14/3.
        assert!((sample_std(&[1.0, 2.0, 3.0, 6.0]) - (14.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert!(sample_std(&[5.0]).is_nan());
        // Budget 2000: the points at 1000, 1500 and 2000 are the second half.
        let grid = [500.0, 1000.0, 1500.0, 2000.0];
        assert_eq!(
            second_half_mean(&grid, &[100.0, 3.0, 4.0, 8.0], 2000.0),
            5.0
        );
    }

    #[test]
    fn an_irregular_axis_gets_a_round_step_not_millions_of_points() {
        // Wall-clock: epochs 0.001 s apart once, over 100 000 s: the step becomes 50 s
        // (100 000 / 2 000 = 50 is already round), 0 … 100 000 in 2 001 points.
        let a = [0.0, 0.001, 50_000.0, 100_000.0];
        let grid = common_grid(&[&a]).unwrap();
        assert_eq!(grid.len(), 2001);
        assert_eq!((grid[1], grid[2000]), (50.0, 100_000.0));
    }

    #[test]
    fn runs_without_a_common_range_are_refused() {
        let e = common_grid(&[&[100.0, 200.0], &[300.0, 400.0]]).unwrap_err();
        assert!(e.to_string().contains("no common range"), "{e}");
    }
}
