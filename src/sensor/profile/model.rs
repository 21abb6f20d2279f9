//! A profile's parameters, their checks, the error scale calibrated per
//! range bin, and the error model: bias, Student-t tails, a persistent
//! part, along and across the line of sight.

use rand::Rng;
use rand_distr::{Distribution, StudentT};

use super::Mount;
use crate::geometry::{Cov2, Vec2};
use crate::rng::{self, Purpose};
use crate::sensor::CameraSettings;
use crate::traffic::ObjectClass;

/// The grid the persistent error is sampled on (seconds).
pub(super) const PERSISTENT_TICK_S: f64 = 0.1;

/// More sensors per vehicle than this are refused.
const MAX_SENSORS: usize = 16;

/// More clutter per sensor and frame than this is refused (each is a node
/// of every graph).
const MAX_CLUTTER_PER_FRAME: f64 = 100.0;

/// Farther sensing ranges than this are refused (metres; the longest
/// automotive lidars reach a few hundred).
const MAX_RANGE_M: f64 = 10_000.0;

/// The Student-t's degrees of freedom at most (beyond, it is Gaussian to
/// every digit that matters; `inf` has no sample).
const MAX_TAIL_DOF: f64 = 1e6;

/// `depth_to_lateral` within this factor of 1 either way.
const MAX_AXIS_RATIO: f64 = 1000.0;

/// Samples per bin when the error scale is calibrated to the published
/// mean translation error.
const CALIBRATION_SAMPLES: usize = 20_000;

/// The parameters of one profile (`[detector.camera]`, `[detector.lidar]`),
/// as published; see the config for each figure's source.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ProfileParams {
    /// Horizontal field of view of each sensor (a full turn: a rotating
    /// lidar).
    pub(crate) fov_rad: f64,
    /// Nothing farther is detected (metres).
    pub(crate) range_m: f64,
    /// Height of the sensor above the ground (metres).
    pub(crate) height_m: f64,
    pub(crate) mount: Mount,
    /// One sensor per entry, yawed from the vehicle's heading.
    pub(crate) yaw_offsets_rad: Vec<f64>,
    /// Upper edges of the range bins (metres, ascending; the last is at
    /// least `range_m`).
    pub(crate) bin_edges_m: Vec<f64>,
    /// Recall of a fully visible object per bin.
    pub(crate) recall: Vec<f64>,
    /// Mean translation error (the distance between the detected and the
    /// true centre, as nuScenes' ATE) per bin, of fully visible objects.
    pub(crate) mean_error_m: Vec<f64>,
    /// The error's standard deviation along the line of sight over that
    /// across it.
    pub(crate) depth_to_lateral: f64,
    /// Depth bias as a share of the range (positive: too far).
    pub(crate) depth_bias_per_m: f64,
    /// Degrees of freedom of the per-frame error's Student-t (> 2; the
    /// smaller, the heavier the tails).
    pub(crate) tail_dof: f64,
    /// Share of the random error's variance that persists over time.
    pub(crate) persistent_share: f64,
    /// Correlation time of the persistent part (seconds).
    pub(crate) correlation_time_s: f64,
    /// A partly hidden object's centre moves towards the sensor by this
    /// share of the hidden part of its extent along the line of sight.
    pub(crate) partial_shift: f64,
    /// Recall falls by this share of the hidden part of the footprint.
    pub(crate) occlusion_recall_loss: f64,
    /// Mean number of clutter detections per sensor and frame (Poisson).
    pub(crate) false_positives_per_frame: f64,
    /// Probability that a detection comes with a duplicate (a second box
    /// on the same object, its own per-frame error).
    pub(crate) duplicate_prob: f64,
    /// Probability that a detection comes with a ghost beside the object.
    pub(crate) ghost_prob: f64,
    /// A ghost's distance from the object's centre (metres): uniform in
    /// this range, in a uniform direction.
    pub(crate) ghost_distance_m: [f64; 2],
    /// Row: the true class; column: the reported class (both in
    /// [`ObjectClass::ALL`]'s order); rows sum to 1.
    pub(crate) class_confusion: [[f64; 7]; 7],
    /// Whether the detector sees colour (a lidar does not: its detections
    /// report a neutral grey).
    pub(crate) sees_colour: bool,
    /// The errors of the boxes' heading and speed.
    pub(crate) boxes: crate::sensor::boxes::BoxErrors,
}

