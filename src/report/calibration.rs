//! Calibration of match probabilities: reliability bins, expected
//! calibration error, Brier score, and the AUROC of the uncertainty for
//! right against wrong pairs.

/// One identified pair, for calibration: the method's probability that it
/// is right, its uncertainty, and whether it was right.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScoredPair {
    pub probability: f64,
    pub uncertainty: f64,
    pub correct: bool,
}

/// Equal-width probability bins of the calibration measures.
pub const CALIBRATION_BINS: usize = 15;

/// One bin of a reliability diagram.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReliabilityBin {
    /// Mean probability of the pairs in the bin.
    pub confidence: f64,
    /// Share of them that were right.
    pub accuracy: f64,
    pub count: usize,
}

/// The non-empty bins of `pairs` by probability (15 equal-width bins of
/// [0, 1]).
pub fn reliability(pairs: &[ScoredPair]) -> Vec<ReliabilityBin> {
    let mut sums = [(0.0, 0.0, 0usize); CALIBRATION_BINS];
    for p in pairs {
        let b = ((p.probability.clamp(0.0, 1.0) * CALIBRATION_BINS as f64) as usize)
            .min(CALIBRATION_BINS - 1);
        sums[b].0 += p.probability;
        sums[b].1 += if p.correct { 1.0 } else { 0.0 };
        sums[b].2 += 1;
    }
    sums.iter()
        .filter(|s| s.2 > 0)
        .map(|&(conf, right, n)| ReliabilityBin {
            confidence: conf / n as f64,
            accuracy: right / n as f64,
            count: n,
        })
        .collect()
}

/// Expected calibration error: the count-weighted mean gap between
/// accuracy and confidence over the bins; NaN without pairs.
pub fn expected_calibration_error(pairs: &[ScoredPair]) -> f64 {
    if pairs.is_empty() {
        return f64::NAN;
    }
    reliability(pairs)
        .iter()
        .map(|b| b.count as f64 * (b.accuracy - b.confidence).abs())
        .sum::<f64>()
        / pairs.len() as f64
}

/// Brier score: the mean squared gap between probability and outcome;
/// NaN without pairs.
pub fn brier_score(pairs: &[ScoredPair]) -> f64 {
    if pairs.is_empty() {
        return f64::NAN;
    }
    pairs
        .iter()
        .map(|p| (p.probability - if p.correct { 1.0 } else { 0.0 }).powi(2))
        .sum::<f64>()
        / pairs.len() as f64
}

/// How well the uncertainty tells wrong pairs from right ones: the
/// probability that a wrong pair has a higher uncertainty than a right one
/// (ties count half; the area under the ROC curve). NaN unless there are
/// both.
pub fn uncertainty_auroc(pairs: &[ScoredPair]) -> f64 {
    let wrong: Vec<f64> = pairs
        .iter()
        .filter(|p| !p.correct)
        .map(|p| p.uncertainty)
        .collect();
    let mut right: Vec<f64> = pairs
        .iter()
        .filter(|p| p.correct)
        .map(|p| p.uncertainty)
        .collect();
    if wrong.is_empty() || right.is_empty() {
        return f64::NAN;
    }
    right.sort_by(f64::total_cmp);
    let below = |u: f64| right.partition_point(|&r| r < u) as f64;
    let not_above = |u: f64| right.partition_point(|&r| r <= u) as f64;
    let score: f64 = wrong
        .iter()
        .map(|&u| below(u) + 0.5 * (not_above(u) - below(u)))
        .sum();
    score / (wrong.len() * right.len()) as f64
}
