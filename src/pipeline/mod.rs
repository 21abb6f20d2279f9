//! One headless run: SUMO steps -> sensing -> graphs -> instances, each
//! handed out at every pose-noise level for [`crate::evaluate`] to match,
//! count and fuse. The stages are called here in order with their own
//! settings. The only file this module reads is a deep method's weights,
//! through `io`; it writes nothing (the caller writes the results).
//!
//! This file names the parts, one job each, and holds what they share: the
//! error, the progress and the counters of a simulation. A run: `instance`,
//! `simulate`, `runners`, `frames` (and `parallel`), `run`. Over time
//! (`coid track`, `[v2x] mode = "cpm"`): `context`, `message`, `vehicle`,
//! `delivery`, `fleet`; a receiver's `peer` state with its
//! `pair_history`, `relative_pose` and `fusion_over_time`; `track`, and
//! `receptions` (messages as a run's instances).

use std::time::Duration;

use crate::bridge::BridgeError;
use crate::graph::GraphError;
use crate::io::{OutputError, WeightsError};
use crate::matching::BuildError;

mod context;
mod delivery;
mod fleet;
mod frames;
mod fusion_over_time;
mod instance;
mod message;
mod pair_history;
mod parallel;
mod peer;
mod receptions;
mod relative_pose;
mod run;
mod runners;
mod simulate;
mod track;
mod vehicle;

