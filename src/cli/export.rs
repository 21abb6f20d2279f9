//! `coid export`: every instance of a configuration as Parquet, for
//! matchers written elsewhere; `coid score`: their matches evaluated beside
//! the built-in methods.

use std::collections::BTreeMap;
use std::path::PathBuf;

use super::{Bars, CommonArgs, ThreadsArg, label_arg, progress_bar};
use crate::commands;
use crate::export::{self, ExportRun, Split};
use crate::io;
use crate::matching::{self, Method, MultiVehicle};
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
    /// Instead of simulating the configuration's runs, the runs of this
    /// dataset (any dataset folder, `coid convert`'s too), written again
    /// with the built-in methods' matches on them (--with-matches; the
    /// config gives their settings). Results go to
    /// results/<dataset folder>-export by default.
    #[arg(long, value_name = "DIR")]
    dataset: Option<PathBuf>,
}

/// Writes the export; returns the line it printed last.
pub fn export(a: ExportArgs) -> anyhow::Result<String> {
    super::no_repeats("--splits", &a.splits)?;
    super::no_repeats("--with-matches", &a.with_matches)?;
    let request = commands::ExportRequest {
        common: a.common.common(&a.threads),
        splits: a.splits.clone(),
        with_matches: a.with_matches.clone(),
        dataset: a.dataset.clone(),
    };
    let mut bars = Bars::new(a.common.quiet.quiet, "exporting");
    let report = commands::export(&request, |e| bars.show(e));
    bars.clear();
    Ok(print_export(&report?))
}

/// Prints what an export wrote as `coid export` does; returns the line.
pub fn print_export(report: &commands::ExportReport) -> String {
    let line = format!("{}; wrote {}", report.summary(), report.folder.display());
    eprintln!("{line}");
    line
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
    /// The export the matches were made from (`coid export --out DIR`
    /// with this configuration): its runs.parquet names the configuration
    /// that made the instances [default: the folder holding --matches].
    #[arg(long, value_name = "DIR")]
    export: Option<PathBuf>,
    /// The dataset the matches were made from (any dataset folder, `coid
    /// convert`'s too): its runs are scored as they are, the built-in
    /// methods beside (the config gives their settings). Results go to
    /// results/<dataset folder>-score by default.
    #[arg(long, value_name = "DIR", conflicts_with = "export")]
    dataset: Option<PathBuf>,
    /// The runs to score: test, or validation (to choose a threshold
    /// there first).
    #[arg(long, default_value = "test", value_parser = label_arg::<Split>("split"))]
    split: Split,
}

/// Checks that `matches` were made for this configuration's instances: the
/// export they come from (`--export`, else the folder holding them) was
/// made with the same instances digest. Returns the export's instance
/// count per run.
fn check_export(
    matches: &std::path::Path,
    export: Option<&std::path::Path>,
    settings: &crate::config::Settings,
) -> anyhow::Result<BTreeMap<u64, u64>> {
    let dir = export_dir(matches, export);
    if export.is_none() && !dir.join(export::RUNS_FILE).is_file() {
        anyhow::bail!(
            "cannot tell which export {} was made from: pass --export DIR (the folder `coid \
             export` wrote; its runs.parquet names the configuration)",
            matches.display()
        );
    }
    let path = dir.join(export::RUNS_FILE);
    let runs = io::frames::read_export_runs(&path)
        .map_err(|why| anyhow::anyhow!("cannot read {}: {why}", path.display()))?;
    let mine = settings.instances_digest()?;
    if let Some(old) = runs
        .first()
        .filter(|r| r.schema_version < export::SCORED_SINCE)
    {
        anyhow::bail!(
            "{} was written by an older coid (export schema {}; this coid scores schemas {} \
             to {}, whose nodes carry the boxes' heading and speed and whose digest covers how \
             unset colours look): export again with this coid",
            path.display(),
            old.schema_version,
            export::SCORED_SINCE,
            export::SCHEMA_VERSION
        );
    }
    if let Some(new) = runs
        .first()
        .filter(|r| r.schema_version > export::SCHEMA_VERSION)
    {
        anyhow::bail!(
            "{} was written by a newer coid (export schema {}; this coid knows schemas up to \
             {}): score with that coid, or export again with this one",
            path.display(),
            new.schema_version,
            export::SCHEMA_VERSION
        );
    }
    match runs.first().map(|r| r.config_digest.clone()) {
        None => anyhow::bail!("{} names no run", path.display()),
        Some(None) => anyhow::bail!(
            "{} was written by an older coid (export schema 1, without config_digest): \
             export again with this coid",
            path.display()
        ),
        Some(Some(d)) if d != mine => anyhow::bail!(
            "the export in {} was made with another configuration (digest {d}; this one's is \
             {mine}): its instances are not this configuration's; score with the config it was \
             exported with",
            dir.display()
        ),
        Some(Some(_)) => {}
    }
    Ok(runs.iter().map(|r| (r.run, r.n_instances)).collect())
}

