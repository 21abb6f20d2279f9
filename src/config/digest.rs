//! What a configuration makes a run do, as one digest: the settings
//! (their `Debug` text, `[v2x]` shown only when not at its defaults, paths
//! left out) and the bytes of every file a run reads. Batches
//! (`batch.toml`) and exports (`runs.parquet`) record it, so its value for
//! a given configuration must not change without a new version.
//!
//! Format versions: 1 before `[sensor] unset_colours`; 2 since it
//! (always in the text): a road user whose demand gives no colour was
//! SUMO's yellow before and is drawn since, so every digest changed once
//! and batches or exports made before are refused, never mixed.

use std::path::{Path, PathBuf};

use super::{ConfigError, Settings};
use crate::fusion::FusionSettings;
use crate::matching::deep::arch::{MaskChoice, MaskScope, PairLoss};
use crate::matching::deep::decision::UncertaintyKind;
use crate::matching::{
    BaselineChoice, DecisionChoice, LambdaChoice, MatchingSettings, MethodKind, MultiVehicle,
};
use crate::rng::Seeds;

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
        let tuned = self.matching.baselines == BaselineChoice::Validated
            && self
                .matching
                .methods
                .iter()
                .any(|m| m.baseline_knob().is_some());
        if tuned {
            let p = self
                .matching
                .models_dir
                .join(crate::matching::BASELINES_FILE);
            d.file(&self.source, &p)?;
        }
        for m in &self.matching.methods {
            if let MethodKind::Deep = m.kind() {
                for ext in ["bpk", "toml"] {
                    let p = self
                        .matching
                        .models_dir
                        .join(format!("{}.{ext}", m.weights_owner().as_str()));
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
            baselines: BaselineChoice::APriori,
            gate_chi2: 0.0,
            models_dir: PathBuf::new(),
            mc_samples: 0,
            dropout_masks: MaskChoice::Shared,
            mc_dropout: None,
            lambda: LambdaChoice::Validated,
            decision: DecisionChoice::Validated,
            uncertainty: UncertaintyKind::Total,
            sender_as_node: self.matching.sender_as_node,
            multi_vehicle: MultiVehicle::Pairwise,
            rematch: 0,
            indicators: crate::matching::deep::arch::IndicatorScope::PerSample,
        };
        s.fusion = FusionSettings {
            variants: Vec::new(),
            align_min_matches: 0,
        };
        let t = &mut s.train;
        (t.methods, t.epochs, t.learning_rate, t.seed) = (Vec::new(), 0, 0.0, 0);
        (t.patience, t.mc_samples, t.batch_size) = (0, 0, 0);
        t.loss = PairLoss::Likelihood;
        t.dropout_masks = MaskScope::PerNode;
        t.paper_dropout_masks = MaskScope::PerNode;
        t.no_match = crate::matching::deep::arch::NoMatchWeights::Entries;
        t.appearance_vectors = true;
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
pub(super) fn sumocfg_inputs(text: &str) -> Vec<String> {
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