/// A profile ready to sense: its parameters and the error scale per bin
/// that makes the simulated mean translation error the published one.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ProfileModel {
    pub(crate) params: ProfileParams,
    /// Per bin: the random error's scale (metres; the per-axis standard
    /// deviation of an isotropic error).
    scale_m: Vec<f64>,
    /// The sensors: the profile's own (one per yaw offset), or a rig's
    /// (`[detector.rigs]`).
    sensors: Vec<RigSensor>,
}

/// One sensor of a rig: its field of view, range, height and yaw (the
/// visibility test's geometry; `yaw_offsets_rad` holds its one yaw) and
/// where it sits on the vehicle. Each sensor tests occlusion from its own
/// pose.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct RigSensor {
    pub(crate) geometry: CameraSettings,
    pub(crate) mount: Mount,
}

impl RigSensor {
    /// The sensor's yaw against the vehicle's heading (radians).
    pub(crate) fn yaw_rad(&self) -> f64 {
        self.geometry
            .yaw_offsets_rad
            .first()
            .copied()
            .unwrap_or(0.0)
    }
}

/// Why a profile's parameters cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("{field}: {message}")]
pub(crate) struct ProfileError {
    pub(crate) field: &'static str,
    pub(crate) message: String,
}

fn invalid(field: &'static str, message: String) -> ProfileError {
    ProfileError { field, message }
}

impl ProfileModel {
    /// Checks the parameters and calibrates the error scale of each bin
    /// so that the mean translation error of a fully visible object in the
    /// bin's middle is the published one (seeded Monte Carlo: the same
    /// parameters always give the same scale).
    pub(crate) fn new(params: ProfileParams) -> Result<ProfileModel, ProfileError> {
        check_geometry(&params)?;
        check_bins(&params)?;
        check_errors(&params)?;
        let p = &params;
        let scale_m = (0..p.bin_edges_m.len())
            .map(|b| {
                let lo = if b == 0 { 0.0 } else { p.bin_edges_m[b - 1] };
                let hi = p.bin_edges_m[b].min(p.range_m.max(lo));
                calibrate_scale(p, 0.5 * (lo + hi), p.mean_error_m[b])
                    .map_err(|m| invalid("mean_error_m", format!("bin {b}: {m}")))
            })
            .collect::<Result<_, _>>()?;
        let sensors = params
            .yaw_offsets_rad
            .iter()
            .map(|&yaw| RigSensor {
                geometry: CameraSettings {
                    fov_rad: params.fov_rad,
                    range_m: params.range_m,
                    height_m: params.height_m,
                    yaw_offsets_rad: vec![yaw],
                },
                mount: params.mount,
            })
            .collect();
        Ok(ProfileModel {
            params,
            scale_m,
            sensors,
        })
    }

    /// This profile's error model on another rig's sensors. Each sensor's
    /// range must lie within the profile's range bins (the recall and
    /// error of farther objects are not known).
    pub(crate) fn with_rig(&self, sensors: Vec<RigSensor>) -> Result<ProfileModel, ProfileError> {
        if sensors.is_empty() || sensors.len() > MAX_SENSORS {
            return Err(invalid(
                "sensors",
                format!("need 1 to {MAX_SENSORS} sensors"),
            ));
        }
        let reach = self.params.bin_edges_m.last().copied().unwrap_or(0.0);
        for (k, s) in sensors.iter().enumerate() {
            let g = &s.geometry;
            if g.fov_rad <= 0.0 || g.fov_rad.is_nan() || g.fov_rad > std::f64::consts::TAU + 1e-9 {
                return Err(invalid(
                    "sensors",
                    format!("sensor {k}: fov_deg must be in (0, 360]"),
                ));
            }
            if !(g.range_m > 0.0 && g.range_m <= reach + 1e-9) {
                return Err(invalid(
                    "sensors",
                    format!(
                        "sensor {k}: range_m must be in (0, {reach}] (the profile's range bins \
                         end there), got {}",
                        g.range_m
                    ),
                ));
            }
            if !(0.0..=100.0).contains(&g.height_m) || g.yaw_offsets_rad.len() != 1 {
                return Err(invalid(
                    "sensors",
                    format!("sensor {k}: height_m must be in [0, 100]"),
                ));
            }
            if !yaw_is_usable(s.yaw_rad()) {
                return Err(invalid(
                    "sensors",
                    format!(
                        "sensor {k}: yaw_deg must be in [-360, 360], got {}",
                        s.yaw_rad().to_degrees()
                    ),
                ));
            }
        }
        Ok(ProfileModel {
            sensors,
            ..self.clone()
        })
    }

