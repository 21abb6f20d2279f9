//! Combining N measurements of one object: as independent (Eq. 14-16,
//! [`fuse`]) or with errors correlated in unknown ways (covariance
//! intersection, [`covariance_intersection`]).

use nalgebra::Matrix2;

use super::{Fused, Measurement};
use crate::geometry::Vec2;

/// Fuses N >= 1 measurements of one object (all in the same frame):
/// `P = (sum_n P_n^-1)^-1`, `M_i = P P_i^-1`, `v = sum_i M_i v_i`.
/// `None` when a covariance (or the information sum) is singular.
pub fn fuse(measurements: &[Measurement]) -> Option<Fused> {
    if measurements.is_empty() {
        return None;
    }
    let infos: Vec<Matrix2<f64>> = measurements
        .iter()
        .map(|m| m.cov_m2.try_inverse())
        .collect::<Option<_>>()?;
    let info_sum = infos.iter().fold(Matrix2::zeros(), |s, i| s + i);
    let cov = info_sum.try_inverse()?;
    let gains: Vec<Matrix2<f64>> = infos.iter().map(|i| cov * i).collect();
    let position_m = gains
        .iter()
        .zip(measurements)
        .fold(Vec2::zeros(), |s, (g, m)| s + g * m.position_m);
    // Symmetrise against round-off.
    let cov_m2 = (cov + cov.transpose()) * 0.5;
    Some(Fused {
        position_m,
        cov_m2,
        gains,
    })
}

/// Covariance intersection of N >= 1 measurements whose errors may be
/// correlated in unknown ways (a shared GNSS error, a track sent again):
/// `P^-1 = sum_i w_i P_i^-1`, `v = P sum_i w_i P_i^-1 v_i`, with weights
/// `w_i >= 0` summing to 1 that minimise the trace of `P` (golden-section
/// moves toward one vertex of the simplex at a time). Never claims more
/// than any convex combination of the inputs; with one measurement, it is
/// that measurement. The gains are `w_i P P_i^-1`.
pub fn covariance_intersection(measurements: &[Measurement]) -> Option<Fused> {
    let infos: Vec<Matrix2<f64>> = measurements
        .iter()
        .map(|m| m.cov_m2.try_inverse())
        .collect::<Option<_>>()?;
    let n = infos.len();
    if n == 0 {
        return None;
    }
    let trace = |w: &[f64]| {
        let info = infos
            .iter()
            .zip(w)
            .fold(Matrix2::zeros(), |s, (i, &w)| s + i * w);
        info.try_inverse().map_or(f64::INFINITY, |p| p.trace())
    };
    // From equal weights, move toward one vertex at a time (the trace of
    // P is convex in w) while the trace falls.
    let mut w = vec![1.0 / n as f64; n];
    for _ in 0..50 {
        let before = trace(&w);
        for i in 0..n {
            let toward = |t: f64| {
                let mut v: Vec<f64> = w.iter().map(|x| x * (1.0 - t)).collect();
                v[i] += t;
                v
            };
            let t = golden_min(|t| trace(&toward(t)), 0.0, 1.0);
            w = toward(t);
        }
        if before - trace(&w) <= 1e-13 * before.abs().max(1e-300) {
            break;
        }
    }
    let info = infos
        .iter()
        .zip(&w)
        .fold(Matrix2::zeros(), |s, (i, &w)| s + i * w);
    let cov = info.try_inverse()?;
    let gains: Vec<Matrix2<f64>> = infos.iter().zip(&w).map(|(i, &w)| cov * i * w).collect();
    let position_m = gains
        .iter()
        .zip(measurements)
        .fold(Vec2::zeros(), |s, (g, m)| s + g * m.position_m);
    Some(Fused {
        position_m,
        cov_m2: (cov + cov.transpose()) * 0.5,
        gains,
    })
}

