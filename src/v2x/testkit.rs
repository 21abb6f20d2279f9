//! Fixtures the tests of cooperation over time share (plain values, no
//! SUMO): the shipped settings, vehicles' sensings made by hand, a step's
//! context, an empty message; also the pipeline's tests'.

use std::collections::BTreeMap;

use super::context::{Context, Sensing, Setup};
use super::message::Sent;
use crate::config::Settings;
use crate::geometry::{Cov2, Pose2, Vec2};
use crate::rng::{self, Purpose};
use crate::sensor::{
    Appearance, Detection, DetectionTruth, Observation, ObservationTruth, Sensed, VisibleObject,
};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

/// The shipped defaults (`configs/default.toml`).
pub(crate) fn settings() -> Settings {
    Settings::defaults().expect("the shipped defaults are valid")
}

/// What a camera reports of road user `id`: a car of its own colour.
pub(crate) fn appearance(id: &str) -> Appearance {
    let h = rng::hash_str(id);
    let c = |k: u32| f64::from(((h >> (8 * k)) & 0xff) as u8) / 255.0;
    Appearance {
        class: ObjectClass::Car,
        colour_rgb: [c(0), c(1), c(2)],
        length_m: 4.5,
        width_m: 1.8,
        height_m: 1.5,
        descriptor: None,
    }
}

/// Road users by id at their true centres (world frame).
pub(crate) type Seen<'a> = [(&'a str, Vec2)];

/// What a vehicle at true pose `pose` senses of the road users `seen`:
/// each detected where it is (body frame, covariance 0.04 m² per axis),
/// visible, and nothing else; in `seen`'s order, unnamed.
pub(crate) fn sensed(pose: Pose2, seen: &Seen) -> Sensed {
    let detections = seen
        .iter()
        .map(|(o, p)| Detection {
            position_m: pose.to_body(p),
            cov_m2: Cov2::identity() * 0.04,
            appearance: appearance(o),
            motion: None,
        })
        .collect();
    let truths = seen
        .iter()
        .map(|(o, p)| DetectionTruth {
            object_id: Some((*o).to_owned()),
            position_m: Some(*p),
            visible_fraction: 1.0,
            sender: false,
        })
        .collect();
    let visible = seen
        .iter()
        .map(|(o, p)| VisibleObject {
            object_id: (*o).to_owned(),
            position_m: *p,
            visible_fraction: 1.0,
        })
        .collect();
    Sensed {
        observation: Observation {
            ego_id: String::new(),
            detections,
        },
        truth: ObservationTruth {
            ego_pose: pose,
            detections: truths,
        },
        visible,
    }
}

/// A vehicle's sensing at one step, owned ([`Side::sensing`] lends it).
pub(crate) struct Side {
    id: String,
    sensed: Sensed,
}

impl Side {
    pub(crate) fn sensing(&self) -> Sensing<'_> {
        Sensing {
            id: &self.id,
            id_hash: rng::hash_str(&self.id),
            sensed: &self.sensed,
            speed_mps: 10.0,
        }
    }
}

/// What vehicle `id` at true pose `pose` senses at `step` of the road
/// users `seen` ([`sensed`]), named by the vehicle and in the node order
/// a run gives it (speed 10 m/s).
pub(crate) fn vehicle_side(id: &str, pose: Pose2, seen: &Seen, step: u64) -> Side {
    let mut sensed = sensed(pose, seen);
    sensed.observation.ego_id = id.to_owned();
    let keys = [step, rng::hash_str(id)];
    sensed.shuffle(&mut rng::stream(7, Purpose::NodeOrder, &keys));
    Side {
        id: id.to_owned(),
        sensed,
    }
}

/// The sensings of `sides`, in order.
pub(crate) fn sensings(sides: &[Side]) -> Vec<Sensing<'_>> {
    sides.iter().map(Side::sensing).collect()
}

/// An empty message from `sender`, generated at `generated_s` at the
/// identity pose.
pub(super) fn sent(sender: &str, generated_s: f64) -> Sent {
    Sent {
        sender: sender.to_owned(),
        generated_s,
        sender_reported: vec![Pose2::identity(); 3],
        objects: Vec::new(),
        labels: Vec::new(),
        sender_pose: Pose2::identity(),
        sender_node: None,
        sender_speed_mps: 0.0,
    }
}

/// A car `id` at `pose`, 5 m/s.
pub(crate) fn car(id: &str, pose: Pose2) -> TrafficObject {
    TrafficObject {
        id: id.to_owned(),
        class: ObjectClass::Car,
        pose,
        length_m: 4.6,
        width_m: 1.8,
        height_m: 1.5,
        colour_rgb: [200, 10, 10],
        speed_mps: 5.0,
        type_id: "car".into(),
        model: None,
    }
}

/// A frame of step `step` (0.1 s each) with the road users `seen`.
pub(crate) fn frame(seen: &Seen, step: u64) -> TrafficFrame {
    TrafficFrame {
        step,
        time_s: step as f64 * 0.1,
        objects: seen
            .iter()
            .map(|(id, p)| car(id, Pose2::new(*p, 0.0)))
            .collect(),
    }
}

/// A junction at the origin, without buildings or lanes.
pub(crate) fn scene() -> StaticScene {
    StaticScene {
        junction_id: "C".into(),
        junction_position_m: Vec2::zeros(),
        buildings: Vec::new(),
        lanes: Vec::new(),
    }
}

/// Every road user's true centre, by id, as a [`Context`] holds it.
pub(crate) fn centres<'a>(seen: &Seen<'a>) -> BTreeMap<&'a str, Vec2> {
    seen.iter().copied().collect()
}

/// The context of step `step` at `time_s`, at every level of `s`.
pub(crate) fn context<'a>(
    s: &'a Settings,
    truth: &'a BTreeMap<&'a str, Vec2>,
    step: u64,
    time_s: f64,
) -> Context<'a> {
    let setup = Setup {
        v: &s.v2x,
        link: &s.link,
        sensor_seed: s.seeds.sensor,
        align_min_matches: s.fusion.align_min_matches,
        levels: &s.pose_noise,
    };
    setup.at(step, time_s, truth)
}
