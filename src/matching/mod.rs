//! Correspondence identification: which detections of two vehicles are the
//! same object. Every method that works from what the vehicles know
//! implements [`Matcher`]: two [`MatchView`]s in (detections, graph, GPS
//! pose; no ground truth, by type), an [`Identification`] out (one-to-one
//! [`Correspondence`]s with a probability and an uncertainty per pair; pairs
//! not listed are "no match"). The oracle is not a `Matcher`: it reads the
//! ground truth ([`oracle::true_pairs`]) and only the evaluation calls it.

pub mod deep;
mod drive;
mod gps_hungarian;
pub mod learning_free;
pub mod likelihood;
pub mod oracle;
pub mod synchronize;
#[cfg(test)]
pub(crate) mod testkit;

pub use gps_hungarian::GpsHungarian;
pub use learning_free::{Mogm, Rgm};

use std::path::PathBuf;

use self::deep::arch::{DeepMethod, MaskChoice, MaskScope};
use self::deep::decision::{Decision, KindLambdas, MatchDistribution, UncertaintyKind};
use crate::fusion::{PoseClaim, PoseEstimate, relative_pose_prior};
use crate::geometry::Pose2;
use crate::graph::SceneGraph;
use crate::sensor::{Detection, PoseNoiseLevel};

crate::label_enum! { "method";
    /// The matching methods, with the labels used in configs and results.
    /// Rows of every table come in this order: first the methods that see
    /// the paper's inputs only (Table 1), then those that also see the
    /// reported poses (Table 1b), then the oracle. A method named after a
    /// published one implements it as published; a `+gps` suffix names an
    /// extension that adds the reported poses.
    pub enum Method {
        /// The paper's Bayesian deep graph matcher on the paper's inputs:
        /// DGMC's network trained with L_coid + L_non + L_unc, MC-dropout
        /// uncertainty, thresholding.
        #[strum(serialize = "coid")]
        Coid,
        /// `coid`'s weights and choices in one pass with every dropout off
        /// (T = 1; DGMC's random indicators are still drawn): what MC
        /// dropout buys.
        #[strum(serialize = "coid-t1")]
        CoidT1,
        /// Ablation: L_coid + L_non.
        #[strum(serialize = "coid+non")]
        CoidNon,
        /// Ablation: L_coid + L_unc.
        #[strum(serialize = "coid+unc")]
        CoidUnc,
        /// DGMC as published (Fey et al. 2020): SplineCNN, Sinkhorn, L
        /// consensus steps on random indicator functions.
        #[strum(serialize = "dgmc")]
        Dgmc,
        /// GCN-GM as published (Fey et al. 2018): SplineCNN embeddings and
        /// Sinkhorn similarity.
        #[strum(serialize = "gcn-gm")]
        GcnGm,
        /// Learning-free multi-order graph matching (appearance and edge
        /// lengths; spectral solution).
        #[strum(serialize = "mogm")]
        Mogm,
        /// Learning-free regularised graph matching that allows "no match"
        /// (IPFP with a price per match).
        #[strum(serialize = "rgm")]
        Rgm,
        /// Our learned correction of the shared pair likelihood (reported
        /// poses, appearance, graph structure): L_coid + L_non + L_unc,
        /// MC-dropout uncertainty, thresholding.
        #[strum(serialize = "ours")]
        Ours,
        /// `ours`'s weights and choices in one pass with every dropout off
        /// (T = 1).
        #[strum(serialize = "ours-t1")]
        OursT1,
        /// `ours` trained with L_coid + L_non.
        #[strum(serialize = "coid+non+gps")]
        CoidNonGps,
        /// `ours` trained with L_coid + L_unc.
        #[strum(serialize = "coid+unc+gps")]
        CoidUncGps,
        /// `ours` trained with L_coid only: DGMC's consensus on our network
        /// with the poses.
        #[strum(serialize = "dgmc+gps")]
        DgmcGps,
        /// `dgmc+gps` without the consensus.
        #[strum(serialize = "gcn-gm+gps")]
        GcnGmGps,
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
        /// Correspondences made elsewhere, read from a file by `coid score`.
        #[strum(serialize = "external")]
        External,
    }
}

