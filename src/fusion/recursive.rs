//! An object's estimate fused again at every update ([`Recursive`]).

use super::{Measurement, covariance_intersection, fuse};
use crate::geometry::{Cov2, Vec2};

/// An object's estimate fused anew at every update with the newest
/// measurements, in two forms: by Eq. 14-16 as if every input were
/// independent (the estimate already holds earlier measurements of the
/// same sources, so it counts them again) and by covariance intersection,
/// which does not.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Recursive {
    /// When it was last updated (s).
    pub time_s: f64,
    pub independent: Measurement,
    pub ci: Measurement,
}

impl Recursive {
    /// `previous` (when there is one) moved to `time_s` with `velocity_mps`,
    /// its covariance grown by white-noise acceleration of
    /// `accel_sigma_mps2`, fused with `measurements` in both forms; without
    /// one, `measurements` fused. `None` when a covariance is singular.
    pub fn update(
        previous: Option<&Recursive>,
        time_s: f64,
        velocity_mps: Vec2,
        accel_sigma_mps2: f64,
        measurements: &[Measurement],
    ) -> Option<Recursive> {
        let grow = |m: Measurement, dt: f64| Measurement {
            position_m: m.position_m + velocity_mps * dt,
            cov_m2: m.cov_m2 + Cov2::identity() * (accel_sigma_mps2 * dt * dt / 2.0).powi(2),
        };
        let (independent, ci) = match previous {
            Some(r) => {
                let dt = time_s - r.time_s;
                let with = |m: Measurement| {
                    let mut all = vec![grow(m, dt)];
                    all.extend_from_slice(measurements);
                    all
                };
                (
                    fuse(&with(r.independent)),
                    covariance_intersection(&with(r.ci)),
                )
            }
            None => (fuse(measurements), covariance_intersection(measurements)),
        };
        Some(Recursive {
            time_s,
            independent: independent?.measurement(),
            ci: ci?.measurement(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f64, var: f64) -> Measurement {
        Measurement {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::identity() * var,
        }
    }

    /// The first update fuses the measurements; each later one adds the
    /// moved, grown estimate: the independent form shrinks on the same
    /// inputs, covariance intersection never claims less than its inputs
    /// allow; a singular input gives none.
    #[test]
    fn each_update_fuses_the_previous_estimate_with_the_new_measurements() {
        let ms = [at(0.0, 1.0), at(2.0, 1.0)];
        let first = Recursive::update(None, 1.0, Vec2::zeros(), 0.0, &ms).unwrap();
        assert_eq!(first.independent, fuse(&ms).unwrap().measurement());
        assert_eq!(
            first.ci,
            covariance_intersection(&ms).unwrap().measurement()
        );
        let v = Vec2::new(1.0, 0.0);
        let second = Recursive::update(Some(&first), 2.0, v, 0.0, &ms).unwrap();
        assert_eq!(second.time_s, 2.0);
        assert!(second.independent.cov_m2.trace() < first.independent.cov_m2.trace());
        // Moved 1 m by its velocity (to 2, variance 0.5) before fusing:
        // information-weighted (2 * 2 + 0 + 2) / 4.
        assert!((second.independent.position_m.x - 1.5).abs() < 1e-12);
        assert!(second.ci.cov_m2.trace() >= first.ci.cov_m2.trace() - 1e-9);
        assert!(Recursive::update(None, 1.0, v, 0.0, &[at(0.0, 0.0)]).is_none());
    }
}
