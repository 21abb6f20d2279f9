//! Correspondence identification: which detections of two vehicles are the
//! same object. Every method that works from what the vehicles know
//! implements [`Matcher`]: two [`MatchView`]s in (detections, graph, GPS
//! pose; no ground truth, by type), an [`Identification`] out (one-to-one
//! [`Correspondence`]s with a probability and an uncertainty per pair; pairs
//! not listed are "no match"). The oracle is not a `Matcher`: it reads the
//! ground truth ([`oracle::true_pairs`]) and only the evaluation calls it.

pub mod deep;
pub mod descriptor;
mod drive;
mod gps_hungarian;
pub mod learning_free;
pub mod likelihood;
pub mod oracle;
pub mod spectral;
pub mod synchronize;
#[cfg(test)]
pub(crate) mod testkit;
#[cfg(test)]
mod tests;

mod build;
mod method;

pub use build::{
    BuildError, DeepChoice, MethodLambdas, PAPER_LAMBDA, Trained, build, method_lambdas,
};
pub use gps_hungarian::GpsHungarian;
pub use learning_free::{Mogm, Rgm};
pub use method::{BaselineKnob, DESCRIPTOR_WEIGHTS, Inputs, Method, MethodKind};
pub use spectral::{Rrwm, Spectral};

use std::path::PathBuf;

use self::deep::arch::MaskChoice;
use self::deep::decision::{Decision, MatchDistribution, UncertaintyKind};
use crate::fusion::{PoseClaim, PoseEstimate, relative_pose_prior};
use crate::geometry::Pose2;
use crate::graph::SceneGraph;
use crate::sensor::{Detection, PoseNoiseLevel};

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
        /// Each vehicle in turn (by id) matched once against the step's
        /// object map, built from the vehicles already matched that it
        /// exchanges with: cost linear in the vehicles, consistent by
        /// construction (`evaluate::map`).
        Map,
    }
}

crate::label_enum! { "baseline thresholds";
    /// Where the baselines' thresholds come from.
    pub enum BaselineChoice {
        /// Each baseline's own, chosen on the validation runs by `coid
        /// train` (as the deep methods' lambdas) and recorded in the models
        /// folder's `baselines.toml`.
        #[strum(serialize = "validated")]
        Validated,
        /// The values fixed before any data was seen: MOGM's minimum score
        /// 0.3, RGM's price per match 1.2, the GPS Hungarians' gate
        /// `[matching] gate_chi2`.
        #[strum(serialize = "a-priori")]
        APriori,
    }
}

/// The file of a models folder that records the baselines' validated
/// thresholds.
pub const BASELINES_FILE: &str = "baselines.toml";

/// `[matching]`: which methods run and how they decide.
#[derive(Clone, PartialEq)]
pub struct MatchingSettings {
    pub methods: Vec<Method>,
    /// Where the baselines' thresholds come from (their values travel
    /// beside the settings: [`crate::pipeline::Found`]).
    pub baselines: BaselineChoice,
    /// GPS-Hungarian gate on the squared Mahalanobis distance (9.21 is the
    /// 99% point of chi-square with 2 degrees of freedom).
    pub gate_chi2: f64,
    /// Folder of the deep methods' trained weights (`<method>.bpk`).
    pub models_dir: PathBuf,
    /// MC-dropout samples at inference (paper: T = 20).
    pub mc_samples: usize,
    /// How the MC-dropout masks are drawn at inference: as the weights
    /// were trained, or Eq. 8's shared masks, or per node.
    pub dropout_masks: MaskChoice,
    /// Every dropout rate at inference (`None`: as trained); Fig. 8b
    /// sweeps it.
    pub mc_dropout: Option<f64>,
    /// Pairs whose uncertainty (binary entropy in bits, in [0, 1]) is at
    /// least lambda are removed by the methods that threshold.
    pub lambda: LambdaChoice,
    /// How the deep methods choose their pairs from the MC samples.
    pub decision: DecisionChoice,
    pub uncertainty: UncertaintyKind,
    /// Each sender is a node of its own graph (its V2X self-report).
    pub sender_as_node: bool,
    /// Pairwise matches as decided, or synchronised per frame.
    pub multi_vehicle: MultiVehicle,
    /// Rounds of match-align-rematch for the methods that use positions:
    /// the relative pose re-estimated from the matches ([`crate::fusion::align`])
    /// and the pair matched again with it (0 = one pass with the GPS pose).
    pub rematch: usize,
    /// DGMC's random node indicators across a pair's MC samples.
    pub indicators: crate::matching::deep::arch::IndicatorScope,
}

/// As derived, but `indicators` is shown only when it is not "per-sample":
/// a config's digest hashes this text, and configs from before it keep
/// their digest (and their batches). For the same reason the text still
/// shows the empty `baseline_values` the settings once carried (the
/// values validation finds are no setting).
impl std::fmt::Debug for MatchingSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("MatchingSettings");
        d.field("methods", &self.methods)
            .field("baselines", &self.baselines)
            .field("baseline_values", &BaselineValues::new())
            .field("gate_chi2", &self.gate_chi2)
            .field("models_dir", &self.models_dir)
            .field("mc_samples", &self.mc_samples)
            .field("dropout_masks", &self.dropout_masks)
            .field("mc_dropout", &self.mc_dropout)
            .field("lambda", &self.lambda)
            .field("decision", &self.decision)
            .field("uncertainty", &self.uncertainty)
            .field("sender_as_node", &self.sender_as_node)
            .field("multi_vehicle", &self.multi_vehicle)
            .field("rematch", &self.rematch);
        if self.indicators != crate::matching::deep::arch::IndicatorScope::PerSample {
            d.field("indicators", &self.indicators);
        }
        d.finish()
    }
}

