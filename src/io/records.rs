//! What coid writes as TOML and reads back, as serde records (never text
//! put together by hand): the record beside each trained model, and a
//! batch's identity. A value TOML cannot hold is refused when writing,
//! not discovered when reading.

use serde::{Deserialize, Serialize};

use crate::matching::Method;
use crate::matching::deep::arch::{Backbone, MaskScope, NoMatchWeights};
use crate::matching::deep::decision::Decision;

/// `<method>.toml` beside `<method>.bpk`: how the weights were made, what
/// the validation runs chose for them, and what they must be to load.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelRecord {
    pub method: String,
    /// The network the weights belong to; loading refuses any other.
    pub architecture: Backbone,
    /// FNV-1a 64 of the `.bpk` bytes (hex); loading refuses other bytes.
    pub weights_fnv64: String,
    pub config: String,
    /// The dataset folder the weights were trained on (`coid train
    /// --dataset`), instead of simulated runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dataset: Option<String>,
    pub train_traffic_seeds: Vec<u64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub train_scenarios: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runs_per_scenario: Option<usize>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub validation_scenarios: Vec<String>,
    pub eval_traffic_seeds: Vec<u64>,
    pub epochs: usize,
    pub learning_rate: f64,
    pub seed: u64,
    pub examples: usize,
    pub steps: usize,
    pub seconds: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_epoch_loss: Option<f64>,
    /// The larger axis component of the training graphs' edges: median,
    /// 95th percentile, and the share beyond the outer knot.
    pub edge_median_m: f64,
    pub edge_p95_m: f64,
    pub edge_clipped_share: f64,
    pub loss: String,
    pub mc_samples: usize,
    /// The training's dropout masks (records written before they could be
    /// chosen: per node).
    #[serde(default = "per_node")]
    pub dropout_masks: MaskScope,
    pub batch_size: usize,
    /// How a published network's NLL weighed "no match" against true
    /// pairs (absent: every entry alike, and for the project's network,
    /// whose `loss` says).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_match: Option<NoMatchWeights>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub patience: Option<usize>,
    /// The training pairs' perturbation per epoch (`[train] node_dropout`,
    /// `position_jitter_m`; absent: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub node_dropout: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_jitter_m: Option<f64>,
    /// The weights training started from (`[train] start_from`): their
    /// file and its checksum (absent: a seeded start).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_from: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_weights_fnv64: Option<String>,
    /// The epoch kept: lowest loss on the validation runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_epoch: Option<usize>,
    /// Chosen on the validation runs (never on the eval seeds), once
    /// `coid train` validated the weights.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation: Option<ValidationRecord>,
    /// Whether the network reads the re-identification descriptor, as
    /// `coid train` chose on the validation runs between a network trained
    /// with it and one trained without (absent: no such choice was made).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub descriptor: Option<DescriptorChoice>,
}

/// The validation runs' choice between reading the re-identification
/// descriptor and leaving it out: each network's mean F1 there, at its own
/// validated operating point.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DescriptorChoice {
    pub reads: bool,
    pub f1_reading: f64,
    pub f1_without: f64,
}

/// The dropout masks of weights whose record does not say.
fn per_node() -> MaskScope {
    MaskScope::PerNode
}

/// `baselines.toml` of a models folder: each baseline's threshold chosen
/// on the validation runs (`coid train`), as the deep methods' lambdas.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaselinesRecord {
    pub config: String,
    /// The dataset whose validation runs chose (`coid train --dataset`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dataset: Option<String>,
    pub validation_seeds: Vec<u64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub validation_scenarios: Vec<String>,
    #[serde(rename = "baseline", default)]
    pub baselines: Vec<BaselineEntry>,
}

/// One baseline's chosen threshold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaselineEntry {
    pub method: Method,
    /// What the value is (`min_score`, `price_per_match`, `gate_chi2`).
    pub parameter: String,
    pub value: f64,
    /// The power of learned descriptors' likelihood ratio in its
    /// appearance term, chosen with it (MOGM and RGM on a dataset with
    /// descriptors; 1 without).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub descriptor_weight: Option<f64>,
    /// Its mean F1 on the validation runs.
    pub f1: f64,
    /// The a-priori value, and its mean F1 on the same runs.
    pub a_priori: f64,
    pub f1_a_priori: f64,
    /// What to know about a value at an end of its grid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

