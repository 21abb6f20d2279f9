//! `coid track`: cooperation over time, as V2X delivers it. Every
//! connected vehicle near the junction tracks its own detections; its
//! reported tracks go out as CPMs over the channel ([`Fleet`]); each
//! receiver extrapolates what it receives to its own time, matches it
//! against its own tracks with the frame matcher of `[v2x] matcher`,
//! carries the association across messages, and fuses what it associated
//! ([`PeerState`]). This file holds the loop and what it accumulates.

use std::collections::{BTreeMap, BTreeSet};

use super::context::{Context, true_centres};
use super::fleet::Fleet;
use super::instance::InstanceSide;
use super::peer::PeerState;
use super::runners::runner;
use super::simulate::{
    check_connected_appeared, note_connected, note_types, sense, warn_unused_types,
};
use super::{Progress, RunError};
use crate::bridge::Sumo;
use crate::config::Settings;
use crate::evaluate::CorrespondenceSource;
use crate::matching::Matcher;
use crate::report::{OverTimeCounts, VehicleTracking};
use crate::sensor::PoseNoiseLevel;

/// What `coid track` measured.
pub struct TrackResults {
    /// One row per connected vehicle, in id order.
    pub vehicles: Vec<VehicleTracking>,
    pub over_time: OverTimeCounts,
}

/// `coid track`: SUMO at `[v2x] step_length_s`; at every step each
/// connected vehicle near the junction tracks its detections (scored by
/// CLEAR-MOT against what its cameras could see), generates a CPM when
/// one is due and sends it to its linked peers over the channel (a
/// `Purpose::Channel` stream per message and receiver); messages that
/// have arrived are matched and associated by their receivers.
pub fn track(
    settings: &Settings,
    mut progress: impl FnMut(Progress),
) -> Result<TrackResults, RunError> {
    let (sc, v) = (&settings.scenario, &settings.v2x);
    let matcher = frame_matcher(settings)?;
    let level = track_level(settings)?;
    let mut sumo = Sumo::start(
        &sc.sumocfg,
        settings.seeds.traffic,
        sc.end_s,
        Some(v.step_length_s),
    )?
    .with_unset_colours(settings.sensor.unset_colours, settings.seeds.traffic);
    let scene = sumo.static_scene(&sc.junction)?;
    let mut tracking = Tracking::default();
    let mut instances = 0;
    let mut seen_connected = BTreeSet::new();
    let mut seen_types = BTreeSet::new();
    while sumo.time_s() + 1e-6 < sc.end_s {
        let frame = sumo.step()?;
        note_connected(settings, &frame, &mut seen_connected);
        note_types(&frame, &mut seen_types);
        let sides = sense(settings, &scene, &frame)?;
        let truth = true_centres(&frame);
        let ctx = Context {
            settings,
            v,
            levels: std::slice::from_ref(&level),
            step: frame.step,
            time_s: frame.time_s,
            truth: &truth,
        };
        tracking.step(&ctx, &sides, matcher.as_ref())?;
        instances += sides.len();
        progress(Progress {
            time_s: frame.time_s,
            end_s: sc.end_s,
            instances,
        });
    }
    sumo.close()?;
    check_connected_appeared(&settings.connected, &seen_connected)?;
    warn_unused_types(settings, &seen_types);
    Ok(tracking.finish())
}

/// The frame matcher every receiver runs: `[v2x] matcher`, which must be a
/// matching method.
fn frame_matcher(settings: &Settings) -> Result<Box<dyn Matcher>, RunError> {
    match runner(settings, settings.v2x.matcher)? {
        CorrespondenceSource::Matcher(m) => Ok(m),
        _ => Err(RunError::Worker(
            "[v2x] matcher must be a matching method".into(),
        )),
    }
}

/// The GNSS accuracy of `coid track`: the `[pose_noise]` level `[v2x]
/// pose_noise` names.
fn track_level(settings: &Settings) -> Result<PoseNoiseLevel, RunError> {
    let label = settings.v2x.pose_noise;
    settings
        .pose_noise
        .iter()
        .find(|l| l.label == label)
        .copied()
        .ok_or_else(|| {
            RunError::Worker(format!(
                "[v2x] pose_noise = \"{}\" is not one of the [pose_noise] levels",
                label.as_str()
            ))
        })
}

/// `coid track`'s state: the fleet, what each receiver knows of each peer
/// (by (receiver, sender)), and the counts of every reception so far.
#[derive(Default)]
struct Tracking {
    fleet: Fleet,
    peers: BTreeMap<(String, String), PeerState>,
    counts: OverTimeCounts,
}

