//! One headless run: SUMO steps -> sensing -> graphs -> instances, each
//! handed out at every pose-noise level for [`crate::evaluate`] to match,
//! count and fuse. The stages are called here in order with their own
//! settings. The only file this module reads is a deep method's weights,
//! through `io`; it writes nothing (the caller writes the results).
//!
//! This file names the parts and holds what they share: the error, the
//! progress and the counters of a simulation.

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
pub use instance::{Instance, InstanceSide};
pub use run::run;
pub use runners::{choice_for, choices, lambdas, runner, runners};
pub use simulate::{Step, simulate, simulate_frames, simulate_steps};
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
