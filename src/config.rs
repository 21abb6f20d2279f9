//! The run configuration: a TOML file read once (serde, unknown keys are
//! errors) and validated into typed settings with units in the field names.
//! Each stage receives only its own slice.
//!
//! Every key has a default (documented beside it and in
//! `configs/default.toml`), so a scenario file only states what differs.
//! Relative paths resolve against the folder of the config file.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::matching::Method;
use crate::matching::deep::decision::UncertaintyKind;

/// Why a configuration could not be used. Each message is one line and names
/// the file and the offending key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: {key}: {message}")]
    Invalid {
        path: PathBuf,
        key: &'static str,
        message: String,
    },
}

// ---------------------------------------------------------------------------
// Raw TOML structure (what the user writes).
// ---------------------------------------------------------------------------

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawConfig {
    scenario: RawScenario,
    connected: RawConnected,
    seeds: RawSeeds,
    camera: RawCamera,
    sensor: RawSensor,
    pose_noise: RawPoseNoise,
    matching: RawMatching,
    fusion: RawFusion,
    train: RawTrain,
    eval: RawEval,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawScenario {
    sumocfg: Option<PathBuf>,
    junction: Option<String>,
    end_s: f64,
    radius_m: f64,
    sample_every_s: f64,
}

impl Default for RawScenario {
    fn default() -> Self {
        Self {
            sumocfg: None,
            junction: None,
            end_s: 130.0,
            radius_m: 50.0,
            sample_every_s: 0.5,
        }
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawConnected {
    ids: Option<Vec<String>>,
    penetration: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawSeeds {
    traffic: u64,
    sensor: u64,
}

impl Default for RawSeeds {
    fn default() -> Self {
        Self {
            traffic: 1,
            sensor: 1,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawCamera {
    fov_deg: f64,
    range_m: f64,
    height_m: f64,
    yaw_offsets_deg: Vec<f64>,
}

impl Default for RawCamera {
    fn default() -> Self {
        Self {
            fov_deg: 90.0,
            range_m: 70.0,
            height_m: 1.5,
            yaw_offsets_deg: vec![0.0],
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawSensor {
    min_visible_fraction: f64,
    aim_height_fraction: f64,
    range_sigma_base_m: f64,
    range_sigma_per_m: f64,
    bearing_sigma_base_deg: f64,
    bearing_sigma_per_m_deg: f64,
    miss_prob_base: f64,
    miss_prob_at_max_range: f64,
    miss_prob_occlusion: f64,
    false_positives_per_frame: f64,
    class_confusion_prob: f64,
    colour_sigma: f64,
    lighting_spread: f64,
    size_sigma_fraction: f64,
}

impl Default for RawSensor {
    fn default() -> Self {
        let s = SensorSettings::default();
        Self {
            min_visible_fraction: s.min_visible_fraction,
            aim_height_fraction: s.aim_height_fraction,
            range_sigma_base_m: s.range_sigma_base_m,
            range_sigma_per_m: s.range_sigma_per_m,
            bearing_sigma_base_deg: s.bearing_sigma_base_rad.to_degrees(),
            bearing_sigma_per_m_deg: s.bearing_sigma_per_m_rad.to_degrees(),
            miss_prob_base: s.miss_prob_base,
            miss_prob_at_max_range: s.miss_prob_at_max_range,
            miss_prob_occlusion: s.miss_prob_occlusion,
            false_positives_per_frame: s.false_positives_per_frame,
            class_confusion_prob: s.class_confusion_prob,
            colour_sigma: s.colour_sigma,
            lighting_spread: s.lighting_spread,
            size_sigma_fraction: s.size_sigma_fraction,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawPoseNoise {
    levels: Vec<PoseNoiseLabel>,
    rtk: RawPoseLevel,
    gps: RawPoseLevel,
}

impl Default for RawPoseNoise {
    fn default() -> Self {
        Self {
            levels: vec![
                PoseNoiseLabel::None,
                PoseNoiseLabel::Rtk,
                PoseNoiseLabel::Gps,
            ],
            rtk: RawPoseLevel {
                position_sigma_m: 0.2,
                heading_sigma_deg: 0.2,
            },
            gps: RawPoseLevel {
                position_sigma_m: 1.2,
                heading_sigma_deg: 0.2,
            },
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPoseLevel {
    position_sigma_m: f64,
    heading_sigma_deg: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawMatching {
    methods: Vec<Method>,
    gate_chi2: f64,
    models_dir: PathBuf,
    mc_samples: usize,
    lambda: f64,
    uncertainty: UncertaintyKind,
}

impl Default for RawMatching {
    fn default() -> Self {
        Self {
            methods: vec![
                Method::Ours,
                Method::CoidNon,
                Method::CoidUnc,
                Method::Dgmc,
                Method::GcnGm,
                Method::Mogm,
                Method::Rgm,
                Method::GpsHungarian,
                Method::Oracle,
            ],
            gate_chi2: 9.21,
            models_dir: PathBuf::from("../models"),
            mc_samples: 20,
            lambda: 0.7,
            uncertainty: UncertaintyKind::Total,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawTrain {
    traffic_seeds: Vec<u64>,
    methods: Vec<Method>,
    epochs: usize,
    learning_rate: f64,
    seed: u64,
}

impl Default for RawTrain {
    fn default() -> Self {
        Self {
            traffic_seeds: (101..=124).collect(),
            methods: vec![
                Method::Ours,
                Method::CoidNon,
                Method::CoidUnc,
                Method::Dgmc,
                Method::GcnGm,
            ],
            epochs: 4,
            learning_rate: 1e-3,
            seed: 7,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawEval {
    traffic_seeds: Vec<u64>,
}

impl Default for RawEval {
    fn default() -> Self {
        Self {
            traffic_seeds: (1..=10).collect(),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawFusion {
    variants: Vec<FusionVariant>,
    align_min_matches: usize,
}

impl Default for RawFusion {
    fn default() -> Self {
        Self {
            variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
            align_min_matches: 3,
        }
    }
}

// ---------------------------------------------------------------------------
// Validated settings (what the program uses).
// ---------------------------------------------------------------------------

/// Everything a run needs, validated.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// The config file these settings came from.
    pub source: PathBuf,
    pub scenario: ScenarioSettings,
    pub connected: ConnectedSelection,
    pub seeds: Seeds,
    pub camera: CameraSettings,
    pub sensor: SensorSettings,
    pub pose_noise: Vec<PoseNoiseLevel>,
    pub matching: MatchingSettings,
    pub fusion: FusionSettings,
    pub train: TrainSettings,
    pub eval: EvalSettings,
}

/// `coid train`: which runs make the training set and how to fit.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainSettings {
    /// SUMO seeds of the training runs (the sensor seed of run k is the
    /// same number). Must not overlap `eval.traffic_seeds`: train and test
    /// instances never come from the same run.
    pub traffic_seeds: Vec<u64>,
    pub methods: Vec<Method>,
    pub epochs: usize,
    pub learning_rate: f64,
    /// Weight initialisation, shuffling and training dropout.
    pub seed: u64,
}

/// `coid eval`: the test runs.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalSettings {
    pub traffic_seeds: Vec<u64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioSettings {
    /// Absolute path of the `.sumocfg`.
    pub sumocfg: PathBuf,
    pub junction: String,
    /// Simulated time at which the run stops.
    pub end_s: f64,
    /// Both connected vehicles must be this close to the junction centre for
    /// a (step, pair) to be an instance.
    pub radius_m: f64,
    /// Instances are taken at most this often (in simulated seconds).
    pub sample_every_s: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub enum ConnectedSelection {
    /// These SUMO vehicle ids carry the camera rig.
    Ids(Vec<String>),
    /// This share of the vehicles (cars, vans, trucks, buses), drawn per
    /// vehicle id from the sensor seed.
    Penetration(f64),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Seeds {
    /// SUMO's `--seed`: departures, driver imperfection.
    pub traffic: u64,
    /// Every draw of the sensor model, the pose noise and the penetration.
    pub sensor: u64,
}

/// The camera rig every connected vehicle carries.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Horizontal field of view of each camera. Default 90 deg (the SPEC's
    /// starting point; OpenCDA uses 100, DMGM 120, Artery 60).
    pub fov_rad: f64,
    /// Detection range. Default 70 m (OpenCDA 50 m, Artery 80 m).
    pub range_m: f64,
    /// Height of the camera above the ground (a roof-line camera on a car).
    pub height_m: f64,
    /// One camera per entry, yawed from the vehicle's heading; the cameras
    /// sit at the front bumper.
    pub yaw_offsets_rad: Vec<f64>,
}

/// The detector stand-in. Defaults are calibrated so the mean single-vehicle
/// displacement error on the default scenario is about 2.0 m (README,
/// "Calibration").
#[derive(Clone, Debug, PartialEq)]
pub struct SensorSettings {
    /// An object is detected only when at least this share of its footprint
    /// samples (centre, corners, edge midpoints) is in view and unblocked.
    pub min_visible_fraction: f64,
    /// Sight lines aim at this fraction of the object's height: a car hides a
    /// car or a person behind it, not the upper half of a truck.
    pub aim_height_fraction: f64,
    /// Range noise standard deviation: `base + per_m * distance`.
    pub range_sigma_base_m: f64,
    pub range_sigma_per_m: f64,
    /// Bearing noise standard deviation: `base + per_m * distance`.
    pub bearing_sigma_base_rad: f64,
    pub bearing_sigma_per_m_rad: f64,
    /// Miss probability: base, plus a share growing linearly to
    /// `miss_prob_at_max_range` at the camera's range, plus
    /// `miss_prob_occlusion * (1 - visible fraction)`.
    pub miss_prob_base: f64,
    pub miss_prob_at_max_range: f64,
    pub miss_prob_occlusion: f64,
    /// Mean number of false positives per camera and frame (Poisson).
    pub false_positives_per_frame: f64,
    /// Probability that the detector reports the confusable class.
    pub class_confusion_prob: f64,
    /// Colour noise per channel (RGB in [0, 1]) at zero distance; doubles at
    /// the camera's range.
    pub colour_sigma: f64,
    /// View-dependent brightness: colours scale by a factor drawn uniformly
    /// from `1 +- lighting_spread`.
    pub lighting_spread: f64,
    /// Relative noise on the measured length, width and height.
    pub size_sigma_fraction: f64,
}

impl Default for SensorSettings {
    fn default() -> Self {
        Self {
            min_visible_fraction: 0.3,
            aim_height_fraction: 0.6,
            range_sigma_base_m: 0.3,
            range_sigma_per_m: 0.095,
            bearing_sigma_base_rad: 0.5_f64.to_radians(),
            bearing_sigma_per_m_rad: 0.02_f64.to_radians(),
            miss_prob_base: 0.03,
            miss_prob_at_max_range: 0.15,
            miss_prob_occlusion: 0.3,
            false_positives_per_frame: 0.3,
            class_confusion_prob: 0.1,
            colour_sigma: 0.06,
            lighting_spread: 0.25,
            size_sigma_fraction: 0.1,
        }
    }
}

/// The pose-noise levels results are reported at.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseNoiseLabel {
    /// Perfect self-localisation.
    None,
    /// RTK-class GNSS: 0.2 m / 0.2 deg by default.
    Rtk,
    /// Plain GPS as in the DMGM data: 1.2 m / 0.2 deg by default.
    Gps,
}

impl PoseNoiseLabel {
    pub fn as_str(self) -> &'static str {
        match self {
            PoseNoiseLabel::None => "none",
            PoseNoiseLabel::Rtk => "rtk",
            PoseNoiseLabel::Gps => "gps",
        }
    }
}

/// One pose-noise level: every connected vehicle's reported pose is its true
/// pose plus independent Gaussian errors, per step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseNoiseLevel {
    pub label: PoseNoiseLabel,
    /// Standard deviation of the error along each of x and y.
    pub position_sigma_m: f64,
    pub heading_sigma_rad: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct MatchingSettings {
    pub methods: Vec<Method>,
    /// GPS-Hungarian gate on the squared Mahalanobis distance (9.21 is the
    /// 99% point of chi-square with 2 degrees of freedom).
    pub gate_chi2: f64,
    /// Folder of the deep methods' trained weights (`<method>.bpk`).
    pub models_dir: PathBuf,
    /// MC-dropout samples at inference (paper: T = 20).
    pub mc_samples: usize,
    /// Pairs whose uncertainty (binary entropy in bits, in [0, 1]) is at
    /// least this are removed (paper: 0.7).
    pub lambda: f64,
    pub uncertainty: UncertaintyKind,
}

/// How the matched measurements are fused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FusionVariant {
    /// Paper Eq. 14-16 with the relative pose from both vehicles' GPS.
    Paper,
    /// The relative pose refined from the matched objects first.
    Aligned,
}

impl FusionVariant {
    pub fn as_str(self) -> &'static str {
        match self {
            FusionVariant::Paper => "paper",
            FusionVariant::Aligned => "aligned",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct FusionSettings {
    pub variants: Vec<FusionVariant>,
    /// The aligned variant falls back to the GPS pose below this many
    /// matched objects.
    pub align_min_matches: usize,
}

impl Settings {
    /// Reads and validates a config file.
    pub fn load(path: &Path) -> Result<Settings, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::from_toml(&text, path)
    }

    /// Parses and validates config text; `path` names the file in errors and
    /// anchors relative paths.
    pub fn from_toml(text: &str, path: &Path) -> Result<Settings, ConfigError> {
        let raw: RawConfig = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
                .unwrap_or(1);
            ConfigError::Parse {
                path: path.to_owned(),
                line,
                message: e.message().replace('\n', " "),
            }
        })?;
        validate(raw, path)
    }
}

fn validate(raw: RawConfig, path: &Path) -> Result<Settings, ConfigError> {
    let invalid = |key: &'static str, message: String| ConfigError::Invalid {
        path: path.to_owned(),
        key,
        message,
    };
    let base = path.parent().unwrap_or(Path::new("."));

    let sumocfg = raw.scenario.sumocfg.ok_or_else(|| {
        invalid(
            "scenario.sumocfg",
            "missing: the SUMO scenario to run".into(),
        )
    })?;
    let sumocfg = if sumocfg.is_absolute() {
        sumocfg
    } else {
        base.join(sumocfg)
    };
    if !sumocfg.is_file() {
        return Err(invalid(
            "scenario.sumocfg",
            format!("no such file: {}", sumocfg.display()),
        ));
    }
    let sumocfg = sumocfg.canonicalize().map_err(|e| {
        invalid(
            "scenario.sumocfg",
            format!("cannot resolve {}: {e}", sumocfg.display()),
        )
    })?;
    let junction = raw
        .scenario
        .junction
        .filter(|j| !j.is_empty())
        .ok_or_else(|| {
            invalid(
                "scenario.junction",
                "missing: the junction id to study".into(),
            )
        })?;
    positive("scenario.end_s", raw.scenario.end_s).map_err(|m| invalid("scenario.end_s", m))?;
    positive("scenario.radius_m", raw.scenario.radius_m)
        .map_err(|m| invalid("scenario.radius_m", m))?;
    positive("scenario.sample_every_s", raw.scenario.sample_every_s)
        .map_err(|m| invalid("scenario.sample_every_s", m))?;

    let connected = match (raw.connected.ids, raw.connected.penetration) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                "connected",
                "give either `ids` or `penetration`, not both".into(),
            ));
        }
        (None, None) => ConnectedSelection::Ids(vec!["cv0".into(), "cv1".into()]),
        (Some(ids), None) => {
            if ids.len() < 2 {
                return Err(invalid(
                    "connected.ids",
                    format!("need at least two connected vehicles, got {}", ids.len()),
                ));
            }
            let mut sorted = ids.clone();
            sorted.sort();
            sorted.dedup();
            if sorted.len() != ids.len() {
                return Err(invalid("connected.ids", "ids repeat".into()));
            }
            ConnectedSelection::Ids(ids)
        }
        (None, Some(p)) => {
            if !(p > 0.0 && p <= 1.0) {
                return Err(invalid(
                    "connected.penetration",
                    format!("must be in (0, 1], got {p}"),
                ));
            }
            ConnectedSelection::Penetration(p)
        }
    };

    let c = raw.camera;
    if !(c.fov_deg > 0.0 && c.fov_deg < 180.0) {
        return Err(invalid(
            "camera.fov_deg",
            format!("must be in (0, 180), got {}", c.fov_deg),
        ));
    }
    positive("camera.range_m", c.range_m).map_err(|m| invalid("camera.range_m", m))?;
    positive("camera.height_m", c.height_m).map_err(|m| invalid("camera.height_m", m))?;
    if c.yaw_offsets_deg.is_empty() || c.yaw_offsets_deg.iter().any(|y| !y.is_finite()) {
        return Err(invalid(
            "camera.yaw_offsets_deg",
            "need one finite yaw per camera".into(),
        ));
    }
    let camera = CameraSettings {
        fov_rad: c.fov_deg.to_radians(),
        range_m: c.range_m,
        height_m: c.height_m,
        yaw_offsets_rad: c.yaw_offsets_deg.iter().map(|y| y.to_radians()).collect(),
    };

    let s = raw.sensor;
    for (key, v) in [
        ("sensor.min_visible_fraction", s.min_visible_fraction),
        ("sensor.aim_height_fraction", s.aim_height_fraction),
        ("sensor.miss_prob_base", s.miss_prob_base),
        ("sensor.miss_prob_at_max_range", s.miss_prob_at_max_range),
        ("sensor.miss_prob_occlusion", s.miss_prob_occlusion),
        ("sensor.class_confusion_prob", s.class_confusion_prob),
        ("sensor.lighting_spread", s.lighting_spread),
    ] {
        if !(0.0..=1.0).contains(&v) {
            return Err(invalid(key, format!("must be in [0, 1], got {v}")));
        }
    }
    for (key, v) in [
        ("sensor.range_sigma_base_m", s.range_sigma_base_m),
        ("sensor.range_sigma_per_m", s.range_sigma_per_m),
        ("sensor.bearing_sigma_base_deg", s.bearing_sigma_base_deg),
        ("sensor.bearing_sigma_per_m_deg", s.bearing_sigma_per_m_deg),
        (
            "sensor.false_positives_per_frame",
            s.false_positives_per_frame,
        ),
        ("sensor.colour_sigma", s.colour_sigma),
        ("sensor.size_sigma_fraction", s.size_sigma_fraction),
    ] {
        if !(v >= 0.0 && v.is_finite()) {
            return Err(invalid(key, format!("must be >= 0, got {v}")));
        }
    }
    if s.range_sigma_base_m + s.bearing_sigma_base_deg <= 0.0 {
        return Err(invalid(
            "sensor.range_sigma_base_m",
            "range and bearing noise cannot both be zero at zero distance (the covariance would be singular)".into(),
        ));
    }
    let sensor = SensorSettings {
        min_visible_fraction: s.min_visible_fraction,
        aim_height_fraction: s.aim_height_fraction,
        range_sigma_base_m: s.range_sigma_base_m,
        range_sigma_per_m: s.range_sigma_per_m,
        bearing_sigma_base_rad: s.bearing_sigma_base_deg.to_radians(),
        bearing_sigma_per_m_rad: s.bearing_sigma_per_m_deg.to_radians(),
        miss_prob_base: s.miss_prob_base,
        miss_prob_at_max_range: s.miss_prob_at_max_range,
        miss_prob_occlusion: s.miss_prob_occlusion,
        false_positives_per_frame: s.false_positives_per_frame,
        class_confusion_prob: s.class_confusion_prob,
        colour_sigma: s.colour_sigma,
        lighting_spread: s.lighting_spread,
        size_sigma_fraction: s.size_sigma_fraction,
    };

    let p = raw.pose_noise;
    if p.levels.is_empty() {
        return Err(invalid(
            "pose_noise.levels",
            "need at least one level".into(),
        ));
    }
    let mut pose_noise = Vec::new();
    for label in dedup_sorted(p.levels) {
        let (sigma_m, sigma_deg) = match label {
            PoseNoiseLabel::None => (0.0, 0.0),
            PoseNoiseLabel::Rtk => (p.rtk.position_sigma_m, p.rtk.heading_sigma_deg),
            PoseNoiseLabel::Gps => (p.gps.position_sigma_m, p.gps.heading_sigma_deg),
        };
        if !(sigma_m >= 0.0 && sigma_deg >= 0.0 && sigma_m.is_finite() && sigma_deg.is_finite()) {
            return Err(invalid(
                "pose_noise",
                format!("level {}: sigmas must be >= 0", label.as_str()),
            ));
        }
        pose_noise.push(PoseNoiseLevel {
            label,
            position_sigma_m: sigma_m,
            heading_sigma_rad: sigma_deg.to_radians(),
        });
    }

    let m = raw.matching;
    if m.methods.is_empty() {
        return Err(invalid(
            "matching.methods",
            "need at least one method".into(),
        ));
    }
    positive("matching.gate_chi2", m.gate_chi2).map_err(|e| invalid("matching.gate_chi2", e))?;
    if m.mc_samples == 0 {
        return Err(invalid(
            "matching.mc_samples",
            "need at least one sample".into(),
        ));
    }
    if !(0.0..=1.0).contains(&m.lambda) {
        return Err(invalid(
            "matching.lambda",
            format!(
                "must be in [0, 1] (binary entropy in bits), got {}",
                m.lambda
            ),
        ));
    }
    let models_dir = if m.models_dir.is_absolute() {
        m.models_dir.clone()
    } else {
        base.join(&m.models_dir)
    };
    let t = raw.train;
    if t.traffic_seeds.is_empty() {
        return Err(invalid(
            "train.traffic_seeds",
            "need at least one run".into(),
        ));
    }
    if let Some(s) = t
        .traffic_seeds
        .iter()
        .find(|s| raw.eval.traffic_seeds.contains(s))
    {
        return Err(invalid(
            "train.traffic_seeds",
            format!("seed {s} is also an eval seed: train and test runs must be disjoint"),
        ));
    }
    if t.methods
        .iter()
        .any(|m| crate::matching::deep::variant(*m).is_none())
    {
        return Err(invalid(
            "train.methods",
            "only deep methods (ours, coid+non, coid+unc, dgmc, gcn-gm) are trained".into(),
        ));
    }
    if t.epochs == 0 {
        return Err(invalid("train.epochs", "need at least one epoch".into()));
    }
    positive("train.learning_rate", t.learning_rate)
        .map_err(|e| invalid("train.learning_rate", e))?;
    if raw.eval.traffic_seeds.is_empty() {
        return Err(invalid(
            "eval.traffic_seeds",
            "need at least one run".into(),
        ));
    }
    let f = raw.fusion;
    if f.variants.is_empty() {
        return Err(invalid(
            "fusion.variants",
            "need at least one variant".into(),
        ));
    }
    if f.align_min_matches < 2 {
        return Err(invalid(
            "fusion.align_min_matches",
            "a rigid alignment needs at least 2 matched objects".into(),
        ));
    }

    Ok(Settings {
        source: path.to_owned(),
        scenario: ScenarioSettings {
            sumocfg,
            junction,
            end_s: raw.scenario.end_s,
            radius_m: raw.scenario.radius_m,
            sample_every_s: raw.scenario.sample_every_s,
        },
        connected,
        seeds: Seeds {
            traffic: raw.seeds.traffic,
            sensor: raw.seeds.sensor,
        },
        camera,
        sensor,
        pose_noise,
        matching: MatchingSettings {
            methods: dedup_sorted(m.methods),
            gate_chi2: m.gate_chi2,
            models_dir,
            mc_samples: m.mc_samples,
            lambda: m.lambda,
            uncertainty: m.uncertainty,
        },
        fusion: FusionSettings {
            variants: dedup_sorted(f.variants),
            align_min_matches: f.align_min_matches,
        },
        train: TrainSettings {
            traffic_seeds: t.traffic_seeds,
            methods: dedup_sorted(t.methods),
            epochs: t.epochs,
            learning_rate: t.learning_rate,
            seed: t.seed,
        },
        eval: EvalSettings {
            traffic_seeds: raw.eval.traffic_seeds,
        },
    })
}

fn positive(key: &str, v: f64) -> Result<(), String> {
    if v > 0.0 && v.is_finite() {
        Ok(())
    } else {
        Err(format!("{key} must be a positive number, got {v}"))
    }
}

/// Sorted, without repeats: output rows come in a fixed order whatever order
/// the user listed things in.
fn dedup_sorted<T: Ord>(mut v: Vec<T>) -> Vec<T> {
    v.sort();
    v.dedup();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_cfg(dir: &Path, body: &str) -> PathBuf {
        std::fs::write(dir.join("scenario.sumocfg"), "<configuration/>").unwrap();
        let path = dir.join("c.toml");
        std::fs::write(&path, body).unwrap();
        path
    }

    const MINIMAL: &str = "[scenario]\nsumocfg = \"scenario.sumocfg\"\njunction = \"C\"\n";

    #[test]
    fn minimal_config_gets_documented_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let s = Settings::load(&write_cfg(dir.path(), MINIMAL)).unwrap();
        assert!(s.scenario.sumocfg.is_absolute());
        assert_eq!(
            s.connected,
            ConnectedSelection::Ids(vec!["cv0".into(), "cv1".into()])
        );
        assert_eq!(s.pose_noise.len(), 3);
        assert_eq!(s.pose_noise[2].position_sigma_m, 1.2);
        assert!((s.camera.fov_rad - 90f64.to_radians()).abs() < 1e-12);
        assert_eq!(s.sensor, SensorSettings::default());
    }

    #[test]
    fn unknown_key_is_an_error_with_a_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_cfg(dir.path(), &format!("{MINIMAL}\n[camera]\nfov = 90\n"));
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(e.contains("unknown field `fov`"), "{e}");
        assert!(e.contains(":6:"), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn bad_values_are_named() {
        let dir = tempfile::tempdir().unwrap();
        for (extra, key) in [
            ("[camera]\nfov_deg = 200.0\n", "camera.fov_deg"),
            ("[connected]\npenetration = 1.5\n", "connected.penetration"),
            ("[connected]\nids = [\"a\"]\n", "connected.ids"),
            (
                "[connected]\nids = [\"a\", \"b\"]\npenetration = 0.3\n",
                "connected",
            ),
            ("[sensor]\nmiss_prob_base = -0.1\n", "sensor.miss_prob_base"),
        ] {
            let path = write_cfg(dir.path(), &format!("{MINIMAL}{extra}"));
            let e = Settings::load(&path).unwrap_err().to_string();
            assert!(e.contains(key), "{extra}: {e}");
        }
    }

    #[test]
    fn missing_sumocfg_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(
            &path,
            "[scenario]\nsumocfg = \"nope.sumocfg\"\njunction = \"C\"\n",
        )
        .unwrap();
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("no such file") && e.contains("nope.sumocfg"),
            "{e}"
        );
    }

    #[test]
    fn unknown_method_lists_the_known_ones() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_cfg(
            dir.path(),
            &format!("{MINIMAL}[matching]\nmethods = [\"magic\"]\n"),
        );
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(e.contains("magic") && e.contains("oracle"), "{e}");
    }
}
