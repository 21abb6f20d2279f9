//! The fusion variants (`[fusion]`) and what each makes of where the peer
//! sits in the ego's frame ([`PeerPose`]).

use super::{Measurement, PoseEstimate, align};
use crate::geometry::Pose2;

crate::label_enum! { "fusion variant";
    /// How the matched measurements are fused.
    #[strum(serialize_all = "lowercase")]
    pub enum FusionVariant {
        /// Paper Eq. 14-16 with the relative pose from both vehicles' GPS.
        Paper,
        /// The relative pose refined from the matched objects first ([`align`]).
        Aligned,
    }
}

/// `[fusion]`: which variants are reported, and when alignment applies.
#[derive(Clone, Debug, PartialEq)]
pub struct FusionSettings {
    pub variants: Vec<FusionVariant>,
    /// The aligned variant falls back to the GPS pose below this many
    /// matched objects.
    pub align_min_matches: usize,
}

/// Where the peer sits in the ego's frame, as a fusion variant sees it.
pub enum PeerPose {
    /// From both GPS poses, its uncertainty ignored (the paper).
    Reported(Pose2),
    /// Refined from the matches, with its covariance.
    Aligned(PoseEstimate),
}

impl PeerPose {
    /// The peer's pose for `variant` from the relative pose of both GPS
    /// poses (`prior`): as it is (`paper`), or refined from the matched
    /// pairs `pairs` gives (ego's measurement, peer's, each in its
    /// vehicle's frame; [`align`] with `align_min_matches`); and whether
    /// it was refined.
    pub fn of(
        variant: FusionVariant,
        prior: &PoseEstimate,
        pairs: impl FnOnce() -> Vec<(Measurement, Measurement)>,
        align_min_matches: usize,
    ) -> (bool, PeerPose) {
        match variant {
            FusionVariant::Paper => (false, PeerPose::Reported(prior.pose)),
            FusionVariant::Aligned => {
                let al = align(&pairs(), prior, align_min_matches);
                (al.refined, PeerPose::Aligned(al.estimate))
            }
        }
    }

    /// A peer's measurement moved into the ego's frame.
    pub fn move_measurement(&self, m: &Measurement) -> Measurement {
        match self {
            PeerPose::Reported(pose) => m.moved(pose),
            PeerPose::Aligned(estimate) => m.moved_uncertain(estimate),
        }
    }
}
