//! Each method's precision-recall curve and average precision: its
//! identified pairs ranked by the probability it reports, the threshold
//! lowered from the most probable pair down to the method's own operating
//! point. Operating points differ between methods (a threshold chosen on
//! validation, a dustbin, a gate); AP compares the rankings whatever the
//! point. Recall counts against every true pair of the instances, so a
//! curve ends at the method's recall and AP is at most that recall: pairs
//! a method never decides are never retrieved.

use super::Inputs;
use super::calibration::pooled;
use super::columns::Columns;
use super::record::MethodLevel;
use crate::report::{ScoredPair, Table};

/// Recall levels of the interpolated curve: 0, 0.01, ..., 1.
pub const CURVE_POINTS: usize = 101;

/// `(recall, precision)` after each distinct probability, highest first
/// (pairs of equal probability enter together), against `ground_truth`
/// true pairs; empty without true pairs.
pub fn curve(pairs: &[ScoredPair], ground_truth: usize) -> Vec<(f64, f64)> {
    if ground_truth == 0 {
        return Vec::new();
    }
    let mut ranked: Vec<&ScoredPair> = pairs.iter().collect();
    ranked.sort_by(|a, b| b.probability.total_cmp(&a.probability));
    let mut points = Vec::new();
    let (mut identified, mut correct) = (0usize, 0usize);
    for (k, p) in ranked.iter().enumerate() {
        identified += 1;
        correct += usize::from(p.correct);
        let last_of_tie = ranked
            .get(k + 1)
            .is_none_or(|next| next.probability != p.probability);
        if last_of_tie {
            points.push((
                correct as f64 / ground_truth as f64,
                correct as f64 / identified as f64,
            ));
        }
    }
    points
}

/// The area under the step curve: the sum of each point's precision times
/// the recall it adds. NaN without true pairs; 0 with nothing decided.
pub fn average_precision(pairs: &[ScoredPair], ground_truth: usize) -> f64 {
    if ground_truth == 0 {
        return f64::NAN;
    }
    area(&curve(pairs, ground_truth))
}

/// The area under a step curve's points.
fn area(points: &[(f64, f64)]) -> f64 {
    let mut ap = 0.0;
    let mut recall_before = 0.0;
    for &(recall, precision) in points {
        ap += precision * (recall - recall_before);
        recall_before = recall;
    }
    ap
}

/// A method's true pairs at a level in one run (its Table 1 count).
fn ground_truth(run: &super::RunEval, key: MethodLevel) -> Option<usize> {
    run.table1.get(&key).map(|c| c.ground_truth)
}

/// The curve of a method at a level, its pairs and true pairs pooled over
/// the runs: its points, its AP (NaN without true pairs) and its pairs.
pub(super) fn pooled_curve(inp: &Inputs, key: MethodLevel) -> (Vec<(f64, f64)>, f64, usize) {
    let pairs = pooled(inp, key);
    let truth: usize = inp.runs.iter().filter_map(|r| ground_truth(r, key)).sum();
    let points = curve(&pairs, truth);
    let ap = if truth == 0 { f64::NAN } else { area(&points) };
    (points, ap, pairs.len())
}

/// Each method's average precision at each level: the mean over the runs
/// with its 95% interval, and on the pairs of every run pooled, beside the
/// recall its curve ends at.
pub(super) fn precision_recall(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        ap: Vec<f64>,
        pooled_ap: f64,
        recall_end: f64,
        n_pairs: usize,
    }
    let rows: Vec<Row> = inp
        .method_levels()
        .map(|key| {
            let ap = inp.per_run(|r| {
                let t = ground_truth(r, key)?;
                let pairs = r.scored.get(&key).map_or(&[][..], Vec::as_slice);
                Some(average_precision(pairs, t)).filter(|v| v.is_finite())
            });
            let (points, pooled_ap, n_pairs) = pooled_curve(inp, key);
            Row {
                key,
                ap,
                pooled_ap,
                recall_end: points.last().map_or(f64::NAN, |p| p.0),
                n_pairs,
            }
        })
        .collect();
    Columns::of(&rows)
        .method_level(|r| r.key)
        .text("inputs", |r| r.key.method.inputs().as_str().to_owned())
        .stat("ap", |r| &r.ap)
        .number("ap_pooled", |r| r.pooled_ap)
        .number("recall_at_operating_point", |r| r.recall_end)
        .count("n_pairs", |r| r.n_pairs)
        .table()
}

/// Each method's pooled curve at each level, at recall 0, 0.01, ..., 1:
/// the interpolated precision (the best precision at that recall or
/// more), NaN past the recall the method reaches.
pub(super) fn pr_curve(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        recall: f64,
        precision: f64,
    }
    let mut rows = Vec::new();
    for key in inp.method_levels() {
        let (points, _, _) = pooled_curve(inp, key);
        for k in 0..CURVE_POINTS {
            let recall = k as f64 / (CURVE_POINTS - 1) as f64;
            let precision = points
                .iter()
                .filter(|p| p.0 >= recall - 1e-12)
                .map(|p| p.1)
                .fold(f64::NAN, f64::max);
            rows.push(Row {
                key,
                recall,
                precision,
            });
        }
    }
    Columns::of(&rows)
        .method_level(|r| r.key)
        .number("recall", |r| r.recall)
        .number("precision", |r| r.precision)
        .table()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(probability: f64, correct: bool) -> ScoredPair {
        ScoredPair {
            probability,
            uncertainty: 1.0 - probability,
            correct,
        }
    }

    /// Right, wrong, right out of 4 true pairs: precision 1 at recall 1/4,
    /// then 2/3 at 1/2: AP = 1/4 + 2/3 * 1/4; ties enter together; no
    /// true pairs, no AP.
    #[test]
    fn average_precision_sums_precision_over_the_recall_each_pair_adds() {
        let pairs = [pair(0.9, true), pair(0.8, false), pair(0.7, true)];
        let ap = average_precision(&pairs, 4);
        assert!((ap - (0.25 + 2.0 / 3.0 * 0.25)).abs() < 1e-12, "{ap}");
        assert_eq!(curve(&pairs, 4).last(), Some(&(0.5, 2.0 / 3.0)));
        let tied = [pair(0.5, true), pair(0.5, false)];
        assert_eq!(curve(&tied, 1), [(1.0, 0.5)]);
        assert!(average_precision(&pairs, 0).is_nan());
        assert_eq!(average_precision(&[], 3), 0.0);
    }
}
