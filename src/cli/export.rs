//! `coid export`: every instance of a configuration as Parquet, for
//! matchers written elsewhere; `coid score`: their matches evaluated beside
//! the built-in methods.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;

use super::{CommonArgs, ThreadsArg, label_arg, progress_bar};
use crate::export::{self, ExportRun, Split};
use crate::io;
use crate::matching::{Method, MultiVehicle};
use crate::tables::RunEval;

#[derive(clap::Args)]
pub struct ExportArgs {
    #[command(flatten)]
    common: CommonArgs,
    #[command(flatten)]
    threads: ThreadsArg,
    /// The splits to export: train ([train] traffic_seeds and scenarios),
    /// validation, test ([eval] traffic_seeds and scenarios) [default:
    /// all three].
    #[arg(long, num_args = 1.., value_parser = label_arg::<Split>("split"))]
    splits: Vec<Split>,
    /// Also write these built-in methods' matches, each as
    /// matches-<method>.parquet (a file `coid score` reads).
    #[arg(long, num_args = 1.., value_parser = label_arg::<Method>("method"))]
    with_matches: Vec<Method>,
}

pub fn export(a: ExportArgs) -> anyhow::Result<()> {
    let (settings, out) = a.common.prepare("-export", io::ResultKind::Export)?;
    let splits = if a.splits.is_empty() {
        vec![Split::Train, Split::Validation, Split::Test]
    } else {
        a.splits.clone()
    };
    let runs: Vec<ExportRun> = export::runs(&settings)?
        .into_iter()
        .filter(|r| splits.contains(&r.split))
        .collect();
    let mut files: Vec<(String, crate::report::Table)> = export::files()
        .into_iter()
        .map(|(n, t)| (n.to_owned(), t))
        .collect();
    files.extend(
        a.with_matches
            .iter()
            .map(|&m| (export::matches_file(m), export::matches_template())),
    );
    let named: Vec<(&str, crate::report::Table)> =
        files.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    let existing = io::Existing::when(a.common.force, io::ResultKind::Export);
    let mut folder = io::TablesFolder::create(&out, existing, &named)?;
    let pb = progress_bar(
        a.common.quiet.quiet,
        runs.len() as u64,
        "{spinner} exporting: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    let mut counts = Vec::new();
    for r in &runs {
        pb.set_message(format!(
            "{} {} seed {}",
            r.split.as_str(),
            r.scenario,
            r.seed
        ));
        let n = export::export_run(r, &a.with_matches, a.threads.get(), |_| {}, &mut folder)
            .with_context(|| format!("run {} ({} seed {}) failed", r.index, r.scenario, r.seed))?;
        counts.push((r, n));
        pb.inc(1);
    }
    pb.finish_and_clear();
    folder.write("runs.parquet", &export::run_table(&counts))?;
    folder.finish(&[("schema.md", export::SCHEMA.to_owned())])?;
    let instances: usize = counts.iter().map(|c| c.1).sum();
    eprintln!(
        "coid: exported {} runs ({instances} instances) of {}; wrote {}",
        runs.len(),
        splits
            .iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        out.display()
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct ScoreArgs {
    #[command(flatten)]
    common: CommonArgs,
    #[command(flatten)]
    threads: ThreadsArg,
    /// Correspondences made elsewhere (Parquet, or CSV by its .csv ending)
    /// for the runs of `coid export` with the same configuration: columns
    /// run, instance, a, b and optionally pose_noise, probability,
    /// uncertainty (see the export's schema.md).
    #[arg(long, value_name = "FILE")]
    matches: PathBuf,
    /// The runs to score: test, or validation (to choose a threshold
    /// there first).
    #[arg(long, default_value = "test", value_parser = label_arg::<Split>("split"))]
    split: Split,
}

pub fn score(a: ScoreArgs) -> anyhow::Result<()> {
    let (settings, out) = a.common.prepare("-score", io::ResultKind::Eval)?;
    if settings.matching.multi_vehicle != MultiVehicle::Pairwise {
        anyhow::bail!(
            "coid score compares pairwise correspondences: set [matching] multi_vehicle = \"pairwise\""
        );
    }
    if a.split == Split::Train {
        anyhow::bail!("coid score scores the test or validation runs (--split), not training runs");
    }
    let path = &a.matches;
    let rows = io::frames::read_matches(path)
        .map_err(|why| anyhow::anyhow!("cannot read {}: {why}", path.display()))?;
    let runs = export::runs(&settings)?;
    let levels: Vec<_> = settings.pose_noise.iter().map(|l| l.label).collect();
    let mut external = export::external_matches(&rows, &runs, a.split, &levels).map_err(|why| {
        anyhow::anyhow!("{} does not fit this configuration: {why}", path.display())
    })?;
    let methods = settings.matching.methods.clone();
    let choices = crate::pipeline::choices(&settings, &methods)?;
    let lambdas: BTreeMap<Method, f64> = choices.iter().map(|(&m, c)| (m, c.lambda)).collect();
    let scored: Vec<&ExportRun> = runs.iter().filter(|r| r.split == a.split).collect();
    let pb = progress_bar(
        a.common.quiet.quiet,
        scored.len() as u64,
        "{spinner} scoring: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    let mut evals: Vec<RunEval> = Vec::new();
    for r in &scored {
        pb.set_message(format!("{} seed {}", r.scenario, r.seed));
        let matches = external.remove(&r.index).unwrap_or_default();
        let e = crate::experiments::eval_run_with(
            &r.settings,
            &methods,
            Some(matches),
            &lambdas,
            a.threads.get(),
            |_| {},
        )
        .map_err(|e| match e {
            crate::pipeline::RunError::Matches(why) => anyhow::anyhow!(
                "{} does not fit run {} ({} seed {}): {why}",
                path.display(),
                r.index,
                r.scenario,
                r.seed
            ),
            other => anyhow::Error::new(other).context(format!(
                "run {} ({} seed {}) failed",
                r.index, r.scenario, r.seed
            )),
        })?;
        evals.push(e);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let existing = io::Existing::when(a.common.force, io::ResultKind::Eval);
    // The report's header names the runs scored.
    let mut header = settings.clone();
    if a.split == Split::Validation {
        header.eval.traffic_seeds = settings.train.validation_seeds.clone();
    }
    super::eval::write(&out, &header, &evals, &choices, None, existing)?;
    let instances: usize = evals.iter().map(|r| r.instances).sum();
    eprintln!(
        "coid: scored {} with {} built-in methods on {} {} runs ({instances} instances); wrote {}",
        path.display(),
        methods.len(),
        evals.len(),
        a.split.as_str(),
        out.display()
    );
    Ok(())
}
