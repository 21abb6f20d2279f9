//! `batch`: Monte Carlo runs on worker processes, resumable and
//! shardable, aggregated with 95 % intervals; `merge`: shard folders into
//! the one aggregate; `batch_run`: one run of a batch, in a worker.

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{ConfigSource, Event};
use crate::batch::{self, Shard};
use crate::config::Settings;
use crate::label::counted;
use crate::{io, pipeline};

/// The most runs a batch may have (each run is a folder; more would only
/// exhaust the disk and the bookkeeping).
pub const MAX_RUNS: usize = 1_000_000;

/// A batch to run (or resume).
#[derive(Clone, Debug, PartialEq)]
pub struct BatchRequest {
    /// A file or the defaults: the batch records its text, which every
    /// run reads instead.
    pub config: ConfigSource,
    /// Runs, 1 to [`MAX_RUNS`].
    pub runs: usize,
    /// Master seed: run i gets traffic and sensor seeds derived from it.
    pub seed: u64,
    /// The batch folder [default: `results/<config stem>-batch`].
    pub out: Option<PathBuf>,
    /// Only this slice of the runs.
    pub shard: Option<Shard>,
    /// Worker processes [default: every core].
    pub workers: Option<usize>,
    /// Threads per run [default: the cores shared among the workers].
    pub threads: Option<usize>,
}

/// What a batch did.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchReport {
    pub folder: PathBuf,
    /// What was run, in one line (the aggregate named last).
    pub line: String,
}

const CI_NOTE: &str =
    "- means over runs, `±` the half-width of the 95% confidence interval (Student t)";

/// Runs the pending runs of the batch of `request` on worker processes
/// and writes the aggregate over every complete run; `on` hears
/// [`Event::Batch`] as runs end and a [`Event::Warning`] per failed run.
///
/// # Errors
/// The configuration or the batch folder is refused (another batch's, a
/// config edited since), workers cannot start, or runs failed (the
/// aggregate then covers the complete runs; the same request retries).
pub fn batch(request: &BatchRequest, mut on: impl FnMut(Event)) -> anyhow::Result<BatchReport> {
    if !(1..=MAX_RUNS).contains(&request.runs) {
        anyhow::bail!("runs must be 1 to {MAX_RUNS}, got {}", request.runs);
    }
    let wanted = super::parallel("workers", request.workers)?;
    let (out, _lock) = claim(request)?;
    // A resumed batch runs from the record it started with.
    let record = io::batch_identity(&out)?;
    let shard = request.shard;
    let pending = batch::pending_runs(&out, &record, shard);
    let mine = (0..request.runs)
        .filter(|i| shard.is_none_or(|s| i % s.count == s.index - 1))
        .count();
    let workers = wanted.min(pending.len()).max(1);
    // Workers x threads stay within the cores unless asked otherwise.
    let threads = match request.threads {
        Some(_) => super::threads(request.threads)?,
        None => (super::cores() / workers).max(1),
    };
    let program = crate::batch::Program::this().context("cannot find the coid executable")?;
    let started = std::time::Instant::now();
    let mut failed = 0;
    let mut done = mine - pending.len();
    on(Event::Batch {
        done,
        total: mine,
        failed,
    });
    let parallel = batch::Parallel { workers, threads };
    let failures = batch::execute(&program, &out, &record, &pending, parallel, |_, ok| {
        done += 1;
        failed += usize::from(!ok);
        on(Event::Batch {
            done,
            total: mine,
            failed,
        });
    })
    .context("cannot start worker processes")?;
    let complete = batch::aggregate(&out, &record)?;
    let shard_note = shard
        .map(|s| format!(" (this folder: shard {}/{})", s.index, s.count))
        .unwrap_or_default();
    let header = format!(
        "{}{shard_note}\n{CI_NOTE}",
        batch::provenance(
            Path::new(&record.config),
            request.seed,
            request.runs,
            &complete
        )
    );
    batch::write_aggregate(&out, &complete.rows, &header)?;
    let empty = match complete.without_instances {
        0 => String::new(),
        n => format!(", {n} without any instance"),
    };
    let line = format!(
        "coid: {} done in {:.1} s on {workers} worker{} ({} complete{empty}); aggregate in {}",
        counted((pending.len() - failures.len()) as u64, "run"),
        started.elapsed().as_secs_f64(),
        if workers == 1 { "" } else { "s" },
        complete.complete,
        out.join("summary.csv").display()
    );
    if failures.is_empty() {
        return Ok(BatchReport { folder: out, line });
    }
    on(Event::Warning(&line));
    for f in &failures {
        on(Event::Warning(&format!(
            "coid: run {} failed: {}",
            f.run, f.message
        )));
    }
    let list: Vec<String> = failures.iter().map(|f| f.run.to_string()).collect();
    anyhow::bail!(
        "{} run(s) failed: {} (the aggregate covers the {} complete runs; run the same command \
         again to retry)",
        failures.len(),
        list.join(", "),
        complete.complete,
    )
}

/// The batch's folder, claimed (locked) for the batch of `request`: its
/// configuration read once, here, validated and kept in the batch's
/// record, which every run reads instead of the user's file.
fn claim(request: &BatchRequest) -> anyhow::Result<(PathBuf, io::BatchLock)> {
    let path = match &request.config {
        ConfigSource::Text { .. } => anyhow::bail!(
            "a batch reads its configuration from a file (it records the file's text and \
             folder): write the configuration to a TOML file"
        ),
        other => other.path(),
    };
    let (settings, text) = Settings::load_with_text(&path)?;
    let config = path
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", path.display()))?;
    let out = super::out_dir(request.out.clone(), &request.config, "-batch");
    let identity = batch::identity(&settings, &config, &text, request.runs, request.seed)?;
    let lock = io::claim_batch_folder(&out, &identity)?;
    Ok((out, lock))
}

