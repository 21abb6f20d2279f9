//! What coid writes as one folder ([`ResultKind`]), the identity file it
//! leaves in each (`.coid-folder.toml`: the kind and every file with its
//! size), and what each kind may hold for `--force` to replace it or a
//! command to extend it ([`ResultKind::check`]).

use std::path::Path;

use super::records::{BatchRecord, FileEntry, FolderRecord, ModelRecord};
use super::staging::is_staging_name;

/// The identity file of a folder coid wrote as one piece.
pub const IDENTITY: &str = ".coid-folder.toml";

/// What a command writes as one folder.
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
    /// A dataset (`coid export`, `coid convert`): Parquet files, `schema.md`.
    Export,
    /// Trackers and messages over a run (`coid track`): `tracking.csv`,
    /// `association.csv`; or a sweep: `sweep.csv`, `sweep_latency.*`.
    Track,
    /// A detector profile measured on the validation runs (`coid
    /// detector`): `detector.csv`.
    Detector,
}

const KINDS: [ResultKind; 10] = [
    ResultKind::Run,
    ResultKind::Eval,
    ResultKind::Render,
    ResultKind::Batch,
    ResultKind::Scenario,
    ResultKind::Family,
    ResultKind::Models,
    ResultKind::Export,
    ResultKind::Track,
    ResultKind::Detector,
];

impl ResultKind {
    /// What such a folder is, for messages.
    pub fn label(self) -> &'static str {
        match self {
            ResultKind::Run => "a run's results (coid run)",
            ResultKind::Eval => "an evaluation (coid eval or score)",
            ResultKind::Render => "pictures (coid render)",
            ResultKind::Batch => "a batch (coid batch or merge)",
            ResultKind::Scenario => "a generated scenario (coid scenarios)",
            ResultKind::Family => "a family of generated scenarios (coid scenarios)",
            ResultKind::Models => "a models folder (coid train)",
            ResultKind::Export => "a dataset (coid export or convert)",
            ResultKind::Track => "tracking results (coid track)",
            ResultKind::Detector => "a detector report (coid detector)",
        }
    }

    /// The kind's name in identity files.
    pub(super) fn name(self) -> &'static str {
        match self {
            ResultKind::Run => "run",
            ResultKind::Eval => "eval",
            ResultKind::Render => "render",
            ResultKind::Batch => "batch",
            ResultKind::Scenario => "scenario",
            ResultKind::Family => "family",
            ResultKind::Models => "models",
            ResultKind::Export => "export",
            ResultKind::Track => "track",
            ResultKind::Detector => "detector",
        }
    }

    fn from_name(name: &str) -> Option<Self> {
        KINDS.into_iter().find(|k| k.name() == name)
    }

    /// `Ok` when `dir` is a folder of this kind that coid wrote and that
    /// still holds what it wrote, so that `--force` may replace (or a
    /// command extend) it; else why not.
    pub fn check(self, dir: &Path) -> Result<(), String> {
        match self {
            ResultKind::Batch => check_batch(dir),
            ResultKind::Models => check_models(dir),
            ResultKind::Family => check_family(dir),
            _ => check_whole(dir, self).map(drop),
        }
    }
}

/// The identity of a folder coid wrote as one piece, and `Ok` only when
/// the folder holds exactly the files it lists, at their sizes.
pub(super) fn check_whole(dir: &Path, kind: ResultKind) -> Result<FolderRecord, String> {
    let record = read_identity(dir)?;
    if record.kind != kind.name() {
        let other = ResultKind::from_name(&record.kind).map_or("another kind", |k| k.label());
        return Err(format!("it holds {other}"));
    }
    let found = files_in(dir).map_err(|e| e.to_string())?;
    for f in &record.files {
        match found.iter().find(|g| g.path == f.path) {
            None => return Err(format!("{} is missing since coid wrote it", f.path)),
            Some(g) if g.bytes != f.bytes => {
                return Err(format!("{} changed since coid wrote it", f.path));
            }
            Some(_) => {}
        }
    }
    if let Some(extra) = found.iter().find(|g| !record.files.contains(g)) {
        return Err(format!(
            "it holds {}, which coid did not write there",
            extra.path
        ));
    }
    Ok(record)
}

/// A folder's identity file, read and parsed.
pub fn read_identity(dir: &Path) -> Result<FolderRecord, String> {
    let text = std::fs::read_to_string(dir.join(IDENTITY)).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            format!("coid did not write it (it has no {IDENTITY})")
        } else {
            format!("cannot read its {IDENTITY}: {e}")
        }
    })?;
    FolderRecord::from_toml(&text).map_err(|e| format!("its {IDENTITY} is not coid's ({e})"))
}

