//! Output folders are claimed, not checked. A command that writes a
//! folder claims `--out` before its work starts ([`Claim::new`]): what is
//! there is looked at once (nothing; or, with `--force`, a folder of the
//! same kind that coid wrote, whose state is remembered), and a staging
//! folder is made beside it (`.<name>.tmp-<pid>-XXXXXX`). The work fills
//! the staging folder; [`Claim::publish`] writes the folder's identity
//! (`.coid-folder.toml`: its kind and every file it holds) and renames it
//! into place with a rename that never replaces what it did not expect:
//!
//! - nothing was there: an atomic rename that fails if anything appeared
//!   meanwhile (Linux `RENAME_NOREPLACE`);
//! - a folder was to be replaced (`--force`): it is moved aside, compared
//!   with its state at the claim, and only then removed; a folder that
//!   changed meanwhile is put back.
//!
//! When the rename is refused, the new results are not lost: they are
//! renamed to `<name>.coid-<pid>` beside `--out` and the error says so.
//!
//! Staging folders of processes that are gone (killed outright) are
//! removed when any folder is next claimed in the same parent; while a
//! live coid fills a staging folder for the same `--out`, a second claim
//! is refused. Folders that grow over several commands (a batch, a models
//! folder, a family of scenarios) are identified per kind instead
//! ([`ResultKind::check`]).

use std::path::{Path, PathBuf};

