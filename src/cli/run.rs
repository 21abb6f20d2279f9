//! `coid run`: one scenario headless, results into one folder
//! ([`crate::commands::run`], its progress shown by [`Bars`]).

use super::{Bars, CommonArgs, ThreadsArg};
use crate::commands::{self, RunReport, RunRequest};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    #[command(flatten)]
    threads: ThreadsArg,
    /// Override [seeds] traffic (SUMO's seed, 0 to 2147483647).
    #[arg(long, value_parser = clap::value_parser!(u64).range(0..=crate::config::MAX_TRAFFIC_SEED))]
    traffic_seed: Option<u64>,
    /// Override [seeds] sensor.
    #[arg(long)]
    sensor_seed: Option<u64>,
}

/// Runs the scenario; returns the line it printed last.
pub fn run(a: Args) -> anyhow::Result<String> {
    let request = RunRequest {
        common: a.common.common(&a.threads),
        traffic_seed: a.traffic_seed,
        sensor_seed: a.sensor_seed,
    };
    let mut bars = Bars::new(a.common.quiet.quiet, "running");
    let report = commands::run(&request, |e| bars.show(e));
    bars.clear();
    Ok(print_report(&report?))
}

/// Prints what a run wrote as `coid run` does (a warning when it had no
/// instance, then its headline and folder); returns the last line.
pub fn print_report(report: &RunReport) -> String {
    if let Some(why) = &report.no_instance {
        eprintln!("coid: warning: no instance: {why}");
    }
    let line = format!("{}; wrote {}", report.headline, report.folder.display());
    eprintln!("{line}");
    line
}
