//! `coid batch` (Monte Carlo runs on worker processes, resumable,
//! shardable) and `coid merge` (shard folders into one aggregate).

use std::path::PathBuf;

use anyhow::Context;

use super::{ConfigArg, QuietArg, progress_bar};
use crate::batch::{self, Shard};
use crate::config::Settings;
use crate::io;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArg,
    /// Number of runs (1 to 1 000 000).
    #[arg(long, value_parser = runs_in_range)]
    runs: usize,
    /// Worker processes [default: the number of cores].
    #[arg(long, short)]
    workers: Option<usize>,
    /// Threads inside each run (the results do not depend on it)
    /// [default: the cores shared among the workers, at least 1].
    #[arg(long)]
    threads: Option<std::num::NonZeroUsize>,
    /// Master seed: run i gets traffic and sensor seeds derived from it.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output folder [default: results/<config file stem>-batch].
    #[arg(long, short)]
    out: Option<PathBuf>,
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
    /// Replace the output folder if it exists (the old one is removed only
    /// after the new one is complete).
    #[arg(long)]
    force: bool,
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
    // Validate the config once here, so a bad config fails before any run.
    let path = a.config.path();
    let settings = Settings::load(&path)?;
    if a.runs == 0 {
        anyhow::bail!("--runs must be at least 1");
    }
    let config = path
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", path.display()))?;
    let out = super::out_dir(a.out, &config, "-batch");
    let workers = a.workers.unwrap_or_else(super::cores).max(1);
    // Workers x threads stay within the cores unless asked otherwise.
    let threads = a
        .threads
        .map_or_else(|| (super::cores() / workers).max(1), |t| t.get());
    io::claim_batch_folder(&out, &batch::identity(&settings, &config, a.runs, a.seed)?)?;
    let pending = batch::pending_runs(&out, a.runs, a.shard);
    let mine = (0..a.runs)
        .filter(|i| a.shard.is_none_or(|s| i % s.count == s.index - 1))
        .count();
    let pb = progress_bar(
        a.quiet.quiet,
        mine as u64,
        "{spinner} runs {pos}/{len} [{bar:30}] {per_sec} eta {eta} {msg}",
    );
    pb.set_position((mine - pending.len()) as u64);
    let exe = std::env::current_exe().context("cannot find the coid executable")?;
    let started = std::time::Instant::now();
    let mut failed_count = 0;
    let parallel = batch::Parallel { workers, threads };
    let failures = batch::execute(&exe, &config, &out, a.seed, &pending, parallel, |_, ok| {
        pb.inc(1);
        if !ok {
            failed_count += 1;
            pb.set_message(format!("{failed_count} failed"));
        }
    })
    .context("cannot start worker processes")?;
    pb.finish_and_clear();
    let (rows, complete) = batch::aggregate(&out)?;
    let shard_note = a
        .shard
        .map(|s| format!(" (this folder: shard {}/{})", s.index, s.count))
        .unwrap_or_default();
    let header = format!(
        "{}{shard_note}\n{CI_NOTE}",
        batch::provenance(&config, a.seed, a.runs, complete)
    );
    batch::write_aggregate(&out, &rows, &header)?;
    eprintln!(
        "coid: {} runs done in {:.1} s on {workers} worker{} ({complete} complete in {}); aggregate in {}",
        pending.len() - failures.len(),
        started.elapsed().as_secs_f64(),
        if workers == 1 { "" } else { "s" },
        out.display(),
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
        "{} run(s) failed: {} (the aggregate covers the {complete} complete runs; run the same command again to retry)",
        failures.len(),
        list.join(", "),
    )
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
    let mut total = 0;
    let existing = io::Existing::when(a.force, io::ResultKind::Batch);
    io::atomic_dir(&a.out, existing, |out| -> anyhow::Result<()> {
        for d in &a.dirs {
            for run in io::completed_runs(d)? {
                let dst = out.join("runs").join(run.file_name().unwrap_or_default());
                io::copy_run(&run, &dst)?;
                total += 1;
            }
        }
        if let Some(id) = &identity {
            io::write_batch_identity(out, id)?;
        }
        let (rows, complete) = batch::aggregate(out)?;
        // The same report as the unsharded batch, so the merged folder is
        // byte-identical to it.
        let line = match &identity {
            Some(b) => batch::provenance(
                std::path::Path::new(&b.config),
                b.master_seed,
                b.runs,
                complete,
            ),
            _ => format!(
                "- merged from {} shard folders; {complete} runs",
                a.dirs.len()
            ),
        };
        let header = format!("{line}\n{CI_NOTE}");
        batch::write_aggregate(out, &rows, &header)?;
        Ok(())
    })?;
    eprintln!("coid: merged {total} runs into {}", a.out.display());
    Ok(())
}