pub use frames::{OnEval, evaluate_frames};
pub use instance::{Instance, InstanceSide, ViewSource};
pub use run::run;
pub use runners::{choice_for, choices, runner, runners};
pub use simulate::{Step, sense_steps, simulate, simulate_frames, simulate_steps};
pub use track::{TrackResults, track};

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    #[error(transparent)]
    Graph(#[from] GraphError),
    #[error(transparent)]
    Weights(#[from] WeightsError),
    #[error(transparent)]
    Baselines(#[from] crate::io::BaselinesError),
    #[error(transparent)]
    Build(#[from] BuildError),
    #[error("{0}")]
    Render(String),
    #[error("connected vehicle(s) {0:?} never appeared in the simulation before its end")]
    MissingConnectedVehicles(Vec<String>),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{0}")]
    Worker(String),
    /// Correspondences made elsewhere that do not fit the run.
    #[error("{0}")]
    Matches(String),
}

/// Progress reported once per simulation step.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub time_s: f64,
    pub end_s: f64,
    pub instances: usize,
}

/// Counters of one simulation.
/// Prints `coid: warning: <message>` on stderr, once per process and
/// message: a command that runs the same settings many times (an
/// evaluation's runs) says it once.
fn warn_once(message: &str) {
    static SAID: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());
    let mut said = SAID
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if !said.iter().any(|m| m == message) {
        eprintln!("coid: warning: {message}");
        said.push(message.to_owned());
    }
}

#[derive(Clone, Debug, Default)]
pub struct SimStats {
    pub n_instances: usize,
    pub n_steps: u64,
    pub sim_end_s: f64,
    /// Wall time spent inside the bridge's step calls.
    pub bridge_time: Duration,
    /// Road users read over all steps (for the per-object bridge cost).
    pub objects_read: u64,
}

#[cfg(test)]
mod tests {
    //! Fixtures the tests of this module's files share (plain values, no
    //! SUMO): the shipped settings, sides made by hand, a step's context.

    use std::collections::BTreeMap;
    use std::sync::Arc;

    use super::Step;
    use super::context::Context;
    use super::instance::{InstanceSide, ViewSource};
    use super::message::Sent;
    use crate::config::Settings;
    use crate::geometry::{Cov2, Pose2, Vec2};
    use crate::rng;
    use crate::sensor::{
        Appearance, Detection, DetectionTruth, Observation, ObservationTruth, Sensed, VisibleObject,
    };
    use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

    /// The shipped defaults (`configs/default.toml`).
    pub(super) fn settings() -> Settings {
        Settings::defaults().expect("the shipped defaults are valid")
    }

    /// What a camera reports of road user `id`: a car of its own colour.
    pub(super) fn appearance(id: &str) -> Appearance {
        let h = rng::hash_str(id);
        let c = |k: u32| f64::from(((h >> (8 * k)) & 0xff) as u8) / 255.0;
        Appearance {
            class: ObjectClass::Car,
            colour_rgb: [c(0), c(1), c(2)],
            length_m: 4.5,
            width_m: 1.8,
            height_m: 1.5,
        }
    }

    /// Road users by id at their true centres (world frame).
    pub(super) type Seen<'a> = [(&'a str, Vec2)];

    /// What vehicle `id` at true pose `pose` senses at `step` of the road
    /// users `seen`: each detected where it is (body frame, covariance
    /// 0.04 m² per axis), visible, and nothing else.
    pub(super) fn vehicle_side(id: &str, pose: Pose2, seen: &Seen, step: u64) -> InstanceSide {
        let detections = seen
            .iter()
            .map(|(o, p)| Detection {
                position_m: pose.to_body(p),
                cov_m2: Cov2::identity() * 0.04,
                appearance: appearance(o),
                motion: None,
            })
            .collect();
        let truths = seen
            .iter()
            .map(|(o, p)| DetectionTruth {
                object_id: Some((*o).to_owned()),
                position_m: Some(*p),
                visible_fraction: 1.0,
                sender: false,
            })
            .collect();
        let visible = seen
            .iter()
            .map(|(o, p)| VisibleObject {
                object_id: (*o).to_owned(),
                position_m: *p,
                visible_fraction: 1.0,
            })
            .collect();
        let sensed = Sensed {
            observation: Observation {
                ego_id: String::new(),
                detections,
            },
            truth: ObservationTruth {
                ego_pose: pose,
                detections: truths,
            },
            visible,
        };
        let keys = [step, rng::hash_str(id)];
        let source = ViewSource::Vehicle(id.to_owned());
        InstanceSide::new(source, sensed, 7, &keys, 10.0, None).expect("a graph")
    }

    /// A step (number 3, at 0.3 s) of two vehicles that see three common
    /// road users (and one each alone): one instance, numbered
    /// `first_index`.
    pub(super) fn two_vehicle_step(first_index: usize) -> Step {
        let common = [
            ("a", Vec2::new(12.0, 3.0)),
            ("b", Vec2::new(18.0, -4.0)),
            ("c", Vec2::new(25.0, 1.0)),
        ];
        let mut seen0 = common.to_vec();
        seen0.push(("d", Vec2::new(5.0, 9.0)));
        let mut seen1 = common.to_vec();
        seen1.push(("e", Vec2::new(30.0, -8.0)));
        let sides = vec![
            vehicle_side("cv0", Pose2::new(Vec2::zeros(), 0.1), &seen0, 3),
            vehicle_side("cv1", Pose2::new(Vec2::new(40.0, 2.0), 3.0), &seen1, 3),
        ];
        Step::new(
            Arc::new(scene()),
            frame(&[], 3),
            sides,
            vec![(0, 1)],
            first_index,
        )
    }

    /// An empty message from `sender`, generated at `generated_s` at the
    /// identity pose.
    pub(super) fn sent(sender: &str, generated_s: f64) -> Sent {
        Sent {
            sender: sender.to_owned(),
            generated_s,
            sender_reported: vec![Pose2::identity(); 3],
            objects: Vec::new(),
            labels: Vec::new(),
            sender_pose: Pose2::identity(),
            sender_node: None,
            sender_speed_mps: 0.0,
        }
    }

    /// A car `id` at `pose`, 5 m/s.
    pub(super) fn car(id: &str, pose: Pose2) -> TrafficObject {
        TrafficObject {
            id: id.to_owned(),
            class: ObjectClass::Car,
            pose,
            length_m: 4.6,
            width_m: 1.8,
            height_m: 1.5,
            colour_rgb: [200, 10, 10],
            speed_mps: 5.0,
            type_id: "car".into(),
        }
    }

    /// A frame of step `step` (0.1 s each) with the road users `seen`.
    pub(super) fn frame(seen: &Seen, step: u64) -> TrafficFrame {
        TrafficFrame {
            step,
            time_s: step as f64 * 0.1,
            objects: seen
                .iter()
                .map(|(id, p)| car(id, Pose2::new(*p, 0.0)))
                .collect(),
        }
    }

    /// A junction at the origin, without buildings or lanes.
    pub(super) fn scene() -> StaticScene {
        StaticScene {
            junction_id: "C".into(),
            junction_position_m: Vec2::zeros(),
            buildings: Vec::new(),
            lanes: Vec::new(),
        }
    }

    /// Every road user's true centre, by id, as a [`Context`] holds it.
    pub(super) fn centres<'a>(seen: &Seen<'a>) -> BTreeMap<&'a str, Vec2> {
        seen.iter().copied().collect()
    }

    /// The context of step `step` at `time_s`, at every level of `s`.
    pub(super) fn context<'a>(
        s: &'a Settings,
        truth: &'a BTreeMap<&'a str, Vec2>,
        step: u64,
        time_s: f64,
    ) -> Context<'a> {
        Context {
            settings: s,
            v: &s.v2x,
            levels: &s.pose_noise,
            step,
            time_s,
            truth,
        }
    }
}
