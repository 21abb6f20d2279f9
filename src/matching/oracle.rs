//! The oracle: pairs detections behind which stands the same true object.
//! It bounds what fusion can reach with perfect correspondences. It reads
//! the ground truth ([`ObservationTruth`]), so it is not a [`super::Matcher`]:
//! the evaluation calls it with the truths beside the observations, and the
//! same pairs are the training labels.

use super::Correspondence;
use crate::sensor::ObservationTruth;

/// Every pair (a, b) of detections of the same true object, sorted by `a`,
/// with probability 1 and no uncertainty.
pub fn true_pairs(first: &ObservationTruth, second: &ObservationTruth) -> Vec<Correspondence> {
    (0..first.detections.len())
        .filter_map(|a| {
            let b = second.find(first.object_id(a)?)?;
            Some(Correspondence {
                a,
                b,
                probability: 1.0,
                uncertainty: 0.0,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;
    use crate::sensor::DetectionTruth;

    fn truth(ids: &[Option<&str>]) -> ObservationTruth {
        ObservationTruth {
            ego_pose: Pose2::identity(),
            detections: ids
                .iter()
                .map(|id| DetectionTruth {
                    object_id: id.map(str::to_owned),
                    position_m: None,
                    visible_fraction: 1.0,
                    sender: false,
                })
                .collect(),
        }
    }

    #[test]
    fn pairs_the_same_objects_and_never_false_positives() {
        let first = truth(&[Some("x"), None, Some("y"), Some("z")]);
        let second = truth(&[Some("y"), None, Some("x"), Some("w")]);
        let pairs: Vec<(usize, usize)> = true_pairs(&first, &second)
            .iter()
            .map(|c| (c.a, c.b))
            .collect();
        assert_eq!(pairs, vec![(0, 2), (2, 0)]);
    }
}
