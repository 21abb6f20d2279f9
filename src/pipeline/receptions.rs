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
use super::instance::{InstanceSide, ViewSource};
use super::over_time::{Context, Sent, Vehicle, World, true_centres};
use crate::config::Settings;
use crate::evaluate;
use crate::geometry::Pose2;
use crate::rng;
use crate::sensor::{
    Detection, DetectionTruth, Observation, ObservationTruth, PoseNoiseLabel, Sensed,
};
use crate::traffic::TrafficFrame;
use crate::v2x::extrapolate;

/// The vehicles' trackers, generators and the messages in flight.
#[derive(Default)]
pub(super) struct Receptions {
    world: World,
}

/// The sides of a sampled step's instances, and the instances as pairs of
/// indices into them (receiver first).
pub(super) type Sides = (Vec<InstanceSide>, Vec<(usize, usize)>);

impl Receptions {
    /// One simulation step: `egos` (every connected vehicle near the
    /// junction, sensed at this step) track and send; the messages due
    /// arrive. When `sample`, the newest message from each sender at each
    /// receiver becomes an instance if both sides hold a common object
    /// (listed by receiver, then sender; each pair ordered by id, as
    /// [`super::Instance`]); otherwise what arrived is only consumed.
    pub(super) fn step(
        &mut self,
        settings: &Settings,
        frame: &TrafficFrame,
        egos: &[InstanceSide],
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
        self.world.send(&ctx, egos);
        let arrived = self.world.arrivals(&ctx, egos);
        let mut sides = Vec::new();
        let mut pairs = Vec::new();
        if !sample {
            return Ok((sides, pairs));
        }
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
        let mut receiver_at: BTreeMap<String, usize> = BTreeMap::new();
        for ((receiver, _), m) in newest {
            let (Some(vehicle), Some(ego)) = (
                self.world.vehicle(&receiver),
                egos.iter()
                    .find(|e| e.sensed.observation.ego_id == receiver),
            ) else {
                continue;
            };
            let message = message_side(&ctx, &m, &receiver)?;
            let r = match receiver_at.get(&receiver) {
                Some(&r) => r,
                None => {
                    let side = receiver_side(&ctx, vehicle, ego)?;
                    sides.push(side);
                    receiver_at.insert(receiver.clone(), sides.len() - 1);
                    sides.len() - 1
                }
            };
            if evaluate::share_a_detected_object(&sides[r].sensed.truth, &message.sensed.truth) {
                sides.push(message);
                let m = sides.len() - 1;
                // An instance's pair is ordered by id, as the ideal ones.
                let id = |k: usize| &sides[k].sensed.observation.ego_id;
                pairs.push(if id(r) < id(m) { (r, m) } else { (m, r) });
            }
        }
        Ok((sides, pairs))
    }
}

/// What each `[pose_noise]` level's GNSS reports: `poses[k]` at level `k`.
fn per_level(ctx: &Context, poses: &[Pose2]) -> Vec<(PoseNoiseLabel, Pose2)> {
    ctx.levels
        .iter()
        .zip(poses)
        .map(|(l, p)| (l.label, *p))
        .collect()
}

/// The receiver's side: its reported tracks (and its own node), in the
/// body frame of its true pose; the truth is each track's last detected
/// object at this step's true position.
fn receiver_side(
    ctx: &Context,
    vehicle: &Vehicle,
    ego: &InstanceSide,
) -> Result<InstanceSide, RunError> {
    let (detections, truths) = vehicle
        .reported_tracks()
        .map(|(_, d, label)| (d, label.truth_at(ctx)))
        .unzip();
    let mut sensed = Sensed {
        observation: Observation {
            // Named by `InstanceSide::new`.
            ego_id: String::new(),
            detections,
        },
        truth: ObservationTruth {
            ego_pose: ego.sensed.truth.ego_pose,
            detections: truths,
        },
        visible: Vec::new(),
    };
    if let Some(k) = ego.sensed.truth.detections.iter().position(|d| d.sender) {
        sensed
            .observation
            .detections
            .push(ego.sensed.observation.detections[k].clone());
        sensed
            .truth
            .detections
            .push(ego.sensed.truth.detections[k].clone());
    }
    let keys = [ctx.step, ego.id_hash, ego.id_hash];
    let reported = per_level(ctx, vehicle.reported_poses());
    InstanceSide::new(
        ego.source.clone(),
        sensed,
        ctx.settings.seeds.sensor,
        &keys,
        ego.speed_mps,
        Some(reported),
    )
}

/// The message's side: the objects it carries (and its sender's own
/// node), moved ahead to the receiver's time, in the body frame of the
/// sender's true pose at generation, with the poses it reported then. Its
/// source is the message ([`ViewSource::Message`]).
fn message_side(ctx: &Context, m: &Sent, receiver: &str) -> Result<InstanceSide, RunError> {
    let dt_s = if ctx.v.compensate_latency {
        ctx.time_s - m.generated_s
    } else {
        0.0
    };
    let accel = ctx.v.tracker.accel_sigma_mps2;
    let now = |id: &Option<String>| id.as_deref().and_then(|o| ctx.truth.get(o)).copied();
    let mut detections = Vec::new();
    let mut truths = Vec::new();
    for (o, label) in m.objects.iter().zip(&m.labels) {
        let (position_m, cov_m2) = extrapolate(
            o.position_m,
            o.velocity_mps,
            &o.position_cov_m2,
            &o.velocity_cov_m2ps2,
            dt_s,
            accel,
        );
        detections.push(Detection {
            position_m,
            cov_m2,
            appearance: label.appearance.clone(),
        });
        truths.push(label.truth_at(ctx));
    }
    if let Some((d, t, velocity_mps)) = &m.sender_node {
        let (position_m, cov_m2) = extrapolate(
            d.position_m,
            *velocity_mps,
            &d.cov_m2,
            &crate::geometry::Cov2::zeros(),
            dt_s,
            accel,
        );
        detections.push(Detection {
            position_m,
            cov_m2,
            appearance: d.appearance.clone(),
        });
        truths.push(DetectionTruth {
            position_m: now(&t.object_id),
            ..t.clone()
        });
    }
    let sensed = Sensed {
        observation: Observation {
            // Named by `InstanceSide::new`.
            ego_id: String::new(),
            detections,
        },
        truth: ObservationTruth {
            ego_pose: m.sender_pose,
            detections: truths,
        },
        visible: Vec::new(),
    };
    let keys = [ctx.step, rng::hash_str(receiver), rng::hash_str(&m.sender)];
    let reported = per_level(ctx, &m.sender_reported);
    let source = ViewSource::Message {
        sender: m.sender.clone(),
        receiver: receiver.to_owned(),
    };
    InstanceSide::new(
        source,
        sensed,
        ctx.settings.seeds.sensor,
        &keys,
        m.sender_speed_mps(),
        Some(reported),
    )
}
