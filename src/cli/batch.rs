//! `coid batch` (Monte Carlo runs on worker processes, resumable,
//! shardable) and `coid merge` (shard folders into one aggregate).

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{ConfigArg, ForceArg, OutArg, QuietArg, ThreadsArg, WorkersArg, progress_bar};
use crate::batch::{self, Shard};
use crate::config::Settings;
use crate::label::counted;
use crate::{io, pipeline};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArg,
    /// Number of runs (1 to 1 000 000).
    #[arg(long, value_parser = runs_in_range)]
    runs: usize,
    #[command(flatten)]
    workers: WorkersArg,
    #[command(flatten)]
    threads: ThreadsArg,
    /// Master seed: run i gets traffic and sensor seeds derived from it.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[command(flatten)]
    out: OutArg,
    /// Only this slice of the runs, `k/n` (1-based): runs i with
    /// i mod n = k - 1; combine the shards' folders with `coid merge`.
    #[arg(long)]
    shard: Option<Shard>,
    #[command(flatten)]
    quiet: QuietArg,
}

#[derive(clap::Args)]
pub struct MergeArgs {
    /// Shard folders (each made by `coid batch --shard k/n`).
    #[arg(required = true)]
    dirs: Vec<PathBuf>,
    /// Output folder: the merged batch (refused when it exists, unless
    /// --force).
    #[arg(long, short)]
    out: PathBuf,
    #[command(flatten)]
    force: ForceArg,
    /// Merge what the folders hold even when runs of the batch are missing
    /// from all of them (a shard not given, or not finished); the
    /// aggregate says how many runs it covers.
    #[arg(long)]
    partial: bool,
}

/// `coid batch-run`: one run of a batch, as `coid batch` starts it in a
/// worker process.
#[derive(clap::Args)]
pub struct RunArgs {
    /// The batch folder (its batch.toml is the configuration).
    #[arg(long)]
    batch: PathBuf,
    /// The run's index in the batch.
    #[arg(long)]
    run: usize,
    #[command(flatten)]
    threads: ThreadsArg,
}

/// `--runs`: 1 to 1 000 000 (each run is a folder; more would only
/// exhaust the disk and the bookkeeping).
fn runs_in_range(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=1_000_000).contains(&n) => Ok(n),
        Ok(n) => Err(format!("{n} is not in 1..=1000000")),
        Err(e) => Err(e.to_string()),
    }
}

const CI_NOTE: &str =
    "- means over runs, `±` the half-width of the 95% confidence interval (Student t)";

