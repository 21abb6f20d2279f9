//! Batch folders: the batch's identity (`batch.toml`) and its lock, the
//! run folders that count (whole, of this batch), their summaries read
//! back, the aggregate written beside them.

use std::path::{Path, PathBuf};

use super::records::BatchRecord;
use super::{
    Existing, OutputError, ResultKind, folder, frames, io, markdown, publish_files, write_text,
};
use crate::report::{AggregateRow, RunRow};

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
        Err(OutputError::NotExtendable { why, .. }) => {
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
}
