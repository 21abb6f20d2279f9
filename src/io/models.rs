//! Trained models on disk: a method's weights, checked against the record
//! beside them (`<method>.toml`: architecture, checksum, how they were made,
//! what the validation runs chose), the loss curve, and the choices read
//! back.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::records::{
    self, BaselineEntry, BaselinesRecord, Lambda, LambdaByKind, ModelRecord, ValidationRecord,
};
use super::{OutputError, io, publish_files, write_text};
use crate::config::Settings;
use crate::matching::deep::arch::{Backbone, MaskScope};
use crate::matching::deep::decision::{Decision, KindLambdas, UncertaintyKind};
use crate::matching::deep::train::TrainReport;
use crate::matching::{BASELINES_FILE, BaselineValue, Method};

/// The weights file of a method in a models folder (a single-pass
/// variant's are those of the method it is one pass of).
pub fn weights_path(models_dir: &Path, method: Method) -> PathBuf {
    models_dir.join(format!("{}.bpk", method.weights_owner().as_str()))
}

#[derive(Debug, thiserror::Error)]
#[error(
    "cannot load the weights of '{method}' from {path} ({reason}); run `coid train --methods {method}` to make them"
)]
pub struct WeightsError {
    pub method: &'static str,
    pub path: PathBuf,
    pub reason: String,
}

/// A method's weights as read: the bytes and the width of the appearance
/// vectors its network reads (0: none).
#[derive(Clone, Debug)]
pub struct Weights {
    pub bytes: Vec<u8>,
    pub appearance_width: crate::sensor::AppearanceWidth,
    /// A published network's graph and indicator width, as it was
    /// trained.
    pub shape: crate::matching::deep::arch::NetworkShape,
}

/// The bytes of a method's weights file, checked against the record
/// beside it (`<method>.toml`: the method, its architecture and the
/// weights' checksum), so that stale or foreign weights never load.
pub fn read_weights(models_dir: &Path, method: Method) -> Result<Weights, WeightsError> {
    let method = method.weights_owner();
    let path = weights_path(models_dir, method);
    let bytes = read_model_file(method, &path, "no such file", |p| std::fs::read(p))?;
    let record = read_model_record(models_dir, method)?;
    let fail = model_error(method, &path);
    let Some(backbone) = method.backbone() else {
        return Err(fail("not a deep method".into()));
    };
    let appearance_width = record.architecture.appearance_width();
    let shape = record.architecture.shape();
    let backbone = backbone.with_appearance(appearance_width).with_shape(shape);
    record.check(method, &backbone, &bytes).map_err(fail)?;
    Ok(Weights {
        bytes,
        appearance_width,
        shape,
    })
}

/// Where the weights trained with another training seed live: a models
/// folder of its own, `seed-<seed>/`, inside the models folder.
pub fn seed_models_dir(models_dir: &Path, seed: u64) -> PathBuf {
    models_dir.join(format!("seed-{seed}"))
}

/// The training seed `method`'s weights in `models_dir` were made with
/// (their record's).
pub fn trained_seed(models_dir: &Path, method: Method) -> Result<u64, WeightsError> {
    Ok(read_model_record(models_dir, method)?.seed)
}

/// A method's `<method>.toml` (a single-pass variant's: its owner's).
pub fn read_model_record(models_dir: &Path, method: Method) -> Result<ModelRecord, WeightsError> {
    let method = method.weights_owner();
    let path = models_dir.join(format!("{}.toml", method.as_str()));
    let missing = "no record beside the weights";
    let text = read_model_file(method, &path, missing, |p| std::fs::read_to_string(p))?;
    ModelRecord::from_toml(&text).map_err(model_error(method, &path))
}

/// A `WeightsError` of `method` about `path`, for a reason.
fn model_error(method: Method, path: &Path) -> impl Fn(String) -> WeightsError + '_ {
    move |reason| WeightsError {
        method: method.as_str(),
        path: path.to_owned(),
        reason,
    }
}

