//! The output side: everything that writes result files, and the reading of
//! weight files and batch folders. Results are never lost or half-written:
//!
//! - a results folder (run, eval, render, a batch's run, ...) is claimed
//!   before the work starts, filled under a temporary name beside it and
//!   renamed into place when complete, never over anything it did not
//!   expect ([`folder::Claim`]);
//! - files added to an existing folder (a batch's aggregate, trained
//!   models) are staged in a temporary folder inside it and renamed into
//!   place one by one ([`publish_files`]).
//!
//! Temporary folders come from `tempfile` (removed on every error path,
//! and on interruption through `crate::interrupt`). `frames` is the only
//! code that touches polars; `markdown` writes the human-readable reports.

pub mod assets;
pub mod folder;
pub mod frames;
pub mod markdown;
pub mod records;

pub use folder::{Claim, Existing, ResultKind, check_extendable, publish_files};

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use polars::prelude::PolarsError;

use crate::config::Settings;
use crate::matching::deep::decision::Decision;
use crate::matching::deep::train::TrainReport;
use crate::matching::{DeepChoice, Method, MethodKind};
use crate::report::{AggregateRow, ObjectRow, RunResults, RunRow, Table};
use records::{BatchRecord, Lambda, ModelRecord, ValidationRecord};

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error(
        "output folder {0} already exists (choose another --out, or pass --force to replace it)"
    )]
    Exists(PathBuf),
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Polars { path: PathBuf, source: PolarsError },
    #[error("cannot draw into {path}: {message}")]
    Picture { path: PathBuf, message: String },
    #[error("{0}")]
    Batch(String),
    #[error("{0}")]
    Install(String),
    #[error("--force does not replace {path}: it is not {kind} ({why})")]
    NotReplaceable {
        path: PathBuf,
        kind: &'static str,
        why: String,
    },
    #[error("{path} is not a folder coid can write: it is {what} (choose another --out)")]
    NotAFolder { path: PathBuf, what: String },
    #[error(
        "another coid (pid {pid}) is writing {path} now (wait for it to finish, or choose another --out)"
    )]
    Busy { path: PathBuf, pid: u32 },
    #[error(
        "{path} appeared while this command ran (something else wrote there; it was left as it is); this command's results are in {kept}"
    )]
    Appeared { path: PathBuf, kept: PathBuf },
    #[error(
        "{path} changed while this command ran, so --force did not replace it (it was left as it is); this command's results are in {kept}"
    )]
    Changed { path: PathBuf, kept: PathBuf },
}

impl OutputError {
    /// A picture that could not be drawn into `dir`, and why.
    pub fn picture(dir: &Path, why: impl std::fmt::Display) -> Self {
        OutputError::Picture {
            path: dir.to_owned(),
            message: why.to_string(),
        }
    }
}

pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_owned(),
        source,
    }
}

/// A run's results folder while the run goes on: `objects.parquet` grows
/// in the claimed folder's staging folder, row group by row group;
/// [`RunFolder::finish`] adds `summary.csv` and `summary.md` and publishes
/// it. Dropped unfinished (an error, a panic), it leaves nothing behind
/// and `out` untouched.
pub struct RunFolder {
    claim: Claim,
    objects: frames::ObjectsWriter,
}

impl RunFolder {
    /// Starts `objects.parquet` in the claimed folder.
    pub fn create(claim: Claim) -> Result<Self, OutputError> {
        let objects = frames::ObjectsWriter::create(&claim.dir().join("objects.parquet"))?;
        Ok(Self { claim, objects })
    }

    /// Adds per-object rows to `objects.parquet`.
    pub fn objects(&mut self, rows: &[ObjectRow]) -> Result<(), OutputError> {
        self.objects.write(rows)
    }

    /// Completes the folder: `objects.parquet`, `summary.csv`, `summary.md`.
    pub fn finish(self, settings: &Settings, results: &RunResults) -> Result<(), OutputError> {
        self.objects.finish()?;
        let dir = self.claim.dir();
        let rows = results.summary.rows();
        frames::write_summary(&dir.join("summary.csv"), &rows)?;
        write_text(
            &dir.join("summary.md"),
            &markdown::run(settings, results, &rows),
        )?;
        self.claim.publish()
    }
}