impl BaselinesRecord {
    pub fn to_toml(&self) -> Result<String, String> {
        let head = "# Written by `coid train`: each baseline's threshold, chosen on the validation\n\
                    # runs like the deep methods' lambdas (best mean F1 over the runs and levels).\n";
        toml::to_string(self)
            .map(|t| format!("{head}{t}"))
            .map_err(|e| e.to_string())
    }

    pub fn from_toml(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| e.message().replace('\n', " "))
    }
}

/// What the validation runs chose for one model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ValidationRecord {
    pub seeds: Vec<u64>,
    pub uncertainty: String,
    /// The entropy threshold; `"none"`: no threshold.
    pub lambda: Lambda,
    pub decision: Decision,
    /// The operating point chosen with the rule: the least E[Y] of a
    /// decided pair (0 in records without one: every pair the rule
    /// chooses).
    #[serde(default)]
    pub min_probability: f64,
    pub temperature: f64,
    pub f1: f64,
    /// The threshold chosen for each uncertainty type (Table 3), with the
    /// decision and temperature above; absent in records written before
    /// the types had their own (their thresholds are not read).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lambdas: Option<LambdaByKind>,
    /// What to know about a choice that lies at an end of what was tried
    /// (a temperature at the end of its range).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// A threshold per uncertainty type, by its label.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LambdaByKind {
    pub entropy: Lambda,
    pub epistemic: Lambda,
    pub aleatoric: Lambda,
}

/// A threshold in [0, 1], or none.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Lambda {
    Value(f64),
    None(NoneWord),
}

/// The word `"none"`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum NoneWord {
    #[serde(rename = "none")]
    None,
}

impl Lambda {
    pub fn from_f64(v: f64) -> Self {
        if v.is_finite() {
            Lambda::Value(v)
        } else {
            Lambda::None(NoneWord::None)
        }
    }

    /// The threshold (infinite: none); `None` when out of [0, 1].
    pub fn to_f64(self) -> Option<f64> {
        match self {
            Lambda::Value(v) if (0.0..=1.0).contains(&v) => Some(v),
            Lambda::Value(_) => None,
            Lambda::None(_) => Some(f64::INFINITY),
        }
    }
}

impl ModelRecord {
    /// The record as TOML.
    pub fn to_toml(&self) -> Result<String, String> {
        let head = "# Written by `coid train`: how these weights were made, and what the\n\
                    # validation runs chose for them. Read back with serde; edit at your risk.\n";
        toml::to_string(self)
            .map(|t| format!("{head}{t}"))
            .map_err(|e| e.to_string())
    }

