//! Counting correspondences against the truth: which pairs are true
//! (same object behind both nodes), how many a method got right, and the
//! CAD rule for an instance. Precision, recall and F1 follow from the
//! counts.

use crate::matching::{Correspondence, oracle};
use crate::sensor::ObservationTruth;

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

    /// correct / identified; undefined (NaN) when nothing was identified:
    /// a method that claims nothing has made no correct claim either.
    pub fn precision(&self) -> f64 {
        ratio(self.correct as f64, self.identified)
    }

    /// correct / ground truth; undefined (NaN) when there was nothing to
    /// find.
    pub fn recall(&self) -> f64 {
        ratio(self.correct as f64, self.ground_truth)
    }

    /// The harmonic mean of precision and recall, from the counts:
    /// `2 correct / (identified + ground truth)`. Defined whenever either
    /// count is (0 when nothing was identified but there was something to
    /// find); NaN only when both are 0.
    pub fn f1(&self) -> f64 {
        ratio(
            2.0 * self.correct as f64,
            self.identified + self.ground_truth,
        )
    }
}

/// `numerator / denominator`, NaN (undefined) when the denominator is 0.
fn ratio(numerator: f64, denominator: usize) -> f64 {
    if denominator == 0 {
        f64::NAN
    } else {
        numerator / denominator as f64
    }
}

/// Number of true pairs: the same object behind a node of each vehicle
/// (camera detections, and a sender's own node with the peer's detection
/// of it).
fn covisible_pairs(first: &ObservationTruth, second: &ObservationTruth) -> usize {
    oracle::true_pairs(first, second).len()
}

/// Whether both vehicles' cameras detect a common object (the paper's CAD
/// rule for an instance; senders' own nodes do not count).
pub fn share_a_detected_object(first: &ObservationTruth, second: &ObservationTruth) -> bool {
    first.detections.iter().any(|d| {
        !d.sender
            && d.object_id.as_deref().is_some_and(|id| {
                second
                    .detections
                    .iter()
                    .any(|e| !e.sender && e.object_id.as_deref() == Some(id))
            })
    })
}

/// Whether `c` pairs two detections of the same real object.
pub fn is_correct(first: &ObservationTruth, second: &ObservationTruth, c: &Correspondence) -> bool {
    let a = first.object_id(c.a);
    a.is_some() && a == second.object_id(c.b)
}

/// Counts `matches` against the truth.
pub fn count_pairs(
    first: &ObservationTruth,
    second: &ObservationTruth,
    matches: &[Correspondence],
) -> PairCounts {
    let correct = matches
        .iter()
        .filter(|c| is_correct(first, second, c))
        .count();
    PairCounts {
        identified: matches.len(),
        correct,
        ground_truth: covisible_pairs(first, second),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::testkit::{corr, sensed};
    use crate::geometry::{Pose2, Vec2};

    #[test]
    fn precision_recall_f1() {
        let z = Vec2::zeros();
        let (_, first) = sensed(
            "a",
            Pose2::identity(),
            &[(Some("x"), z), (Some("y"), z), (None, z)],
        );
        let (_, second) = sensed(
            "b",
            Pose2::identity(),
            &[(Some("y"), z), (Some("x"), z), (Some("z"), z)],
        );
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
        // Nothing identified: precision undefined (not 1), recall and F1 0.
        let none = count_pairs(&first, &second, &[]);
        assert!(none.precision().is_nan());
        assert_eq!(none.recall(), 0.0);
        assert_eq!(none.f1(), 0.0);
        assert!(PairCounts::default().f1().is_nan());
    }
}