    /// The bin of a distance.
    pub(super) fn bin(&self, d_m: f64) -> usize {
        range_bin(&self.params.bin_edges_m, d_m)
    }

    /// The random error's per-axis scale at distance `d_m` (metres).
    pub(super) fn scale_at(&self, d_m: f64) -> f64 {
        self.scale_m[self.bin(d_m)]
    }

    /// The sensors, each with its geometry and mount.
    pub(crate) fn sensors(&self) -> &[RigSensor] {
        &self.sensors
    }

    /// Standard deviations (depth, lateral) of the random error at a
    /// distance: the scale split by `depth_to_lateral` so that the total
    /// variance is that of an isotropic error of the scale.
    pub(super) fn axis_sigmas(&self, d_m: f64) -> (f64, f64) {
        let s = self.scale_at(d_m);
        let (cd, cl) = axis_factors(self.params.depth_to_lateral);
        (s * cd, s * cl)
    }

    /// The covariance the detector reports for a detection measured at
    /// `p_sensor_m` (sensor frame): zero-mean Gaussian, the random error's
    /// second moments along and across the measured line of sight. It
    /// knows nothing of the bias, the tails or the persistence.
    pub(super) fn nominal_covariance(&self, p_sensor_m: &Vec2) -> Cov2 {
        let d = p_sensor_m.norm();
        let (sd, sl) = self.axis_sigmas(d);
        let rot = line_of_sight(p_sensor_m);
        rot * Cov2::new(sd * sd, 0.0, 0.0, sl * sl) * rot.transpose()
    }
}

/// `v` as a usable number in `lo..=hi` (`NaN` never is).
fn in_range(field: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), ProfileError> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(invalid(field, format!("must be in [{lo}, {hi}], got {v}")))
    }
}

/// Field of view, range, height, sensors.
fn check_geometry(p: &ProfileParams) -> Result<(), ProfileError> {
    if p.fov_rad <= 0.0 || p.fov_rad.is_nan() || p.fov_rad > std::f64::consts::TAU + 1e-9 {
        return Err(invalid("fov_deg", "must be in (0, 360]".into()));
    }
    if !(p.range_m > 0.0 && p.range_m <= MAX_RANGE_M) {
        return Err(invalid(
            "range_m",
            format!("must be in (0, {MAX_RANGE_M}], got {}", p.range_m),
        ));
    }
    in_range("height_m", p.height_m, 0.0, 100.0)?;
    if p.yaw_offsets_rad.is_empty() || p.yaw_offsets_rad.len() > MAX_SENSORS {
        return Err(invalid(
            "yaw_offsets_deg",
            format!("need 1 to {MAX_SENSORS} sensors"),
        ));
    }
    if let Some(y) = p.yaw_offsets_rad.iter().find(|y| !yaw_is_usable(**y)) {
        return Err(invalid(
            "yaw_offsets_deg",
            format!("each must be in [-360, 360], got {}", y.to_degrees()),
        ));
    }
    Ok(())
}

/// A sensor's yaw (radians): a number within one turn either way
/// (`NaN` never is).
fn yaw_is_usable(yaw_rad: f64) -> bool {
    yaw_rad.abs() <= std::f64::consts::TAU + 1e-9
}