/// A folder of Parquet tables written as the work goes on (`coid
/// export`): each file grows row group by row group in the claimed
/// folder's staging folder; [`TablesFolder::finish`] adds text files and
/// publishes it. Dropped unfinished, it leaves nothing behind.
pub struct TablesFolder {
    claim: Claim,
    files: Vec<(String, frames::TableWriter)>,
}

impl TablesFolder {
    /// One Parquet file per `(name, template)`, with the template's
    /// columns, in the claimed folder.
    pub fn create(claim: Claim, files: &[(&str, Table)]) -> Result<Self, OutputError> {
        let files = files
            .iter()
            .map(|(name, template)| {
                let path = claim.dir().join(name);
                Ok((
                    (*name).to_owned(),
                    frames::TableWriter::create(&path, template)?,
                ))
            })
            .collect::<Result<_, OutputError>>()?;
        Ok(Self { claim, files })
    }

    /// Appends `table` to the file `name` (one of those it was made with).
    pub fn write(&mut self, name: &str, table: &Table) -> Result<(), OutputError> {
        match self.files.iter_mut().find(|(n, _)| n == name) {
            Some((_, w)) => w.write(table),
            None => Err(OutputError::Batch(format!("no table file {name}"))),
        }
    }

    /// Completes every file, adds `texts` and publishes the folder.
    pub fn finish(self, texts: &[(&str, String)]) -> Result<(), OutputError> {
        for (_, w) in self.files {
            w.finish()?;
        }
        write_texts(self.claim.dir(), texts)?;
        self.claim.publish()
    }
}

/// Writes each `(file name, text)` into `dir`.
pub fn write_texts(dir: &Path, files: &[(&str, String)]) -> Result<(), OutputError> {
    files
        .iter()
        .try_for_each(|(name, text)| write_text(&dir.join(name), text))
}

/// Removes the comment SUMO's tools put at the top of an XML file (the
/// tool version, the time it ran and the absolute paths of its options), so
/// that the same inputs give the same bytes.
pub fn strip_generator_comment(path: &Path) -> Result<(), OutputError> {
    let text = std::fs::read_to_string(path).map_err(io(path))?;
    let stripped = match (text.find("<!-- generated on"), text.find("-->")) {
        (Some(a), Some(b)) if a < b => {
            let rest = text[b + 3..].trim_start_matches(['\r', '\n']);
            format!("{}{rest}", &text[..a])
        }
        _ => return Ok(()),
    };
    write_text(path, &stripped)
}

fn write_text(path: &Path, text: &str) -> Result<(), OutputError> {
    std::fs::write(path, text).map_err(io(path))
}

/// Writes `coid track`'s tables (CSV) and whatever `plots` draws into
/// `dir`.
pub fn write_tracking(
    dir: &Path,
    tables: &[(&str, &Table)],
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    for (name, t) in tables {
        frames::write_table(&dir.join(name), t)?;
    }
    plots(dir)
}

/// Writes `coid eval`'s tables (CSV), its `summary.md` and whatever `plots`
/// draws into `dir` (made if missing).
pub fn write_eval(
    dir: &Path,
    settings: &Settings,
    tables: &[(&str, &Table)],
    choices: &std::collections::BTreeMap<Method, DeepChoice>,
    pooled: Option<&str>,
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    for (name, t) in tables {
        frames::write_table(&dir.join(name), t)?;
    }
    write_text(
        &dir.join("summary.md"),
        &markdown::eval(settings, tables, choices, pooled),
    )?;
    plots(dir)
}

// ---------------------------------------------------------------------------
// Trained models.
// ---------------------------------------------------------------------------

/// The weights file of a method in a models folder.
pub fn weights_path(models_dir: &Path, method: Method) -> PathBuf {
    models_dir.join(format!("{}.bpk", method.as_str()))
}

#[derive(Debug, thiserror::Error)]
#[error(
    "cannot load the weights of '{method}' from {path} ({reason}); run `coid train` to make them"
)]
pub struct WeightsError {
    pub method: &'static str,
    pub path: PathBuf,
    pub reason: String,
}

