//! The data behind `coid eval`'s plots.

use super::calibration::ReliabilityBin;

/// A pose-noise level's reliability diagram: (level, bins).
pub type LevelReliability = (String, Vec<ReliabilityBin>);

/// One point of the lambda sweep: (lambda, precision, recall, F1).
pub type SweepPoint = (f64, f64, f64, f64);

/// One level's precision-recall curves: the level, and per method its
/// (recall, precision) points.
pub type LevelCurves = (String, Vec<(String, Vec<(f64, f64)>)>);

/// The data behind `coid eval`'s plots.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlotData {
    /// Per Table 3 method and level: (what it is, points).
    pub lambda_sweep: Vec<(String, Vec<SweepPoint>)>,
    /// Methods, and per level the (mean, ci) F1 of each method.
    pub methods: Vec<String>,
    pub f1: Vec<(String, Vec<(f64, f64)>)>,
    /// Per level: pooled single and fused errors of `ours` (aligned fusion
    /// when configured, else paper).
    pub errors: Vec<(String, Vec<f64>, Vec<f64>)>,
    /// Per deep method: per level, its reliability diagram.
    pub reliability: Vec<(String, Vec<LevelReliability>)>,
    /// Per level: each method's precision-recall curve (recall,
    /// precision), its pairs pooled over the runs.
    pub pr_curves: Vec<LevelCurves>,
}
