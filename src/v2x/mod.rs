//! Cooperation over time, as V2X delivers it (`[v2x]`). Its devices: each
//! connected vehicle's own tracker (`tracker`), Collective Perception
//! Messages generated from its tracks (`cpm`), a channel that delays and
//! loses them (`channel`), GNSS error correlated in time (`gnss`), and the
//! receivers' association of track ids over messages (`receiver`). Its
//! simulation, step by step ([`Context`], `context`): each vehicle tracks,
//! steps its GNSS (`sensor::gnss`) and sends (`vehicle`, `message`), the messages go over
//! the channel (`delivery`, `fleet`); a receiver keeps what it knows of each
//! peer (`peer`): both sides' views (`views`), the relative pose over time
//! (`relative_pose`), the association scored against the truth
//! (`pair_history`) and the fusion of what it associated (`estimates`).
//! `coid track`'s state over a run is `tracking`, with its counts
//! (`counts`); `[v2x] mode = "cpm"` runs make the messages that arrived
//! their instances' sides (`receptions`). `[v2x] mode = "ideal"` (the
//! default) uses none of them: a peer's detections arrive at once, at every
//! step.

pub mod channel;
mod context;
mod counts;
pub mod cpm;
mod delivery;
mod estimates;
mod fleet;
mod message;
mod pair_history;
mod peer;
pub mod receiver;
mod receptions;
mod relative_pose;
#[cfg(test)]
pub(crate) mod testkit;
pub mod tracker;
mod tracking;
mod vehicle;
mod views;

pub(crate) use context::{Sensing, Setup, true_centres};
pub use counts::{OverTimeCounts, VehicleTracking};
pub use message::ViewSource;
pub(crate) use receptions::{ReceptionSide, Receptions};
pub use tracking::TrackResults;
pub(crate) use tracking::Tracking;

use nalgebra::{Matrix4, Vector4};

use crate::geometry::{Cov2, Vec2};
use crate::matching::Method;
use crate::sensor::PoseNoiseLabel;

crate::label_enum! { "v2x mode";
    /// How peers' perception reaches a vehicle.
    pub enum V2xMode {
        /// At once, at every step (no trackers, messages or channel).
        #[strum(serialize = "ideal")]
        Ideal,
        /// Tracks sent as CPMs over a lossy, delayed channel.
        #[strum(serialize = "cpm")]
        Cpm,
    }
}

/// `[v2x]`.
#[derive(Clone, PartialEq)]
pub struct V2xSettings {
    pub mode: V2xMode,
    /// SUMO's step (the camera frame period) for `coid track` and the
    /// `cpm` mode (s); the `ideal` mode keeps the scenario's.
    pub step_length_s: f64,
    /// Correlation time of the GNSS error (s), in both modes; 0:
    /// independent per step.
    pub gnss_correlation_s: f64,
    /// The GNSS heading error grows at low speed as `sigma_v / v` (course
    /// over ground), added in quadrature to the level's (m/s); 0: off.
    pub gnss_heading_speed_sigma_mps: f64,
    /// The frame matcher each receiver runs on every message.
    pub matcher: Method,
    /// The GNSS accuracy (one of the configured levels).
    pub pose_noise: PoseNoiseLabel,
    /// Whether receivers move received objects ahead to their own time.
    pub compensate_latency: bool,
    pub tracker: tracker::TrackerSettings,
    pub cpm: cpm::CpmSettings,
    pub channel: channel::ChannelSettings,
    pub association: receiver::AssociationSettings,
}

/// As derived, but `gnss_heading_speed_sigma_mps` is shown only when it
/// is on: a config's digest hashes this text, and configs from before it
/// existed keep their digest (and their batches and exports).
impl std::fmt::Debug for V2xSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("V2xSettings");
        d.field("mode", &self.mode)
            .field("step_length_s", &self.step_length_s)
            .field("gnss_correlation_s", &self.gnss_correlation_s);
        if self.gnss_heading_speed_sigma_mps != 0.0 {
            d.field(
                "gnss_heading_speed_sigma_mps",
                &self.gnss_heading_speed_sigma_mps,
            );
        }
        d.field("matcher", &self.matcher)
            .field("pose_noise", &self.pose_noise)
            .field("compensate_latency", &self.compensate_latency)
            .field("tracker", &self.tracker)
            .field("cpm", &self.cpm)
            .field("channel", &self.channel)
            .field("association", &self.association)
            .finish()
    }
}

impl Default for V2xSettings {
    fn default() -> Self {
        Self {
            mode: V2xMode::Ideal,
            step_length_s: 0.1,
            gnss_correlation_s: 0.0,
            gnss_heading_speed_sigma_mps: 0.0,
            matcher: Method::GpsAppHungarian,
            pose_noise: PoseNoiseLabel::GPS,
            compensate_latency: true,
            tracker: tracker::TrackerSettings::default(),
            cpm: cpm::CpmSettings::default(),
            channel: channel::ChannelSettings::default(),
            association: receiver::AssociationSettings::default(),
        }
    }
}

/// Latency compensation: a received object moved `dt_s` ahead with its
/// velocity, its covariance grown by the motion model (white-noise
/// acceleration `accel_sigma_mps2`; position and velocity taken as
/// uncorrelated, as a CPM carries them). Exact in the mean for
/// constant-velocity motion.
pub fn extrapolate(
    position_m: Vec2,
    velocity_mps: Vec2,
    position_cov_m2: &Cov2,
    velocity_cov_m2ps2: &Cov2,
    dt_s: f64,
    accel_sigma_mps2: f64,
) -> (Vec2, Cov2) {
    let x = Vector4::new(position_m.x, position_m.y, velocity_mps.x, velocity_mps.y);
    let mut p = Matrix4::zeros();
    p.fixed_view_mut::<2, 2>(0, 0).copy_from(position_cov_m2);
    p.fixed_view_mut::<2, 2>(2, 2).copy_from(velocity_cov_m2ps2);
    let (x, p) = tracker::predict(&x, &p, dt_s, accel_sigma_mps2);
    (
        Vec2::new(x[0], x[1]),
        p.fixed_view::<2, 2>(0, 0).into_owned(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// For an object at constant velocity, the extrapolated position is
    /// where it is after the latency; the covariance grows with the
    /// velocity's uncertainty.
    #[test]
    fn latency_compensation_is_exact_for_constant_velocity() {
        let (p0, v) = (Vec2::new(5.0, -2.0), Vec2::new(12.0, 3.0));
        for dt in [0.0, 0.1, 0.3] {
            let truth = p0 + v * dt;
            let (p, c) = extrapolate(
                p0,
                v,
                &(Cov2::identity() * 0.25),
                &(Cov2::identity() * 4.0),
                dt,
                2.0,
            );
            assert!((p - truth).norm() < 1e-12, "{dt}");
            let expected = 0.25 + 4.0 * dt * dt + 4.0 * dt.powi(4) / 4.0;
            assert!((c[(0, 0)] - expected).abs() < 1e-12, "{dt}: {c}");
        }
    }
}
