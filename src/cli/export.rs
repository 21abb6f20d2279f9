//! `coid export`: every instance of a configuration as Parquet, for
//! matchers written elsewhere; `coid score`: their matches evaluated beside
//! the built-in methods.

use std::path::PathBuf;

use super::{Bars, CommonArgs, ThreadsArg, label_arg};
use crate::commands;
use crate::export::Split;
use crate::matching::Method;

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

/// Scores the matches; returns the line it printed last.
pub fn score(a: ScoreArgs) -> anyhow::Result<String> {
    let request = commands::ScoreRequest {
        common: a.common.common(&a.threads),
        matches: commands::Matches::File(a.matches.clone()),
        export: a.export.clone(),
        dataset: a.dataset.clone(),
        split: a.split,
    };
    let mut bars = Bars::new(a.common.quiet.quiet, "scoring");
    let report = commands::score(&request, |e| bars.show(e));
    bars.clear();
    Ok(print_score(&report?))
}

/// Prints what scoring wrote and noticed as `coid score` does; returns
/// the line.
pub fn print_score(report: &commands::ScoreReport) -> String {
    for note in &report.notes {
        eprintln!("{note}");
    }
    let line = report.line();
    eprintln!("{line}");
    line
}