/// The minimum of a unimodal `f` on `[lo, hi]` by golden-section search.
fn golden_min(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..80 {
        if fc <= fd {
            hi = d;
            (d, fd) = (c, fc);
            c = hi - g * (hi - lo);
            fc = f(c);
        } else {
            lo = c;
            (c, fc) = (d, fd);
            d = lo + g * (hi - lo);
            fd = f(d);
        }
    }
    let mid = (lo + hi) / 2.0;
    // The ends may be the minimum (one measurement dominates).
    [0.0, 1.0, mid]
        .into_iter()
        .min_by(|&a, &b| f(a).total_cmp(&f(b)))
        .unwrap_or(mid)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::geometry::Cov2;

    /// Covariance intersection on hand-made covariances: two mirrored
    /// ellipses meet at w = 1/2 with P = diag(1.6, 1.6); a measurement
    /// that is tighter on every axis takes all the weight; CI is never
    /// tighter than the independent form, and unlike it never claims less
    /// than half the error of two identical, fully correlated copies.
    #[test]
    fn covariance_intersection_gives_the_known_results() {
        let m = |x: f64, a: f64, b: f64| Measurement {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::new(a, 0.0, 0.0, b),
        };
        let ci = covariance_intersection(&[m(0.0, 1.0, 4.0), m(2.0, 4.0, 1.0)]).unwrap();
        assert!(
            (ci.cov_m2 - Cov2::identity() * 1.6).norm() < 1e-6,
            "{}",
            ci.cov_m2
        );
        assert!((ci.position_m.x - 0.4).abs() < 1e-6, "{}", ci.position_m);
        let ci = covariance_intersection(&[m(0.0, 1.0, 1.0), m(5.0, 4.0, 9.0)]).unwrap();
        assert!((ci.position_m.x).abs() < 1e-6 && (ci.cov_m2 - Cov2::identity()).norm() < 1e-6);
        let same = [m(1.0, 2.0, 2.0), m(1.0, 2.0, 2.0)];
        let (ci, ind) = (
            covariance_intersection(&same).unwrap(),
            fuse(&same).unwrap(),
        );
        assert!((ci.cov_m2 - Cov2::identity() * 2.0).norm() < 1e-9);
        assert!((ind.cov_m2 - Cov2::identity()).norm() < 1e-12);
        let one = covariance_intersection(&[m(3.0, 2.0, 5.0)]).unwrap();
        assert_eq!((one.position_m.x, one.cov_m2[(1, 1)]), (3.0, 5.0));
        let gains = ci.gains.iter().fold(Matrix2::zeros(), |s, g| s + g);
        assert!((gains - Matrix2::identity()).norm() < 1e-9);
    }

    fn cov(a: f64, b: f64, c: f64) -> Cov2 {
        // A valid covariance from a lower-triangular factor.
        let l = Matrix2::new(a, 0.0, c, b);
        l * l.transpose() + Cov2::identity() * 1e-3
    }

    proptest! {
        #[test]
        fn gains_sum_to_identity(fs in proptest::collection::vec((0.1..3.0f64, 0.1..3.0f64, -2.0..2.0f64, -20.0..20.0f64, -20.0..20.0f64), 1..6)) {
            let ms: Vec<Measurement> = fs.iter().map(|&(a, b, c, x, y)| Measurement { position_m: Vec2::new(x, y), cov_m2: cov(a, b, c) }).collect();
            let f = fuse(&ms).unwrap();
            let sum = f.gains.iter().fold(Matrix2::zeros(), |s, g| s + g);
            prop_assert!((sum - Matrix2::identity()).norm() < 1e-9);
            // The fused covariance is no larger than any input's.
            for m in &ms {
                prop_assert!(f.cov_m2.trace() <= m.cov_m2.trace() + 1e-9);
            }
        }

        #[test]
        fn agreeing_measurements_fuse_to_the_same_point(x in -50.0..50.0f64, y in -50.0..50.0f64, a in 0.1..3.0f64, b in 0.1..3.0f64) {
            let p = Vec2::new(x, y);
            let ms = [Measurement { position_m: p, cov_m2: cov(a, b, 0.3) }, Measurement { position_m: p, cov_m2: cov(b, a, -0.5) }];
            prop_assert!((fuse(&ms).unwrap().position_m - p).norm() < 1e-9);
        }
    }

    #[test]
    fn equal_covariances_average_and_halve() {
        let c = Cov2::identity() * 4.0;
        let f = fuse(&[
            Measurement {
                position_m: Vec2::new(0.0, 0.0),
                cov_m2: c,
            },
            Measurement {
                position_m: Vec2::new(2.0, 4.0),
                cov_m2: c,
            },
        ])
        .unwrap();
        assert!((f.position_m - Vec2::new(1.0, 2.0)).norm() < 1e-12);
        assert!((f.cov_m2 - Cov2::identity() * 2.0).norm() < 1e-12);
    }

    #[test]
    fn singular_covariance_is_refused() {
        assert!(
            fuse(&[Measurement {
                position_m: Vec2::zeros(),
                cov_m2: Cov2::zeros()
            }])
            .is_none()
        );
        assert!(fuse(&[]).is_none());
    }
}
