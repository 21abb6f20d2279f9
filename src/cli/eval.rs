//! `coid eval`: its arguments parsed, `commands::eval` called (every
//! method on the test runs, the paper's tables and plots; with `--suite`,
//! over several scenarios, per scenario and pooled) and its line
//! printed (`commands::mc_sweep` with `--mc-sweep`,
//! `commands::reid_sweep` with `--reid-sweep`).

use std::path::PathBuf;

use super::{CommonArgs, ThreadsArg};
use crate::commands;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    #[command(flatten)]
    threads: ThreadsArg,
    /// Evaluate on the validation runs ([train] validation_seeds) instead
    /// of the test runs, into results/<config file stem>-validation: the
    /// runs every choice (lambda, the sensor-noise calibration) is made on.
    #[arg(long)]
    validation: bool,
    /// More scenario configs to evaluate beside --config, each on its own
    /// runs ([eval] traffic_seeds): the tables are written per scenario
    /// (<out>/<name>/, the name being the config's folder for a coid.toml,
    /// else its file stem) and pooled over every run (<out>/pooled/). The
    /// configs must share the models, pose-noise levels and fusion variants.
    #[arg(long, num_args = 1.., value_name = "CONFIG")]
    suite: Vec<PathBuf>,
    /// The paper's Fig. 8b for `ours`: MC-dropout samples T (1, 10, ...,
    /// 100) and the dropout rate at inference (0.1 to 0.8, T = 20), one at
    /// a time, on the validation runs and on the test runs:
    /// mc_sweep.csv and mc_sweep.png/.svg, into
    /// results/<config file stem>-mc-sweep
    #[arg(long, conflicts_with_all = ["validation", "suite"])]
    mc_sweep: bool,
    /// Where learned and learning-free matching cross: at each of these
    /// cross-view rank-1 rates of the re-identification descriptor
    /// ([appearance] descriptor = "reid"; rank1 set, auroc = "free"), the
    /// methods with the models and baseline choices of
    /// `<models_dir>/rank1-<R>` (made by `coid train --reid-rank1 R`) on
    /// the validation and the test runs: reid_sweep.csv (F1 with its 95%
    /// interval, AP), reid_sweep_differences.csv (coid - mogm, ours -
    /// gps-app-hungarian, paired) and reid_sweep.png/.svg, into
    /// results/<config file stem>-reid-sweep
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "RANK1",
        conflicts_with_all = ["validation", "suite", "mc_sweep", "dataset"]
    )]
    reid_sweep: Vec<f64>,
    /// Evaluate on a dataset's runs instead of simulating (a folder that
    /// `coid export` or `coid convert` wrote): its test runs (validation
    /// runs with --validation), its pose-noise levels; the config gives
    /// the methods and their settings. Results go to
    /// results/<dataset folder>-eval by default.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["suite", "mc_sweep"])]
    dataset: Option<PathBuf>,
}

/// `coid eval --reid-sweep`: `commands::reid_sweep`, its differences
/// printed on stdout.
fn reid_sweep(a: &Args) -> anyhow::Result<()> {
    let request = commands::ReidSweepRequest {
        common: a.common.common(&a.threads),
        points: a.reid_sweep.clone(),
    };
    let mut bars = super::Bars::new(a.common.quiet.quiet, "re-identification sweep");
    let report = commands::reid_sweep(&request, |e| bars.show(e));
    bars.clear();
    let report = report?;
    println!("{}", report.differences);
    eprintln!("{}", report.line);
    Ok(())
}

pub fn eval(a: Args) -> anyhow::Result<()> {
    if a.mc_sweep {
        let common = a.common.common(&a.threads);
        let doing = "sweeping T and the dropout rate";
        let mut bars = super::Bars::new(a.common.quiet.quiet, doing);
        let report = commands::mc_sweep(&common, |e| bars.show(e));
        bars.clear();
        eprintln!("{}", report?.line);
        return Ok(());
    }
    if !a.reid_sweep.is_empty() {
        return reid_sweep(&a);
    }
    let request = commands::EvalRequest {
        common: a.common.common(&a.threads),
        validation: a.validation,
        suite: a.suite,
        dataset: a.dataset,
    };
    let mut bars = super::Bars::new(a.common.quiet.quiet, "evaluating");
    let report = commands::eval(&request, |e| bars.show(e));
    bars.clear();
    eprintln!("{}", report?.line());
    Ok(())
}