pub fn batch(a: Args) -> anyhow::Result<()> {
    // The configuration is read once, here: validated, and kept in the
    // batch's record, which every run reads instead of the user's file.
    let path = a.config.path();
    let (settings, text) = Settings::load_with_text(&path)?;
    let config = path
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", path.display()))?;
    let out = super::out_dir(a.out.out, &config, "-batch");
    let identity = batch::identity(&settings, &config, &text, a.runs, a.seed)?;
    let _lock = io::claim_batch_folder(&out, &identity)?;
    // A resumed batch runs from the record it started with.
    let record = io::batch_identity(&out)?;
    let pending = batch::pending_runs(&out, &record, a.shard);
    let mine = (0..a.runs)
        .filter(|i| a.shard.is_none_or(|s| i % s.count == s.index - 1))
        .count();
    let wanted = a.workers.get();
    let workers = wanted.min(pending.len()).max(1);
    // Workers x threads stay within the cores unless asked otherwise.
    let threads = a.threads.or((super::cores() / workers).max(1));
    let pb = progress_bar(
        a.quiet.quiet,
        mine as u64,
        "{spinner} runs {pos}/{len} [{bar:30}] {per_sec} eta {eta} {msg}",
    );
    pb.set_position((mine - pending.len()) as u64);
    let program = crate::batch::Program::this().context("cannot find the coid executable")?;
    let started = std::time::Instant::now();
    let mut failed_count = 0;
    let parallel = batch::Parallel { workers, threads };
    let failures = batch::execute(&program, &out, &record, &pending, parallel, |_, ok| {
        pb.inc(1);
        if !ok {
            failed_count += 1;
            pb.set_message(format!("{failed_count} failed"));
        }
    })
    .context("cannot start worker processes")?;
    pb.finish_and_clear();
    let done = batch::aggregate(&out, &record)?;
    let shard_note = a
        .shard
        .map(|s| format!(" (this folder: shard {}/{})", s.index, s.count))
        .unwrap_or_default();
    let header = format!(
        "{}{shard_note}\n{CI_NOTE}",
        batch::provenance(Path::new(&record.config), a.seed, a.runs, &done)
    );
    batch::write_aggregate(&out, &done.rows, &header)?;
    let empty = match done.without_instances {
        0 => String::new(),
        n => format!(", {n} without any instance"),
    };
    eprintln!(
        "coid: {} done in {:.1} s on {workers} worker{} ({} complete{empty}); aggregate in {}",
        counted((pending.len() - failures.len()) as u64, "run"),
        started.elapsed().as_secs_f64(),
        if workers == 1 { "" } else { "s" },
        done.complete,
        out.join("summary.csv").display()
    );
    if failures.is_empty() {
        return Ok(());
    }
    for f in &failures {
        eprintln!("coid: run {} failed: {}", f.run, f.message);
    }
    let list: Vec<String> = failures.iter().map(|f| f.run.to_string()).collect();
    anyhow::bail!(
        "{} run(s) failed: {} (the aggregate covers the {} complete runs; run the same command again to retry)",
        failures.len(),
        list.join(", "),
        done.complete,
    )
}

/// One run of a batch, in a worker process: from the batch's record,
/// into `runs/run-NNNNNN` (nothing to do when it is complete).
pub fn run_one(a: RunArgs) -> anyhow::Result<()> {
    let record = io::batch_identity(&a.batch)?;
    if a.run >= record.runs {
        anyhow::bail!("the batch has {} runs, not run {}", record.runs, a.run);
    }
    if io::run_is_complete(&a.batch, &record, a.run) {
        return Ok(());
    }
    let settings = super::calibrated(&batch::settings_of(&record, a.run)?, true)?;
    let claim = io::Claim::new(
        &io::run_dir(&a.batch, a.run),
        io::ResultKind::Run,
        io::Existing::Rerun,
    )?
    .of_batch_run(record.run(a.run));
    let mut folder = io::RunFolder::create(claim)?;
    let results = pipeline::run(
        &settings,
        a.threads.get(),
        &pipeline::Warnings::default(),
        |_| {},
        |rows| folder.objects(rows),
    )
    .context("run failed")?;
    folder.finish(&settings, &results)?;
    Ok(())
}

pub fn merge(a: MergeArgs) -> anyhow::Result<()> {
    let mut seen = std::collections::BTreeSet::new();
    for d in &a.dirs {
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
    for d in &a.dirs {
        let id = io::batch_identity(d)?;
        match &identity {
            Some(i) if !i.same_batch(&id) => anyhow::bail!(
                "{} belongs to a different batch than {}",
                d.display(),
                a.dirs[0].display()
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
    for d in &a.dirs {
        for (i, dir) in io::completed_runs(d, &identity) {
            runs.entry(i).or_insert(dir);
        }
    }
    let missing: Vec<String> = (0..identity.runs)
        .filter(|i| !runs.contains_key(i))
        .map(|i| i.to_string())
        .collect();
    if !missing.is_empty() && !a.partial {
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
        );
    }
    let claim = io::Claim::new(
        &a.out,
        io::ResultKind::Batch,
        io::Existing::when(a.force.force),
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
    eprintln!("coid: merged {merged} into {}", out.display());
    Ok(())
}