/// Range bins, and one recall and mean error per bin.
fn check_bins(p: &ProfileParams) -> Result<(), ProfileError> {
    let n = p.bin_edges_m.len();
    if n == 0 {
        return Err(invalid("bin_edges_m", "need at least one bin".into()));
    }
    if p.recall.len() != n || p.mean_error_m.len() != n {
        return Err(invalid(
            "recall",
            format!(
                "recall ({}) and mean_error_m ({}) need one entry per bin ({n})",
                p.recall.len(),
                p.mean_error_m.len()
            ),
        ));
    }
    if p.bin_edges_m.windows(2).any(|w| w[1] <= w[0])
        || p.bin_edges_m[0] <= 0.0
        || !p.bin_edges_m[n - 1].is_finite()
    {
        return Err(invalid(
            "bin_edges_m",
            "bin edges must be positive, finite and ascending".into(),
        ));
    }
    if p.bin_edges_m[n - 1] < p.range_m {
        return Err(invalid(
            "bin_edges_m",
            format!(
                "the last bin ends at {} m, before range_m ({} m)",
                p.bin_edges_m[n - 1],
                p.range_m
            ),
        ));
    }
    for &r in &p.recall {
        in_range("recall", r, 0.0, 1.0)?;
    }
    for &e in &p.mean_error_m {
        if e <= 0.0 || !e.is_finite() {
            return Err(invalid(
                "mean_error_m",
                format!("each must be > 0, got {e}"),
            ));
        }
    }
    Ok(())
}

/// The error model, clutter and confusion.
fn check_errors(p: &ProfileParams) -> Result<(), ProfileError> {
    if !(p.tail_dof > 2.0 && p.tail_dof <= MAX_TAIL_DOF) {
        return Err(invalid(
            "tail_dof",
            format!(
                "must be in (2, {MAX_TAIL_DOF:e}] (> 2: finite variance; the larger, the \
                 closer to Gaussian), got {}",
                p.tail_dof
            ),
        ));
    }
    in_range(
        "depth_to_lateral",
        p.depth_to_lateral,
        1.0 / MAX_AXIS_RATIO,
        MAX_AXIS_RATIO,
    )?;
    in_range("depth_bias_per_m", p.depth_bias_per_m, -1.0, 1.0)?;
    in_range("correlation_time_s", p.correlation_time_s, 0.0, 1e6)?;
    if p.persistent_share > 0.0 && p.correlation_time_s == 0.0 {
        return Err(invalid(
            "correlation_time_s",
            "must be > 0 when persistent_share is".into(),
        ));
    }
    in_range("persistent_share", p.persistent_share, 0.0, 1.0)?;
    in_range("partial_shift", p.partial_shift, 0.0, 1.0)?;
    in_range("occlusion_recall_loss", p.occlusion_recall_loss, 0.0, 1.0)?;
    in_range("duplicate_prob", p.duplicate_prob, 0.0, 1.0)?;
    in_range("ghost_prob", p.ghost_prob, 0.0, 1.0)?;
    in_range(
        "false_positives_per_frame",
        p.false_positives_per_frame,
        0.0,
        MAX_CLUTTER_PER_FRAME,
    )?;
    in_range("ghost_distance_m", p.ghost_distance_m[0], 0.0, 1e3)?;
    in_range(
        "ghost_distance_m",
        p.ghost_distance_m[1],
        p.ghost_distance_m[0],
        1e3,
    )?;
    for (k, row) in p.class_confusion.iter().enumerate() {
        let sum: f64 = row.iter().sum();
        if row.iter().any(|v| v.is_nan() || *v < 0.0) || sum.is_nan() || (sum - 1.0).abs() > 1e-6 {
            return Err(invalid(
                "class_confusion",
                format!(
                    "row {k} ({}) must be non-negative and sum to 1, sums to {sum}",
                    ObjectClass::ALL[k].as_str()
                ),
            ));
        }
    }
    Ok(())
}

/// The range bin of distance `d_m` among bins with upper `edges_m`
/// (ascending, at least one): the first that reaches it, the last for
/// anything beyond.
pub(crate) fn range_bin(edges_m: &[f64], d_m: f64) -> usize {
    edges_m
        .iter()
        .position(|e| d_m <= *e)
        .unwrap_or(edges_m.len() - 1)
}

