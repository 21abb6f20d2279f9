//! An instance and its two sides: [`InstanceSide`], one side (a connected
//! vehicle's sensing, or with `[v2x] mode = "cpm"` a receiver's reported
//! tracks or a message it received) with its graph and GNSS-reported
//! poses (whose view it is: a [`ViewSource`]), and [`Instance`], two sides
//! of a step, handed out at a pose-noise level.

use super::RunError;
use crate::evaluate::{PairAtLevel, Side};
use crate::geometry::{Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::matching::MatchView;
use crate::rng::{self, Purpose};
use crate::sensor::gnss;
use crate::sensor::{PoseNoiseLabel, PoseNoiseLevel, Sensed};
use crate::traffic::{StaticScene, TrafficFrame};
use crate::v2x::{ReceptionSide, Sensing, ViewSource};

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
    /// (`[v2x] mode = "cpm"`) or read from a dataset instead of drawn
    /// afresh at each step.
    reported: Option<Vec<(PoseNoiseLabel, Pose2)>>,
    /// The accuracy the receiver claims at every level, when a dataset
    /// gives it (else it is the level's, at the vehicle's speed).
    claimed: Option<Vec<PoseNoiseLevel>>,
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
        let graph = delaunay_of(&sensed)?;
        let id_hash = rng::hash_str(&sensed.observation.ego_id);
        Ok(InstanceSide {
            source,
            sensed,
            graph,
            id_hash,
            speed_mps,
            reported,
            claimed: None,
        })
    }

    /// A side read from a dataset: its nodes in the dataset's order (no
    /// shuffle: a node's number is the dataset's), with the pose it
    /// reports and the accuracy it claims at every level.
    pub(super) fn read(
        sensed: Sensed,
        at_levels: Vec<(PoseNoiseLevel, Pose2)>,
    ) -> Result<InstanceSide, RunError> {
        let graph = delaunay_of(&sensed)?;
        let id = sensed.observation.ego_id.clone();
        Ok(InstanceSide {
            id_hash: rng::hash_str(&id),
            source: ViewSource::Vehicle(id),
            sensed,
            graph,
            speed_mps: 0.0,
            reported: Some(at_levels.iter().map(|(l, p)| (l.label, *p)).collect()),
            claimed: Some(at_levels.into_iter().map(|(l, _)| l).collect()),
        })
    }

    /// The accuracy the receiver claims at `level`: the dataset's, else
    /// the level's at the vehicle's speed (as the error is drawn).
    fn claimed(&self, level: &PoseNoiseLevel, heading_speed_sigma_mps: f64) -> PoseNoiseLevel {
        self.claimed
            .as_ref()
            .and_then(|c| c.iter().find(|l| l.label == level.label).copied())
            .unwrap_or_else(|| gnss::at_speed(level, self.speed_mps, heading_speed_sigma_mps))
    }

    /// A side of a reception (`[v2x] mode = "cpm"`), named and ordered as
    /// [`InstanceSide::new`] does.
    pub(super) fn reception(r: ReceptionSide, sensor_seed: u64) -> Result<InstanceSide, RunError> {
        InstanceSide::new(
            r.source,
            r.sensed,
            sensor_seed,
            &r.order_keys,
            r.speed_mps,
            Some(r.reported),
        )
    }

    /// What a vehicle's side brings to a step of cooperation over time.
    pub(super) fn sensing(&self) -> Sensing<'_> {
        Sensing {
            id: self.source.vehicle(),
            id_hash: self.id_hash,
            sensed: &self.sensed,
            speed_mps: self.speed_mps,
        }
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
        gnss::white_pose(
            sensor_seed,
            step,
            self.id_hash,
            level,
            &self.sensed.truth.ego_pose,
        )
    }
}

