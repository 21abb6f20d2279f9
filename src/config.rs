//! The run configuration: a TOML file read once and validated into typed
//! settings with units in the field names. Each stage's settings type lives
//! with its stage (`traffic::ScenarioSettings`, `sensor::SensorSettings`,
//! ...); this module only reads, merges and checks, so it depends on the
//! stages and never the reverse.
//!
//! One source of defaults: `configs/default.toml`, compiled in. The user's
//! file is deep-merged over it (a table the user gives replaces only the
//! keys it names; `[connected]` is replaced as a whole, since `ids` and
//! `penetration` exclude each other), so a scenario file states only what
//! differs, and errors keep the line numbers of the user's file. Relative
//! paths resolve against the folder of the file that states them: the
//! user's folder, or the installation's `configs/` for the defaults (so the
//! shipped models are found from any folder).

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::de::{DeTable, DeValue};

use crate::evaluate::EvalSettings;
use crate::fusion::{FusionSettings, FusionVariant};
use crate::matching::deep::decision::UncertaintyKind;
use crate::matching::deep::model::PairLoss;
use crate::matching::deep::{self, train::TrainSettings};
use crate::matching::{DecisionChoice, LambdaChoice, MatchingSettings, Method, MultiVehicle};
use crate::rng::Seeds;
use crate::sensor::{
    CameraSettings, ConnectedSelection, LinkSettings, PoseNoiseLabel, PoseNoiseLevel,
    SensorSettings,
};
use crate::traffic::ScenarioSettings;
use crate::v2x::channel::{ChannelSettings, LossKind, LossModel};
use crate::v2x::cpm::CpmSettings;
use crate::v2x::receiver::AssociationSettings;
use crate::v2x::tracker::TrackerSettings;
use crate::v2x::{V2xMode, V2xSettings};

/// The defaults: every key, with its documentation.
pub const DEFAULTS_TOML: &str = include_str!("../configs/default.toml");

