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
//! appearance is incompatible. Both are [`super::likelihood`]'s pair
//! log-likelihood and assignment, which the deep matchers start from too.

use super::likelihood::{LikelihoodTerms, assign, pair_terms};
use super::{Correspondence, Identification, MatchView, Matcher, Method, binary_entropy_bits};
use crate::fusion::PoseEstimate;

pub struct GpsHungarian {
    /// Gate on the squared Mahalanobis distance.
    pub gate_chi2: f64,
    /// Whether appearance enters the cost (`gps-app-hungarian`).
    pub appearance: bool,
    /// The power of learned descriptors' likelihood ratio in its
    /// appearance term (1: as fitted; 0: unused).
    pub descriptor_weight: f64,
}

impl Matcher for GpsHungarian {
    fn method(&self) -> Method {
        if self.appearance {
            Method::GpsAppHungarian
        } else {
            Method::GpsHungarian
        }
    }

    fn uses_positions(&self) -> bool {
        true
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Identification {
        let terms = LikelihoodTerms {
            appearance: self.appearance,
            descriptor_weight: self.descriptor_weight,
            ..LikelihoodTerms::full(self.gate_chi2)
        };
        let pairs = pair_terms(first, second, relative, &terms);
        let m = second.detections.len();
        let scores: Vec<Option<f64>> = pairs
            .iter()
            .map(|p| p.map(|p| p.log_likelihood()))
            .collect();
        let matches = assign(first.detections.len(), m, &scores)
            .into_iter()
            .map(|(a, b)| {
                // Likelihood ratio against a perfect pair: 1 at zero
                // distance and identical looks (and descriptors), about 0
                // at the gate.
                let perfect = match (
                    &first.detections[a].appearance.descriptor,
                    &second.detections[b].appearance.descriptor,
                ) {
                    (Some(d), Some(_)) if self.appearance => {
                        d.most_alike_ratio().powf(self.descriptor_weight)
                    }
                    _ => 1.0,
                };
                let probability = scores[a * m + b].map_or(0.0, |s| (s.exp() / perfect).min(1.0));
                Correspondence {
                    a,
                    b,
                    probability,
                    uncertainty: binary_entropy_bits(probability),
                }
            })
            .collect();
        Identification::matches_only(matches)
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
            descriptor_weight: 1.0,
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
            descriptor_weight: 1.0,
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
                descriptor_weight: 1.0,
            }
            .identify(&a.view(), &b.view())
            .matches;
            (testkit::correct(&a, &b, &m), m.len())
        };
        assert_eq!(right(true), (2, 2));
        assert_eq!(right(false), (0, 2));
    }

    /// Regression (probabilities above 1 with appearance vectors): with
    /// descriptors whose likelihood ratio exceeds 1, GPS+appearance
    /// Hungarian's probability is still a ratio against a perfect pair:
    /// in [0, 1], and 1 for an exact pair with identical descriptors.
    #[test]
    fn gps_app_hungarian_probabilities_stay_in_0_1_with_descriptors() {
        use crate::sensor::{Descriptor, DescriptorLaw};
        let white = [0.9; 3];
        let world = vec![
            (Vec2::new(10.0, 5.0), ObjectClass::Car, white),
            (Vec2::new(20.0, -3.0), ObjectClass::Car, white),
            (Vec2::new(15.0, 12.0), ObjectClass::Car, white),
        ];
        let law = DescriptorLaw {
            slope: 10.0,
            neutral: 0.6,
        };
        let describe = |side: &mut Side| {
            for (d, &k) in side.detections.iter_mut().zip(&side.objects) {
                let mut values = vec![0.2f32; 3];
                values[k] = 1.0;
                d.appearance.descriptor = Some(Descriptor {
                    values: values.into(),
                    law,
                });
            }
        };
        let mut a = Side::of((0.0, 0.0, 0.0), &world, &[0, 1, 2], testkit::EXACT);
        let mut b = Side::of((30.0, 4.0, 2.5), &world, &[2, 0], testkit::EXACT);
        describe(&mut a);
        describe(&mut b);
        let m = GpsHungarian {
            gate_chi2: 9.21,
            appearance: true,
            descriptor_weight: 1.0,
        }
        .identify(&a.view(), &b.view())
        .matches;
        assert_eq!(testkit::correct(&a, &b, &m), 2);
        for c in &m {
            assert!((c.probability - 1.0).abs() < 1e-9, "{c:?}");
            assert!(c.uncertainty.is_finite());
        }
    }
}
