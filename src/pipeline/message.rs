//! A CPM as the simulation sends it ([`Sent`]): the objects in the
//! sender's body frame with the poses its GNSS reported, its own node, and
//! beside them what only the evaluation knows (the sender's true pose,
//! each object's [`TrackLabel`]).

use super::context::Context;
use crate::geometry::{Pose2, Vec2};
use crate::sensor::{Appearance, Detection, DetectionTruth};
use crate::v2x::cpm::PerceivedObject;

/// A generated message with what the evaluation knows beside it.
#[derive(Clone)]
pub(super) struct Sent {
    pub sender: String,
    pub generated_s: f64,
    /// The sender's GNSS-reported pose at generation, per level of
    /// [`Context::levels`].
    pub sender_reported: Vec<Pose2>,
    pub objects: Vec<PerceivedObject>,
    /// Per object: the appearance of its last detection (the paper's
    /// shared appearance, beyond CPM's standard containers), and the true
    /// object behind it (evaluation only).
    pub labels: Vec<TrackLabel>,
    /// Evaluation only: the sender's true pose at generation.
    pub sender_pose: Pose2,
    /// The sender's own node (its self-report, with `[matching]
    /// sender_as_node`) and its velocity, sender's body frame.
    pub sender_node: Option<(Detection, DetectionTruth, Vec2)>,
}

impl Sent {
    /// The sender's speed at generation (0 without its own node).
    pub fn sender_speed_mps(&self) -> f64 {
        self.sender_node.as_ref().map_or(0.0, |n| n.2.norm())
    }
}

/// What a track's last detection looked like, and (evaluation only) what
/// lay behind it.
#[derive(Clone, Debug)]
pub(super) struct TrackLabel {
    pub appearance: Appearance,
    pub truth: Option<String>,
    pub visible_fraction: f64,
}

impl TrackLabel {
    /// What lies behind the labelled node: its object at this step's true
    /// position (evaluation only).
    pub fn truth_at(&self, ctx: &Context) -> DetectionTruth {
        DetectionTruth {
            object_id: self.truth.clone(),
            position_m: self
                .truth
                .as_deref()
                .and_then(|o| ctx.truth.get(o))
                .copied(),
            visible_fraction: self.visible_fraction,
            sender: false,
        }
    }
}
