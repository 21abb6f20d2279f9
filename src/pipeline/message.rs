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

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::geometry::Cov2;
    use crate::pipeline::tests::{appearance, context, settings};

    /// A label's truth is its object where it is now; a false positive's
    /// has no object and no position.
    #[test]
    fn a_label_names_its_object_where_it_is_now() {
        let s = settings();
        let truth = BTreeMap::from([("a", Vec2::new(3.0, 4.0))]);
        let ctx = context(&s, &truth, 0, 0.0);
        let label = |t: Option<&str>| TrackLabel {
            appearance: appearance("a"),
            truth: t.map(str::to_owned),
            visible_fraction: 0.6,
        };
        let t = label(Some("a")).truth_at(&ctx);
        assert_eq!(t.object_id.as_deref(), Some("a"));
        assert_eq!(t.position_m, Some(Vec2::new(3.0, 4.0)));
        assert_eq!((t.visible_fraction, t.sender), (0.6, false));
        let t = label(None).truth_at(&ctx);
        assert_eq!((t.object_id, t.position_m), (None, None));
    }

    /// A message's sender speed is that of its own node, 0 without one.
    #[test]
    fn a_senders_speed_is_its_nodes() {
        let mut m = Sent {
            sender: "cv0".into(),
            generated_s: 0.0,
            sender_reported: Vec::new(),
            objects: Vec::new(),
            labels: Vec::new(),
            sender_pose: Pose2::identity(),
            sender_node: None,
        };
        assert_eq!(m.sender_speed_mps(), 0.0);
        let node = Detection {
            position_m: Vec2::zeros(),
            cov_m2: Cov2::identity(),
            appearance: appearance("cv0"),
            motion: None,
        };
        let truth = DetectionTruth {
            object_id: Some("cv0".into()),
            position_m: None,
            visible_fraction: 1.0,
            sender: true,
        };
        m.sender_node = Some((node, truth, Vec2::new(3.0, 4.0)));
        assert_eq!(m.sender_speed_mps(), 5.0);
    }
}
