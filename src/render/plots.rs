//! The plots of `coid eval` ([`eval_plots`]) and `coid batch`
//! ([`batch_plot`]) from their data.

use std::path::Path;

use super::RenderError;
use super::charts::{Panel, bars_with_ci, cdf, line_panels};
use crate::matching::Method;
use crate::report::{AggregateRow, Metric, PlotData};
use crate::sensor::PoseNoiseLabel;

/// `coid eval`'s plots into `dir`: `lambda_sweep`, `error_cdf`,
/// `f1_per_method`, `pr_curve` and each deep method's reliability, each
/// as PNG and SVG.
pub fn eval_plots(dir: &Path, d: &PlotData) -> Result<(), RenderError> {
    let sweep: Vec<Panel> = d
        .lambda_sweep
        .iter()
        .map(|(what, pts)| Panel {
            bands: Vec::new(),
            title: format!("{what}: lambda sweep"),
            x_label: "lambda (entropy threshold, bits)".into(),
            y_label: "mean over test runs".into(),
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.05),
            series: vec![
                ("precision".into(), pts.iter().map(|p| (p.0, p.1)).collect()),
                ("recall".into(), pts.iter().map(|p| (p.0, p.2)).collect()),
                ("F1".into(), pts.iter().map(|p| (p.0, p.3)).collect()),
            ],
        })
        .collect();
    line_panels(&dir.join("lambda_sweep"), &sweep)?;
    let max_err = d
        .errors
        .iter()
        .flat_map(|(_, s, f)| s.iter().chain(f))
        .cloned()
        .filter(|x| x.is_finite())
        .fold(1.0, f64::max)
        .min(10.0);
    let cdfs: Vec<Panel> = d
        .errors
        .iter()
        .map(|(level, s, f)| Panel {
            bands: Vec::new(),
            title: format!("ours, displacement error, pose noise {level}"),
            x_label: "error (m)".into(),
            y_label: "share of objects".into(),
            x_range: (0.0, max_err),
            y_range: (0.0, 1.0),
            series: vec![("single vehicle".into(), cdf(s)), ("fused".into(), cdf(f))],
        })
        .collect();
    line_panels(&dir.join("error_cdf"), &cdfs)?;
    bars_with_ci(
        &dir.join("f1_per_method"),
        "F1 per method (mean and 95% CI over test runs)",
        "F1",
        &d.methods,
        &d.f1,
    )?;
    pr_curves(dir, d)?;
    for (method, per_level) in &d.reliability {
        let mut series: Vec<(String, Vec<(f64, f64)>)> =
            vec![("perfect".into(), vec![(0.0, 0.0), (1.0, 1.0)])];
        series.extend(per_level.iter().map(|(level, bins)| {
            let pts = bins.iter().map(|b| (b.confidence, b.accuracy)).collect();
            (format!("pose noise {level}"), pts)
        }));
        let panel = Panel {
            bands: Vec::new(),
            title: format!("{method}: reliability of identified pairs"),
            x_label: "probability E[Y] (15 bins)".into(),
            y_label: "share right".into(),
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.0),
            series,
        };
        line_panels(&dir.join(format!("reliability_{method}")), &[panel])?;
    }
    Ok(())
}

/// `pr_curve`: one panel per pose-noise level, a curve per method.
fn pr_curves(dir: &Path, d: &PlotData) -> Result<(), RenderError> {
    let pr: Vec<Panel> = d
        .pr_curves
        .iter()
        .map(|(level, curves)| Panel {
            bands: Vec::new(),
            title: format!("precision-recall, pose noise {level}"),
            x_label: "recall (pairs ranked by reported probability)".into(),
            y_label: "precision".into(),
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.05),
            series: curves.clone(),
        })
        .collect();
    if !pr.is_empty() {
        line_panels(&dir.join("pr_curve"), &pr)?;
    }
    Ok(())
}

/// A batch's F1 per method (first fusion variant; F1 does not depend on
/// it) with 95% CIs, per pose-noise level, into `dir/f1_per_method`.
pub fn batch_plot(dir: &Path, rows: &[AggregateRow]) -> Result<(), RenderError> {
    let Some(first_fusion) = rows.first().map(|r| r.key.fusion) else {
        return Ok(());
    };
    let rows: Vec<_> = rows
        .iter()
        .filter(|r| r.key.fusion == first_fusion)
        .collect();
    let mut methods: Vec<Method> = rows.iter().map(|r| r.key.method).collect();
    methods.dedup();
    // Levels by label (the order of the legend).
    let mut levels: Vec<PoseNoiseLabel> = rows.iter().map(|r| r.key.pose_noise).collect();
    levels.sort_by_key(|l| l.as_str());
    levels.dedup();
    let series: Vec<(String, Vec<(f64, f64)>)> = levels
        .iter()
        .map(|&l| {
            let v = methods
                .iter()
                .map(|&m| {
                    rows.iter()
                        .find(|r| r.key.method == m && r.key.pose_noise == l)
                        .map(|r| r.get(Metric::F1))
                        .unwrap_or((f64::NAN, f64::NAN))
                })
                .collect();
            (l.as_str().to_owned(), v)
        })
        .collect();
    let methods: Vec<String> = methods.iter().map(|m| m.as_str().to_owned()).collect();
    bars_with_ci(
        &dir.join("f1_per_method"),
        "F1 per method (mean and 95% CI over runs)",
        "F1",
        &methods,
        &series,
    )
}
