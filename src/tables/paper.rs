//! The paper's tables: Table 1 (precision, recall and F1 per method),
//! Table 2 (F1 of the deep methods before and after thresholding at their
//! own lambda, and the paired change with its bootstrap interval), Table 3 (F1 of `ours` thresholded on each uncertainty
//! type at that type's own validated lambda), the lambda sweep (Fig. 8a) and the case study of `ours`.

use super::Inputs;
use super::columns::{Columns, ErrorStats, Scores};
use super::paired::BOOTSTRAP_SEED;
use super::record::{LevelFusion, MethodLevel};
use super::seeds::SeedSpread;
use crate::evaluate::PairCounts;
use crate::matching::Method;
use crate::matching::deep::decision::UncertaintyKind;
use crate::report::{Metric, PairedDifference, Table, paired_bootstrap};
use crate::sensor::PoseNoiseLabel;

/// The uncertainty types of Table 3, in its order.
const TABLE3_KINDS: [UncertaintyKind; 3] = [
    UncertaintyKind::Epistemic,
    UncertaintyKind::Aleatoric,
    UncertaintyKind::Total,
];

/// How many runs have a defined precision (something identified), in
/// Table 1 and the sweep.
const N_RUNS_PRECISION: &str = "n_runs_precision";

/// Table 1 (or 1b): precision, recall and F1 of each method over the runs;
/// a deep method evaluated with several training seeds has, in each run,
/// the mean over its seeds, and the spread of its seeds' F1 beside.
pub(super) fn table1(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        scores: Scores,
        spread: Option<SeedSpread>,
    }
    let rows: Vec<Row> = inp
        .method_levels()
        .map(|key| match inp.seed_spread(key) {
            Some(spread) => Row {
                key,
                scores: Scores {
                    precision: inp.per_run_over_seeds(key, PairCounts::precision),
                    recall: inp.per_run_over_seeds(key, PairCounts::recall),
                    f1: inp.per_run_over_seeds(key, PairCounts::f1),
                },
                spread: Some(spread),
            },
            None => Row {
                key,
                scores: Scores::of(inp, |run| run.table1.get(&key).copied()),
                spread: None,
            },
        })
        .collect();
    let spread = |r: &Row, f: fn(&SeedSpread) -> f64| r.spread.as_ref().map_or(f64::NAN, f);
    let mut columns = Columns::of(&rows)
        .method_level(|r| r.key)
        .text("inputs", |r| r.key.method.inputs().as_str().to_owned())
        .scores(|r| &r.scores)
        .defined("n_runs", |r| &r.scores.f1)
        .defined(N_RUNS_PRECISION, |r| &r.scores.precision);
    if rows.iter().any(|r| r.spread.is_some()) {
        columns = columns
            .text("training_seeds", |r| {
                r.spread
                    .as_ref()
                    .map_or_else(String::new, SeedSpread::label)
            })
            .number("f1_seeds_sd", |r| spread(r, SeedSpread::sd))
            .number("f1_seeds_min", |r| spread(r, SeedSpread::min))
            .number("f1_seeds_max", |r| spread(r, SeedSpread::max));
    }
    columns.table()
}

pub(super) fn table2(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        f1_before: Vec<f64>,
        f1_after: Vec<f64>,
        change: PairedDifference,
    }
    let mut rows = Vec::new();
    for m in inp.deep_methods() {
        for &l in &inp.levels {
            let before = inp.rule(m, l);
            let after = inp.own_threshold(m, l, inp.kind);
            // NaN where a run lacks one, so that the runs stay paired.
            let f1_of =
                |counts: Option<&crate::evaluate::PairCounts>| counts.map_or(f64::NAN, |c| c.f1());
            let before_per_run: Vec<f64> = inp
                .runs
                .iter()
                .map(|run| f1_of(run.unthresholded.get(&before)))
                .collect();
            let after_per_run: Vec<f64> = inp
                .runs
                .iter()
                .map(|run| f1_of(run.thresholded.get(&after)))
                .collect();
            rows.push(Row {
                key: MethodLevel::new(m, l),
                change: paired_bootstrap(&after_per_run, &before_per_run, BOOTSTRAP_SEED),
                f1_before: before_per_run,
                f1_after: after_per_run,
            });
        }
    }
    Columns::of(&rows)
        .method_level(|r| r.key)
        .stat("f1_before", |r| &r.f1_before)
        .stat("f1_after", |r| &r.f1_after)
        .number("f1_change", |r| r.change.mean)
        .number("f1_change_lo95", |r| r.change.lo)
        .number("f1_change_hi95", |r| r.change.hi)
        .table()
}

