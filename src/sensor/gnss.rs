//! The GNSS error of a vehicle's reported pose, every model of it in one
//! place: independent Gaussian errors per step at a pose-noise level
//! ([`reported_pose`]), or errors correlated in time, a first-order
//! Gauss-Markov process per axis (x, y, heading), `e(t + dt) = a e(t) +
//! sqrt(1 - a²) sigma w`, `a = exp(-dt / tau)`, started from its
//! stationary distribution, so that every step has the level's sigma and
//! errors decorrelate over `tau` (a level's `correlation_s`, else `[v2x]
//! gnss_correlation_s`; 0, the default, gives independent errors per
//! step).
//!
//! The `cpm` mode steps the process frame by frame ([`next_error`]); the
//! `ideal` mode, which senses only at sampled steps, takes it as a pure
//! function of the vehicle, the level and the time ([`drift_error`]). In
//! both, the heading error may grow at low speed ([`at_speed`]).

use rand::Rng;
use rand_distr::{Distribution, Normal, StandardNormal};

use crate::geometry::{Pose2, Vec2};
use crate::rng::{self, Purpose};
use crate::sensor::PoseNoiseLevel;

/// The pose a vehicle's GPS reports: the true pose plus independent Gaussian
/// errors on x, y and heading at the given level.
pub fn reported_pose(truth: &Pose2, level: &PoseNoiseLevel, rng: &mut impl Rng) -> Pose2 {
    let n = |sigma: f64, rng: &mut _| {
        if sigma > 0.0 {
            Normal::new(0.0, sigma)
                .map(|d| d.sample(rng))
                .unwrap_or(0.0)
        } else {
            0.0
        }
    };
    let dx = n(level.position_sigma_m, rng);
    let dy = n(level.position_sigma_m, rng);
    let dh = n(level.heading_sigma_rad, rng);
    Pose2::new(
        truth.position_m() + Vec2::new(dx, dy),
        truth.heading_rad() + dh,
    )
}

/// The stream of a vehicle's GNSS draws at `step` and `level` (named by
/// the seed, the step, the vehicle and the level: the same whichever other
/// vehicles or levels were drawn).
pub fn stream(
    seed: u64,
    step: u64,
    vehicle_hash: u64,
    level: &PoseNoiseLevel,
) -> rand_chacha::ChaCha8Rng {
    rng::stream(
        seed,
        Purpose::PoseNoise,
        &[step, vehicle_hash, level.label.stream_code()],
    )
}

/// The pose the white model reports for a vehicle at `step` and `level`
/// ([`reported_pose`] from the vehicle's own [`stream`]).
pub fn white_pose(
    seed: u64,
    step: u64,
    vehicle_hash: u64,
    level: &PoseNoiseLevel,
    truth: &Pose2,
) -> Pose2 {
    reported_pose(truth, level, &mut stream(seed, step, vehicle_hash, level))
}

/// A vehicle at one step, as its GNSS draws name it.
#[derive(Clone, Copy, Debug)]
pub struct VehicleAt {
    pub seed: u64,
    pub step: u64,
    pub time_s: f64,
    pub vehicle_hash: u64,
    /// Its speed over ground (m/s): the heading error may grow below it.
    pub speed_mps: f64,
}

/// The pose a vehicle reports at every level of `levels` when the `ideal`
/// mode draws them at sensing: each level drifting over its correlation
/// time (a level's own, else `default_tau_s`) or white, its heading error
/// grown at low speed by `speed_sigma_mps`; `None` when every level is
/// white and the heading error fixed (the pose is then drawn when asked,
/// [`white_pose`]: the shipped results).
pub fn ideal_poses(
    at: VehicleAt,
    levels: &[PoseNoiseLevel],
    default_tau_s: f64,
    speed_sigma_mps: f64,
    truth: &Pose2,
) -> Option<Vec<(crate::sensor::PoseNoiseLabel, Pose2)>> {
    let drifts = levels.iter().any(|l| l.correlation_s(default_tau_s) > 0.0);
    if !drifts && speed_sigma_mps == 0.0 {
        return None;
    }
    let poses = levels.iter().map(|level| {
        let tau_s = level.correlation_s(default_tau_s);
        let level = at_speed(level, at.speed_mps, speed_sigma_mps);
        let pose = if tau_s > 0.0 {
            drift_error(at.seed, at.vehicle_hash, &level, at.time_s, tau_s).apply(truth)
        } else {
            white_pose(at.seed, at.step, at.vehicle_hash, &level, truth)
        };
        (level.label, pose)
    });
    Some(poses.collect())
}

