//! Pictures (plotters, PNG and SVG): the scene of one instance, top-down,
//! as the paper draws it (Figs. 5 and 7): roads, buildings, every road user
//! as an oriented box (connected vehicles highlighted), each connected
//! vehicle's camera frustum and detections, and the correspondences between
//! the two vehicles' detections, green when right and red when wrong, line
//! width growing with uncertainty; non-covisible detections ringed.
//!
//! Also the plots of `coid eval` (lambda sweep, error CDFs, F1 per method)
//! and `coid batch` (F1 per method).
//!
//! This module and `io` are the only ones that write result files; it
//! draws what it is given into the folder it is given (a temporary one that
//! `io` renames into place).

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::geometry::{Pose2, Vec2};
use crate::matching::{Correspondence, Method};
use crate::report::{AggregateRow, Metric, PlotData};
use crate::sensor::PoseNoiseLabel;
use crate::sensor::profile::{RigSensor, sensor_in_body_m};
use crate::sensor::{Observation, ObservationTruth};
use crate::traffic::{StaticScene, TrafficFrame};

static FONT: Once = Once::new();

/// Registers the shipped DejaVu Sans for all text (no system fonts needed).
fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

#[derive(Debug, thiserror::Error)]
#[error("cannot draw {path}: {message}")]
pub struct RenderError {
    pub path: String,
    pub message: String,
}

/// Everything one scene picture shows.
pub struct SceneView<'a> {
    pub scene: &'a StaticScene,
    pub frame: &'a TrafficFrame,
    /// The sensors each of the two connected vehicles carries (its
    /// detector profile's or its rig's), and where they sit on it.
    pub sensors: [Vec<RigSensor>; 2],
    /// The two connected vehicles' observations with the truth beside
    /// them (detections are placed in the world with each vehicle's true
    /// pose: what it measured about its surroundings).
    pub egos: [(&'a Observation, &'a ObservationTruth); 2],
    /// The vehicle behind each of them (a message's sender), by its id in
    /// `frame`: whose frustums are drawn and whose box is outlined.
    pub vehicles: [&'a str; 2],
    pub matches: &'a [Correspondence],
    pub caption: String,
    /// Half the width of the square window around the junction, metres.
    pub half_window_m: f64,
}

const EGO_COLOURS: [RGBColor; 2] = [RGBColor(30, 90, 200), RGBColor(230, 120, 0)];
const RIGHT: RGBColor = RGBColor(20, 160, 60);
const WRONG: RGBColor = RGBColor(215, 30, 40);

/// Draws `view` to `<stem>.png` and `<stem>.svg`.
pub fn render_scene(view: &SceneView, stem: &Path, size_px: u32) -> Result<(), RenderError> {
    register_font();
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    let err = |p: &Path| {
        let path = p.display().to_string();
        move |e: String| RenderError {
            path: path.clone(),
            message: e,
        }
    };
    {
        let root = BitMapBackend::new(&png, (size_px, size_px)).into_drawing_area();
        draw(view, &root).map_err(err(&png))?;
        root.present().map_err(|e| err(&png)(e.to_string()))?;
    }
    {
        let root = SVGBackend::new(&svg, (size_px, size_px)).into_drawing_area();
        draw(view, &root).map_err(err(&svg))?;
        root.present().map_err(|e| err(&svg)(e.to_string()))?;
    }
    Ok(())
}

fn pt(p: &Vec2) -> (f64, f64) {
    (p.x, p.y)
}

fn draw<DB: DrawingBackend>(view: &SceneView, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let c = view.scene.junction_position_m;
    let h = view.half_window_m;
    let chart = ChartBuilder::on(root)
        .caption(&view.caption, ("sans-serif", 18))
        .margin(10)
        .build_cartesian_2d((c.x - h)..(c.x + h), (c.y - h)..(c.y + h))
        .map_err(e)?;
    let area = chart.plotting_area();
    let (w_px, _) = area.dim_in_pixel();
    let px_per_m = f64::from(w_px) / (2.0 * h);
    draw_ground(view, area, px_per_m).map_err(e)?;
    draw_frustums(view, area).map_err(e)?;
    draw_road_users(view, area).map_err(e)?;
    draw_detections(view, area).map_err(e)?;
    draw_matches(view, area).map_err(e)?;
    draw_legend(root).map_err(e)
}

type Area<DB> = DrawingArea<
    DB,
    plotters::coord::cartesian::Cartesian2d<
        plotters::coord::types::RangedCoordf64,
        plotters::coord::types::RangedCoordf64,
    >,