/// The bytes of a method's weights file, checked against the record
/// beside it (`<method>.toml`: the method, its architecture and the
/// weights' checksum), so that stale or foreign weights never load.
pub fn read_weights(models_dir: &Path, method: Method) -> Result<Vec<u8>, WeightsError> {
    let path = weights_path(models_dir, method);
    let bytes = read_model_file(method, &path, "no such file", |p| std::fs::read(p))?;
    let record = read_record(models_dir, method)?;
    let fail = model_error(method, &path);
    let MethodKind::Deep(deep) = method.kind() else {
        return Err(fail("not a deep method".into()));
    };
    record
        .check(method, &deep.architecture(), &bytes)
        .map_err(fail)?;
    Ok(bytes)
}

/// A method's `<method>.toml`.
fn read_record(models_dir: &Path, method: Method) -> Result<ModelRecord, WeightsError> {
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

/// What `coid train` records beside each model's weights.
pub struct TrainingRecord<'a> {
    pub method: Method,
    pub settings: &'a Settings,
    pub n_examples: usize,
    pub report: &'a TrainReport,
    pub seconds: f64,
}

/// What `coid train` chose for one method on the validation runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Validation {
    /// The entropy threshold with the best mean F1 over the validation
    /// runs and pose-noise levels (infinite: no threshold).
    pub lambda: f64,
    /// The decision rule chosen with it.
    pub decision: Decision,
    /// The calibration temperature fitted before both.
    pub temperature: f64,
    /// That mean F1.
    pub f1: f64,
    pub seeds: Vec<u64>,
    /// The uncertainty the threshold applies to.
    pub uncertainty: &'static str,
}

/// The record of a model just trained (no validation yet).
fn model_record(record: &TrainingRecord, weights: &[u8]) -> Result<ModelRecord, OutputError> {
    let t = &record.settings.train;
    let MethodKind::Deep(deep) = record.method.kind() else {
        let method = record.method.as_str();
        return Err(OutputError::Batch(format!(
            "'{method}' is not a deep method"
        )));
    };
    let paths = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect();
    let r = record.report;
    Ok(ModelRecord {
        method: record.method.as_str().to_owned(),
        architecture: deep.architecture(),
        weights_fnv64: records::fnv64_hex(weights),
        config: record.settings.source.display().to_string(),
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
        batch_size: t.batch_size,
        patience: r.best_epoch.map(|_| t.patience),
        best_epoch: r.best_epoch,
        validation: None,
    })
}

/// Adds what the validation runs chose to the record that [`write_model`]
/// wrote (replacing an earlier choice), renamed into place.
pub fn record_validation(dir: &Path, method: Method, v: &Validation) -> Result<(), OutputError> {
    let mut record = read_record(dir, method).map_err(|e| OutputError::Batch(e.to_string()))?;
    record.validation = Some(ValidationRecord {
        seeds: v.seeds.clone(),
        uncertainty: v.uncertainty.to_owned(),
        lambda: Lambda::from_f64(v.lambda),
        decision: v.decision,
        temperature: v.temperature,
        f1: v.f1,
    });
    let name = format!("{}.toml", method.as_str());
    let body = record.to_toml().map_err(OutputError::Batch)?;
    publish_files(dir, |tmp| write_text(&tmp.join(&name), &body))
}

/// What `coid train` chose for a deep method on the validation runs, as
/// its `<method>.toml` records it (each `None` when it records none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Validated {
    /// The entropy threshold (infinite: no threshold).
    pub lambda: Option<f64>,
    pub decision: Option<Decision>,
    /// The calibration temperature of the reported probabilities.
    pub temperature: Option<f64>,
}