/// The settings the report's header names the scored runs by.
fn report_header(settings: &crate::config::Settings, split: Split) -> crate::config::Settings {
    let mut header = settings.clone();
    if split == Split::Validation {
        header.eval.traffic_seeds = settings.train.validation_seeds.clone();
    }
    if let Some(d) = &mut header.dataset {
        d.split = Some(split.as_str().to_owned());
    }
    header
}

/// The instance count of every run the matches were made from: the
/// dataset's (`--dataset`), else the export's, checked to be this
/// configuration's ([`check_export`]).
fn made_from(
    a: &ScoreArgs,
    settings: &crate::config::Settings,
) -> anyhow::Result<BTreeMap<u64, u64>> {
    match &a.dataset {
        Some(dir) => Ok(crate::dataset::Dataset::open(dir)
            .map_err(|e| anyhow::anyhow!("{} is not a usable dataset: {e}", dir.display()))?
            .runs
            .iter()
            .map(|r| (r.run, r.n_instances))
            .collect()),
        None => check_export(&a.matches, a.export.as_deref(), settings),
    }
}

/// Refused unless the export in `export_dir` holds every run of `split`
/// (its runs: `exported`): matches for runs it does not hold were not made
/// from it.
fn check_split_exported(
    export_dir: &std::path::Path,
    runs: &[ExportRun],
    split: Split,
    exported: &BTreeMap<u64, u64>,
) -> anyhow::Result<()> {
    let missing = runs
        .iter()
        .filter(|r| r.split == split && !exported.contains_key(&(r.index as u64)))
        .count();
    if missing == 0 {
        return Ok(());
    }
    let mut held: Vec<&str> = runs
        .iter()
        .filter(|r| exported.contains_key(&(r.index as u64)))
        .map(|r| r.split.as_str())
        .collect();
    held.dedup();
    anyhow::bail!(
        "the export in {} does not hold the {} {} runs this configuration scores (it holds {} \
         runs): export them (`coid export --splits {}`) and match them",
        export_dir.display(),
        missing,
        split.as_str(),
        if held.is_empty() {
            "no".to_owned()
        } else {
            held.join(" and ")
        },
        split.as_str()
    )
}

/// The folder of the export `--matches` came from.
fn export_dir(matches: &std::path::Path, export: Option<&std::path::Path>) -> PathBuf {
    match export {
        Some(d) => d.to_owned(),
        None => match matches.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        },
    }
}

/// The scored runs with instances that the matches file names none of
/// (every pair there counts as unmatched): a matcher that found nothing
/// in a whole run is rare; a file cut short or filtered is not.
fn unnamed_runs(
    external: &BTreeMap<usize, crate::evaluate::ExternalMatches>,
    exported: &BTreeMap<u64, u64>,
) -> Vec<String> {
    external
        .iter()
        .filter(|(run, m)| {
            m.by_instance.is_empty() && exported.get(&(**run as u64)).is_some_and(|&n| n > 0)
        })
        .map(|(run, _)| run.to_string())
        .collect()
}