impl Tracking {
    /// One step: `sides` (what every connected vehicle near the junction
    /// sensed) track and send; every message that has arrived is received
    /// ([`PeerState::receive`]).
    fn step(
        &mut self,
        ctx: &Context,
        sides: &[InstanceSide],
        matcher: &dyn Matcher,
    ) -> Result<(), RunError> {
        self.fleet.send(ctx, sides);
        for m in self.fleet.arrivals(ctx, sides) {
            let Some(receiver) = self.fleet.vehicle(&m.receiver) else {
                continue;
            };
            let peer = self
                .peers
                .entry((m.receiver.clone(), m.message.sender.clone()))
                .or_default();
            let c = peer.receive(ctx, receiver, &m.message, matcher)?;
            self.counts.add(&c);
        }
        Ok(())
    }

    fn finish(self) -> TrackResults {
        let mut counts = self.counts;
        for p in self.peers.values() {
            counts.pairs += p.pairs_seen();
        }
        TrackResults {
            vehicles: self.fleet.finish(),
            over_time: counts,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Pose2, Vec2};
    use crate::matching::Method;
    use crate::pipeline::tests::{centres, context, settings, vehicle_side};
    use crate::sensor::PoseNoiseLabel;
    use crate::v2x::channel::LossModel;

    /// `coid track` needs a matching method and a configured level, and
    /// says which setting is wrong.
    #[test]
    fn the_matcher_and_level_must_be_usable() {
        let mut s = settings();
        assert_eq!(track_level(&s).unwrap().label, s.v2x.pose_noise);
        assert!(frame_matcher(&s).is_ok());
        s.v2x.matcher = Method::Oracle;
        let e = frame_matcher(&s).err().unwrap().to_string();
        assert!(e.contains("[v2x] matcher"), "{e}");
        s.pose_noise.retain(|l| l.label != PoseNoiseLabel::Gps);
        s.v2x.pose_noise = PoseNoiseLabel::Gps;
        let e = track_level(&s).unwrap_err().to_string();
        assert!(e.contains("pose_noise = \"gps\""), "{e}");
    }

    /// Two vehicles that see the same objects, over a lossless channel:
    /// every message is received, each receiver associates the other's
    /// objects with its own tracks, and the rows and counts add up.
    #[test]
    fn two_vehicles_that_see_the_same_objects_associate_them() {
        let mut s = settings();
        s.v2x.channel.loss = LossModel::Independent { probability: 0.0 };
        let objects = [
            ("a", Vec2::new(12.0, 3.0)),
            ("b", Vec2::new(18.0, -4.0)),
            ("c", Vec2::new(25.0, 8.0)),
        ];
        let truth = centres(&objects);
        let level = track_level(&s).unwrap();
        let matcher = frame_matcher(&s).unwrap();
        let mut tracking = Tracking::default();
        let poses = [
            Pose2::new(Vec2::new(0.0, 1.0), 0.3),
            Pose2::new(Vec2::new(40.0, 2.0), 3.0),
        ];
        let steps = 20;
        for step in 0..steps {
            let sides = [
                vehicle_side("cv0", poses[0], &objects, step),
                vehicle_side("cv1", poses[1], &objects, step),
            ];
            let ctx = Context {
                levels: std::slice::from_ref(&level),
                ..context(&s, &truth, step, step as f64 * 0.1)
            };
            tracking.step(&ctx, &sides, matcher.as_ref()).unwrap();
        }
        let r = tracking.finish();
        let ids: Vec<&str> = r.vehicles.iter().map(|v| v.ego_id.as_str()).collect();
        assert_eq!(ids, ["cv0", "cv1"]);
        assert!(r.vehicles.iter().all(|v| v.steps == steps && v.lost == 0));
        // Each message arrives one step later: all but the last ones,
        // which are in flight when the run ends, not delivered.
        let delivered: u64 = r.vehicles.iter().map(|v| v.delivered).sum();
        let in_flight: u64 = r.vehicles.iter().map(|v| v.in_flight_at_end).sum();
        assert_eq!((r.over_time.receptions, in_flight), (delivered, 2));
        assert_eq!(r.over_time.pairs, 6, "three objects, both ways");
        assert_eq!(r.over_time.pairs_found, 6);
        assert_eq!(
            r.over_time.over_time.correct,
            r.over_time.over_time.identified
        );
        assert_eq!(r.over_time.switches, 0);
    }
}
