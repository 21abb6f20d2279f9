//! A batch's rows: each run's summary read back ([`RunRow`]) and their
//! aggregate over runs ([`AggregateRow`]: means with 95% intervals), both
//! keyed by one typed [`RowKey`]. The metrics a batch aggregates are named
//! once, by [`Metric`]: the run's `summary.csv` columns, what is read back,
//! the aggregate's columns and its report all take their names from it.

use std::collections::HashMap;

use super::run::RowKey;
use super::stats::mean_ci95;
use super::table::Table;

/// A run metric a batch aggregates, by its `summary.csv` column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Metric {
    Precision,
    Recall,
    F1,
    DeSingle,
    DeFused,
    DeSingleCovisible,
    DeFusedCovisible,
    DeFusedMatched,
}

impl Metric {
    /// Every metric, in the aggregate's column order.
    pub const ALL: [Metric; 8] = [
        Metric::Precision,
        Metric::Recall,
        Metric::F1,
        Metric::DeSingle,
        Metric::DeFused,
        Metric::DeSingleCovisible,
        Metric::DeFusedCovisible,
        Metric::DeFusedMatched,
    ];

    /// Its column: in a run's `summary.csv` and, with `_ci95` beside it, in
    /// a batch's.
    pub fn column(self) -> &'static str {
        match self {
            Metric::Precision => "precision",
            Metric::Recall => "recall",
            Metric::F1 => "f1",
            Metric::DeSingle => "de_single_m",
            Metric::DeFused => "de_fused_m",
            Metric::DeSingleCovisible => "de_single_covis_m",
            Metric::DeFusedCovisible => "de_fused_covis_m",
            Metric::DeFusedMatched => "de_fused_matched_m",
        }
    }

    fn index(self) -> usize {
        Metric::ALL
            .iter()
            .position(|&m| m == self)
            .unwrap_or_default()
    }
}

/// The key columns of every row table.
pub const KEY_COLUMNS: [&str; 3] = ["method", "pose_noise", "fusion"];

/// One row of a run's `summary.csv`, as read back for a batch aggregate.
#[derive(Clone, Debug, PartialEq)]
pub struct RunRow {
    pub key: RowKey,
    pub n_instances: u64,
    /// By [`Metric::ALL`]'s order; NaN where undefined.
    pub values: [f64; Metric::ALL.len()],
}

impl RunRow {
    pub fn get(&self, m: Metric) -> f64 {
        self.values[m.index()]
    }
}

/// One line of a batch's `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct AggregateRow {
    pub key: RowKey,
    /// Runs with at least one instance: the means are over these.
    pub n_runs: usize,
    /// Complete runs without any instance (no metric is defined in them).
    pub n_runs_without_instances: usize,
    /// Runs in which the method identified at least one pair (precision is
    /// defined); the precision mean is over these.
    pub n_runs_precision: usize,
    pub n_instances: u64,
    /// (mean over runs, 95% CI half-width), by [`Metric::ALL`]'s order.
    pub stats: [(f64, f64); Metric::ALL.len()],
}

impl AggregateRow {
    pub fn get(&self, m: Metric) -> (f64, f64) {
        self.stats[m.index()]
    }
}

/// Aggregates runs (each its summary rows, in run order): one row per
/// (method, pose noise, fusion) in order of first appearance, with the mean
/// over the runs that have instances and the 95% interval; runs without
/// any instance are counted apart.
pub fn aggregate(runs: &[Vec<RunRow>]) -> Vec<AggregateRow> {
    let mut order: Vec<RowKey> = Vec::new();
    let mut groups: HashMap<RowKey, Vec<&RunRow>> = HashMap::new();
    for row in runs.iter().flatten() {
        if !groups.contains_key(&row.key) {
            order.push(row.key);
        }
        groups.entry(row.key).or_default().push(row);
    }
    order
        .into_iter()
        .map(|key| {
            let rows = &groups[&key];
            let stats =
                Metric::ALL.map(|m| mean_ci95(&rows.iter().map(|r| r.get(m)).collect::<Vec<_>>()));
            AggregateRow {
                key,
                n_runs: rows.iter().filter(|r| r.n_instances > 0).count(),
                n_runs_without_instances: rows.iter().filter(|r| r.n_instances == 0).count(),
                n_runs_precision: rows
                    .iter()
                    .filter(|r| r.get(Metric::Precision).is_finite())
                    .count(),
                n_instances: rows.iter().map(|r| r.n_instances).sum(),
                stats,
            }
        })
        .collect()
}

/// A batch's `summary.csv` as a table: the key, the run counts, then each
/// metric's mean and `_ci95` (and after precision, how many runs define
/// it).
pub fn aggregate_table(rows: &[AggregateRow]) -> Table {
    let mut t = Table::default();
    let text = |f: fn(&RowKey) -> &'static str| rows.iter().map(|r| f(&r.key).to_owned()).collect();
    t.text(KEY_COLUMNS[0], text(|k| k.method.as_str()));
    t.text(KEY_COLUMNS[1], text(|k| k.pose_noise.as_str()));
    t.text(KEY_COLUMNS[2], text(|k| k.fusion.as_str()));
    let count = |f: fn(&AggregateRow) -> u64| rows.iter().map(f).collect();
    t.count("n_runs", count(|r| r.n_runs as u64));
    t.count(
        "n_runs_without_instances",
        count(|r| r.n_runs_without_instances as u64),
    );
    t.count("n_instances", count(|r| r.n_instances));
    for m in Metric::ALL {
        t.number(m.column(), rows.iter().map(|r| r.get(m).0).collect());
        t.number(
            &format!("{}_ci95", m.column()),
            rows.iter().map(|r| r.get(m).1).collect(),
        );
        if m == Metric::Precision {
            t.count("n_runs_precision", count(|r| r.n_runs_precision as u64));
        }
    }
    t
}