>;
type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// Roads (lanes as thick grey lines) and buildings.
fn draw_ground<DB: DrawingBackend>(
    view: &SceneView,
    area: &Area<DB>,
    px_per_m: f64,
) -> DrawResult<DB> {
    for lane in &view.scene.lanes {
        let width = ((lane.width_m * px_per_m).round() as u32).max(1);
        let style = RGBColor(205, 205, 205).stroke_width(width);
        area.draw(&PathElement::new(
            lane.centre_m.iter().map(pt).collect::<Vec<_>>(),
            style,
        ))?;
    }
    for b in &view.scene.buildings {
        let pts: Vec<(f64, f64)> = b.vertices_m.iter().map(pt).collect();
        area.draw(&Polygon::new(pts.clone(), RGBColor(200, 180, 150).filled()))?;
        area.draw(&PathElement::new(pts, RGBColor(120, 100, 80)))?;
    }
    Ok(())
}

/// Each connected vehicle's sensors' fields of view (a full turn: a
/// rotating lidar's disc).
fn draw_frustums<DB: DrawingBackend>(view: &SceneView, area: &Area<DB>) -> DrawResult<DB> {
    for (k, vehicle) in view.vehicles.iter().enumerate() {
        let Some(obj) = view.frame.find(vehicle).map(|i| &view.frame.objects[i]) else {
            continue;
        };
        for s in &view.sensors[k] {
            let camera = &s.geometry;
            let at = sensor_in_body_m(s.mount, obj.length_m);
            let cam = obj.pose.compose(&Pose2::new(at, s.yaw_rad()));
            let mut pts = vec![pt(&cam.position_m())];
            let segments = (camera.fov_rad / 0.1).ceil().max(16.0) as u32;
            for s in 0..=segments {
                let a = -camera.fov_rad / 2.0 + camera.fov_rad * f64::from(s) / f64::from(segments);
                pts.push(pt(
                    &cam.to_parent(&(Vec2::new(a.cos(), a.sin()) * camera.range_m))
                ));
            }
            area.draw(&Polygon::new(pts, EGO_COLOURS[k].mix(0.08).filled()))?;
        }
    }
    Ok(())
}

/// Every road user as an oriented box; connected vehicles outlined.
fn draw_road_users<DB: DrawingBackend>(view: &SceneView, area: &Area<DB>) -> DrawResult<DB> {
    for o in &view.frame.objects {
        let corners: Vec<(f64, f64)> = o.footprint().corners().iter().map(pt).collect();
        let fill = RGBColor(o.colour_rgb[0], o.colour_rgb[1], o.colour_rgb[2]);
        area.draw(&Polygon::new(corners.clone(), fill.filled()))?;
        let ego = view.vehicles.iter().position(|v| *v == o.id);
        let outline = match ego {
            Some(k) => EGO_COLOURS[k].stroke_width(3),
            None => BLACK.stroke_width(1),
        };
        let mut closed = corners.clone();
        closed.push(corners[0]);
        area.draw(&PathElement::new(closed, outline))?;
    }
    Ok(())
}

/// Detection `i` of vehicle `k`, in the world with the vehicle's true pose.
fn detection_world(view: &SceneView, k: usize, i: usize) -> Vec2 {
    let (obs, truth) = view.egos[k];
    truth.ego_pose.to_parent(&obs.detections[i].position_m)
}

/// Detections as crosses, ringed when the other vehicle does not see them.
fn draw_detections<DB: DrawingBackend>(view: &SceneView, area: &Area<DB>) -> DrawResult<DB> {
    for (k, (obs, truth)) in view.egos.iter().enumerate() {
        let other = view.egos[1 - k].1;
        for i in 0..obs.detections.len() {
            let p = pt(&detection_world(view, k, i));
            area.draw(&Cross::new(p, 5, EGO_COLOURS[k].stroke_width(2)))?;
            let covisible = truth
                .object_id(i)
                .is_some_and(|id| other.find(id).is_some());
            if !covisible {
                area.draw(&Circle::new(p, 8, EGO_COLOURS[k].stroke_width(1)))?;
            }
        }
    }
    Ok(())
}

/// Correspondences: green right, red wrong, wider when more uncertain.
fn draw_matches<DB: DrawingBackend>(view: &SceneView, area: &Area<DB>) -> DrawResult<DB> {
    for m in view.matches {
        let a = view.egos[0].1.object_id(m.a);
        let right = a.is_some() && a == view.egos[1].1.object_id(m.b);
        let width = 1 + (4.0 * m.uncertainty.clamp(0.0, 1.0)).round() as u32;
        let colour = if right { RIGHT } else { WRONG };
        area.draw(&PathElement::new(
            vec![
                pt(&detection_world(view, 0, m.a)),
                pt(&detection_world(view, 1, m.b)),
            ],
            colour.stroke_width(width),
        ))?;
    }
    Ok(())
}

