//! An instance and its two sides: [`InstanceSide`], one side (a connected
//! vehicle's sensing, or with `[v2x] mode = "cpm"` a receiver's reported
//! tracks or a message it received) with its graph and GNSS-reported
//! poses, [`ViewSource`], whose view a side is, and [`Instance`], two sides
//! of a step, handed out at a pose-noise level.

use std::fmt;

use super::RunError;
use crate::evaluate::{PairAtLevel, Side};
use crate::geometry::{Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::matching::MatchView;
use crate::rng::{self, Purpose};
use crate::sensor::{self, Detection, DetectionTruth, PoseNoiseLabel, PoseNoiseLevel, Sensed};
use crate::traffic::{StaticScene, TrafficFrame};

/// Whose view one side of an instance is. Its text ([`fmt::Display`]) is
/// the side's id wherever a side is named (the observation's `ego_id`,
/// hence the exports' and tables' ids): the vehicle's id, or `<sender> ->
/// <receiver>` for a message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ViewSource {
    /// A connected vehicle's own view: what it sensed at the step, or with
    /// `[v2x] mode = "cpm"` its reported tracks.
    Vehicle(String),
    /// A message `sender` sent and `receiver` received (`[v2x] mode =
    /// "cpm"`).
    Message { sender: String, receiver: String },
}

impl ViewSource {
    /// The vehicle whose view this is: the vehicle, or the message's
    /// sender.
    pub fn vehicle(&self) -> &str {
        match self {
            ViewSource::Vehicle(id) => id,
            ViewSource::Message { sender, .. } => sender,
        }
    }
}

impl fmt::Display for ViewSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ViewSource::Vehicle(id) => f.write_str(id),
            ViewSource::Message { sender, receiver } => write!(f, "{sender} -> {receiver}"),
        }
    }
}

/// One side of an instance: a connected vehicle near the junction at one
/// step, with what it sees; or, with `[v2x] mode = "cpm"`, one side of a
/// reception: a receiver's reported tracks, or a message it received.
pub struct InstanceSide {
    /// Whose view this is.
    pub source: ViewSource,
    /// What the side holds; its observation's `ego_id` is the source's
    /// text.
    pub sensed: Sensed,
    pub graph: SceneGraph,
    /// The hash of the side's id text (a key of its random streams).
    pub(super) id_hash: u64,
    /// The vehicle's speed (m/s), forward.
    pub(super) speed_mps: f64,
    /// The GNSS-reported pose at every level, when it is carried over time
    /// (`[v2x] mode = "cpm"`) instead of drawn afresh at each step.
    reported: Option<Vec<(PoseNoiseLabel, Pose2)>>,
}

impl InstanceSide {
    /// A side from what it holds, named by `source` (the observation's id
    /// is set to its text here): its nodes listed in the order of the
    /// `Purpose::NodeOrder` stream `order_keys` (no order may carry
    /// labels), then its Delaunay graph.
    pub(super) fn new(
        source: ViewSource,
        mut sensed: Sensed,
        sensor_seed: u64,
        order_keys: &[u64],
        speed_mps: f64,
        reported: Option<Vec<(PoseNoiseLabel, Pose2)>>,
    ) -> Result<InstanceSide, RunError> {
        sensed.observation.ego_id = source.to_string();
        sensed.shuffle(&mut rng::stream(
            sensor_seed,
            Purpose::NodeOrder,
            order_keys,
        ));
        let positions: Vec<Vec2> = sensed
            .observation
            .detections
            .iter()
            .map(|d| d.position_m)
            .collect();
        let graph = SceneGraph::delaunay(&positions)?;
        let id_hash = rng::hash_str(&sensed.observation.ego_id);
        Ok(InstanceSide {
            source,
            sensed,
            graph,
            id_hash,
            speed_mps,
            reported,
        })
    }

    /// The side's own node, when it has one (the sender's self-report,
    /// `[matching] sender_as_node`): its detection and truth.
    pub(super) fn own_node(&self) -> Option<(Detection, DetectionTruth)> {
        let k = self.sensed.truth.detections.iter().position(|d| d.sender)?;
        Some((
            self.sensed.observation.detections[k].clone(),
            self.sensed.truth.detections[k].clone(),
        ))
    }

    /// The side's id: its source's text.
    pub fn id(&self) -> &str {
        &self.sensed.observation.ego_id
    }

    /// The pose this vehicle's GPS reports at `step` at a noise level (its
    /// own seeded stream per step, vehicle and level), or the one it
    /// carries at that level.
    pub fn reported_pose(&self, sensor_seed: u64, step: u64, level: &PoseNoiseLevel) -> Pose2 {
        if let Some(carried) = &self.reported {
            return carried
                .iter()
                .find(|(l, _)| *l == level.label)
                .map(|(_, p)| *p)
                .expect("a side carries a pose at every level of its run");
        }
        let mut s = rng::stream(
            sensor_seed,
            Purpose::PoseNoise,
            &[step, self.id_hash, level.label.stream_code()],
        );
        sensor::reported_pose(&self.sensed.truth.ego_pose, level, &mut s)
    }
}

/// One evaluation instance: a step and a pair of sides (connected vehicles
/// near the junction, or a receiver and a message it received) that detect
/// at least one common object.
pub struct Instance<'a> {
    /// Running index within the simulation.
    pub index: usize,
    pub scene: &'a StaticScene,
    pub frame: &'a TrafficFrame,
    /// The pair, ordered by id ([`InstanceSide::id`]).
    pub a: &'a InstanceSide,
    pub b: &'a InstanceSide,
}

impl<'a> Instance<'a> {
    /// The instance at a pose-noise level: each vehicle's detections, graph
    /// and GPS-reported pose, with the truth beside them.
    pub fn at_level(&self, sensor_seed: u64, level: &PoseNoiseLevel) -> PairAtLevel<'a> {
        let step = self.frame.step;
        let side = |e: &'a InstanceSide| Side {
            view: MatchView {
                detections: &e.sensed.observation.detections,
                graph: &e.graph,
                pose_reported: e.reported_pose(sensor_seed, step, level),
                pose_noise: *level,
            },
            obs: &e.sensed.observation,
            truth: &e.sensed.truth,
        };
        PairAtLevel {
            instance: self.index,
            first: side(self.a),
            second: side(self.b),
            level: *level,
        }
    }
}
