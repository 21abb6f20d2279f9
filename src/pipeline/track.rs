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
use super::simulate::{check_connected_appeared, note_connected, sense};
use super::{Progress, RunError};
use crate::bridge::Sumo;
use crate::config::Settings;
use crate::evaluate::Runner;
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
    )?;
    let scene = sumo.static_scene(&sc.junction)?;
    let mut tracking = Tracking::default();
    let mut instances = 0;
    let mut seen_connected = BTreeSet::new();
    while sumo.time_s() + 1e-6 < sc.end_s {
        let frame = sumo.step()?;
        note_connected(settings, &frame, &mut seen_connected);
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
    Ok(tracking.finish())
}

/// The frame matcher every receiver runs: `[v2x] matcher`, which must be a
/// matching method.
fn frame_matcher(settings: &Settings) -> Result<Box<dyn Matcher>, RunError> {
    match runner(settings, settings.v2x.matcher)? {
        Runner::Matcher(m) => Ok(m),
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
