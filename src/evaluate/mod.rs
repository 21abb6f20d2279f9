//! Evaluation of one instance, and of a frame's instances together: the
//! one place that identifies a pair of vehicles' correspondences, counts
//! them against the truth (precision, recall) and fuses what they matched
//! (displacement errors, single vs fused). `run`, `eval`, `render` and the
//! training-data collection all go through [`evaluate`] or
//! [`evaluate_frame`]. Pure computation; the protocol is written down in
//! docs/protocol.md.
//!
//! One job a file: `counts` (correspondences against the truth),
//! `sources` (where correspondences come from: a matcher, the oracle, a
//! file), `pair` (one instance, one method), `frame` (a frame's decisions
//! across vehicles and their consistency), `map` (the frame's object map),
//! `estimates` (fusion per instance and over every view); here the
//! instance at one level that they all take.
//!
//! This module, the oracle and the pictures are the only readers of the
//! ground truth ([`ObservationTruth`]); matchers receive [`MatchView`]s.

mod counts;
mod estimates;
mod frame;
mod map;
mod pair;
mod sources;
#[cfg(test)]
mod testkit;

pub use counts::{PairCounts, count_pairs, is_correct, share_a_detected_object};
pub use estimates::{ObjectEstimate, ViewEstimate};
pub use frame::{Consistency, FrameEval, evaluate_frame};
pub use pair::{MethodEval, evaluate};
pub use sources::{CorrespondenceSource, ExternalMatches};

use crate::matching::MatchView;
use crate::sensor::{Observation, ObservationTruth, PoseNoiseLevel};

/// `[eval]`: the test runs of `coid eval`.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalSettings {
    /// Traffic (= sensor) seeds of the test runs; disjoint from the
    /// training runs.
    pub traffic_seeds: Vec<u64>,
    /// More scenarios (config files) to test on, each on `traffic_seeds`;
    /// disjoint from the training and validation scenarios.
    pub scenarios: Vec<std::path::PathBuf>,
    /// The training seeds whose weights the deep methods are evaluated
    /// with: the models folder's own, and the others in its `seed-<N>/`
    /// folders (empty: the models folder's weights alone).
    pub training_seeds: Vec<u64>,
}

/// One vehicle of an instance at one pose-noise level: what it knows (its
/// view, with the GPS pose of that level) and the truth beside it.
#[derive(Clone, Copy, Debug)]
pub struct Side<'a> {
    pub view: MatchView<'a>,
    pub obs: &'a Observation,
    pub truth: &'a ObservationTruth,
}

/// An instance (a step and a pair of connected vehicles) at one pose-noise
/// level.
#[derive(Clone, Copy, Debug)]
pub struct PairAtLevel<'a> {
    /// The instance's running index within its run.
    pub instance: usize,
    pub first: Side<'a>,
    pub second: Side<'a>,
    pub level: PoseNoiseLevel,
}