/// Says which scored runs the matches file left out ([`unnamed_runs`]).
fn warn_unnamed(path: &std::path::Path, unnamed: &[String]) {
    if !unnamed.is_empty() {
        eprintln!(
            "coid: warning: {} names no instance of run(s) {} (they have instances): all their \
             pairs count as unmatched",
            path.display(),
            unnamed.join(", ")
        );
    }
}

/// Says how many rows of the matches file name runs of other splits than
/// the scored one (left out).
fn note_other_splits(path: &std::path::Path, other_splits: usize, rows: usize, split: Split) {
    if other_splits > 0 {
        eprintln!(
            "coid: {other_splits} of {}'s {rows} rows name runs of other splits than {}: left \
             out (--split chooses the runs scored)",
            path.display(),
            split.as_str()
        );
    }
}

/// Scores the matches; returns the line it printed last.
pub fn score(a: ScoreArgs) -> anyhow::Result<String> {
    let (settings, claim) =
        a.common
            .prepare_dataset("-score", io::ResultKind::Eval, a.dataset.as_deref())?;
    let out = claim.out().to_owned();
    if settings.matching.multi_vehicle != MultiVehicle::Pairwise {
        anyhow::bail!(
            "coid score compares pairwise correspondences: set [matching] multi_vehicle = \"pairwise\""
        );
    }
    if a.split == Split::Train {
        anyhow::bail!("coid score scores the test or validation runs (--split), not training runs");
    }
    let path = &a.matches;
    let exported = made_from(&a, &settings)?;
    let rows = io::frames::read_matches(path)
        .map_err(|why| anyhow::anyhow!("cannot read {}: {why}", path.display()))?;
    let runs = export::runs(&settings)?;
    let export_dir = export_dir(path, a.export.as_deref().or(a.dataset.as_deref()));
    check_split_exported(&export_dir, &runs, a.split, &exported)?;
    let levels: Vec<_> = settings.pose_noise.iter().map(|l| l.label).collect();
    let (mut external, other_splits) = export::external_matches(&rows, &runs, a.split, &levels)
        .map_err(|why| {
            anyhow::anyhow!("{} does not fit this configuration: {why}", path.display())
        })?;
    let unnamed = unnamed_runs(&external, &exported);
    let methods = settings.matching.methods.clone();
    let choices = crate::pipeline::choices(&settings, &methods)?;
    let lambdas = matching::method_lambdas(&choices);
    let scored: Vec<&ExportRun> = runs.iter().filter(|r| r.split == a.split).collect();
    let pb = progress_bar(
        a.common.quiet.quiet,
        scored.len() as u64,
        "{spinner} scoring: run {pos}/{len} [{bar:30}] {msg} eta {eta}",
    );
    let mut evals: Vec<RunEval> = Vec::new();
    let warnings = crate::pipeline::Warnings::default();
    for r in &scored {
        pb.set_message(format!("{} seed {}", r.scenario, r.seed));
        let matches = external.remove(&r.index).unwrap_or_default();
        let e = crate::experiments::eval_run_with(
            &r.settings,
            &methods,
            Some(matches),
            &lambdas,
            a.threads.get(),
            &warnings,
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
    let header = report_header(&settings, a.split);
    claim.fill(|dir| super::eval::write(dir, &header, &evals, &choices, None))?;
    warn_unnamed(path, &unnamed);
    note_other_splits(path, other_splits, rows.len(), a.split);
    let instances: usize = evals.iter().map(|r| r.instances).sum();
    let line = format!(
        "coid: scored {} with {} on {} ({}); wrote {}",
        path.display(),
        crate::label::counted(methods.len() as u64, "built-in method"),
        crate::label::counted(evals.len() as u64, &format!("{} run", a.split.as_str())),
        crate::label::counted(instances as u64, "instance"),
        out.display()
    );
    eprintln!("{line}");
    Ok(line)
}
