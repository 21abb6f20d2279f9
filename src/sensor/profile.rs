//! Detector profiles: detections as real detectors make them, with errors
//! that are *not* what the matchers and the fusion assume.
//!
//! `paper` is the model of [`super::observe`] (Gaussian range and bearing
//! errors, fresh every frame, reported with the covariance they were drawn
//! from). `camera` (a monocular 3D detector) and `lidar` (a 360 deg
//! rotating lidar detector) take their recall and mean translation error
//! per range bin from published figures (`[detector.<profile>]`, with the
//! sources in the config's comments and `docs/detectors.md`), and their
//! errors depart from the matchers' assumption the way real detectors'
//! do:
//!
//! - a depth bias growing with range (the camera),
//! - heavy tails: the per-frame part is Student-t,
//! - a part that persists per (observer, object) over time: a stationary
//!   AR(1) (Ornstein-Uhlenbeck) process with a stated correlation time,
//!   sampled on a fixed 0.1 s grid, a pure function of its name (no state
//!   is carried between frames, so the error at a time does not depend on
//!   which frames were sensed before),
//! - a centre pulled towards the sensor when only part of the object is
//!   visible,
//! - duplicates and ghosts next to real objects, and class confusion by a
//!   matrix.
//!
//! Each detection reports the profile's *nominal* covariance: a zero-mean
//! Gaussian, white in time, of the error's second moments (what a real
//! detector would publish). The true error distribution stays here.

use std::collections::BTreeSet;

use rand::Rng;
use rand_distr::{Distribution, StudentT};

use super::{
    Appearance, CameraSettings, Detection, DetectionTruth, Sensed, SensorSettings, VisibleObject,
    clutter_count, clutter_look, clutter_point, false_positive, note_visible, observe_appearance,
    sensed_from, typical_size_m, visible_fraction,
};
use crate::geometry::{Cov2, Pose2, Vec2};
use crate::rng::{self, Purpose};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

crate::label_enum! { "detector profile";
    /// `[detector] profile`: how the connected vehicles' detectors make
    /// detections.
    #[strum(serialize_all = "lowercase")]
    pub enum DetectorProfile {
        /// The paper's model (`[camera]`, `[sensor]`): Gaussian range and
        /// bearing errors, fresh every frame, reported with exactly the
        /// covariance they were drawn from.
        Paper,
        /// A monocular 3D camera detector (`[detector.camera]`).
        Camera,
        /// A 360 deg rotating lidar detector (`[detector.lidar]`).
        Lidar,
    }
}

crate::label_enum! { "sensor mount";
    /// Where a profile's sensors sit on the vehicle.
    #[strum(serialize_all = "lowercase")]
    pub enum Mount {
        /// At the middle of the front bumper (a camera).
        Front,
        /// At the centre of the roof (a rotating lidar).
        Roof,
    }
}

/// The grid the persistent error is sampled on (seconds).
pub const PERSISTENT_TICK_S: f64 = 0.1;

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

/// `[detector]`: which profile the connected vehicles' detectors follow,
/// and the parameters of the two that are not the paper's.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorSettings {
    pub profile: DetectorProfile,
    /// A mixed fleet: each profile's share of the connected vehicles
    /// (summing to 1, in label order), drawn per vehicle id; empty: every
    /// vehicle carries `profile`.
    pub mix: Vec<(DetectorProfile, f64)>,
    /// Profiles by SUMO vehicle type id (`[detector] by_type`): a vehicle
    /// of a listed type carries its profile, whatever `mix` and `profile`
    /// say.
    pub by_type: Vec<(String, DetectorProfile)>,
    pub camera: ProfileModel,
    pub lidar: ProfileModel,
    /// Named rigs (`[detector.rigs]`): a profile's error model on sensors
    /// of their own.
    pub rigs: Vec<NamedRig>,
    /// Rigs by SUMO vehicle type id (`[detector] rig_by_type`): a vehicle
    /// of a listed type carries its rig, over `by_type`, `mix` and
    /// `profile`. Indices into `rigs`.
    pub rig_by_type: Vec<(String, usize)>,
}

/// A rig of `[detector.rigs]`.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedRig {
    pub name: String,
    /// Whose error model its sensors have.
    pub profile: DetectorProfile,
    pub model: ProfileModel,
}

impl DetectorSettings {
    /// The chosen profile's model (`None`: the paper's).
    pub fn model(&self) -> Option<&ProfileModel> {
        self.model_of(self.profile)
    }

    /// A profile's model (`None`: the paper's).
    pub fn model_of(&self, profile: DetectorProfile) -> Option<&ProfileModel> {
        match profile {
            DetectorProfile::Paper => None,
            DetectorProfile::Camera => Some(&self.camera),
            DetectorProfile::Lidar => Some(&self.lidar),
        }
    }

    /// The profile connected vehicle `vehicle_id` of SUMO type `type_id`
    /// carries: its type's (`by_type`), else in a mixed fleet one drawn by
    /// the vehicle's id (the same vehicle carries the same profile at
    /// every step), else `profile`.
    pub fn profile_of(&self, sensor_seed: u64, vehicle_id: &str, type_id: &str) -> DetectorProfile {
        if let Some((_, p)) = self.by_type.iter().find(|(t, _)| t == type_id) {
            return *p;
        }
        if self.mix.is_empty() {
            return self.profile;
        }
        let u = rng::unit(
            sensor_seed,
            Purpose::DetectorMix,
            &[rng::hash_str(vehicle_id)],
        );
        let mut acc = 0.0;
        for &(p, share) in &self.mix {
            acc += share;
            if u < acc {
                return p;
            }
        }
        self.mix.last().map_or(self.profile, |m| m.0)
    }

