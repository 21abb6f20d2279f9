//! Both sides of one reception as the receiver matches them ([`Views`]):
//! its reported tracks and the peer's known objects, each with its ids and
//! true objects, the poses they are seen through and what the two GNSS
//! receivers claim of them.

use crate::fusion::{Measurement, PoseEstimate, relative_pose_prior};
use crate::geometry::Pose2;
use crate::matching::claim;
use crate::sensor::{Detection, PoseNoiseLevel};

/// A detection as a measurement to fuse: its position and covariance.
pub(super) fn measurement(d: &Detection) -> Measurement {
    Measurement {
        position_m: d.position_m,
        cov_m2: d.cov_m2,
    }
}

/// The pair-level views of one reception: the receiver's reported tracks
/// (`ego`, its body frame) and the peer's known objects (`peer`, in the
/// frame of `peer_reported`), each with its ids and true objects.
#[derive(Clone)]
pub(super) struct Views {
    pub ego: Vec<Detection>,
    pub ego_ids: Vec<u64>,
    pub ego_truth: Vec<Option<String>>,
    pub peer: Vec<Detection>,
    pub peer_ids: Vec<u64>,
    pub peer_truth: Vec<Option<String>>,
    /// The peer objects' frame: the newest message's reported sender pose.
    pub peer_reported: Pose2,
    /// What the receiver's and the sender's GNSS claim of the poses they
    /// report (the level, the heading's at each one's speed).
    pub ego_claim: PoseNoiseLevel,
    pub peer_claim: PoseNoiseLevel,
}

impl Views {
    /// The peer's pose in the receiver's frame from the two reported
    /// poses, with what both receivers claim of them.
    pub(super) fn gps_prior(&self, receiver_reported: &Pose2) -> PoseEstimate {
        relative_pose_prior(
            receiver_reported,
            &self.peer_reported,
            claim(&self.ego_claim),
            claim(&self.peer_claim),
        )
    }
}
