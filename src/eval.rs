//! Evaluation: correspondence counts (precision, recall, F1) and displacement
//! errors, single-vehicle vs fused, for one instance at a time, and their
//! aggregation into summary rows. Pure computation; the protocol is written
//! down in the README ("Evaluation protocol").

use std::collections::{BTreeMap, HashMap};

use crate::config::{FusionVariant, PoseNoiseLabel, PoseNoiseLevel};
use crate::fusion::{Measurement, PosePrior, align, fuse};
use crate::geometry::Vec2;
use crate::matching::{Correspondence, Method};
use crate::sensor::Observation;

/// Correspondence counts of one or more instances.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairCounts {
    /// Pairs the method identified.
    pub identified: usize,
    /// Identified pairs whose two detections are the same true object.
    pub correct: usize,
    /// True covisible pairs: same object detected by both vehicles.
    pub ground_truth: usize,
}

impl PairCounts {
    pub fn add(&mut self, other: PairCounts) {
        self.identified += other.identified;
        self.correct += other.correct;
        self.ground_truth += other.ground_truth;
    }

    /// correct / identified; 1 when nothing was identified (no false claim).
    pub fn precision(&self) -> f64 {
        if self.identified == 0 {
            1.0
        } else {
            self.correct as f64 / self.identified as f64
        }
    }

    /// correct / ground truth; 1 when there was nothing to find.
    pub fn recall(&self) -> f64 {
        if self.ground_truth == 0 {
            1.0
        } else {
            self.correct as f64 / self.ground_truth as f64
        }
    }

    pub fn f1(&self) -> f64 {
        let (p, r) = (self.precision(), self.recall());
        if p + r == 0.0 {
            0.0
        } else {
            2.0 * p * r / (p + r)
        }
    }
}

/// Number of objects both vehicles detected (true covisible pairs).
pub fn covisible_pairs(first: &Observation, second: &Observation) -> usize {
    first
        .detections
        .iter()
        .filter_map(|d| d.truth_id.as_ref())
        .filter(|id| {
            second
                .detections
                .iter()
                .any(|d| d.truth_id.as_ref() == Some(*id))
        })
        .count()
}

pub fn count_pairs(
    first: &Observation,
    second: &Observation,
    matches: &[Correspondence],
) -> PairCounts {
    let correct = matches
        .iter()
        .filter(|c| {
            let a = &first.detections[c.a].truth_id;
            a.is_some() && *a == second.detections[c.b].truth_id
        })
        .count();
    PairCounts {
        identified: matches.len(),
        correct,
        ground_truth: covisible_pairs(first, second),
    }
}

/// One (ego, object) estimate of one instance, all positions in the world
/// frame: estimates live in the ego's frame and are placed in the world with
/// the ego's true pose, so the error is what the ego gets wrong about the
/// object relative to itself.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectEstimate {
    pub ego_id: String,
    pub peer_id: String,
    pub object_id: String,
    /// Whether the correspondence used for this object was right.
    pub match_correct: bool,
    /// Whether the relative pose was refined from matches (aligned variant).
    pub pose_refined: bool,
    pub truth_m: Vec2,
    pub single_m: Vec2,
    pub fused_m: Vec2,
}

impl ObjectEstimate {
    pub fn single_error_m(&self) -> f64 {
        (self.single_m - self.truth_m).norm()
    }
    pub fn fused_error_m(&self) -> f64 {
        (self.fused_m - self.truth_m).norm()
    }
}

/// The relative-pose prior of `second` in `first`'s frame from both reported
/// poses: each vehicle contributes its GPS error.
fn gps_prior(
    first_reported: &crate::geometry::Pose2,
    second_reported: &crate::geometry::Pose2,
    level: &PoseNoiseLevel,
) -> PosePrior {
    PosePrior {
        pose: first_reported.relative(second_reported),
        position_sigma_m: std::f64::consts::SQRT_2 * level.position_sigma_m,
        heading_sigma_rad: std::f64::consts::SQRT_2 * level.heading_sigma_rad,
    }
}

/// Everything one ego needs to fuse what its peer shares with it.
pub struct EgoSide<'a> {
    pub obs: &'a Observation,
    pub pose_reported: crate::geometry::Pose2,
}

