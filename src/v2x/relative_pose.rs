//! The relative pose of a peer estimated over time ([`PoseCorrection`]): a
//! world-frame correction of the sender's reported pose (the two GNSS
//! errors, slowly varying when they are correlated in time), moved toward
//! each reception's alignment of the pairs associated over time by
//! `[v2x.association] pose_smoothing` (0: off, each message's reported
//! poses alone).

use super::context::Context;
use super::views::{Views, measurement};
use crate::fusion::{Measurement, align};
use crate::geometry::{Pose2, wrap_angle};

/// The correction of a peer's reported pose (world frame: translation and
/// heading), once there is one.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct PoseCorrection {
    offset: Option<Pose2>,
}

impl PoseCorrection {
    /// The sender's reported pose `reported` corrected, once a correction
    /// has been estimated.
    pub(super) fn apply(&self, reported: &Pose2) -> Option<Pose2> {
        let d = self.offset?;
        Some(Pose2::new(
            reported.position_m() + d.position_m(),
            reported.heading_rad() + d.heading_rad(),
        ))
    }

    /// Aligns the pairs associated over time (with the current estimate
    /// as the prior: `views` in the corrected frame) against the
    /// receiver's reported pose, and moves the correction toward what they
    /// say of `raw`, the sender's reported pose of this message.
    pub(super) fn update(
        &mut self,
        ctx: &Context,
        receiver_reported: &Pose2,
        views: &Views,
        pairs: &[(u64, u64)],
        raw: &Pose2,
    ) {
        let w = ctx.v.association.pose_smoothing;
        if w <= 0.0 {
            return;
        }
        let measured: Vec<(Measurement, Measurement)> = pairs
            .iter()
            .filter_map(|&(e, p)| {
                let a = views.ego_ids.iter().position(|&x| x == e)?;
                let b = views.peer_ids.iter().position(|&x| x == p)?;
                Some((measurement(&views.ego[a]), measurement(&views.peer[b])))
            })
            .collect();
        let prior = views.gps_prior(receiver_reported);
        let aligned = align(&measured, &prior, ctx.align_min_matches);
        if !aligned.refined {
            return;
        }
        // The sender's pose as aligned, against what it reported: a
        // correction in the world frame (the two GNSS errors, slowly
        // varying when they are correlated in time), whatever the
        // receiver's heading.
        let aligned_pose = receiver_reported.compose(&aligned.estimate.pose);
        let target = Pose2::new(
            aligned_pose.position_m() - raw.position_m(),
            wrap_angle(aligned_pose.heading_rad() - raw.heading_rad()),
        );
        self.smooth_toward(&target, w);
    }

