//! What a receiver knows of one peer over time ([`PeerState`]) and what it
//! does with each message from it: the peer's objects kept (forgotten
//! 1.5 x `max_interval_s` after their last message) and moved ahead to the
//! receiver's time, both sides' [`Views`], the frame matcher on them
//! through the reported poses and through the relative pose estimated over
//! time, the association carried across messages (`v2x::receiver`), then
//! the counts and the fusion of what it associated.

use std::collections::{BTreeMap, BTreeSet};

use super::RunError;
use super::context::Context;
use super::fusion_over_time::{RecursiveFusion, fuse_pairs};
use super::message::{Sent, TrackLabel};
use super::pair_history::PairHistory;
use super::relative_pose::PoseCorrection;
use super::vehicle::ConnectedVehicle;
use crate::geometry::{Pose2, Vec2, rotate_cov};
use crate::graph::SceneGraph;
use crate::matching::{MatchView, Matcher};
use crate::report::OverTimeCounts;
use crate::sensor::Detection;
use crate::v2x::cpm::PerceivedObject;
use crate::v2x::receiver::Association;

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

/// The pair-level views of one reception: the receiver's reported tracks
/// (`ego`, its body frame) and the peer's known objects (`peer`, in the
/// frame of `peer_reported`), each with its ids and true objects.
#[derive(Clone)]
pub(super) struct Views {
    pub ego: Vec<Detection>,
    pub ego_ids: Vec<u64>,
    pub ego_truth: Vec<Option<String>>,
    pub peer: Vec<Detection>,
    pub peer_ids: Vec<u64>,
    pub peer_truth: Vec<Option<String>>,
    /// The peer objects' frame: the newest message's reported sender pose.
    pub peer_reported: Pose2,
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
    ) -> Result<OverTimeCounts, RunError> {
        self.remember(ctx, m);
        let views = self.views(ctx, receiver, m.sender_reported[0]);
        let mut c = OverTimeCounts {
            receptions: 1,
            ..OverTimeCounts::default()
        };
        if views.ego.is_empty() || views.peer.is_empty() {
            return Ok(c);
        }
        // Per message: the matcher on this message's poses alone.
        let matched = identified(ctx, receiver, &views, matcher)?;
        // Over time: the relative pose as estimated over earlier messages,
        // then the evidence carried across them.
        let (corrected, corrected_matched) = match self.correction.apply(&views.peer_reported) {
            Some(peer_reported) => {
                let v = Views {
                    peer_reported,
                    ..views.clone()
                };
                let m = identified(ctx, receiver, &v, matcher)?;
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
    /// ahead to now and into the frame of `peer_reported`.
    fn views(&self, ctx: &Context, receiver: &ConnectedVehicle, peer_reported: Pose2) -> Views {
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
            let (p, cov) = ctx.object_moved_ahead(&k.object, k.generated_s);
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
}

/// The frame matcher on the two views: (ego id, peer id).
fn identified(
    ctx: &Context,
    receiver: &ConnectedVehicle,
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
        pose_reported: receiver.reported_poses()[0],
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
