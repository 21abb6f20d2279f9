//! GPS-Hungarian and GPS-appearance-Hungarian: the second vehicle's
//! detections are moved into the first vehicle's frame with the relative
//! pose both GPS receivers report, their covariance grown by that pose's
//! uncertainty (`fusion::relative_pose_prior`: both position errors, and
//! the heading errors times the lever arm); pairs cost their squared
//! Mahalanobis distance; the assignment is solved optimally (`lsap`,
//! Jonker-Volgenant) and pairs beyond the chi-square gate are dropped.
//! `gps-hungarian` uses position only. `gps-app-hungarian`, the baseline a
//! practitioner writes first, adds the appearance (class, colour, size) to
//! the same cost as a log-likelihood term, `-2 ln s`, and gates pairs whose
//! appearance is incompatible.

use super::learning_free::{AffinityParams, appearance_similarity};
use super::{Correspondence, Identification, MatchView, Matcher, Method, binary_entropy_bits};
use crate::fusion::{Measurement, relative_pose_prior};

pub struct GpsHungarian {
    /// Gate on the squared Mahalanobis distance.
    pub gate_chi2: f64,
    /// Whether appearance enters the cost (`gps-app-hungarian`).
    pub appearance: bool,
}

impl Matcher for GpsHungarian {
    fn method(&self) -> Method {
        if self.appearance {
            Method::GpsAppHungarian
        } else {
            Method::GpsHungarian
        }
    }

    fn identify(&self, first: &MatchView, second: &MatchView) -> Identification {
        Identification::plain(self.assign(first, second))
    }
}

/// One candidate pair: its squared Mahalanobis distance and appearance
/// similarity.
#[derive(Clone, Copy)]
struct Candidate {
    d2: f64,
    appearance: f64,
}

impl GpsHungarian {
    /// The pairs that pass the gates, `n x m` row-major (`None`: gated).
    fn candidates(&self, first: &MatchView, second: &MatchView) -> Vec<Option<Candidate>> {
        let level = &first.pose_noise;
        let pose = relative_pose_prior(
            &first.pose_reported,
            &second.pose_reported,
            level.position_sigma_m,
            level.heading_sigma_rad,
        );
        let moved: Vec<Measurement> = second
            .detections
            .iter()
            .map(|d| {
                let m = Measurement {
                    position_m: d.position_m,
                    cov_m2: d.cov_m2,
                };
                m.moved_uncertain(&pose)
            })
            .collect();
        let min_appearance = AffinityParams::default().min_appearance;
        let mut out = Vec::with_capacity(first.detections.len() * moved.len());
        for da in first.detections {
            for (db, mb) in second.detections.iter().zip(&moved) {
                let r = da.position_m - mb.position_m;
                let d2 = (da.cov_m2 + mb.cov_m2)
                    .try_inverse()
                    .map(|s_inv| (r.transpose() * s_inv * r)[(0, 0)]);
                let appearance = if self.appearance {
                    appearance_similarity(&da.appearance, &db.appearance)
                } else {
                    1.0
                };
                out.push(match d2 {
                    Some(d2)
                        if d2.is_finite()
                            && d2 <= self.gate_chi2
                            && appearance >= min_appearance =>
                    {
                        Some(Candidate { d2, appearance })
                    }
                    _ => None,
                });
            }
        }
        out
    }