/// The legend (top-left), drawn in pixels.
fn draw_legend<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let legend: [(&str, ShapeStyle); 6] = [
        ("vehicle 1 detections", EGO_COLOURS[0].stroke_width(2)),
        ("vehicle 2 detections", EGO_COLOURS[1].stroke_width(2)),
        ("correct match", RIGHT.stroke_width(3)),
        ("wrong match", WRONG.stroke_width(3)),
        ("ring: not seen by the other", BLACK.stroke_width(1)),
        ("thicker line: more uncertain", BLACK.stroke_width(4)),
    ];
    let (x0, y0) = (20i32, 40i32);
    root.draw(&Rectangle::new(
        [(x0 - 8, y0 - 12), (x0 + 250, y0 + 6 * 20)],
        WHITE.mix(0.85).filled(),
    ))?;
    for (k, (label, style)) in legend.iter().enumerate() {
        let y = y0 + 20 * k as i32;
        root.draw(&PathElement::new(vec![(x0, y), (x0 + 24, y)], *style))?;
        root.draw(&Text::new(
            label.to_string(),
            (x0 + 32, y - 7),
            ("sans-serif", 13),
        ))?;
    }
    Ok(())
}

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
pub fn bars_with_ci(
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
pub fn cdf(values: &[f64]) -> Vec<(f64, f64)> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let n = v.len().max(1) as f64;
    v.iter()
        .enumerate()
        .map(|(k, &x)| (x, (k + 1) as f64 / n))
        .collect()
}

/// `coid eval`'s plots into `dir`: `lambda_sweep`, `error_cdf` and
/// `f1_per_method`, each as PNG and SVG.
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Polygon;
    use crate::sensor::CameraSettings;
    use crate::sensor::profile::Mount;
    use crate::traffic::{Lane, ObjectClass, TrafficObject};

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

    fn non_white_share(path: &Path) -> (u32, u32, f64) {
        let img = image::open(path).unwrap().to_rgb8();
        let n = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        (
            img.width(),
            img.height(),
            n as f64 / (img.width() * img.height()) as f64,
        )
    }

    #[test]
    fn a_scene_with_one_vehicle_and_no_detections_renders() {
        let share = render_one_vehicle(1.5, Mount::Front);
        // Road, building, frustum and legend cover part of the picture,
        // not all of it.
        assert!(share > 0.05 && share < 0.9, "non-white share {share}");
    }

    /// A rotating lidar's field of view is a disc around the roof: it
    /// covers more of the picture than a front camera's frustum.
    #[test]
    fn a_lidar_is_drawn_as_a_disc() {
        let camera = render_one_vehicle(1.5, Mount::Front);
        let lidar = render_one_vehicle(std::f64::consts::TAU, Mount::Roof);
        assert!(lidar > camera + 0.1, "lidar {lidar}, camera {camera}");
    }

    /// Renders one vehicle with sensors of `fov_rad` on `mount`; the
    /// picture's non-white share.
    fn render_one_vehicle(fov_rad: f64, mount: Mount) -> f64 {
        let scene = StaticScene {
            junction_id: "C".into(),
            junction_position_m: Vec2::zeros(),
            buildings: vec![Polygon {
                vertices_m: vec![
                    Vec2::new(10.0, 10.0),
                    Vec2::new(30.0, 10.0),
                    Vec2::new(30.0, 30.0),
                    Vec2::new(10.0, 30.0),
                ],
            }],
            lanes: vec![Lane {
                width_m: 3.2,
                centre_m: vec![Vec2::new(-80.0, -1.6), Vec2::new(80.0, -1.6)],
            }],
        };
        let ego = TrafficObject {
            id: "cv0".into(),
            class: ObjectClass::Car,
            pose: Pose2::new(Vec2::new(-20.0, -1.6), 0.0),
            length_m: 4.6,
            width_m: 1.8,
            height_m: 1.5,
            colour_rgb: [240, 240, 240],
            speed_mps: 5.0,
            type_id: "car".into(),
        };
        let frame = TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects: vec![ego.clone()],
        };
        let obs = Observation {
            ego_id: "cv0".into(),
            detections: vec![],
        };
        let truth = ObservationTruth {
            ego_pose: ego.pose,
            detections: vec![],
        };
        let other = Observation {
            ego_id: "cv1".into(),
            detections: vec![],
        };
        let other_truth = ObservationTruth {
            ego_pose: Pose2::identity(),
            detections: vec![],
        };
        let geometry = CameraSettings {
            fov_rad,
            range_m: 70.0,
            height_m: 1.5,
            yaw_offsets_rad: vec![0.0],
        };
        let rig = vec![RigSensor { geometry, mount }];
        let view = SceneView {
            scene: &scene,
            frame: &frame,
            sensors: [rig.clone(), rig],
            egos: [(&obs, &truth), (&other, &other_truth)],
            vehicles: ["cv0", "cv1"],
            matches: &[],
            caption: "empty".into(),
            half_window_m: 80.0,
        };
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("scene");
        render_scene(&view, &stem, 400).unwrap();
        let (w, h, share) = non_white_share(&stem.with_extension("png"));
        assert_eq!((w, h), (400, 400));
        let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("polygon"));
        share
    }
}
