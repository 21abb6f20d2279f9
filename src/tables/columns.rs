//! A table from typed rows: each column named once, beside what a row
//! gives for it ([`Columns`]); and the per-run samples that several tables
//! share, with their columns: precision, recall and F1 ([`Scores`]), and
//! the displacement errors over the common object set ([`ErrorStats`]).

use super::Inputs;
use super::record::{MethodLevel, RunEval};
use crate::evaluate::PairCounts;
use crate::fusion::FusionVariant;
use crate::report::{KEY_COLUMNS, Metric, ObjectErrors, RowKey, Table};
use crate::sensor::PoseNoiseLabel;

/// A table being made from `rows`, column by column.
pub(super) struct Columns<'r, R> {
    rows: &'r [R],
    table: Table,
}

impl<'r, R> Columns<'r, R> {
    pub(super) fn of(rows: &'r [R]) -> Self {
        Self {
            rows,
            table: Table::default(),
        }
    }

    pub(super) fn table(self) -> Table {
        self.table
    }

    pub(super) fn text(mut self, name: &str, f: impl Fn(&R) -> String) -> Self {
        self.table.text(name, self.rows.iter().map(f).collect());
        self
    }

    pub(super) fn number(mut self, name: &str, f: impl Fn(&R) -> f64) -> Self {
        self.table.number(name, self.rows.iter().map(f).collect());
        self
    }

    pub(super) fn count(mut self, name: &str, f: impl Fn(&R) -> usize) -> Self {
        let counts = self.rows.iter().map(|r| f(r) as u64).collect();
        self.table.count(name, counts);
        self
    }

    /// `name` and `name_ci95`: the mean of each row's per-run samples and
    /// the half-width of its 95% interval ([`Table::stat`]).
    pub(super) fn stat(mut self, name: &str, f: impl Fn(&R) -> &[f64]) -> Self {
        self.table.stat(name, &self.samples(f));
        self
    }

    /// `name`: how many of each row's per-run samples are defined.
    pub(super) fn defined(mut self, name: &str, f: impl Fn(&R) -> &[f64]) -> Self {
        self.table.defined(name, &self.samples(f));
        self
    }

    fn samples(&self, f: impl Fn(&R) -> &[f64]) -> Vec<Vec<f64>> {
        self.rows.iter().map(|r| f(r).to_vec()).collect()
    }

    /// The key column `method`.
    pub(super) fn method(self, f: impl Fn(&R) -> crate::matching::Method) -> Self {
        self.text(KEY_COLUMNS[0], |r| f(r).as_str().to_owned())
    }

    /// The key column `pose_noise`.
    pub(super) fn pose_noise(self, f: impl Fn(&R) -> PoseNoiseLabel) -> Self {
        self.text(KEY_COLUMNS[1], |r| f(r).as_str().to_owned())
    }

    /// The key column `fusion`.
    pub(super) fn fusion(self, f: impl Fn(&R) -> FusionVariant) -> Self {
        self.text(KEY_COLUMNS[2], |r| f(r).as_str().to_owned())
    }

    /// The key columns `method` and `pose_noise`.
    pub(super) fn method_level(self, f: impl Fn(&R) -> MethodLevel) -> Self {
        self.method(|r| f(r).method).pose_noise(|r| f(r).pose_noise)
    }

    /// The key columns of a summary row: `method`, `pose_noise`, `fusion`.
    pub(super) fn row_key(self, f: impl Fn(&R) -> RowKey) -> Self {
        self.method(|r| f(r).method)
            .pose_noise(|r| f(r).pose_noise)
            .fusion(|r| f(r).fusion)
    }

    /// `precision`, `recall` and `f1`, each with its interval.
    pub(super) fn scores(self, f: impl Fn(&R) -> &Scores) -> Self {
        self.stat(Metric::Precision.column(), |r| &f(r).precision)
            .stat(Metric::Recall.column(), |r| &f(r).recall)
            .stat(Metric::F1.column(), |r| &f(r).f1)
    }

    /// The mean displacement errors, single and fused, over the common
    /// object set and its covisible part, each with its interval.
    pub(super) fn errors(self, f: impl Fn(&R) -> &ErrorStats) -> Self {
        self.stat(Metric::DeSingle.column(), |r| &f(r).single_m)
            .stat(Metric::DeFused.column(), |r| &f(r).fused_m)
            .stat(Metric::DeSingleCovisible.column(), |r| &f(r).single_covis_m)
            .stat(Metric::DeFusedCovisible.column(), |r| &f(r).fused_covis_m)
            .stat("nees_fused", |r| &f(r).fused_nees)
            .stat("nees_fused_hedged", |r| &f(r).fused_nees_hedged)
    }
}

/// A row's per-run precision, recall and F1 (runs without the row left
/// out).
pub(super) struct Scores {
    pub precision: Vec<f64>,
    pub recall: Vec<f64>,
    pub f1: Vec<f64>,
}

impl Scores {
    /// The scores of each run's `counts`.
    pub(super) fn of(inp: &Inputs, counts: impl Fn(&RunEval) -> Option<PairCounts>) -> Self {
        Self {
            precision: inp.per_run(|run| counts(run).map(|c| c.precision())),
            recall: inp.per_run(|run| counts(run).map(|c| c.recall())),
            f1: inp.per_run(|run| counts(run).map(|c| c.f1())),
        }
    }
}

/// A row's per-run mean displacement errors (m), single and fused, over
/// the common object set and its covisible part (runs without the row
/// left out).
pub(super) struct ErrorStats {
    pub single_m: Vec<f64>,
    pub fused_m: Vec<f64>,
    pub single_covis_m: Vec<f64>,
    pub fused_covis_m: Vec<f64>,
    /// The fused estimates' mean NEES (2 degrees of freedom).
    pub fused_nees: Vec<f64>,
    /// The same against the claim hedged by the match.
    pub fused_nees_hedged: Vec<f64>,
}

impl ErrorStats {
    /// The means of each run's `errors`.
    pub(super) fn of(inp: &Inputs, errors: impl Fn(&RunEval) -> Option<&ObjectErrors>) -> Self {
        let mean = |f: fn(&ObjectErrors) -> f64| inp.per_run(|run| errors(run).map(f));
        Self {
            single_m: mean(|e| e.all.mean_single_m()),
            fused_m: mean(|e| e.all.mean_fused_m()),
            single_covis_m: mean(|e| e.covisible.mean_single_m()),
            fused_covis_m: mean(|e| e.covisible.mean_fused_m()),
            fused_nees: mean(|e| e.all.mean_fused_nees()),
            fused_nees_hedged: mean(|e| e.all.mean_fused_nees_hedged()),
        }
    }
}