    fn assign(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence> {
        let (n, m) = (first.detections.len(), second.detections.len());
        if n == 0 || m == 0 {
            return Vec::new();
        }
        let candidates = self.candidates(first, second);
        // Cost: -2 ln(likelihood ratio) = d2 - 2 ln(appearance). Gated pairs
        // cost more than any pair that passes, so the solver never trades a
        // good pair for a gated one.
        let cost_of = |c: &Candidate| c.d2 - 2.0 * c.appearance.ln();
        let worst = self.gate_chi2 - 2.0 * AffinityParams::default().min_appearance.ln();
        let blocked = worst.max(1.0) * 1e3;
        let cost: Vec<f64> = candidates
            .iter()
            .map(|c| c.as_ref().map_or(blocked, cost_of))
            .collect();
        let Ok((rows, cols)) = lsap::solve(n, m, &cost, false) else {
            return Vec::new();
        };
        let mut out: Vec<Correspondence> = rows
            .into_iter()
            .zip(cols)
            .filter_map(|(a, b)| {
                let c = candidates[a * m + b]?;
                // Likelihood ratio against the gate: 1 at zero distance and
                // identical looks, about 0 at the gate.
                let probability = (-0.5 * c.d2).exp() * c.appearance;
                Some(Correspondence {
                    a,
                    b,
                    probability,
                    uncertainty: binary_entropy_bits(probability),
                })
            })
            .collect();
        out.sort_by_key(|c| c.a);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Vec2;
    use crate::matching::testkit::{self, Side};
    use crate::traffic::ObjectClass;

    #[test]
    fn exact_poses_recover_the_true_pairs_and_gate_the_rest() {
        let white = [0.9; 3];
        let world = vec![
            (Vec2::new(10.0, 5.0), ObjectClass::Car, white),
            (Vec2::new(20.0, -3.0), ObjectClass::Car, white),
            (Vec2::new(15.0, 12.0), ObjectClass::Car, white),
            (Vec2::new(-40.0, 0.0), ObjectClass::Car, white),
        ];
        let a = Side::of((0.0, 0.0, 0.0), &world, &[0, 1, 2], testkit::EXACT);
        // The second vehicle sees the last two objects (in the other order)
        // and one object the first does not see.
        let b = Side::of((30.0, 30.0, -2.0), &world, &[2, 3, 1], testkit::EXACT);
        let m = GpsHungarian {
            gate_chi2: 9.21,
            appearance: false,
        }
        .identify(&a.view(), &b.view())
        .matches;
        let pairs: Vec<(usize, usize)> = m.iter().map(|c| (c.a, c.b)).collect();
        assert_eq!(pairs, vec![(1, 2), (2, 0)]);
        assert!(
            m.iter()
                .all(|c| c.probability > 0.99 && c.uncertainty < 0.1)
        );
        let empty = Side::new(vec![], vec![], b.pose, testkit::EXACT);
        let none = GpsHungarian {
            gate_chi2: 9.21,
            appearance: true,
        }
        .identify(&a.view(), &empty.view());
        assert!(none.matches.is_empty());
    }

    /// A white car, a red van and a white car in a row, 3 m apart; the
    /// second vehicle sees the first two and its GPS is 3 m off along the
    /// row. By position alone its car lands on the van and its van on the
    /// second car (both wrong, and cheaper than the true pairs); with
    /// appearance the true pairs win.
    #[test]
    fn appearance_decides_where_position_cannot() {
        let (white, red) = ([0.95; 3], [0.7, 0.1, 0.1]);
        let world = vec![
            (Vec2::new(20.0, 0.0), ObjectClass::Car, white),
            (Vec2::new(23.0, 0.0), ObjectClass::Van, red),
            (Vec2::new(26.0, 0.0), ObjectClass::Car, white),
        ];
        let a = Side::of((0.0, 0.0, 0.0), &world, &[0, 1, 2], testkit::GPS);
        let mut b = Side::of((40.0, 10.0, 2.8), &world, &[0, 1], testkit::GPS);
        b.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(3.0, 0.0), 2.8);
        let right = |appearance: bool| {
            let m = GpsHungarian {
                gate_chi2: 9.21,
                appearance,
            }
            .identify(&a.view(), &b.view())
            .matches;
            (testkit::correct(&a, &b, &m), m.len())
        };
        assert_eq!(right(true), (2, 2));
        assert_eq!(right(false), (0, 2));
    }
}