crate::label_enum! { "inputs";
    /// What a method sees besides each vehicle's own detections.
    pub enum Inputs {
        /// The paper's inputs: each vehicle's detections in its own body
        /// frame, their appearance and Delaunay graphs; no GPS pose, no
        /// heading (Table 1).
        #[strum(serialize = "paper")]
        Paper,
        /// The paper's inputs and both vehicles' reported (V2X) poses
        /// (Table 1b).
        #[strum(serialize = "v2x-poses")]
        V2xPoses,
        /// The ground truth (the oracle).
        #[strum(serialize = "truth")]
        Truth,
    }
}

impl Method {
    /// Every method, in table order.
    pub fn all() -> &'static [Method] {
        <Method as strum::VariantArray>::VARIANTS
    }

    /// What kind of method this is.
    pub fn kind(self) -> MethodKind {
        match self {
            Method::Coid | Method::CoidT1 => MethodKind::Deep(DeepMethod::Coid),
            Method::CoidNon => MethodKind::Deep(DeepMethod::CoidNon),
            Method::CoidUnc => MethodKind::Deep(DeepMethod::CoidUnc),
            Method::Dgmc => MethodKind::Deep(DeepMethod::Dgmc),
            Method::GcnGm => MethodKind::Deep(DeepMethod::GcnGm),
            Method::Ours | Method::OursT1 => MethodKind::Deep(DeepMethod::Ours),
            Method::CoidNonGps => MethodKind::Deep(DeepMethod::CoidNonGps),
            Method::CoidUncGps => MethodKind::Deep(DeepMethod::CoidUncGps),
            Method::DgmcGps => MethodKind::Deep(DeepMethod::DgmcGps),
            Method::GcnGmGps => MethodKind::Deep(DeepMethod::GcnGmGps),
            Method::Mogm | Method::Rgm => MethodKind::LearningFree,
            Method::GpsHungarian | Method::GpsAppHungarian => MethodKind::GpsBased,
            Method::Oracle => MethodKind::Oracle,
            Method::External => MethodKind::External,
        }
    }

    /// What the method sees: the paper's inputs (Table 1) or the reported
    /// poses too (Table 1b).
    pub fn inputs(self) -> Inputs {
        match self {
            Method::Coid
            | Method::CoidT1
            | Method::CoidNon
            | Method::CoidUnc
            | Method::Dgmc
            | Method::GcnGm
            | Method::Mogm
            | Method::Rgm => Inputs::Paper,
            Method::Ours
            | Method::OursT1
            | Method::CoidNonGps
            | Method::CoidUncGps
            | Method::DgmcGps
            | Method::GcnGmGps
            | Method::GpsHungarian
            | Method::GpsAppHungarian => Inputs::V2xPoses,
            // What `coid export` hands a matcher written elsewhere: the
            // reported poses included.
            Method::External => Inputs::V2xPoses,
            Method::Oracle => Inputs::Truth,
        }
    }

    /// Whose weights and validated choices a deep method runs with: its
    /// own, or for a single-pass variant (`coid-t1`, `ours-t1`) those of
    /// the method it is one pass of.
    pub fn weights_owner(self) -> Method {
        match self {
            Method::CoidT1 => Method::Coid,
            Method::OursT1 => Method::Ours,
            m => m,
        }
    }

    /// Whether the method runs one pass with every dropout off (no MC
    /// dropout).
    pub fn single_pass(self) -> bool {
        self.weights_owner() != self
    }

    /// The single-pass variant of a method, if it has one.
    pub fn single_pass_variant(self) -> Option<Method> {
        Method::all()
            .iter()
            .copied()
            .find(|m| m.single_pass() && m.weights_owner() == self)
    }
}

/// The kinds of [`Method`]: what a method needs to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MethodKind {
    /// A trained network: weights, a lambda and a decision rule.
    Deep(DeepMethod),
    /// Learning-free graph matching (MOGM, RGM).
    LearningFree,
    /// Gated assignment on the GPS-moved positions (and appearance).
    GpsBased,
    /// The true correspondences: not a [`Matcher`].
    Oracle,
    /// Matches made elsewhere, read from a file: not a [`Matcher`].
    External,
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

