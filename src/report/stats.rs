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
