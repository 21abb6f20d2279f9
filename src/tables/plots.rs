//! The data of `coid eval`'s plots: the lambda sweep of the paper's
//! method and `ours`, each
//! method's F1, the error distributions of `ours` and each deep method's
//! reliability diagrams.

use super::Inputs;
use super::calibration::pooled;
use super::paper::sweep_rows;
use super::precision_recall::pooled_curve;
use super::record::{LevelFusion, MethodLevel, RunEval};
use crate::config::Settings;
use crate::fusion::FusionVariant;
use crate::matching::MethodLambdas;
use crate::report::{LevelCurves, PlotData, SweepPoint, mean_ci95, reliability};

/// The data of `coid eval`'s plots.
pub fn plot_data(settings: &Settings, runs: &[RunEval], lambdas: &MethodLambdas) -> PlotData {
    let inp = Inputs::new(settings, runs, lambdas);
    let mean = |v: &[f64]| mean_ci95(v).0;
    let sweep = sweep_rows(&inp);
    // One panel per method and level; a method on the paper's inputs is
    // the same at every level, so it gets one.
    let lambda_sweep = sweep
        .chunks(inp.grid.len().max(1))
        .filter(|points| {
            let first = &points[0];
            first.method.inputs() != crate::matching::Inputs::Paper
                || Some(&first.pose_noise) == inp.levels.first()
        })
        .map(|points| {
            let first = &points[0];
            let label = if first.method.inputs() == crate::matching::Inputs::Paper {
                format!("{}, any pose noise", first.method.as_str())
            } else {
                format!(
                    "{}, pose noise {}",
                    first.method.as_str(),
                    first.pose_noise.as_str()
                )
            };
            let points: Vec<SweepPoint> = points
                .iter()
                .map(|p| {
                    let s = &p.scores;
                    (p.lambda, mean(&s.precision), mean(&s.recall), mean(&s.f1))
                })
                .collect();
            (label, points)
        })
        .collect();
    let f1 = inp
        .levels
        .iter()
        .map(|&l| {
            let v = inp
                .methods
                .iter()
                .map(|&m| {
                    let key = MethodLevel::new(m, l);
                    mean_ci95(&inp.per_run(|r| r.table1.get(&key).map(|c| c.f1())))
                })
                .collect();
            (l.as_str().to_owned(), v)
        })
        .collect();
    let reliability = inp
        .deep_methods()
        .iter()
        .map(|&m| {
            let per_level = inp
                .levels
                .iter()
                .map(|&l| {
                    let pairs = pooled(&inp, MethodLevel::new(m, l));
                    (l.as_str().to_owned(), reliability(&pairs))
                })
                .collect();
            (m.as_str().to_owned(), per_level)
        })
        .collect();
    PlotData {
        lambda_sweep,
        methods: inp.methods.iter().map(|m| m.as_str().to_owned()).collect(),
        f1,
        errors: error_samples(&inp),
        reliability,
        pr_curves: pr_curves(&inp),
    }
}

/// Per level: every method's pooled precision-recall curve (the oracle
/// left out: one point at (1, 1)).
fn pr_curves(inp: &Inputs) -> Vec<LevelCurves> {
    inp.levels
        .iter()
        .map(|&l| {
            let curves = inp
                .methods
                .iter()
                .filter(|m| m.kind() != crate::matching::MethodKind::Oracle)
                .map(|&m| {
                    let (points, _, _) = pooled_curve(inp, MethodLevel::new(m, l));
                    (m.as_str().to_owned(), points)
                })
                .collect();
            (l.as_str().to_owned(), curves)
        })
        .collect()
}

/// Per level: the pooled single and fused errors of `ours` (aligned fusion
/// when configured, else paper).
fn error_samples(inp: &Inputs) -> Vec<(String, Vec<f64>, Vec<f64>)> {
    let fusion = if inp.variants.contains(&FusionVariant::Aligned) {
        FusionVariant::Aligned
    } else {
        FusionVariant::Paper
    };
    inp.levels
        .iter()
        .map(|&pose_noise| {
            let key = LevelFusion { pose_noise, fusion };
            let (mut single, mut fused) = (Vec::new(), Vec::new());
            for samples in inp.runs.iter().filter_map(|r| r.ours_errors.get(&key)) {
                single.extend_from_slice(&samples.single_m);
                fused.extend_from_slice(&samples.fused_m);
            }
            (pose_noise.as_str().to_owned(), single, fused)
        })
        .collect()
}
