//! What one step of cooperation over time shares ([`Context`]): the slices
//! of the settings it reads ([`Setup`]), the time and every road user's
//! true centre; what each vehicle brings to it ([`Sensing`]); and latency
//! compensation, what was received moved ahead to that time.

use std::collections::BTreeMap;

use super::V2xSettings;
use super::cpm::PerceivedObject;
use crate::geometry::{Cov2, Vec2};
use crate::sensor::{LinkSettings, PoseNoiseLevel, Sensed};
use crate::traffic::TrafficFrame;

/// Every road user's true centre at `frame`, world frame, by id.
pub(crate) fn true_centres(frame: &TrafficFrame) -> BTreeMap<&str, Vec2> {
    frame
        .objects
        .iter()
        .map(|o| (o.id.as_str(), o.pose.position_m()))
        .collect()
}

/// What cooperation over time reads of the settings, the same at every
/// step of a run.
#[derive(Clone, Copy)]
pub(crate) struct Setup<'a> {
    /// `[v2x]`.
    pub v: &'a V2xSettings,
    /// Which connected vehicles exchange (`[connected]`).
    pub link: &'a LinkSettings,
    /// The sensor seed, which keys the channel's and the GNSS's streams.
    pub sensor_seed: u64,
    /// `[fusion] align_min_matches`, for the relative pose over time.
    pub align_min_matches: usize,
    /// The GNSS accuracies each vehicle's error is drawn at: `[v2x]
    /// pose_noise` alone for `coid track` (its receivers use the first),
    /// every `[pose_noise]` level in a run.
    pub levels: &'a [PoseNoiseLevel],
}

impl<'a> Setup<'a> {
    /// The context of step `step` at `time_s`, where the road users are
    /// `truth`.
    pub(crate) fn at(
        self,
        step: u64,
        time_s: f64,
        truth: &'a BTreeMap<&'a str, Vec2>,
    ) -> Context<'a> {
        Context {
            v: self.v,
            link: self.link,
            sensor_seed: self.sensor_seed,
            align_min_matches: self.align_min_matches,
            levels: self.levels,
            step,
            time_s,
            truth,
        }
    }
}

/// What one step shares.
pub(crate) struct Context<'a> {
    pub v: &'a V2xSettings,
    pub link: &'a LinkSettings,
    pub sensor_seed: u64,
    pub align_min_matches: usize,
    /// The GNSS accuracies of [`Setup::levels`].
    pub levels: &'a [PoseNoiseLevel],
    pub step: u64,
    pub time_s: f64,
    /// Every road user's true centre, world frame.
    pub truth: &'a BTreeMap<&'a str, Vec2>,
}

/// What one connected vehicle near the junction brings to a step: its id,
/// the hash of its id (a key of its streams), what it sensed (its true
/// pose, its detections, what its cameras could see) and its speed (m/s).
#[derive(Clone, Copy)]
pub(crate) struct Sensing<'a> {
    pub id: &'a str,
    pub id_hash: u64,
    pub sensed: &'a Sensed,
    pub speed_mps: f64,
}

impl Context<'_> {
    /// The GNSS accuracy `coid track`'s receivers work at.
    pub(super) fn level(&self) -> &PoseNoiseLevel {
        &self.levels[0]
    }

    /// Latency compensation: a point a sender generated at `generated_s`
    /// (position and velocity with their covariances, in the sender's
    /// frame) moved ahead to this step with its velocity when `[v2x]
    /// compensate_latency` ([`super::extrapolate`], the trackers' motion
    /// model), or left where it was.
    pub(super) fn moved_ahead(
        &self,
        generated_s: f64,
        position_m: Vec2,
        velocity_mps: Vec2,
        position_cov_m2: &Cov2,
        velocity_cov_m2ps2: &Cov2,
    ) -> (Vec2, Cov2) {
        let dt_s = if self.v.compensate_latency {
            self.time_s - generated_s
        } else {
            0.0
        };
        super::extrapolate(
            position_m,
            velocity_mps,
            position_cov_m2,
            velocity_cov_m2ps2,
            dt_s,
            self.v.tracker.accel_sigma_mps2,
        )
    }

    /// A received object of a message generated at `generated_s`, moved
    /// ahead to this step ([`Context::moved_ahead`]).
    pub(super) fn object_moved_ahead(&self, o: &PerceivedObject, generated_s: f64) -> (Vec2, Cov2) {
        self.moved_ahead(
            generated_s,
            o.position_m,
            o.velocity_mps,
            &o.position_cov_m2,
            &o.velocity_cov_m2ps2,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::v2x::testkit::{context, frame, settings};

    #[test]
    fn the_true_centres_are_every_road_users_position_by_id() {
        let f = frame(
            &[("b", Vec2::new(2.0, 1.0)), ("a", Vec2::new(-3.0, 1.0))],
            0,
        );
        let c = true_centres(&f);
        assert_eq!(c.len(), 2);
        assert_eq!(
            (c["a"], c["b"]),
            (Vec2::new(-3.0, 1.0), Vec2::new(2.0, 1.0))
        );
    }

    /// With latency compensation, what was generated 0.3 s ago moves 0.3 s
    /// along its velocity and grows uncertain; without, it stays as sent.
    #[test]
    fn what_was_received_is_moved_ahead_by_its_age_when_compensating() {
        let mut s = settings();
        let truth = BTreeMap::new();
        let (p, v) = (Vec2::new(10.0, -2.0), Vec2::new(5.0, 1.0));
        let (pc, vc) = (Cov2::identity() * 0.25, Cov2::identity());
        let ctx = context(&s, &truth, 13, 1.3);
        assert_eq!(ctx.level().label, s.pose_noise[0].label);
        let (moved, cov) = ctx.moved_ahead(1.0, p, v, &pc, &vc);
        assert!((moved - (p + v * 0.3)).norm() < 1e-9);
        assert!(cov[(0, 0)] > pc[(0, 0)] + 0.3 * 0.3 - 1e-9);
        let o = PerceivedObject {
            local_id: 1,
            position_m: p,
            velocity_mps: v,
            position_cov_m2: pc,
            velocity_cov_m2ps2: vc,
            age_s: 2.0,
            class: crate::traffic::ObjectClass::Car,
        };
        assert_eq!(ctx.object_moved_ahead(&o, 1.0), (moved, cov));
        s.v2x.compensate_latency = false;
        let ctx = context(&s, &truth, 13, 1.3);
        assert_eq!(ctx.moved_ahead(1.0, p, v, &pc, &vc), (p, pc));
    }
}
