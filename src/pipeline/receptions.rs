//! `[v2x] mode = "cpm"` in runs. At every step each connected vehicle near
//! the junction tracks its detections and sends its CPMs over the channel
//! (the same trackers, generation rules and channel as `coid track`). At
//! each sampled step, every message that has arrived becomes an instance:
//! the receiver's reported tracks against the objects the message carries,
//! moved ahead to the receiver's time with their velocity
//! (`[v2x] compensate_latency`), each in its vehicle's body frame, with
//! the GNSS poses (correlated over `[v2x] gnss_correlation_s`) at every
//! `[pose_noise]` level. Every method is then evaluated on these instances
//! exactly as on the ideal ones.

use std::collections::BTreeMap;

use super::RunError;
use super::context::{Context, true_centres};
use super::delivery::InFlight;
use super::fleet::Fleet;
use super::instance::{InstanceSide, ViewSource};
use super::message::Sent;
use super::vehicle::ConnectedVehicle;
use crate::config::Settings;
use crate::evaluate;
use crate::geometry::{Cov2, Pose2};
use crate::rng;
use crate::sensor::{
    Detection, DetectionTruth, Observation, ObservationTruth, PoseNoiseLabel, Sensed,
};
use crate::traffic::TrafficFrame;

/// The vehicles' trackers, generators and the messages in flight.
#[derive(Default)]
pub(super) struct Receptions {
    fleet: Fleet,
}

/// The sides of a sampled step's instances, and the instances as pairs of
/// indices into them (each pair ordered by id).
pub(super) type Sides = (Vec<InstanceSide>, Vec<(usize, usize)>);

impl Receptions {
    /// One simulation step: `vehicles` (every connected vehicle near the
    /// junction, sensed at this step) track and send; the messages due
    /// arrive. When `sample`, the newest message from each sender at each
    /// receiver becomes an instance if both sides hold a common object
    /// (listed by receiver, then sender; each pair ordered by id, as
    /// [`super::Instance`]); otherwise what arrived is only consumed.
    pub(super) fn step(
        &mut self,
        settings: &Settings,
        frame: &TrafficFrame,
        vehicles: &[InstanceSide],
        sample: bool,
    ) -> Result<Sides, RunError> {
        let truth = true_centres(frame);
        let ctx = Context {
            settings,
            v: &settings.v2x,
            levels: &settings.pose_noise,
            step: frame.step,
            time_s: frame.time_s,
            truth: &truth,
        };
        self.fleet.send(&ctx, vehicles);
        let arrived = self.fleet.arrivals(&ctx, vehicles);
        let mut sides = Vec::new();
        let mut pairs = Vec::new();
        if !sample {
            return Ok((sides, pairs));
        }
        let mut receiver_at: BTreeMap<String, usize> = BTreeMap::new();
        for ((receiver, _), m) in newest_per_link(arrived) {
            let (Some(vehicle), Some(sensed)) = (
                self.fleet.vehicle(&receiver),
                vehicles.iter().find(|e| e.source.vehicle() == receiver),
            ) else {
                continue;
            };
            let message = message_side(&ctx, &m, &receiver)?;
            let r = match receiver_at.get(&receiver) {
                Some(&r) => r,
                None => {
                    sides.push(receiver_side(&ctx, vehicle, sensed)?);
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
        Ok((sides, pairs))
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
fn receiver_side(
    ctx: &Context,
    vehicle: &ConnectedVehicle,
    sensed: &InstanceSide,
) -> Result<InstanceSide, RunError> {
    let (mut detections, mut truths): (Vec<Detection>, Vec<DetectionTruth>) = vehicle
        .reported_tracks()
        .map(|(_, d, label)| (d, label.truth_at(ctx)))
        .unzip();
    if let Some((d, t)) = sensed.own_node() {
        detections.push(d);
        truths.push(t);
    }
    let keys = [ctx.step, sensed.id_hash, sensed.id_hash];
    let reported = per_level(ctx, vehicle.reported_poses());
    InstanceSide::new(
        sensed.source.clone(),
        unnamed(detections, truths, sensed.sensed.truth.ego_pose),
        ctx.settings.seeds.sensor,
        &keys,
        sensed.speed_mps,
        Some(reported),
    )
}

/// The message's side: the objects it carries (and its sender's own
/// node), moved ahead to the receiver's time, in the body frame of the
/// sender's true pose at generation, with the poses it reported then. Its
/// source is the message ([`ViewSource::Message`]).
fn message_side(ctx: &Context, m: &Sent, receiver: &str) -> Result<InstanceSide, RunError> {
    let mut detections = Vec::new();
    let mut truths = Vec::new();
    for (o, label) in m.objects.iter().zip(&m.labels) {
        let (position_m, cov_m2) = ctx.object_moved_ahead(o, m.generated_s);
        detections.push(Detection {
            position_m,
            cov_m2,
            appearance: label.appearance.clone(),
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
        detections.push(Detection {
            position_m,
            cov_m2,
            appearance: d.appearance.clone(),
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
    InstanceSide::new(
        source,
        unnamed(detections, truths, m.sender_pose),
        ctx.settings.seeds.sensor,
        &keys,
        m.sender_speed_mps(),
        Some(reported),
    )
}
