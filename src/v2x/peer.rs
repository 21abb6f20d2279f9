//! What a receiver knows of one peer over time ([`PeerState`]) and what it
//! does with each message from it: the peer's objects kept (forgotten
//! 1.5 x `max_interval_s` after their last message) and moved ahead to the
//! receiver's time, both sides' views, the frame matcher on them
//! through the reported poses and through the relative pose estimated over
//! time, the association carried across messages (`v2x::receiver`), then
//! the counts and the fusion of what it associated.

use std::collections::{BTreeMap, BTreeSet};

use super::context::Context;
use super::counts::OverTimeCounts;
use super::cpm::PerceivedObject;
use super::estimates::{RecursiveFusion, fuse_pairs};
use super::message::{Sent, TrackLabel};
use super::pair_history::PairHistory;
use super::receiver::Association;
use super::relative_pose::PoseCorrection;
use super::vehicle::ConnectedVehicle;
use super::views::Views;
use crate::geometry::{Pose2, Vec2, rotate_cov};
use crate::graph::{GraphError, SceneGraph};
use crate::matching::{MatchView, Matcher};
use crate::sensor::Detection;
use crate::sensor::gnss::at_speed;

/// What a receiver knows of one peer.
#[derive(Default)]
pub(super) struct PeerState {
    association: Association,
    /// The peer's objects last received, by its ids.
    known: BTreeMap<u64, Known>,
    history: PairHistory,
    correction: PoseCorrection,
    fused: RecursiveFusion,
}

/// A peer's object as last received.
#[derive(Clone)]
struct Known {
    object: PerceivedObject,
    generated_s: f64,
    sender_reported: Pose2,
    label: TrackLabel,
}

impl PeerState {
    /// True pairs (ego track, peer id) ever in view.
    pub(super) fn pairs_seen(&self) -> u64 {
        self.history.pairs_seen()
    }