/// Fused estimates of every object `ego` detected (with a true id) that the
/// correspondences pair with one of `peer`'s detections. `pairs` index
/// `(ego detection, peer detection)`.
pub fn fuse_for_ego(
    ego: &EgoSide,
    peer: &EgoSide,
    pairs: &[(usize, usize)],
    level: &PoseNoiseLevel,
    variant: FusionVariant,
    align_min_matches: usize,
    truth_world_m: &HashMap<&str, Vec2>,
) -> Vec<ObjectEstimate> {
    let prior = gps_prior(&ego.pose_reported, &peer.pose_reported, level);
    let measured = |obs: &Observation, k: usize| Measurement {
        position_m: obs.detections[k].position_m,
        cov_m2: obs.detections[k].cov_m2,
    };
    let alignment = match variant {
        FusionVariant::Paper => None,
        FusionVariant::Aligned => {
            let matched: Vec<(Measurement, Measurement)> = pairs
                .iter()
                .map(|&(a, b)| (measured(ego.obs, a), measured(peer.obs, b)))
                .collect();
            Some(align(&matched, &prior, align_min_matches))
        }
    };
    let (peer_in_ego, refined) = match alignment {
        Some(a) => (a.pose, a.refined),
        None => (prior.pose, false),
    };
    let mut out = Vec::new();
    for &(a, b) in pairs {
        let det = &ego.obs.detections[a];
        let Some(id) = det.truth_id.as_deref() else {
            continue;
        };
        let Some(&truth_m) = truth_world_m.get(id) else {
            continue;
        };
        let own = measured(ego.obs, a);
        let shared = measured(peer.obs, b).moved(&peer_in_ego);
        let Some(fused) = fuse(&[own, shared]) else {
            continue;
        };
        let to_world = |p: &Vec2| ego.obs.ego_pose_true.to_parent(p);
        out.push(ObjectEstimate {
            ego_id: ego.obs.ego_id.clone(),
            peer_id: peer.obs.ego_id.clone(),
            object_id: id.to_owned(),
            match_correct: peer.obs.detections[b].truth_id.as_deref() == Some(id),
            pose_refined: refined,
            truth_m,
            single_m: to_world(&own.position_m),
            fused_m: to_world(&fused.position_m),
        });
    }
    out
}

/// Fused estimates for both vehicles of a pair: each fuses what the other
/// shares for every matched object it detected (`matches` index
/// `(first detection, second detection)`).
pub fn fuse_pair(
    first: &EgoSide,
    second: &EgoSide,
    matches: &[Correspondence],
    level: &PoseNoiseLevel,
    variant: FusionVariant,
    align_min_matches: usize,
    truth_world_m: &HashMap<&str, Vec2>,
) -> Vec<ObjectEstimate> {
    let ab: Vec<(usize, usize)> = matches.iter().map(|c| (c.a, c.b)).collect();
    let ba: Vec<(usize, usize)> = matches.iter().map(|c| (c.b, c.a)).collect();
    let mut est = fuse_for_ego(
        first,
        second,
        &ab,
        level,
        variant,
        align_min_matches,
        truth_world_m,
    );
    est.extend(fuse_for_ego(
        second,
        first,
        &ba,
        level,
        variant,
        align_min_matches,
        truth_world_m,
    ));
    est
}

/// The key of a summary row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RowKey {
    pub method: Method,
    pub pose_noise: PoseNoiseLabel,
    pub fusion: FusionVariant,
}

/// Running sums for one summary row.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Accumulator {
    pub instances: usize,
    pub counts: PairCounts,
    pub objects: usize,
    pub single_error_sum_m: f64,
    pub fused_error_sum_m: f64,
}

/// One line of `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct SummaryRow {
    pub key: RowKey,
    pub n_instances: usize,
    pub n_objects: usize,
    pub precision: f64,
    pub recall: f64,
    pub f1: f64,
    /// Mean over objects; NaN when no object was matched.
    pub de_single_m: f64,
    pub de_fused_m: f64,
}

#[derive(Clone, Debug, Default)]
pub struct Summary {
    pub rows: BTreeMap<RowKey, Accumulator>,
}

impl Summary {
    pub fn record(&mut self, key: RowKey, counts: PairCounts, estimates: &[ObjectEstimate]) {
        let acc = self.rows.entry(key).or_default();
        acc.instances += 1;
        acc.counts.add(counts);
        acc.objects += estimates.len();
        acc.single_error_sum_m += estimates.iter().map(|e| e.single_error_m()).sum::<f64>();
        acc.fused_error_sum_m += estimates.iter().map(|e| e.fused_error_m()).sum::<f64>();
    }

