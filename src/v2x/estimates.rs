//! Fusion of what a receiver associated with one peer, scored against the
//! truth: once per reception ([`fuse_pairs`]: single, Eq. 14-16,
//! covariance intersection) and recursively into a running estimate per
//! ego track ([`RecursiveFusion`], where the independent form counts the
//! same information again: the NEES shows it).

use std::collections::BTreeMap;

use super::context::Context;
use super::counts::OverTimeCounts;
use super::vehicle::ConnectedVehicle;
use super::views::{Views, measurement};
use crate::fusion::{Measurement, Recursive, covariance_intersection, fuse, nees};
/// Ego tracks fused with the peer objects `pairs` associates them with:
/// the summed errors single, by Eq. 14-16 and by covariance intersection,
/// against the object's true centre in the receiver's body frame, and
/// their count.
pub(super) fn fuse_pairs(
    ctx: &Context,
    receiver: &ConnectedVehicle,
    views: &Views,
    pairs: &[(u64, u64)],
) -> (f64, f64, f64, u64) {
    let prior = views.gps_prior(&receiver.reported_poses()[0]);
    let body = receiver.pose().inverse();
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
        let ego = measurement(&views.ego[a]);
        let peer = measurement(&views.peer[b]).moved_uncertain(&prior);
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

/// Per ego track associated with one peer: the peer's object it is fused
/// with and its recursively fused estimate (the receiver's tracking
/// frame).
#[derive(Default)]
pub(super) struct RecursiveFusion {
    fused: BTreeMap<u64, (u64, Recursive)>,
}

impl RecursiveFusion {
    /// Updates each associated ego track's recursive estimate with the ego
    /// track and the peer's object of this reception (a track whose
    /// association changed starts again), and scores it against the truth.
    pub(super) fn update(
        &mut self,
        ctx: &Context,
        receiver: &ConnectedVehicle,
        views: &Views,
        pairs: &[(u64, u64)],
        c: &mut OverTimeCounts,
    ) {
        let prior = views.gps_prior(&receiver.reported_poses()[0]);
        let mut next = BTreeMap::new();
        for &(e, p) in pairs {
            let (Some((track, track_cov)), Some(b)) = (
                receiver.track(e),
                views.peer_ids.iter().position(|&x| x == p),
            ) else {
                continue;
            };
            let ego = Measurement {
                position_m: track.position_m,
                cov_m2: *track_cov,
            };
            let body = measurement(&views.peer[b]).moved_uncertain(&prior);
            let peer = body.moved(&receiver.pose());
            let previous = self.fused.get(&e).filter(|(q, _)| *q == p);
            let r = Recursive::update(
                previous.map(|(_, r)| r),
                ctx.time_s,
                track.velocity_mps,
                ctx.v.tracker.accel_sigma_mps2,
                &[ego, peer],
            );
            let (Some(r), Some(once), Some(once_ci)) =
                (r, fuse(&[ego, peer]), covariance_intersection(&[ego, peer]))
            else {
                continue;
            };
            next.insert(e, (p, r));
            let truth = receiver
                .label(e)
                .and_then(|l| l.truth.as_deref())
                .and_then(|o| ctx.truth.get(o));
            if let Some(&truth) = truth {
                let error = |m: &Measurement| m.position_m - truth;
                let nees_of = |m: &Measurement| nees(error(m), &m.cov_m2);
                let (ind, ci) = (&r.independent, &r.ci);
                c.recursive_fused_sum_m += error(ind).norm();
                c.recursive_ci_sum_m += error(ci).norm();
                c.recursive_nees_fused_sum += nees_of(ind);
                c.recursive_nees_ci_sum += nees_of(ci);
                c.once_nees_fused_sum += nees_of(&once.measurement());
                c.once_nees_ci_sum += nees_of(&once_ci.measurement());
                c.recursive_n += 1;
            }
        }
        self.fused = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Cov2, Pose2, Vec2};
    use crate::sensor::Detection;
    use crate::v2x::testkit::{appearance, centres, context, settings, vehicle_side};

    const OBJECTS: [(&str, Vec2); 2] = [("a", Vec2::new(12.0, 3.0)), ("b", Vec2::new(18.0, -4.0))];

    fn receiver_pose() -> Pose2 {
        Pose2::new(Vec2::new(0.0, 1.0), 0.3)
    }

    fn sender_pose() -> Pose2 {
        Pose2::new(Vec2::new(40.0, 2.0), 3.0)
    }

    fn detection(p: Vec2) -> Detection {
        Detection {
            position_m: p,
            cov_m2: Cov2::identity() * 0.04,
            appearance: appearance("a"),
            motion: None,
        }
    }

    /// The receiver after `n` steps of 0.1 s seeing `OBJECTS` still (at
    /// the first level, no noise: its reported pose is its true one).
    fn receiver(n: u64) -> ConnectedVehicle {
        let s = settings();
        let truth = centres(&OBJECTS);
        let mut v = ConnectedVehicle::new("cv0", &s.v2x);
        for step in 0..n {
            let ctx = context(&s, &truth, step, step as f64 * 0.1);
            let side = vehicle_side("cv0", receiver_pose(), &OBJECTS, step);
            v.step(&ctx, &side.sensing());
        }
        v
    }

    /// Views of `OBJECTS`: the receiver's `ego_offset` off each (world
    /// frame), the sender's (peer ids 10, 11) the other way.
    fn views(ego_ids: Vec<u64>, ego_offset: Vec2) -> Views {
        let (r, s) = (receiver_pose(), sender_pose());
        Views {
            ego: OBJECTS
                .iter()
                .map(|(_, p)| detection(r.to_body(&(p + ego_offset))))
                .collect(),
            ego_ids,
            ego_truth: OBJECTS.iter().map(|(o, _)| Some((*o).to_owned())).collect(),
            peer: OBJECTS
                .iter()
                .map(|(_, p)| detection(s.to_body(&(p - ego_offset))))
                .collect(),
            peer_ids: vec![10, 11],
            peer_truth: OBJECTS.iter().map(|(o, _)| Some((*o).to_owned())).collect(),
            peer_reported: s,
            ego_claim: settings().pose_noise[0],
            peer_claim: settings().pose_noise[0],
        }
    }

    #[test]
    fn a_detection_is_measured_where_it_is_with_its_covariance() {
        let d = detection(Vec2::new(3.0, 4.0));
        assert_eq!(measurement(&d).position_m, d.position_m);
        assert_eq!(measurement(&d).cov_m2, d.cov_m2);
    }

    /// Two equally sure views on either side of an object fuse onto it
    /// (Eq. 14-16; covariance intersection comes closer than either);
    /// pairs of unknown ids are left out, a wrong pair is far off.
    #[test]
    fn fusing_two_views_either_side_of_an_object_lands_on_it() {
        let s = settings();
        let truth = centres(&OBJECTS);
        let ctx = context(&s, &truth, 2, 0.2);
        let v = views(vec![1, 2], Vec2::new(0.3, 0.0));
        let rx = receiver(1);
        let (single, fused, ci, n) = fuse_pairs(&ctx, &rx, &v, &[(1, 10), (2, 11), (7, 10)]);
        assert_eq!(n, 2);
        assert!((single - 0.6).abs() < 1e-9, "{single}");
        assert!(fused < 1e-9, "{fused}");
        assert!(ci < single, "{ci}");
        let wrong = fuse_pairs(&ctx, &rx, &v, &[(1, 11)]);
        assert!(wrong.1 > 1.0);
    }

    /// A track fused again with the same peer object gains information
    /// (its covariance shrinks); a new partner starts it again; each
    /// update is scored against the truth.
    #[test]
    fn a_recursive_estimate_accumulates_until_its_partner_changes() {
        let s = settings();
        let truth = centres(&OBJECTS);
        let hits = u64::from(s.v2x.tracker.confirm_hits);
        let rx = receiver(hits);
        let ids: Vec<u64> = rx.reported_tracks().map(|t| t.0).collect();
        let by_object = |o: &str| {
            rx.reported_tracks()
                .find(|t| t.2.truth.as_deref() == Some(o))
                .unwrap()
                .0
        };
        let (ea, eb) = (by_object("a"), by_object("b"));
        assert_eq!(ids.len(), 2);
        let v = views(vec![ea, eb], Vec2::zeros());
        let mut rf = RecursiveFusion::default();
        let mut c = OverTimeCounts::default();
        let trace = |rf: &RecursiveFusion| rf.fused[&ea].1.independent.cov_m2.trace();
        rf.update(&context(&s, &truth, 5, 0.5), &rx, &v, &[(ea, 10)], &mut c);
        let once = trace(&rf);
        rf.update(&context(&s, &truth, 6, 0.6), &rx, &v, &[(ea, 10)], &mut c);
        assert!(trace(&rf) < once, "{} !< {once}", trace(&rf));
        rf.update(&context(&s, &truth, 7, 0.7), &rx, &v, &[(ea, 11)], &mut c);
        assert!((trace(&rf) - once).abs() < 1e-12, "started again");
        assert_eq!(rf.fused[&ea].0, 11);
        assert_eq!(c.recursive_n, 3);
        assert!(c.recursive_fused_sum_m.is_finite() && c.once_nees_ci_sum.is_finite());
        rf.update(&context(&s, &truth, 8, 0.8), &rx, &v, &[], &mut c);
        assert!(rf.fused.is_empty(), "no association, no estimate");
    }
}
