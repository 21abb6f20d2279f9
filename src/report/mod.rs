//! What results look like before they are written: summary rows of a run,
//! the per-object rows, the paper's tables as named columns, a batch's
//! rows, and the data behind the plots. Plain data and the arithmetic that
//! makes it (pooling; means over Monte Carlo runs with 95% intervals from
//! Student's t quantiles, statrs); `io` writes it and `render` draws it.
//!
//! One job per file: `stats` (means and intervals), `run` (a run's rows:
//! the summary with its one column table, per-object rows), `table` (named
//! columns), `batch` (a run's summary read back, the aggregate over runs,
//! keyed by [`RowKey`], its columns named once by [`Metric`]), `tracking`
//! (cooperation over time), `calibration`, `detector` (the detector
//! report: a profile against its figures), `exchange` (rows read from
//! other tools' files), `plots`.

mod batch;
mod calibration;
mod detector;
mod exchange;
mod plots;
mod run;
mod stats;
mod table;
mod tracking;

pub use batch::{AggregateRow, KEY_COLUMNS, Metric, RunRow, aggregate, aggregate_table};
pub use calibration::*;
pub use detector::{DetectorStats, reid_table};
pub use exchange::{ExportRunRow, MatchRow};
pub use plots::{LevelCurves, PlotData, SweepPoint};
pub use run::*;
pub use stats::{PairedDifference, mean_ci95, paired_bootstrap};
pub use table::{Table, TableColumn};
pub use tracking::*;

#[cfg(test)]
mod tests;
