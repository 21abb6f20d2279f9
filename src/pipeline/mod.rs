//! One headless run: SUMO steps -> sensing -> graphs -> instances, each
//! handed out at every pose-noise level for [`crate::evaluate`] to match,
//! count and fuse. The stages are called here in order with their own
//! settings. The only file this module reads is a deep method's weights,
//! through `io`; it writes nothing (the caller writes the results).
//!
//! This file names the parts, one job each, and holds what they share: the
//! error, the progress and the counters of a simulation. A run: `instance`,
//! `simulate`, `runners`, `evaluation`, `frames` (and `parallel`), `run`; `coid track`:
//! `track`. Cooperation over time itself (trackers, messages, the channel,
//! the receivers) is [`crate::v2x`]'s; this module runs it.

use std::time::Duration;

use crate::bridge::BridgeError;
use crate::graph::GraphError;
use crate::io::{OutputError, WeightsError};
use crate::matching::BuildError;

mod evaluation;
mod frames;
mod instance;
mod parallel;
mod replay;
mod run;
mod runners;
mod simulate;
mod track;

pub use crate::v2x::{TrackResults, ViewSource};
pub use evaluation::OnEval;
pub use frames::evaluate_frames;
pub use instance::{Instance, InstanceSide};
pub use replay::network_node_attributes;
pub use run::run;
pub use runners::{Found, choice_for, choices, runner, runner_with, runners, runners_with};
pub use simulate::{Step, sense_steps, sighting_pairs, simulate, simulate_frames, simulate_steps};
pub use track::track;

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
    /// A dataset that does not fit, or cannot stand in for a run.
    #[error("dataset {dir}: {why}")]
    Dataset { dir: String, why: String },
    /// The re-identification descriptor cannot be calibrated, or a run
    /// was asked for before it was.
    #[error("{0}")]
    Calibration(String),
}

/// Progress reported once per simulation step.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub time_s: f64,
    pub end_s: f64,
    pub instances: usize,
}

/// What the runs of one command have to say beside their results, each
/// message once (`coid: warning: <message>` on stderr): the command owns
/// it and hands it to every run it starts, so that the same settings run
/// many times (an evaluation's runs) say it once.
#[derive(Debug, Default)]
pub struct Warnings {
    said: std::sync::Mutex<Vec<String>>,
}

impl Warnings {
    /// Prints `message` as a warning unless it was said before.
    pub fn say(&self, message: &str) {
        let mut said = self
            .said
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if !said.iter().any(|m| m == message) {
            eprintln!("coid: warning: {message}");
            said.push(message.to_owned());
        }
    }
}

/// Counters of one simulation.
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
    //! SUMO): sides and steps made by hand; the plainer ones are
    //! [`crate::v2x::testkit`]'s.

    use std::sync::Arc;

    use super::Step;
    use super::instance::InstanceSide;
    use crate::geometry::{Pose2, Vec2};
    use crate::rng;
    use crate::v2x::ViewSource;
    use crate::v2x::testkit::{Seen, sensed};
    pub(super) use crate::v2x::testkit::{car, frame, scene, settings};

    /// What vehicle `id` at true pose `pose` senses at `step` of the road
    /// users `seen` ([`sensed`]), as a side named by the vehicle (speed
    /// 10 m/s).
    pub(super) fn vehicle_side(id: &str, pose: Pose2, seen: &Seen, step: u64) -> InstanceSide {
        let keys = [step, rng::hash_str(id)];
        let source = ViewSource::Vehicle(id.to_owned());
        InstanceSide::new(source, sensed(pose, seen), 7, &keys, 10.0, None).expect("a graph")
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
}