/// Per-axis factors (depth, lateral) with `cd / cl = ratio` and
/// `cd² + cl² = 2`.
fn axis_factors(ratio: f64) -> (f64, f64) {
    let cl = (2.0 / (1.0 + ratio * ratio)).sqrt();
    (ratio * cl, cl)
}

/// The rotation from (depth, lateral) axes to the sensor frame at a point.
pub(super) fn line_of_sight(p_sensor_m: &Vec2) -> nalgebra::Matrix2<f64> {
    let b = p_sensor_m.y.atan2(p_sensor_m.x);
    let (s, c) = b.sin_cos();
    nalgebra::Matrix2::new(c, -s, s, c)
}

/// A Student-t draw scaled to unit variance.
fn unit_student(dof: f64, rng: &mut impl Rng) -> f64 {
    let t: f64 = StudentT::new(dof)
        .map(|d| d.sample(rng))
        .unwrap_or_else(|_| rng.sample(rand_distr::StandardNormal));
    t * ((dof - 2.0) / dof).sqrt()
}

/// The unit-variance random error (depth, lateral) before scaling: the
/// persistent part (given) and a fresh heavy-tailed part, mixed by
/// `persistent_share`.
pub(super) fn unit_error(p: &ProfileParams, persistent: [f64; 2], rng: &mut impl Rng) -> [f64; 2] {
    let (a, b) = (p.persistent_share.sqrt(), (1.0 - p.persistent_share).sqrt());
    let fresh = [unit_student(p.tail_dof, rng), unit_student(p.tail_dof, rng)];
    [
        a * persistent[0] + b * fresh[0],
        a * persistent[1] + b * fresh[1],
    ]
}

/// The scale that makes the mean error norm at distance `d_m` (bias plus
/// the random error) equal `target_m`.
fn calibrate_scale(p: &ProfileParams, d_m: f64, target_m: f64) -> Result<f64, String> {
    let bias = p.depth_bias_per_m * d_m;
    if bias.abs() >= target_m {
        return Err(format!(
            "the depth bias alone ({:.3} m at {d_m:.1} m) reaches the mean error {target_m} m",
            bias.abs()
        ));
    }
    let mut rng = rng::stream(0, Purpose::PersistentError, &[u64::MAX]);
    let (cd, cl) = axis_factors(p.depth_to_lateral);
    let unit: Vec<[f64; 2]> = (0..CALIBRATION_SAMPLES)
        .map(|_| {
            let persistent = [
                rng.sample(rand_distr::StandardNormal),
                rng.sample(rand_distr::StandardNormal),
            ];
            let e = unit_error(p, persistent, &mut rng);
            [cd * e[0], cl * e[1]]
        })
        .collect();
    let mean_norm = |s: f64| {
        unit.iter()
            .map(|e| (bias + s * e[0]).hypot(s * e[1]))
            .sum::<f64>()
            / unit.len() as f64
    };
    // Monotone in s: bisect.
    let (mut lo, mut hi) = (0.0, 4.0 * target_m);
    while mean_norm(hi) < target_m {
        hi *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if mean_norm(mid) < target_m {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// The persistent part (depth, lateral; unit variance) of `observer`'s
/// error on `object` at `time_s`: a stationary AR(1) with correlation time
/// `tau_s` on the [`PERSISTENT_TICK_S`] grid ([`rng::gauss_markov_at`],
/// each axis named by seed, observer, object and axis), so that it is the
/// same whichever frames were sensed before.
pub(super) fn persistent_error(
    seed: u64,
    observer: &str,
    object: &str,
    time_s: f64,
    tau_s: f64,
) -> [f64; 2] {
    let (o, j) = (rng::hash_str(observer), rng::hash_str(object));
    [0u64, 1].map(|axis| {
        let base = rng::key(&[seed, Purpose::PersistentError as u64, o, j, axis]);
        rng::gauss_markov_at(base, time_s, tau_s, PERSISTENT_TICK_S)
    })
}
