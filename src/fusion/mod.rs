//! Multi-vehicle fusion of matched measurements (paper Section 3.4,
//! Eq. 14-16) and, beyond the paper, refinement of the relative pose between
//! two vehicles from the objects they both matched. One job a file:
//! `combine` (Eq. 14-16 and covariance intersection), `consistency` (the
//! claim a fused estimate can honestly make, and its NEES), `pose` (a pose
//! with its uncertainty, the relative pose of two GPS poses, a measurement
//! moved with an uncertain pose), `align` (weighted rigid alignment),
//! `variant` (what each fusion variant makes of the peer's pose),
//! `recursive` (an estimate fused again at every reception).
//!
//! Pure computation on nalgebra types; every position and covariance is in
//! one common frame, stated by the caller.

mod align;
mod combine;
mod consistency;
mod pose;
mod recursive;
mod variant;

pub use align::align;
pub use combine::{covariance_intersection, fuse};
pub use consistency::{consistency_scale, hedged_covariance, nees};
pub use pose::{PoseClaim, PoseEstimate, relative_pose_prior};
pub use recursive::Recursive;
pub use variant::{FusionSettings, FusionVariant, PeerPose};

use nalgebra::Matrix2;

use crate::geometry::{Cov2, Pose2, Vec2};

/// One vehicle's measurement of an object, already in the common frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurement {
    pub position_m: Vec2,
    pub cov_m2: Cov2,
}

impl Measurement {
    /// The measurement of a point given in `pose`'s body frame, expressed in
    /// the parent frame: the covariance rotates with the point (`sigma` of
    /// Eq. 15).
    pub fn moved(&self, pose: &Pose2) -> Measurement {
        Measurement {
            position_m: pose.to_parent(&self.position_m),
            cov_m2: pose.cov_to_parent(&self.cov_m2),
        }
    }
}

/// The fused estimate of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct Fused {
    /// Eq. 15.
    pub position_m: Vec2,
    /// Eq. 16.
    pub cov_m2: Cov2,
    /// Eq. 14, one gain per measurement, in input order; they sum to I.
    pub gains: Vec<Matrix2<f64>>,
}

impl Fused {
    /// The fused estimate as a measurement to fuse again.
    pub fn measurement(&self) -> Measurement {
        Measurement {
            position_m: self.position_m,
            cov_m2: self.cov_m2,
        }
    }
}