/// The one threshold of a baseline that validation chooses, and the grid
/// it is chosen from (the same procedure as the deep methods' lambda: the
/// value with the best mean F1 on the validation runs).
#[derive(Clone, Debug, PartialEq)]
pub struct BaselineKnob {
    /// What the value is, for records and messages.
    pub name: &'static str,
    pub grid: Vec<f64>,
}

impl Method {
    /// The baseline's threshold that validation chooses, if it has one:
    /// MOGM's minimum share of the largest eigenvector entry (applied after
    /// the spectral solution), RGM's price per match (it shapes the
    /// optimisation), a GPS Hungarian's gate on the squared Mahalanobis
    /// distance (the chi-square 2-dof 90 % to 99.9999 % points).
    pub fn baseline_knob(self) -> Option<BaselineKnob> {
        let knob = |name, grid: &[f64]| {
            Some(BaselineKnob {
                name,
                grid: grid.to_vec(),
            })
        };
        match self {
            Method::Mogm => knob(
                "min_score",
                &[0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9],
            ),
            Method::Rgm => knob("price_per_match", &[0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.5, 2.0]),
            Method::GpsHungarian | Method::GpsAppHungarian => {
                knob("gate_chi2", &[4.61, 5.99, 9.21, 13.82, 18.42, 23.03, 27.63])
            }
            _ => None,
        }
    }
}

/// `[matching]`: which methods run and how they decide.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchingSettings {
    pub methods: Vec<Method>,
    /// Where the baselines' thresholds come from.
    pub baselines: BaselineChoice,
    /// The baselines' thresholds to run with (from `baselines.toml`, or a
    /// grid point during validation); a baseline not listed runs at its
    /// a-priori value. Filled when the runners are built, never by the
    /// config.
    pub baseline_values: std::collections::BTreeMap<Method, f64>,
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
}

impl MatchingSettings {
    /// The threshold baseline `method` runs with: its entry of
    /// `baseline_values`, else its a-priori value (MOGM's minimum score
    /// 0.3, RGM's price per match 1.2, a GPS Hungarian's `gate_chi2`).
    /// NaN for a method without one.
    pub fn baseline_value(&self, method: Method) -> f64 {
        let a_priori = match method {
            Method::Mogm => Mogm::default().min_score,
            Method::Rgm => Rgm::default().lambda,
            Method::GpsHungarian | Method::GpsAppHungarian => self.gate_chi2,
            _ => f64::NAN,
        };
        self.baseline_values
            .get(&method)
            .copied()
            .unwrap_or(a_priori)
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

/// Why a method could not be built.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    #[error("the oracle reads ground truth; the evaluation runs it, not a Matcher")]
    Oracle,
    #[error(
        "'external' correspondences come from a file: score them with `coid score --matches FILE`"
    )]
    External,
    #[error("'{0}' needs trained weights")]
    NoWeights(&'static str),
    #[error("'{method}': the weights do not fit its network ({reason})")]
    BadWeights {
        method: &'static str,
        reason: String,
    },
}

/// How a deep method decides: its entropy threshold lambda (when it
/// thresholds; infinite: no threshold) and its decision rule, each chosen
/// on validation runs or fixed by the config.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeepChoice {
    /// The threshold on the configured uncertainty type.
    pub lambda: f64,
    /// The threshold of every uncertainty type (Table 3).
    pub lambdas: KindLambdas,
    pub decision: Decision,
    /// The calibration temperature of the reported probabilities (1: as
    /// they are).
    pub temperature: f64,
    /// The dropout masks the weights were trained with (their record's).
    pub trained_masks: MaskScope,
}

/// Each deep method's threshold of every uncertainty type.
pub type MethodLambdas = std::collections::BTreeMap<Method, KindLambdas>;

