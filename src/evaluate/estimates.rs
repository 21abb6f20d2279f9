//! What each ego estimates about each real object it detects, fused with
//! the peers' detections its matches pair with its own (Eq. 14-16, in the
//! paper's form or with the relative pose aligned from the matches): per
//! instance ([`ObjectEstimate`]: the ego and one peer) and per frame
//! ([`ViewEstimate`]: the ego and every peer that matched the object).
//! The object set is every real object the ego detects, whatever the
//! method did.

use std::collections::BTreeMap;

use super::{MethodEval, PairAtLevel, Side};
use crate::fusion::{
    FusionSettings, FusionVariant, Measurement, PeerPose, consistency_scale, fuse,
    hedged_covariance, nees, relative_pose_prior,
};
use crate::geometry::Vec2;
use crate::matching::claim;
use crate::sensor::Observation;

/// One (ego, object) estimate of one instance, all positions in the world
/// frame: estimates live in the ego's frame and are placed in the world with
/// the ego's true pose, so the error is what the ego gets wrong about the
/// object relative to itself. There is one for every real object the ego
/// detects, whatever the method did: the object set is the same for every
/// method.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectEstimate {
    pub ego_id: String,
    pub peer_id: String,
    pub object_id: String,
    /// Whether the peer detects the object too.
    pub covisible: bool,
    /// Whether the method paired the ego's detection with one of the
    /// peer's; if not, the fused estimate is the single one.
    pub matched: bool,
    /// Whether it was paired with the peer's detection of the same object.
    pub match_correct: bool,
    /// Whether the relative pose was refined from matches (aligned variant).
    pub pose_refined: bool,
    pub truth_m: Vec2,
    pub single_m: Vec2,
    pub fused_m: Vec2,
    /// The fused estimate's NEES: its error against the covariance the
    /// fusion claims for it (Eq. 16; the ego's own where nothing was
    /// fused), in the ego's frame. Its mean is 2 (the degrees of freedom)
    /// when every reported covariance is the truth and the match right.
    pub fused_nees: f64,
    /// The same against the claim hedged by the match
    /// ([`hedged_covariance`]): Eq. 16's scaled where the two measurements
    /// disagree beyond chi2's 99 % ([`consistency_scale`]), mixed by the
    /// method's probability that the match is right with what a wrong one
    /// would leave.
    pub fused_nees_hedged: f64,
}

impl ObjectEstimate {
    pub fn single_error_m(&self) -> f64 {
        (self.single_m - self.truth_m).norm()
    }
    pub fn fused_error_m(&self) -> f64 {
        (self.fused_m - self.truth_m).norm()
    }
}

/// One (ego, real object) of a frame, fused from every vehicle that
/// matched it (Eq. 14-16 with N terms), beside the pairwise estimates of
/// the same object: the object set is every real object an ego of the
/// frame detects, the same for every method.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewEstimate {
    pub ego_id: String,
    pub object_id: String,
    /// Vehicles that detect the object: the ego and those of its instance
    /// peers that do (from the truth, the same for every method).
    pub seen_by: usize,
    /// Measurements fused: the ego's and one per peer that matched it.
    pub views: usize,
    pub single_error_m: f64,
    /// The mean pairwise fused error over the ego's instances whose peer
    /// sees the object too (over all its instances when none does): what
    /// fusing with one covisible peer at a time gives.
    pub pairwise_error_m: f64,
    pub fused_error_m: f64,
}

/// How one ego fuses: the variant and its setting (the poses' claims
/// come with each side's view).
pub(super) struct FusionContext {
    variant: FusionVariant,
    align_min_matches: usize,
}

impl FusionContext {
    pub(super) fn new(variant: FusionVariant, fusion: &FusionSettings) -> Self {
        Self {
            variant,
            align_min_matches: fusion.align_min_matches,
        }
    }
}