/// Every file under `dir` but the identity, by relative `/`-separated
/// path, sorted, with its size. A symbolic link counts as a file of size 0
/// (never followed).
pub(super) fn files_in(dir: &Path) -> std::io::Result<Vec<FileEntry>> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<FileEntry>) -> std::io::Result<()> {
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let meta = std::fs::symlink_metadata(e.path())?;
            if meta.is_dir() {
                walk(root, &e.path(), out)?;
                continue;
            }
            let rel = e.path();
            let rel = rel.strip_prefix(root).unwrap_or(&rel);
            let path: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            let path = path.join("/");
            if path != IDENTITY {
                let bytes = if meta.is_file() { meta.len() } else { 0 };
                out.push(FileEntry { path, bytes });
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out)?;
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

/// A batch folder: its `batch.toml` a batch record, its other files the
/// aggregate, `runs/` holding only run folders coid wrote (whole or
/// damaged: a batch reruns those).
fn check_batch(dir: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(dir.join("batch.toml"))
        .map_err(|_| "it is not a batch folder (no batch.toml)".to_owned())?;
    BatchRecord::from_toml(&text)
        .map_err(|e| format!("its batch.toml is not a batch record of this coid ({e})"))?;
    for e in std::fs::read_dir(dir).map_err(|e| e.to_string())? {
        let e = e.map_err(|e| e.to_string())?;
        let name = e.file_name().to_string_lossy().into_owned();
        let fine = match name.as_str() {
            IDENTITY | "batch.toml" | "summary.csv" | "summary.md" | "f1_per_method.png"
            | "f1_per_method.svg" => true,
            "runs" => check_runs(&e.path()).is_ok(),
            _ => is_staging_name(&name),
        };
        if !fine {
            return Err(format!("it holds {name}, which coid did not write there"));
        }
    }
    check_runs(&dir.join("runs"))
}

/// `runs/` of a batch: only run folders coid wrote (or nothing).
fn check_runs(runs: &Path) -> Result<(), String> {
    let Ok(entries) = std::fs::read_dir(runs) else {
        return Ok(());
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if is_staging_name(&name) {
            continue;
        }
        match read_identity(&e.path()) {
            Ok(r) if r.kind == ResultKind::Run.name() => {}
            _ => return Err(format!("runs/{name} is not a run folder coid wrote")),
        }
    }
    Ok(())
}

/// A models folder: only `<method>.bpk`, `<method>.toml` (a model record,
/// as `coid train` writes it) and `<method>_loss.csv` of known methods,
/// `baselines.toml` (the baselines' validated thresholds), and folders
/// that are models folders themselves (another training seed's,
/// `seed-N`, or another descriptor's, as the shipped `models/reid`).
fn check_models(dir: &Path) -> Result<(), String> {
    for e in std::fs::read_dir(dir).map_err(|e| e.to_string())? {
        let e = e.map_err(|e| e.to_string())?;
        let name = e.file_name().to_string_lossy().into_owned();
        if is_staging_name(&name) {
            continue;
        }
        // Another training seed's models (`coid train --seed N`: into
        // `<models>/seed-N`) or another configuration's: a models folder
        // of its own.
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            check_models(&e.path()).map_err(|why| format!("{name}: {why}"))?;
            continue;
        }
        if name == crate::matching::BASELINES_FILE {
            let text = std::fs::read_to_string(e.path()).unwrap_or_default();
            if super::records::BaselinesRecord::from_toml(&text).is_err() {
                return Err(format!("it holds {name}, which coid did not write there"));
            }
            continue;
        }
        let method = ["_loss.csv", ".bpk", ".toml"]
            .iter()
            .find_map(|ext| name.strip_suffix(ext))
            .filter(|m| crate::label::parse::<crate::matching::Method>("method", m).is_ok());
        let fine = method.is_some()
            && (!name.ends_with(".toml")
                || std::fs::read_to_string(e.path())
                    .is_ok_and(|t| ModelRecord::from_toml(&t).is_ok()));
        if !fine || !e.path().is_file() {
            return Err(format!("it holds {name}, which coid did not write there"));
        }
    }
    Ok(())
}

/// A family of scenarios: its identity (kind family), `README.md`, and
/// scenario folders (each claimed on its own when it is written again).
fn check_family(dir: &Path) -> Result<(), String> {
    let record = read_identity(dir)?;
    if record.kind != ResultKind::Family.name() {
        return Err("it is not a family of scenarios coid wrote".into());
    }
    for e in std::fs::read_dir(dir).map_err(|e| e.to_string())? {
        let e = e.map_err(|e| e.to_string())?;
        let name = e.file_name().to_string_lossy().into_owned();
        let fine = match name.as_str() {
            IDENTITY | "README.md" => true,
            _ if is_staging_name(&name) => true,
            _ => e.path().is_dir(),
        };
        if !fine {
            return Err(format!("it holds {name}, which coid did not write there"));
        }
    }
    Ok(())
}