/// The Delaunay graph over a side's detections, in their order.
fn delaunay_of(sensed: &Sensed) -> Result<SceneGraph, RunError> {
    let positions: Vec<Vec2> = sensed
        .observation
        .detections
        .iter()
        .map(|d| d.position_m)
        .collect();
    Ok(SceneGraph::delaunay(&positions)?)
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
    /// and GPS-reported pose with the accuracy its receiver claims (the
    /// level's, its heading's at the vehicle's speed with `[v2x]
    /// gnss_heading_speed_sigma_mps`: as the error is drawn), with the
    /// truth beside them.
    pub fn at_level(
        &self,
        sensor_seed: u64,
        level: &PoseNoiseLevel,
        heading_speed_sigma_mps: f64,
    ) -> PairAtLevel<'a> {
        let step = self.frame.step;
        let side = |e: &'a InstanceSide| Side {
            view: MatchView {
                detections: &e.sensed.observation.detections,
                graph: &e.graph,
                pose_reported: e.reported_pose(sensor_seed, step, level),
                pose_noise: e.claimed(level, heading_speed_sigma_mps),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::tests::{car, frame, scene, vehicle_side};

    fn pose() -> Pose2 {
        Pose2::new(Vec2::new(10.0, -4.0), 0.7)
    }

    fn seen() -> Vec<(&'static str, Vec2)> {
        vec![
            ("a", Vec2::new(20.0, 0.0)),
            ("b", Vec2::new(25.0, 6.0)),
            ("c", Vec2::new(14.0, 9.0)),
            ("d", Vec2::new(30.0, -3.0)),
        ]
    }

    /// A new side takes its source's text as its id, shuffles its nodes
    /// with their truths in step (each still where its object is), and
    /// has one graph node per detection.
    #[test]
    fn a_new_side_is_named_by_its_source_and_keeps_each_node_with_its_truth() {
        let side = vehicle_side("cv0", pose(), &seen(), 3);
        assert_eq!(side.id(), "cv0");
        assert_eq!(side.sensed.observation.ego_id, "cv0");
        assert_eq!(side.graph.node_count(), 4);
        let ids: Vec<&str> = (0..4)
            .map(|k| side.sensed.truth.object_id(k).unwrap())
            .collect();
        assert_ne!(ids, ["a", "b", "c", "d"], "listed in SUMO's order");
        for (d, t) in side
            .sensed
            .observation
            .detections
            .iter()
            .zip(&side.sensed.truth.detections)
        {
            let world = pose().to_parent(&d.position_m);
            assert!((world - t.position_m.unwrap()).norm() < 1e-9);
        }
        assert!(side.sensed.own_node().is_none());
    }

    /// A side's own node (the sender's self-report) is found among its
    /// shuffled nodes.
    #[test]
    fn a_side_finds_its_own_node() {
        let mut side = vehicle_side("cv0", pose(), &seen(), 3);
        side.sensed.add_sender(&car("cv0", pose()));
        side.sensed
            .shuffle(&mut rng::stream(1, Purpose::NodeOrder, &[9]));
        let (d, t) = side.sensed.own_node().unwrap();
        assert!(t.sender && t.object_id.as_deref() == Some("cv0"));
        assert_eq!(d.position_m, Vec2::zeros());
    }

    /// A pose drawn at a level comes from the side's stream for the step:
    /// the same draw again, another at the next step, the truth at no
    /// noise. A carried pose is returned as it was carried.
    #[test]
    fn a_reported_pose_is_drawn_per_step_or_carried() {
        let side = vehicle_side("cv0", pose(), &seen(), 3);
        let gps = PoseNoiseLevel {
            label: PoseNoiseLabel::GPS,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.01,
            correlation_s: None,
        };
        let none = PoseNoiseLevel {
            label: PoseNoiseLabel::NONE,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
            correlation_s: None,
        };
        let p = side.reported_pose(7, 3, &gps);
        assert_eq!(p, side.reported_pose(7, 3, &gps));
        assert_ne!(p, side.reported_pose(7, 4, &gps));
        assert!((p.position_m() - pose().position_m()).norm() > 1e-6);
        assert_eq!(side.reported_pose(7, 3, &none), pose());
        let carried = Pose2::new(Vec2::new(1.0, 2.0), 0.3);
        let sensed = side.sensed.clone();
        let side = InstanceSide::new(
            ViewSource::Vehicle("cv0".into()),
            sensed,
            7,
            &[1],
            0.0,
            Some(vec![
                (PoseNoiseLabel::NONE, pose()),
                (PoseNoiseLabel::GPS, carried),
            ]),
        )
        .unwrap();
        assert_eq!(side.reported_pose(7, 3, &gps), carried);
        assert_eq!(side.reported_pose(7, 99, &gps), carried);
    }

    /// An instance at a level hands both sides' detections, graphs and
    /// reported poses to the matcher's views, with their truths beside.
    #[test]
    fn an_instance_at_a_level_pairs_each_sides_view_with_its_truth() {
        let a = vehicle_side("cv0", pose(), &seen(), 3);
        let b = vehicle_side(
            "cv1",
            Pose2::new(Vec2::new(40.0, 0.0), 3.0),
            &seen()[1..],
            3,
        );
        let (scene, frame) = (scene(), frame(&[], 3));
        let inst = Instance {
            index: 5,
            scene: &scene,
            frame: &frame,
            a: &a,
            b: &b,
        };
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::RTK,
            position_sigma_m: 0.2,
            heading_sigma_rad: 0.003,
            correlation_s: None,
        };
        let pair = inst.at_level(7, &level, 0.0);
        assert_eq!(pair.instance, 5);
        assert_eq!(pair.level, level);
        assert_eq!(pair.first.obs.ego_id, "cv0");
        assert_eq!(pair.second.view.detections.len(), 3);
        assert_eq!(pair.second.truth.detections.len(), 3);
        assert_eq!(pair.first.view.pose_reported, a.reported_pose(7, 3, &level));
    }
}
