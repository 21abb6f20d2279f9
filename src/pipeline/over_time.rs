//! `coid track`: cooperation over time, as V2X delivers it. Every
//! connected vehicle near the junction tracks its own detections; its
//! reported tracks go out as CPMs over the channel; each receiver
//! extrapolates what it receives to its own time, matches it against its
//! own tracks with the frame matcher of `[v2x] matcher`, carries the
//! association across messages, and fuses what it associated.

use std::collections::{BTreeMap, BTreeSet};

use super::instance::InstanceSide;
use super::runners::runner;
use super::simulate::{check_connected_appeared, note_connected, sense};
use super::{Progress, RunError};
use crate::bridge::Sumo;
use crate::config::Settings;
use crate::evaluate::{PairCounts, Runner};
use crate::fusion::{Measurement, align, covariance_intersection, fuse, relative_pose_prior};
use crate::geometry::{Cov2, Pose2, Vec2, rotate_cov, wrap_angle};
use crate::graph::SceneGraph;
use crate::matching::{MatchView, Matcher};
use crate::report::{OverTimeCounts, VehicleTracking};
use crate::rng::{self, Purpose};
use crate::sensor::{Appearance, Detection, DetectionTruth, PoseNoiseLevel};
use crate::traffic::TrafficFrame;
use crate::v2x::V2xSettings;
use crate::v2x::cpm::{CpmGenerator, PerceivedObject, TrackSnapshot};
use crate::v2x::gnss::{GnssError, next_error};
use crate::v2x::receiver::Association;
use crate::v2x::tracker::{MotCounter, TrackMeasurement, Tracker};

/// What `coid track` measured.
pub struct TrackResults {
    /// One row per connected vehicle, in id order.
    pub vehicles: Vec<VehicleTracking>,
    pub over_time: OverTimeCounts,
}

/// A track within this distance of an object counts as tracking it
/// (CLEAR-MOT's threshold; m).
const MOT_THRESHOLD_M: f64 = 2.0;

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
    let matcher = match runner(settings, v.matcher)? {
        Runner::Matcher(m) => m,
        _ => {
            return Err(RunError::Worker(
                "[v2x] matcher must be a matching method".into(),
            ));
        }
    };
    let level = settings
        .pose_noise
        .iter()
        .find(|l| l.label == v.pose_noise)
        .copied()
        .ok_or_else(|| {
            RunError::Worker(format!(
                "[v2x] pose_noise = \"{}\" is not one of the [pose_noise] levels",
                v.pose_noise.as_str()
            ))
        })?;
    let mut sumo = Sumo::start(
        &sc.sumocfg,
        settings.seeds.traffic,
        sc.end_s,
        Some(v.step_length_s),
    )?;
    let scene = sumo.static_scene(&sc.junction)?;
    let mut world = World::default();
    let mut instances = 0;
    let mut seen_connected = BTreeSet::new();
    while sumo.time_s() + 1e-6 < sc.end_s {
        let frame = sumo.step()?;
        note_connected(settings, &frame, &mut seen_connected);
        let egos = sense(settings, &scene, &frame)?;
        let truth = true_centres(&frame);
        let ctx = Context {
            settings,
            v,
            levels: std::slice::from_ref(&level),
            step: frame.step,
            time_s: frame.time_s,
            truth: &truth,
        };
        world.send(&ctx, &egos);
        world.receive(&ctx, &egos, matcher.as_ref())?;
        instances += egos.len();
        progress(Progress {
            time_s: frame.time_s,
            end_s: sc.end_s,
            instances,
        });
    }
    sumo.close()?;
    check_connected_appeared(&settings.connected, &seen_connected)?;
    Ok(world.finish())
}

/// Every road user's true centre at `frame`, world frame, by id.
pub(super) fn true_centres(frame: &TrafficFrame) -> BTreeMap<&str, Vec2> {
    frame
        .objects
        .iter()
        .map(|o| (o.id.as_str(), o.pose.position_m()))
        .collect()
}

/// What one step shares.
pub(super) struct Context<'a> {
    pub settings: &'a Settings,
    pub v: &'a V2xSettings,
    /// The GNSS accuracies each vehicle's error is drawn at: `[v2x]
    /// pose_noise` alone for `coid track` (its receivers use the first),
    /// every `[pose_noise]` level in a run.
    pub levels: &'a [PoseNoiseLevel],
    pub step: u64,
    pub time_s: f64,
    /// Every road user's true centre, world frame.
    pub truth: &'a BTreeMap<&'a str, Vec2>,
}