/// Reads one file of a method's model, `missing` as the reason when it
/// does not exist.
fn read_model_file<T>(
    method: Method,
    path: &Path,
    missing: &str,
    read: impl FnOnce(&Path) -> std::io::Result<T>,
) -> Result<T, WeightsError> {
    read(path).map_err(|e| {
        model_error(method, path)(if e.kind() == std::io::ErrorKind::NotFound {
            missing.into()
        } else {
            e.to_string()
        })
    })
}

#[derive(Debug, thiserror::Error)]
#[error(
    "cannot read the baselines' validated thresholds from {path} ({reason}); run `coid train \
     --validate-only` to choose them, or set [matching] baselines = \"a-priori\""
)]
pub struct BaselinesError {
    pub path: PathBuf,
    pub reason: String,
}

/// Each baseline's threshold as `baselines.toml` of `models_dir` records
/// it; an error when the file is missing or malformed, or lacks one of
/// `methods` that has a threshold.
pub fn read_baselines(
    models_dir: &Path,
    methods: &[Method],
) -> Result<std::collections::BTreeMap<Method, BaselineValue>, BaselinesError> {
    let path = models_dir.join(BASELINES_FILE);
    let fail = |reason: String| BaselinesError {
        path: path.clone(),
        reason,
    };
    let text = std::fs::read_to_string(&path).map_err(|e| {
        fail(if e.kind() == std::io::ErrorKind::NotFound {
            "no such file".into()
        } else {
            e.to_string()
        })
    })?;
    let record = BaselinesRecord::from_toml(&text).map_err(fail)?;
    let values: std::collections::BTreeMap<Method, BaselineValue> = record
        .baselines
        .iter()
        .map(|b| {
            let value = BaselineValue {
                value: b.value,
                descriptor_weight: b.descriptor_weight.unwrap_or(1.0),
            };
            (b.method, value)
        })
        .collect();
    for m in methods.iter().filter(|m| m.baseline_knob().is_some()) {
        match values.get(m).map(|v| v.value) {
            Some(v) if v.is_finite() && v >= 0.0 => {}
            Some(v) => return Err(fail(format!("'{}' has value {v}", m.as_str()))),
            None => return Err(fail(format!("'{}' is not in it", m.as_str()))),
        }
    }
    Ok(values)
}

/// Records the baselines' thresholds chosen on the validation runs in
/// `baselines.toml` of `dir`, replacing the entries of the same methods
/// and keeping the others; renamed into place.
pub fn record_baselines(
    dir: &Path,
    settings: &Settings,
    chosen: &[BaselineEntry],
) -> Result<(), OutputError> {
    let path = dir.join(BASELINES_FILE);
    let mut kept: Vec<BaselineEntry> = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| BaselinesRecord::from_toml(&t).ok())
        .map(|r| r.baselines)
        .unwrap_or_default();
    kept.retain(|b| chosen.iter().all(|c| c.method != b.method));
    kept.extend(chosen.iter().cloned());
    kept.sort_by_key(|b| b.method);
    let t = &settings.train;
    let record = BaselinesRecord {
        config: settings.source.display().to_string(),
        dataset: settings
            .dataset
            .as_ref()
            .map(|d| d.dir.display().to_string()),
        validation_seeds: t.validation_seeds.clone(),
        validation_scenarios: t
            .validation_scenarios
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        baselines: kept,
    };
    let body = record.to_toml().map_err(OutputError::Batch)?;
    publish_files(dir, |tmp| write_text(&tmp.join(BASELINES_FILE), &body))
}

/// What `coid train` records beside each model's weights.
pub struct TrainingRecord<'a> {
    pub method: Method,
    pub settings: &'a Settings,
    pub n_examples: usize,
    pub report: &'a TrainReport,
    pub seconds: f64,
    /// The weights training started from (`[train] start_from`'s), as
    /// read; `None`: a seeded start.
    pub start: Option<&'a [u8]>,
}

