//! `[v2x] mode = "cpm"` in runs. At every step each connected vehicle near
//! the junction tracks its detections and sends its CPMs over the channel
//! (the same trackers, generation rules and channel as `coid track`). At
//! each sampled step, every message that has arrived becomes an instance:
//! the receiver's reported tracks against the objects the message carries,
//! moved ahead to the receiver's time with their velocity
//! (`[v2x] compensate_latency`), each in its vehicle's body frame, with
//! the GNSS poses (correlated over `[v2x] gnss_correlation_s`) at every
//! `[pose_noise]` level. The run makes these sides instances, and every
//! method is evaluated on them exactly as on the ideal ones.

use std::collections::BTreeMap;

use super::context::{Context, Sensing};
use super::delivery::InFlight;
use super::fleet::Fleet;
use super::message::{Sent, ViewSource};
use super::vehicle::ConnectedVehicle;
use crate::evaluate;
use crate::geometry::{Cov2, Pose2};
use crate::rng;
use crate::sensor::{
    Detection, DetectionTruth, Observation, ObservationTruth, PoseNoiseLabel, Sensed,
};

/// The vehicles' trackers, generators and the messages in flight.
#[derive(Default)]
pub(crate) struct Receptions {
    fleet: Fleet,
}

/// One side of a reception, before the run makes it an instance's side:
/// whose view it is, what it holds (in the body frame of its vehicle's true
/// pose), the keys of its node order's stream, its vehicle's speed (m/s)
/// and the pose its GNSS reports at every level.
pub(crate) struct ReceptionSide {
    pub source: ViewSource,
    pub sensed: Sensed,
    pub order_keys: [u64; 3],
    pub speed_mps: f64,
    pub reported: Vec<(PoseNoiseLabel, Pose2)>,
}

impl ReceptionSide {
    /// Its id: the source's text.
    fn id(&self) -> String {
        self.source.to_string()
    }
}

/// The sides of a sampled step's instances, and the instances as pairs of
/// indices into them (each pair ordered by id).
pub(crate) type Sides = (Vec<ReceptionSide>, Vec<(usize, usize)>);

impl Receptions {
    /// One simulation step: `vehicles` (every connected vehicle near the
    /// junction, sensed at this step) track and send; the messages due
    /// arrive. When `sample`, the newest message from each sender at each
    /// receiver becomes an instance if both sides hold a common object
    /// (listed by receiver, then sender; each pair ordered by id, as an
    /// instance's sides are); otherwise what arrived is only consumed.
    pub(crate) fn step(&mut self, ctx: &Context, vehicles: &[Sensing], sample: bool) -> Sides {
        self.fleet.send(ctx, vehicles);
        let arrived = self.fleet.arrivals(ctx, vehicles);
        let mut sides = Vec::new();
        let mut pairs = Vec::new();
        if !sample {
            return (sides, pairs);
        }
        let mut receiver_at: BTreeMap<String, usize> = BTreeMap::new();
        for ((receiver, _), m) in newest_per_link(arrived) {
            let (Some(vehicle), Some(sensed)) = (
                self.fleet.vehicle(&receiver),
                vehicles.iter().find(|e| e.id == receiver),
            ) else {
                continue;
            };
            let message = message_side(ctx, &m, &receiver);
            let r = match receiver_at.get(&receiver) {
                Some(&r) => r,
                None => {
                    sides.push(receiver_side(ctx, vehicle, sensed));
                    receiver_at.insert(receiver.clone(), sides.len() - 1);
                    sides.len() - 1
                }
            };
            if evaluate::share_a_detected_object(&sides[r].sensed.truth, &message.sensed.truth) {
                sides.push(message);
                let m = sides.len() - 1;
                // An instance's pair is ordered by id, as the ideal ones.
                let id = |k: usize| sides[k].id();
                pairs.push(if id(r) < id(m) { (r, m) } else { (m, r) });
            }
        }
        (sides, pairs)
    }
}

/// The newest message (by generation time; the first to arrive of equals)
/// from each sender at each receiver, by (receiver, sender).
fn newest_per_link(arrived: Vec<InFlight>) -> BTreeMap<(String, String), Sent> {
    let mut newest: BTreeMap<(String, String), Sent> = BTreeMap::new();
    for m in arrived {
        let key = (m.receiver, m.message.sender.clone());
        match newest.get(&key) {
            Some(old) if old.generated_s >= m.message.generated_s => {}
            _ => {
                newest.insert(key, m.message);
            }
        }
    }
    newest
}

/// What each `[pose_noise]` level's GNSS reports: `poses[k]` at level `k`.
fn per_level(ctx: &Context, poses: &[Pose2]) -> Vec<(PoseNoiseLabel, Pose2)> {
    ctx.levels
        .iter()
        .zip(poses)
        .map(|(l, p)| (l.label, *p))
        .collect()
}

