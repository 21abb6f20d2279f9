//! The output side: everything that writes result files, and the reading of
//! weight files and batch folders. Results are never lost or half-written:
//!
//! - a results folder (run, eval, render, a batch's run) is filled under a
//!   temporary name beside it and renamed into place when complete
//!   ([`atomic_dir`]); an existing folder is replaced only when asked, and
//!   only once the new one is complete;
//! - files added to an existing folder (a batch's aggregate, trained
//!   models) are staged in a temporary folder inside it and renamed into
//!   place one by one ([`publish_files`]).
//!
//! Temporary folders come from `tempfile` (removed on every error path).
//! `frames` is the only code that touches polars; `markdown` writes the
//! human-readable reports.

pub mod assets;
pub mod frames;
pub mod markdown;
pub mod records;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use polars::prelude::PolarsError;

use crate::config::Settings;
use crate::matching::deep::decision::Decision;
use crate::matching::deep::train::TrainReport;
use crate::matching::{DeepChoice, Method};
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
}

pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io {
        path: path.to_owned(),
        source,
    }
}

/// A temporary folder in `parent` named `.<name>.tmp-<pid>-XXXXXX`, with
/// the permissions a plain `mkdir` would give (tempfile's default is
/// 0700). Staging folders of `name` left by processes that no longer run
/// (killed, interrupted) are removed first.
fn staging_dir(parent: &Path, name: &str) -> Result<tempfile::TempDir, OutputError> {
    remove_stale_staging(parent, name);
    let prefix = format!(".{name}.tmp-{}-", std::process::id());
    let mut b = tempfile::Builder::new();
    b.prefix(&prefix);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o777));
    }
    b.tempdir_in(parent).map_err(io(parent))
}