/// What `coid train` chose for `method` on the validation runs (its
/// `<method>.toml`); an error when the file is missing or malformed, or a
/// value it records is out of range.
pub fn read_validated(models_dir: &Path, method: Method) -> Result<Validated, WeightsError> {
    let record = read_record(models_dir, method)?;
    let Some(v) = record.validation else {
        return Ok(Validated {
            lambda: None,
            decision: None,
            temperature: None,
        });
    };
    let fail = |reason: &str| WeightsError {
        method: method.as_str(),
        path: models_dir.join(format!("{}.toml", method.as_str())),
        reason: reason.to_owned(),
    };
    let lambda = v
        .lambda
        .to_f64()
        .ok_or_else(|| fail("validation.lambda is not in [0, 1] or \"none\""))?;
    if !(v.temperature.is_finite() && v.temperature > 0.0) {
        return Err(fail("validation.temperature is not a positive number"));
    }
    Ok(Validated {
        lambda: Some(lambda),
        decision: Some(v.decision),
        temperature: Some(v.temperature),
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

// ---------------------------------------------------------------------------
// Batch folders.
// ---------------------------------------------------------------------------

/// The folder of run `i` in a batch folder.
pub fn run_dir(batch_dir: &Path, i: usize) -> PathBuf {
    batch_dir.join("runs").join(format!("run-{i:06}"))
}

/// Whether run `i` of `batch` is complete and whole in `batch_dir`: its
/// identity names this batch and run, it holds exactly the files that
/// identity lists, the summary has its rows and the Parquet file both its
/// magic numbers (anything else is run again by a resumed batch).
pub fn run_is_complete(batch_dir: &Path, batch: &BatchRecord, i: usize) -> bool {
    let dir = run_dir(batch_dir, i);
    let summary = std::fs::read_to_string(dir.join("summary.csv")).unwrap_or_default();
    folder::is_batch_run(&dir, &batch.run(i))
        && summary_is_whole(&summary)
        && std::fs::metadata(dir.join("summary.md")).is_ok_and(|m| m.len() > 0)
        && frames::parquet_is_whole(&dir.join("objects.parquet"))
}

/// Whether a run's `summary.csv` is whole: a header, at least one row (a
/// run without instances has one per method, level and fusion variant,
/// with `n_instances` 0), every row with the header's number of fields,
/// ended by a newline (a file cut short fails one of these).
fn summary_is_whole(text: &str) -> bool {
    let mut lines = text.lines();
    let Some(header) = lines.next() else {
        return false;
    };
    let fields = |l: &str| l.split(',').count();
    let n = fields(header);
    let rows: Vec<&str> = lines.collect();
    header.starts_with("method,")
        && !rows.is_empty()
        && text.ends_with('\n')
        && rows.iter().all(|r| fields(r) == n && !r.is_empty())
}

/// A batch folder held by this process: an exclusive lock on the folder,
/// released when dropped (or when the process ends, however it ends), so
/// that two `coid batch` never work in one folder at once.
#[derive(Debug)]
pub struct BatchLock {
    _folder: std::fs::File,
}

/// Claims `dir` for the batch described by `identity` (its `batch.toml`):
/// creates it, or accepts it when it holds the same batch; a folder of
/// another batch, a folder that is not a batch's, and a folder another
/// `coid batch` works in now are refused.
pub fn claim_batch_folder(dir: &Path, identity: &BatchRecord) -> Result<BatchLock, OutputError> {
    match folder::check_extendable(dir, ResultKind::Batch, Existing::Replace) {
        Ok(()) => {}
        Err(OutputError::NotReplaceable { why, .. }) => {
            let empty = std::fs::read_dir(dir).is_ok_and(|mut d| d.next().is_none());
            if !dir.join("batch.toml").is_file() && !empty {
                return Err(OutputError::Batch(format!(
                    "{} exists and is not a batch folder (no batch.toml); choose another --out",
                    dir.display()
                )));
            }
            if !empty {
                return Err(OutputError::Batch(format!(
                    "{} holds a batch this coid cannot resume ({why}); choose another --out",
                    dir.display()
                )));
            }
        }
        Err(e) => return Err(e),
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let lock = lock_folder(dir)?;
    if !dir.join("batch.toml").is_file() {
        write_batch_identity(dir, identity)?;
        return Ok(lock);
    }
    let existing = batch_identity(dir)?;
    if existing.same_batch(identity) {
        return Ok(lock);
    }
    let what = if existing.runs != identity.runs || existing.master_seed != identity.master_seed {
        format!(
            "{} runs from master seed {}",
            existing.runs, existing.master_seed
        )
    } else {
        format!(
            "its configuration or a file it reads has changed since (digest {} then, {} now)",
            existing.config_digest, identity.config_digest
        )
    };
    Err(OutputError::Batch(format!(
        "{} holds a different batch ({what}); choose another --out",
        dir.display()
    )))
}

/// Takes the exclusive lock of a batch folder (`flock` on the folder).
fn lock_folder(dir: &Path) -> Result<BatchLock, OutputError> {
    use std::os::fd::AsRawFd;
    let f = std::fs::File::open(dir).map_err(io(dir))?;
    // SAFETY: flock on a descriptor this function owns.
    let r = unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if r != 0 {
        let e = std::io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
            return Err(OutputError::Batch(format!(
                "another coid batch is working in {} now (wait for it to finish, or choose another --out)",
                dir.display()
            )));
        }
        return Err(io(dir)(e));
    }
    Ok(BatchLock { _folder: f })
}

/// The identity (`batch.toml`) of a batch folder.
pub fn batch_identity(dir: &Path) -> Result<BatchRecord, OutputError> {
    let text = std::fs::read_to_string(dir.join("batch.toml")).map_err(|_| {
        OutputError::Batch(format!(
            "{} is not a batch folder (no batch.toml)",
            dir.display()
        ))
    })?;
    BatchRecord::from_toml(&text).map_err(|e| {
        OutputError::Batch(format!(
            "{}: batch.toml is not a batch record of this coid ({e})",
            dir.display()
        ))
    })
}

/// The complete runs of `batch` in `batch_dir`, as (run index, folder), in
/// run order; folders under `runs/` that are not whole runs of this batch
/// are left out.
pub fn completed_runs(batch_dir: &Path, batch: &BatchRecord) -> Vec<(usize, PathBuf)> {
    (0..batch.runs)
        .filter(|&i| run_is_complete(batch_dir, batch, i))
        .map(|i| (i, run_dir(batch_dir, i)))
        .collect()
}

/// The summary rows of each run folder, in the order given.
pub fn read_runs(run_dirs: &[PathBuf]) -> Result<Vec<Vec<RunRow>>, OutputError> {
    run_dirs
        .iter()
        .map(|d| frames::read_run_summary(&d.join("summary.csv")))
        .collect()
}

/// Writes a batch's aggregate (`summary.csv`, `summary.md`) and whatever
/// `plots` draws into its folder, each file renamed into place.
pub fn write_batch_summary(
    dir: &Path,
    rows: &[AggregateRow],
    header: &str,
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    publish_files(dir, |tmp| {
        frames::write_aggregate(&tmp.join("summary.csv"), rows)?;
        write_text(&tmp.join("summary.md"), &markdown::batch(rows, header))?;
        plots(tmp)
    })
}

/// Copies a complete run folder (its files and identity) to `dst`.
pub fn copy_run(src: &Path, dst: &Path) -> Result<(), OutputError> {
    folder::copy_folder(src, dst)
}

/// Writes a batch's identity (`batch.toml`).
pub fn write_batch_identity(dir: &Path, identity: &BatchRecord) -> Result<(), OutputError> {
    let text = identity.to_toml().map_err(OutputError::Batch)?;
    publish_files(dir, |tmp| write_text(&tmp.join("batch.toml"), &text))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_folder_belongs_to_one_batch() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("b");
        let id = |digest: &str, runs: usize, path: &str| BatchRecord {
            config_digest: digest.into(),
            runs,
            master_seed: 1,
            config: path.into(),
            config_text: String::new(),
        };
        drop(claim_batch_folder(&d, &id("ab", 4, "/x/c.toml")).unwrap());
        // The same batch from a config at another path resumes, but not
        // while another claim holds the folder.
        let held = claim_batch_folder(&d, &id("ab", 4, "/y/c.toml")).unwrap();
        let e = claim_batch_folder(&d, &id("ab", 4, "/y/c.toml"))
            .map(drop)
            .unwrap_err();
        assert!(e.to_string().contains("another coid batch"), "{e}");
        drop(held);
        let e = claim_batch_folder(&d, &id("ab", 5, "/x/c.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("different batch (4 runs from master seed 1)"),
            "{e}"
        );
        let e = claim_batch_folder(&d, &id("cd", 4, "/x/c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("has changed since"), "{e}");
        assert_eq!(batch_identity(&d).unwrap(), id("ab", 4, "/x/c.toml"));
        assert!(batch_identity(dir.path()).is_err());
    }

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
}
