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
mod batches;
pub mod folder;
pub mod frames;
mod identity;
pub mod markdown;
mod models;
pub mod records;
mod results;
mod staging;
pub mod torch;

pub use batches::*;
pub use folder::{Claim, Existing, check_extendable, publish_files};
pub use identity::ResultKind;
pub use models::*;
pub use records::{BaselineEntry, DescriptorChoice};
pub use results::*;

use std::path::{Path, PathBuf};

use polars::prelude::PolarsError;

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
    #[error(
        "--force does not replace {path}: {why} (it replaces only {kind} that coid wrote, as \
         coid wrote it)"
    )]
    NotReplaceable {
        path: PathBuf,
        kind: &'static str,
        why: String,
    },
    #[error("coid does not add to {path}: {why} (it adds only to {kind} that coid wrote)")]
    NotExtendable {
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

/// Writes each `(file name, text)` into `dir`.
pub fn write_texts(dir: &Path, files: &[(&str, String)]) -> Result<(), OutputError> {
    files
        .iter()
        .try_for_each(|(name, text)| write_text(&dir.join(name), text))
}

/// What a family of scenarios in `dir` holds: its README's text (empty
/// without one), and each folder's name with its `README.md` (one line,
/// the scenario's description; empty without one), by name.
pub fn read_family(dir: &Path) -> Result<(String, Vec<(String, String)>), OutputError> {
    let mut scenarios = Vec::new();
    for e in std::fs::read_dir(dir).map_err(io(dir))? {
        let e = e.map_err(io(dir))?;
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || !e.path().is_dir() {
            continue;
        }
        let described = std::fs::read_to_string(e.path().join("README.md")).unwrap_or_default();
        scenarios.push((name, described.trim_end().to_owned()));
    }
    scenarios.sort();
    let readme = std::fs::read_to_string(dir.join("README.md")).unwrap_or_default();
    Ok((readme, scenarios))
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
