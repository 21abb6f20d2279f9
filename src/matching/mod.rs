//! Correspondence identification: which detections of two vehicles are the
//! same object. Every method implements [`Matcher`]; the rest of the program
//! sees only plain [`Correspondence`] lists with a probability and an
//! uncertainty per pair. Pairs not listed are "no match" (non-covisible).

mod gps_hungarian;
mod oracle;

pub use gps_hungarian::GpsHungarian;
pub use oracle::Oracle;

use serde::Deserialize;

use crate::config::PoseNoiseLevel;
use crate::geometry::Pose2;
use crate::graph::SceneGraph;
use crate::sensor::Detection;

/// The matching methods, with the labels used in configs and results.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Deserialize)]
pub enum Method {
    /// Detections moved into the ego frame with the GPS poses, gated
    /// Hungarian assignment on Mahalanobis distance.
    #[serde(rename = "gps-hungarian")]
    GpsHungarian,
    /// The true correspondences: an upper bound for fusion.
    #[serde(rename = "oracle")]
    Oracle,
}

impl Method {
    pub fn as_str(self) -> &'static str {
        match self {
            Method::GpsHungarian => "gps-hungarian",
            Method::Oracle => "oracle",
        }
    }
}

/// One vehicle's side of a matching problem: what that vehicle knows.
#[derive(Clone, Copy, Debug)]
pub struct MatchView<'a> {
    /// Detections in the vehicle's body frame.
    pub detections: &'a [Detection],
    pub graph: &'a SceneGraph,
    /// The vehicle's pose as its GPS reports it, world frame.
    pub pose_reported: Pose2,
    /// The accuracy the GPS claims for that pose (the noise level's sigmas).
    pub pose_noise: PoseNoiseLevel,
}

/// Detection `a` of the first vehicle is detection `b` of the second.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    pub a: usize,
    pub b: usize,
    /// The method's probability that the pair is the same object.
    pub probability: f64,
    /// Binary entropy of `probability`, in bits (0 = certain, 1 = coin flip).
    pub uncertainty: f64,
}

/// A one-to-one correspondence method between two vehicles' detections.
pub trait Matcher: Send + Sync {
    fn method(&self) -> Method;
    /// One-to-one pairs (each `a` and each `b` at most once), sorted by `a`.
    fn match_pair(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence>;
}

/// Binary entropy in bits, 0 at p in {0, 1} and 1 at p = 0.5.
pub fn binary_entropy_bits(p: f64) -> f64 {
    let p = p.clamp(0.0, 1.0);
    let h = |q: f64| if q <= 0.0 { 0.0 } else { -q * q.log2() };
    h(p) + h(1.0 - p)
}

/// Builds the matcher for a method.
pub fn matcher_for(method: Method, gate_chi2: f64) -> Box<dyn Matcher> {
    match method {
        Method::GpsHungarian => Box::new(GpsHungarian { gate_chi2 }),
        Method::Oracle => Box::new(Oracle),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entropy_bounds() {
        assert_eq!(binary_entropy_bits(0.0), 0.0);
        assert_eq!(binary_entropy_bits(1.0), 0.0);
        assert!((binary_entropy_bits(0.5) - 1.0).abs() < 1e-12);
        assert!(binary_entropy_bits(0.9) < binary_entropy_bits(0.7));
    }
}