    /// The vehicle types `by_type` and `rig_by_type` name that are not
    /// among `seen` (the types of a run's road users), sorted, each once:
    /// those entries changed nothing.
    pub fn unused_types<'a>(&'a self, seen: &BTreeSet<String>) -> Vec<&'a str> {
        let named = self.by_type.iter().map(|(t, _)| t.as_str());
        let named = named.chain(self.rig_by_type.iter().map(|(t, _)| t.as_str()));
        let unused: BTreeSet<&str> = named.filter(|t| !seen.contains(*t)).collect();
        unused.into_iter().collect()
    }

    /// What connected vehicle `vehicle_id` of SUMO type `type_id` senses
    /// with: its type's rig (`rig_by_type`), else its profile's model
    /// ([`Self::profile_of`]); `None`: the paper's model.
    pub fn model_for(
        &self,
        sensor_seed: u64,
        vehicle_id: &str,
        type_id: &str,
    ) -> Option<&ProfileModel> {
        if let Some((_, k)) = self.rig_by_type.iter().find(|(t, _)| t == type_id) {
            return self.rigs.get(*k).map(|r| &r.model);
        }
        self.model_of(self.profile_of(sensor_seed, vehicle_id, type_id))
    }

    /// Whether every vehicle senses with the paper's model.
    pub fn is_paper(&self) -> bool {
        self.mix.is_empty()
            && self.by_type.is_empty()
            && self.rig_by_type.is_empty()
            && self.profile == DetectorProfile::Paper
    }
}

/// The parameters of one profile (`[detector.camera]`, `[detector.lidar]`),
/// as published; see the config for each figure's source.
#[derive(Clone, Debug, PartialEq)]
pub struct ProfileParams {
    /// Horizontal field of view of each sensor (a full turn: a rotating
    /// lidar).
    pub fov_rad: f64,
    /// Nothing farther is detected (metres).
    pub range_m: f64,
    /// Height of the sensor above the ground (metres).
    pub height_m: f64,
    pub mount: Mount,
    /// One sensor per entry, yawed from the vehicle's heading.
    pub yaw_offsets_rad: Vec<f64>,
    /// Upper edges of the range bins (metres, ascending; the last is at
    /// least `range_m`).
    pub bin_edges_m: Vec<f64>,
    /// Recall of a fully visible object per bin.
    pub recall: Vec<f64>,
    /// Mean translation error (the distance between the detected and the
    /// true centre, as nuScenes' ATE) per bin, of fully visible objects.
    pub mean_error_m: Vec<f64>,
    /// The error's standard deviation along the line of sight over that
    /// across it.
    pub depth_to_lateral: f64,
    /// Depth bias as a share of the range (positive: too far).
    pub depth_bias_per_m: f64,
    /// Degrees of freedom of the per-frame error's Student-t (> 2; the
    /// smaller, the heavier the tails).
    pub tail_dof: f64,
    /// Share of the random error's variance that persists over time.
    pub persistent_share: f64,
    /// Correlation time of the persistent part (seconds).
    pub correlation_time_s: f64,
    /// A partly hidden object's centre moves towards the sensor by this
    /// share of the hidden part of its extent along the line of sight.
    pub partial_shift: f64,
    /// Recall falls by this share of the hidden part of the footprint.
    pub occlusion_recall_loss: f64,
    /// Mean number of clutter detections per sensor and frame (Poisson).
    pub false_positives_per_frame: f64,
    /// Probability that a detection comes with a duplicate (a second box
    /// on the same object, its own per-frame error).
    pub duplicate_prob: f64,
    /// Probability that a detection comes with a ghost beside the object.
    pub ghost_prob: f64,
    /// A ghost's distance from the object's centre (metres): uniform in
    /// this range, in a uniform direction.
    pub ghost_distance_m: [f64; 2],
    /// Row: the true class; column: the reported class (both in
    /// [`ObjectClass::ALL`]'s order); rows sum to 1.
    pub class_confusion: [[f64; 7]; 7],
    /// Whether the detector sees colour (a lidar does not: its detections
    /// report a neutral grey).
    pub sees_colour: bool,
    /// The errors of the boxes' heading and speed.
    pub boxes: super::boxes::BoxErrors,
}

