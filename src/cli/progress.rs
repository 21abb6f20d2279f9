//! A command's progress as `coid` shows it ([`Bars`]): the events of
//! [`crate::commands`] as progress bars on stderr, and the line saying
//! what a descriptor's calibration measured. The Python package shows
//! them with the same bars.

use indicatif::ProgressBar;

use super::{CALIBRATION_TEMPLATE, SIM_TEMPLATE, calibration_line, progress_bar};
use crate::commands::Event;

/// The bar over a batch's runs.
const BATCH_TEMPLATE: &str = "{spinner} runs {pos}/{len} [{bar:30}] {per_sec} eta {eta} {msg}";

/// The bar over the pairs a conversion reads.
const PAIRS_TEMPLATE: &str = "{spinner} converting: pair {pos}/{len} [{bar:30}] eta {eta}";

/// The bars of one command: over the validation runs while the
/// descriptor is calibrated, over a run's simulated time, over the runs,
/// over the pairs converted. Nothing when quiet.
pub struct Bars {
    quiet: bool,
    /// What the bar over the runs says the command does ("exporting").
    doing: &'static str,
    calibration: Option<ProgressBar>,
    simulation: Option<ProgressBar>,
    runs: Option<ProgressBar>,
    pairs: Option<ProgressBar>,
    batch: Option<ProgressBar>,
}

impl Bars {
    /// The bars of a command that `doing` (its bar over the runs says so).
    pub fn new(quiet: bool, doing: &'static str) -> Self {
        Self {
            quiet,
            doing,
            calibration: None,
            simulation: None,
            runs: None,
            pairs: None,
            batch: None,
        }
    }

    pub fn show(&mut self, event: Event) {
        match event {
            Event::Calibrating { done, total } => {
                let bar = self
                    .calibration
                    .get_or_insert_with(|| progress_bar(self.quiet, 0, CALIBRATION_TEMPLATE));
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            }
            Event::Calibrated { reid, runs } => {
                if let Some(bar) = self.calibration.take() {
                    bar.finish_and_clear();
                }
                if let Some(line) = calibration_line(reid, runs).filter(|_| !self.quiet) {
                    eprintln!("{line}");
                }
            }
            Event::Simulating(p) => {
                let bar = self.simulation.get_or_insert_with(|| {
                    progress_bar(self.quiet, (p.end_s * 10.0).round() as u64, SIM_TEMPLATE)
                });
                super::show_sim_progress(bar, p);
            }
            Event::Warning(line) => {
                let bars = [
                    &self.calibration,
                    &self.simulation,
                    &self.runs,
                    &self.pairs,
                    &self.batch,
                ];
                match bars.into_iter().flatten().next() {
                    Some(bar) => bar.suspend(|| eprintln!("{line}")),
                    None => eprintln!("{line}"),
                }
            }
            Event::Batch {
                done,
                total,
                failed,
            } => {
                let bar = self
                    .batch
                    .get_or_insert_with(|| progress_bar(self.quiet, total as u64, BATCH_TEMPLATE));
                bar.set_position(done as u64);
                if failed > 0 {
                    bar.set_message(format!("{failed} failed"));
                }
            }
            Event::Pairs { done, total } => {
                let bar = self
                    .pairs
                    .get_or_insert_with(|| progress_bar(self.quiet, total as u64, PAIRS_TEMPLATE));
                bar.set_position(done as u64);
            }
            Event::Runs {
                done,
                total,
                current,
            } => {
                let template = format!(
                    "{{spinner}} {}: run {{pos}}/{{len}} [{{bar:30}}] {{msg}} eta {{eta}}",
                    self.doing
                );
                let bar = self
                    .runs
                    .get_or_insert_with(|| progress_bar(self.quiet, total as u64, &template));
                bar.set_position(done as u64);
                bar.set_message(current.to_owned());
            }
        }
    }

    /// Clears the bars (the command ended, well or not).
    pub fn clear(&mut self) {
        for bar in [
            self.calibration.take(),
            self.simulation.take(),
            self.runs.take(),
            self.pairs.take(),
            self.batch.take(),
        ]
        .into_iter()
        .flatten()
        {
            bar.finish_and_clear();
        }
    }
}
