//! One connected vehicle over time ([`ConnectedVehicle`]): its tracker of
//! its own camera detections (scored by CLEAR-MOT against what its cameras
//! could see), its GNSS error stepped at every level, its reported tracks
//! with their labels, and the CPMs it generates from them.

use std::collections::{BTreeMap, BTreeSet};

use super::V2xSettings;
use super::context::{Context, Sensing};
use super::counts::VehicleTracking;
use super::cpm::{CpmGenerator, PerceivedObject, TrackSnapshot};
use super::message::{Sent, TrackLabel};
use super::tracker::{MotCounter, TrackMeasurement, Tracker};
use crate::geometry::{Cov2, Pose2, Vec2};
use crate::sensor::gnss::{self, GnssError, at_speed, next_error};
use crate::sensor::{Detection, DetectionTruth};

/// A track within this distance of an object counts as tracking it
/// (CLEAR-MOT's threshold; m).
const MOT_THRESHOLD_M: f64 = 2.0;

/// One connected vehicle.
pub(super) struct ConnectedVehicle {
    tracker: Tracker,
    mot: MotCounter,
    generator: CpmGenerator,
    /// Per level: the time and GNSS error of the last step.
    gnss: Vec<(f64, GnssError)>,
    /// Per track: what its last detection looked like.
    labels: BTreeMap<u64, TrackLabel>,
    row: VehicleTracking,
    /// This step: true pose, GNSS-reported pose per level, reported
    /// tracks, its own node (body frame) and its velocity (body frame).
    pose: Pose2,
    reported: Vec<Pose2>,
    tracks: Vec<TrackSnapshot>,
    track_covs: Vec<Cov2>,
    self_node: Option<(Detection, DetectionTruth, Vec2)>,
    /// This step's speed (m/s).
    speed_mps: f64,
}

impl ConnectedVehicle {
    pub(super) fn new(id: &str, v: &V2xSettings) -> Self {
        Self {
            tracker: Tracker::new(v.tracker.clone()),
            mot: MotCounter::new(MOT_THRESHOLD_M),
            generator: CpmGenerator::default(),
            gnss: Vec::new(),
            labels: BTreeMap::new(),
            row: VehicleTracking {
                ego_id: id.to_owned(),
                ..VehicleTracking::default()
            },
            pose: Pose2::identity(),
            reported: Vec::new(),
            tracks: Vec::new(),
            track_covs: Vec::new(),
            self_node: None,
            speed_mps: 0.0,
        }
    }

    /// This step's true pose (evaluation only: the frame its sensors
    /// measure in).
    pub(super) fn pose(&self) -> Pose2 {
        self.pose
    }

    /// This step's speed (m/s).
    pub(super) fn speed_mps(&self) -> f64 {
        self.speed_mps
    }

    /// This step's GNSS-reported poses, one per level of the context.
    pub(super) fn reported_poses(&self) -> &[Pose2] {
        &self.reported
    }

    /// The reported track `id` in the tracking frame, with its position
    /// covariance.
    pub(super) fn track(&self, id: u64) -> Option<(&TrackSnapshot, &Cov2)> {
        let k = self.tracks.iter().position(|t| t.id == id)?;
        Some((&self.tracks[k], &self.track_covs[k]))
    }

    /// What track `id`'s last detection looked like.
    pub(super) fn label(&self, id: u64) -> Option<&TrackLabel> {
        self.labels.get(&id)
    }

    /// This step's reported tracks: id, position with the look of its
    /// last detection in the body frame of the true pose, and its label.
    pub(super) fn reported_tracks(&self) -> impl Iterator<Item = (u64, Detection, &TrackLabel)> {
        let body = self.pose.inverse();
        self.tracks
            .iter()
            .zip(&self.track_covs)
            .filter_map(move |(t, cov)| {
                let label = self.labels.get(&t.id)?;
                let d = Detection {
                    position_m: body.to_parent(&t.position_m),
                    cov_m2: body.cov_to_parent(cov),
                    appearance: label.appearance.clone(),
                    motion: None,
                };
                Some((t.id, d, label))
            })
    }

    /// Tracks this step's camera detections in the tracking frame, scores
    /// the reported tracks, steps the GNSS error, and generates a CPM when
    /// one is due. `side` is what the vehicle sensed at this step.
    pub(super) fn step(&mut self, ctx: &Context, side: &Sensing) -> Option<Sent> {
        self.pose = side.sensed.truth.ego_pose;
        self.speed_mps = side.speed_mps;
        self.step_gnss(ctx, side);
        self.self_node = side
            .sensed
            .own_node()
            .map(|(d, t)| (d, t, Vec2::new(side.speed_mps, 0.0)));
        self.track_detections(ctx, side);
        self.score(side);
        self.row.steps += 1;
        if !self.generator.due(&ctx.v.cpm, ctx.time_s) {
            return None;
        }
        let chosen = self.generator.select(&ctx.v.cpm, ctx.time_s, &self.tracks);
        self.row.messages += 1;
        self.row.objects_sent += chosen.len() as u64;
        Some(self.message(ctx, &chosen, side.id))
    }