/// What `coid train` chose for one method on the validation runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Validation {
    /// The entropy threshold with the best mean F1 over the validation
    /// runs and pose-noise levels (infinite: no threshold).
    pub lambda: f64,
    /// The decision rule chosen with it.
    pub decision: Decision,
    /// The operating point chosen with the rule: the least E[Y] of a
    /// decided pair.
    pub min_probability: f64,
    /// The calibration temperature fitted before both.
    pub temperature: f64,
    /// That mean F1.
    pub f1: f64,
    pub seeds: Vec<u64>,
    /// The uncertainty the threshold applies to.
    pub uncertainty: &'static str,
    /// The threshold chosen for each uncertainty type.
    pub lambdas: KindLambdas,
}

/// The record of a model just trained (no validation yet).
fn model_record(record: &TrainingRecord, weights: &[u8]) -> Result<ModelRecord, OutputError> {
    let t = &record.settings.train;
    let Some(backbone) = record.method.backbone() else {
        let method = record.method.as_str();
        return Err(OutputError::Batch(format!(
            "'{method}' is not a deep method"
        )));
    };
    let paths = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect();
    let start = t
        .start_from
        .as_ref()
        .map(|dir| weights_path(dir, record.method));
    let r = record.report;
    Ok(ModelRecord {
        method: record.method.as_str().to_owned(),
        architecture: backbone
            .with_appearance(record.settings.appearance_width())
            .with_shape(t.network),
        weights_fnv64: records::fnv64_hex(weights),
        config: record.settings.source.display().to_string(),
        dataset: record
            .settings
            .dataset
            .as_ref()
            .map(|d| d.dir.display().to_string()),
        train_traffic_seeds: t.traffic_seeds.clone(),
        train_scenarios: paths(&t.scenarios),
        runs_per_scenario: (!t.scenarios.is_empty()).then_some(t.runs_per_scenario),
        validation_scenarios: paths(&t.validation_scenarios),
        eval_traffic_seeds: record.settings.eval.traffic_seeds.clone(),
        epochs: t.epochs,
        learning_rate: t.learning_rate,
        seed: t.seed,
        examples: record.n_examples,
        steps: r.steps,
        seconds: (record.seconds * 10.0).round() / 10.0,
        final_epoch_loss: r.epoch_losses.last().copied(),
        edge_median_m: r.edges.median_m,
        edge_p95_m: r.edges.p95_m,
        edge_clipped_share: r.edges.clipped_share,
        loss: t.loss.as_str().to_owned(),
        mc_samples: t.mc_samples,
        dropout_masks: record
            .method
            .training_masks(t.dropout_masks, t.paper_dropout_masks),
        batch_size: t.batch_size,
        no_match: matches!(backbone, Backbone::Published(_)).then_some(t.no_match),
        patience: r.best_epoch.map(|_| t.patience),
        node_dropout: (t.augment.node_dropout > 0.0).then_some(t.augment.node_dropout),
        position_jitter_m: (t.augment.position_jitter_m > 0.0)
            .then_some(t.augment.position_jitter_m),
        start_from: start.map(|p| p.display().to_string()),
        start_weights_fnv64: record.start.map(records::fnv64_hex),
        best_epoch: r.best_epoch,
        validation: None,
        descriptor: None,
    })
}

/// Adds what the validation runs chose to the record that [`write_model`]
/// wrote (replacing an earlier choice), renamed into place.
pub fn record_validation(dir: &Path, method: Method, v: &Validation) -> Result<(), OutputError> {
    let mut record =
        read_model_record(dir, method).map_err(|e| OutputError::Batch(e.to_string()))?;
    record.validation = Some(ValidationRecord {
        seeds: v.seeds.clone(),
        uncertainty: v.uncertainty.to_owned(),
        lambda: Lambda::from_f64(v.lambda),
        decision: v.decision,
        min_probability: v.min_probability,
        temperature: v.temperature,
        f1: v.f1,
        lambdas: Some(LambdaByKind {
            entropy: Lambda::from_f64(v.lambdas.get(UncertaintyKind::Total)),
            epistemic: Lambda::from_f64(v.lambdas.get(UncertaintyKind::Epistemic)),
            aleatoric: Lambda::from_f64(v.lambdas.get(UncertaintyKind::Aleatoric)),
        }),
        note: crate::matching::deep::decision::temperature_at_bound(v.temperature),
    });
    let name = format!("{}.toml", method.as_str());
    let body = record.to_toml().map_err(OutputError::Batch)?;
    publish_files(dir, |tmp| write_text(&tmp.join(&name), &body))
}

