//! Test fixtures shared by the matchers' tests: a small world of objects
//! whose colours and classes repeat, and vehicles that see it.

use super::{Correspondence, MatchView, Matcher};
use crate::geometry::{Cov2, Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::sensor::{Appearance, Detection, PoseNoiseLabel, PoseNoiseLevel};
use crate::traffic::ObjectClass;

pub(crate) const EXACT: PoseNoiseLevel = PoseNoiseLevel {
    label: PoseNoiseLabel::NONE,
    position_sigma_m: 0.0,
    heading_sigma_rad: 0.0,
    correlation_s: None,
};

/// Plain GPS as in the default config: 1.2 m per axis, 0.2 deg.
pub(crate) const GPS: PoseNoiseLevel = PoseNoiseLevel {
    label: PoseNoiseLabel::GPS,
    position_sigma_m: 1.2,
    heading_sigma_rad: 0.2 * std::f64::consts::PI / 180.0,
    correlation_s: None,
};

/// The first vehicle of the fixtures sits at the origin...
pub(crate) const POSE_A: Pose2Spec = (0.0, 0.0, 0.0);
/// ...the second 54 m away, facing back.
pub(crate) const POSE_B: Pose2Spec = (45.0, 30.0, -2.4);

/// (x, y, heading) of a pose, so poses can be constants.
pub(crate) type Pose2Spec = (f64, f64, f64);

pub(crate) fn pose((x, y, h): Pose2Spec) -> Pose2 {
    Pose2::new(Vec2::new(x, y), h)
}

/// Objects in the world: position, class, colour. Colours repeat.
pub(crate) fn world_objects() -> Vec<(Vec2, ObjectClass, [f64; 3])> {
    let white = [0.95; 3];
    let black = [0.1; 3];
    let red = [0.7, 0.1, 0.1];
    vec![
        (Vec2::new(12.0, 3.0), ObjectClass::Car, white),
        (Vec2::new(18.0, -6.0), ObjectClass::Car, black),
        (Vec2::new(25.0, 9.0), ObjectClass::Car, white),
        (Vec2::new(31.0, -2.0), ObjectClass::Truck, red),
        (Vec2::new(9.0, 14.0), ObjectClass::Pedestrian, black),
        (Vec2::new(22.0, 17.0), ObjectClass::Car, white),
        (Vec2::new(36.0, 12.0), ObjectClass::Car, black),
        (Vec2::new(15.0, -15.0), ObjectClass::Bicycle, red),
    ]
}

/// A detection of a car-sized object at `position_m` (body frame).
pub(crate) fn detection(position_m: Vec2, class: ObjectClass, colour: [f64; 3]) -> Detection {
    Detection {
        position_m,
        cov_m2: Cov2::identity() * 0.25,
        appearance: Appearance {
            class,
            colour_rgb: colour,
            length_m: 4.6,
            width_m: 1.8,
            height_m: 1.5,
            descriptor: None,
        },
        motion: None,
    }
}

/// One vehicle of a fixture: its detections, their true object indices,
/// its graph and its reported pose.
#[derive(Clone)]
pub(crate) struct Side {
    pub detections: Vec<Detection>,
    /// The world object behind each detection.
    pub objects: Vec<usize>,
    pub graph: SceneGraph,
    pub pose: Pose2,
    pub level: PoseNoiseLevel,
}

impl Side {
    /// A vehicle at `at` that detects `objects[k]` for each k of `order`,
    /// exactly.
    pub fn of(
        at: Pose2Spec,
        objects: &[(Vec2, ObjectClass, [f64; 3])],
        order: &[usize],
        level: PoseNoiseLevel,
    ) -> Side {
        let p = pose(at);
        let detections = order
            .iter()
            .map(|&k| {
                let (w, class, colour) = objects[k];
                detection(p.to_body(&w), class, colour)
            })
            .collect();
        Side::new(detections, order.to_vec(), p, level)
    }

    pub fn new(
        detections: Vec<Detection>,
        objects: Vec<usize>,
        pose: Pose2,
        level: PoseNoiseLevel,
    ) -> Side {
        let positions: Vec<Vec2> = detections.iter().map(|d| d.position_m).collect();
        Side {
            graph: SceneGraph::delaunay(&positions).expect("finite positions"),
            detections,
            objects,
            pose,
            level,
        }
    }

    pub fn view(&self) -> MatchView<'_> {
        MatchView {
            detections: &self.detections,
            graph: &self.graph,
            pose_reported: self.pose,
            pose_noise: self.level,
        }
    }
}

/// How many of `matches` pair the same world object.
pub(crate) fn correct(a: &Side, b: &Side, matches: &[Correspondence]) -> usize {
    matches
        .iter()
        .filter(|c| a.objects[c.a] == b.objects[c.b])
        .count()
}

/// The scene seen from `POSE_A`, and a rigidly moved, reordered copy of it
/// seen from `POSE_B`, both with exact poses.
pub(crate) fn moved_copy() -> (Side, Side) {
    let objects = world_objects();
    let all: Vec<usize> = (0..objects.len()).collect();
    (
        Side::of(POSE_A, &objects, &all, EXACT),
        Side::of(POSE_B, &objects, &[5, 2, 7, 0, 3, 6, 1, 4], EXACT),
    )
}

/// Matches [`moved_copy`]'s two sides and returns the fraction of objects
/// paired with their true twin and the number of wrong pairs.
pub(crate) fn self_match(matcher: &dyn Matcher) -> (f64, usize) {
    let (a, b) = moved_copy();
    let m = matcher.identify(&a.view(), &b.view()).matches;
    let right = correct(&a, &b, &m);
    (right as f64 / a.detections.len() as f64, m.len() - right)
}

/// The deep network's input of the Delaunay graph over `points`: classes
/// in turn, grey levels that vary, seen with heading 0.4.
pub(crate) fn graph_input(points: &[(f64, f64)]) -> super::deep::graph::OffsetGraph {
    let positions: Vec<Vec2> = points.iter().map(|&(x, y)| Vec2::new(x, y)).collect();
    let scene = SceneGraph::delaunay(&positions).unwrap();
    let detections: Vec<Detection> = positions
        .iter()
        .enumerate()
        .map(|(k, p)| detection(*p, ObjectClass::ALL[k % 7], [0.1 * k as f64 % 1.0; 3]))
        .collect();
    super::deep::graph::OffsetGraph::offsets(
        &detections,
        &scene,
        &Pose2::new(Vec2::zeros(), 0.4),
        crate::sensor::AppearanceWidth::NONE,
    )
}
