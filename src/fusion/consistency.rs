//! The claim a fused estimate can honestly make: the inputs' covariances
//! scaled by their spread ([`consistency_scale`]), hedged by the
//! probability that the match is right ([`hedged_covariance`]), and the
//! error an estimate makes against the covariance it claims ([`nees`]).

use super::{Fused, Measurement};
use crate::geometry::{Cov2, Vec2};

/// The chi-square probability beyond which matched measurements are
/// taken to disagree more than their covariances allow
/// ([`consistency_scale`]): the textbook 99 %, fixed before any data was
/// looked at.
pub const CONSISTENCY_GATE_PROB: f64 = 0.99;

/// How much the measurements' covariances must grow for their spread about
/// the fused position to be believable: `q = sum_i (v_i - v)^T P_i^-1
/// (v_i - v)` is chi-square with `2 (N - 1)` degrees of freedom when every
/// covariance is the truth and every measurement is of the same object (for
/// two, `d^T (P_1 + P_2)^-1 d` of their difference `d`). Beyond the
/// [`CONSISTENCY_GATE_PROB`] quantile the covariances are scaled by the
/// maximum-likelihood factor `q / (2 (N - 1))`, below it by 1. Scaling
/// every covariance by one factor keeps the gains and the fused position
/// and scales Eq. 16's covariance by it: the claim grows where the inputs
/// disagree (a wrong match, a report too confident), as an adaptive filter
/// scales its covariance by the innovation. 1 for one measurement.
pub fn consistency_scale(measurements: &[Measurement], fused: &Fused) -> f64 {
    let dof = 2 * measurements.len().saturating_sub(1);
    if dof == 0 {
        return 1.0;
    }
    let q: f64 = measurements
        .iter()
        .map(|m| {
            let d = m.position_m - fused.position_m;
            m.cov_m2
                .try_inverse()
                .map_or(f64::INFINITY, |inv| (d.transpose() * inv * d)[(0, 0)])
        })
        .sum();
    if q > consistency_gate(dof) {
        q / dof as f64
    } else {
        1.0
    }
}

/// The covariance a fused estimate `fused` can claim when the match it
/// fused is right only with `probability` (the matching method's own): the
/// mixture of two hypotheses about the committed estimate's error. Right:
/// Eq. 16's covariance times the inputs' [`consistency_scale`] `scale`.
/// Wrong: the ego's own measurement `own` is the object's only evidence, so
/// the error is its error plus the pull of the fusion, `P_own + (v -
/// v_own)(v - v_own)^T`: the covariance probabilistic data association
/// gives an estimate committed to one hypothesis. With probability 1 it is
/// the scaled Eq. 16; it stays honest only as far as the method's
/// probabilities are calibrated.
pub fn hedged_covariance(own: &Measurement, fused: &Fused, scale: f64, probability: f64) -> Cov2 {
    let p = probability.clamp(0.0, 1.0);
    let pull = fused.position_m - own.position_m;
    fused.cov_m2 * (scale * p) + (own.cov_m2 + pull * pull.transpose()) * (1.0 - p)
}

/// The [`CONSISTENCY_GATE_PROB`] quantile of the chi-square distribution
/// with `dof` degrees of freedom (statrs), computed once for the first
/// sixteen measurements' `dof` (the fusion asks for it per object).
fn consistency_gate(dof: usize) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    let quantile = |dof: usize| {
        ChiSquared::new(dof as f64).map_or(f64::INFINITY, |d| d.inverse_cdf(CONSISTENCY_GATE_PROB))
    };
    let table = TABLE.get_or_init(|| (0..=30).map(quantile).collect());
    table.get(dof).copied().unwrap_or_else(|| quantile(dof))
}