/// The estimates of every real object `ego` detected (false positives have
/// no truth; the ego's own node is not a detection): fused with the peer's
/// detection the correspondences pair it with (`pairs` index `(ego
/// detection, peer detection)`), or the ego's own where there is none.
/// `paper` moves the peer's detection with the relative pose of both GPS
/// poses and rotates its covariance (Eq. 14-16); `aligned` refines that
/// pose from the matched pairs and adds the covariance of the refined pose
/// to the moved detection's.
pub(super) fn fuse_for_ego(
    ego: &Side,
    peer: &Side,
    pairs: &[(usize, usize)],
    probabilities: &[f64],
    ctx: &FusionContext,
) -> Vec<ObjectEstimate> {
    let (refined, peer_pose) = peer_pose(ego, peer, pairs, ctx);
    let moved = |m: &Measurement| peer_pose.move_measurement(m);
    let mut partner: Vec<Option<usize>> = vec![None; ego.obs.detections.len()];
    let mut probability = vec![1.0; ego.obs.detections.len()];
    for (&(a, b), &p) in pairs.iter().zip(probabilities) {
        partner[a] = Some(b);
        probability[a] = p;
    }
    let to_world = |p: &Vec2| ego.truth.ego_pose.to_parent(p);
    let mut out = Vec::new();
    for (a, id, truth_m) in real_detections(ego) {
        let own = measured(ego.obs, a);
        let (fused, fused_cov, hedged_cov) = partner[a]
            .and_then(|b| {
                let ms = [own, moved(&measured(peer.obs, b))];
                fuse(&ms).map(|f| {
                    let scale = consistency_scale(&ms, &f);
                    let hedged = hedged_covariance(&own, &f, scale, probability[a]);
                    (f.position_m, f.cov_m2, hedged)
                })
            })
            .unwrap_or((own.position_m, own.cov_m2, own.cov_m2));
        let error_ego = fused - ego.truth.ego_pose.to_body(&truth_m);
        let fused_nees = nees(error_ego, &fused_cov);
        let matched = partner[a].is_some();
        out.push(ObjectEstimate {
            ego_id: ego.obs.ego_id.clone(),
            peer_id: peer.obs.ego_id.clone(),
            object_id: id.to_owned(),
            covisible: peer.truth.find(id).is_some(),
            matched,
            match_correct: partner[a].is_some_and(|b| peer.truth.object_id(b) == Some(id)),
            pose_refined: refined,
            truth_m,
            single_m: to_world(&own.position_m),
            fused_m: to_world(&fused),
            fused_nees,
            fused_nees_hedged: nees(error_ego, &hedged_cov),
        });
    }
    out
}

/// Every ego of the frame (`ego_ids`: the frame's vehicles) fuses each
/// real object it detects from all the peers (of its instances) whose
/// detection the decided matches pair with its own; beside it, the mean of
/// the pairwise fused errors of `scored` over the peers that see the
/// object.
pub(super) fn all_views(
    pairs: &[PairAtLevel],
    scored: &[MethodEval],
    ego_ids: &[&str],
    ctx: &FusionContext,
) -> Vec<ViewEstimate> {
    // Per (ego, object): sums of the pairwise fused errors over the peers
    // that see the object too, and over all peers.
    let mut pairwise: BTreeMap<(&str, &str), [(f64, usize); 2]> = BTreeMap::new();
    for e in scored {
        for (v, est) in &e.fused {
            if *v == ctx.variant {
                for x in est {
                    let sums = pairwise.entry((&x.ego_id, &x.object_id)).or_default();
                    let err = x.fused_error_m();
                    if x.covisible {
                        sums[0].0 += err;
                        sums[0].1 += 1;
                    }
                    sums[1].0 += err;
                    sums[1].1 += 1;
                }
            }
        }
    }
    let mut out = Vec::new();
    for ego_id in ego_ids {
        let mut ego = None;
        let mut peers: Vec<(Side, Vec<(usize, usize)>)> = Vec::new();
        for (p, e) in pairs.iter().zip(scored) {
            let m = &e.identification.matches;
            if p.first.obs.ego_id == *ego_id {
                ego = Some(p.first);
                peers.push((p.second, m.iter().map(|c| (c.a, c.b)).collect()));
            } else if p.second.obs.ego_id == *ego_id {
                ego = Some(p.second);
                peers.push((p.first, m.iter().map(|c| (c.b, c.a)).collect()));
            }
        }
        let Some(ego) = ego else { continue };
        for mut v in fuse_all_views(&ego, &peers, ctx) {
            let [covisible, all] = pairwise[&(v.ego_id.as_str(), v.object_id.as_str())];
            let (sum, n) = if covisible.1 > 0 { covisible } else { all };
            v.pairwise_error_m = sum / n as f64;
            out.push(v);
        }
    }
    out
}