/// One run of a batch, in a worker process: from the batch's record in
/// `batch_dir`, into `runs/run-NNNNNN` on `threads` threads (nothing to
/// do when it is complete).
///
/// # Errors
/// The batch's record is refused, `run` is not one of its runs, or the
/// run fails.
pub fn batch_run(batch_dir: &Path, run: usize, threads: usize) -> anyhow::Result<()> {
    let record = io::batch_identity(batch_dir)?;
    if run >= record.runs {
        anyhow::bail!("the batch has {} runs, not run {run}", record.runs);
    }
    if io::run_is_complete(batch_dir, &record, run) {
        return Ok(());
    }
    let settings = super::calibrated(&batch::settings_of(&record, run)?, &mut |_| {})?;
    let claim = io::Claim::new(
        &io::run_dir(batch_dir, run),
        io::ResultKind::Run,
        io::Existing::Rerun,
    )?
    .of_batch_run(record.run(run));
    let mut folder = io::RunFolder::create(claim)?;
    let results = pipeline::run(
        &settings,
        threads,
        &pipeline::Warnings::default(),
        |_| {},
        |rows| folder.objects(rows),
    )
    .context("run failed")?;
    folder.finish(&settings, &results)?;
    Ok(())
}

/// Shard folders to merge.
#[derive(Clone, Debug, PartialEq)]
pub struct MergeRequest {
    /// Shard folders, each made by a batch with a shard.
    pub dirs: Vec<PathBuf>,
    /// The merged batch's folder.
    pub out: PathBuf,
    /// Replace a folder coid wrote that did not change since.
    pub force: bool,
    /// Merge what the folders hold even when runs are missing from all of
    /// them.
    pub partial: bool,
}

/// Merges the shard folders of `request` into one batch folder,
/// byte-identical to the unsharded batch's; returns the line saying so.
///
/// # Errors
/// A folder is given twice, belongs to another batch, runs are missing
/// (without `partial`), or the folder is taken.
pub fn merge(request: &MergeRequest) -> anyhow::Result<String> {
    let dirs = &request.dirs;
    let mut seen = std::collections::BTreeSet::new();
    for d in dirs {
        let full = d
            .canonicalize()
            .with_context(|| format!("cannot read {}", d.display()))?;
        if !seen.insert(full) {
            anyhow::bail!(
                "{} is given twice (its runs would count twice)",
                d.display()
            );
        }
    }
    let mut identity: Option<io::records::BatchRecord> = None;
    for d in dirs {
        let id = io::batch_identity(d)?;
        match &identity {
            Some(i) if !i.same_batch(&id) => anyhow::bail!(
                "{} belongs to a different batch than {}",
                d.display(),
                dirs[0].display()
            ),
            _ => identity = Some(id),
        }
    }
    let Some(identity) = identity else {
        anyhow::bail!("no folder to merge");
    };
    // Each run once, from the first folder that holds it whole (the same
    // run in two folders is the same bytes).
    let mut runs: std::collections::BTreeMap<usize, PathBuf> = Default::default();
    for d in dirs {
        for (i, dir) in io::completed_runs(d, &identity) {
            runs.entry(i).or_insert(dir);
        }
    }
    check_missing(&runs, &identity, request.partial)?;
    let claim = io::Claim::new(
        &request.out,
        io::ResultKind::Batch,
        io::Existing::when(request.force),
    )?;
    let out = claim.out().to_owned();
    claim.fill(|dir| -> anyhow::Result<()> {
        for (&i, run) in &runs {
            io::copy_run(run, &io::run_dir(dir, i))?;
        }
        io::write_batch_identity(dir, &identity)?;
        let done = batch::aggregate(dir, &identity)?;
        // The same report as the unsharded batch, so the merged folder is
        // byte-identical to it.
        let line = batch::provenance(
            Path::new(&identity.config),
            identity.master_seed,
            identity.runs,
            &done,
        );
        let header = format!("{line}\n{CI_NOTE}");
        batch::write_aggregate(dir, &done.rows, &header)?;
        Ok(())
    })?;
    let merged = counted(runs.len() as u64, "run");
    Ok(format!("coid: merged {merged} into {}", out.display()))
}

/// Refuses a merge that misses runs of the batch, unless `partial`.
fn check_missing(
    runs: &std::collections::BTreeMap<usize, PathBuf>,
    identity: &io::records::BatchRecord,
    partial: bool,
) -> anyhow::Result<()> {
    let missing: Vec<String> = (0..identity.runs)
        .filter(|i| !runs.contains_key(i))
        .map(|i| i.to_string())
        .collect();
    if missing.is_empty() || partial {
        return Ok(());
    }
    let shown: Vec<&str> = missing.iter().take(10).map(String::as_str).collect();
    anyhow::bail!(
        "the folders hold {} of the batch's {} runs; {} missing ({}{}): give every shard's \
         folder (finished), or pass --partial to merge what is there",
        runs.len(),
        identity.runs,
        missing.len(),
        shown.join(", "),
        if missing.len() > shown.len() {
            ", ..."
        } else {
            ""
        }
    )
}
