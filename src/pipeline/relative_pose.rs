//! The relative pose of a peer estimated over time ([`PoseCorrection`]): a
//! world-frame correction of the sender's reported pose (the two GNSS
//! errors, slowly varying when they are correlated in time), moved toward
//! each reception's alignment of the pairs associated over time by
//! `[v2x.association] pose_smoothing` (0: off, each message's reported
//! poses alone).

use super::context::Context;
use super::fusion_over_time::measurement;
use super::peer::Views;
use crate::fusion::{Measurement, align, relative_pose_prior};
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
        let prior = relative_pose_prior(
            receiver_reported,
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