/// Removes `parent/.<name>.tmp-<pid>-*` whose process is gone (best
/// effort: a folder that cannot be removed stays).
fn remove_stale_staging(parent: &Path, name: &str) {
    let prefix = format!(".{name}.tmp-");
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    for e in entries.flatten() {
        let file_name = e.file_name();
        let Some(rest) = file_name.to_str().and_then(|n| n.strip_prefix(&prefix)) else {
            continue;
        };
        let pid = rest.split('-').next().and_then(|p| p.parse::<i32>().ok());
        if pid.is_some_and(|p| !process_runs(p)) {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Whether process `pid` exists (signal 0 probes without sending).
fn process_runs(pid: i32) -> bool {
    if pid <= 0 {
        return false;
    }
    // SAFETY: kill with signal 0 only checks for the process.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Refuses `out` before any work when it exists (and not `force`), or
/// when its folder cannot be written: a staging folder is made there and
/// removed again.
pub fn check_output(out: &Path, existing: Existing) -> Result<(), OutputError> {
    Staged::new(out, existing).map(drop)
}

/// What a command writes as one folder: `--force` replaces an existing
/// folder only when it holds nothing but what this kind of command
/// writes (so never a user's folder, another command's results, or the
/// inputs of the run: configs and scenarios are not among those files).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResultKind {
    /// `summary.csv`, `objects.parquet`, `summary.md`.
    Run,
    /// CSV tables, `summary.md`, PNG and SVG pictures; for a suite, one
    /// such folder per scenario.
    Eval,
    /// `instance-NNNN.png` and `.svg`.
    Render,
    /// `batch.toml`, `runs/` of run folders, the aggregate.
    Batch,
    /// One generated scenario: its SUMO files, `coid.toml`, `README.md`.
    Scenario,
    /// A family of generated scenarios: `README.md` and scenario folders.
    Family,
    /// Trained models: `<method>.bpk`, `.toml`, `_loss.csv`.
    Models,
    /// An export of instances (`coid export`): Parquet files, `schema.md`.
    Export,
    /// Trackers and messages over a run (`coid track`): `tracking.csv`,
    /// `association.csv`; or a sweep: `sweep.csv`, `sweep_latency.*`.
    Track,
}

impl ResultKind {
    fn label(self) -> &'static str {
        match self {
            ResultKind::Run => "a run's results (coid run)",
            ResultKind::Eval => "an evaluation (coid eval)",
            ResultKind::Render => "pictures (coid render)",
            ResultKind::Batch => "a batch (coid batch or merge)",
            ResultKind::Scenario => "a generated scenario (coid scenarios)",
            ResultKind::Family => "a family of generated scenarios (coid scenarios)",
            ResultKind::Models => "a models folder (coid train)",
            ResultKind::Export => "an export (coid export)",
            ResultKind::Track => "tracking results (coid track)",
        }
    }

    /// Whether the file `name` (in a folder of this kind) is one it writes.
    fn writes_file(self, name: &str) -> bool {
        let ext = |e: &str| name.ends_with(e);
        match self {
            ResultKind::Run => matches!(name, "summary.csv" | "objects.parquet" | "summary.md"),
            ResultKind::Eval => ext(".csv") || ext(".md") || ext(".png") || ext(".svg"),
            ResultKind::Render => name.starts_with("instance-") && (ext(".png") || ext(".svg")),
            ResultKind::Batch => matches!(
                name,
                "batch.toml"
                    | "summary.csv"
                    | "summary.md"
                    | "f1_per_method.png"
                    | "f1_per_method.svg"
            ),
            ResultKind::Scenario => {
                ext(".xml") || ext(".sumocfg") || matches!(name, "coid.toml" | "README.md")
            }
            ResultKind::Family => name == "README.md",
            ResultKind::Models => ext(".bpk") || ext(".toml") || ext("_loss.csv"),
            ResultKind::Export => ext(".parquet") || name == "schema.md",
            ResultKind::Track => {
                matches!(name, "tracking.csv" | "association.csv" | "sweep.csv")
                    || name.starts_with("sweep_latency.")
            }
        }
    }

    /// `Ok` when `dir` holds only what this kind writes.
    fn check(self, dir: &Path) -> Result<(), String> {
        let entries = std::fs::read_dir(dir).map_err(|e| e.to_string())?;
        for e in entries {
            let e = e.map_err(|e| e.to_string())?;
            let name = e.file_name().to_string_lossy().into_owned();
            let path = e.path();
            let fine = if path.is_dir() {
                match self {
                    ResultKind::Eval => ResultKind::Eval.check(&path).is_ok(),
                    ResultKind::Family => ResultKind::Scenario.check(&path).is_ok(),
                    ResultKind::Batch if name == "runs" => std::fs::read_dir(&path)
                        .map_err(|e| e.to_string())?
                        .all(|r| r.is_ok_and(|r| ResultKind::Run.check(&r.path()).is_ok())),
                    _ => false,
                }
            } else {
                self.writes_file(&name) || name.starts_with('.')
            };
            if !fine {
                return Err(format!("it holds {name}, which coid did not write there"));
            }
        }
        Ok(())
    }
}

/// What to do when an output folder exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Existing {
    /// Refuse (no `--force`).
    Refuse,
    /// Replace it if it is a folder of this kind (`--force`).
    Replace(ResultKind),
}

impl Existing {
    /// `Replace(kind)` with `--force`, else `Refuse`.
    pub fn when(force: bool, kind: ResultKind) -> Self {
        if force {
            Existing::Replace(kind)
        } else {
            Existing::Refuse
        }
    }

    /// `Ok` when `out` may be written.
    fn allows(self, out: &Path) -> Result<(), OutputError> {
        if !out.exists() {
            return Ok(());
        }
        match self {
            Existing::Refuse => Err(OutputError::Exists(out.to_owned())),
            Existing::Replace(kind) => kind.check(out).map_err(|why| OutputError::NotReplaceable {
                path: out.to_owned(),
                kind: kind.label(),
                why,
            }),
        }
    }
}

/// Creates `out` atomically: `fill` writes into a temporary sibling folder,
/// which then replaces `out` (when it exists: as `existing` says).
/// Whatever `fill` fails with is returned, and nothing is left behind.
pub fn atomic_dir<E: From<OutputError>>(
    out: &Path,
    existing: Existing,
    fill: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let staged = Staged::new(out, existing)?;
    fill(staged.dir.path())?;
    staged.publish()?;
    Ok(())
}

/// A folder being filled under a temporary name beside `out`.
struct Staged {
    out: PathBuf,
    parent: PathBuf,
    name: String,
    dir: tempfile::TempDir,
}

impl Staged {
    /// Refused when `out` exists and `existing` does not allow it.
    fn new(out: &Path, existing: Existing) -> Result<Self, OutputError> {
        existing.allows(out)?;
        let parent = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(io(&parent))?;
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        let dir = staging_dir(&parent, &name)?;
        Ok(Self {
            out: out.to_owned(),
            parent,
            name,
            dir,
        })
    }

    fn publish(self) -> Result<(), OutputError> {
        replace_dir(self.dir, &self.out, &self.parent, &self.name)
    }
}

/// A run's results folder while the run goes on: `objects.parquet` grows
/// in a temporary folder beside `out`, row group by row group;
/// [`RunFolder::finish`] adds `summary.csv` and `summary.md` and renames
/// the folder into place. Dropped unfinished (an error, a panic), it
/// leaves nothing behind and `out` untouched.
pub struct RunFolder {
    staged: Staged,
    objects: frames::ObjectsWriter,
}

impl RunFolder {
    /// Refused at once when `out` exists and not `force`, or cannot be
    /// written.
    pub fn create(out: &Path, force: bool) -> Result<Self, OutputError> {
        let staged = Staged::new(out, Existing::when(force, ResultKind::Run))?;
        let objects = frames::ObjectsWriter::create(&staged.dir.path().join("objects.parquet"))?;
        Ok(Self { staged, objects })
    }

    /// Adds per-object rows to `objects.parquet`.
    pub fn objects(&mut self, rows: &[ObjectRow]) -> Result<(), OutputError> {
        self.objects.write(rows)
    }

    /// Completes the folder: `objects.parquet`, `summary.csv`, `summary.md`.
    pub fn finish(self, settings: &Settings, results: &RunResults) -> Result<(), OutputError> {
        self.objects.finish()?;
        let dir = self.staged.dir.path();
        let rows = results.summary.rows();
        frames::write_summary(&dir.join("summary.csv"), &rows)?;
        write_text(
            &dir.join("summary.md"),
            &markdown::run(settings, results, &rows),
        )?;
        self.staged.publish()
    }
}

/// A folder of Parquet tables written as the work goes on (`coid
/// export`): each file grows row group by row group in a temporary folder
/// beside `out`; [`TablesFolder::finish`] adds text files and renames the
/// folder into place. Dropped unfinished, it leaves nothing behind.
pub struct TablesFolder {
    staged: Staged,
    files: Vec<(String, frames::TableWriter)>,
}

impl TablesFolder {
    /// One Parquet file per `(name, template)`, with the template's
    /// columns. Refused at once when `out` exists and `existing` does not
    /// allow it, or cannot be written.
    pub fn create(
        out: &Path,
        existing: Existing,
        files: &[(&str, Table)],
    ) -> Result<Self, OutputError> {
        let staged = Staged::new(out, existing)?;
        let files = files
            .iter()
            .map(|(name, template)| {
                let path = staged.dir.path().join(name);
                Ok((
                    (*name).to_owned(),
                    frames::TableWriter::create(&path, template)?,
                ))
            })
            .collect::<Result<_, OutputError>>()?;
        Ok(Self { staged, files })
    }

    /// Appends `table` to the file `name` (one of those it was made with).
    pub fn write(&mut self, name: &str, table: &Table) -> Result<(), OutputError> {
        match self.files.iter_mut().find(|(n, _)| n == name) {
            Some((_, w)) => w.write(table),
            None => Err(OutputError::Batch(format!("no table file {name}"))),
        }
    }

    /// Completes every file, adds `texts` and renames the folder into place.
    pub fn finish(self, texts: &[(&str, String)]) -> Result<(), OutputError> {
        for (_, w) in self.files {
            w.finish()?;
        }
        write_texts(self.staged.dir.path(), texts)?;
        self.staged.publish()
    }
}

/// Renames the complete `staged` folder to `out`; an old `out` moves into a
/// temporary folder first and is removed once the new one is in place.
fn replace_dir(
    staged: tempfile::TempDir,
    out: &Path,
    parent: &Path,
    name: &str,
) -> Result<(), OutputError> {
    let old = if out.exists() {
        let old = staging_dir(parent, &format!("{name}.old"))?;
        std::fs::rename(out, old.path().join(name)).map_err(io(out))?;
        Some(old)
    } else {
        None
    };
    let staged = staged.keep();
    std::fs::rename(&staged, out).map_err(|e| {
        let _ = std::fs::remove_dir_all(&staged);
        io(out)(e)
    })?;
    drop(old);
    Ok(())
}

/// Adds files to the existing folder `dir`: `fill` writes them into a
/// temporary folder inside `dir`, then each is renamed into place (an
/// existing file of the same name is replaced).
pub fn publish_files(
    dir: &Path,
    fill: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let staged = staging_dir(dir, "staging")?;
    fill(staged.path())?;
    let mut names: Vec<_> = std::fs::read_dir(staged.path())
        .map_err(io(staged.path()))?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()
        .map_err(io(staged.path()))?;
    names.sort();
    for name in names {
        let dst = dir.join(&name);
        std::fs::rename(staged.path().join(&name), &dst).map_err(io(&dst))?;
    }
    Ok(())
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
/// `out`, atomically.
pub fn write_tracking(
    out: &Path,
    existing: Existing,
    tables: &[(&str, &Table)],
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    atomic_dir(out, existing, |dir| {
        for (name, t) in tables {
            frames::write_table(&dir.join(name), t)?;
        }
        plots(dir)
    })
}

/// Writes `coid eval`'s tables (CSV), its `summary.md` and whatever `plots`
/// draws into `out`, atomically.
pub fn write_eval(
    out: &Path,
    settings: &Settings,
    tables: &[(&str, &Table)],
    choices: &std::collections::BTreeMap<Method, DeepChoice>,
    pooled: Option<&str>,
    existing: Existing,
    plots: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    atomic_dir(out, existing, |dir| -> Result<(), OutputError> {
        for (name, t) in tables {
            frames::write_table(&dir.join(name), t)?;
        }
        write_text(
            &dir.join("summary.md"),
            &markdown::eval(settings, tables, choices, pooled),
        )?;
        plots(dir)
    })
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
    let (arch, _) =
        crate::matching::deep::variant(method).ok_or_else(|| fail("not a deep method".into()))?;
    record.check(method, &arch, &bytes).map_err(fail)?;
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
    let (architecture, _) = crate::matching::deep::variant(record.method).ok_or_else(|| {
        OutputError::Batch(format!("'{}' is not a deep method", record.method.as_str()))
    })?;
    let paths = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect();
    let r = record.report;
    Ok(ModelRecord {
        method: record.method.as_str().to_owned(),
        architecture,
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

/// Whether a run folder is complete and whole: its three files, the
/// summary not cut short, the Parquet file with both its magic numbers
/// (a damaged folder is run again by a resumed batch).
pub fn run_is_complete(run_dir: &Path) -> bool {
    let summary = std::fs::read_to_string(run_dir.join("summary.csv")).unwrap_or_default();
    summary_is_whole(&summary)
        && std::fs::metadata(run_dir.join("summary.md")).is_ok_and(|m| m.len() > 0)
        && frames::parquet_is_whole(&run_dir.join("objects.parquet"))
}

/// Whether a run's `summary.csv` is whole: a header, at least one row,
/// every row with the header's number of fields, ended by a newline (a
/// file cut short fails one of these).
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

/// Claims `dir` for the batch described by `identity` (its `batch.toml`):
/// creates it, or accepts it when it holds the same batch; a folder of
/// another batch is refused.
pub fn claim_batch_folder(dir: &Path, identity: &BatchRecord) -> Result<(), OutputError> {
    let has_entries = std::fs::read_dir(dir).is_ok_and(|mut d| d.next().is_some());
    if has_entries && !dir.join("batch.toml").is_file() {
        return Err(OutputError::Batch(format!(
            "{} exists and is not a batch folder (no batch.toml); choose another --out",
            dir.display()
        )));
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    if !dir.join("batch.toml").is_file() {
        return write_batch_identity(dir, identity);
    }
    let existing = batch_identity(dir)?;
    if existing.same_batch(identity) {
        return Ok(());
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

/// The complete run folders under `<batch_dir>/runs`, sorted by name.
pub fn completed_runs(batch_dir: &Path) -> Result<Vec<PathBuf>, OutputError> {
    let runs = batch_dir.join("runs");
    if !runs.is_dir() {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(&runs).map_err(io(&runs))? {
        let p = e.map_err(io(&runs))?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.starts_with("run-") && run_is_complete(&p) {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

/// The summary rows of each complete run, in run order.
pub fn read_runs(run_dirs: &[PathBuf]) -> Result<Vec<Vec<RunRow>>, OutputError> {
    let mut dirs = run_dirs.to_vec();
    dirs.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    dirs.iter()
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

/// Copies a complete run folder (flat: files only) into `dst` atomically.
pub fn copy_run(src: &Path, dst: &Path) -> Result<(), OutputError> {
    atomic_dir(
        dst,
        Existing::Replace(ResultKind::Run),
        |tmp| -> Result<(), OutputError> {
            for e in std::fs::read_dir(src).map_err(io(src))? {
                let p = e.map_err(io(src))?.path();
                if p.is_file() {
                    let to = tmp.join(p.file_name().unwrap_or_default());
                    std::fs::copy(&p, &to).map_err(io(&to))?;
                }
            }
            Ok(())
        },
    )
}

/// Writes a batch's identity (`batch.toml`).
pub fn write_batch_identity(dir: &Path, identity: &BatchRecord) -> Result<(), OutputError> {
    let text = identity.to_toml().map_err(OutputError::Batch)?;
    publish_files(dir, |tmp| write_text(&tmp.join("batch.toml"), &text))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_folder_appears_complete_or_not_at_all() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        // A failing fill leaves nothing behind.
        let run = Existing::Replace(ResultKind::Eval);
        let e = atomic_dir(&out, Existing::Refuse, |d| -> Result<(), OutputError> {
            std::fs::write(d.join("a.csv"), "half").unwrap();
            Err(OutputError::Batch("boom".into()))
        });
        assert!(e.is_err());
        assert!(names(root.path()).is_empty(), "{:?}", names(root.path()));
        // A complete one appears; an existing one is kept without force...
        atomic_dir(&out, Existing::Refuse, |d| {
            write_text(&d.join("a.csv"), "one")
        })
        .unwrap();
        assert!(matches!(
            atomic_dir(&out, Existing::Refuse, |_| -> Result<(), OutputError> {
                Ok(())
            }),
            Err(OutputError::Exists(_))
        ));
        // ...and replaced with force, only once the new one is complete.
        let e = atomic_dir(&out, run, |_| Err(OutputError::Batch("no".into())));
        assert!(e.is_err());
        assert_eq!(std::fs::read_to_string(out.join("a.csv")).unwrap(), "one");
        atomic_dir(&out, run, |d| write_text(&d.join("b.csv"), "two")).unwrap();
        assert_eq!(names(&out), vec!["b.csv"]);
        assert_eq!(names(root.path()), vec!["res"]);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&out).unwrap().permissions().mode();
            assert_ne!(
                mode & 0o055,
                0,
                "a results folder is readable by others: {mode:o}"
            );
        }
    }

    /// Staging folders left by processes that are gone (killed) are
    /// removed when the same folder is written again; those of a live
    /// process stay.
    #[test]
    fn stale_staging_folders_of_dead_processes_are_removed() {
        let root = tempfile::tempdir().unwrap();
        // Above Linux's pid_max: no such process.
        let dead = root.path().join(".res.tmp-2147483000-abc123");
        let live = root
            .path()
            .join(format!(".res.tmp-{}-def456", std::process::id()));
        for d in [&dead, &live] {
            std::fs::create_dir_all(d).unwrap();
        }
        let out = root.path().join("res");
        atomic_dir(&out, Existing::Refuse, |d| {
            write_text(&d.join("a.csv"), "x")
        })
        .unwrap();
        assert!(!dead.exists());
        assert!(live.exists());
    }

    #[test]
    fn published_files_replace_old_ones_and_leave_no_staging() {
        let dir = tempfile::tempdir().unwrap();
        write_text(&dir.path().join("summary.csv"), "old").unwrap();
        publish_files(dir.path(), |t| {
            write_text(&t.join("summary.csv"), "new")?;
            write_text(&t.join("summary.md"), "md")
        })
        .unwrap();
        assert_eq!(names(dir.path()), vec!["summary.csv", "summary.md"]);
        assert_eq!(
            std::fs::read_to_string(dir.path().join("summary.csv")).unwrap(),
            "new"
        );
        assert!(publish_files(dir.path(), |_| Err(OutputError::Batch("x".into()))).is_err());
        assert_eq!(names(dir.path()), vec!["summary.csv", "summary.md"]);
    }

    #[test]
    fn a_batch_folder_belongs_to_one_batch() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().join("b");
        let id = |digest: &str, runs: usize, path: &str| BatchRecord {
            config_digest: digest.into(),
            runs,
            master_seed: 1,
            config: path.into(),
        };
        claim_batch_folder(&d, &id("ab", 4, "/x/c.toml")).unwrap();
        // The same batch from a config at another path resumes.
        claim_batch_folder(&d, &id("ab", 4, "/y/c.toml")).unwrap();
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