/// A side's content before [`InstanceSide::new`] names it: its nodes, their
/// truths, and the true pose of the frame they are in.
fn unnamed(detections: Vec<Detection>, truths: Vec<DetectionTruth>, ego_pose: Pose2) -> Sensed {
    Sensed {
        observation: Observation {
            ego_id: String::new(),
            detections,
        },
        truth: ObservationTruth {
            ego_pose,
            detections: truths,
        },
        visible: Vec::new(),
    }
}

/// The receiver's side: its reported tracks (and its own node), in the
/// body frame of its true pose; the truth is each track's last detected
/// object at this step's true position. `sensed`: what it sensed at this
/// step.
fn receiver_side(ctx: &Context, vehicle: &ConnectedVehicle, sensed: &Sensing) -> ReceptionSide {
    let (mut detections, mut truths): (Vec<Detection>, Vec<DetectionTruth>) = vehicle
        .reported_tracks()
        .map(|(_, d, label)| (d, label.truth_at(ctx)))
        .unzip();
    if let Some((d, t)) = sensed.sensed.own_node() {
        detections.push(d);
        truths.push(t);
    }
    let keys = [ctx.step, sensed.id_hash, sensed.id_hash];
    let reported = per_level(ctx, vehicle.reported_poses());
    ReceptionSide {
        source: ViewSource::Vehicle(sensed.id.to_owned()),
        sensed: unnamed(detections, truths, sensed.sensed.truth.ego_pose),
        order_keys: keys,
        speed_mps: sensed.speed_mps,
        reported,
    }
}