    /// One message to one receiver: delivered after `latency_s`, or lost.
    pub(super) fn delivery(&mut self, latency_s: Option<f64>) {
        self.row.delivery(latency_s);
    }

    /// The tracker on this step's camera detections (the world frame of
    /// the true pose), each track labelled by its last detection, and the
    /// reported tracks.
    fn track_detections(&mut self, ctx: &Context, side: &Sensing) {
        let (observed, truth) = (&side.sensed.observation, &side.sensed.truth);
        let camera: Vec<usize> = (0..truth.detections.len())
            .filter(|&k| !truth.detections[k].sender)
            .collect();
        let measurements: Vec<TrackMeasurement> = camera
            .iter()
            .map(|&k| {
                let d = &observed.detections[k];
                TrackMeasurement {
                    position_m: self.pose.to_parent(&d.position_m),
                    cov_m2: self.pose.cov_to_parent(&d.cov_m2),
                    class: d.appearance.class,
                    colour_rgb: d.appearance.colour_rgb,
                }
            })
            .collect();
        let ids = self.tracker.step(ctx.time_s, &measurements);
        for (&k, id) in camera.iter().zip(ids) {
            let t = &truth.detections[k];
            let label = TrackLabel {
                appearance: observed.detections[k].appearance.clone(),
                truth: t.object_id.clone(),
                visible_fraction: t.visible_fraction,
            };
            self.labels.insert(id, label);
        }
        let live: BTreeSet<u64> = self.tracker.tracks().iter().map(|t| t.id).collect();
        self.labels.retain(|id, _| live.contains(id));
        (self.tracks, self.track_covs) = self
            .tracker
            .reported()
            .map(|t| {
                let snap = TrackSnapshot {
                    id: t.id,
                    position_m: t.position_m(),
                    velocity_mps: t.velocity_mps(),
                };
                (snap, t.position_cov_m2())
            })
            .unzip();
    }

    /// Steps the GNSS error at every level (a stream per step, vehicle
    /// and level).
    fn step_gnss(&mut self, ctx: &Context, side: &Sensing) {
        let previous = std::mem::take(&mut self.gnss);
        self.reported.clear();
        for (k, level) in ctx.levels.iter().enumerate() {
            let mut stream = gnss::stream(ctx.sensor_seed, ctx.step, side.id_hash, level);
            let last = previous.get(k).map(|&(t, e)| (ctx.time_s - t, e));
            let level = at_speed(level, side.speed_mps, ctx.v.gnss_heading_speed_sigma_mps);
            let e = next_error(
                last.map(|p| p.1),
                last.map_or(0.0, |p| p.0),
                level.correlation_s(ctx.v.gnss_correlation_s),
                &level,
                &mut stream,
            );
            self.gnss.push((ctx.time_s, e));
            self.reported.push(e.apply(&self.pose));
        }
    }

    /// CLEAR-MOT on this step's reported tracks.
    fn score(&mut self, side: &Sensing) {
        let truth: Vec<(String, Vec2)> = side
            .sensed
            .visible
            .iter()
            .map(|o| (o.object_id.clone(), o.position_m))
            .collect();
        let tracked: Vec<(u64, Vec2)> = self.tracks.iter().map(|t| (t.id, t.position_m)).collect();
        self.mot.step(&truth, &tracked);
    }

    /// The CPM of the chosen tracks: in the body frame of the sender's
    /// true pose (what its sensors measure), with its reported pose.
    fn message(&self, ctx: &Context, chosen: &[u64], sender: &str) -> Sent {
        let body = self.pose.inverse();
        let mut sent = Sent {
            sender: sender.to_owned(),
            generated_s: ctx.time_s,
            sender_reported: self.reported.clone(),
            objects: Vec::new(),
            labels: Vec::new(),
            sender_pose: self.pose,
            sender_node: self.self_node.clone(),
            sender_speed_mps: self.speed_mps,
        };
        for id in chosen {
            let Some(t) = self.tracker.tracks().iter().find(|t| t.id == *id) else {
                continue;
            };
            let Some(label) = self.labels.get(id) else {
                continue;
            };
            sent.objects.push(PerceivedObject {
                local_id: t.id,
                position_m: body.to_parent(&t.position_m()),
                velocity_mps: body.to_parent(&t.velocity_mps()) - body.to_parent(&Vec2::zeros()),
                position_cov_m2: body.cov_to_parent(&t.position_cov_m2()),
                velocity_cov_m2ps2: body.cov_to_parent(&t.velocity_cov_m2ps2()),
                age_s: ctx.time_s - t.born_s,
                class: t.class,
            });
            sent.labels.push(label.clone());
        }
        sent
    }

