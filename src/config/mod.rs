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
//!
//! One job per file: `raw` (the serde structure), `merge` (the user's file
//! over the defaults), `check` (what every section's validation uses),
//! `validate` (the stage sections), `learning` (`[train]`, `[eval]`),
//! `lists` (scenario lists: the only part that reads folders), `v2x`,
//! `detector` (`[detector]`: the detector profiles),
//! `digest` (what a configuration makes a run do, as one value).

mod appearance;
mod check;
mod detector;
mod digest;
mod learning;
mod lists;
mod merge;
mod raw;
mod v2x;
mod validate;
mod variants;

use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::de::DeTable;

use crate::evaluate::EvalSettings;
use crate::fusion::FusionSettings;
use crate::matching::MatchingSettings;
use crate::matching::deep::train::TrainSettings;
use crate::rng::Seeds;
use crate::sensor::profile::DetectorSettings;
use crate::sensor::{
    CameraSettings, ConnectedSelection, LinkSettings, PoseNoiseLevel, SensorSettings,
};
use crate::traffic::ScenarioSettings;
use crate::v2x::{V2xMode, V2xSettings};

pub use check::MAX_TRAFFIC_SEED;

/// The defaults: every key, with its documentation.
pub const DEFAULTS_TOML: &str = include_str!("../../configs/default.toml");

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

/// What the command line sets over a config file (`--traffic-seed`,
/// `--sensor-seed`, a batch's per-run seeds): set into the merged file
/// before validation, never into settings after it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Overrides {
    pub traffic_seed: Option<u64>,
    pub sensor_seed: Option<u64>,
    /// `[train] seed`.
    pub train_seed: Option<u64>,
    /// `[appearance] rank1`, with `auroc = "free"`: a point of the
    /// re-identification sweep.
    pub reid_rank1: Option<f64>,
    /// `[train] appearance_vectors` (`coid train --without-descriptor`:
    /// false).
    pub appearance_vectors: Option<bool>,
}

impl Overrides {
    fn apply(&self, raw: &mut raw::RawConfig) {
        if let Some(t) = self.train_seed {
            raw.train.seed = t;
        }
        if let Some(t) = self.traffic_seed {
            raw.seeds.traffic = t;
        }
        if let Some(s) = self.sensor_seed {
            raw.seeds.sensor = s;
        }
        if let Some(r) = self.reid_rank1 {
            raw.appearance.rank1 = r;
            raw.appearance.auroc = raw::RawRate::Word("free".into());
        }
        if let Some(v) = self.appearance_vectors {
            raw.train.appearance_vectors = v;
        }
    }
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
    /// `[detector]`: the detector profile (the paper's by default).
    pub detector: DetectorSettings,
    /// `[appearance]`: the vehicle catalogue and the re-identification
    /// descriptor (neither by default).
    pub appearance: crate::sensor::AppearanceSettings,
    /// Instances read from a dataset folder instead of simulated (`coid
    /// eval --dataset`, ...): the folder, and the run of it these settings
    /// run (`None`: the whole dataset, before it is split into runs).
    pub dataset: Option<DatasetSource>,
}

/// A dataset's run as a run's source of instances.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSource {
    pub dir: PathBuf,
    /// The split whose runs are evaluated (for the report), once chosen.
    pub split: Option<String>,
    /// The index of the run in the dataset's `runs.parquet` order.
    pub run: Option<usize>,
    /// What the nodes' appearance vectors say, fitted on the dataset's
    /// validation runs (`None`: no vectors, no validation runs, or they
    /// tell nothing apart there).
    pub descriptor_law: Option<crate::sensor::DescriptorLaw>,
    /// The width of the nodes' appearance vectors.
    pub appearance_width: crate::sensor::AppearanceWidth,
}

impl Settings {
    /// The width of the appearance vectors the deep networks train on: a
    /// dataset's usable vectors ([`DatasetSource::usable_appearance_width`]),
    /// else the calibrated re-identification descriptor's
    /// ([`crate::sensor::AppearanceSettings::appearance_width`]), or none.
    pub fn appearance_width(&self) -> crate::sensor::AppearanceWidth {
        if !self.train.appearance_vectors {
            return crate::sensor::AppearanceWidth::NONE;
        }
        match &self.dataset {
            Some(d) => d.usable_appearance_width(),
            None => self.appearance.appearance_width(),
        }
    }
}

impl DatasetSource {
    /// The width of the appearance vectors the methods may use: the
    /// dataset's, when its validation runs fitted what they say.
    pub fn usable_appearance_width(&self) -> crate::sensor::AppearanceWidth {
        match self.descriptor_law {
            Some(_) => self.appearance_width,
            None => crate::sensor::AppearanceWidth::NONE,
        }
    }
}

/// As derived, but `v2x` is shown only when it is not the default (and
/// `detector` only when its profile is not the paper's): the
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
        // `[appearance]` at its defaults adds nothing (digests of configs
        // without it stay as they were).
        if !self.appearance.is_default() {
            d.field("appearance", &self.appearance);
        }
        // The GNSS drifts in `ideal` runs too (it once was white there
        // whatever `gnss_correlation_s` said): such configs' digests
        // differ from that model's, so that a batch or export it made is
        // refused, never mixed.
        let drifts = self
            .pose_noise
            .iter()
            .any(|l| l.correlation_s(self.v2x.gnss_correlation_s) > 0.0);
        if self.v2x.mode == V2xMode::Ideal && drifts {
            d.field("ideal_gnss_drift", &true);
        }
        // The profiles' parameters change nothing while the paper's model
        // senses: shown only when another profile does.
        if !self.detector.is_paper() {
            d.field("detector", &self.detector);
        }
        if let Some(dataset) = &self.dataset {
            d.field("dataset", dataset);
        }
        d.finish()
    }
}

impl Settings {
    /// Reads and validates a config file.
    pub fn load(path: &Path) -> Result<Settings, ConfigError> {
        Self::load_with(path, &Overrides::default())
    }

    /// Reads a config file, sets `overrides` over it and validates the
    /// result.
    pub fn load_with(path: &Path, overrides: &Overrides) -> Result<Settings, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::from_toml_with(&text, path, overrides)
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
        Self::from_toml_with(text, path, &Overrides::default())
    }

    /// [`Settings::from_toml`] with `overrides` set over the merged file
    /// before it is validated (so they are checked as the file is).
    pub fn from_toml_with(
        text: &str,
        path: &Path,
        overrides: &Overrides,
    ) -> Result<Settings, ConfigError> {
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
        let stated = merge::stated_keys(user.get_ref(), "");
        let defaults = DeTable::parse(DEFAULTS_TOML).map_err(|e| parse_error(DEFAULTS_TOML, e))?;
        let mut defaults = defaults.into_inner();
        merge::anchor_default_paths(&mut defaults);
        merge::merge_under(user.get_mut(), defaults);
        let mut raw = raw::RawConfig::deserialize(toml::de::Deserializer::from(user))
            .map_err(|e| parse_error(text, e))?;
        overrides.apply(&mut raw);
        validate::validate(raw, path, &stated)
    }
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

#[cfg(test)]
mod tests;