impl Context<'_> {
    /// The GNSS accuracy `coid track`'s receivers work at.
    fn level(&self) -> &PoseNoiseLevel {
        &self.levels[0]
    }
}

/// Every vehicle's state, the messages in flight and the receivers' links.
#[derive(Default)]
pub(super) struct World {
    vehicles: BTreeMap<String, Vehicle>,
    in_flight: Vec<InFlight>,
    links: BTreeMap<(String, String), Link>,
    counts: OverTimeCounts,
}

/// A message on its way to one receiver.
pub(super) struct InFlight {
    pub arrival_s: f64,
    pub receiver: String,
    pub message: Sent,
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
    pub labels: Vec<Label>,
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
pub(super) struct Label {
    pub appearance: Appearance,
    pub truth: Option<String>,
    pub visible_fraction: f64,
}

impl Label {
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

/// One connected vehicle.
pub(super) struct Vehicle {
    tracker: Tracker,
    mot: MotCounter,
    generator: CpmGenerator,
    /// Per level: the time and GNSS error of the last step.
    gnss: Vec<(f64, GnssError)>,
    /// Per track: what its last detection looked like.
    labels: BTreeMap<u64, Label>,
    row: VehicleTracking,
    /// This step: true pose, GNSS-reported pose per level, reported
    /// tracks, its own node (body frame) and its velocity (body frame).
    pose: Pose2,
    reported: Vec<Pose2>,
    tracks: Vec<TrackSnapshot>,
    track_covs: Vec<Cov2>,
    self_node: Option<(Detection, DetectionTruth, Vec2)>,
}

/// What a receiver knows of one peer.
#[derive(Default)]
struct Link {
    association: Association,
    /// The peer's objects last received, by its ids.
    known: BTreeMap<u64, Known>,
    last: BTreeMap<u64, u64>,
    first_in_view: BTreeMap<(u64, u64), f64>,
    found: BTreeSet<(u64, u64)>,
    /// The relative pose over time: the correction (world frame:
    /// translation and heading) of the sender's reported pose.
    offset: Option<Pose2>,
    /// Per ego track associated with this peer: its recursively fused
    /// estimate.
    fused: BTreeMap<u64, Recursive>,
}

/// A recursively fused estimate of one ego track with one peer object, in
/// the receiver's tracking frame, by Eq. 14-16 and by covariance
/// intersection.
#[derive(Clone, Copy)]
struct Recursive {
    peer: u64,
    time_s: f64,
    independent: Measurement,
    ci: Measurement,
}

#[derive(Clone)]
struct Known {
    object: PerceivedObject,
    generated_s: f64,
    sender_reported: Pose2,
    label: Label,
}

impl World {
    /// Every vehicle near the junction tracks, and sends its CPM when one
    /// is due to its linked peers over the channel.
    pub(super) fn send(&mut self, ctx: &Context, egos: &[InstanceSide]) {
        let positions: Vec<Vec2> = egos
            .iter()
            .map(|e| e.sensed.truth.ego_pose.position_m())
            .collect();
        let links = ctx.settings.link.links(&positions);
        for (i, ego) in egos.iter().enumerate() {
            let id = ego.sensed.observation.ego_id.clone();
            let veh = self
                .vehicles
                .entry(id.clone())
                .or_insert_with(|| Vehicle::new(&id, ctx.v));
            let Some(sent) = veh.step(ctx, ego) else {
                continue;
            };
            for (j, peer) in egos.iter().enumerate() {
                if j == i || !links.linked(i, j) {
                    continue;
                }
                let mut stream = rng::stream(
                    ctx.settings.seeds.sensor,
                    Purpose::Channel,
                    &[ctx.step, ego.id_hash, peer.id_hash],
                );
                let d = (positions[j] - positions[i]).norm();
                let delivered = ctx.v.channel.deliver(d, &mut stream);
                veh.row.delivery(delivered);
                if let Some(latency) = delivered {
                    self.in_flight.push(InFlight {
                        arrival_s: ctx.time_s + latency,
                        receiver: peer.sensed.observation.ego_id.clone(),
                        message: sent.clone(),
                    });
                }
            }
        }
    }