/// Copies `method`'s model (weights, record, loss curve) from the
/// candidate folder `from` into `to`, its record noting the validation
/// runs' choice between reading the re-identification descriptor and not;
/// the files are renamed into place together.
pub fn adopt_candidate(
    from: &Path,
    to: &Path,
    method: Method,
    choice: records::DescriptorChoice,
) -> Result<(), OutputError> {
    let mut record =
        read_model_record(from, method).map_err(|e| OutputError::Batch(e.to_string()))?;
    record.descriptor = Some(choice);
    let body = record.to_toml().map_err(OutputError::Batch)?;
    let name = method.as_str();
    publish_files(to, |tmp| {
        for file in [format!("{name}.bpk"), format!("{name}_loss.csv")] {
            let (src, dst) = (from.join(&file), tmp.join(&file));
            std::fs::copy(&src, &dst).map_err(io(&src))?;
        }
        write_text(&tmp.join(format!("{name}.toml")), &body)
    })
}

/// What `coid train` chose for a deep method on the validation runs, as
/// its `<method>.toml` records it (each `None` when it records none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Validated {
    /// The threshold of each uncertainty type (infinite: no threshold).
    pub lambdas: Option<KindLambdas>,
    pub decision: Option<Decision>,
    /// The operating point chosen with the rule (0 in records without one).
    pub min_probability: f64,
    /// The calibration temperature of the reported probabilities.
    pub temperature: Option<f64>,
    /// The dropout masks the weights were trained with.
    pub trained_masks: MaskScope,
}

/// What `coid train` chose for `method` on the validation runs (its
/// `<method>.toml`); an error when the file is missing or malformed, or a
/// value it records is out of range.
pub fn read_validated(models_dir: &Path, method: Method) -> Result<Validated, WeightsError> {
    let method = method.weights_owner();
    let record = read_model_record(models_dir, method)?;
    let Some(v) = record.validation else {
        return Ok(Validated {
            lambdas: None,
            decision: None,
            min_probability: 0.0,
            temperature: None,
            trained_masks: record.dropout_masks,
        });
    };
    let fail = |reason: &str| WeightsError {
        method: method.as_str(),
        path: models_dir.join(format!("{}.toml", method.as_str())),
        reason: reason.to_owned(),
    };
    let lambdas = match v.lambdas {
        Some(by_kind) => {
            let read = |l: Lambda, kind: &str| {
                l.to_f64().ok_or_else(|| {
                    fail(&format!(
                        "validation.lambdas.{kind} is not in [0, 1] or \"none\""
                    ))
                })
            };
            Some(KindLambdas::from_values([
                read(by_kind.entropy, "entropy")?,
                read(by_kind.epistemic, "epistemic")?,
                read(by_kind.aleatoric, "aleatoric")?,
            ]))
        }
        None => None,
    };
    if !(v.temperature.is_finite() && v.temperature > 0.0) {
        return Err(fail("validation.temperature is not a positive number"));
    }
    if !(0.0..1.0).contains(&v.min_probability) {
        return Err(fail("validation.min_probability is not in [0, 1)"));
    }
    Ok(Validated {
        lambdas,
        decision: Some(v.decision),
        min_probability: v.min_probability,
        temperature: Some(v.temperature),
        trained_masks: record.dropout_masks,
    })
}

/// Writes a trained model into `dir`: `<method>.bpk` (the weights),
/// `<method>.toml` (config, seeds, data size, final loss, and the
/// validated lambda once known) and
/// `<method>_loss.csv` (mean loss per epoch, and the validation loss with
/// early stopping: epoch 0 is before training), each renamed into place
/// when complete.
fn loss_curve(report: &TrainReport) -> String {
    if report.validation_losses.is_empty() {
        let mut curve = String::from("epoch,mean_loss\n");
        for (k, l) in report.epoch_losses.iter().enumerate() {
            let _ = writeln!(curve, "{},{l:.6}", k + 1);
        }
        return curve;
    }
    let mut curve = String::from("epoch,mean_loss,validation_loss\n");
    for (k, v) in report.validation_losses.iter().enumerate() {
        let train = k
            .checked_sub(1)
            .and_then(|e| report.epoch_losses.get(e))
            .map_or(String::new(), |l| format!("{l:.6}"));
        let _ = writeln!(curve, "{k},{train},{v:.6}");
    }
    curve
}