impl MatchingSettings {
    /// The threshold baseline `method` runs with when validation found
    /// none: MOGM's minimum score 0.3, RGM's price per match 1.2, a GPS
    /// Hungarian's `gate_chi2`. NaN for a method without one.
    pub fn a_priori_value(&self, method: Method) -> f64 {
        match method {
            Method::Mogm => Mogm::default().min_score,
            Method::Rgm => Rgm::default().lambda,
            Method::Spectral => Spectral::default().min_score,
            Method::Rrwm => Rrwm::default().min_score,
            Method::GpsHungarian | Method::GpsAppHungarian => self.gate_chi2,
            _ => f64::NAN,
        }
    }

    /// What baseline `method` runs with: `found` (validated, or a grid
    /// point while validating), else its a-priori threshold with the
    /// descriptors' ratio as fitted.
    pub fn baseline(&self, found: Option<BaselineValue>, method: Method) -> BaselineValue {
        found.unwrap_or_else(|| BaselineValue::at(self.a_priori_value(method)))
    }
}

/// The baselines' thresholds a run uses, found on the validation runs
/// (`baselines.toml`) or a grid point while they are found; a baseline not
/// listed runs at its a-priori value.
pub type BaselineValues = std::collections::BTreeMap<Method, BaselineValue>;

/// What a baseline runs with beside its method: its threshold
/// ([`Method::baseline_knob`]) and, for the learning-free matchers on
/// data with learned descriptors, the power of their likelihood ratio
/// (1 elsewhere).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaselineValue {
    pub value: f64,
    pub descriptor_weight: f64,
}

impl BaselineValue {
    /// `value` with the descriptors' ratio as fitted.
    pub fn at(value: f64) -> Self {
        Self {
            value,
            descriptor_weight: 1.0,
        }
    }
}

/// Where the entropy threshold lambda comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LambdaChoice {
    /// Each method's own, chosen on validation seeds by `coid train` and
    /// recorded beside its weights.
    Validated,
    /// This value for every method (the paper: 0.7; infinite: no
    /// threshold).
    Fixed(f64),
}

/// Where a deep method's decision rule comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DecisionChoice {
    /// Each method's own, chosen on validation seeds by `coid train` and
    /// recorded beside its weights.
    Validated,
    /// This rule for every deep method.
    Fixed(Decision),
}

/// One vehicle's side of a matching problem: what that vehicle knows.
#[derive(Clone, Copy, Debug)]
pub struct MatchView<'a> {
    /// Detections in the vehicle's body frame.
    pub detections: &'a [Detection],
    pub graph: &'a SceneGraph,
    /// The vehicle's pose as its GPS reports it, world frame.
    pub pose_reported: Pose2,
    /// The accuracy the GPS claims for that pose: the noise level's
    /// sigmas, the heading's at the vehicle's speed
    /// (`[v2x] gnss_heading_speed_sigma_mps`), as its error is drawn.
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

impl Correspondence {
    /// The pair (a, b) at `probability`, its uncertainty the binary
    /// entropy of it.
    pub fn with_probability(a: usize, b: usize, probability: f64) -> Self {
        Self {
            a,
            b,
            probability,
            uncertainty: binary_entropy_bits(probability),
        }
    }
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
    pub fn matches_only(matches: Vec<Correspondence>) -> Self {
        Self {
            matches,
            distribution: None,
        }
    }
}

/// A one-to-one correspondence method between two vehicles' detections.
pub trait Matcher: Send + Sync {
    fn method(&self) -> Method;

    /// The correspondences between `first`'s and `second`'s detections,
    /// given `relative`: the second vehicle's pose in the first one's body
    /// frame with its uncertainty, as far as it is known (from both GPS
    /// poses, [`gps_relative_pose`], or refined by aligning a first
    /// matching). Methods that match on appearance and structure alone
    /// ignore it.
    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        relative: &PoseEstimate,
    ) -> Identification;

    /// Whether `relative` enters [`Self::identify_with`], so that
    /// match-align-rematch can change the result.
    fn uses_positions(&self) -> bool {
        false
    }

    /// Multiply-adds this matcher's networks have done so far, counted
    /// from their products' shapes ([`deep::cost`]); 0 for a matcher
    /// without a network. A run holds its time against them.
    fn network_macs(&self) -> u64 {
        0
    }

    /// The correspondences with the relative pose both GPS receivers
    /// report.
    fn identify(&self, first: &MatchView, second: &MatchView) -> Identification {
        self.identify_with(first, second, &gps_relative_pose(first, second))
    }
}

/// The second vehicle's pose in the first vehicle's body frame from both
/// reported GPS poses, with the uncertainty their claimed accuracy gives
/// (both position errors, and the heading errors times the lever arm;
/// [`relative_pose_prior`]).
pub fn gps_relative_pose(first: &MatchView, second: &MatchView) -> PoseEstimate {
    relative_pose_prior(
        &first.pose_reported,
        &second.pose_reported,
        claim(&first.pose_noise),
        claim(&second.pose_noise),
    )
}

/// What a receiver at `level` claims of its pose.
pub fn claim(level: &PoseNoiseLevel) -> PoseClaim {
    PoseClaim {
        position_sigma_m: level.position_sigma_m,
        heading_sigma_rad: level.heading_sigma_rad,
    }
}

/// Binary entropy in bits, 0 at p in {0, 1} and 1 at p = 0.5.
pub fn binary_entropy_bits(p: f64) -> f64 {
    let p = p.clamp(0.0, 1.0);
    let h = |q: f64| if q <= 0.0 { 0.0 } else { -q * q.log2() };
    h(p) + h(1.0 - p)
}
