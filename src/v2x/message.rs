//! A CPM as the simulation sends it ([`Sent`]): the objects in the
//! sender's body frame with the poses its GNSS reported, its own node, and
//! beside them what only the evaluation knows (the sender's true pose,
//! each object's [`TrackLabel`]); and whose view a side of an instance is
//! ([`ViewSource`]: a vehicle's own, or a message's).

use std::fmt;

use super::context::Context;
use super::cpm::PerceivedObject;
use crate::geometry::{Pose2, Vec2};
use crate::sensor::{Appearance, Detection, DetectionTruth};

/// Whose view one side of an instance is. Its text ([`fmt::Display`]) is
/// the side's id wherever a side is named (the observation's `ego_id`,
/// hence the exports' and tables' ids): the vehicle's id, or `<sender> ->
/// <receiver>` for a message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ViewSource {
    /// A connected vehicle's own view: what it sensed at the step, or with
    /// `[v2x] mode = "cpm"` its reported tracks.
    Vehicle(String),
    /// A message `sender` sent and `receiver` received (`[v2x] mode =
    /// "cpm"`).
    Message { sender: String, receiver: String },
}

impl ViewSource {
    /// The vehicle whose view this is: the vehicle, or the message's
    /// sender.
    pub fn vehicle(&self) -> &str {
        match self {
            ViewSource::Vehicle(id) => id,
            ViewSource::Message { sender, .. } => sender,
        }
    }
}

impl fmt::Display for ViewSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ViewSource::Vehicle(id) => f.write_str(id),
            ViewSource::Message { sender, receiver } => write!(f, "{sender} -> {receiver}"),
        }
    }
}

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
    /// The sender's speed at generation (m/s; a CPM's originating vehicle
    /// container carries it, own node or not).
    pub sender_speed_mps: f64,
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
    use crate::v2x::testkit::{appearance, context, settings};

    /// A vehicle's side is named by the vehicle, a message's by `<sender>
    /// -> <receiver>` (what exports and tables write), and the vehicle
    /// behind a message is its sender.
    #[test]
    fn a_source_reads_as_the_vehicle_or_sender_to_receiver() {
        let v = ViewSource::Vehicle("cv1".into());
        let m = ViewSource::Message {
            sender: "cv0".into(),
            receiver: "cv1".into(),
        };
        assert_eq!(v.to_string(), "cv1");
        assert_eq!(m.to_string(), "cv0 -> cv1");
        assert_eq!((v.vehicle(), m.vehicle()), ("cv1", "cv0"));
    }

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
}