    /// Its row of `coid track`'s table.
    pub(super) fn finish(mut self) -> VehicleTracking {
        self.row.mot = self.mot.counts;
        self.row.tracks_started = self.tracker.started();
        self.row
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::v2x::testkit::{centres, context, settings, vehicle_side};

    fn pose() -> Pose2 {
        Pose2::new(Vec2::new(10.0, 5.0), 0.5)
    }

    fn seen() -> [(&'static str, Vec2); 2] {
        [("a", Vec2::new(30.0, 12.0)), ("b", Vec2::new(22.0, 20.0))]
    }

    /// Steps a vehicle that sees `seen()` still for `n` steps of 0.1 s;
    /// returns it and the messages it generated.
    fn stepped(n: u64) -> (ConnectedVehicle, Vec<Sent>) {
        let s = settings();
        let truth = centres(&seen());
        let mut v = ConnectedVehicle::new("cv0", &s.v2x);
        let mut sent = Vec::new();
        for step in 0..n {
            let ctx = context(&s, &truth, step, step as f64 * 0.1);
            let side = vehicle_side("cv0", pose(), &seen(), step);
            sent.extend(v.step(&ctx, &side.sensing()));
        }
        (v, sent)
    }

    /// Tracks are reported once confirmed (`confirm_hits`), where their
    /// objects are (body frame), labelled with them.
    #[test]
    fn confirmed_tracks_are_reported_where_their_objects_are() {
        let hits = u64::from(settings().v2x.tracker.confirm_hits);
        let (v, _) = stepped(hits - 1);
        assert_eq!(v.reported_tracks().count(), 0);
        let (v, _) = stepped(hits);
        let reported: Vec<(u64, Detection, &TrackLabel)> = v.reported_tracks().collect();
        assert_eq!(reported.len(), 2);
        for (id, d, label) in reported {
            let object = seen()
                .into_iter()
                .find(|(o, _)| Some(*o) == label.truth.as_deref())
                .unwrap();
            assert!((pose().to_parent(&d.position_m) - object.1).norm() < 1e-6);
            let (track, _) = v.track(id).unwrap();
            assert!((track.position_m - object.1).norm() < 1e-6);
            assert_eq!(v.label(id).unwrap().truth, label.truth);
        }
        assert_eq!(v.pose(), pose());
    }

    /// One GNSS pose per level, the truth at the level without noise.
    #[test]
    fn the_gnss_reports_a_pose_per_level() {
        let s = settings();
        let (v, sent) = stepped(2);
        assert_eq!(v.reported_poses().len(), s.pose_noise.len());
        let none = s.pose_noise.iter().position(|l| l.position_sigma_m == 0.0);
        assert_eq!(v.reported_poses()[none.unwrap()], pose());
        assert_eq!(sent[1].sender_reported, v.reported_poses());
    }

    /// A message is generated when one is due (10 Hz: every step); a
    /// track goes in once confirmed (and not again while it stands
    /// still), in the sender's body frame with its label, and the
    /// vehicle's row counts steps, messages and objects.
    #[test]
    fn messages_carry_the_confirmed_tracks_in_the_senders_body_frame() {
        let hits = u64::from(settings().v2x.tracker.confirm_hits);
        let (v, sent) = stepped(hits + 2);
        assert_eq!(sent.len() as u64, hits + 2);
        let carrying: Vec<&Sent> = sent.iter().filter(|m| !m.objects.is_empty()).collect();
        assert_eq!(carrying.len(), 1);
        let first = carrying[0];
        assert_eq!(first.sender, "cv0");
        assert_eq!(first.generated_s, (hits - 1) as f64 * 0.1);
        assert_eq!(first.sender_pose, pose());
        assert!(first.sender_node.is_none());
        assert_eq!((first.objects.len(), first.labels.len()), (2, 2));
        for (o, label) in first.objects.iter().zip(&first.labels) {
            let (_, at) = seen()
                .into_iter()
                .find(|(id, _)| Some(*id) == label.truth.as_deref())
                .unwrap();
            assert!((pose().to_parent(&o.position_m) - at).norm() < 1e-6);
            assert!(o.velocity_mps.norm() < 1e-6);
        }
        let objects: usize = sent.iter().map(|m| m.objects.len()).sum();
        let row = v.finish();
        assert_eq!((row.steps, row.messages), (hits + 2, hits + 2));
        assert_eq!(row.objects_sent, objects as u64);
        assert_eq!(row.tracks_started, 2);
        assert_eq!(row.mot.ground_truth as u64, 2 * (hits + 2));
    }
}
