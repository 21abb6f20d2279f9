//! `coid batch` (Monte Carlo runs on worker processes, resumable,
//! shardable), `coid merge` (shard folders into one aggregate) and `coid
//! batch-run` (one run, in a worker): their arguments parsed,
//! `commands::batch`, `merge` and `batch_run` called, their lines
//! printed.

use std::path::PathBuf;

use super::{ConfigArg, ForceArg, OutArg, QuietArg, ThreadsArg, WorkersArg};
use crate::commands::{self, Shard};

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

/// `--runs`: 1 to [`commands::batch::MAX_RUNS`].
fn runs_in_range(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=commands::batch::MAX_RUNS).contains(&n) => Ok(n),
        Ok(n) => Err(format!("{n} is not in 1..=1000000")),
        Err(e) => Err(e.to_string()),
    }
}

pub fn batch(a: Args) -> anyhow::Result<()> {
    let request = commands::BatchRequest {
        config: a.config.source(),
        runs: a.runs,
        seed: a.seed,
        out: a.out.out,
        shard: a.shard,
        workers: a.workers.workers,
        threads: a.threads.threads,
    };
    let mut bars = super::Bars::new(a.quiet.quiet, "running");
    let report = commands::batch(&request, |e| bars.show(e));
    bars.clear();
    eprintln!("{}", report?.line);
    Ok(())
}

/// One run of a batch, in a worker process: from the batch's record,
/// into `runs/run-NNNNNN` (nothing to do when it is complete).
pub fn run_one(a: RunArgs) -> anyhow::Result<()> {
    commands::batch_run(&a.batch, a.run, a.threads.get())
}

pub fn merge(a: MergeArgs) -> anyhow::Result<()> {
    let line = commands::merge(&commands::MergeRequest {
        dirs: a.dirs,
        out: a.out,
        force: a.force.force,
        partial: a.partial,
    })?;
    eprintln!("{line}");
    Ok(())
}