    /// Hands every message that has arrived to its receiver
    /// ([`World::arrivals`]).
    fn receive(
        &mut self,
        ctx: &Context,
        egos: &[InstanceSide],
        matcher: &dyn Matcher,
    ) -> Result<(), RunError> {
        for m in self.arrivals(ctx, egos) {
            let Some(receiver) = self.vehicles.get(&m.receiver) else {
                continue;
            };
            let link = self
                .links
                .entry((m.receiver.clone(), m.message.sender.clone()))
                .or_default();
            let c = link.receive(ctx, receiver, &m.message, matcher)?;
            self.counts.add(&c);
        }
        Ok(())
    }

    /// The vehicle `id`, once it has been near the junction.
    pub(super) fn vehicle(&self, id: &str) -> Option<&Vehicle> {
        self.vehicles.get(id)
    }

    /// The messages that have arrived by now at receivers still near the
    /// junction (the others are dropped), in arrival order.
    pub(super) fn arrivals(&mut self, ctx: &Context, egos: &[InstanceSide]) -> Vec<InFlight> {
        let now = ctx.time_s + 1e-9;
        let (mut due, rest): (Vec<InFlight>, Vec<InFlight>) = std::mem::take(&mut self.in_flight)
            .into_iter()
            .partition(|m| m.arrival_s <= now);
        self.in_flight = rest;
        due.sort_by(|a, b| a.arrival_s.total_cmp(&b.arrival_s));
        let here: BTreeSet<&str> = egos
            .iter()
            .map(|e| e.sensed.observation.ego_id.as_str())
            .collect();
        due.retain(|m| {
            here.contains(m.receiver.as_str()) && self.vehicles.contains_key(&m.receiver)
        });
        due
    }

    fn finish(self) -> TrackResults {
        let mut counts = self.counts;
        for l in self.links.values() {
            counts.pairs += l.first_in_view.len() as u64;
        }
        TrackResults {
            vehicles: self.vehicles.into_values().map(Vehicle::finish).collect(),
            over_time: counts,
        }
    }
}

impl Vehicle {
    /// This step's GNSS-reported poses, one per level of the context.
    pub(super) fn reported_poses(&self) -> &[Pose2] {
        &self.reported
    }