    pub fn from_toml(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| e.message().replace('\n', " "))
    }

    /// `Ok` when these are the weights this record describes, for the
    /// network of `method`.
    pub fn check(&self, method: Method, arch: &Backbone, weights: &[u8]) -> Result<(), String> {
        if self.method != method.as_str() {
            return Err(format!("the record is of '{}'", self.method));
        }
        if self.architecture != *arch {
            if let (Backbone::Likelihood(_), Some(now)) = (self.architecture, renamed_to(method)) {
                return Err(format!(
                    "these weights are of the method now called '{}' (the project's network \
                     with the reported poses); '{}' is the published network on the paper's \
                     inputs: rename the files to {}.bpk and {}.toml (method = \"{}\"), or \
                     train '{}'",
                    now.as_str(),
                    method.as_str(),
                    now.as_str(),
                    now.as_str(),
                    now.as_str(),
                    method.as_str()
                ));
            }
            return Err("the weights were trained for another architecture".into());
        }
        let sum = fnv64_hex(weights);
        if self.weights_fnv64 != sum {
            return Err(format!(
                "the weights are not the ones recorded (checksum {sum}, recorded {})",
                self.weights_fnv64
            ));
        }
        Ok(())
    }

    /// What makes `other`'s training differ from this one's, by field
    /// name: empty when both ran one recipe (only the training seed and
    /// what it led to may differ). The training data are compared by what
    /// they are (traffic seeds, runs per scenario, number of scenarios,
    /// examples and their edge statistics), not by the paths they were
    /// read from, which depend on the folder the command ran in.
    pub fn recipe_differences(&self, other: &Self) -> Vec<&'static str> {
        let fields = [
            ("method", self.method == other.method),
            ("dataset", self.dataset == other.dataset),
            ("architecture", self.architecture == other.architecture),
            (
                "train_traffic_seeds",
                self.train_traffic_seeds == other.train_traffic_seeds,
            ),
            (
                "train_scenarios",
                self.train_scenarios.len() == other.train_scenarios.len(),
            ),
            (
                "runs_per_scenario",
                self.runs_per_scenario == other.runs_per_scenario,
            ),
            ("examples", self.examples == other.examples),
            (
                "edge statistics",
                self.edge_median_m == other.edge_median_m
                    && self.edge_p95_m == other.edge_p95_m
                    && self.edge_clipped_share == other.edge_clipped_share,
            ),
            ("epochs", self.epochs == other.epochs),
            ("learning_rate", self.learning_rate == other.learning_rate),
            ("loss", self.loss == other.loss),
            ("mc_samples", self.mc_samples == other.mc_samples),
            ("dropout_masks", self.dropout_masks == other.dropout_masks),
            ("batch_size", self.batch_size == other.batch_size),
            (
                "no_match",
                self.no_match.unwrap_or(NoMatchWeights::Entries)
                    == other.no_match.unwrap_or(NoMatchWeights::Entries),
            ),
            ("patience", self.patience == other.patience),
            (
                "augmentation",
                self.node_dropout == other.node_dropout
                    && self.position_jitter_m == other.position_jitter_m,
            ),
        ];
        fields
            .into_iter()
            .filter(|(_, same)| !same)
            .map(|(name, _)| name)
            .collect()
    }
}

/// The name that the project's network, once recorded as `method`, has
/// now: the deep baselines and ablations with the reported poses carry a
/// `+gps` suffix since the published networks took their names.
fn renamed_to(method: Method) -> Option<Method> {
    match method {
        Method::Dgmc => Some(Method::DgmcGps),
        Method::GcnGm => Some(Method::GcnGmGps),
        Method::CoidNon => Some(Method::CoidNonGps),
        Method::CoidUnc => Some(Method::CoidUncGps),
        _ => None,
    }
}

/// FNV-1a 64 of `bytes`, as 16 hex digits.
pub fn fnv64_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// `batch.toml`: what a batch is, by content: the digest of its resolved
/// configuration and of every file it reads, the number of runs and the
/// master seed. Two batches are the same exactly when these are. It also
/// keeps the configuration as it was read when the batch started (its
/// text and where it was, which anchors its relative paths): every run of
/// the batch runs from this record, never from the user's file again, so
/// an edit to that file while the batch runs cannot mix configurations.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BatchRecord {
    pub config_digest: String,
    pub runs: usize,
    pub master_seed: u64,
    /// Where the config was read: anchors its relative paths (not part of
    /// the identity).
    pub config: String,
    /// The config file's text as it was read (not part of the identity:
    /// the digest is).
    pub config_text: String,
}

impl BatchRecord {
    pub fn to_toml(&self) -> Result<String, String> {
        let head = "# Written by `coid batch`: what this batch is. Every run reads its configuration\n\
                    # from here; resuming checks that the configuration (and every file it reads) is\n\
                    # still the same (config_digest).\n";
        toml::to_string(self)
            .map(|t| format!("{head}{t}"))
            .map_err(|e| e.to_string())
    }

