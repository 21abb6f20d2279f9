//! `coid track`: its arguments parsed, `commands::track` (or, with
//! `--sweep`, `commands::track_sweep`) called and its lines printed.

use super::CommonArgs;
use crate::commands::{self, TrackRequest};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Sweep latency (0, 100, 300 ms; compensated and not), loss (0, 10,
    /// 30 %) and rate (10, 5, 1 Hz), one at a time around the config's
    /// [v2x], over the test runs ([eval] traffic_seeds): sweep.csv (means
    /// with 95% intervals over runs) and sweep_latency.png/.svg.
    #[arg(long)]
    sweep: bool,
    /// With --sweep: over the validation runs ([train] validation_seeds)
    /// instead, where settings may be chosen.
    #[arg(long, requires = "sweep")]
    validation: bool,
}

pub fn track(a: Args) -> anyhow::Result<()> {
    let request = TrackRequest {
        common: a.common.common(&super::ThreadsArg::default()),
        validation: a.validation,
    };
    let doing = if a.sweep { "sweeping" } else { "tracking" };
    let mut bars = super::Bars::new(a.common.quiet.quiet, doing);
    let report = if a.sweep {
        commands::track_sweep(&request, |e| bars.show(e))
    } else {
        commands::track(&request, |e| bars.show(e))
    };
    bars.clear();
    let report = report?;
    if let Some(why) = &report.no_vehicle {
        eprintln!("{why}");
    }
    eprintln!("{}", report.line);
    Ok(())
}
