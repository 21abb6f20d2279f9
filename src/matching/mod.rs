//! Correspondence identification: which detections of two vehicles are the
//! same object. Every method that works from what the vehicles know
//! implements [`Matcher`]: two [`MatchView`]s in (detections, graph, GPS
//! pose; no ground truth, by type), an [`Identification`] out (one-to-one
//! [`Correspondence`]s with a probability and an uncertainty per pair; pairs
//! not listed are "no match"). The oracle is not a `Matcher`: it reads the
//! ground truth ([`oracle::true_pairs`]) and only the evaluation calls it.

pub mod deep;
mod gps_hungarian;
pub mod learning_free;
pub mod oracle;
pub mod synchronize;
#[cfg(test)]
pub(crate) mod testkit;

pub use gps_hungarian::GpsHungarian;
pub use learning_free::{Mogm, Rgm};

use std::path::PathBuf;

use self::deep::decision::{MatchDistribution, UncertaintyKind};
use crate::geometry::Pose2;
use crate::graph::SceneGraph;
use crate::sensor::{Detection, PoseNoiseLevel};

crate::label_enum! { "method";
    /// The matching methods, with the labels used in configs and results.
    /// Rows of every table come in this order.
    pub enum Method {
        /// The paper's Bayesian deep graph matcher: L_coid + L_non + L_unc,
        /// MC-dropout uncertainty, thresholding.
        #[strum(serialize = "ours")]
        Ours,
        /// The paper's network as published: `ours` without the GPS
        /// position term (appearance and graph structure only).
        #[strum(serialize = "ours-noprior")]
        OursNoPrior,
        /// Ablation: L_coid + L_non.
        #[strum(serialize = "coid+non")]
        CoidNon,
        /// Ablation: L_coid + L_unc.
        #[strum(serialize = "coid+unc")]
        CoidUnc,
        /// DGMC: GNN + neighbourhood consensus, L_coid only.
        #[strum(serialize = "dgmc")]
        Dgmc,
        /// GCN-GM: GNN similarity + Sinkhorn, L_coid only.
        #[strum(serialize = "gcn-gm")]
        GcnGm,
        /// Learning-free multi-order graph matching (appearance, edge lengths,
        /// edge directions; spectral solution).
        #[strum(serialize = "mogm")]
        Mogm,
        /// Learning-free regularised graph matching that allows "no match"
        /// (IPFP with a price per match).
        #[strum(serialize = "rgm")]
        Rgm,
        /// Detections moved into the ego frame with the GPS poses, gated
        /// Hungarian assignment on Mahalanobis distance.
        #[strum(serialize = "gps-hungarian")]
        GpsHungarian,
        /// GPS-Hungarian with appearance (class, colour, size) in the same
        /// cost, gated: the baseline a practitioner writes first.
        #[strum(serialize = "gps-app-hungarian")]
        GpsAppHungarian,
        /// The true correspondences: an upper bound for fusion.
        #[strum(serialize = "oracle")]
        Oracle,
    }
}

impl Method {
    /// Every method, in table order.
    pub fn all() -> &'static [Method] {
        <Method as strum::VariantArray>::VARIANTS
    }
}

crate::label_enum! { "multi-vehicle mode";
    /// How the pairwise matches of a frame with three or more connected
    /// vehicles are combined.
    #[strum(serialize_all = "lowercase")]
    pub enum MultiVehicle {
        /// Each pair on its own, as the method decided (may contradict
        /// itself across three vehicles).
        Pairwise,
        /// One consistent assignment of detections to objects per frame
        /// ([`synchronize::synchronize`]); two detections match exactly when
        /// they share an object.
        Synchronized,
    }
}