/// `ego`'s estimate of every real object it detects, fused with the
/// matched detection of every peer (`peers`: each with its matched (ego
/// detection, peer detection)), each peer's pose from the variant of
/// `ctx`; the ego's own where no peer matched it. `pairwise_error_m` is
/// left NaN for the caller.
fn fuse_all_views(
    ego: &Side,
    peers: &[(Side, Vec<(usize, usize)>)],
    ctx: &FusionContext,
) -> Vec<ViewEstimate> {
    let poses: Vec<PeerPose> = peers
        .iter()
        .map(|(peer, pairs)| peer_pose(ego, peer, pairs, ctx).1)
        .collect();
    let mut out = Vec::new();
    for (a, id, truth_m) in real_detections(ego) {
        let own = measured(ego.obs, a);
        let mut measurements = vec![own];
        for ((peer, pairs), pose) in peers.iter().zip(&poses) {
            if let Some(&(_, b)) = pairs.iter().find(|(x, _)| *x == a) {
                measurements.push(pose.move_measurement(&measured(peer.obs, b)));
            }
        }
        let fused = if measurements.len() > 1 {
            fuse(&measurements).map_or(own.position_m, |f| f.position_m)
        } else {
            own.position_m
        };
        let error = |p: &Vec2| (ego.truth.ego_pose.to_parent(p) - truth_m).norm();
        out.push(ViewEstimate {
            ego_id: ego.obs.ego_id.clone(),
            object_id: id.to_owned(),
            seen_by: 1 + peers
                .iter()
                .filter(|(peer, _)| peer.truth.find(id).is_some())
                .count(),
            views: measurements.len(),
            single_error_m: error(&own.position_m),
            pairwise_error_m: f64::NAN,
            fused_error_m: error(&fused),
        });
    }
    out
}

/// The ego's detections of real objects (false positives have no truth;
/// the ego's own node is not a detection): index, object id, true
/// position (world frame).
fn real_detections<'a>(ego: &Side<'a>) -> impl Iterator<Item = (usize, &'a str, Vec2)> {
    ego.truth
        .detections
        .iter()
        .enumerate()
        .filter(|(_, t)| !t.sender)
        .filter_map(|(a, t)| Some((a, t.object_id.as_deref()?, t.position_m?)))
}

/// Detection `k` of `obs` as a measurement in that vehicle's frame.
pub(super) fn measured(obs: &Observation, k: usize) -> Measurement {
    Measurement {
        position_m: obs.detections[k].position_m,
        cov_m2: obs.detections[k].cov_m2,
    }
}

