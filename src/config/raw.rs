//! The raw TOML structure: what the merged file holds (every key is
//! present, because the defaults state every key), as serde reads it.
//! Nothing here is checked; `validate` turns it into settings.

use std::path::PathBuf;

use serde::Deserialize;

use crate::fusion::FusionVariant;
use crate::matching::MultiVehicle;
use crate::matching::deep::arch::{MaskChoice, MaskScope, NoMatchWeights, PairLoss};
use crate::matching::deep::decision::UncertaintyKind;
use crate::matching::{BaselineChoice, Method};
use crate::sensor::PoseNoiseLabel;
use crate::sensor::profile::{DetectorProfile, Mount};
use crate::v2x::V2xMode;
use crate::v2x::channel::LossKind;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConfig {
    pub(super) scenario: RawScenario,
    pub(super) connected: RawConnected,
    pub(super) seeds: RawSeeds,
    pub(super) camera: RawCamera,
    pub(super) sensor: RawSensor,
    pub(super) pose_noise: RawPoseNoise,
    pub(super) matching: RawMatching,
    pub(super) fusion: RawFusion,
    pub(super) train: RawTrain,
    pub(super) eval: RawEval,
    pub(super) v2x: RawV2x,
    pub(super) detector: RawDetector,
    pub(super) appearance: RawAppearance,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAppearance {
    pub(super) vehicles: String,
    pub(super) catalogue: String,
    pub(super) descriptor: String,
    pub(super) width: usize,
    pub(super) rank1: f64,
    pub(super) auroc: RawRate,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDetector {
    pub(super) profile: DetectorProfile,
    pub(super) mix: std::collections::BTreeMap<String, f64>,
    pub(super) by_type: std::collections::BTreeMap<String, String>,
    pub(super) camera: RawProfile,
    pub(super) lidar: RawProfile,
    pub(super) rigs: std::collections::BTreeMap<String, RawRig>,
    pub(super) rig_by_type: std::collections::BTreeMap<String, String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRig {
    pub(super) profile: DetectorProfile,
    pub(super) sensors: Vec<RawRigSensor>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRigSensor {
    pub(super) yaw_deg: f64,
    pub(super) fov_deg: f64,
    pub(super) range_m: f64,
    pub(super) height_m: f64,
    pub(super) mount: Mount,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawProfile {
    pub(super) fov_deg: f64,
    pub(super) range_m: f64,
    pub(super) height_m: f64,
    pub(super) mount: Mount,
    pub(super) yaw_offsets_deg: Vec<f64>,
    pub(super) bin_edges_m: Vec<f64>,
    pub(super) recall: Vec<f64>,
    pub(super) mean_error_m: Vec<f64>,
    pub(super) depth_to_lateral: f64,
    pub(super) depth_bias_per_m: f64,
    pub(super) tail_dof: f64,
    pub(super) persistent_share: f64,
    pub(super) correlation_time_s: f64,
    pub(super) partial_shift: f64,
    pub(super) occlusion_recall_loss: f64,
    pub(super) false_positives_per_frame: f64,
    pub(super) duplicate_prob: f64,
    pub(super) ghost_prob: f64,
    pub(super) ghost_distance_m: [f64; 2],
    pub(super) class_confusion: [[f64; 7]; 7],
    pub(super) sees_colour: bool,
    pub(super) heading_sigma_deg: f64,
    pub(super) heading_flip_prob: f64,
    pub(super) speed_sigma_mps: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawV2x {
    pub(super) mode: V2xMode,
    pub(super) step_length_s: f64,
    pub(super) gnss_correlation_s: f64,
    pub(super) gnss_heading_speed_sigma_mps: f64,
    pub(super) matcher: Method,
    pub(super) pose_noise: PoseNoiseLabel,
    pub(super) compensate_latency: bool,
    pub(super) tracker: RawTracker,
    pub(super) cpm: RawCpm,
    pub(super) channel: RawChannel,
    pub(super) association: RawAssociation,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAssociation {
    pub(super) smoothing: f64,
    pub(super) threshold: f64,
    pub(super) pose_smoothing: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTracker {
    pub(super) accel_sigma_mps2: f64,
    pub(super) gate_chi2: f64,
    pub(super) confirm_hits: u32,
    pub(super) max_coast_s: f64,
    pub(super) birth_speed_sigma_mps: f64,
    pub(super) appearance_sigma: f64,
    pub(super) reid_s: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCpm {
    pub(super) rate_hz: f64,
    pub(super) position_change_m: f64,
    pub(super) speed_change_mps: f64,
    pub(super) heading_change_deg: f64,
    pub(super) max_interval_s: f64,
    pub(super) max_objects: usize,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawChannel {
    pub(super) latency_s: f64,
    pub(super) jitter_mean_s: f64,
    pub(super) loss: LossKind,
    pub(super) loss_probability: f64,
    pub(super) loss_range_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawScenario {
    pub(super) sumocfg: PathBuf,
    pub(super) junction: String,
    pub(super) end_s: f64,
    pub(super) radius_m: f64,
    pub(super) sample_every_s: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConnected {
    #[serde(default)]
    pub(super) ids: Option<Vec<String>>,
    #[serde(default)]
    pub(super) penetration: Option<f64>,
    #[serde(default)]
    pub(super) comm_range_m: Option<f64>,
    #[serde(default)]
    pub(super) max_peers: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSeeds {
    pub(super) traffic: u64,
    pub(super) sensor: u64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCamera {
    pub(super) fov_deg: f64,
    pub(super) range_m: f64,
    pub(super) height_m: f64,
    pub(super) yaw_offsets_deg: Vec<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSensor {
    pub(super) min_visible_fraction: f64,
    pub(super) aim_height_fraction: f64,
    pub(super) range_sigma_base_m: f64,
    pub(super) range_sigma_per_m: f64,
    pub(super) bearing_sigma_base_deg: f64,
    pub(super) bearing_sigma_per_m_deg: f64,
    pub(super) miss_prob_base: f64,
    pub(super) miss_prob_at_max_range: f64,
    pub(super) miss_prob_occlusion: f64,
    pub(super) false_positives_per_frame: f64,
    pub(super) class_confusion_prob: f64,
    pub(super) colour_sigma: f64,
    pub(super) lighting_spread: f64,
    pub(super) size_sigma_fraction: f64,
    pub(super) unset_colours: crate::traffic::UnsetColours,
    pub(super) heading_sigma_deg: f64,
    pub(super) heading_flip_prob: f64,
    pub(super) speed_sigma_mps: f64,
}

/// `[pose_noise]`: the levels results are reported at, and a table of
/// sigmas for every level but `none` (`rtk` and `gps` by default; any
/// other name a config gives one, `"gps-2m" = { ... }`).
#[derive(Debug)]
pub(super) struct RawPoseNoise {
    pub(super) levels: Vec<PoseNoiseLabel>,
    pub(super) defined: std::collections::BTreeMap<String, RawPoseLevel>,
}

impl<'de> Deserialize<'de> for RawPoseNoise {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = RawPoseNoise;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("levels = [...] and a table of sigmas per level")
            }

            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<RawPoseNoise, A::Error> {
                let mut levels = None;
                let mut defined = std::collections::BTreeMap::new();
                while let Some(key) = map.next_key::<String>()? {
                    if key == "levels" {
                        levels = Some(map.next_value()?);
                    } else {
                        defined.insert(key, map.next_value()?);
                    }
                }
                let levels = levels.ok_or_else(|| serde::de::Error::missing_field("levels"))?;
                Ok(RawPoseNoise { levels, defined })
            }
        }
        d.deserialize_map(Visitor)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPoseLevel {
    pub(super) position_sigma_m: f64,
    pub(super) heading_sigma_deg: f64,
    /// The level's own GNSS correlation time [default: `[v2x]
    /// gnss_correlation_s`].
    #[serde(default)]
    pub(super) correlation_s: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawMatching {
    pub(super) methods: Vec<Method>,
    pub(super) baselines: BaselineChoice,
    pub(super) gate_chi2: f64,
    pub(super) models_dir: PathBuf,
    pub(super) mc_samples: usize,
    pub(super) dropout_masks: MaskChoice,
    pub(super) mc_dropout: RawRate,
    pub(super) lambda: RawLambda,
    pub(super) decision: String,
    pub(super) uncertainty: UncertaintyKind,
    pub(super) sender_as_node: bool,
    pub(super) multi_vehicle: MultiVehicle,
    pub(super) rematch: usize,
    pub(super) indicators: crate::matching::deep::arch::IndicatorScope,
}

/// `mc_dropout = 0.3` or `mc_dropout = "trained"`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum RawRate {
    Value(f64),
    Word(String),
}

/// `lambda = 0.7` or `lambda = "validated"`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(super) enum RawLambda {
    Value(f64),
    Word(String),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTrain {
    pub(super) traffic_seeds: Vec<u64>,
    pub(super) validation_seeds: Vec<u64>,
    pub(super) methods: Vec<Method>,
    pub(super) epochs: usize,
    pub(super) learning_rate: f64,
    pub(super) seed: u64,
    pub(super) scenarios: Vec<PathBuf>,
    pub(super) validation_scenarios: Vec<PathBuf>,
    pub(super) runs_per_scenario: usize,
    pub(super) patience: usize,
    pub(super) loss: PairLoss,
    pub(super) mc_samples: usize,
    pub(super) dropout_masks: MaskScope,
    pub(super) paper_dropout_masks: MaskScope,
    pub(super) batch_size: usize,
    pub(super) sample_every_s: f64,
    pub(super) no_match: NoMatchWeights,
    pub(super) appearance_vectors: bool,
    pub(super) start_from: PathBuf,
    pub(super) graph: crate::matching::deep::arch::NetworkGraph,
    pub(super) consensus_dim: usize,
    pub(super) edge_scale_m: f64,
    pub(super) node_dropout: f64,
    pub(super) position_jitter_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawEval {
    pub(super) traffic_seeds: Vec<u64>,
    pub(super) scenarios: Vec<PathBuf>,
    pub(super) training_seeds: Vec<u64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawFusion {
    pub(super) variants: Vec<FusionVariant>,
    pub(super) align_min_matches: usize,
}
