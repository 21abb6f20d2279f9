//! How much a learned appearance descriptor says ([`fit_law`]): the
//! log-likelihood ratio of one object against two as a line in the
//! descriptors' cosine similarity, from a logistic regression on labelled
//! pairs of validation data (its intercept less the pairs' prior log-odds
//! puts the line's zero, the neutral similarity). The appearance
//! similarity multiplies by that ratio
//! ([`crate::sensor::Descriptor::likelihood_ratio`]).

use crate::sensor::DescriptorLaw;

/// The law of [`fit_logistic`]'s fit to `pairs`: its slope, and the
/// similarity where the likelihood ratio is 1 (the log-odds equal the
/// pairs' prior log-odds). `None` when the fit is, or its slope is not
/// positive (the descriptor does not tell objects apart).
pub fn fit_law(pairs: &[(f64, bool)]) -> Option<DescriptorLaw> {
    let (slope, intercept) = fit_logistic(pairs)?;
    let positives = pairs.iter().filter(|p| p.1).count() as f64;
    let prior = (positives / (pairs.len() as f64 - positives)).ln();
    (slope > 0.0).then(|| DescriptorLaw {
        slope,
        neutral: (prior - intercept) / slope,
    })
}

/// The precision of the prior on the slope (1 / 10^2).
const RIDGE: f64 = 0.01;

/// The logistic regression `P(same | cos) = sigmoid(a cos + b)` fitted to
/// `pairs` (cosine similarity, same object) by Newton's method: `(a, b)`;
/// `None` without pairs of both kinds, or when the fit does not settle.
pub fn fit_logistic(pairs: &[(f64, bool)]) -> Option<(f64, f64)> {
    let positives = pairs.iter().filter(|p| p.1).count();
    if positives == 0 || positives == pairs.len() {
        return None;
    }
    let (mut a, mut b) = (0.0f64, 0.0f64);
    for _ in 0..100 {
        // Gradient and Hessian of the log-likelihood with a weak Gaussian
        // prior on the slope (sigma 10), so that pairs a cosine separates
        // perfectly still settle on a finite slope.
        let (mut ga, mut gb) = (-RIDGE * a, 0.0);
        let (mut haa, mut hab, mut hbb) = (RIDGE, 0.0, 1e-9);
        for &(x, y) in pairs {
            let p = 1.0 / (1.0 + (-(a * x + b)).exp());
            let r = f64::from(u8::from(y)) - p;
            ga += r * x;
            gb += r;
            let w = p * (1.0 - p);
            haa += w * x * x;
            hab += w * x;
            hbb += w;
        }
        let det = haa * hbb - hab * hab;
        if det <= 0.0 || !det.is_finite() {
            return None;
        }
        let da = (hbb * ga - hab * gb) / det;
        let db = (haa * gb - hab * ga) / det;
        a += da;
        b += db;
        if da.abs() < 1e-9 && db.abs() < 1e-9 {
            break;
        }
    }
    (a.is_finite() && b.is_finite()).then_some((a, b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Pairs drawn from a known logistic law give back its slope and
    /// intercept, and the neutral similarity where the log-odds are the
    /// prior's; pairs of one kind give none; a cosine that says nothing
    /// gives a slope near 0 and no law.
    #[test]
    fn the_fit_recovers_a_known_law() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let law = |a: f64, b: f64, rng: &mut ChaCha8Rng| -> Vec<(f64, bool)> {
            (0..20_000)
                .map(|_| {
                    let x: f64 = rng.random();
                    let p = 1.0 / (1.0 + (-(a * x + b)).exp());
                    (x, rng.random::<f64>() < p)
                })
                .collect()
        };
        let pairs = law(8.0, -6.0, &mut rng);
        let (a, b) = fit_logistic(&pairs).unwrap();
        assert!((a - 8.0).abs() < 0.5 && (b + 6.0).abs() < 0.4, "{a} {b}");
        let fitted = fit_law(&pairs).unwrap();
        let positives = pairs.iter().filter(|p| p.1).count() as f64;
        let prior = (positives / (pairs.len() as f64 - positives)).ln();
        assert!((a * fitted.neutral + b - prior).abs() < 1e-9);
        let flat = law(-0.5, -1.0, &mut rng);
        assert!((fit_logistic(&flat).unwrap().0 + 0.5).abs() < 0.4);
        assert!(fit_law(&flat).is_none());
        assert!(fit_logistic(&[(0.5, true), (0.9, true)]).is_none());
        assert!(fit_law(&[]).is_none());
        // A cosine that separates perfectly: a finite, steep slope.
        let separable: Vec<(f64, bool)> = (0..40).map(|k| (f64::from(k) / 40.0, k >= 30)).collect();
        let steep = fit_law(&separable).unwrap();
        assert!(steep.slope > 10.0 && steep.slope.is_finite(), "{steep:?}");
    }
}
