//! Means over Monte Carlo runs with the half-width of their 95% interval
//! (Student's t quantiles from statrs).

use statrs::distribution::{ContinuousCDF, StudentsT};

/// The 97.5% quantile of Student's t with `dof` degrees of freedom (NaN
/// for 0).
pub fn t_975(dof: usize) -> f64 {
    StudentsT::new(0.0, 1.0, dof as f64)
        .map(|t| t.inverse_cdf(0.975))
        .unwrap_or(f64::NAN)
}

/// Mean and half-width of the 95% confidence interval (Student t) of a
/// sample, ignoring values that are not finite; the half-width is NaN for
/// fewer than two values.
pub fn mean_ci95(values: &[f64]) -> (f64, f64) {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let n = v.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = v.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (mean, f64::NAN);
    }
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (mean, t_975(n - 1) * (var / n as f64).sqrt())
}

/// A paired difference over runs: its mean and the 95% percentile
/// bootstrap interval of that mean.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairedDifference {
    /// Runs where both sides are defined.
    pub n: usize,
    pub mean: f64,
    pub lo: f64,
    pub hi: f64,
}

impl PairedDifference {
    /// `Some(true)` when the interval lies above 0, `Some(false)` below,
    /// `None` when it covers 0 (or is undefined): "no difference".
    pub fn sign(&self) -> Option<bool> {
        if self.lo > 0.0 {
            Some(true)
        } else if self.hi < 0.0 {
            Some(false)
        } else {
            None
        }
    }
}

/// Resamples of [`paired_bootstrap`].
pub const BOOTSTRAP_RESAMPLES: usize = 10_000;

/// The paired difference `a - b` over runs (the same runs, hence the same
/// instances, on both sides; runs where either is not finite left out):
/// its mean and the 2.5% and 97.5% percentiles of the means of
/// [`BOOTSTRAP_RESAMPLES`] resamples of the runs with replacement, drawn
/// from a stream seeded with `seed` (the same inputs, the same interval).
/// Fewer than two runs give an undefined (NaN) interval.
pub fn paired_bootstrap(a: &[f64], b: &[f64], seed: u64) -> PairedDifference {
    use rand::Rng;
    let d: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(x, y)| x - y)
        .filter(|v| v.is_finite())
        .collect();
    let n = d.len();
    let mean = if n == 0 {
        f64::NAN
    } else {
        d.iter().sum::<f64>() / n as f64
    };
    if n < 2 {
        return PairedDifference {
            n,
            mean,
            lo: f64::NAN,
            hi: f64::NAN,
        };
    }
    let mut rng = crate::rng::stream(seed, crate::rng::Purpose::Bootstrap, &[n as u64]);
    let mut means: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .map(|_| (0..n).map(|_| d[rng.random_range(0..n)]).sum::<f64>() / n as f64)
        .collect();
    means.sort_by(f64::total_cmp);
    let at = |q: f64| means[((q * (means.len() - 1) as f64).round() as usize).min(means.len() - 1)];
    PairedDifference {
        n,
        mean,
        lo: at(0.025),
        hi: at(0.975),
    }
}
