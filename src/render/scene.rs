//! The scene of one instance, top-down, as the paper draws it (Figs. 5
//! and 7): roads, buildings, every road user as an oriented box (connected
//! vehicles highlighted), each connected vehicle's sensors' fields of view
//! and detections, and the correspondences between the two vehicles'
//! detections, green when right and red when wrong, line width growing
//! with uncertainty; non-covisible detections ringed.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{RenderError, register_font};
use crate::geometry::{Pose2, Vec2};
use crate::matching::Correspondence;
use crate::sensor::profile::{RigSensor, sensor_in_body_m};
use crate::sensor::{Observation, ObservationTruth};
use crate::traffic::{StaticScene, TrafficFrame};

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Polygon;
    use crate::sensor::CameraSettings;
    use crate::sensor::profile::Mount;
    use crate::traffic::{Lane, ObjectClass, TrafficObject};

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
            model: None,
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