use super::records::{BatchRecord, BatchRun, FileEntry, FolderRecord, ModelRecord};
use super::staging::{is_staging_name, keep_beside, other_writer, rename_noreplace, staging_dir};
use super::{OutputError, io};

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
    /// An export of instances (`coid export`): Parquet files, `schema.md`.
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
            ResultKind::Export => "an export (coid export)",
            ResultKind::Track => "tracking results (coid track)",
            ResultKind::Detector => "a detector report (coid detector)",
        }
    }

    /// The kind's name in identity files.
    fn name(self) -> &'static str {
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
fn check_whole(dir: &Path, kind: ResultKind) -> Result<FolderRecord, String> {
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
fn files_in(dir: &Path) -> std::io::Result<Vec<FileEntry>> {
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
/// as `coid train` writes it) and `<method>_loss.csv` of known methods, and
/// `baselines.toml` (the baselines' validated thresholds).
fn check_models(dir: &Path) -> Result<(), String> {
    for e in std::fs::read_dir(dir).map_err(|e| e.to_string())? {
        let e = e.map_err(|e| e.to_string())?;
        let name = e.file_name().to_string_lossy().into_owned();
        if is_staging_name(&name) {
            continue;
        }
        // Another training seed's models (`coid train --seed N`: into
        // `<models>/seed-N`), a models folder of its own.
        if e.path().is_dir()
            && name
                .strip_prefix("seed-")
                .is_some_and(|s| s.parse::<u64>().is_ok())
        {
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

/// What to do when an output folder exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Existing {
    /// Refuse (no `--force`).
    Refuse,
    /// Replace it if it is a folder of the same kind that coid wrote and
    /// that holds what coid wrote there (`--force`).
    Replace,
    /// Replace any run folder coid wrote, whole or damaged (a batch's
    /// worker, for a run the batch found incomplete).
    Rerun,
}

impl Existing {
    /// `Replace` with `--force`, else `Refuse`.
    pub fn when(force: bool) -> Self {
        if force {
            Existing::Replace
        } else {
            Existing::Refuse
        }
    }
}

/// `Ok` when `out` may be written by a command of `kind` without being
/// claimed (folders that grow: a models folder, a family of scenarios):
/// it does not exist, or it is a folder of that kind and `existing` allows
/// adding to it.
pub fn check_extendable(
    out: &Path,
    kind: ResultKind,
    existing: Existing,
) -> Result<(), OutputError> {
    match what_is_at(out)? {
        None => Ok(()),
        Some(()) if existing == Existing::Refuse => Err(OutputError::Exists(out.to_owned())),
        Some(()) => kind.check(out).map_err(|why| OutputError::NotReplaceable {
            path: out.to_owned(),
            kind: kind.label(),
            why,
        }),
    }
}

/// `Some` when a folder is at `out`, `None` when nothing is; an error when
/// a file or a symbolic link is (never followed or replaced).
fn what_is_at(out: &Path) -> Result<Option<()>, OutputError> {
    let not_a_folder = |what: String| OutputError::NotAFolder {
        path: out.to_owned(),
        what,
    };
    if out.file_name().is_none() {
        return Err(not_a_folder("not a folder name".into()));
    }
    match std::fs::symlink_metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io(out)(e)),
        Ok(m) if m.file_type().is_symlink() => {
            let to = std::fs::read_link(out)
                .map(|t| t.display().to_string())
                .unwrap_or_default();
            let what = if out.exists() {
                format!("a symbolic link (to {to})")
            } else {
                format!("a symbolic link to {to}, which does not exist")
            };
            Err(not_a_folder(what))
        }
        Ok(m) if !m.is_dir() => Err(not_a_folder("a file".into())),
        Ok(_) => Ok(Some(())),
    }
}

/// The state of a folder at its claim, compared before it is replaced:
/// every entry under it with its size and modification time.
#[derive(Debug, PartialEq)]
struct Fingerprint(Vec<(String, u64, Option<std::time::SystemTime>)>);

fn fingerprint(dir: &Path) -> std::io::Result<Fingerprint> {
    fn walk(
        dir: &Path,
        prefix: &str,
        out: &mut Vec<(String, u64, Option<std::time::SystemTime>)>,
    ) -> std::io::Result<()> {
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let meta = std::fs::symlink_metadata(e.path())?;
            let name = format!("{prefix}{}", e.file_name().to_string_lossy());
            out.push((name.clone(), meta.len(), meta.modified().ok()));
            if meta.is_dir() {
                walk(&e.path(), &format!("{name}/"), out)?;
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, "", &mut out)?;
    out.sort();
    Ok(Fingerprint(out))
}

/// An output folder claimed by this process: filled in [`Claim::dir`],
/// then published with [`Claim::publish`]. Dropped unpublished (an error,
/// a panic), it leaves nothing behind and `out` untouched; on SIGINT or
/// SIGTERM the staging folder is removed too (`crate::interrupt`).
pub struct Claim {
    out: PathBuf,
    parent: PathBuf,
    name: String,
    kind: ResultKind,
    /// The state of the folder `--force` is to replace, if one was there.
    found: Option<Fingerprint>,
    batch_run: Option<BatchRun>,
    _registered: crate::interrupt::Registered,
    staging: tempfile::TempDir,
}

impl Claim {
    /// Claims `out` for a command that writes a folder of `kind`: refused
    /// at once when something is there that `existing` does not allow,
    /// when another coid is filling the same folder now, or when its
    /// parent cannot be written.
    pub fn new(out: &Path, kind: ResultKind, existing: Existing) -> Result<Claim, OutputError> {
        let found = match what_is_at(out)? {
            None => None,
            Some(()) => {
                let allowed = match existing {
                    Existing::Refuse => return Err(OutputError::Exists(out.to_owned())),
                    Existing::Replace => kind.check(out),
                    Existing::Rerun => read_identity(out).and_then(|r| {
                        (r.kind == kind.name())
                            .then_some(())
                            .ok_or_else(|| "it is not a run folder".to_owned())
                    }),
                };
                allowed.map_err(|why| OutputError::NotReplaceable {
                    path: out.to_owned(),
                    kind: kind.label(),
                    why,
                })?;
                Some(fingerprint(out).map_err(io(out))?)
            }
        };
        let parent = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(io(&parent))?;
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        // Registered as it is made: Ctrl-C from here on removes it.
        let (staging, registered) =
            crate::interrupt::make_registered(|| staging_dir(&parent, &name))?;
        if let Some(pid) = other_writer(&parent, &name, staging.path()) {
            return Err(OutputError::Busy {
                path: out.to_owned(),
                pid,
            });
        }
        Ok(Claim {
            out: out.to_owned(),
            parent,
            name,
            kind,
            found,
            batch_run: None,
            _registered: registered,
            staging,
        })
    }

    /// Marks the folder as run `batch_run.run` of a batch (its identity
    /// says so).
    pub fn of_batch_run(mut self, batch_run: BatchRun) -> Self {
        self.batch_run = Some(batch_run);
        self
    }

    /// Where to write the folder's files.
    pub fn dir(&self) -> &Path {
        self.staging.path()
    }

    /// The folder's final place.
    pub fn out(&self) -> &Path {
        &self.out
    }

    /// Fills the folder with `fill`, then publishes it.
    pub fn fill<E: From<OutputError>>(
        self,
        fill: impl FnOnce(&Path) -> Result<(), E>,
    ) -> Result<(), E> {
        fill(self.dir())?;
        self.publish()?;
        Ok(())
    }

    /// Writes the identity and renames the complete folder into place (see
    /// the module documentation); when that is refused, keeps it beside
    /// `out` and says where.
    pub fn publish(self) -> Result<(), OutputError> {
        let record = FolderRecord {
            kind: self.kind.name().to_owned(),
            coid_version: env!("CARGO_PKG_VERSION").to_owned(),
            batch_run: self.batch_run.clone(),
            files: files_in(self.dir()).map_err(io(self.dir()))?,
        };
        let text = record.to_toml().map_err(OutputError::Batch)?;
        let identity = self.dir().join(IDENTITY);
        std::fs::write(&identity, text).map_err(io(&identity))?;
        let Claim {
            out,
            parent,
            name,
            found,
            _registered,
            staging,
            ..
        } = self;
        let staged = staging.path().to_owned();
        let Some(before) = found else {
            return match rename_noreplace(&staged, &out) {
                Ok(()) => {
                    let _ = staging.keep();
                    Ok(())
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let kept = keep_beside(staging, &parent, &name)?;
                    Err(OutputError::Appeared { path: out, kept })
                }
                Err(e) => Err(io(&out)(e)),
            };
        };
        // Move the old folder aside, then make sure it is what was claimed.
        let aside = staging_dir(&parent, &format!("{name}.old"))?;
        let old = aside.path().join("old");
        std::fs::rename(&out, &old).map_err(io(&out))?;
        if fingerprint(&old).ok().as_ref() != Some(&before) {
            let back = rename_noreplace(&old, &out);
            if back.is_ok() {
                drop(aside);
            } else {
                let _ = keep_beside(aside, &parent, &format!("{name}.old"));
            }
            let kept = keep_beside(staging, &parent, &name)?;
            return Err(OutputError::Changed { path: out, kept });
        }
        match rename_noreplace(&staged, &out) {
            Ok(()) => {
                let _ = staging.keep();
                drop(aside);
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let _ = keep_beside(aside, &parent, &format!("{name}.old"));
                let kept = keep_beside(staging, &parent, &name)?;
                Err(OutputError::Appeared { path: out, kept })
            }
            Err(e) => Err(io(&out)(e)),
        }
    }
}

/// Adds files (or folders) to the existing folder `dir`: `fill` writes
/// them into a temporary folder inside `dir`, then each is renamed into
/// place in name order (an existing file or folder of the same name is
/// replaced: a folder is moved aside first and removed with the temporary
/// folder). Interrupted before the renames, `dir` is as it was.
pub fn publish_files<E: From<OutputError>>(
    dir: &Path,
    fill: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let (staged, _registered) = crate::interrupt::make_registered(|| staging_dir(dir, "staging"))?;
    fill(staged.path())?;
    let mut names: Vec<_> = std::fs::read_dir(staged.path())
        .map_err(io(staged.path()))?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()
        .map_err(io(staged.path()))?;
    names.sort();
    let aside = staged.path().join(".replaced");
    for name in names {
        let dst = dir.join(&name);
        if std::fs::symlink_metadata(&dst).is_ok_and(|m| m.is_dir()) {
            std::fs::create_dir_all(&aside).map_err(io(&aside))?;
            std::fs::rename(&dst, aside.join(&name)).map_err(io(&dst))?;
        }
        std::fs::rename(staged.path().join(&name), &dst).map_err(io(&dst))?;
    }
    Ok(())
}

/// Whether `dir` is run `expected.run` of the batch `expected` names, whole:
/// its identity says so and it holds exactly the files it lists.
pub fn is_batch_run(dir: &Path, expected: &BatchRun) -> bool {
    check_whole(dir, ResultKind::Run).is_ok_and(|r| r.batch_run.as_ref() == Some(expected))
}

/// Copies a folder coid wrote (its files and its identity) into `dst`,
/// which must not exist.
pub fn copy_folder(src: &Path, dst: &Path) -> Result<(), OutputError> {
    std::fs::create_dir_all(dst).map_err(io(dst))?;
    for e in std::fs::read_dir(src).map_err(io(src))? {
        let p = e.map_err(io(src))?.path();
        let to = dst.join(p.file_name().unwrap_or_default());
        if p.is_dir() {
            copy_folder(&p, &to)?;
        } else {
            std::fs::copy(&p, &to).map_err(io(&to))?;
        }
    }
    Ok(())
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

    fn write(dir: &Path, name: &str, text: &str) -> Result<(), OutputError> {
        let p = dir.join(name);
        std::fs::write(&p, text).map_err(io(&p))
    }

    #[test]
    fn a_folder_appears_complete_or_not_at_all() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        let claim = |e| Claim::new(&out, ResultKind::Eval, e);
        // A failing fill leaves nothing behind.
        let e = claim(Existing::Refuse).unwrap().fill(|d| {
            write(d, "a.csv", "half")?;
            Err(OutputError::Batch("boom".into()))
        });
        assert!(e.is_err());
        assert!(names(root.path()).is_empty(), "{:?}", names(root.path()));
        // A complete one appears, with its identity; an existing one is
        // kept without force...
        claim(Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "a.csv", "one"))
            .unwrap();
        assert_eq!(names(&out), vec![IDENTITY, "a.csv"]);
        assert!(matches!(
            claim(Existing::Refuse).map(drop),
            Err(OutputError::Exists(_))
        ));
        // ...and replaced with force, only once the new one is complete.
        let e = claim(Existing::Replace)
            .unwrap()
            .fill(|_| Err(OutputError::Batch("no".into())));
        assert!(e.is_err());
        assert_eq!(std::fs::read_to_string(out.join("a.csv")).unwrap(), "one");
        claim(Existing::Replace)
            .unwrap()
            .fill(|d| write(d, "b.csv", "two"))
            .unwrap();
        assert_eq!(names(&out), vec![IDENTITY, "b.csv"]);
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

    /// What appears at `out` while a command runs is never replaced: the
    /// new results are kept beside it; a folder `--force` was to replace
    /// that changed meanwhile is put back.
    #[test]
    fn a_claimed_folder_never_replaces_what_appeared_or_changed() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        let c = Claim::new(&out, ResultKind::Run, Existing::Refuse).unwrap();
        write(c.dir(), "summary.csv", "mine").unwrap();
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("theirs.txt"), "precious").unwrap();
        let e = c.publish().unwrap_err().to_string();
        assert!(e.contains("appeared while"), "{e}");
        assert_eq!(names(&out), vec!["theirs.txt"]);
        let kept = root.path().join(format!("res.coid-{}", std::process::id()));
        assert_eq!(
            std::fs::read_to_string(kept.join("summary.csv")).unwrap(),
            "mine"
        );
        std::fs::remove_dir_all(&kept).unwrap();
        // --force on a run folder coid wrote; a file added meanwhile.
        std::fs::remove_dir_all(&out).unwrap();
        Claim::new(&out, ResultKind::Run, Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "summary.csv", "old"))
            .unwrap();
        let c = Claim::new(&out, ResultKind::Run, Existing::Replace).unwrap();
        std::fs::write(out.join("note.txt"), "added").unwrap();
        let e = c.publish().unwrap_err().to_string();
        assert!(e.contains("changed while"), "{e}");
        assert_eq!(
            std::fs::read_to_string(out.join("note.txt")).unwrap(),
            "added"
        );
        assert!(kept.is_dir());
    }

    #[test]
    fn force_needs_an_identity_of_the_same_kind_and_unchanged_files() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("summary.csv"), "mine").unwrap();
        let why = |kind| match Claim::new(&out, kind, Existing::Replace) {
            Err(e) => e.to_string(),
            Ok(_) => "accepted".into(),
        };
        assert!(why(ResultKind::Run).contains("no .coid-folder.toml"));
        std::fs::remove_dir_all(&out).unwrap();
        Claim::new(&out, ResultKind::Run, Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "summary.csv", "x"))
            .unwrap();
        assert!(why(ResultKind::Eval).contains("it holds a run's results"));
        assert_eq!(why(ResultKind::Run), "accepted");
        std::fs::write(out.join("summary.csv"), "longer").unwrap();
        assert!(why(ResultKind::Run).contains("summary.csv changed"));
        std::fs::write(out.join("summary.csv"), "x").unwrap();
        std::fs::write(out.join("c.toml"), "").unwrap();
        assert!(why(ResultKind::Run).contains("it holds c.toml"));
    }

    /// Staging folders left by processes that are gone (killed) are
    /// removed when any folder is claimed in the same parent; a live
    /// process's staging folder for the same name refuses the claim.
    #[test]
    fn stale_staging_folders_of_dead_processes_are_removed() {
        let root = tempfile::tempdir().unwrap();
        // Above Linux's pid_max: no such process.
        let dead = root.path().join(".other.tmp-2147483000-abc123");
        std::fs::create_dir_all(&dead).unwrap();
        let out = root.path().join("res");
        Claim::new(&out, ResultKind::Eval, Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "a.csv", "x"))
            .unwrap();
        assert!(!dead.exists());
        // pid 1 always runs.
        let live = root.path().join(".next.tmp-1-def456");
        std::fs::create_dir_all(&live).unwrap();
        let e = Claim::new(
            &root.path().join("next"),
            ResultKind::Eval,
            Existing::Refuse,
        )
        .map(drop)
        .unwrap_err()
        .to_string();
        assert!(e.contains("pid 1"), "{e}");
        assert!(live.exists());
    }

    #[test]
    fn published_files_replace_old_ones_and_leave_no_staging() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "summary.csv", "old").unwrap();
        publish_files(dir.path(), |t| {
            write(t, "summary.csv", "new")?;
            write(t, "summary.md", "md")
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
}
