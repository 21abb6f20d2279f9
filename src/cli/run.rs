//! `coid run`: one scenario headless, results into one folder
//! ([`crate::commands::run`], its progress shown by [`RunProgress`]).

use indicatif::ProgressBar;

use super::{CommonArgs, ThreadsArg, calibration_line, progress_bar};
use crate::commands::{self, RunEvent, RunReport, RunRequest};

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
        config: a.common.config.source(),
        out: a.common.out.out.clone(),
        force: a.common.force.force,
        threads: a.threads.threads,
        traffic_seed: a.traffic_seed,
        sensor_seed: a.sensor_seed,
    };
    let mut progress = RunProgress::new(a.common.quiet.quiet);
    let report = commands::run(&request, |e| progress.show(e));
    progress.clear();
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

/// A run's progress as `coid run` shows it: a bar over the validation
/// runs while the descriptor is calibrated (and the line saying what it
/// measured), then one over the simulated time. Nothing when quiet.
pub struct RunProgress {
    quiet: bool,
    calibration: Option<ProgressBar>,
    simulation: Option<ProgressBar>,
}

impl RunProgress {
    pub fn new(quiet: bool) -> Self {
        Self {
            quiet,
            calibration: None,
            simulation: None,
        }
    }

    pub fn show(&mut self, event: RunEvent) {
        match event {
            RunEvent::Calibrating { done, total } => {
                let bar = self.calibration.get_or_insert_with(|| {
                    progress_bar(self.quiet, 0, super::CALIBRATION_TEMPLATE)
                });
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            }
            RunEvent::Calibrated { reid, runs } => {
                if let Some(bar) = self.calibration.take() {
                    bar.finish_and_clear();
                }
                if let Some(line) = calibration_line(reid, runs).filter(|_| !self.quiet) {
                    eprintln!("{line}");
                }
            }
            RunEvent::Simulating(p) => {
                let bar = self.simulation.get_or_insert_with(|| {
                    progress_bar(
                        self.quiet,
                        (p.end_s * 10.0).round() as u64,
                        super::SIM_TEMPLATE,
                    )
                });
                super::show_sim_progress(bar, p);
            }
        }
    }

    /// Clears the bars (the run ended, well or not).
    pub fn clear(&mut self) {
        for bar in [self.calibration.take(), self.simulation.take()]
            .into_iter()
            .flatten()
        {
            bar.finish_and_clear();
        }
    }
}