/// Where `peer` sits in `ego`'s frame for the variant of `ctx` (`pairs`:
/// the matched (ego detection, peer detection)), and whether it was
/// refined from the matches.
fn peer_pose(
    ego: &Side,
    peer: &Side,
    pairs: &[(usize, usize)],
    ctx: &FusionContext,
) -> (bool, PeerPose) {
    let prior = relative_pose_prior(
        &ego.view.pose_reported,
        &peer.view.pose_reported,
        claim(&ego.view.pose_noise),
        claim(&peer.view.pose_noise),
    );
    let matched = || {
        pairs
            .iter()
            .map(|&(a, b)| (measured(ego.obs, a), measured(peer.obs, b)))
            .collect()
    };
    PeerPose::of(ctx.variant, &prior, matched, ctx.align_min_matches)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::testkit::{TestFrame, paper_fusion, sensed};
    use crate::evaluate::{CorrespondenceSource, evaluate_frame};
    use crate::geometry::Pose2;
    use crate::matching::MultiVehicle;
    use crate::sensor::ObservationTruth;

    #[test]
    fn fusion_from_every_view_reduces_to_the_pair_for_two_vehicles() {
        let objects = [
            (Some("x"), Vec2::new(5.0, 8.0)),
            (Some("y"), Vec2::new(12.0, -3.0)),
            (Some("z"), Vec2::new(-4.0, 6.0)),
        ];
        let poses = [(0.0, 0.1), (15.0, 2.0), (-10.0, -1.2)]
            .map(|(x, h)| Pose2::new(Vec2::new(x, -12.0), h));
        // Measurements off by a different vector for every detection.
        let sensed: Vec<(Observation, ObservationTruth)> = ["a", "b", "c"]
            .iter()
            .zip(&poses)
            .enumerate()
            .map(|(v, (id, p))| {
                let (mut obs, truth) = sensed(id, *p, &objects);
                for (k, d) in obs.detections.iter_mut().enumerate() {
                    let t = (3 * v + k) as f64;
                    d.position_m += Vec2::new(0.4 * t.sin(), 0.3 * t.cos());
                }
                (obs, truth)
            })
            .collect();
        let frame = TestFrame::new(sensed, &poses);
        let pair = |i: usize, j: usize| frame.pair(i, j);
        let fusion = paper_fusion();
        let oracle = |pairs: &[PairAtLevel]| {
            let source = CorrespondenceSource::Oracle;
            evaluate_frame(pairs, &source, &fusion, MultiVehicle::Pairwise)
        };
        // Two vehicles: every view estimate is the pairwise one.
        let two = oracle(&[pair(0, 1)]);
        let views = &two.views[0].1;
        assert_eq!(views.len(), 6);
        for v in views {
            assert_eq!((v.views, v.seen_by), (2, 2));
            assert_eq!(v.fused_error_m, v.pairwise_error_m, "{v:?}");
            assert!(v.fused_error_m < v.single_error_m + 0.3);
        }
        // Each pairwise estimate's NEES is its error against the fused
        // covariance (Eq. 16), whichever frame it is computed in.
        for x in &two.pairs[0].fused[0].1 {
            let k = objects
                .iter()
                .position(|o| o.0 == Some(x.object_id.as_str()))
                .unwrap();
            let (u, w) = if x.ego_id == "a" { (0, 1) } else { (1, 0) };
            let world: Vec<Measurement> = [u, w]
                .iter()
                .map(|&v| measured(&frame.sensed[v].0, k).moved(&poses[v]))
                .collect();
            let f = fuse(&world).unwrap();
            let e = f.position_m - objects[k].1;
            let nees = (e.transpose() * f.cov_m2.try_inverse().unwrap() * e)[(0, 0)];
            assert!(
                (x.fused_nees - nees).abs() < 1e-9 * nees.max(1.0),
                "{x:?} vs {nees}"
            );
            // The oracle's matches are certain: the hedged claim is Eq.
            // 16's scaled by the pair's consistency.
            let scale = consistency_scale(&world, &f);
            assert!((x.fused_nees_hedged - nees / scale).abs() < 1e-9 * nees.max(1.0));
        }
        // Three vehicles: each ego fuses all three measurements, which is
        // the fusion of the three moved into the world frame.
        let all = oracle(&[pair(0, 1), pair(0, 2), pair(1, 2)]);
        let views = &all.views[0].1;
        assert_eq!(views.len(), 9);
        for v in views {
            assert_eq!((v.views, v.seen_by), (3, 3));
            let k = objects
                .iter()
                .position(|o| o.0 == Some(v.object_id.as_str()))
                .unwrap();
            let world: Vec<Measurement> = (0..3)
                .map(|u| measured(&frame.sensed[u].0, k).moved(&poses[u]))
                .collect();
            let expected = (fuse(&world).unwrap().position_m - objects[k].1).norm();
            assert!(
                (v.fused_error_m - expected).abs() < 1e-9,
                "{v:?} vs {expected}"
            );
            assert!(v.fused_error_m != v.pairwise_error_m);
        }
    }
}
