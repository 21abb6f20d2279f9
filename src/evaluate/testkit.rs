//! Hand-made vehicles, frames and matchers for the evaluation's tests.

use super::{PairAtLevel, Side};
use crate::fusion::{FusionSettings, FusionVariant};
use crate::geometry::{Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::matching::{Correspondence, Identification, MatchView, Matcher, Method, testkit};
use crate::sensor::{
    DetectionTruth, Observation, ObservationTruth, PoseNoiseLabel, PoseNoiseLevel,
};

/// The Delaunay graph of an observation's detections.
pub(super) fn graph(o: &Observation) -> SceneGraph {
    let positions: Vec<Vec2> = o.detections.iter().map(|d| d.position_m).collect();
    SceneGraph::delaunay(&positions).unwrap()
}

/// An observation of `objects` (id, world position) from `pose`, exact.
pub(super) fn sensed(
    ego: &str,
    pose: Pose2,
    objects: &[(Option<&str>, Vec2)],
) -> (Observation, ObservationTruth) {
    let class = crate::traffic::ObjectClass::Car;
    let obs = Observation {
        ego_id: ego.into(),
        detections: objects
            .iter()
            .map(|(_, w)| testkit::detection(pose.to_body(w), class, [0.5; 3]))
            .collect(),
    };
    let truth = ObservationTruth {
        ego_pose: pose,
        detections: objects
            .iter()
            .map(|(id, w)| DetectionTruth {
                object_id: id.map(str::to_owned),
                position_m: id.map(|_| *w),
                visible_fraction: 1.0,
                sender: false,
            })
            .collect(),
    };
    (obs, truth)
}

/// A sure correspondence of `a` and `b`.
pub(super) fn corr(a: usize, b: usize) -> Correspondence {
    Correspondence {
        a,
        b,
        probability: 1.0,
        uncertainty: 0.0,
    }
}

/// A matcher that returns fixed pairs (for property tests).
pub(super) struct Fixed(pub(super) Vec<Correspondence>);

impl Matcher for Fixed {
    fn method(&self) -> Method {
        Method::Mogm
    }
    fn identify_with(
        &self,
        _: &MatchView,
        _: &MatchView,
        _: &crate::fusion::PoseEstimate,
    ) -> Identification {
        Identification::matches_only(self.0.clone())
    }
}

/// The view of `obs` reported from `pose`, at pose-noise `level`.
pub(super) fn view_at<'a>(
    obs: &'a Observation,
    graph: &'a SceneGraph,
    pose: Pose2,
    level: PoseNoiseLevel,
) -> MatchView<'a> {
    MatchView {
        detections: &obs.detections,
        graph,
        pose_reported: pose,
        pose_noise: level,
    }
}

/// The view of `obs` reported from `pose` (exact when `pose` is the
/// true pose), at the GPS pose-noise level.
pub(super) fn exact_view<'a>(
    obs: &'a Observation,
    graph: &'a SceneGraph,
    pose: Pose2,
) -> MatchView<'a> {
    let gps = PoseNoiseLevel {
        label: PoseNoiseLabel::GPS,
        position_sigma_m: 1.2,
        heading_sigma_rad: 0.0035,
        correlation_s: None,
    };
    view_at(obs, graph, pose, gps)
}

/// Connected vehicles of a hand-made frame (exact views at GPS level).
pub(super) struct TestFrame {
    pub(super) sensed: Vec<(Observation, ObservationTruth)>,
    graphs: Vec<SceneGraph>,
    poses: Vec<Pose2>,
}

impl TestFrame {
    pub(super) fn new(sensed: Vec<(Observation, ObservationTruth)>, poses: &[Pose2]) -> Self {
        let graphs = sensed.iter().map(|(o, _)| graph(o)).collect();
        Self {
            sensed,
            graphs,
            poses: poses.to_vec(),
        }
    }

    fn side(&self, k: usize) -> Side<'_> {
        Side {
            view: exact_view(&self.sensed[k].0, &self.graphs[k], self.poses[k]),
            obs: &self.sensed[k].0,
            truth: &self.sensed[k].1,
        }
    }

    /// (0, 1), (0, 2), (1, 2), ...: every pair, as a frame lists them.
    pub(super) fn every_pair(&self) -> Vec<PairAtLevel<'_>> {
        let n = self.sensed.len();
        (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .map(|(i, j)| self.pair(i, j))
            .collect()
    }

    pub(super) fn pair(&self, i: usize, j: usize) -> PairAtLevel<'_> {
        let (first, second) = (self.side(i), self.side(j));
        PairAtLevel {
            instance: 0,
            first,
            second,
            level: first.view.pose_noise,
        }
    }
}

/// The paper's fusion only.
pub(super) fn paper_fusion() -> FusionSettings {
    FusionSettings {
        variants: vec![FusionVariant::Paper],
        align_min_matches: 3,
    }
}