/// The methods of Table 3: the paper's method on its inputs, and ours
/// with the poses, those of them the runs evaluated.
pub(super) fn table3_methods(inp: &Inputs) -> Vec<Method> {
    inp.deep_methods()
        .into_iter()
        .filter(|m| matches!(m, Method::Coid | Method::Ours))
        .collect()
}

pub(super) fn table3(inp: &Inputs) -> Table {
    struct Row {
        method: Method,
        kind: UncertaintyKind,
        lambda: f64,
        pose_noise: PoseNoiseLabel,
        f1: Vec<f64>,
    }
    let mut rows = Vec::new();
    for m in table3_methods(inp) {
        for &l in &inp.levels {
            for kind in TABLE3_KINDS {
                let key = inp.own_threshold(m, l, kind);
                rows.push(Row {
                    method: m,
                    kind,
                    lambda: inp.grid[inp.at(m, kind)],
                    pose_noise: l,
                    f1: inp.per_run(|run| run.thresholded.get(&key).map(|c| c.f1())),
                });
            }
        }
    }
    Columns::of(&rows)
        .method(|r| r.method)
        .text("uncertainty", |r| r.kind.as_str().to_owned())
        .number("lambda", |r| r.lambda)
        .pose_noise(|r| r.pose_noise)
        .stat(Metric::F1.column(), |r| &r.f1)
        .table()
}

/// One point of the lambda sweep (Fig. 8a) of the paper's method or
/// `ours` (its own decision rule, the configured uncertainty type).
pub(super) struct SweepRow {
    pub method: Method,
    pub pose_noise: PoseNoiseLabel,
    pub lambda: f64,
    pub scores: Scores,
}

/// The lambda sweep of each Table 3 method, level by level, every lambda
/// of the grid.
pub(super) fn sweep_rows(inp: &Inputs) -> Vec<SweepRow> {
    let mut rows = Vec::new();
    for m in table3_methods(inp) {
        for &l in &inp.levels {
            let rule = inp.rule(m, l);
            for (k, &lambda) in inp.grid.iter().enumerate() {
                let key = rule.threshold(inp.kind, k);
                rows.push(SweepRow {
                    method: m,
                    pose_noise: l,
                    lambda,
                    scores: Scores::of(inp, |run| run.thresholded.get(&key).copied()),
                });
            }
        }
    }
    rows
}

pub(super) fn sweep(inp: &Inputs) -> Table {
    Columns::of(&sweep_rows(inp))
        .method(|r| r.method)
        .number("lambda", |r| r.lambda)
        .pose_noise(|r| r.pose_noise)
        .scores(|r| &r.scores)
        .defined(N_RUNS_PRECISION, |r| &r.scores.precision)
        .table()
}

/// The case study of `ours` (the paper's last table): precision, recall and
/// displacement errors over the common object set and its covisible part,
/// with oracle fusion on the same set for reference.
pub(super) fn case_study(inp: &Inputs) -> Table {
    struct Row {
        key: LevelFusion,
        scores: Scores,
        errors: ErrorStats,
        oracle_fused_m: Vec<f64>,
    }
    let mut rows = Vec::new();
    for &l in &inp.levels {
        let ours = MethodLevel::new(Method::Ours, l);
        let oracle = MethodLevel::new(Method::Oracle, l);
        for &v in &inp.variants {
            rows.push(Row {
                key: LevelFusion {
                    pose_noise: l,
                    fusion: v,
                },
                scores: Scores::of(inp, |run| run.table1.get(&ours).copied()),
                errors: ErrorStats::of(inp, |run| run.errors.get(&ours.row(v))),
                oracle_fused_m: inp
                    .per_run(|run| run.errors.get(&oracle.row(v)).map(|e| e.all.mean_fused_m())),
            });
        }
    }
    Columns::of(&rows)
        .pose_noise(|r| r.key.pose_noise)
        .fusion(|r| r.key.fusion)
        .stat(Metric::Precision.column(), |r| &r.scores.precision)
        .stat(Metric::Recall.column(), |r| &r.scores.recall)
        .errors(|r| &r.errors)
        .stat("de_fused_oracle_m", |r| &r.oracle_fused_m)
        .table()
}