/// `[matching]`: which methods run and how they decide.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchingSettings {
    pub methods: Vec<Method>,
    /// GPS-Hungarian gate on the squared Mahalanobis distance (9.21 is the
    /// 99% point of chi-square with 2 degrees of freedom).
    pub gate_chi2: f64,
    /// Folder of the deep methods' trained weights (`<method>.bpk`).
    pub models_dir: PathBuf,
    /// MC-dropout samples at inference (paper: T = 20).
    pub mc_samples: usize,
    /// Pairs whose uncertainty (binary entropy in bits, in [0, 1]) is at
    /// least lambda are removed by the methods that threshold.
    pub lambda: LambdaChoice,
    pub uncertainty: UncertaintyKind,
    /// Each sender is a node of its own graph (its V2X self-report).
    pub sender_as_node: bool,
    /// Pairwise matches as decided, or synchronised per frame.
    pub multi_vehicle: MultiVehicle,
}

/// Where the entropy threshold lambda comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LambdaChoice {
    /// Each method's own, chosen on validation seeds by `coid train` and
    /// recorded beside its weights.
    Validated,
    /// This value for every method (the paper: 0.7).
    Fixed(f64),
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

/// What a method says about one pair of vehicles.
#[derive(Clone, Debug, PartialEq)]
pub struct Identification {
    /// One-to-one pairs (each `a` and each `b` at most once), sorted by `a`.
    pub matches: Vec<Correspondence>,
    /// Deep methods: the mean assignment and uncertainties behind the
    /// decision, so that other thresholds can be applied without matching
    /// again.
    pub distribution: Option<MatchDistribution>,
}

impl Identification {
    /// Correspondences without a distribution behind them.
    pub fn plain(matches: Vec<Correspondence>) -> Self {
        Self {
            matches,
            distribution: None,
        }
    }
}

/// A one-to-one correspondence method between two vehicles' detections.
pub trait Matcher: Send + Sync {
    fn method(&self) -> Method;
    fn identify(&self, first: &MatchView, second: &MatchView) -> Identification;
}

/// Binary entropy in bits, 0 at p in {0, 1} and 1 at p = 0.5.
pub fn binary_entropy_bits(p: f64) -> f64 {
    let p = p.clamp(0.0, 1.0);
    let h = |q: f64| if q <= 0.0 { 0.0 } else { -q * q.log2() };
    h(p) + h(1.0 - p)
}

/// Why a method could not be built.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    #[error("the oracle reads ground truth; the evaluation runs it, not a Matcher")]
    Oracle,
    #[error("'{0}' needs trained weights")]
    NoWeights(&'static str),
    #[error("'{method}': the weights do not fit its network ({reason})")]
    BadWeights {
        method: &'static str,
        reason: String,
    },
}