/// Where the defaults' relative paths are anchored: the `configs/` folder
/// of this build's files in the user's data folder (written out by
/// `io::assets::install`, which every command calls first), so the
/// default scenario and weights are the ones this binary carries, from
/// any folder. The library's own tests read the checkout's `configs/`.
pub fn defaults_dir() -> PathBuf {
    if cfg!(test) {
        return Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    }
    crate::paths::install_dir()
        .map(|d| d.join("configs"))
        .unwrap_or_else(|_| PathBuf::from("configs"))
}

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
// Raw TOML structure (what the merged file holds): every key is present,
// because the defaults state every key.
// ---------------------------------------------------------------------------

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
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
    v2x: RawV2x,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawV2x {
    mode: V2xMode,
    step_length_s: f64,
    gnss_correlation_s: f64,
    matcher: Method,
    pose_noise: PoseNoiseLabel,
    compensate_latency: bool,
    tracker: RawTracker,
    cpm: RawCpm,
    channel: RawChannel,
    association: RawAssociation,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAssociation {
    smoothing: f64,
    threshold: f64,
    pose_smoothing: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTracker {
    accel_sigma_mps2: f64,
    gate_chi2: f64,
    confirm_hits: u32,
    max_coast_s: f64,
    birth_speed_sigma_mps: f64,
    appearance_sigma: f64,
    reid_s: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCpm {
    rate_hz: f64,
    position_change_m: f64,
    speed_change_mps: f64,
    heading_change_deg: f64,
    max_interval_s: f64,
    max_objects: usize,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawChannel {
    latency_s: f64,
    jitter_mean_s: f64,
    loss: LossKind,
    loss_probability: f64,
    loss_range_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenario {
    sumocfg: PathBuf,
    junction: String,
    end_s: f64,
    radius_m: f64,
    sample_every_s: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConnected {
    #[serde(default)]
    ids: Option<Vec<String>>,
    #[serde(default)]
    penetration: Option<f64>,
    #[serde(default)]
    comm_range_m: Option<f64>,
    #[serde(default)]
    max_peers: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSeeds {
    traffic: u64,
    sensor: u64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    fov_deg: f64,
    range_m: f64,
    height_m: f64,
    yaw_offsets_deg: Vec<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
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

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPoseNoise {
    levels: Vec<PoseNoiseLabel>,
    rtk: RawPoseLevel,
    gps: RawPoseLevel,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPoseLevel {
    position_sigma_m: f64,
    heading_sigma_deg: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMatching {
    methods: Vec<Method>,
    gate_chi2: f64,
    models_dir: PathBuf,
    mc_samples: usize,
    lambda: RawLambda,
    decision: String,
    uncertainty: UncertaintyKind,
    sender_as_node: bool,
    multi_vehicle: MultiVehicle,
    rematch: usize,
}

/// `lambda = 0.7` or `lambda = "validated"`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum RawLambda {
    Value(f64),
    Word(String),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrain {
    traffic_seeds: Vec<u64>,
    validation_seeds: Vec<u64>,
    methods: Vec<Method>,
    epochs: usize,
    learning_rate: f64,
    seed: u64,
    scenarios: Vec<PathBuf>,
    validation_scenarios: Vec<PathBuf>,
    runs_per_scenario: usize,
    patience: usize,
    loss: PairLoss,
    mc_samples: usize,
    batch_size: usize,
    sample_every_s: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEval {
    traffic_seeds: Vec<u64>,
    scenarios: Vec<PathBuf>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFusion {
    variants: Vec<FusionVariant>,
    align_min_matches: usize,
}

// ---------------------------------------------------------------------------
// Validated settings (what the program uses).
// ---------------------------------------------------------------------------

/// Everything a run needs, validated; each field is one stage's slice.
#[derive(Clone, PartialEq)]
pub struct Settings {
    /// The config file these settings came from.
    pub source: PathBuf,
    pub scenario: ScenarioSettings,
    pub connected: ConnectedSelection,
    /// `[connected] comm_range_m`, `max_peers`.
    pub link: LinkSettings,
    pub seeds: Seeds,
    pub camera: CameraSettings,
    pub sensor: SensorSettings,
    pub pose_noise: Vec<PoseNoiseLevel>,
    pub matching: MatchingSettings,
    pub fusion: FusionSettings,
    pub train: TrainSettings,
    pub eval: EvalSettings,
    pub v2x: V2xSettings,
}

/// As derived, but `v2x` is shown only when it is not the default: the
/// digest of a config ([`Settings::digest`]) hashes this text, and configs
/// from before `[v2x]` existed keep their digest (and their batches).
impl std::fmt::Debug for Settings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Settings");
        d.field("source", &self.source)
            .field("scenario", &self.scenario)
            .field("connected", &self.connected)
            .field("link", &self.link)
            .field("seeds", &self.seeds)
            .field("camera", &self.camera)
            .field("sensor", &self.sensor)
            .field("pose_noise", &self.pose_noise)
            .field("matching", &self.matching)
            .field("fusion", &self.fusion)
            .field("train", &self.train)
            .field("eval", &self.eval);
        if self.v2x != V2xSettings::default() {
            d.field("v2x", &self.v2x);
        }
        d.finish()
    }
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

    /// Reads and validates a config file; also returns its text as read
    /// (what a batch records and runs from).
    pub fn load_with_text(path: &Path) -> Result<(Settings, String), ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        Ok((Self::from_toml(&text, path)?, text))
    }

    /// The defaults alone (`configs/default.toml` as compiled in).
    pub fn defaults() -> Result<Settings, ConfigError> {
        Self::from_toml("", &defaults_dir().join("default.toml"))
    }

    /// Parses config text, merges it over the defaults and validates it;
    /// `path` names the file in errors and anchors its relative paths.
    pub fn from_toml(text: &str, path: &Path) -> Result<Settings, ConfigError> {
        let parse_error = |source_text: &str, e: toml::de::Error| {
            let line = e
                .span()
                .filter(|s| s.start <= source_text.len())
                .map(|s| source_text[..s.start].matches('\n').count() + 1)
                .unwrap_or(1);
            ConfigError::Parse {
                path: path.to_owned(),
                line,
                message: e.message().replace('\n', " "),
            }
        };
        let mut user = DeTable::parse(text).map_err(|e| parse_error(text, e))?;
        let user_sumocfg = user.get_ref().get("scenario").and_then(|s| {
            let t = s.get_ref().as_table()?;
            Some((t.contains_key("sumocfg"), t.contains_key("junction")))
        });
        if let Some((true, false)) = user_sumocfg {
            return Err(ConfigError::Invalid {
                path: path.to_owned(),
                key: "scenario.junction",
                message: "missing: the junction id to study in your sumocfg (the default junction belongs to the default scenario)".into(),
            });
        }
        let stated = stated_keys(user.get_ref(), "");
        let defaults = DeTable::parse(DEFAULTS_TOML).map_err(|e| parse_error(DEFAULTS_TOML, e))?;
        let mut defaults = defaults.into_inner();
        anchor_default_paths(&mut defaults);
        merge_under(user.get_mut(), defaults);
        let raw = RawConfig::deserialize(toml::de::Deserializer::from(user))
            .map_err(|e| parse_error(text, e))?;
        validate(raw, path, &stated)
    }
}

/// Every key a TOML table states, as `section.key` (nested tables joined
/// by dots).
fn stated_keys(table: &DeTable<'_>, prefix: &str) -> std::collections::BTreeSet<String> {
    let mut out = std::collections::BTreeSet::new();
    for (key, value) in table {
        let name = format!("{prefix}{}", key.get_ref());
        if let DeValue::Table(t) = value.get_ref() {
            out.extend(stated_keys(t, &format!("{name}.")));
        }
        out.insert(name);
    }
    out
}

impl Settings {
    /// A digest of what these settings make a run do, by content, never
    /// by path: every setting (paths left out), the bytes of the SUMO
    /// configuration and of every file it names (network, routes,
    /// additional files), the weights and records of the deep methods it
    /// runs, and the bytes of each listed scenario's config. Two configs
    /// at different paths that say the same have the same digest; an edit
    /// to any of those files changes it.
    pub fn digest(&self) -> Result<String, ConfigError> {
        let mut blank = self.clone();
        blank.source = PathBuf::new();
        blank.scenario.sumocfg = PathBuf::new();
        blank.matching.models_dir = PathBuf::new();
        blank.train.scenarios.clear();
        blank.train.validation_scenarios.clear();
        blank.eval.scenarios.clear();
        // `[v2x]` at its defaults adds nothing (see the `Debug` impl).
        let mut d = Digest::default();
        d.feed(format!("{blank:?}").as_bytes());
        d.file(&self.source, &self.scenario.sumocfg)?;
        let sumocfg = std::fs::read_to_string(&self.scenario.sumocfg).unwrap_or_default();
        let dir = self.scenario.sumocfg.parent().unwrap_or(Path::new("."));
        for name in sumocfg_inputs(&sumocfg) {
            d.file(&self.source, &dir.join(name))?;
        }
        for m in &self.matching.methods {
            if crate::matching::deep::variant(*m).is_some() {
                for ext in ["bpk", "toml"] {
                    let p = self
                        .matching
                        .models_dir
                        .join(format!("{}.{ext}", m.as_str()));
                    d.file(&self.source, &p)?;
                }
            }
        }
        let lists = [
            &self.train.scenarios,
            &self.train.validation_scenarios,
            &self.eval.scenarios,
        ];
        for p in lists.into_iter().flatten() {
            d.file(&self.source, p)?;
        }
        Ok(format!("{:016x}", d.0))
    }
}

impl Settings {
    /// A digest of what makes the instances of this configuration's
    /// training, validation and test runs (what `coid export` writes, and
    /// `coid score` takes matches for): [`Settings::digest`] with the
    /// matchers, their weights, fusion and the fitting settings left out
    /// (they do not change a single instance), and the run seeds (each run
    /// takes its own from the seed lists).
    pub fn instances_digest(&self) -> Result<String, ConfigError> {
        let mut s = self.clone();
        s.seeds = Seeds {
            traffic: 0,
            sensor: 0,
        };
        s.matching = MatchingSettings {
            methods: Vec::new(),
            gate_chi2: 0.0,
            models_dir: PathBuf::new(),
            mc_samples: 0,
            lambda: LambdaChoice::Validated,
            decision: DecisionChoice::Validated,
            uncertainty: UncertaintyKind::Total,
            sender_as_node: self.matching.sender_as_node,
            multi_vehicle: MultiVehicle::Pairwise,
            rematch: 0,
        };
        s.fusion = FusionSettings {
            variants: Vec::new(),
            align_min_matches: 0,
        };
        let t = &mut s.train;
        (t.methods, t.epochs, t.learning_rate, t.seed) = (Vec::new(), 0, 0.0, 0);
        (t.patience, t.mc_samples, t.batch_size) = (0, 0, 0);
        t.loss = PairLoss::Likelihood;
        s.digest()
    }
}

/// FNV-1a 64 over everything fed.
struct Digest(u64);

impl Default for Digest {
    fn default() -> Self {
        Digest(0xcbf2_9ce4_8422_2325)
    }
}

impl Digest {
    fn feed(&mut self, bytes: &[u8]) {
        for b in (bytes.len() as u64).to_le_bytes().iter().chain(bytes) {
            self.0 ^= u64::from(*b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    fn file(&mut self, config: &Path, path: &Path) -> Result<(), ConfigError> {
        let bytes = std::fs::read(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        });
        match bytes {
            Ok(b) => {
                self.feed(&b);
                Ok(())
            }
            Err(e) => Err(ConfigError::Invalid {
                path: config.to_owned(),
                key: "scenario",
                message: format!("cannot read a file the run reads: {e}"),
            }),
        }
    }
}

/// The files a `.sumocfg` names: `net-file`, `route-files` and
/// `additional-files` values (comma-separated, relative to its folder).
fn sumocfg_inputs(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for tag in ["net-file", "route-files", "additional-files"] {
        let mut rest = text;
        while let Some(k) = rest.find(&format!("<{tag}")) {
            rest = &rest[k + tag.len() + 1..];
            let Some(v) = rest.find("value=\"") else {
                break;
            };
            let value = &rest[v + 7..];
            let Some(end) = value.find('"') else {
                break;
            };
            out.extend(
                value[..end]
                    .split(',')
                    .map(str::trim)
                    .filter(|s| !s.is_empty())
                    .map(str::to_owned),
            );
            rest = &value[end..];
        }
    }
    out
}

/// Makes the defaults' relative paths absolute (anchored at
/// [`defaults_dir`]), so they mean the same from any user's folder.
fn anchor_default_paths(defaults: &mut DeTable<'_>) {
    for (section, key) in [("scenario", "sumocfg"), ("matching", "models_dir")] {
        let Some(DeValue::Table(t)) = defaults.get_mut(section).map(|v| v.get_mut()) else {
            continue;
        };
        if let Some(v) = t.get_mut(key)
            && let DeValue::String(s) = v.get_mut()
            && Path::new(s.as_ref()).is_relative()
        {
            let abs = defaults_dir().join(s.as_ref());
            *s = Cow::Owned(abs.to_string_lossy().into_owned());
        }
    }
}

/// Adds every key of `defaults` that `user` lacks, recursing into tables
/// both have (except `[connected]`, which the user's replaces whole).
fn merge_under<'i>(user: &mut DeTable<'i>, defaults: DeTable<'i>) {
    for (key, value) in defaults {
        match user.get_mut(key.get_ref().as_ref()) {
            None => {
                user.insert(key, value);
            }
            Some(mine) => {
                if key.get_ref() == "connected" {
                    continue;
                }
                if let (DeValue::Table(mine), DeValue::Table(theirs)) =
                    (mine.get_mut(), value.into_inner())
                {
                    merge_under(mine, theirs);
                }
            }
        }
    }
}

/// Names the file in validation errors and resolves its relative paths.
/// The largest traffic seed: SUMO's `--seed` is a signed 32-bit int.
pub const MAX_TRAFFIC_SEED: u64 = i32::MAX as u64;

/// More cameras per vehicle than this are refused (each one's detections
/// are nodes of every graph).
const MAX_CAMERAS: usize = 16;

/// More MC-dropout samples than these are refused: every sample holds the
/// network's activations of both graphs (the paper uses T = 20 and sweeps
/// 10-100).
const MAX_MC_SAMPLES: usize = 1000;
const MAX_TRAIN_MC_SAMPLES: usize = 100;

/// More false positives per camera and frame than this are refused: each
/// is a node of every graph (and a sample of memory per step).
const MAX_FALSE_POSITIVES_PER_FRAME: f64 = 100.0;

struct Checker<'a> {
    path: &'a Path,
    /// The keys the user's file states (`section.key`), so that a
    /// conflict between two keys is reported under the one the user wrote.
    stated: &'a std::collections::BTreeSet<String>,
}

/// A number in a message: as written for ordinary values, in scientific
/// notation for huge or tiny ones (never 300 digits).
fn num(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-4..1e7).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl Checker<'_> {
    fn invalid(&self, key: &'static str, message: String) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_owned(),
            key,
            message,
        }
    }

    fn positive(&self, key: &'static str, v: f64) -> Result<(), ConfigError> {
        if v > 0.0 && v.is_finite() {
            Ok(())
        } else {
            Err(self.invalid(key, format!("must be a positive number, got {}", num(v))))
        }
    }

    fn non_negative(&self, key: &'static str, v: f64) -> Result<(), ConfigError> {
        if v >= 0.0 && v.is_finite() {
            Ok(())
        } else {
            Err(self.invalid(key, format!("must be >= 0, got {}", num(v))))
        }
    }

    fn fraction(&self, key: &'static str, v: f64) -> Result<(), ConfigError> {
        if (0.0..=1.0).contains(&v) {
            Ok(())
        } else {
            Err(self.invalid(key, format!("must be in [0, 1], got {}", num(v))))
        }
    }

    /// A traffic seed SUMO accepts (`--seed` is a 32-bit int).
    fn traffic_seed(&self, key: &'static str, seed: u64) -> Result<(), ConfigError> {
        if seed <= MAX_TRAFFIC_SEED {
            Ok(())
        } else {
            Err(self.invalid(
                key,
                format!("{seed} is beyond SUMO's seed range (0 to {MAX_TRAFFIC_SEED})"),
            ))
        }
    }

    /// A list of run seeds: each in SUMO's range, none twice.
    fn seed_list(&self, key: &'static str, seeds: &[u64]) -> Result<(), ConfigError> {
        for (k, &s) in seeds.iter().enumerate() {
            self.traffic_seed(key, s)?;
            if seeds[..k].contains(&s) {
                return Err(self.invalid(key, format!("seed {s} is listed twice")));
            }
        }
        Ok(())
    }

    /// `list` sorted (output rows come in a fixed order whatever order the
    /// user listed things in), refused when it names something twice.
    fn distinct<T: Ord + crate::label::Label>(
        &self,
        key: &'static str,
        mut list: Vec<T>,
    ) -> Result<Vec<T>, ConfigError> {
        list.sort();
        match list.windows(2).find(|w| w[0] == w[1]) {
            Some(w) => Err(self.invalid(key, format!("lists '{}' twice", w[0].label()))),
            None => Ok(list),
        }
    }

    /// Of two keys in conflict, the one to report: the one the user's
    /// file states (the first when it states both or neither).
    fn blame(&self, first: &'static str, second: &'static str) -> (&'static str, &'static str) {
        if !self.stated.contains(first) && self.stated.contains(second) {
            (second, first)
        } else {
            (first, second)
        }
    }

    /// A path relative to the config file's folder.
    fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_owned()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }
}

fn validate(
    raw: RawConfig,
    path: &Path,
    stated: &std::collections::BTreeSet<String>,
) -> Result<Settings, ConfigError> {
    let c = Checker { path, stated };
    c.traffic_seed("seeds.traffic", raw.seeds.traffic)?;
    let (train, eval) = train_and_eval(&c, raw.train, raw.eval)?;
    Ok(Settings {
        source: path.to_owned(),
        scenario: scenario(&c, raw.scenario)?,
        link: link(&c, &raw.connected)?,
        connected: connected(&c, raw.connected)?,
        seeds: Seeds {
            traffic: raw.seeds.traffic,
            sensor: raw.seeds.sensor,
        },
        camera: camera(&c, raw.camera)?,
        sensor: sensor(&c, raw.sensor)?,
        pose_noise: pose_noise(&c, raw.pose_noise)?,
        matching: matching(&c, raw.matching)?,
        fusion: fusion(&c, raw.fusion)?,
        train,
        eval,
        v2x: v2x(&c, raw.v2x)?,
    })
}

fn scenario(c: &Checker, s: RawScenario) -> Result<ScenarioSettings, ConfigError> {
    let sumocfg = c.resolve(&s.sumocfg);
    if sumocfg.is_dir() {
        return Err(c.invalid(
            "scenario.sumocfg",
            format!(
                "{} is a folder, not a SUMO configuration file (.sumocfg)",
                sumocfg.display()
            ),
        ));
    }
    if !sumocfg.is_file() {
        return Err(c.invalid(
            "scenario.sumocfg",
            format!("no such file: {}", sumocfg.display()),
        ));
    }
    let sumocfg = sumocfg.canonicalize().map_err(|e| {
        c.invalid(
            "scenario.sumocfg",
            format!("cannot resolve {}: {e}", sumocfg.display()),
        )
    })?;
    if s.junction.is_empty() {
        return Err(c.invalid(
            "scenario.junction",
            "missing: the junction id to study".into(),
        ));
    }
    c.positive("scenario.end_s", s.end_s)?;
    c.positive("scenario.radius_m", s.radius_m)?;
    c.positive("scenario.sample_every_s", s.sample_every_s)?;
    Ok(ScenarioSettings {
        sumocfg,
        junction: s.junction,
        end_s: s.end_s,
        radius_m: s.radius_m,
        sample_every_s: s.sample_every_s,
    })
}

fn link(c: &Checker, raw: &RawConnected) -> Result<LinkSettings, ConfigError> {
    if let Some(r) = raw.comm_range_m {
        c.positive("connected.comm_range_m", r)?;
    }
    if raw.max_peers == Some(0) {
        return Err(c.invalid(
            "connected.max_peers",
            "must be at least 1 (leave it out for no limit)".into(),
        ));
    }
    Ok(LinkSettings {
        comm_range_m: raw.comm_range_m,
        max_peers: raw.max_peers,
    })
}

fn connected(c: &Checker, raw: RawConnected) -> Result<ConnectedSelection, ConfigError> {
    match (raw.ids, raw.penetration) {
        (Some(_), Some(_)) => Err(c.invalid(
            "connected",
            "give either `ids` or `penetration`, not both".into(),
        )),
        (None, None) => Err(c.invalid(
            "connected",
            "give `ids` (at least two vehicle ids) or `penetration`".into(),
        )),
        (Some(ids), None) => {
            if ids.len() < 2 {
                return Err(c.invalid(
                    "connected.ids",
                    format!("need at least two connected vehicles, got {}", ids.len()),
                ));
            }
            let mut sorted = ids.clone();
            sorted.sort();
            sorted.dedup();
            if sorted.len() != ids.len() {
                return Err(c.invalid("connected.ids", "ids repeat".into()));
            }
            Ok(ConnectedSelection::Ids(ids))
        }
        (None, Some(p)) => {
            if !(p > 0.0 && p <= 1.0) {
                return Err(c.invalid(
                    "connected.penetration",
                    format!("must be in (0, 1], got {}", num(p)),
                ));
            }
            Ok(ConnectedSelection::Penetration(p))
        }
    }
}

fn camera(c: &Checker, raw: RawCamera) -> Result<CameraSettings, ConfigError> {
    if !(raw.fov_deg > 0.0 && raw.fov_deg < 180.0) {
        return Err(c.invalid(
            "camera.fov_deg",
            format!("must be in (0, 180), got {}", num(raw.fov_deg)),
        ));
    }
    c.positive("camera.range_m", raw.range_m)?;
    c.positive("camera.height_m", raw.height_m)?;
    let yaws = &raw.yaw_offsets_deg;
    if yaws.is_empty() || yaws.iter().any(|y| !y.is_finite()) {
        return Err(c.invalid(
            "camera.yaw_offsets_deg",
            "need one finite yaw per camera".into(),
        ));
    }
    if yaws.len() > MAX_CAMERAS {
        return Err(c.invalid(
            "camera.yaw_offsets_deg",
            format!("at most {MAX_CAMERAS} cameras, got {}", yaws.len()),
        ));
    }
    // The same direction twice (also as 0 and 360) is one camera counted
    // twice: every detection doubled.
    for (k, y) in yaws.iter().enumerate() {
        let same = |o: &f64| ((y - o).rem_euclid(360.0)).min((o - y).rem_euclid(360.0)) < 1e-9;
        if let Some(o) = yaws[..k].iter().find(|o| same(o)) {
            return Err(c.invalid(
                "camera.yaw_offsets_deg",
                format!(
                    "{} and {} deg are the same camera (one camera per direction)",
                    num(*o),
                    num(*y)
                ),
            ));
        }
    }
    Ok(CameraSettings {
        fov_rad: raw.fov_deg.to_radians(),
        range_m: raw.range_m,
        height_m: raw.height_m,
        yaw_offsets_rad: raw.yaw_offsets_deg.iter().map(|y| y.to_radians()).collect(),
    })
}

fn sensor(c: &Checker, s: RawSensor) -> Result<SensorSettings, ConfigError> {
    c.fraction("sensor.min_visible_fraction", s.min_visible_fraction)?;
    c.fraction("sensor.aim_height_fraction", s.aim_height_fraction)?;
    c.fraction("sensor.miss_prob_base", s.miss_prob_base)?;
    c.fraction("sensor.miss_prob_at_max_range", s.miss_prob_at_max_range)?;
    c.fraction("sensor.miss_prob_occlusion", s.miss_prob_occlusion)?;
    c.fraction("sensor.class_confusion_prob", s.class_confusion_prob)?;
    c.fraction("sensor.lighting_spread", s.lighting_spread)?;
    c.non_negative("sensor.range_sigma_base_m", s.range_sigma_base_m)?;
    c.non_negative("sensor.range_sigma_per_m", s.range_sigma_per_m)?;
    c.non_negative("sensor.bearing_sigma_base_deg", s.bearing_sigma_base_deg)?;
    c.non_negative("sensor.bearing_sigma_per_m_deg", s.bearing_sigma_per_m_deg)?;
    c.non_negative(
        "sensor.false_positives_per_frame",
        s.false_positives_per_frame,
    )?;
    if s.false_positives_per_frame > MAX_FALSE_POSITIVES_PER_FRAME {
        return Err(c.invalid(
            "sensor.false_positives_per_frame",
            format!(
                "at most {MAX_FALSE_POSITIVES_PER_FRAME} per camera and frame, got {}",
                num(s.false_positives_per_frame)
            ),
        ));
    }
    c.non_negative("sensor.colour_sigma", s.colour_sigma)?;
    c.non_negative("sensor.size_sigma_fraction", s.size_sigma_fraction)?;
    if s.range_sigma_base_m + s.bearing_sigma_base_deg <= 0.0 {
        return Err(c.invalid(
            "sensor.range_sigma_base_m",
            "range and bearing noise cannot both be zero at zero distance (the covariance would be singular)".into(),
        ));
    }
    Ok(SensorSettings {
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
    })
}

fn pose_noise(c: &Checker, p: RawPoseNoise) -> Result<Vec<PoseNoiseLevel>, ConfigError> {
    if p.levels.is_empty() {
        return Err(c.invalid("pose_noise.levels", "need at least one level".into()));
    }
    c.distinct("pose_noise.levels", p.levels)?
        .into_iter()
        .map(|label| {
            let (sigma_m, sigma_deg) = match label {
                PoseNoiseLabel::None => (0.0, 0.0),
                PoseNoiseLabel::Rtk => (p.rtk.position_sigma_m, p.rtk.heading_sigma_deg),
                PoseNoiseLabel::Gps => (p.gps.position_sigma_m, p.gps.heading_sigma_deg),
            };
            let ok = |v: f64| v >= 0.0 && v.is_finite();
            if !(ok(sigma_m) && ok(sigma_deg)) {
                return Err(c.invalid(
                    "pose_noise",
                    format!("level {}: sigmas must be >= 0", label.as_str()),
                ));
            }
            Ok(PoseNoiseLevel {
                label,
                position_sigma_m: sigma_m,
                heading_sigma_rad: sigma_deg.to_radians(),
            })
        })
        .collect()
}

fn matching(c: &Checker, m: RawMatching) -> Result<MatchingSettings, ConfigError> {
    if m.methods.is_empty() {
        return Err(c.invalid("matching.methods", "need at least one method".into()));
    }
    if m.methods.contains(&Method::External) {
        return Err(c.invalid(
            "matching.methods",
            "'external' correspondences come from a file: score them with `coid score --matches FILE`".into(),
        ));
    }
    c.positive("matching.gate_chi2", m.gate_chi2)?;
    if !(1..=MAX_MC_SAMPLES).contains(&m.mc_samples) {
        return Err(c.invalid(
            "matching.mc_samples",
            format!(
                "must be 1 to {MAX_MC_SAMPLES} samples, got {}",
                m.mc_samples
            ),
        ));
    }
    let lambda = match m.lambda {
        RawLambda::Word(w) if w == "validated" => LambdaChoice::Validated,
        RawLambda::Word(w) if w == "none" => LambdaChoice::Fixed(f64::INFINITY),
        RawLambda::Value(v) if (0.0..=1.0).contains(&v) => LambdaChoice::Fixed(v),
        RawLambda::Value(v) => {
            return Err(c.invalid(
                "matching.lambda",
                format!("must be in [0, 1] (binary entropy in bits), got {}", num(v)),
            ));
        }
        RawLambda::Word(w) => {
            return Err(c.invalid(
                "matching.lambda",
                format!("must be a number in [0, 1], \"none\" or \"validated\", got \"{w}\""),
            ));
        }
    };
    let decision = match m.decision.as_str() {
        "validated" => DecisionChoice::Validated,
        word => DecisionChoice::Fixed(word.parse().map_err(|_| {
            c.invalid(
                "matching.decision",
                format!("must be \"validated\", \"assignment\" or \"mutual\", got \"{word}\""),
            )
        })?),
    };
    if m.rematch > MAX_REMATCH {
        return Err(c.invalid(
            "matching.rematch",
            format!("at most {MAX_REMATCH} rounds, got {}", m.rematch),
        ));
    }
    Ok(MatchingSettings {
        methods: c.distinct("matching.methods", m.methods)?,
        gate_chi2: m.gate_chi2,
        models_dir: c.resolve(&m.models_dir),
        mc_samples: m.mc_samples,
        lambda,
        decision,
        uncertainty: m.uncertainty,
        sender_as_node: m.sender_as_node,
        multi_vehicle: m.multi_vehicle,
        rematch: m.rematch,
    })
}

/// More rounds of match-align-rematch than this change nothing but the
/// run time (the alignment settles after two or three).
const MAX_REMATCH: usize = 10;

fn train_and_eval(
    c: &Checker,
    t: RawTrain,
    e: RawEval,
) -> Result<(TrainSettings, EvalSettings), ConfigError> {
    if t.traffic_seeds.is_empty() {
        return Err(c.invalid("train.traffic_seeds", "need at least one run".into()));
    }
    c.seed_list("train.traffic_seeds", &t.traffic_seeds)?;
    c.seed_list("train.validation_seeds", &t.validation_seeds)?;
    c.seed_list("eval.traffic_seeds", &e.traffic_seeds)?;
    let (train, validation, test) = (
        ("train.traffic_seeds", &t.traffic_seeds),
        ("train.validation_seeds", &t.validation_seeds),
        ("eval.traffic_seeds", &e.traffic_seeds),
    );
    for ((key, a), (other, b)) in [(train, test), (validation, test), (validation, train)] {
        if let Some(s) = a.iter().find(|s| b.contains(s)) {
            let (blamed, with) = c.blame(key, other);
            return Err(c.invalid(
                blamed,
                format!(
                    "seed {s} is in both {blamed} and {with}: training, validation and test \
                     runs must be disjoint"
                ),
            ));
        }
    }
    if t.validation_seeds.is_empty() {
        return Err(c.invalid("train.validation_seeds", "need at least one run".into()));
    }
    fitting(c, &t)?;
    if e.traffic_seeds.is_empty() {
        return Err(c.invalid("eval.traffic_seeds", "need at least one run".into()));
    }
    let runs = runs_per_scenario(c, &t)?;
    let lists = scenario_lists(c, &t, &e)?;
    let train = TrainSettings {
        traffic_seeds: t.traffic_seeds,
        validation_seeds: t.validation_seeds,
        methods: c.distinct("train.methods", t.methods)?,
        epochs: t.epochs,
        learning_rate: t.learning_rate,
        seed: t.seed,
        scenarios: lists.train,
        validation_scenarios: lists.validation,
        runs_per_scenario: runs,
        patience: t.patience,
        loss: t.loss,
        mc_samples: t.mc_samples,
        batch_size: t.batch_size,
        sample_every_s: t.sample_every_s,
    };
    Ok((
        train,
        EvalSettings {
            traffic_seeds: e.traffic_seeds,
            scenarios: lists.test,
        },
    ))
}

/// `[train]`'s methods and fitting settings.
fn fitting(c: &Checker, t: &RawTrain) -> Result<(), ConfigError> {
    if t.methods.iter().any(|m| deep::variant(*m).is_none()) {
        return Err(c.invalid(
            "train.methods",
            "only deep methods (ours, ours-noprior, coid+non, coid+unc, dgmc, gcn-gm) are trained"
                .into(),
        ));
    }
    if t.epochs == 0 {
        return Err(c.invalid("train.epochs", "need at least one epoch".into()));
    }
    if !(1..=MAX_TRAIN_MC_SAMPLES).contains(&t.mc_samples) {
        return Err(c.invalid(
            "train.mc_samples",
            format!(
                "must be 1 to {MAX_TRAIN_MC_SAMPLES} samples per pair, got {}",
                t.mc_samples
            ),
        ));
    }
    if !(1..=1024).contains(&t.batch_size) {
        return Err(c.invalid(
            "train.batch_size",
            format!("must be 1-1024 pairs, got {}", t.batch_size),
        ));
    }
    c.positive("train.learning_rate", t.learning_rate)?;
    c.positive("train.sample_every_s", t.sample_every_s)
}

/// `[train] runs_per_scenario`, checked against the seeds it takes from.
fn runs_per_scenario(c: &Checker, t: &RawTrain) -> Result<usize, ConfigError> {
    let runs = t.runs_per_scenario;
    let too_many = (!t.scenarios.is_empty() && runs > t.traffic_seeds.len())
        || (!t.validation_scenarios.is_empty() && runs > t.validation_seeds.len());
    if runs == 0 || too_many {
        return Err(c.invalid(
            "train.runs_per_scenario",
            format!(
                "must be between 1 and the number of training (validation) seeds that listed \
                 training (validation) scenarios run, got {runs}"
            ),
        ));
    }
    Ok(runs)
}

/// The scenario configs of each role, folders expanded.
struct ScenarioLists {
    train: Vec<PathBuf>,
    validation: Vec<PathBuf>,
    test: Vec<PathBuf>,
}

/// Expands the scenario lists and checks that no scenario (no SUMO
/// configuration) has two roles: training, validation and test scenarios
/// are disjoint.
fn scenario_lists(c: &Checker, t: &RawTrain, e: &RawEval) -> Result<ScenarioLists, ConfigError> {
    let lists = ScenarioLists {
        train: expand_scenarios(c, "train.scenarios", &t.scenarios)?,
        validation: expand_scenarios(c, "train.validation_scenarios", &t.validation_scenarios)?,
        test: expand_scenarios(c, "eval.scenarios", &e.scenarios)?,
    };
    let mut role: BTreeMap<PathBuf, &'static str> = BTreeMap::new();
    for (key, list) in [
        ("train.scenarios", &lists.train),
        ("train.validation_scenarios", &lists.validation),
        ("eval.scenarios", &lists.test),
    ] {
        for path in list {
            let sumocfg = scenario_identity(path).map_err(|m| c.invalid(key, m))?;
            if let Some(other) = role.get(&sumocfg).filter(|&&o| o != key) {
                return Err(c.invalid(
                    key,
                    format!(
                        "{} is also in {other} (the same SUMO scenario {}): training, \
                         validation and test scenarios must be disjoint",
                        path.display(),
                        sumocfg.display()
                    ),
                ));
            }
            role.insert(sumocfg, key);
        }
    }
    Ok(lists)
}

/// The files of a scenario list: a file stays, a scenario folder stands
/// for its `coid.toml`, another folder for every scenario folder in it
/// (sorted).
fn expand_scenarios(
    c: &Checker,
    key: &'static str,
    list: &[PathBuf],
) -> Result<Vec<PathBuf>, ConfigError> {
    let mut out = Vec::new();
    for p in list.iter().map(|p| c.resolve(p)) {
        if p.is_file() {
            out.push(p);
        } else if p.join("coid.toml").is_file() {
            // A scenario folder itself.
            out.push(p.join("coid.toml"));
        } else if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(&p)
                .map_err(|e| c.invalid(key, format!("cannot list {}: {e}", p.display())))?
                .filter_map(|d| d.ok().map(|d| d.path().join("coid.toml")))
                .filter(|f| f.is_file())
                .collect();
            if found.is_empty() {
                return Err(c.invalid(
                    key,
                    format!("{} holds no scenario folder with a coid.toml", p.display()),
                ));
            }
            found.sort();
            out.extend(found);
        } else {
            return Err(c.invalid(key, format!("no such file or folder: {}", p.display())));
        }
    }
    Ok(out)
}

/// What makes two scenario configs the same scenario: the SUMO
/// configuration they run (canonical path), read from `[scenario] sumocfg`
/// without loading the rest.
fn scenario_identity(path: &Path) -> Result<PathBuf, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| format!("{}: {}", path.display(), e.message()))?;
    let sumocfg = table
        .get("scenario")
        .and_then(|s| s.get("sumocfg"))
        .and_then(|v| v.as_str())
        .ok_or_else(|| format!("{} has no [scenario] sumocfg", path.display()))?;
    let full = path.parent().unwrap_or(Path::new(".")).join(sumocfg);
    full.canonicalize()
        .map_err(|e| format!("{}: {}: {e}", path.display(), full.display()))
}

impl Settings {
    /// These settings with the scenario and connected vehicles of another
    /// config (a scenario of a training, validation or test list).
    pub fn with_scenario_of(&self, path: &Path) -> Result<Settings, ConfigError> {
        let other = Settings::load(path)?;
        let mut s = self.clone();
        s.scenario = other.scenario;
        s.connected = other.connected;
        s.source = other.source;
        Ok(s)
    }
}

fn fusion(c: &Checker, f: RawFusion) -> Result<FusionSettings, ConfigError> {
    if f.variants.is_empty() {
        return Err(c.invalid("fusion.variants", "need at least one variant".into()));
    }
    if f.align_min_matches < 2 {
        return Err(c.invalid(
            "fusion.align_min_matches",
            "a rigid alignment needs at least 2 matched objects".into(),
        ));
    }
    Ok(FusionSettings {
        variants: c.distinct("fusion.variants", f.variants)?,
        align_min_matches: f.align_min_matches,
    })
}

/// Objects per message at most (a CPM's object container is bounded).
const MAX_CPM_OBJECTS: usize = 1000;

fn v2x(c: &Checker, v: RawV2x) -> Result<V2xSettings, ConfigError> {
    if !(v.step_length_s > 0.0 && v.step_length_s <= 1.0) {
        return Err(c.invalid(
            "v2x.step_length_s",
            format!("must be in (0, 1] s, got {}", num(v.step_length_s)),
        ));
    }
    c.non_negative("v2x.gnss_correlation_s", v.gnss_correlation_s)?;
    if matches!(v.matcher, Method::Oracle | Method::External) {
        return Err(c.invalid("v2x.matcher", "must be a matching method".into()));
    }
    let a = v.association;
    if !(a.smoothing > 0.0 && a.smoothing <= 1.0) {
        return Err(c.invalid(
            "v2x.association.smoothing",
            format!("must be in (0, 1], got {}", num(a.smoothing)),
        ));
    }
    if !(0.0..1.0).contains(&a.threshold) {
        return Err(c.invalid(
            "v2x.association.threshold",
            format!("must be in [0, 1), got {}", num(a.threshold)),
        ));
    }
    c.fraction("v2x.association.pose_smoothing", a.pose_smoothing)?;
    Ok(V2xSettings {
        mode: v.mode,
        step_length_s: v.step_length_s,
        gnss_correlation_s: v.gnss_correlation_s,
        matcher: v.matcher,
        pose_noise: v.pose_noise,
        compensate_latency: v.compensate_latency,
        association: AssociationSettings {
            smoothing: a.smoothing,
            threshold: a.threshold,
            pose_smoothing: a.pose_smoothing,
        },
        tracker: tracker(c, v.tracker)?,
        cpm: cpm(c, v.cpm)?,
        channel: channel(c, v.channel)?,
    })
}

fn tracker(c: &Checker, t: RawTracker) -> Result<TrackerSettings, ConfigError> {
    c.positive("v2x.tracker.accel_sigma_mps2", t.accel_sigma_mps2)?;
    c.positive("v2x.tracker.gate_chi2", t.gate_chi2)?;
    c.positive("v2x.tracker.max_coast_s", t.max_coast_s)?;
    c.positive("v2x.tracker.birth_speed_sigma_mps", t.birth_speed_sigma_mps)?;
    c.non_negative("v2x.tracker.appearance_sigma", t.appearance_sigma)?;
    c.non_negative("v2x.tracker.reid_s", t.reid_s)?;
    if t.confirm_hits == 0 {
        return Err(c.invalid("v2x.tracker.confirm_hits", "need at least 1 hit".into()));
    }
    Ok(TrackerSettings {
        accel_sigma_mps2: t.accel_sigma_mps2,
        gate_chi2: t.gate_chi2,
        confirm_hits: t.confirm_hits,
        max_coast_s: t.max_coast_s,
        birth_speed_sigma_mps: t.birth_speed_sigma_mps,
        appearance_sigma: t.appearance_sigma,
        reid_s: t.reid_s,
    })
}

fn cpm(c: &Checker, m: RawCpm) -> Result<CpmSettings, ConfigError> {
    if !(1.0..=10.0).contains(&m.rate_hz) {
        return Err(c.invalid(
            "v2x.cpm.rate_hz",
            format!(
                "must be in [1, 10] Hz (T_GenCpm 0.1-1 s), got {}",
                num(m.rate_hz)
            ),
        ));
    }
    c.positive("v2x.cpm.position_change_m", m.position_change_m)?;
    c.positive("v2x.cpm.speed_change_mps", m.speed_change_mps)?;
    c.positive("v2x.cpm.heading_change_deg", m.heading_change_deg)?;
    c.positive("v2x.cpm.max_interval_s", m.max_interval_s)?;
    if !(1..=MAX_CPM_OBJECTS).contains(&m.max_objects) {
        return Err(c.invalid(
            "v2x.cpm.max_objects",
            format!("must be 1 to {MAX_CPM_OBJECTS}, got {}", m.max_objects),
        ));
    }
    Ok(CpmSettings {
        rate_hz: m.rate_hz,
        position_change_m: m.position_change_m,
        speed_change_mps: m.speed_change_mps,
        heading_change_deg: m.heading_change_deg,
        max_interval_s: m.max_interval_s,
        max_objects: m.max_objects,
    })
}

fn channel(c: &Checker, ch: RawChannel) -> Result<ChannelSettings, ConfigError> {
    c.non_negative("v2x.channel.latency_s", ch.latency_s)?;
    c.non_negative("v2x.channel.jitter_mean_s", ch.jitter_mean_s)?;
    c.fraction("v2x.channel.loss_probability", ch.loss_probability)?;
    c.positive("v2x.channel.loss_range_m", ch.loss_range_m)?;
    Ok(ChannelSettings {
        latency_s: ch.latency_s,
        jitter_mean_s: ch.jitter_mean_s,
        loss: match ch.loss {
            LossKind::Independent => LossModel::Independent {
                probability: ch.loss_probability,
            },
            LossKind::Distance => LossModel::Distance {
                probability_at_0: ch.loss_probability,
                range_m: ch.loss_range_m,
            },
        },
    })
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

    const MINIMAL: &str = "[scenario]\nsumocfg = \"scenario.sumocfg\"\njunction = \"J1\"\n";

    /// A folder of scenario folders `s0`, `s1`, ... each with its own SUMO
    /// configuration and a `coid.toml`.
    fn family(dir: &Path, n: usize) {
        for k in 0..n {
            let d = dir.join("fam").join(format!("s{k}"));
            std::fs::create_dir_all(&d).unwrap();
            write_cfg(&d, MINIMAL);
            std::fs::rename(d.join("c.toml"), d.join("coid.toml")).unwrap();
        }
    }

    #[test]
    fn scenario_lists_expand_folders_and_keep_roles_apart() {
        let dir = tempfile::tempdir().unwrap();
        family(dir.path(), 3);
        let body = format!("{MINIMAL}[train]\nscenarios = [\"fam\"]\nruns_per_scenario = 2\n");
        let s = Settings::load(&write_cfg(dir.path(), &body)).unwrap();
        let names: Vec<String> = s
            .train
            .scenarios
            .iter()
            .map(|p| {
                p.parent()
                    .unwrap()
                    .file_name()
                    .unwrap()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        assert_eq!(names, ["s0", "s1", "s2"]);
        assert_eq!(s.train.runs_per_scenario, 2);
        // A scenario folder names itself.
        let body = format!("{MINIMAL}[eval]\nscenarios = [\"fam/s1\"]\n");
        let s = Settings::load(&write_cfg(dir.path(), &body)).unwrap();
        assert!(s.eval.scenarios[0].ends_with("s1/coid.toml"));
        // One scenario in two roles, named by a folder and by a file.
        let body = format!(
            "{MINIMAL}[train]\nscenarios = [\"fam\"]\n[eval]\nscenarios = [\"fam/s1/coid.toml\"]\n"
        );
        let err = Settings::load(&write_cfg(dir.path(), &body))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("eval.scenarios") && err.contains("disjoint"),
            "{err}"
        );
        let body = format!(
            "{MINIMAL}[train]\nscenarios = [\"fam/s0/coid.toml\"]\nvalidation_scenarios = [\"fam/s0/coid.toml\"]\n"
        );
        let err = Settings::load(&write_cfg(dir.path(), &body))
            .unwrap_err()
            .to_string();
        assert!(err.contains("validation_scenarios"), "{err}");
        // Missing paths, empty folders and impossible run counts.
        for (extra, key) in [
            ("[train]\nscenarios = [\"nowhere\"]\n", "no such file"),
            ("[train]\nscenarios = [\".\"]\n", "holds no scenario folder"),
            ("[train]\nruns_per_scenario = 0\n", "runs_per_scenario"),
            (
                "[train]\nruns_per_scenario = 11\nvalidation_scenarios = [\"../fam/s2\"]\n",
                "runs_per_scenario",
            ),
        ] {
            let empty = dir.path().join("empty");
            std::fs::create_dir_all(&empty).unwrap();
            let err = Settings::load(&write_cfg(&empty, &format!("{MINIMAL}{extra}")))
                .unwrap_err()
                .to_string();
            assert!(err.contains(key), "{extra}: {err}");
        }
    }

    #[test]
    fn the_digest_is_by_content_not_by_path() {
        let dir = tempfile::tempdir().unwrap();
        let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("sumo_nets/intersection");
        for d in ["a", "b"] {
            let to = dir.path().join(d);
            std::fs::create_dir_all(&to).unwrap();
            for f in [
                "intersection.sumocfg",
                "intersection.net.xml",
                "intersection.rou.xml",
                "buildings.poly.xml",
            ] {
                std::fs::copy(scenario.join(f), to.join(f)).unwrap();
            }
            let body = "[scenario]\nsumocfg = \"intersection.sumocfg\"\njunction = \"C\"\n";
            std::fs::write(to.join("c.toml"), body).unwrap();
        }
        let load = |d: &str| Settings::load(&dir.path().join(d).join("c.toml")).unwrap();
        let (a, b) = (load("a").digest().unwrap(), load("b").digest().unwrap());
        assert_eq!(a, b, "the same config at two paths");
        // A setting, or a byte of a file the run reads, changes it.
        let routes = dir.path().join("b/intersection.rou.xml");
        let text = std::fs::read_to_string(&routes).unwrap();
        std::fs::write(&routes, format!("{text}\n")).unwrap();
        assert_ne!(load("b").digest().unwrap(), a);
        let mut edited = load("a");
        edited.sensor.colour_sigma += 0.01;
        assert_ne!(edited.digest().unwrap(), a);
        assert_eq!(
            sumocfg_inputs("<net-file value=\"n.xml\"/><route-files value=\"r1.xml, r2.xml\"/>"),
            ["n.xml", "r1.xml", "r2.xml"]
        );
    }

    #[test]
    fn the_defaults_are_the_shipped_file_and_valid() {
        let d = Settings::defaults().unwrap();
        let shipped = Settings::load(&defaults_dir().join("default.toml")).unwrap();
        // Same settings whether the file is read as a user's file or taken
        // as the compiled-in defaults (paths aside: both resolve to the
        // installation).
        assert_eq!(d.scenario.sumocfg, shipped.scenario.sumocfg);
        assert_eq!(d.sensor, shipped.sensor);
        assert_eq!(d.matching.methods.len(), 11);
        assert!(d.matching.sender_as_node);
        assert_eq!(d.matching.lambda, LambdaChoice::Validated);
        assert_eq!(
            d.connected,
            ConnectedSelection::Ids(vec!["cv0".into(), "cv1".into()])
        );
        assert!(d.matching.models_dir.join("ours.bpk").is_file());
        // The shipped [v2x] is the code's default, and at its default it
        // is not part of the text a config's digest hashes (configs from
        // before it keep their digest); changed, it is.
        assert_eq!(d.v2x, V2xSettings::default());
        assert!(!format!("{d:?}").contains("v2x"));
        let mut changed = d.clone();
        changed.v2x.channel.latency_s = 0.3;
        assert!(format!("{changed:?}").contains("v2x"));
        assert_ne!(d.digest().unwrap(), changed.digest().unwrap());
    }

    #[test]
    fn a_minimal_user_file_gets_the_defaults_and_its_own_paths() {
        let dir = tempfile::tempdir().unwrap();
        let s = Settings::load(&write_cfg(dir.path(), MINIMAL)).unwrap();
        let d = Settings::defaults().unwrap();
        assert!(
            s.scenario
                .sumocfg
                .starts_with(dir.path().canonicalize().unwrap())
        );
        assert_eq!(s.scenario.junction, "J1");
        assert_eq!(s.scenario.end_s, d.scenario.end_s);
        assert_eq!(
            (&s.sensor, &s.camera, &s.pose_noise),
            (&d.sensor, &d.camera, &d.pose_noise)
        );
        // The shipped models, not a folder beside the user's file.
        assert_eq!(s.matching.models_dir, d.matching.models_dir);
        assert_eq!(s.pose_noise[2].position_sigma_m, 1.2);
    }

    #[test]
    fn tables_merge_key_by_key_but_connected_is_replaced_whole() {
        let dir = tempfile::tempdir().unwrap();
        let body = format!(
            "{MINIMAL}[connected]\npenetration = 0.3\n[pose_noise]\nrtk = {{ position_sigma_m = 0.5 }}\n[camera]\nrange_m = 50.0\n"
        );
        let s = Settings::load(&write_cfg(dir.path(), &body)).unwrap();
        assert_eq!(s.connected, ConnectedSelection::Penetration(0.3));
        assert_eq!(s.pose_noise[1].position_sigma_m, 0.5);
        assert!((s.pose_noise[1].heading_sigma_rad - 0.2f64.to_radians()).abs() < 1e-15);
        assert_eq!(
            (s.camera.range_m, s.camera.yaw_offsets_rad.len()),
            (50.0, 1)
        );
    }

    #[test]
    fn a_user_scenario_needs_its_own_junction() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_cfg(dir.path(), "[scenario]\nsumocfg = \"scenario.sumocfg\"\n");
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("scenario.junction") && e.contains("missing"),
            "{e}"
        );
    }

    #[test]
    fn unknown_key_is_an_error_with_the_users_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_cfg(dir.path(), &format!("{MINIMAL}\n[camera]\nfov = 90\n"));
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(e.contains("unknown field `fov`"), "{e}");
        assert!(e.contains(":6:"), "{e}");
        assert!(!e.contains('\n'));
        let path = write_cfg(
            dir.path(),
            &format!("{MINIMAL}[seeds]\ntraffic = \"one\"\n"),
        );
        let e = Settings::load(&path).unwrap_err().to_string();
        assert!(e.contains(":5:"), "{e}");
    }

    #[test]
    fn bad_values_are_named() {
        let dir = tempfile::tempdir().unwrap();
        for (extra, key) in [
            ("[camera]\nfov_deg = 200.0\n", "camera.fov_deg"),
            ("[connected]\npenetration = 1.5\n", "connected.penetration"),
            ("[seeds]\ntraffic = 2147483648\n", "seeds.traffic"),
            ("[matching]\nmethods = [\"external\"]\n", "matching.methods"),
            ("[v2x]\nstep_length_s = 0.0\n", "v2x.step_length_s"),
            ("[v2x.cpm]\nrate_hz = 20.0\n", "v2x.cpm.rate_hz"),
            ("[v2x.cpm]\nmax_objects = 0\n", "v2x.cpm.max_objects"),
            (
                "[v2x.channel]\nloss_probability = 1.5\n",
                "v2x.channel.loss_probability",
            ),
            (
                "[v2x.tracker]\nconfirm_hits = 0\n",
                "v2x.tracker.confirm_hits",
            ),
            ("[v2x]\nmatcher = \"oracle\"\n", "v2x.matcher"),
            (
                "[v2x.tracker]\nappearance_sigma = -0.1\n",
                "v2x.tracker.appearance_sigma",
            ),
            ("[v2x.tracker]\nreid_s = -1.0\n", "v2x.tracker.reid_s"),
            (
                "[v2x.association]\nsmoothing = 0.0\n",
                "v2x.association.smoothing",
            ),
            (
                "[v2x.association]\nthreshold = 1.0\n",
                "v2x.association.threshold",
            ),
            ("[eval]\ntraffic_seeds = [1, 2, 1]\n", "eval.traffic_seeds"),
            (
                "[eval]\ntraffic_seeds = [3000000000]\n",
                "eval.traffic_seeds",
            ),
            (
                "[train]\nvalidation_seeds = [125, 125]\n",
                "train.validation_seeds",
            ),
            (
                "[sensor]\nfalse_positives_per_frame = 1e9\n",
                "sensor.false_positives_per_frame",
            ),
            ("[connected]\nids = [\"a\"]\n", "connected.ids"),
            (
                "[connected]\npenetration = 0.3\ncomm_range_m = -5.0\n",
                "connected.comm_range_m",
            ),
            (
                "[connected]\npenetration = 0.3\nmax_peers = 0\n",
                "connected.max_peers",
            ),
            (
                "[connected]\nids = [\"a\", \"b\"]\npenetration = 0.3\n",
                "connected",
            ),
            ("[sensor]\nmiss_prob_base = -0.1\n", "sensor.miss_prob_base"),
            ("[train]\ntraffic_seeds = [1]\n", "train.traffic_seeds"),
            (
                "[train]\nvalidation_seeds = [101]\n",
                "train.validation_seeds",
            ),
            (
                "[train]\nvalidation_seeds = [3]\n",
                "train.validation_seeds",
            ),
            ("[matching]\nlambda = \"best\"\n", "matching.lambda"),
            ("[matching]\nlambda = 1.5\n", "matching.lambda"),
            ("[matching]\nrematch = 11\n", "matching.rematch"),
            ("[matching]\ndecision = \"best\"\n", "matching.decision"),
            (
                "[fusion]\nalign_min_matches = 1\n",
                "fusion.align_min_matches",
            ),
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
        assert!(e.contains(":5:"), "{e}");
    }
}