    pub fn from_toml(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| e.message().replace('\n', " "))
    }

    /// Whether `other` is the same batch (the path and text aside).
    pub fn same_batch(&self, other: &BatchRecord) -> bool {
        (&self.config_digest, self.runs, self.master_seed)
            == (&other.config_digest, other.runs, other.master_seed)
    }

    /// What a run folder of this batch records about it ([`BatchRun`]).
    pub fn run(&self, run: usize) -> BatchRun {
        BatchRun {
            batch_digest: self.config_digest.clone(),
            master_seed: self.master_seed,
            run,
        }
    }
}

/// `.coid-folder.toml`: the identity of a folder coid wrote as one piece
/// (a run, an evaluation, pictures, an export, ...): which command made it,
/// and every file it holds with its size. `--force` replaces a folder only
/// when this file says it is of the same kind and the folder still holds
/// exactly those files; a batch counts a run folder only when it names the
/// batch and run, and its files are whole.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FolderRecord {
    /// The kind of folder (`run`, `eval`, `render`, ...).
    pub kind: String,
    /// The coid version that wrote it.
    pub coid_version: String,
    /// For a run of a batch: which batch and run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch_run: Option<BatchRun>,
    /// Every file, by path relative to the folder (`/`-separated), sorted.
    #[serde(default)]
    pub files: Vec<FileEntry>,
}

/// The batch and run a run folder belongs to: run `run` of the batch whose
/// configuration digest is `batch_digest`, seeds derived from `master_seed`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BatchRun {
    pub batch_digest: String,
    pub master_seed: u64,
    pub run: usize,
}

/// One file of a folder and its size.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    pub path: String,
    pub bytes: u64,
}

impl FolderRecord {
    pub fn to_toml(&self) -> Result<String, String> {
        let head = "# Written by coid: what made this folder and the files it holds. `--force` replaces\n\
                    # the folder only while it holds exactly these files.\n";
        toml::to_string(self)
            .map(|t| format!("{head}{t}"))
            .map_err(|e| e.to_string())
    }