    /// This step's reported tracks: id, position with the look of its
    /// last detection in the body frame of the true pose, and its label.
    pub(super) fn reported_tracks(&self) -> impl Iterator<Item = (u64, Detection, &Label)> {
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
                };
                Some((t.id, d, label))
            })
    }

    fn new(id: &str, v: &V2xSettings) -> Self {
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
        }
    }

    /// Tracks this step's camera detections in the tracking frame, scores
    /// the reported tracks, steps the GNSS error, and generates a CPM when
    /// one is due.
    fn step(&mut self, ctx: &Context, ego: &InstanceSide) -> Option<Sent> {
        self.pose = ego.sensed.truth.ego_pose;
        self.step_gnss(ctx, ego);
        self.self_node = ego
            .sensed
            .truth
            .detections
            .iter()
            .position(|d| d.sender)
            .map(|k| {
                (
                    ego.sensed.observation.detections[k].clone(),
                    ego.sensed.truth.detections[k].clone(),
                    Vec2::new(ego.speed_mps, 0.0),
                )
            });
        let camera: Vec<usize> = (0..ego.sensed.truth.detections.len())
            .filter(|&k| !ego.sensed.truth.detections[k].sender)
            .collect();
        let measurements: Vec<TrackMeasurement> = camera
            .iter()
            .map(|&k| {
                let d = &ego.sensed.observation.detections[k];
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
            let d = &ego.sensed.observation.detections[k];
            let t = &ego.sensed.truth.detections[k];
            let label = Label {
                appearance: d.appearance.clone(),
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
        self.score(ego);
        self.row.steps += 1;
        if !self.generator.due(&ctx.v.cpm, ctx.time_s) {
            return None;
        }
        let chosen = self.generator.select(&ctx.v.cpm, ctx.time_s, &self.tracks);
        self.row.messages += 1;
        self.row.objects_sent += chosen.len() as u64;
        Some(self.message(ctx, &chosen, &ego.sensed.observation.ego_id))
    }

    /// Steps the GNSS error at every level (a stream per step, vehicle
    /// and level).
    fn step_gnss(&mut self, ctx: &Context, ego: &InstanceSide) {
        let previous = std::mem::take(&mut self.gnss);
        self.reported.clear();
        for (k, level) in ctx.levels.iter().enumerate() {
            let mut stream = rng::stream(
                ctx.settings.seeds.sensor,
                Purpose::PoseNoise,
                &[ctx.step, ego.id_hash, level.label.stream_code()],
            );
            let last = previous.get(k).map(|&(t, e)| (ctx.time_s - t, e));
            let e = next_error(
                last.map(|p| p.1),
                last.map_or(0.0, |p| p.0),
                ctx.v.gnss_correlation_s,
                level,
                &mut stream,
            );
            self.gnss.push((ctx.time_s, e));
            self.reported.push(e.apply(&self.pose));
        }
    }

    /// CLEAR-MOT on this step's reported tracks.
    fn score(&mut self, ego: &InstanceSide) {
        let truth: Vec<(String, Vec2)> = ego
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

    fn finish(mut self) -> VehicleTracking {
        self.row.mot = self.mot.counts;
        self.row.tracks_started = self.tracker.started();
        self.row
    }
}

/// The pair-level views of one reception.
#[derive(Clone)]
struct Views {
    ego: Vec<Detection>,
    ego_ids: Vec<u64>,
    ego_truth: Vec<Option<String>>,
    peer: Vec<Detection>,
    peer_ids: Vec<u64>,
    peer_truth: Vec<Option<String>>,
    /// The peer objects' frame: the newest message's reported sender pose.
    peer_reported: Pose2,
}

impl Link {
    /// One message at its receiver: the known peer objects updated, both
    /// sides' views built, matched, associated, fused and counted.
    fn receive(
        &mut self,
        ctx: &Context,
        receiver: &Vehicle,
        m: &Sent,
        matcher: &dyn Matcher,
    ) -> Result<OverTimeCounts, RunError> {
        for (k, o) in m.objects.iter().enumerate() {
            self.known.insert(
                o.local_id,
                Known {
                    object: o.clone(),
                    generated_s: m.generated_s,
                    sender_reported: m.sender_reported[0],
                    label: m.labels[k].clone(),
                },
            );
        }
        // Forget objects the peer stopped sending (it sends each at
        // least every max_interval_s).
        let horizon = ctx.v.cpm.max_interval_s * 1.5;
        self.known
            .retain(|_, k| ctx.time_s - k.generated_s <= horizon);
        let views = self.views(ctx, receiver, m.sender_reported[0]);
        let mut c = OverTimeCounts {
            receptions: 1,
            ..OverTimeCounts::default()
        };
        if views.ego.is_empty() || views.peer.is_empty() {
            return Ok(c);
        }
        // Per message: the matcher on this message's poses alone.
        let matched = self.matched(ctx, receiver, &views, matcher)?;
        // Over time: the relative pose as estimated over earlier messages,
        // then the evidence carried across them.
        let corrected = match self.offset {
            Some(d) => {
                let p = views.peer_reported;
                let peer_reported = Pose2::new(
                    p.position_m() + d.position_m(),
                    p.heading_rad() + d.heading_rad(),
                );
                let v = Views {
                    peer_reported,
                    ..views.clone()
                };
                let m = self.matched(ctx, receiver, &v, matcher)?;
                (v, m)
            }
            None => (views.clone(), matched.clone()),
        };
        let s = &ctx.v.association;
        let live_ego: BTreeSet<u64> = views.ego_ids.iter().copied().collect();
        let live_peer: BTreeSet<u64> = self.known.keys().copied().collect();
        self.association
            .retain(|e| live_ego.contains(&e), |p| live_peer.contains(&p));
        self.association
            .update(s, &views.ego_ids, &views.peer_ids, &corrected.1);
        let over_time = self.association.decide(s, &views.ego_ids, &views.peer_ids);
        let truths = self.count(ctx, &views, &matched, &over_time, &mut c);
        self.estimate_pose(
            ctx,
            receiver,
            &corrected.0,
            &over_time,
            &views.peer_reported,
        );
        let views = corrected.0;
        let de = fuse_pairs(ctx, receiver, &views, &over_time);
        (c.de_single_sum_m, c.de_fused_sum_m, c.de_ci_sum_m, c.de_n) = de;
        let de = fuse_pairs(ctx, receiver, &views, &truths);
        (
            c.oracle_single_sum_m,
            c.oracle_fused_sum_m,
            c.oracle_ci_sum_m,
            c.oracle_n,
        ) = de;
        self.fuse_recursively(ctx, receiver, &views, &over_time, &mut c);
        Ok(c)
    }

    /// Updates each associated ego track's recursive estimate with the ego
    /// track and the peer's object of this reception (a track whose
    /// association changed starts again), and scores it against the truth.
    fn fuse_recursively(
        &mut self,
        ctx: &Context,
        receiver: &Vehicle,
        views: &Views,
        pairs: &[(u64, u64)],
        c: &mut OverTimeCounts,
    ) {
        let prior = relative_pose_prior(
            &receiver.reported[0],
            &views.peer_reported,
            ctx.level().position_sigma_m,
            ctx.level().heading_sigma_rad,
        );
        let mut next = BTreeMap::new();
        for &(e, p) in pairs {
            let (Some(k), Some(b)) = (
                receiver.tracks.iter().position(|t| t.id == e),
                views.peer_ids.iter().position(|&x| x == p),
            ) else {
                continue;
            };
            let track = receiver.tracks[k];
            let ego = Measurement {
                position_m: track.position_m,
                cov_m2: receiver.track_covs[k],
            };
            let body = Measurement {
                position_m: views.peer[b].position_m,
                cov_m2: views.peer[b].cov_m2,
            }
            .moved_uncertain(&prior);
            let peer = body.moved(&receiver.pose);
            let grow = |m: Measurement, dt: f64| Measurement {
                position_m: m.position_m + track.velocity_mps * dt,
                cov_m2: m.cov_m2
                    + Cov2::identity() * (ctx.v.tracker.accel_sigma_mps2 * dt * dt / 2.0).powi(2),
            };
            let previous = self.fused.get(&e).filter(|r| r.peer == p);
            let (ind, ci) = match previous {
                Some(r) => {
                    let dt = ctx.time_s - r.time_s;
                    (
                        fuse(&[grow(r.independent, dt), ego, peer]),
                        covariance_intersection(&[grow(r.ci, dt), ego, peer]),
                    )
                }
                None => (fuse(&[ego, peer]), covariance_intersection(&[ego, peer])),
            };
            let (Some(ind), Some(ci), Some(once), Some(once_ci)) = (
                ind,
                ci,
                fuse(&[ego, peer]),
                covariance_intersection(&[ego, peer]),
            ) else {
                continue;
            };
            let m = |f: &crate::fusion::Fused| Measurement {
                position_m: f.position_m,
                cov_m2: f.cov_m2,
            };
            next.insert(
                e,
                Recursive {
                    peer: p,
                    time_s: ctx.time_s,
                    independent: m(&ind),
                    ci: m(&ci),
                },
            );
            let truth = receiver
                .labels
                .get(&e)
                .and_then(|l| l.truth.as_deref())
                .and_then(|o| ctx.truth.get(o));
            if let Some(&truth) = truth {
                c.recursive_fused_sum_m += (ind.position_m - truth).norm();
                c.recursive_ci_sum_m += (ci.position_m - truth).norm();
                c.recursive_nees_fused_sum += nees(&m(&ind), truth);
                c.recursive_nees_ci_sum += nees(&m(&ci), truth);
                c.once_nees_fused_sum += nees(&m(&once), truth);
                c.once_nees_ci_sum += nees(&m(&once_ci), truth);
                c.recursive_n += 1;
            }
        }
        self.fused = next;
    }

    /// Aligns the pairs associated over time (with the current estimate
    /// as the prior) and moves the correction toward what they say, by
    /// `[v2x.association] pose_smoothing` (0: the relative pose comes
    /// from each message's reported poses alone).
    fn estimate_pose(
        &mut self,
        ctx: &Context,
        receiver: &Vehicle,
        views: &Views,
        pairs: &[(u64, u64)],
        raw: &Pose2,
    ) {
        // `raw`: the sender's reported pose of this message.
        let w = ctx.v.association.pose_smoothing;
        if w <= 0.0 {
            return;
        }
        let measured: Vec<(Measurement, Measurement)> = pairs
            .iter()
            .filter_map(|&(e, p)| {
                let a = views.ego_ids.iter().position(|&x| x == e)?;
                let b = views.peer_ids.iter().position(|&x| x == p)?;
                let m = |d: &Detection| Measurement {
                    position_m: d.position_m,
                    cov_m2: d.cov_m2,
                };
                Some((m(&views.ego[a]), m(&views.peer[b])))
            })
            .collect();
        let prior = relative_pose_prior(
            &receiver.reported[0],
            &views.peer_reported,
            ctx.level().position_sigma_m,
            ctx.level().heading_sigma_rad,
        );
        let aligned = align(&measured, &prior, ctx.settings.fusion.align_min_matches);
        if !aligned.refined {
            return;
        }
        // The sender's pose as aligned, against what it reported: a
        // correction in the world frame (the two GNSS errors, slowly
        // varying when they are correlated in time), whatever the
        // receiver's heading.
        let aligned_pose = receiver.reported[0].compose(&aligned.estimate.pose);
        let target = Pose2::new(
            aligned_pose.position_m() - raw.position_m(),
            wrap_angle(aligned_pose.heading_rad() - raw.heading_rad()),
        );
        let old = self.offset.unwrap_or_else(Pose2::identity);
        let t = old.position_m() + (target.position_m() - old.position_m()) * w;
        let turn = wrap_angle(target.heading_rad() - old.heading_rad());
        self.offset = Some(Pose2::new(t, old.heading_rad() + w * turn));
    }

    fn views(&self, ctx: &Context, receiver: &Vehicle, peer_reported: Pose2) -> Views {
        let mut v = Views {
            ego: Vec::new(),
            ego_ids: Vec::new(),
            ego_truth: Vec::new(),
            peer: Vec::new(),
            peer_ids: Vec::new(),
            peer_truth: Vec::new(),
            peer_reported,
        };
        for (id, d, label) in receiver.reported_tracks() {
            v.ego.push(d);
            v.ego_ids.push(id);
            v.ego_truth.push(label.truth.clone());
        }
        for (&id, k) in &self.known {
            let o = &k.object;
            let dt = if ctx.v.compensate_latency {
                ctx.time_s - k.generated_s
            } else {
                0.0
            };
            let (p, cov) = crate::v2x::extrapolate(
                o.position_m,
                o.velocity_mps,
                &o.position_cov_m2,
                &o.velocity_cov_m2ps2,
                dt,
                ctx.v.tracker.accel_sigma_mps2,
            );
            // Into the frame of the newest message, through the reported
            // poses the two messages carry.
            let world = k.sender_reported.to_parent(&p);
            let turn = k.sender_reported.heading_rad() - peer_reported.heading_rad();
            v.peer.push(Detection {
                position_m: peer_reported.to_body(&world),
                cov_m2: rotate_cov(&cov, turn),
                appearance: k.label.appearance.clone(),
            });
            v.peer_ids.push(id);
            v.peer_truth.push(k.label.truth.clone());
        }
        v
    }

    /// The frame matcher on the two views: (ego id, peer id).
    fn matched(
        &self,
        ctx: &Context,
        receiver: &Vehicle,
        views: &Views,
        matcher: &dyn Matcher,
    ) -> Result<Vec<(u64, u64)>, RunError> {
        let graph = |d: &[Detection]| {
            let p: Vec<Vec2> = d.iter().map(|x| x.position_m).collect();
            SceneGraph::delaunay(&p)
        };
        let (ga, gb) = (graph(&views.ego)?, graph(&views.peer)?);
        let a = MatchView {
            detections: &views.ego,
            graph: &ga,
            pose_reported: receiver.reported[0],
            pose_noise: *ctx.level(),
        };
        let b = MatchView {
            detections: &views.peer,
            graph: &gb,
            pose_reported: views.peer_reported,
            pose_noise: *ctx.level(),
        };
        Ok(matcher
            .identify(&a, &b)
            .matches
            .iter()
            .map(|c| (views.ego_ids[c.a], views.peer_ids[c.b]))
            .collect())
    }

    /// Pair counts of both decisions, time in view and to first right,
    /// and switches; returns the true pairs in view.
    fn count(
        &mut self,
        ctx: &Context,
        views: &Views,
        per_message: &[(u64, u64)],
        over_time: &[(u64, u64)],
        c: &mut OverTimeCounts,
    ) -> Vec<(u64, u64)> {
        let label = |ids: &[u64], truth: &[Option<String>]| -> BTreeMap<u64, String> {
            ids.iter()
                .zip(truth)
                .filter_map(|(&i, t)| t.clone().map(|t| (i, t)))
                .collect()
        };
        let (ego, peer) = (
            label(&views.ego_ids, &views.ego_truth),
            label(&views.peer_ids, &views.peer_truth),
        );
        let right = |&(e, p): &(u64, u64)| ego.get(&e).is_some_and(|o| peer.get(&p) == Some(o));
        let truths: Vec<(u64, u64)> = ego
            .iter()
            .flat_map(|(&e, o)| {
                peer.iter()
                    .filter(move |(_, q)| *q == o)
                    .map(move |(&p, _)| (e, p))
            })
            .collect();
        let counts = |pairs: &[(u64, u64)]| PairCounts {
            identified: pairs.len(),
            correct: pairs.iter().filter(|p| right(p)).count(),
            ground_truth: truths.len(),
        };
        c.per_message = counts(per_message);
        c.over_time = counts(over_time);
        c.pairs_in_view = truths.len() as u64;
        c.per_message_right = truths.iter().filter(|t| per_message.contains(t)).count() as u64;
        c.over_time_right = truths.iter().filter(|t| over_time.contains(t)).count() as u64;
        for t in &truths {
            let first = *self.first_in_view.entry(*t).or_insert(ctx.time_s);
            if over_time.contains(t) && self.found.insert(*t) {
                c.pairs_found += 1;
                c.time_to_first_right_sum_s += ctx.time_s - first;
            }
        }
        for &(e, p) in over_time {
            if self.last.insert(e, p).is_some_and(|q| q != p) {
                c.switches += 1;
            }
        }
        truths
    }
}

/// Ego tracks fused with the peer objects `pairs` associates them with:
/// the summed errors single, by Eq. 14-16 and by covariance intersection,
/// against the object's true centre in the receiver's body frame, and
/// their count.
fn fuse_pairs(
    ctx: &Context,
    receiver: &Vehicle,
    views: &Views,
    pairs: &[(u64, u64)],
) -> (f64, f64, f64, u64) {
    let prior = relative_pose_prior(
        &receiver.reported[0],
        &views.peer_reported,
        ctx.level().position_sigma_m,
        ctx.level().heading_sigma_rad,
    );
    let body = receiver.pose.inverse();
    let mut out = (0.0, 0.0, 0.0, 0);
    for &(e, p) in pairs {
        let (Some(a), Some(b)) = (
            views.ego_ids.iter().position(|&x| x == e),
            views.peer_ids.iter().position(|&x| x == p),
        ) else {
            continue;
        };
        let Some(truth) = views.ego_truth[a]
            .as_deref()
            .and_then(|o| ctx.truth.get(o))
            .map(|w| body.to_parent(w))
        else {
            continue;
        };
        let ego = Measurement {
            position_m: views.ego[a].position_m,
            cov_m2: views.ego[a].cov_m2,
        };
        let peer = Measurement {
            position_m: views.peer[b].position_m,
            cov_m2: views.peer[b].cov_m2,
        }
        .moved_uncertain(&prior);
        let (Some(ind), Some(ci)) = (fuse(&[ego, peer]), covariance_intersection(&[ego, peer]))
        else {
            continue;
        };
        out.0 += (ego.position_m - truth).norm();
        out.1 += (ind.position_m - truth).norm();
        out.2 += (ci.position_m - truth).norm();
        out.3 += 1;
    }
    out
}

/// The normalised estimation error squared of `m` against `truth`:
/// `e^T P^-1 e`, 2 on average (two dimensions) when the claimed
/// covariance is honest.
fn nees(m: &Measurement, truth: Vec2) -> f64 {
    let e = m.position_m - truth;
    m.cov_m2
        .try_inverse()
        .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[0])
}