/// The thresholds of the deep methods' choices (what the tables and the
/// lambda grid need of them).
pub fn method_lambdas(choices: &std::collections::BTreeMap<Method, DeepChoice>) -> MethodLambdas {
    choices.iter().map(|(&m, c)| (m, c.lambdas)).collect()
}

/// Builds the matcher of a method, in canonical node order and with the
/// configured rounds of match-align-rematch. Deep methods need their
/// trained weights (`weights`, the bytes of `<method>.bpk`) and their
/// `choice`; MC-dropout masks are drawn from streams seeded with
/// `dropout_seed`.
pub fn build(
    method: Method,
    settings: &MatchingSettings,
    choice: DeepChoice,
    dropout_seed: u64,
    weights: Option<&[u8]>,
) -> Result<Box<dyn Matcher>, BuildError> {
    let value = settings.baseline_value(method);
    let inner: Box<dyn Matcher> = match method.kind() {
        MethodKind::LearningFree if method == Method::Mogm => Box::new(Mogm {
            min_score: value,
            ..Mogm::default()
        }),
        MethodKind::LearningFree => Box::new(Rgm {
            lambda: value,
            ..Rgm::default()
        }),
        MethodKind::GpsBased => Box::new(GpsHungarian {
            gate_chi2: value,
            appearance: method == Method::GpsAppHungarian,
        }),
        MethodKind::Oracle => return Err(BuildError::Oracle),
        MethodKind::External => return Err(BuildError::External),
        MethodKind::Deep(deep_method) => {
            let bytes = weights.ok_or(BuildError::NoWeights(method.as_str()))?;
            let threshold = deep_method
                .thresholds_by_default()
                .then_some((settings.uncertainty, choice.lambda));
            // A single-pass variant: one sample with every dropout off.
            let (samples, dropout) = if method.single_pass() {
                (1, Some(0.0))
            } else {
                (settings.mc_samples, settings.mc_dropout)
            };
            let run = deep::Inference {
                samples,
                threshold,
                decision: choice.decision,
                temperature: choice.temperature,
                seed: dropout_seed,
                masks: settings.dropout_masks.resolve(choice.trained_masks),
                dropout,
                gate_chi2: settings.gate_chi2,
            };
            deep::matcher(method, deep_method, bytes, run).map_err(|reason| {
                BuildError::BadWeights {
                    method: method.as_str(),
                    reason,
                }
            })?
        }
    };
    Ok(Box::new(drive::Driven::new(inner, settings.rematch)))
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
            baselines: BaselineChoice::APriori,
            baseline_values: Default::default(),
            gate_chi2: 9.21,
            models_dir: PathBuf::new(),
            mc_samples: 20,
            dropout_masks: MaskChoice::AsTrained,
            mc_dropout: None,
            lambda: LambdaChoice::Fixed(0.7),
            decision: DecisionChoice::Fixed(Decision::Assignment),
            uncertainty: UncertaintyKind::Total,
            sender_as_node: true,
            multi_vehicle: MultiVehicle::Pairwise,
            rematch: 0,
        }
    }

    const CHOICE: DeepChoice = DeepChoice {
        lambda: 0.7,
        lambdas: KindLambdas::all(0.7),
        decision: Decision::Assignment,
        temperature: 1.0,
        trained_masks: MaskScope::PerNode,
    };

    fn plain(method: Method) -> Box<dyn Matcher> {
        build(method, &settings(), CHOICE, 1, None).unwrap()
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

    /// A vehicle's detections in another order: `order[k]` is the old
    /// index of new detection k.
    fn permuted(side: &Side, order: &[usize]) -> Side {
        Side {
            detections: order.iter().map(|&k| side.detections[k].clone()).collect(),
            objects: order.iter().map(|&k| side.objects[k]).collect(),
            graph: side.graph.permuted(order),
            pose: side.pose,
            level: side.level,
        }
    }

    /// Permuting one vehicle's detections permutes every method's matches
    /// (and a deep method's distribution) and changes nothing else, bit for
    /// bit: with one pass and with match-align-rematch, on a scene with GPS
    /// error, look-alikes and objects only one vehicle sees.
    #[test]
    fn permuting_detections_permutes_every_methods_matches_and_nothing_else() {
        let mut world = testkit::world_objects();
        world.extend(
            testkit::world_objects()
                .iter()
                .map(|&(p, c, col)| (p + Vec2::new(30.0, -25.0), c, col)),
        );
        let all: Vec<usize> = (0..world.len()).collect();
        let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
        let mut b = Side::of(
            testkit::POSE_B,
            &world,
            &[3, 9, 12, 0, 5, 14, 2, 10, 7],
            testkit::GPS,
        );
        b.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(1.5, -1.0), -2.395);
        let order_a: Vec<usize> = (0..a.detections.len()).rev().collect();
        let order_b = [4, 0, 8, 2, 6, 1, 7, 3, 5];
        for rematch in [0, 2] {
            let s = MatchingSettings {
                rematch,
                ..settings()
            };
            for &method in Method::all() {
                if matches!(method, Method::Oracle | Method::External) {
                    continue;
                }
                let weights = match method.kind() {
                    MethodKind::Deep(d) => Some(deep::opened_weights(d, 3)),
                    _ => None,
                };
                let all_pairs = DeepChoice {
                    lambda: f64::INFINITY,
                    lambdas: KindLambdas::all(f64::INFINITY),
                    ..CHOICE
                };
                let m = build(method, &s, all_pairs, 1, weights.as_deref()).unwrap();
                let before = m.identify(&a.view(), &b.view());
                let (pa, pb) = (permuted(&a, &order_a), permuted(&b, &order_b));
                let after = m.identify(&pa.view(), &pb.view());
                // Map the permuted answer back to the original indices.
                let mut back: Vec<Correspondence> = after
                    .matches
                    .iter()
                    .map(|c| Correspondence {
                        a: order_a[c.a],
                        b: order_b[c.b],
                        ..*c
                    })
                    .collect();
                back.sort_by_key(|c| c.a);
                assert_eq!(back, before.matches, "{method:?}, rematch {rematch}");
                // An untrained published network sends every node to its
                // dustbin; its distribution is compared below.
                let published = matches!(
                    method.kind(),
                    MethodKind::Deep(d) if d.architecture().is_none()
                );
                assert!(
                    !before.matches.is_empty() || method == Method::Rgm || published,
                    "{method:?}"
                );
                if let (Some(d0), Some(d1)) = (&before.distribution, &after.distribution) {
                    let (ra, rb) = (inverse(&order_a), inverse(&order_b));
                    assert_eq!(&d1.relabelled(&ra, &rb), d0, "{method:?}");
                }
            }
        }
    }

    fn inverse(p: &[usize]) -> Vec<usize> {
        let mut q = vec![0; p.len()];
        for (k, &i) in p.iter().enumerate() {
            q[i] = k;
        }
        q
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
            build(Method::Oracle, &settings(), CHOICE, 1, None),
            Err(BuildError::Oracle)
        ));
        let e = build(Method::Ours, &settings(), CHOICE, 1, None)
            .err()
            .unwrap();
        assert_eq!(e.to_string(), "'ours' needs trained weights");
        let e = build(
            Method::Ours,
            &settings(),
            CHOICE,
            1,
            Some(b"not a burnpack"),
        )
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
                "coid",
                "coid-t1",
                "coid+non",
                "coid+unc",
                "dgmc",
                "gcn-gm",
                "mogm",
                "rgm",
                "ours",
                "ours-t1",
                "coid+non+gps",
                "coid+unc+gps",
                "dgmc+gps",
                "gcn-gm+gps",
                "gps-hungarian",
                "gps-app-hungarian",
                "oracle",
                "external"
            ]
        );
    }

    /// A single-pass variant is its owner's weights run once with every
    /// dropout off (T = 1; the consensus's random indicators are still
    /// drawn): exactly the owner with one sample at rate 0, under its own
    /// label, with no epistemic uncertainty (its one sample's entropy is
    /// the mean's), where the owner's MC dropout has some.
    #[test]
    fn single_pass_variants_are_one_pass_without_epistemic_uncertainty() {
        let world = testkit::world_objects();
        let all: Vec<usize> = (0..world.len()).collect();
        let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
        let b = Side::of(testkit::POSE_B, &world, &[3, 0, 5, 2, 7, 6], testkit::GPS);
        let one_pass = MatchingSettings {
            mc_samples: 1,
            mc_dropout: Some(0.0),
            ..settings()
        };
        for (one, owner) in [
            (Method::CoidT1, Method::Coid),
            (Method::OursT1, Method::Ours),
        ] {
            let MethodKind::Deep(d) = owner.kind() else {
                unreachable!()
            };
            let weights = deep::opened_weights(d, 3);
            let dist = |m: Method, s: &MatchingSettings| {
                let matcher = build(m, s, CHOICE, 1, Some(&weights)).unwrap();
                assert_eq!(matcher.method(), m);
                matcher
                    .identify(&a.view(), &b.view())
                    .distribution
                    .expect("a deep method's distribution")
            };
            let single = dist(one, &settings());
            assert_eq!(single, dist(owner, &one_pass), "{one:?}");
            let epistemic = |d: &MatchDistribution| {
                let pairs = (0..d.n1).flat_map(|i| (0..d.n2).map(move |j| (i, j)));
                pairs
                    .map(|(i, j)| d.uncertainty(i, j, UncertaintyKind::Epistemic))
                    .fold(0.0, f64::max)
            };
            assert!(epistemic(&single) < 1e-5, "{one:?}");
            assert!(epistemic(&dist(owner, &settings())) > 1e-3, "{owner:?}");
        }
    }

    /// The methods of Table 1 see the paper's inputs only: another
    /// reported pose and another claimed accuracy for either vehicle (the
    /// detections, in each body frame, unchanged) change nothing they say,
    /// bit for bit; a method with the poses does change.
    #[test]
    fn the_methods_on_the_papers_inputs_never_read_a_pose() {
        let world = testkit::world_objects();
        let all: Vec<usize> = (0..world.len()).collect();
        let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
        let b = Side::of(testkit::POSE_B, &world, &[3, 0, 5, 2, 7, 6], testkit::GPS);
        let (mut a2, mut b2) = (a.clone(), b.clone());
        a2.pose = crate::geometry::Pose2::new(a.pose.position_m() + Vec2::new(30.0, -8.0), 1.1);
        b2.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(-2.0, 4.0), 0.3);
        (a2.level, b2.level) = (testkit::EXACT, testkit::EXACT);
        let s = MatchingSettings {
            rematch: 2,
            ..settings()
        };
        let all_pairs = DeepChoice {
            lambda: f64::INFINITY,
            lambdas: KindLambdas::all(f64::INFINITY),
            ..CHOICE
        };
        let paper: Vec<Method> = Method::all()
            .iter()
            .copied()
            .filter(|m| m.inputs() == Inputs::Paper)
            .collect();
        assert_eq!(paper.len(), 8);
        for method in paper.into_iter().chain([Method::GpsAppHungarian]) {
            let weights = match method.kind() {
                MethodKind::Deep(d) => Some(deep::opened_weights(d, 3)),
                _ => None,
            };
            let m = build(method, &s, all_pairs, 1, weights.as_deref()).unwrap();
            let before = m.identify(&a.view(), &b.view());
            let moved = m.identify(&a2.view(), &b2.view());
            if method.inputs() == Inputs::Paper {
                assert_eq!(before, moved, "{method:?}");
            } else {
                assert_ne!(before, moved, "{method:?}");
            }
        }
    }

    /// A config naming a method that was renamed is refused in one line
    /// that names its replacement.
    #[test]
    fn a_renamed_method_is_refused_with_its_new_name() {
        let e = crate::label::parse::<Method>("method", "ours-noprior").unwrap_err();
        assert!(e.contains("renamed") && e.contains("'coid'"), "{e}");
        assert!(!e.contains('\n'));
        assert_eq!(
            crate::label::parse::<Method>("method", "dgmc+gps"),
            Ok(Method::DgmcGps)
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