/// Below this speed a course-over-ground heading is as bad as at it
/// (m/s; GNSS receivers call course over ground erratic below about 0.75
/// kn).
pub const MIN_HEADING_SPEED_MPS: f64 = 0.4;

/// The drift's grid: this share of the correlation time, at least 0.1 s.
const DRIFT_TICKS_PER_TAU: f64 = 50.0;

/// `level` at a vehicle's speed: its heading sigma and course over
/// ground's `speed_sigma_mps / max(v, MIN_HEADING_SPEED_MPS)` in
/// quadrature. Perfect self-localisation (both sigmas 0) stays perfect;
/// `speed_sigma_mps = 0` gives the level itself.
pub fn at_speed(level: &PoseNoiseLevel, speed_mps: f64, speed_sigma_mps: f64) -> PoseNoiseLevel {
    if speed_sigma_mps <= 0.0 || (level.position_sigma_m == 0.0 && level.heading_sigma_rad == 0.0) {
        return *level;
    }
    let course = speed_sigma_mps / speed_mps.abs().max(MIN_HEADING_SPEED_MPS);
    PoseNoiseLevel {
        heading_sigma_rad: level.heading_sigma_rad.hypot(course),
        ..*level
    }
}

/// The GNSS error of vehicle `vehicle_hash` at `level` and `time_s`,
/// drifting with correlation time `tau_s > 0`: per axis the level's sigma
/// times a unit Gauss-Markov process ([`rng::gauss_markov_at`] on a grid
/// of `tau_s / 50`, at least 0.1 s), named by seed, vehicle, level and
/// axis, so that it is the same whichever steps were sensed before.
pub fn drift_error(
    seed: u64,
    vehicle_hash: u64,
    level: &PoseNoiseLevel,
    time_s: f64,
    tau_s: f64,
) -> GnssError {
    let tick_s = (tau_s / DRIFT_TICKS_PER_TAU).max(0.1);
    let unit = |axis: u64| {
        let code = level.label.stream_code();
        let base = rng::key(&[seed, Purpose::GnssDrift as u64, vehicle_hash, code, axis]);
        rng::gauss_markov_at(base, time_s, tau_s, tick_s)
    };
    GnssError {
        position_m: Vec2::new(
            level.position_sigma_m * unit(0),
            level.position_sigma_m * unit(1),
        ),
        heading_rad: level.heading_sigma_rad * unit(2),
    }
}

/// A vehicle's GNSS error at one time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GnssError {
    pub position_m: Vec2,
    pub heading_rad: f64,
}

impl GnssError {
    /// The pose the GNSS reports for `truth`.
    pub fn apply(&self, truth: &Pose2) -> Pose2 {
        Pose2::new(
            truth.position_m() + self.position_m,
            truth.heading_rad() + self.heading_rad,
        )
    }
}

