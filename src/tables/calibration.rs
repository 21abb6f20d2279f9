//! How far each method's decided matches can be trusted: calibration of
//! its probabilities on its identified pairs, and consistency across
//! vehicles.

use super::Inputs;
use super::columns::{Columns, Scores};
use super::record::MethodLevel;
use crate::matching::synchronize::TripleCounts;
use crate::report::{
    ScoredPair, Table, brier_score, expected_calibration_error, uncertainty_auroc,
};

/// Every identified pair of a method at a level, pooled over the runs.
pub(super) fn pooled(inp: &Inputs, key: MethodLevel) -> Vec<ScoredPair> {
    inp.runs
        .iter()
        .filter_map(|r| r.scored.get(&key))
        .flatten()
        .copied()
        .collect()
}

/// Calibration of each method's probabilities, pooled over the runs. On
/// its own identified pairs: ECE (15 bins), Brier score, and the AUROC of
/// the uncertainty for telling wrong pairs from right ones. On one common
/// set of pairs (the deep methods: in every instance, the pairs any of
/// them decided, each scored by every one's probability): ECE, Brier
/// score, and the AUROC of the probability for telling true pairs from
/// false ones; the same pairs for every method, so these compare.
pub(super) fn calibration(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        pairs: Vec<ScoredPair>,
        common: Vec<ScoredPair>,
    }
    let rows: Vec<Row> = inp
        .method_levels()
        .map(|key| Row {
            key,
            pairs: pooled(inp, key),
            common: inp
                .runs
                .iter()
                .filter_map(|r| r.common.get(&key))
                .flatten()
                .copied()
                .collect(),
        })
        .collect();
    let or_nan = |pairs: &[ScoredPair], f: fn(&[ScoredPair]) -> f64| {
        if pairs.is_empty() { f64::NAN } else { f(pairs) }
    };
    Columns::of(&rows)
        .method_level(|r| r.key)
        .count("n_pairs", |r| r.pairs.len())
        .number("ece", |r| expected_calibration_error(&r.pairs))
        .number("brier", |r| brier_score(&r.pairs))
        .number("auroc", |r| uncertainty_auroc(&r.pairs))
        .count("common_n_pairs", |r| r.common.len())
        .number("common_ece", |r| {
            or_nan(&r.common, expected_calibration_error)
        })
        .number("common_brier", |r| or_nan(&r.common, brier_score))
        .number("common_auroc", |r| or_nan(&r.common, uncertainty_auroc))
        .table()
}

/// Consistency across vehicles of each method's decided matches: triple
/// chains and the share the third pair contradicts (pooled over the runs),
/// and the implied objects as a clustering (precision, recall, F1: mean
/// over the runs with a 95% interval).
pub(super) fn consistency(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        triples: TripleCounts,
        objects: Scores,
    }
    let rows: Vec<Row> = inp
        .method_levels()
        .map(|key| {
            let mut triples = TripleCounts::default();
            for c in inp.runs.iter().filter_map(|run| run.consistency.get(&key)) {
                triples.add(c.triples);
            }
            Row {
                key,
                triples,
                objects: Scores::of(inp, |run| run.consistency.get(&key).map(|c| c.objects)),
            }
        })
        .collect();
    Columns::of(&rows)
        .method_level(|r| r.key)
        .count("triple_chains", |r| r.triples.chains)
        .number("inconsistent_triple_share", |r| r.triples.share())
        .stat("object_precision", |r| &r.objects.precision)
        .stat("object_recall", |r| &r.objects.recall)
        .stat("object_f1", |r| &r.objects.f1)
        .table()
}
