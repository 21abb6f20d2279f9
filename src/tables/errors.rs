//! Displacement errors: every method's over the common object set and its
//! covisible part, and fusion from every view by how many vehicles see the
//! object.

use super::Inputs;
use super::columns::{Columns, ErrorStats};
use super::record::ViewKey;
use crate::report::{Metric, RowKey, Table, seen_by_label};

/// Every method's displacement errors per pose-noise level and fusion
/// variant: over the common object set (every real object an ego
/// detects, the same set for every method: fused where the method
/// matched, single elsewhere) and over its covisible part; means over
/// runs with 95% intervals.
pub(super) fn errors(inp: &Inputs) -> Table {
    struct Row {
        key: RowKey,
        errors: ErrorStats,
    }
    let rows: Vec<Row> = inp
        .rows()
        .map(|key| Row {
            key,
            errors: ErrorStats::of(inp, |run| run.errors.get(&key)),
        })
        .collect();
    Columns::of(&rows)
        .row_key(|r| r.key)
        .errors(|r| &r.errors)
        .table()
}

/// Fusion from every view: per method, level, fusion variant and number
/// of vehicles that see the object (1, 2, 3, 4+), the displacement error
/// of the same (ego, object) set single, fused pairwise (mean over the
/// ego's peers that see the object) and fused from every matched view;
/// means over the runs with their 95% intervals, the object count summed.
pub(super) fn views(inp: &Inputs) -> Table {
    struct Row {
        key: ViewKey,
        n_objects: usize,
        single_m: Vec<f64>,
        pairwise_m: Vec<f64>,
        all_views_m: Vec<f64>,
    }
    let mut rows = Vec::new();
    for row in inp.rows() {
        for seen_by in 1..=4 {
            let key = ViewKey { row, seen_by };
            let sums = |run: &super::RunEval| run.views.get(&key).copied();
            let n_objects: usize = inp.runs.iter().filter_map(sums).map(|s| s.n).sum();
            if n_objects == 0 {
                continue;
            }
            rows.push(Row {
                key,
                n_objects,
                single_m: inp.per_run(|run| sums(run).map(|s| s.means().0)),
                pairwise_m: inp.per_run(|run| sums(run).map(|s| s.means().1)),
                all_views_m: inp.per_run(|run| sums(run).map(|s| s.means().2)),
            });
        }
    }
    Columns::of(&rows)
        .row_key(|r| r.key.row)
        .text("seen_by", |r| seen_by_label(r.key.seen_by))
        .count("n_objects", |r| r.n_objects)
        .stat(Metric::DeSingle.column(), |r| &r.single_m)
        .stat("de_fused_pairwise_m", |r| &r.pairwise_m)
        .stat("de_fused_all_views_m", |r| &r.all_views_m)
        .table()
}