    /// Rows in a fixed order (method, pose noise, fusion).
    pub fn rows(&self) -> Vec<SummaryRow> {
        self.rows
            .iter()
            .map(|(key, acc)| {
                let mean = |s: f64| {
                    if acc.objects == 0 {
                        f64::NAN
                    } else {
                        s / acc.objects as f64
                    }
                };
                SummaryRow {
                    key: *key,
                    n_instances: acc.instances,
                    n_objects: acc.objects,
                    precision: acc.counts.precision(),
                    recall: acc.counts.recall(),
                    f1: acc.counts.f1(),
                    de_single_m: mean(acc.single_error_sum_m),
                    de_fused_m: mean(acc.fused_error_sum_m),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Cov2, Pose2};
    use crate::sensor::{Appearance, Detection};
    use crate::traffic::ObjectClass;

    fn det(p: Vec2, id: Option<&str>) -> Detection {
        Detection {
            position_m: p,
            cov_m2: Cov2::identity() * 0.5,
            appearance: Appearance {
                class: ObjectClass::Car,
                colour_rgb: [0.5; 3],
                length_m: 4.6,
                width_m: 1.8,
                height_m: 1.5,
            },
            truth_id: id.map(str::to_owned),
            visible_fraction: 1.0,
        }
    }

    fn corr(a: usize, b: usize) -> Correspondence {
        Correspondence {
            a,
            b,
            probability: 1.0,
            uncertainty: 0.0,
        }
    }

    #[test]
    fn precision_recall_f1() {
        let first = Observation {
            ego_id: "a".into(),
            ego_pose_true: Pose2::identity(),
            detections: vec![
                det(Vec2::zeros(), Some("x")),
                det(Vec2::zeros(), Some("y")),
                det(Vec2::zeros(), None),
            ],
        };
        let second = Observation {
            ego_id: "b".into(),
            ego_pose_true: Pose2::identity(),
            detections: vec![
                det(Vec2::zeros(), Some("y")),
                det(Vec2::zeros(), Some("x")),
                det(Vec2::zeros(), Some("z")),
            ],
        };
        let c = count_pairs(&first, &second, &[corr(0, 1), corr(1, 2), corr(2, 0)]);
        assert_eq!(
            c,
            PairCounts {
                identified: 3,
                correct: 1,
                ground_truth: 2
            }
        );
        assert!((c.precision() - 1.0 / 3.0).abs() < 1e-12);
        assert!((c.recall() - 0.5).abs() < 1e-12);
        assert!((c.f1() - 0.4).abs() < 1e-12);
        let none = count_pairs(&first, &second, &[]);
        assert_eq!(none.precision(), 1.0);
        assert_eq!(none.recall(), 0.0);
        assert_eq!(none.f1(), 0.0);
    }

    #[test]
    fn zero_noise_gives_zero_error_single_and_fused() {
        // Two egos with exact measurements and exact poses.
        let pa = Pose2::new(Vec2::new(0.0, 0.0), 0.3);
        let pb = Pose2::new(Vec2::new(30.0, 10.0), 2.0);
        let objects = [
            ("x", Vec2::new(15.0, 8.0)),
            ("y", Vec2::new(20.0, -2.0)),
            ("z", Vec2::new(10.0, 15.0)),
        ];
        let obs = |pose: &Pose2, id: &str| Observation {
            ego_id: id.into(),
            ego_pose_true: *pose,
            detections: objects
                .iter()
                .map(|(o, w)| det(pose.to_body(w), Some(o)))
                .collect(),
        };
        let (oa, ob) = (obs(&pa, "a"), obs(&pb, "b"));
        let truth: HashMap<&str, Vec2> = objects.iter().copied().collect();
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::None,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
        };
        for variant in [FusionVariant::Paper, FusionVariant::Aligned] {
            let est = fuse_for_ego(
                &EgoSide {
                    obs: &oa,
                    pose_reported: pa,
                },
                &EgoSide {
                    obs: &ob,
                    pose_reported: pb,
                },
                &[(0, 0), (1, 1), (2, 2)],
                &level,
                variant,
                3,
                &truth,
            );
            assert_eq!(est.len(), 3);
            for e in est {
                assert!(
                    e.single_error_m() < 1e-9 && e.fused_error_m() < 1e-9,
                    "{e:?}"
                );
                assert!(e.match_correct);
            }
        }
    }
}