/// Builds the matcher of a method. Deep methods need their trained
/// weights (`weights`, the bytes of `<method>.bpk`) and, when they
/// threshold, their `lambda`; MC-dropout masks are drawn from streams
/// seeded with `dropout_seed`.
pub fn build(
    method: Method,
    settings: &MatchingSettings,
    lambda: f64,
    dropout_seed: u64,
    weights: Option<&[u8]>,
) -> Result<Box<dyn Matcher>, BuildError> {
    Ok(match method {
        Method::Mogm => Box::new(Mogm::default()),
        Method::Rgm => Box::new(Rgm::default()),
        Method::GpsHungarian | Method::GpsAppHungarian => Box::new(GpsHungarian {
            gate_chi2: settings.gate_chi2,
            appearance: method == Method::GpsAppHungarian,
        }),
        Method::Oracle => return Err(BuildError::Oracle),
        deep_method => {
            let bytes = weights.ok_or(BuildError::NoWeights(deep_method.as_str()))?;
            let threshold =
                deep::thresholds_by_default(deep_method).then_some((settings.uncertainty, lambda));
            let matcher = deep::DeepMatcher::from_weights(
                deep_method,
                bytes,
                settings.mc_samples,
                threshold,
                dropout_seed,
            )
            .map_err(|reason| BuildError::BadWeights {
                method: deep_method.as_str(),
                reason,
            })?;
            Box::new(matcher)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::testkit::{self, Side};
    use super::*;
    use crate::geometry::Vec2;
    use crate::traffic::ObjectClass;

    fn settings() -> MatchingSettings {
        MatchingSettings {
            methods: vec![],
            gate_chi2: 9.21,
            models_dir: PathBuf::new(),
            mc_samples: 20,
            lambda: LambdaChoice::Fixed(0.7),
            uncertainty: UncertaintyKind::Total,
            sender_as_node: true,
            multi_vehicle: MultiVehicle::Pairwise,
        }
    }

    fn plain(method: Method) -> Box<dyn Matcher> {
        build(method, &settings(), 0.7, 1, None).unwrap()
    }

    #[test]
    fn every_learning_free_matcher_matches_a_moved_copy_of_a_scene_to_itself() {
        for method in [
            Method::Mogm,
            Method::Rgm,
            Method::GpsHungarian,
            Method::GpsAppHungarian,
        ] {
            assert_eq!(
                testkit::self_match(plain(method).as_ref()),
                (1.0, 0),
                "{method:?}"
            );
        }
    }

    #[test]
    fn graph_matchers_find_nothing_in_unrelated_scenes() {
        // The second vehicle sees other objects of other classes elsewhere.
        let objects = testkit::world_objects();
        let others: Vec<(Vec2, ObjectClass, [f64; 3])> = objects
            .iter()
            .map(|&(p, c, col)| {
                let class = if c == ObjectClass::Pedestrian {
                    ObjectClass::Bus
                } else {
                    ObjectClass::Pedestrian
                };
                (Vec2::new(p.y * 1.7, -p.x * 0.6), class, col)
            })
            .collect();
        let idx: Vec<usize> = (0..objects.len()).collect();
        let a = Side::of(testkit::POSE_A, &objects, &idx, testkit::EXACT);
        let b = Side::of(testkit::POSE_B, &others, &idx, testkit::EXACT);
        // RGM prices every match, so unsupported pairs stay unmatched.
        let rgm = plain(Method::Rgm).identify(&a.view(), &b.view());
        assert!(rgm.matches.is_empty());
        // Spectral matching (MOGM) has no absolute "no match": it keeps the
        // strongest compatible candidates (here: the first vehicle's
        // pedestrian and bicycle, both compatible with the second's
        // pedestrians), a known weakness of the method.
        let mogm = plain(Method::Mogm).identify(&a.view(), &b.view());
        assert!(mogm.matches.len() <= 2);
    }

    #[test]
    fn the_oracle_is_not_a_matcher_and_deep_methods_need_weights() {
        assert!(matches!(
            build(Method::Oracle, &settings(), 0.7, 1, None),
            Err(BuildError::Oracle)
        ));
        let e = build(Method::Ours, &settings(), 0.7, 1, None)
            .err()
            .unwrap();
        assert_eq!(e.to_string(), "'ours' needs trained weights");
        let e = build(Method::Ours, &settings(), 0.7, 1, Some(b"not a burnpack"))
            .err()
            .unwrap();
        assert!(
            e.to_string().starts_with("'ours': the weights do not fit"),
            "{e}"
        );
    }

    #[test]
    fn method_labels_are_the_published_ones_in_table_order() {
        let labels: Vec<&str> = Method::all().iter().map(|m| m.as_str()).collect();
        assert_eq!(
            labels,
            [
                "ours",
                "ours-noprior",
                "coid+non",
                "coid+unc",
                "dgmc",
                "gcn-gm",
                "mogm",
                "rgm",
                "gps-hungarian",
                "gps-app-hungarian",
                "oracle"
            ]
        );
    }

    #[test]
    fn entropy_bounds() {
        assert_eq!(binary_entropy_bits(0.0), 0.0);
        assert_eq!(binary_entropy_bits(1.0), 0.0);
        assert!((binary_entropy_bits(0.5) - 1.0).abs() < 1e-12);
        assert!(binary_entropy_bits(0.9) < binary_entropy_bits(0.7));
    }
}