/// The normalised estimation error squared of an estimate off by `error`
/// that claims covariance `cov`: `e^T P^-1 e`, 2 on average (two
/// dimensions) when the claim is honest; NaN when `cov` is singular.
pub fn nees(error: Vec2, cov: &Cov2) -> f64 {
    cov.try_inverse()
        .map_or(f64::NAN, |inv| (error.transpose() * inv * error)[(0, 0)])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::fuse;

    /// The consistency scale on hand-made pairs: two measurements at the
    /// same place (and one alone) keep Eq. 16's claim; 10 m apart with unit
    /// covariances `q = 100 / 2 = 50`, beyond chi2(2)'s 99 % (9.21), so the
    /// claim grows by `q / 2 = 25`; just inside the gate it stays.
    #[test]
    fn consistency_scale_gives_the_known_results() {
        let at = |x: f64| Measurement {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::identity(),
        };
        let scale = |ms: &[Measurement]| consistency_scale(ms, &fuse(ms).unwrap());
        assert_eq!(scale(&[at(1.0), at(1.0)]), 1.0);
        assert_eq!(scale(&[at(3.0)]), 1.0);
        assert!((scale(&[at(0.0), at(10.0)]) - 25.0).abs() < 1e-9);
        // q = d^2 / 2: d^2 = 18.0 gives q = 9.0 < 9.21; 19.0 gives 9.5.
        assert_eq!(scale(&[at(0.0), at(18f64.sqrt())]), 1.0);
        assert!((scale(&[at(0.0), at(19f64.sqrt())]) - 4.75).abs() < 1e-9);
        // Three measurements: dof 4, gate 13.28; spread q = 2 * 6^2 = 72.
        let three = [at(-6.0), at(0.0), at(6.0)];
        assert!((scale(&three) - 72.0 / 4.0).abs() < 1e-9);
    }

    /// Pairs drawn from their own covariances: the scale passes about 1 %
    /// of them and the gated claim's NEES stays near 2. When one in five
    /// pairs is a wrong match (the peer's detection of another object 6 m
    /// away), Eq. 16's NEES is far above 2 and the gated one within 1 to 4.
    #[test]
    fn consistency_scale_keeps_the_claim_honest_under_wrong_matches() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let cov = [
            Cov2::new(1.0, 0.3, 0.3, 0.5),
            Cov2::new(0.4, -0.1, -0.1, 2.0),
        ];
        let mut draw = |c: &Cov2, centre: Vec2| {
            let l = c.cholesky().unwrap().l();
            centre + l * Vec2::new(unit.sample(&mut rng), unit.sample(&mut rng))
        };
        let n = 20_000;
        let (mut scaled, mut nees, mut nees_gated) = (0, [0.0; 2], [0.0; 2]);
        for i in 0..n {
            let wrong = i % 5 == 0;
            let peer_object = if wrong {
                Vec2::new(6.0, 0.0)
            } else {
                Vec2::zeros()
            };
            let ms = [
                Measurement {
                    position_m: draw(&cov[0], Vec2::zeros()),
                    cov_m2: cov[0],
                },
                Measurement {
                    position_m: draw(&cov[1], peer_object),
                    cov_m2: cov[1],
                },
            ];
            let f = fuse(&ms).unwrap();
            let s = consistency_scale(&ms, &f);
            let e = f.position_m;
            let q = (e.transpose() * f.cov_m2.try_inverse().unwrap() * e)[(0, 0)];
            let k = usize::from(wrong);
            nees[k] += q;
            nees_gated[k] += q / s;
            scaled += usize::from(!wrong && s > 1.0);
        }
        let right = (n - n / 5) as f64;
        let passed = scaled as f64 / right;
        assert!((0.007..0.013).contains(&passed), "{passed}");
        let gated_right = nees_gated[0] / right;
        assert!((1.85..2.05).contains(&gated_right), "{gated_right}");
        let all = (nees[0] + nees[1]) / n as f64;
        let all_gated = (nees_gated[0] + nees_gated[1]) / n as f64;
        assert!(all > 4.0, "{all}");
        assert!((1.0..4.0).contains(&all_gated), "{all_gated}");
    }

    /// The hedged claim on hand-made cases: certain, it is Eq. 16's times
    /// the scale; impossible, the ego's own plus the pull of the fusion.
    #[test]
    fn hedged_covariance_gives_the_known_results() {
        let own = Measurement {
            position_m: Vec2::new(0.0, 0.0),
            cov_m2: Cov2::new(2.0, 0.0, 0.0, 1.0),
        };
        let peer = Measurement {
            position_m: Vec2::new(1.0, 0.0),
            cov_m2: Cov2::new(2.0, 0.0, 0.0, 1.0),
        };
        let f = fuse(&[own, peer]).unwrap();
        assert!((hedged_covariance(&own, &f, 1.0, 1.0) - f.cov_m2).norm() < 1e-12);
        assert!((hedged_covariance(&own, &f, 3.0, 1.0) - f.cov_m2 * 3.0).norm() < 1e-12);
        // Fused at (0.5, 0): the pull adds 0.25 along x.
        let wrong = Cov2::new(2.25, 0.0, 0.0, 1.0);
        assert!((hedged_covariance(&own, &f, 1.0, 0.0) - wrong).norm() < 1e-12);
        let half = f.cov_m2 * 0.5 + wrong * 0.5;
        assert!((hedged_covariance(&own, &f, 1.0, 0.5) - half).norm() < 1e-12);
    }

    /// Three in ten matches wrong (the peer's measurement of another
    /// object anywhere in a 40 m square, as likely inside the ego's wide
    /// covariance as anywhere else), each with the probability a
    /// calibrated method would give (the posterior of "same object" with a
    /// prior of 0.7): Eq. 16's NEES is far above 2 (578 here), the hedged
    /// claim's near 2 (2.004), as the mixture is the error's covariance.
    #[test]
    fn the_hedged_claim_is_honest_when_the_probability_is_calibrated() {
        use rand::{Rng, SeedableRng};
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let (p_own, p_peer) = (Cov2::new(4.0, 0.5, 0.5, 2.0), Cov2::new(0.1, 0.0, 0.0, 0.2));
        let sum_inv = (p_own + p_peer).try_inverse().unwrap();
        let density_right = |d: Vec2| {
            (-0.5 * (d.transpose() * sum_inv * d)[(0, 0)]).exp()
                / (2.0 * std::f64::consts::PI * (p_own + p_peer).determinant().sqrt())
        };
        let (prior, half) = (0.7, 20.0);
        let area = (2.0 * half) * (2.0 * half);
        let n = 40_000;
        let (mut eq16, mut hedged) = (0.0, 0.0);
        for _ in 0..n {
            let draw = |c: &Cov2, rng: &mut rand_chacha::ChaCha8Rng| {
                c.cholesky().unwrap().l() * Vec2::new(unit.sample(rng), unit.sample(rng))
            };
            let own = Measurement {
                position_m: draw(&p_own, &mut rng),
                cov_m2: p_own,
            };
            let peer_at = if rng.random::<f64>() < prior {
                draw(&p_peer, &mut rng)
            } else {
                Vec2::new(rng.random_range(-half..half), rng.random_range(-half..half))
            };
            let peer = Measurement {
                position_m: peer_at,
                cov_m2: p_peer,
            };
            let right = prior * density_right(peer_at - own.position_m);
            let probability = right / (right + (1.0 - prior) / area);
            let ms = [own, peer];
            let f = fuse(&ms).unwrap();
            let e = f.position_m;
            let nees = |c: Cov2| (e.transpose() * c.try_inverse().unwrap() * e)[(0, 0)];
            eq16 += nees(f.cov_m2);
            let scale = consistency_scale(&ms, &f);
            hedged += nees(hedged_covariance(&own, &f, scale, probability));
        }
        let (eq16, hedged) = (eq16 / n as f64, hedged / n as f64);
        assert!(eq16 > 10.0, "{eq16}");
        assert!((1.8..2.2).contains(&hedged), "{eq16} {hedged}");
    }

    #[test]
    fn nees_is_two_for_an_honest_unit_error_and_nan_when_singular() {
        let e = Vec2::new(1.0, 1.0);
        assert!((nees(e, &Cov2::identity()) - 2.0).abs() < 1e-12);
        assert!(nees(e, &Cov2::zeros()).is_nan());
    }
}