    /// One message at its receiver: the known peer objects updated, both
    /// sides' views built, matched, associated, fused and counted.
    pub(super) fn receive(
        &mut self,
        ctx: &Context,
        receiver: &ConnectedVehicle,
        m: &Sent,
        matcher: &dyn Matcher,
    ) -> Result<OverTimeCounts, GraphError> {
        self.remember(ctx, m);
        let views = self.views(ctx, receiver, m);
        let mut c = OverTimeCounts {
            receptions: 1,
            ..OverTimeCounts::default()
        };
        if views.ego.is_empty() || views.peer.is_empty() {
            return Ok(c);
        }
        // Per message: the matcher on this message's poses alone.
        let matched = identified(receiver, &views, matcher)?;
        // Over time: the relative pose as estimated over earlier messages,
        // then the evidence carried across them.
        let (corrected, corrected_matched) = match self.correction.apply(&views.peer_reported) {
            Some(peer_reported) => {
                let v = Views {
                    peer_reported,
                    ..views.clone()
                };
                let m = identified(receiver, &v, matcher)?;
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
            .update(s, &views.ego_ids, &views.peer_ids, &corrected_matched);
        let over_time = self.association.decide(s, &views.ego_ids, &views.peer_ids);
        let truths = self
            .history
            .count(ctx.time_s, &views, &matched, &over_time, &mut c);
        self.correction.update(
            ctx,
            &receiver.reported_poses()[0],
            &corrected,
            &over_time,
            &views.peer_reported,
        );
        let de = fuse_pairs(ctx, receiver, &corrected, &over_time);
        (c.de_single_sum_m, c.de_fused_sum_m, c.de_ci_sum_m, c.de_n) = de;
        let de = fuse_pairs(ctx, receiver, &corrected, &truths);
        (
            c.oracle_single_sum_m,
            c.oracle_fused_sum_m,
            c.oracle_ci_sum_m,
            c.oracle_n,
        ) = de;
        self.fused
            .update(ctx, receiver, &corrected, &over_time, &mut c);
        Ok(c)
    }

    /// Keeps the objects of `m`, and forgets those the peer stopped
    /// sending (it sends each at least every `max_interval_s`).
    fn remember(&mut self, ctx: &Context, m: &Sent) {
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
        let horizon = ctx.v.cpm.max_interval_s * 1.5;
        self.known
            .retain(|_, k| ctx.time_s - k.generated_s <= horizon);
    }

    /// The receiver's reported tracks, and the known peer objects moved
    /// ahead to now and into the frame of the sender's pose `m` reports.
    fn views(&self, ctx: &Context, receiver: &ConnectedVehicle, m: &Sent) -> Views {
        let peer_reported = m.sender_reported[0];
        let sigma = ctx.v.gnss_heading_speed_sigma_mps;
        let mut v = Views {
            ego: Vec::new(),
            ego_ids: Vec::new(),
            ego_truth: Vec::new(),
            peer: Vec::new(),
            peer_ids: Vec::new(),
            peer_truth: Vec::new(),
            peer_reported,
            ego_claim: at_speed(ctx.level(), receiver.speed_mps(), sigma),
            peer_claim: at_speed(ctx.level(), m.sender_speed_mps, sigma),
        };
        for (id, d, label) in receiver.reported_tracks() {
            v.ego.push(d);
            v.ego_ids.push(id);
            v.ego_truth.push(label.truth.clone());
        }
        for (&id, k) in &self.known {
            let (p, cov) = ctx.object_moved_ahead(&k.object, k.generated_s);
            // Into the frame of the newest message, through the reported
            // poses the two messages carry.
            let world = k.sender_reported.to_parent(&p);
            let turn = k.sender_reported.heading_rad() - peer_reported.heading_rad();
            v.peer.push(Detection {
                position_m: peer_reported.to_body(&world),
                cov_m2: rotate_cov(&cov, turn),
                appearance: k.label.appearance.clone(),
                motion: None,
            });
            v.peer_ids.push(id);
            v.peer_truth.push(k.label.truth.clone());
        }
        v
    }
}

/// The frame matcher on the two views: (ego id, peer id).
fn identified(
    receiver: &ConnectedVehicle,
    views: &Views,
    matcher: &dyn Matcher,
) -> Result<Vec<(u64, u64)>, GraphError> {
    let graph = |d: &[Detection]| {
        let p: Vec<Vec2> = d.iter().map(|x| x.position_m).collect();
        SceneGraph::delaunay(&p)
    };
    let (ga, gb) = (graph(&views.ego)?, graph(&views.peer)?);
    let a = MatchView {
        detections: &views.ego,
        graph: &ga,
        pose_reported: receiver.reported_poses()[0],
        pose_noise: views.ego_claim,
    };
    let b = MatchView {
        detections: &views.peer,
        graph: &gb,
        pose_reported: views.peer_reported,
        pose_noise: views.peer_claim,
    };
    Ok(matcher
        .identify(&a, &b)
        .matches
        .iter()
        .map(|c| (views.ego_ids[c.a], views.peer_ids[c.b]))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::CorrespondenceSource;
    use crate::matching::Method;
    use crate::pipeline::runner;
    use crate::v2x::testkit::{centres, context, settings, vehicle_side};

    const OBJECTS: [(&str, Vec2); 3] = [
        ("a", Vec2::new(12.0, 3.0)),
        ("b", Vec2::new(18.0, -4.0)),
        ("c", Vec2::new(25.0, 8.0)),
    ];

    /// The receiver (cv0) and the sender (cv1) after both saw `OBJECTS`
    /// still until their tracks were confirmed, and the sender's first
    /// message that carries them.
    fn tracked() -> (ConnectedVehicle, Sent) {
        let s = settings();
        let truth = centres(&OBJECTS);
        let poses = [
            Pose2::new(Vec2::new(0.0, 1.0), 0.3),
            Pose2::new(Vec2::new(40.0, 2.0), 3.0),
        ];
        let mut v =
            [("cv0", poses[0]), ("cv1", poses[1])].map(|(id, _)| ConnectedVehicle::new(id, &s.v2x));
        let mut message = None;
        for step in 0..u64::from(s.v2x.tracker.confirm_hits) {
            let ctx = context(&s, &truth, step, step as f64 * 0.1);
            v[0].step(
                &ctx,
                &vehicle_side("cv0", poses[0], &OBJECTS, step).sensing(),
            );
            let side = vehicle_side("cv1", poses[1], &OBJECTS, step);
            let sent = v[1].step(&ctx, &side.sensing());
            message = sent.filter(|m| !m.objects.is_empty()).or(message);
        }
        let [receiver, _] = v;
        (receiver, message.expect("a message with the objects"))
    }

    fn matcher() -> Box<dyn Matcher> {
        match runner(&settings(), Method::GpsHungarian) {
            Ok(CorrespondenceSource::Matcher(m)) => m,
            _ => panic!("gps-hungarian is a matcher"),
        }
    }

    /// The peer's objects are moved into the frame of the pose given:
    /// through it they are where they are.
    #[test]
    fn the_peers_objects_are_seen_through_the_pose_given() {
        let s = settings();
        let truth = centres(&OBJECTS);
        let (receiver, m) = tracked();
        let ctx = context(&s, &truth, 9, m.generated_s);
        let mut state = PeerState::default();
        state.remember(&ctx, &m);
        let frame = Pose2::new(Vec2::new(-5.0, 7.0), 1.0);
        let mut through = m.clone();
        through.sender_reported[0] = frame;
        let v = state.views(&ctx, &receiver, &through);
        assert_eq!((v.ego.len(), v.peer.len()), (3, 3));
        for (d, t) in v.peer.iter().zip(&v.peer_truth) {
            let at = centres(&OBJECTS)[t.as_deref().unwrap()];
            assert!((frame.to_parent(&d.position_m) - at).norm() < 1e-6);
        }
    }

    /// Messages about the same objects are matched right at once and
    /// associated over time within a few receptions; objects the peer
    /// stopped sending are forgotten.
    #[test]
    fn the_same_objects_are_associated_over_time_then_forgotten() {
        let s = settings();
        let truth = centres(&OBJECTS);
        let (receiver, m) = tracked();
        let matcher = matcher();
        let mut state = PeerState::default();
        let mut associated_at = None;
        for k in 0..6 {
            let ctx = context(&s, &truth, 10 + k, m.generated_s + 0.1);
            let c = state
                .receive(&ctx, &receiver, &m, matcher.as_ref())
                .unwrap();
            assert_eq!(c.receptions, 1);
            assert_eq!((c.per_message.correct, c.per_message.ground_truth), (3, 3));
            assert_eq!(c.over_time.correct, c.over_time.identified, "never wrong");
            if c.over_time.correct == 3 && associated_at.is_none() {
                associated_at = Some(k);
                assert_eq!((c.de_n, c.oracle_n), (3, 3));
                assert!(c.de_fused_sum_m < c.de_single_sum_m + 1e-9);
            }
        }
        assert!(associated_at.is_some(), "associated within 6 receptions");
        assert_eq!(state.pairs_seen(), 3);
        let mut empty = m.clone();
        empty.objects.clear();
        empty.labels.clear();
        let late = s.v2x.cpm.max_interval_s * 2.0;
        let ctx = context(&s, &truth, 40, m.generated_s + late);
        let c = state
            .receive(&ctx, &receiver, &empty, matcher.as_ref())
            .unwrap();
        assert_eq!((c.receptions, c.per_message.ground_truth), (1, 0));
    }
}