/// The error `dt_s` after `previous` (or a first one, stationary), with
/// correlation time `tau_s`; draws three normals, always.
pub fn next_error(
    previous: Option<GnssError>,
    dt_s: f64,
    tau_s: f64,
    level: &PoseNoiseLevel,
    rng: &mut impl Rng,
) -> GnssError {
    let mut w = || -> f64 { StandardNormal.sample(rng) };
    let (wx, wy, wh) = (w(), w(), w());
    let a = match previous {
        Some(_) if tau_s > 0.0 => (-dt_s.max(0.0) / tau_s).exp(),
        _ => 0.0,
    };
    let b = (1.0 - a * a).sqrt();
    let prev = previous.unwrap_or_default();
    let (sp, sh) = (level.position_sigma_m, level.heading_sigma_rad);
    GnssError {
        position_m: Vec2::new(
            a * prev.position_m.x + b * sp * wx,
            a * prev.position_m.y + b * sp * wy,
        ),
        heading_rad: a * prev.heading_rad + b * sh * wh,
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::sensor::PoseNoiseLabel;

    /// The ideal mode's drift: the level's sigma at any time, correlation
    /// exp(-lag / tau) between two times, the same value whenever asked.
    #[test]
    fn the_drift_keeps_sigma_and_correlates_over_tau() {
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::GPS,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.0035,
            correlation_s: None,
        };
        let tau = 30.0;
        let n = 3000u64;
        let at = |v: u64, t: f64| drift_error(5, v, &level, t, tau).position_m.x;
        let x0: Vec<f64> = (0..n).map(|v| at(v, 200.0)).collect();
        let var = x0.iter().map(|x| x * x).sum::<f64>() / n as f64;
        assert!((var.sqrt() - 1.2).abs() < 0.06, "sigma {}", var.sqrt());
        for (lag, expect) in [(3.0, (-0.1f64).exp()), (30.0, (-1f64).exp()), (300.0, 0.0)] {
            let c = (0..n)
                .map(|v| x0[v as usize] * at(v, 200.0 + lag))
                .sum::<f64>()
                / n as f64
                / var;
            assert!((c - expect).abs() < 0.06, "lag {lag}: {c} vs {expect}");
        }
        assert_eq!(at(9, 12.5), at(9, 12.5));
    }

    /// Course over ground: the heading sigma grows as sigma_v / v below a
    /// walking pace's floor; perfect self-localisation stays perfect.
    #[test]
    fn the_heading_error_grows_at_low_speed() {
        let gps = PoseNoiseLevel {
            label: PoseNoiseLabel::GPS,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.2f64.to_radians(),
            correlation_s: None,
        };
        let at = |v: f64| at_speed(&gps, v, 0.05).heading_sigma_rad;
        assert!((at(100.0 / 3.6) - gps.heading_sigma_rad).abs() < 0.001);
        assert!(
            (at(10.0 / 3.6).to_degrees() - 1.02).abs() < 0.05,
            "{}",
            at(10.0 / 3.6).to_degrees()
        );
        assert_eq!(at(0.0), at(MIN_HEADING_SPEED_MPS));
        assert!(at(0.0) > at(1.0));
        assert_eq!(at_speed(&gps, 0.0, 0.0), gps);
        let none = PoseNoiseLevel {
            label: PoseNoiseLabel::NONE,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
            correlation_s: None,
        };
        assert_eq!(at_speed(&none, 0.0, 0.05), none);
    }

    /// The process keeps the level's sigma at every step and its lag
    /// correlation is exp(-dt / tau); tau = 0 is white.
    #[test]
    fn gauss_markov_keeps_sigma_and_correlates_over_tau() {
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::GPS,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.0035,
            correlation_s: None,
        };
        let series = |tau: f64| {
            let mut r = ChaCha8Rng::seed_from_u64(3);
            let mut e = None;
            (0..200_000)
                .map(|_| {
                    let n = next_error(e, 0.1, tau, &level, &mut r);
                    e = Some(n);
                    n.position_m.x
                })
                .collect::<Vec<f64>>()
        };
        for (tau, expect) in [(2.0, (-0.1f64 / 2.0).exp()), (0.0, 0.0)] {
            let x = series(tau);
            let n = x.len() as f64;
            let var = x.iter().map(|v| v * v).sum::<f64>() / n;
            let lag = x.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (n - 1.0) / var;
            assert!(
                (var.sqrt() - 1.2).abs() < 0.04,
                "tau {tau}: sigma {}",
                var.sqrt()
            );
            assert!(
                (lag - expect).abs() < 0.02,
                "tau {tau}: lag {lag} vs {expect}"
            );
        }
    }
}

#[cfg(test)]
mod level_tests {
    use super::*;
    use crate::sensor::PoseNoiseLabel;

    /// In the `ideal` mode a level drifts over its own correlation time
    /// while another stays white; with no level drifting and a fixed
    /// heading error, the poses are drawn when asked (`None`).
    #[test]
    fn each_level_drifts_over_its_own_correlation_time() {
        let white = PoseNoiseLevel {
            label: PoseNoiseLabel::GPS,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.01,
            correlation_s: None,
        };
        let drifting = PoseNoiseLevel {
            label: PoseNoiseLabel::RTK,
            correlation_s: Some(20.0),
            ..white
        };
        let truth = Pose2::new(Vec2::new(10.0, -4.0), 0.3);
        let at = VehicleAt {
            seed: 5,
            step: 40,
            time_s: 4.0,
            vehicle_hash: 77,
            speed_mps: 8.0,
        };
        assert_eq!(ideal_poses(at, &[white], 0.0, 0.0, &truth), None);
        let poses = ideal_poses(at, &[white, drifting], 0.0, 0.0, &truth).unwrap();
        assert_eq!(
            poses[0],
            (white.label, white_pose(5, 40, 77, &white, &truth))
        );
        let drift = drift_error(5, 77, &drifting, 4.0, 20.0).apply(&truth);
        assert_eq!(poses[1], (drifting.label, drift));
        // A step later the drifting level has barely moved; the white one
        // is drawn afresh.
        let later = ideal_poses(
            VehicleAt {
                step: 41,
                time_s: 4.1,
                ..at
            },
            &[white, drifting],
            0.0,
            0.0,
            &truth,
        )
        .unwrap();
        let moved = |a: &Pose2, b: &Pose2| (a.position_m() - b.position_m()).norm();
        assert!(moved(&later[1].1, &poses[1].1) < 0.2 * moved(&later[0].1, &poses[0].1));
    }
}