    pub fn from_toml(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| e.message().replace('\n', " "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::deep::arch::Architecture;

    fn record() -> ModelRecord {
        ModelRecord {
            method: "ours".into(),
            architecture: Backbone::Likelihood(Architecture::default()),
            weights_fnv64: fnv64_hex(b"weights"),
            config: "c.toml".into(),
            dataset: None,
            train_traffic_seeds: vec![1, 2],
            train_scenarios: Vec::new(),
            runs_per_scenario: None,
            validation_scenarios: Vec::new(),
            eval_traffic_seeds: vec![3],
            epochs: 2,
            learning_rate: 0.002,
            seed: 7,
            examples: 10,
            steps: 4,
            seconds: 1.5,
            final_epoch_loss: None,
            edge_median_m: 16.6,
            edge_p95_m: 48.6,
            edge_clipped_share: 0.05,
            loss: "likelihood".into(),
            mc_samples: 2,
            dropout_masks: MaskScope::Shared,
            batch_size: 32,
            no_match: None,
            patience: Some(3),
            node_dropout: None,
            position_jitter_m: None,
            start_from: None,
            start_weights_fnv64: None,
            best_epoch: Some(1),
            validation: Some(ValidationRecord {
                seeds: vec![4],
                uncertainty: "entropy".into(),
                lambda: Lambda::from_f64(f64::INFINITY),
                decision: Decision::Mutual,
                min_probability: 0.25,
                temperature: 1.5,
                f1: 0.9,
                lambdas: Some(LambdaByKind {
                    entropy: Lambda::from_f64(f64::INFINITY),
                    epistemic: Lambda::from_f64(0.3),
                    aleatoric: Lambda::from_f64(0.6),
                }),
                note: None,
            }),
            descriptor: None,
        }
    }

    #[test]
    fn a_model_record_reads_back_as_written_and_checks_its_weights() {
        let r = record();
        let back = ModelRecord::from_toml(&r.to_toml().unwrap()).unwrap();
        assert_eq!(back, r);
        assert_eq!(
            back.validation.unwrap().lambda.to_f64(),
            Some(f64::INFINITY)
        );
        let arch = Backbone::Likelihood(Architecture::default());
        assert!(r.check(Method::Ours, &arch, b"weights").is_ok());
        assert!(
            r.check(Method::Ours, &arch, b"other")
                .unwrap_err()
                .contains("checksum")
        );
        assert!(r.check(Method::Dgmc, &arch, b"weights").is_err());
        let other = Backbone::Likelihood(Architecture {
            hidden: 128,
            ..Architecture::default()
        });
        assert!(r.check(Method::Ours, &other, b"weights").is_err());
        // Weights of the project's network recorded as 'dgmc' (before the
        // published DGMC took the name) are refused with the new name.
        let old = ModelRecord {
            method: "dgmc".into(),
            ..record()
        };
        let d = Method::Dgmc.backbone().unwrap();
        let e = old.check(Method::Dgmc, &d, b"weights").unwrap_err();
        assert!(e.contains("now called 'dgmc+gps'"), "{e}");
        // A NaN loss is written as TOML's nan and read back.
        let nan = ModelRecord {
            final_epoch_loss: Some(f64::NAN),
            ..record()
        };
        let back = ModelRecord::from_toml(&nan.to_toml().unwrap()).unwrap();
        assert!(back.final_epoch_loss.unwrap().is_nan());
        assert!(ModelRecord::from_toml("method = 3").is_err());
    }

    /// The training's dropout masks are recorded; a record written before
    /// they could be chosen reads as per-node masks (how such weights were
    /// trained).
    #[test]
    fn a_record_without_dropout_masks_was_trained_per_node() {
        let text = record().to_toml().unwrap();
        assert!(text.contains("dropout_masks = \"shared\""), "{text}");
        let old: String = text
            .lines()
            .filter(|l| !l.starts_with("dropout_masks"))
            .map(|l| format!("{l}\n"))
            .collect();
        let back = ModelRecord::from_toml(&old).unwrap();
        assert_eq!(back.dropout_masks, MaskScope::PerNode);
    }

    /// Two seeds of one recipe differ only in the seed and what it led
    /// to; another folder or another recipe is told apart by field.
    #[test]
    fn seeds_of_one_recipe_differ_only_in_what_the_seed_led_to() {
        let seven = record();
        let eight = ModelRecord {
            seed: 8,
            weights_fnv64: fnv64_hex(b"other weights"),
            config: "/elsewhere/c.toml".into(),
            steps: 5,
            seconds: 9.0,
            final_epoch_loss: Some(0.5),
            best_epoch: Some(2),
            validation: None,
            ..record()
        };
        assert!(seven.recipe_differences(&eight).is_empty());
        let other = ModelRecord {
            epochs: 3,
            examples: 11,
            dropout_masks: MaskScope::PerNode,
            ..eight
        };
        assert_eq!(
            seven.recipe_differences(&other),
            ["examples", "epochs", "dropout_masks"]
        );
    }

    #[test]
    fn a_batch_is_its_content_not_its_path() {
        let a = BatchRecord {
            config_digest: "ab".into(),
            runs: 4,
            master_seed: 1,
            config: "/x/c.toml".into(),
            config_text: "[seeds]\ntraffic = 3\n".into(),
        };
        let moved = BatchRecord {
            config: "/elsewhere/c.toml".into(),
            ..a.clone()
        };
        assert!(a.same_batch(&moved));
        let edited = BatchRecord {
            config_digest: "cd".into(),
            ..a.clone()
        };
        assert!(!a.same_batch(&edited));
        assert_eq!(BatchRecord::from_toml(&a.to_toml().unwrap()).unwrap(), a);
    }

    #[test]
    fn a_folder_record_reads_back_as_written() {
        let r = FolderRecord {
            kind: "run".into(),
            coid_version: "0.1.0".into(),
            batch_run: Some(BatchRun {
                batch_digest: "ab".into(),
                master_seed: 1,
                run: 5,
            }),
            files: vec![FileEntry {
                path: "pooled/table1.csv".into(),
                bytes: 12,
            }],
        };
        assert_eq!(FolderRecord::from_toml(&r.to_toml().unwrap()).unwrap(), r);
        assert!(FolderRecord::from_toml("kind = 3").is_err());
    }
}