    /// Moves the correction (identity before the first) a share `w` of the
    /// way to `target`, the heading along the shorter turn.
    fn smooth_toward(&mut self, target: &Pose2, w: f64) {
        let old = self.offset.unwrap_or_else(Pose2::identity);
        let t = old.position_m() + (target.position_m() - old.position_m()) * w;
        let turn = wrap_angle(target.heading_rad() - old.heading_rad());
        self.offset = Some(Pose2::new(t, old.heading_rad() + w * turn));
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::geometry::{Cov2, Vec2};
    use crate::sensor::{Detection, PoseNoiseLabel, PoseNoiseLevel};
    use crate::v2x::testkit::{appearance, context, settings};

    /// No correction before the first estimate; a full step lands on the
    /// target, half a step halfway, turning the shorter way.
    #[test]
    fn the_correction_moves_toward_its_target_by_the_smoothing() {
        let raw = Pose2::new(Vec2::new(4.0, 2.0), 0.5);
        let mut c = PoseCorrection::default();
        assert!(c.apply(&raw).is_none());
        c.smooth_toward(&Pose2::new(Vec2::new(2.0, -2.0), 3.0), 0.5);
        let d = c.apply(&Pose2::identity()).unwrap();
        assert!((d.position_m() - Vec2::new(1.0, -1.0)).norm() < 1e-12);
        assert!((d.heading_rad() - 1.5).abs() < 1e-12);
        c.smooth_toward(&Pose2::new(Vec2::new(2.0, -2.0), 3.0), 1.0);
        let d = c.apply(&Pose2::identity()).unwrap();
        assert!((d.position_m() - Vec2::new(2.0, -2.0)).norm() < 1e-12);
        assert!((d.heading_rad() - 3.0).abs() < 1e-12);
        let moved = c.apply(&raw).unwrap();
        assert!((moved.position_m() - Vec2::new(6.0, 0.0)).norm() < 1e-12);
        // From 3.0 halfway to -3.0 the shorter way is through pi, not 0.
        c.smooth_toward(&Pose2::new(Vec2::new(2.0, -2.0), -3.0), 0.5);
        let d = c.apply(&Pose2::identity()).unwrap();
        assert!(
            (d.heading_rad().cos() + 1.0).abs() < 1e-9,
            "{}",
            d.heading_rad()
        );
    }

    /// Pairs that agree on where the sender really is move the correction
    /// there: the corrected reported pose is the true one; with the
    /// smoothing at 0 nothing moves.
    #[test]
    fn aligned_pairs_correct_the_senders_reported_pose() {
        let mut s = settings();
        s.v2x.association.pose_smoothing = 1.0;
        let gps = PoseNoiseLevel {
            label: PoseNoiseLabel::GPS,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.01,
            correlation_s: None,
        };
        let mut still = s.clone();
        still.v2x.association.pose_smoothing = 0.0;
        let truth = BTreeMap::new();
        let ctx = Context {
            levels: std::slice::from_ref(&gps),
            ..context(&s, &truth, 0, 0.0)
        };
        let sender = Pose2::new(Vec2::new(30.0, 5.0), 2.9);
        let raw = Pose2::new(Vec2::new(31.0, 4.2), 2.92);
        let objects = [
            (10.0, 2.0),
            (15.0, -6.0),
            (22.0, 9.0),
            (5.0, 12.0),
            (18.0, 3.0),
        ];
        let detection = |p: Vec2| Detection {
            position_m: p,
            cov_m2: Cov2::identity() * 1e-4,
            appearance: appearance("a"),
            motion: None,
        };
        let views = Views {
            ego: objects
                .iter()
                .map(|&(x, y)| detection(Vec2::new(x, y)))
                .collect(),
            ego_ids: (0..5).collect(),
            ego_truth: vec![None; 5],
            peer: objects
                .iter()
                .map(|&(x, y)| detection(sender.to_body(&Vec2::new(x, y))))
                .collect(),
            peer_ids: (10..15).collect(),
            peer_truth: vec![None; 5],
            peer_reported: raw,
            ego_claim: *ctx.level(),
            peer_claim: *ctx.level(),
        };
        let pairs: Vec<(u64, u64)> = (0..5).map(|k| (k, k + 10)).collect();
        let mut c = PoseCorrection::default();
        c.update(&ctx, &Pose2::identity(), &views, &pairs[..2], &raw);
        assert!(
            c.apply(&raw).is_none(),
            "fewer pairs than align_min_matches"
        );
        c.update(&ctx, &Pose2::identity(), &views, &pairs, &raw);
        let corrected = c.apply(&raw).unwrap();
        let (dp, dh) = (
            (corrected.position_m() - sender.position_m()).norm(),
            wrap_angle(corrected.heading_rad() - sender.heading_rad()).abs(),
        );
        assert!(dp < 0.01 && dh < 1e-3, "{dp} m, {dh} rad");
        let ctx = Context {
            v: &still.v2x,
            ..ctx
        };
        let mut off = PoseCorrection::default();
        off.update(&ctx, &Pose2::identity(), &views, &pairs, &raw);
        assert!(off.apply(&raw).is_none());
    }
}