/// A profile ready to sense: its parameters and the error scale per bin
/// that makes the simulated mean translation error the published one.
#[derive(Clone, Debug, PartialEq)]
pub struct ProfileModel {
    pub params: ProfileParams,
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
pub struct RigSensor {
    pub geometry: CameraSettings,
    pub mount: Mount,
}

impl RigSensor {
    /// The sensor's yaw against the vehicle's heading (radians).
    pub fn yaw_rad(&self) -> f64 {
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
pub struct ProfileError {
    pub field: &'static str,
    pub message: String,
}

fn invalid(field: &'static str, message: String) -> ProfileError {
    ProfileError { field, message }
}

impl ProfileModel {
    /// Checks the parameters and calibrates the error scale of each bin
    /// so that the mean translation error of a fully visible object in the
    /// bin's middle is the published one (seeded Monte Carlo: the same
    /// parameters always give the same scale).
    pub fn new(params: ProfileParams) -> Result<ProfileModel, ProfileError> {
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
    pub fn with_rig(&self, sensors: Vec<RigSensor>) -> Result<ProfileModel, ProfileError> {
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
    fn bin(&self, d_m: f64) -> usize {
        range_bin(&self.params.bin_edges_m, d_m)
    }

    /// The random error's per-axis scale at distance `d_m` (metres).
    pub fn scale_at(&self, d_m: f64) -> f64 {
        self.scale_m[self.bin(d_m)]
    }

    /// The sensors, each with its geometry and mount.
    pub fn sensors(&self) -> &[RigSensor] {
        &self.sensors
    }

    /// Standard deviations (depth, lateral) of the random error at a
    /// distance: the scale split by `depth_to_lateral` so that the total
    /// variance is that of an isotropic error of the scale.
    fn axis_sigmas(&self, d_m: f64) -> (f64, f64) {
        let s = self.scale_at(d_m);
        let (cd, cl) = axis_factors(self.params.depth_to_lateral);
        (s * cd, s * cl)
    }

    /// The covariance the detector reports for a detection measured at
    /// `p_sensor_m` (sensor frame): zero-mean Gaussian, the random error's
    /// second moments along and across the measured line of sight. It
    /// knows nothing of the bias, the tails or the persistence.
    pub fn nominal_covariance(&self, p_sensor_m: &Vec2) -> Cov2 {
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
pub fn range_bin(edges_m: &[f64], d_m: f64) -> usize {
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
fn line_of_sight(p_sensor_m: &Vec2) -> nalgebra::Matrix2<f64> {
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
fn unit_error(p: &ProfileParams, persistent: [f64; 2], rng: &mut impl Rng) -> [f64; 2] {
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
pub fn persistent_error(
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

/// A sensor of an ego at one step under a profile.
struct ProfileSensor<'a> {
    /// The sensor's pose, world frame.
    pose: Pose2,
    /// The sensor's pose in the ego's body frame.
    in_ego: Pose2,
    rig: &'a CameraSettings,
    model: &'a ProfileModel,
    /// `[sensor]` for what the profiles share with the paper's model
    /// (visibility, appearance noise), with class confusion off.
    sensor: &'a SensorSettings,
}

/// The paper's model's sensors: `[camera]`'s cameras, in front.
pub fn paper_rig(camera: &CameraSettings) -> Vec<RigSensor> {
    camera
        .yaw_offsets_rad
        .iter()
        .map(|&yaw| RigSensor {
            geometry: CameraSettings {
                yaw_offsets_rad: vec![yaw],
                ..camera.clone()
            },
            mount: Mount::Front,
        })
        .collect()
}

/// Where a sensor on `mount` sits in the body frame of a vehicle
/// `length_m` long (metres).
pub fn sensor_in_body_m(mount: Mount, length_m: f64) -> Vec2 {
    match mount {
        Mount::Front => Vec2::new(length_m / 2.0, 0.0),
        Mount::Roof => Vec2::zeros(),
    }
}

/// Where a sensor sits on `ego`, yawed by `yaw_rad`.
fn sensor_pose(ego: &TrafficObject, mount: Mount, yaw_rad: f64) -> Pose2 {
    ego.pose
        .compose(&Pose2::new(sensor_in_body_m(mount, ego.length_m), yaw_rad))
}

impl ProfileSensor<'_> {
    fn detection(&self, p_sensor: &Vec2, appearance: Appearance) -> Detection {
        Detection {
            position_m: self.in_ego.to_parent(p_sensor),
            cov_m2: self
                .in_ego
                .cov_to_parent(&self.model.nominal_covariance(p_sensor)),
            appearance,
            motion: None,
        }
    }

    /// The appearance the detector reports: the class through the
    /// confusion matrix, colour only if it sees colour.
    fn appearance(
        &self,
        class: ObjectClass,
        colour_rgb: [u8; 3],
        size_m: [f64; 3],
        d_m: f64,
        rng: &mut impl Rng,
    ) -> Appearance {
        let mut a = observe_appearance(class, colour_rgb, size_m, d_m, self.rig, self.sensor, rng);
        let row = &self.model.params.class_confusion[class_index(class)];
        let u: f64 = rng.random();
        let mut acc = 0.0;
        a.class = class;
        for (k, p) in row.iter().enumerate() {
            acc += p;
            if u < acc {
                a.class = ObjectClass::ALL[k];
                break;
            }
        }
        if !self.model.params.sees_colour {
            a.colour_rgb = [0.5; 3];
        }
        a
    }

    /// Measures a point at `p_true` (sensor frame) with the profile's
    /// error: bias, persistent and heavy-tailed parts along and across the
    /// line of sight.
    fn measure(&self, p_true: &Vec2, persistent: [f64; 2], rng: &mut impl Rng) -> Vec2 {
        let p = &self.model.params;
        let d = p_true.norm().max(0.1);
        let (sd, sl) = self.model.axis_sigmas(d);
        let e = unit_error(p, persistent, rng);
        let depth = p.depth_bias_per_m * d + sd * e[0];
        let rot = line_of_sight(p_true);
        p_true + rot * Vec2::new(depth, sl * e[1])
    }

    /// Tries to detect `frame.objects[k]`; as [`super::Camera::detect`],
    /// plus the duplicates and ghosts it brings. Draws the same amount
    /// from the stream whatever happens.
    #[allow(clippy::too_many_arguments)]
    fn detect(
        &self,
        frame: &TrafficFrame,
        scene: &StaticScene,
        ego_index: usize,
        k: usize,
        seed: u64,
        rng: &mut impl Rng,
    ) -> Option<(VisibleObject, Vec<(Detection, DetectionTruth)>)> {
        let p = &self.model.params;
        let obj = &frame.objects[k];
        let reach = self.rig.range_m + obj.footprint().bounding_radius_m();
        if (obj.pose.position_m() - self.pose.position_m()).norm() > reach {
            return None;
        }
        let vis = visible_fraction(
            &self.pose,
            ego_index,
            k,
            frame,
            scene,
            self.rig,
            self.sensor,
        );
        if vis < self.sensor.min_visible_fraction || vis == 0.0 {
            return None;
        }
        let centre = self.pose.to_body(&obj.pose.position_m());
        let d = centre.norm();
        let recall = p.recall[self.model.bin(d)] * (1.0 - p.occlusion_recall_loss * (1.0 - vis));
        // The visible part's centre: pulled towards the sensor by a share
        // of the hidden depth extent.
        let rel = obj.pose.heading_rad() - self.pose.heading_rad() - centre.y.atan2(centre.x);
        let extent = (obj.length_m * rel.cos()).abs() + (obj.width_m * rel.sin()).abs();
        let pull = p.partial_shift * (1.0 - vis) * extent / 2.0;
        let seen_centre = centre * ((d - pull).max(0.1 * d) / d.max(1e-9));
        let ego_id = &frame.objects[ego_index].id;
        let persistent =
            persistent_error(seed, ego_id, &obj.id, frame.time_s, p.correlation_time_s);
        let u: f64 = rng.random();
        let measured = self.measure(&seen_centre, persistent, rng);
        let size = [obj.length_m, obj.width_m, obj.height_m];
        let appearance = self.appearance(obj.class, obj.colour_rgb, size, d, rng);
        // A duplicate: the same object again, its own per-frame error.
        let u_dup: f64 = rng.random();
        let dup_at = self.measure(&seen_centre, [0.0, 0.0], rng);
        let dup_look = self.appearance(obj.class, obj.colour_rgb, size, d, rng);
        // A ghost: beside the object.
        let u_ghost: f64 = rng.random();
        let r = p.ghost_distance_m[0]
            + (p.ghost_distance_m[1] - p.ghost_distance_m[0]) * rng.random::<f64>();
        let phi = std::f64::consts::TAU * rng.random::<f64>();
        let ghost_true = centre + Vec2::new(r * phi.cos(), r * phi.sin());
        let ghost_at = self.measure(&ghost_true, [0.0, 0.0], rng);
        let ghost_look = self.appearance(obj.class, obj.colour_rgb, size, d, rng);

        let object = VisibleObject {
            object_id: obj.id.clone(),
            position_m: obj.pose.position_m(),
            visible_fraction: vis,
        };
        if u >= recall {
            return Some((object, Vec::new()));
        }
        let mut out = vec![(
            self.detection(&measured, appearance),
            DetectionTruth {
                object_id: Some(obj.id.clone()),
                position_m: Some(obj.pose.position_m()),
                visible_fraction: vis,
                sender: false,
            },
        )];
        // Duplicates and ghosts are false positives: no object of their own.
        if u_dup < p.duplicate_prob {
            out.push((self.detection(&dup_at, dup_look), false_positive()));
        }
        if u_ghost < p.ghost_prob && ghost_at.norm() <= self.rig.range_m {
            out.push((self.detection(&ghost_at, ghost_look), false_positive()));
        }
        Some((object, out))
    }

    /// Clutter of one frame: Poisson many, uniform over the field's area,
    /// of any class and colour.
    fn clutter(&self, rng: &mut impl Rng) -> Vec<(Detection, DetectionTruth)> {
        let p = &self.model.params;
        (0..clutter_count(p.false_positives_per_frame, rng))
            .map(|_| {
                let (point, r) = clutter_point(self.rig, rng);
                let at = self.measure(&point, [0.0, 0.0], rng);
                let (class, colour) = clutter_look(rng);
                let look = self.appearance(class, colour, typical_size_m(class), r, rng);
                (self.detection(&at, look), false_positive())
            })
            .collect()
    }
}

fn class_index(class: ObjectClass) -> usize {
    ObjectClass::ALL
        .iter()
        .position(|c| *c == class)
        .unwrap_or(0)
}

/// What the sensors of `frame.objects[ego_index]` detect under `model`,
/// with the truth beside it: as [`super::observe`], with the profile's
/// sensors and errors. Per-frame draws come from `rng` in a fixed order
/// (per sensor: objects in frame order, then clutter); the persistent
/// error is named by `seed`, the ego, the object and the time.
pub fn observe_profile(
    frame: &TrafficFrame,
    scene: &StaticScene,
    ego_index: usize,
    model: &ProfileModel,
    sensor: &SensorSettings,
    seed: u64,
    rng: &mut impl Rng,
) -> Sensed {
    let ego = &frame.objects[ego_index];
    let mut found: Vec<(Detection, DetectionTruth)> = Vec::new();
    let mut visible: Vec<VisibleObject> = Vec::new();
    let mut seen = vec![false; frame.objects.len()];
    for rs in model.sensors() {
        let pose = sensor_pose(ego, rs.mount, rs.yaw_rad());
        let s = ProfileSensor {
            pose,
            in_ego: ego.pose.relative(&pose),
            rig: &rs.geometry,
            model,
            sensor,
        };
        for (k, already) in seen.iter_mut().enumerate() {
            if k == ego_index || *already {
                continue;
            }
            if let Some((object, dets)) = s.detect(frame, scene, ego_index, k, seed, rng) {
                *already = !dets.is_empty();
                note_visible(&mut visible, object);
                found.extend(dets);
            }
        }
        found.extend(s.clutter(rng));
    }
    sensed_from(ego, found, visible)
}

#[cfg(test)]
mod tests {
    use super::super::tests::sensor;
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// A camera-like profile: depth bias, heavy tails, persistence.
    fn params() -> ProfileParams {
        let mut identity = [[0.0; 7]; 7];
        for (k, row) in identity.iter_mut().enumerate() {
            row[k] = 1.0;
        }
        ProfileParams {
            fov_rad: 90f64.to_radians(),
            range_m: 60.0,
            height_m: 1.5,
            mount: Mount::Front,
            yaw_offsets_rad: vec![0.0],
            bin_edges_m: vec![20.0, 40.0, 60.0],
            recall: vec![0.9, 0.7, 0.4],
            mean_error_m: vec![0.4, 1.0, 2.0],
            depth_to_lateral: 3.0,
            depth_bias_per_m: 0.01,
            tail_dof: 4.0,
            persistent_share: 0.5,
            correlation_time_s: 2.0,
            partial_shift: 0.5,
            occlusion_recall_loss: 0.5,
            false_positives_per_frame: 0.0,
            duplicate_prob: 0.0,
            ghost_prob: 0.0,
            ghost_distance_m: [1.0, 3.0],
            class_confusion: identity,
            sees_colour: true,
            boxes: crate::sensor::boxes::BoxErrors {
                heading_sigma_rad: 0.1,
                heading_flip_prob: 0.02,
                speed_sigma_mps: 0.5,
            },
        }
    }

    fn car(id: &str, x: f64, y: f64) -> TrafficObject {
        TrafficObject {
            id: id.into(),
            class: ObjectClass::Car,
            pose: Pose2::new(Vec2::new(x, y), 0.0),
            length_m: 4.6,
            width_m: 1.8,
            height_m: 1.5,
            colour_rgb: [200, 10, 10],
            speed_mps: 0.0,
            type_id: "car".into(),
        }
    }

    fn scene() -> StaticScene {
        StaticScene {
            junction_id: "C".into(),
            junction_position_m: Vec2::zeros(),
            buildings: Vec::new(),
            lanes: Vec::new(),
        }
    }

    /// Errors (sensor frame: x along the line of sight) of one detection
    /// of a lone car at `x_m`, over `frames` independent objects.
    fn errors(model: &ProfileModel, x_m: f64, frames: u64) -> Vec<Vec2> {
        let sensor = sensor();
        (0..frames)
            .filter_map(|k| {
                let mut f = TrafficFrame {
                    step: 0,
                    time_s: 0.0,
                    objects: vec![car("ego", 0.0, 0.0), car(&format!("o{k}"), x_m, 0.0)],
                };
                f.objects[0].length_m = 0.0; // the sensor at the ego's centre
                let mut rng = ChaCha8Rng::seed_from_u64(k);
                let s = observe_profile(&f, &scene(), 0, model, &sensor, 7, &mut rng);
                let d = s.observation.detections.first()?;
                Some(d.position_m - Vec2::new(x_m, 0.0))
            })
            .collect()
    }

    #[test]
    fn the_mean_translation_error_is_the_published_one_per_bin() {
        let model = ProfileModel::new(params()).unwrap();
        for (x, target) in [(10.0, 0.4), (30.0, 1.0), (50.0, 2.0)] {
            let e = errors(&model, x, 6000);
            let mean = e.iter().map(|v| v.norm()).sum::<f64>() / e.len() as f64;
            assert!(
                (mean / target - 1.0).abs() < 0.05,
                "{x} m: {mean} vs {target}"
            );
        }
    }

    /// The reported covariance is not the error's distribution: biased in
    /// depth, heavier tails than a Gaussian of the same variance.
    #[test]
    fn the_nominal_covariance_is_not_the_error_distribution() {
        let model = ProfileModel::new(params()).unwrap();
        let e = errors(&model, 50.0, 6000);
        let n = e.len() as f64;
        let mean_depth = e.iter().map(|v| v.x).sum::<f64>() / n;
        assert!((mean_depth - 0.5).abs() < 0.15, "bias {mean_depth}");
        let cov = model.nominal_covariance(&Vec2::new(50.0, 0.0));
        let nees: Vec<f64> = e
            .iter()
            .map(|v| (v.transpose() * cov.try_inverse().unwrap() * v)[(0, 0)])
            .collect();
        // Beyond the Gaussian's 99.9 % NEES (13.8): far more than 0.1 %.
        let beyond = nees.iter().filter(|&&x| x > 13.8).count() as f64 / n;
        assert!(beyond > 0.004, "tail share {beyond}");
    }

    /// The same object seen 0.1 s apart: the errors are correlated by the
    /// persistent share (0.5 x exp(-0.1 / 2)); another object's are not.
    #[test]
    fn consecutive_frames_share_the_persistent_error() {
        let model = ProfileModel::new(params()).unwrap();
        let sensor = sensor();
        let depth_error = |obj: u64, time_s: f64, stream: u64| {
            let f = TrafficFrame {
                step: 0,
                time_s,
                objects: vec![
                    TrafficObject {
                        length_m: 0.0,
                        ..car("ego", 0.0, 0.0)
                    },
                    car(&format!("o{obj}"), 30.0, 0.0),
                ],
            };
            let mut rng = ChaCha8Rng::seed_from_u64(stream);
            let s = observe_profile(&f, &scene(), 0, &model, &sensor, 7, &mut rng);
            s.observation
                .detections
                .first()
                .map(|d| d.position_m.x - 30.0)
        };
        let pairs: Vec<(f64, f64)> = (0..4000u64)
            .filter_map(|o| {
                Some((
                    depth_error(o, 50.0, 2 * o)?,
                    depth_error(o, 50.1, 2 * o + 1)?,
                ))
            })
            .collect();
        let corr = |pairs: &[(f64, f64)]| {
            let n = pairs.len() as f64;
            let (ma, mb) = (
                pairs.iter().map(|p| p.0).sum::<f64>() / n,
                pairs.iter().map(|p| p.1).sum::<f64>() / n,
            );
            let cov = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum::<f64>();
            let va = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum::<f64>();
            let vb = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum::<f64>();
            cov / (va * vb).sqrt()
        };
        let same = corr(&pairs);
        assert!(
            (same - 0.5 * (-0.05f64).exp()).abs() < 0.06,
            "same object: {same}"
        );
        let shifted: Vec<(f64, f64)> = pairs
            .iter()
            .zip(pairs.iter().skip(1))
            .map(|(a, b)| (a.0, b.1))
            .collect();
        assert!(
            corr(&shifted).abs() < 0.06,
            "other objects: {}",
            corr(&shifted)
        );
    }

    #[test]
    fn with_gaussian_parameters_the_nominal_covariance_is_the_truth() {
        let mut p = params();
        p.depth_bias_per_m = 0.0;
        p.tail_dof = 1e6;
        p.persistent_share = 0.0;
        let model = ProfileModel::new(p).unwrap();
        let e = errors(&model, 30.0, 6000);
        let cov = model.nominal_covariance(&Vec2::new(30.0, 0.0));
        let mean_nees = e
            .iter()
            .map(|v| (v.transpose() * cov.try_inverse().unwrap() * v)[(0, 0)])
            .sum::<f64>()
            / e.len() as f64;
        assert!((mean_nees - 2.0).abs() < 0.1, "{mean_nees}");
    }

    #[test]
    fn the_persistent_error_is_stationary_and_decorrelates_over_its_time() {
        let tau = 2.0;
        let at = |obj: u64, t: f64| persistent_error(3, "ego", &format!("o{obj}"), t, tau)[0];
        let n = 4000;
        let x0: Vec<f64> = (0..n).map(|o| at(o, 100.0)).collect();
        let var = x0.iter().map(|x| x * x).sum::<f64>() / n as f64;
        assert!((var - 1.0).abs() < 0.08, "variance {var}");
        for (lag, expected) in [(0.1, (-0.05f64).exp()), (tau, (-1f64).exp()), (10.0, 0.0)] {
            let corr = (0..n)
                .map(|o| x0[o as usize] * at(o, 100.0 + lag))
                .sum::<f64>()
                / n as f64;
            assert!(
                (corr - expected).abs() < 0.06,
                "lag {lag}: {corr} vs {expected}"
            );
        }
        // A pure function of its name.
        assert_eq!(at(5, 12.3), at(5, 12.3));
        assert_eq!(persistent_error(3, "ego", "x", 1.0, 0.0), [0.0, 0.0]);
    }

    /// What a sensor at the ego's centre makes of one car 15 m ahead.
    fn sense_a_lone_car(model: &ProfileModel) -> Sensed {
        let mut f = TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects: vec![car("ego", 0.0, 0.0), car("a", 15.0, 0.0)],
        };
        f.objects[0].length_m = 0.0;
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        observe_profile(&f, &scene(), 0, model, &sensor(), 7, &mut rng)
    }

    #[test]
    fn duplicates_and_ghosts_are_false_positives_beside_the_object() {
        let mut p = params();
        p.duplicate_prob = 1.0;
        p.ghost_prob = 1.0;
        p.recall = vec![1.0; 3];
        let model = ProfileModel::new(p).unwrap();
        let s = sense_a_lone_car(&model);
        let ids: Vec<_> = s
            .truth
            .detections
            .iter()
            .map(|t| t.object_id.clone())
            .collect();
        assert_eq!(ids, vec![Some("a".to_owned()), None, None]);
        for d in &s.observation.detections {
            assert!((d.position_m - Vec2::new(15.0, 0.0)).norm() < 6.0);
        }
    }

    #[test]
    fn the_confusion_matrix_decides_the_reported_class_and_a_lidar_sees_no_colour() {
        let mut p = params();
        p.recall = vec![1.0; 3];
        p.class_confusion[0] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]; // a car is always a van
        p.sees_colour = false;
        let model = ProfileModel::new(p).unwrap();
        let s = sense_a_lone_car(&model);
        let a = &s.observation.detections[0].appearance;
        assert_eq!(a.class, ObjectClass::Van);
        assert_eq!(a.colour_rgb, [0.5; 3]);
    }

    /// In a mixed fleet each vehicle carries the profile its id draws, at
    /// every step, in the configured shares; without a mix, `profile`.
    #[test]
    fn a_mixed_fleet_draws_each_vehicles_profile_by_its_id() {
        let model = ProfileModel::new(params()).unwrap();
        let mut d = DetectorSettings {
            profile: DetectorProfile::Paper,
            mix: vec![
                (DetectorProfile::Camera, 0.7),
                (DetectorProfile::Lidar, 0.3),
            ],
            by_type: Vec::new(),
            camera: model.clone(),
            lidar: model,
            rigs: Vec::new(),
            rig_by_type: Vec::new(),
        };
        let n = 20_000;
        let lidar = (0..n)
            .filter(|k| d.profile_of(5, &format!("veh{k}"), "car") == DetectorProfile::Lidar)
            .count() as f64
            / f64::from(n);
        assert!((lidar - 0.3).abs() < 0.015, "lidar share {lidar}");
        assert_eq!(
            d.profile_of(5, "veh7", "car"),
            d.profile_of(5, "veh7", "car")
        );
        assert!(!d.is_paper());
        d.by_type = vec![("bus_cv".into(), DetectorProfile::Lidar)];
        assert_eq!(d.profile_of(5, "veh7", "bus_cv"), DetectorProfile::Lidar);
        d.mix.clear();
        assert_eq!(d.profile_of(5, "veh7", "car"), DetectorProfile::Paper);
        assert!(!d.is_paper());
        d.by_type.clear();
        assert!(d.is_paper());
    }

    /// The clean profile: Gaussian, white, unbiased, no false positives,
    /// no confusion, nothing for partly hidden objects.
    fn clean() -> ProfileParams {
        let mut p = params();
        p.depth_bias_per_m = 0.0;
        p.tail_dof = 1e6;
        p.persistent_share = 0.0;
        p.partial_shift = 0.0;
        p.occlusion_recall_loss = 0.0;
        p
    }

    /// What one profile does to a lone car 30 m ahead, over `N` cars each
    /// seen twice 0.1 s apart.
    #[derive(Debug, PartialEq)]
    struct Signature {
        recall: f64,
        mean_depth_error_m: f64,
        /// Share of NEES (against the nominal covariance) beyond the
        /// Gaussian's 99.9 % point.
        tail_share: f64,
        /// Correlation of the depth errors of one car 0.1 s apart.
        lag_correlation: f64,
        false_positives_per_frame: f64,
        wrong_class_share: f64,
    }

    fn signature(p: ProfileParams) -> Signature {
        const N: u64 = 3000;
        let model = ProfileModel::new(p).unwrap();
        let cov_inv = model
            .nominal_covariance(&Vec2::new(30.0, 0.0))
            .try_inverse()
            .unwrap();
        let see = |obj: u64, time_s: f64, stream: u64| {
            let f = TrafficFrame {
                step: 0,
                time_s,
                objects: vec![
                    TrafficObject {
                        length_m: 0.0,
                        ..car("ego", 0.0, 0.0)
                    },
                    car(&format!("o{obj}"), 30.0, 0.0),
                ],
            };
            let mut rng = ChaCha8Rng::seed_from_u64(stream);
            observe_profile(&f, &scene(), 0, &model, &sensor(), 7, &mut rng)
        };
        let (mut found, mut fp, mut wrong) = (0usize, 0usize, 0usize);
        let mut errors = Vec::new();
        let mut pairs = Vec::new();
        for o in 0..N {
            let mut depth = [None, None];
            for (i, t) in [50.0, 50.1].into_iter().enumerate() {
                let s = see(o, t, 2 * o + i as u64);
                for (d, truth) in s.observation.detections.iter().zip(&s.truth.detections) {
                    if truth.object_id.is_none() {
                        fp += 1;
                        continue;
                    }
                    found += 1;
                    wrong += usize::from(d.appearance.class != ObjectClass::Car);
                    let e = d.position_m - Vec2::new(30.0, 0.0);
                    errors.push(e);
                    depth[i] = Some(e.x);
                }
            }
            if let [Some(a), Some(b)] = depth {
                pairs.push((a, b));
            }
        }
        let n = errors.len() as f64;
        let mean = |v: &mut dyn Iterator<Item = f64>, n: f64| v.sum::<f64>() / n;
        let (ma, mb) = (
            mean(&mut pairs.iter().map(|p| p.0), pairs.len() as f64),
            mean(&mut pairs.iter().map(|p| p.1), pairs.len() as f64),
        );
        let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
        let va: f64 = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum();
        let vb: f64 = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum();
        Signature {
            recall: found as f64 / (2 * N) as f64,
            mean_depth_error_m: mean(&mut errors.iter().map(|e| e.x), n),
            tail_share: errors
                .iter()
                .filter(|e| (e.transpose() * cov_inv * *e)[(0, 0)] > 13.8)
                .count() as f64
                / n,
            lag_correlation: cov / (va * vb).sqrt(),
            false_positives_per_frame: fp as f64 / (2 * N) as f64,
            wrong_class_share: wrong as f64 / n,
        }
    }

    /// Each error component switched on alone, from the clean profile,
    /// moves its own statistic and leaves the others where the clean
    /// profile has them (within sampling noise); the components for
    /// partly hidden objects change nothing for a car in plain view.
    #[test]
    fn each_error_component_alone_changes_what_it_should_and_nothing_else() {
        let base = signature(clean());
        assert!(base.mean_depth_error_m.abs() < 0.06, "{base:?}");
        assert!(base.tail_share < 0.004, "{base:?}");
        assert!(base.lag_correlation.abs() < 0.05, "{base:?}");
        assert_eq!(base.false_positives_per_frame, 0.0);
        assert_eq!(base.wrong_class_share, 0.0);
        type Edit = fn(&mut ProfileParams);
        let cases: [(&str, Edit); 8] = [
            ("depth bias", |p| p.depth_bias_per_m = 0.01),
            ("heavy tails", |p| p.tail_dof = 3.0),
            ("persistent error", |p| p.persistent_share = 0.6),
            ("duplicates", |p| p.duplicate_prob = 0.5),
            ("ghosts", |p| p.ghost_prob = 0.5),
            ("class confusion", |p| {
                p.class_confusion[0] = [0.8, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0]
            }),
            ("partial shift", |p| p.partial_shift = 1.0),
            ("occlusion recall loss", |p| p.occlusion_recall_loss = 1.0),
        ];
        for (name, edit) in cases {
            let mut p = clean();
            edit(&mut p);
            let s = signature(p);
            let moved = |a: f64, b: f64, tol: f64| (a - b).abs() > tol;
            let changed = [
                ("recall", moved(s.recall, base.recall, 0.0)),
                (
                    "bias",
                    moved(s.mean_depth_error_m, base.mean_depth_error_m, 0.1),
                ),
                ("tails", moved(s.tail_share, base.tail_share, 0.004)),
                (
                    "persistence",
                    moved(s.lag_correlation, base.lag_correlation, 0.1),
                ),
                (
                    "false positives",
                    moved(s.false_positives_per_frame, 0.0, 0.0),
                ),
                ("class", moved(s.wrong_class_share, 0.0, 0.0)),
            ];
            let expected: &[&str] = match name {
                "depth bias" => &["bias"],
                "heavy tails" => &["tails"],
                "persistent error" => &["persistence"],
                "duplicates" | "ghosts" => &["false positives"],
                "class confusion" => &["class"],
                _ => &[],
            };
            let got: Vec<&str> = changed.iter().filter(|c| c.1).map(|c| c.0).collect();
            assert_eq!(got, expected, "{name}: {s:?} against {base:?}");
            if expected.is_empty() {
                assert_eq!(s, base, "{name} changed a car in plain view");
            }
        }
    }

    /// A car half hidden behind another: its detection lies closer to the
    /// sensor by `partial_shift` x the hidden share x half its depth
    /// extent; the car in front, in plain view, does not move.
    #[test]
    fn a_partly_hidden_objects_centre_shifts_toward_the_sensor() {
        let frame = TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects: vec![
                TrafficObject {
                    length_m: 0.0,
                    ..car("ego", 0.0, 0.0)
                },
                car("front", 10.0, 0.9),
                car("hidden", 20.0, 0.0),
            ],
        };
        let model = |shift: f64| {
            let mut p = clean();
            p.recall = vec![1.0; 3];
            p.partial_shift = shift;
            ProfileModel::new(p).unwrap()
        };
        let (without, with) = (model(0.0), model(1.0));
        let sense = |shift: f64, seed: u64| {
            let model = if shift > 0.0 { &with } else { &without };
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            observe_profile(&frame, &scene(), 0, model, &sensor(), 7, &mut rng)
        };
        let at = |s: &Sensed, id: &str| {
            let k = s
                .truth
                .detections
                .iter()
                .position(|t| t.object_id.as_deref() == Some(id))
                .unwrap();
            (
                s.observation.detections[k].position_m,
                s.truth.detections[k].visible_fraction,
            )
        };
        let (mut closer, mut n) = (0.0, 0.0);
        let mut vis = 0.0;
        for seed in 0..2000 {
            let (off, on) = (sense(0.0, seed), sense(1.0, seed));
            assert_eq!(at(&off, "front"), at(&on, "front"));
            let (p_off, v) = at(&off, "hidden");
            let (p_on, _) = at(&on, "hidden");
            closer += p_off.norm() - p_on.norm();
            n += 1.0;
            vis = v;
        }
        assert!(vis > 0.2 && vis < 0.8, "visible fraction {vis}");
        let expected = (1.0 - vis) * 4.6 / 2.0;
        let closer = closer / n;
        assert!(
            (closer / expected - 1.0).abs() < 0.1,
            "{closer} m closer, expected {expected} m"
        );
    }

    /// A rig's sensors each look from their own pose: a rear camera sees
    /// the car behind, which the profile's one front camera cannot; a
    /// sensor reaching beyond the range bins is refused.
    #[test]
    fn a_rig_senses_with_its_own_sensors() {
        let mut p = params();
        p.recall = vec![1.0; 3];
        let front = ProfileModel::new(p).unwrap();
        let sensor_at = |yaw_deg: f64, range_m: f64| RigSensor {
            geometry: CameraSettings {
                fov_rad: 90f64.to_radians(),
                range_m,
                height_m: 1.5,
                yaw_offsets_rad: vec![yaw_deg.to_radians()],
            },
            mount: Mount::Roof,
        };
        let both = front
            .with_rig(vec![sensor_at(0.0, 60.0), sensor_at(180.0, 60.0)])
            .unwrap();
        let frame = TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects: vec![car("ego", 0.0, 0.0), car("behind", -20.0, 0.0)],
        };
        let ids = |m: &ProfileModel| {
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let s = observe_profile(&frame, &scene(), 0, m, &sensor(), 7, &mut rng);
            s.truth
                .detections
                .iter()
                .filter_map(|t| t.object_id.clone())
                .collect::<Vec<_>>()
        };
        assert!(ids(&front).is_empty());
        assert_eq!(ids(&both), vec!["behind".to_owned()]);
        assert_eq!(front.sensors().len(), 1);
        assert_eq!(both.sensors().len(), 2);
        let e = front.with_rig(vec![sensor_at(0.0, 61.0)]).unwrap_err();
        assert_eq!(e.field, "sensors", "{e}");
        assert!(front.with_rig(Vec::new()).is_err());
    }

    #[test]
    fn unusable_parameters_are_refused_by_name() {
        type Edit = Box<dyn Fn(&mut ProfileParams)>;
        let cases: Vec<(&str, Edit)> = vec![
            (
                "recall",
                Box::new(|p| p.recall.pop().map(|_| ()).unwrap_or(())),
            ),
            ("tail_dof", Box::new(|p| p.tail_dof = 2.0)),
            (
                "bin_edges_m",
                Box::new(|p| p.bin_edges_m = vec![20.0, 10.0, 60.0]),
            ),
            ("bin_edges_m", Box::new(|p| p.range_m = 80.0)),
            ("mean_error_m", Box::new(|p| p.depth_bias_per_m = 0.1)),
            (
                "class_confusion",
                Box::new(|p| p.class_confusion[2][2] = 0.5),
            ),
            ("ghost_prob", Box::new(|p| p.ghost_prob = 1.5)),
            (
                "correlation_time_s",
                Box::new(|p| p.correlation_time_s = 0.0),
            ),
        ];
        for (field, edit) in cases {
            let mut p = params();
            edit(&mut p);
            let e = ProfileModel::new(p).unwrap_err();
            assert_eq!(e.field, field, "{e}");
        }
    }
}