pub fn write_model(dir: &Path, record: &TrainingRecord, weights: &[u8]) -> Result<(), OutputError> {
    let method = record.method.as_str();
    let curve = loss_curve(record.report);
    let meta = model_record(record, weights)?
        .to_toml()
        .map_err(OutputError::Batch)?;
    publish_files(dir, |tmp| {
        let bpk = tmp.join(format!("{method}.bpk"));
        std::fs::write(&bpk, weights).map_err(io(&bpk))?;
        write_text(&tmp.join(format!("{method}.toml")), &meta)?;
        write_text(&tmp.join(format!("{method}_loss.csv")), &curve)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_weights_name_the_method_and_the_remedy() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_weights(dir.path(), Method::Ours)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("'ours'") && e.contains("no such file") && e.contains("coid train"),
            "{e}"
        );
    }

    /// A record whose network convolves over the complete graph hands
    /// that graph to the matcher; the shipped ones the paper's Delaunay.
    #[test]
    fn the_weights_run_on_the_graph_their_record_names() {
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
        assert_eq!(
            read_weights(&shipped, Method::Coid).unwrap().shape,
            crate::matching::deep::arch::NetworkShape::default()
        );
        let dir = tempfile::tempdir().unwrap();
        std::fs::copy(shipped.join("coid.bpk"), dir.path().join("coid.bpk")).unwrap();
        let record = std::fs::read_to_string(shipped.join("coid.toml")).unwrap();
        let edited = record.replace("[architecture]\n", "[architecture]\ngraph = \"complete\"\n");
        assert_ne!(edited, record);
        std::fs::write(dir.path().join("coid.toml"), edited).unwrap();
        assert_eq!(
            read_weights(dir.path(), Method::Coid).unwrap().shape.graph,
            crate::matching::deep::arch::NetworkGraph::Complete
        );
    }

    /// The models `configs/reid.toml` evaluates load, every seed of a
    /// method made the same choice about the descriptor (so the seeds are
    /// one recipe), and the weights are what the choice says.
    #[test]
    fn the_shipped_reid_models_load_with_their_descriptor_choice() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/reid");
        for method in [Method::Coid, Method::Ours] {
            let mut reads = Vec::new();
            for dir in [root.clone(), root.join("seed-8"), root.join("seed-9")] {
                let w = read_weights(&dir, method).unwrap();
                let record = read_model_record(&dir, method).unwrap();
                let choice = record.descriptor.expect("a descriptor choice");
                assert_eq!(
                    choice.reads,
                    !w.appearance_width.is_none(),
                    "{}",
                    dir.display()
                );
                assert_eq!(choice.reads, choice.f1_reading > choice.f1_without);
                reads.push(choice);
            }
            assert!(reads.windows(2).all(|p| p[0] == p[1]), "{reads:?}");
        }
    }

    /// Regression: a record whose first layer is narrower than class,
    /// colour and size underflowed the appearance width (a panic in debug
    /// builds); it is refused as no architecture of this coid.
    #[test]
    fn a_record_narrower_than_the_node_attributes_is_another_architecture() {
        let dir = tempfile::tempdir().unwrap();
        let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
        std::fs::copy(models.join("ours.bpk"), dir.path().join("ours.bpk")).unwrap();
        let record = std::fs::read_to_string(models.join("ours.toml")).unwrap();
        assert!(record.contains("node_features = 13"), "{record}");
        let narrow = record.replace("node_features = 13", "node_features = 5");
        std::fs::write(dir.path().join("ours.toml"), narrow).unwrap();
        let e = read_weights(dir.path(), Method::Ours)
            .unwrap_err()
            .to_string();
        assert!(e.contains("is narrower than class, colour and size"), "{e}");
    }
}