/// The message's side: the objects it carries (and its sender's own
/// node), moved ahead to the receiver's time, in the body frame of the
/// sender's true pose at generation, with the poses it reported then. Its
/// source is the message ([`ViewSource::Message`]).
fn message_side(ctx: &Context, m: &Sent, receiver: &str) -> ReceptionSide {
    let mut detections = Vec::new();
    let mut truths = Vec::new();
    for (o, label) in m.objects.iter().zip(&m.labels) {
        let (position_m, cov_m2) = ctx.object_moved_ahead(o, m.generated_s);
        detections.push(Detection {
            position_m,
            cov_m2,
            appearance: label.appearance.clone(),
            motion: None,
        });
        truths.push(label.truth_at(ctx));
    }
    if let Some((d, t, velocity_mps)) = &m.sender_node {
        let (position_m, cov_m2) = ctx.moved_ahead(
            m.generated_s,
            d.position_m,
            *velocity_mps,
            &d.cov_m2,
            &Cov2::zeros(),
        );
        // Its box: the sender's own heading (0 in its body frame) and
        // speed at generation, as its self-report carries them.
        detections.push(Detection {
            position_m,
            cov_m2,
            appearance: d.appearance.clone(),
            motion: d.motion,
        });
        let now = t.object_id.as_deref().and_then(|o| ctx.truth.get(o));
        truths.push(DetectionTruth {
            position_m: now.copied(),
            ..t.clone()
        });
    }
    let keys = [ctx.step, rng::hash_str(receiver), rng::hash_str(&m.sender)];
    let reported = per_level(ctx, &m.sender_reported);
    let source = ViewSource::Message {
        sender: m.sender.clone(),
        receiver: receiver.to_owned(),
    };
    ReceptionSide {
        source,
        sensed: unnamed(detections, truths, m.sender_pose),
        order_keys: keys,
        speed_mps: m.sender_speed_mps,
        reported,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Vec2;
    use crate::v2x::channel::LossModel;
    use crate::v2x::cpm::PerceivedObject;
    use crate::v2x::testkit::{
        appearance, centres, context, sensings, sent, settings, vehicle_side,
    };

    const OBJECTS: [(&str, Vec2); 3] = [
        ("a", Vec2::new(12.0, 3.0)),
        ("b", Vec2::new(18.0, -4.0)),
        ("c", Vec2::new(25.0, 8.0)),
    ];

    fn arrived(receiver: &str, sender: &str, generated_s: f64, arrival_s: f64) -> InFlight {
        InFlight {
            arrival_s,
            latency_s: arrival_s - generated_s,
            receiver: receiver.into(),
            message: sent(sender, generated_s),
        }
    }

    /// Of what arrived, the newest message of each sender at each receiver
    /// counts (by generation, not arrival).
    #[test]
    fn the_newest_message_per_sender_and_receiver_counts() {
        let newest = newest_per_link(vec![
            arrived("cv0", "cv1", 1.0, 1.1),
            arrived("cv0", "cv1", 1.2, 1.25),
            arrived("cv0", "cv1", 1.1, 1.3),
            arrived("cv1", "cv0", 0.9, 1.3),
        ]);
        let got: Vec<(&str, &str, f64)> = newest
            .iter()
            .map(|((r, s), m)| (r.as_str(), s.as_str(), m.generated_s))
            .collect();
        assert_eq!(got, [("cv0", "cv1", 1.2), ("cv1", "cv0", 0.9)]);
    }

    /// A message's side is the message (named `<sender> -> <receiver>`):
    /// its objects and its sender's node moved ahead by their age with
    /// their velocity, in the sender's frame, with the poses it reported,
    /// and the truth where the objects are now.
    #[test]
    fn a_messages_side_is_what_it_carries_moved_to_now() {
        let s = settings();
        let truth = centres(&OBJECTS);
        let ctx = context(&s, &truth, 13, 1.3);
        let mut m = sent("cv1", 1.0);
        m.sender_reported = s.pose_noise.iter().map(|_| Pose2::identity()).collect();
        m.objects.push(PerceivedObject {
            local_id: 4,
            position_m: Vec2::new(10.0, 0.0),
            velocity_mps: Vec2::new(-2.0, 1.0),
            position_cov_m2: Cov2::identity() * 0.1,
            velocity_cov_m2ps2: Cov2::identity(),
            age_s: 1.0,
            class: crate::traffic::ObjectClass::Car,
        });
        m.labels.push(super::super::message::TrackLabel {
            appearance: appearance("b"),
            truth: Some("b".into()),
            visible_fraction: 0.8,
        });
        let own = Detection {
            position_m: Vec2::zeros(),
            cov_m2: Cov2::identity() * 0.01,
            appearance: appearance("cv1"),
            motion: Some(crate::sensor::boxes::Motion {
                heading_rad: 0.0,
                speed_mps: 10.0,
            }),
        };
        let own_truth = DetectionTruth {
            object_id: Some("cv1".into()),
            position_m: None,
            visible_fraction: 1.0,
            sender: true,
        };
        m.sender_node = Some((own, own_truth, Vec2::new(10.0, 0.0)));
        m.sender_speed_mps = 10.0;
        let side = message_side(&ctx, &m, "cv0");
        assert_eq!(side.id(), "cv1 -> cv0");
        assert_eq!(side.source.vehicle(), "cv1");
        assert_eq!(side.speed_mps, 10.0);
        let k = side.sensed.truth.find("b").unwrap();
        let moved = side.sensed.observation.detections[k].position_m;
        assert!((moved - Vec2::new(9.4, 0.3)).norm() < 1e-9, "{moved}");
        assert_eq!(
            side.sensed.truth.detections[k].position_m,
            Some(OBJECTS[1].1)
        );
        let (node, t) = side.sensed.own_node().unwrap();
        assert!((node.position_m - Vec2::new(3.0, 0.0)).norm() < 1e-9);
        // Its box is the sender's self-report (r49_12).
        assert_eq!(node.motion, m.sender_node.as_ref().unwrap().0.motion);
        assert_eq!(t.position_m, None, "cv1 is not in the frame");
    }

    /// With two vehicles sending over a lossless channel, a sampled step
    /// has both receptions as instances: each receiver's tracks against
    /// the other's message, each pair ordered by id; an unsampled step
    /// only consumes what arrived.
    #[test]
    fn each_message_that_arrived_is_an_instance_with_its_receiver() {
        let mut s = settings();
        s.v2x.channel.loss = LossModel::Independent { probability: 0.0 };
        let poses = [
            Pose2::new(Vec2::new(0.0, 1.0), 0.3),
            Pose2::new(Vec2::new(40.0, 2.0), 3.0),
        ];
        let truth = centres(&OBJECTS);
        let mut r = Receptions::default();
        let hits = u64::from(s.v2x.tracker.confirm_hits);
        let mut last = None;
        // The tracks are confirmed and sent at step `hits - 1` (and not
        // again while they stand still): their messages arrive at `hits`.
        for step in 0..=hits {
            let vehicles = [
                vehicle_side("cv0", poses[0], &OBJECTS, step),
                vehicle_side("cv1", poses[1], &OBJECTS, step),
            ];
            let sample = step == hits;
            let ctx = context(&s, &truth, step, step as f64 * 0.1);
            let (sides, pairs) = r.step(&ctx, &sensings(&vehicles), sample);
            if !sample {
                assert!(sides.is_empty() && pairs.is_empty());
            }
            last = Some((sides, pairs));
        }
        let (sides, pairs) = last.unwrap();
        let ids: Vec<String> = sides.iter().map(ReceptionSide::id).collect();
        assert_eq!(ids, ["cv0", "cv1 -> cv0", "cv1", "cv0 -> cv1"]);
        assert_eq!(pairs, [(0, 1), (3, 2)]);
        for (a, b) in pairs {
            assert!(sides[a].id() < sides[b].id());
        }
        assert_eq!(sides[0].sensed.observation.detections.len(), 3);
        assert_eq!(sides[0].source, ViewSource::Vehicle("cv0".into()));
    }
}
