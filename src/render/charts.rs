//! Charts: line panels with 95 % bands ([`line_panels`]), grouped bars
//! with 95 % intervals ([`bars_with_ci`]), and what they take: axis ranges
//! that show the differences ([`fitted_range`]), empirical CDFs
//! ([`cdf`]).

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{RenderError, register_font};

/// One panel of a line plot: named series of (x, y) points.
#[derive(Default)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_range: (f64, f64),
    pub y_range: (f64, f64),
    pub series: Vec<(String, Vec<(f64, f64)>)>,
    /// Per series, the half-width of the 95% interval at each of its
    /// points, drawn as a band around the line (none where missing).
    pub bands: Vec<Vec<f64>>,
}

/// An axis range that shows the differences among `values` (finite ones;
/// each with its interval half-width `ci`, NaN when none): from the lowest
/// to the highest, padded by a tenth of the span, and at least
/// `min_span` wide; `(0, 1)` without any value.
pub fn fitted_range(values: &[(f64, f64)], min_span: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &(v, ci) in values.iter().filter(|(v, _)| v.is_finite()) {
        let ci = if ci.is_finite() { ci.abs() } else { 0.0 };
        lo = lo.min(v - ci);
        hi = hi.max(v + ci);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let mid = (lo + hi) / 2.0;
    let half = ((hi - lo) * 1.2).max(min_span) / 2.0;
    (mid - half, mid + half)
}

const SERIES_COLOURS: [RGBColor; 6] = [
    RGBColor(30, 90, 200),
    RGBColor(230, 120, 0),
    RGBColor(20, 160, 60),
    RGBColor(215, 30, 40),
    RGBColor(120, 60, 170),
    RGBColor(90, 90, 90),
];

/// Panels side by side, to `<stem>.png` and `<stem>.svg`.
pub fn line_panels(stem: &Path, panels: &[Panel]) -> Result<(), RenderError> {
    register_font();
    let (w, h) = (420 * panels.len().max(1) as u32, 380);
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    let fail = |p: &Path, m: String| RenderError {
        path: p.display().to_string(),
        message: m,
    };
    {
        let root = BitMapBackend::new(&png, (w, h)).into_drawing_area();
        draw_panels(&root, panels).map_err(|m| fail(&png, m))?;
        root.present().map_err(|e| fail(&png, e.to_string()))?;
    }
    {
        let root = SVGBackend::new(&svg, (w, h)).into_drawing_area();
        draw_panels(&root, panels).map_err(|m| fail(&svg, m))?;
        root.present().map_err(|e| fail(&svg, e.to_string()))?;
    }
    Ok(())
}

fn draw_panels<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    panels: &[Panel],
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let areas = root.split_evenly((1, panels.len().max(1)));
    for (panel, area) in panels.iter().zip(areas.iter()) {
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(
                panel.x_range.0..panel.x_range.1,
                panel.y_range.0..panel.y_range.1,
            )
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc(panel.x_label.as_str())
            .y_desc(panel.y_label.as_str())
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(e)?;
        for (k, (name, points)) in panel.series.iter().enumerate() {
            let colour = SERIES_COLOURS[k % SERIES_COLOURS.len()];
            if let Some(band) = panel.bands.get(k).filter(|b| b.len() == points.len()) {
                chart
                    .draw_series(std::iter::once(Polygon::new(
                        band_outline(points, band),
                        colour.mix(0.15).filled(),
                    )))
                    .map_err(e)?;
            }
            // An undefined value (a precision with no pair identified,
            // the "no threshold" row of a sweep) is left out, not drawn
            // at some made-up height.
            chart
                .draw_series(LineSeries::new(
                    points
                        .iter()
                        .copied()
                        .filter(|(x, y)| x.is_finite() && y.is_finite()),
                    colour.stroke_width(2),
                ))
                .map_err(e)?
                .label(name.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

/// The outline of a band around `points`: `y + ci` forward, `y - ci` back
/// (points without a finite value or interval left out).
fn band_outline(points: &[(f64, f64)], ci: &[f64]) -> Vec<(f64, f64)> {
    let kept: Vec<(f64, f64, f64)> = points
        .iter()
        .zip(ci)
        .filter(|((x, y), c)| x.is_finite() && y.is_finite() && c.is_finite())
        .map(|(&(x, y), &c)| (x, y, c))
        .collect();
    let upper = kept.iter().map(|&(x, y, c)| (x, y + c));
    let lower = kept.iter().rev().map(|&(x, y, c)| (x, y - c));
    upper.chain(lower).collect()
}

/// Grouped bars with 95% confidence intervals: one group per category
/// (method), one bar per series (pose-noise level); `values[s][c]` is
/// (mean, ci half-width).
pub(super) fn bars_with_ci(
    stem: &Path,
    title: &str,
    y_label: &str,
    categories: &[String],
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<(), RenderError> {
    register_font();
    let w = (90 * categories.len().max(1) as u32).max(500);
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    let fail = |p: &Path, m: String| RenderError {
        path: p.display().to_string(),
        message: m,
    };
    {
        let root = BitMapBackend::new(&png, (w, 420)).into_drawing_area();
        draw_bars(&root, title, y_label, categories, series).map_err(|m| fail(&png, m))?;
        root.present().map_err(|e| fail(&png, e.to_string()))?;
    }
    {
        let root = SVGBackend::new(&svg, (w, 420)).into_drawing_area();
        draw_bars(&root, title, y_label, categories, series).map_err(|m| fail(&svg, m))?;
        root.present().map_err(|e| fail(&svg, e.to_string()))?;
    }
    Ok(())
}

fn draw_bars<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    y_label: &str,
    categories: &[String],
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let n = categories.len().max(1) as f64;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(45)
        .build_cartesian_2d(0.0..n, 0.0..1.05)
        .map_err(e)?;
    let labels: Vec<String> = categories.to_vec();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(categories.len().max(1) * 2 + 1)
        .x_label_formatter(&|x: &f64| {
            let c = x - x.floor();
            if (c - 0.5).abs() < 1e-6 {
                labels.get(x.floor() as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
        .y_desc(y_label)
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(e)?;
    let k = series.len().max(1) as f64;
    let bar_w = 0.8 / k;
    for (s, (name, values)) in series.iter().enumerate() {
        let colour = SERIES_COLOURS[s % SERIES_COLOURS.len()];
        let x_of = |c: usize| c as f64 + 0.1 + bar_w * s as f64;
        chart
            .draw_series(
                values
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| v.0.is_finite())
                    .map(|(c, &(m, _))| {
                        Rectangle::new(
                            [(x_of(c), 0.0), (x_of(c) + bar_w * 0.9, m)],
                            colour.filled(),
                        )
                    }),
            )
            .map_err(e)?
            .label(name.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], colour.filled()));
        chart
            .draw_series(
                values
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| v.0.is_finite() && v.1.is_finite())
                    .map(|(c, &(m, ci))| {
                        let x = x_of(c) + bar_w * 0.45;
                        PathElement::new(
                            vec![(x, (m - ci).max(0.0)), (x, (m + ci).min(1.05))],
                            BLACK.stroke_width(2),
                        )
                    }),
            )
            .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(e)?;
    Ok(())
}

/// Empirical CDF points of a sample (sorted), for [`line_panels`].
pub(super) fn cdf(values: &[f64]) -> Vec<(f64, f64)> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let n = v.len().max(1) as f64;
    v.iter()
        .enumerate()
        .map(|(k, &x)| (x, (k + 1) as f64 / n))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fitted_ranges_show_the_differences_and_bands_go_round_their_lines() {
        // Values 0.80-0.84 with intervals: the axis spans them, not 0-1.
        let (lo, hi) = fitted_range(&[(0.80, 0.01), (0.84, 0.02), (f64::NAN, 0.5)], 0.05);
        assert!(lo < 0.79 && lo > 0.7 && hi > 0.86 && hi < 0.95, "{lo} {hi}");
        // A flat line still gets the minimum span, centred on it.
        let (lo, hi) = fitted_range(&[(2.0, f64::NAN), (2.0, f64::NAN)], 0.2);
        assert!((lo - 1.9).abs() < 1e-12 && (hi - 2.1).abs() < 1e-12);
        assert_eq!(fitted_range(&[], 0.1), (0.0, 1.0));
        let band = band_outline(&[(0.0, 1.0), (1.0, 2.0), (2.0, f64::NAN)], &[0.5, 0.1, 0.1]);
        assert_eq!(band, [(0.0, 1.5), (1.0, 2.1), (1.0, 1.9), (0.0, 0.5)]);
    }
}
