//! The matching methods ([`Method`]), what each sees ([`Inputs`]) and
//! needs to run ([`MethodKind`]), and a baseline's threshold that
//! validation chooses ([`BaselineKnob`]).

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
        /// `coid`'s weights with the paper's fixed rule instead of the
        /// choices validation makes: the one-to-one assignment of E[Y]
        /// (Eq. 4), pairs whose total entropy is at least 0.7 removed
        /// (l. 155, 343); no calibration temperature, no operating point.
        #[strum(serialize = "coid-paper-rule")]
        CoidPaperRule,
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
        /// Learning-free spectral matching (Leordeanu & Hebert 2005) on
        /// edge lengths over every pair of same-class candidates, Hungarian,
        /// a threshold.
        #[strum(serialize = "spectral")]
        Spectral,
        /// Learning-free reweighted random walk matching (Cho et al. 2010,
        /// as pygmtools implements it) on the same affinity, Hungarian, a
        /// threshold.
        #[strum(serialize = "rrwm")]
        Rrwm,
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
            Method::Coid
            | Method::CoidT1
            | Method::CoidPaperRule
            | Method::CoidNon
            | Method::CoidUnc
            | Method::Dgmc
            | Method::GcnGm
            | Method::Ours
            | Method::OursT1
            | Method::CoidNonGps
            | Method::CoidUncGps
            | Method::DgmcGps
            | Method::GcnGmGps => MethodKind::Deep,
            Method::Mogm | Method::Rgm | Method::Spectral | Method::Rrwm => {
                MethodKind::LearningFree
            }
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
            | Method::CoidPaperRule
            | Method::CoidNon
            | Method::CoidUnc
            | Method::Dgmc
            | Method::GcnGm
            | Method::Mogm
            | Method::Rgm
            | Method::Spectral
            | Method::Rrwm => Inputs::Paper,
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

    /// Whose weights a deep method runs with: its own, or for a variant
    /// (`coid-t1`, `coid-paper-rule`, `ours-t1`) those of the method it is
    /// a variant of; a single-pass variant takes that method's validated
    /// choices too.
    pub fn weights_owner(self) -> Method {
        match self {
            Method::CoidT1 | Method::CoidPaperRule => Method::Coid,
            Method::OursT1 => Method::Ours,
            m => m,
        }
    }

    /// Whether the method runs another method's weights (it is neither
    /// trained nor validated itself).
    pub fn is_variant(self) -> bool {
        self.weights_owner() != self
    }

    /// Whether the method runs one pass with every dropout off (no MC
    /// dropout).
    pub fn single_pass(self) -> bool {
        matches!(self, Method::CoidT1 | Method::OursT1)
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
    /// A trained network: weights, a lambda and a decision rule; its
    /// network is [`Method::backbone`].
    Deep,
    /// Learning-free graph matching (MOGM, RGM).
    LearningFree,
    /// Gated assignment on the GPS-moved positions (and appearance).
    GpsBased,
    /// The true correspondences: not a [`Matcher`].
    Oracle,
    /// Matches made elsewhere, read from a file: not a [`Matcher`].
    External,
}

/// The one threshold of a baseline that validation chooses, and the grid
/// it is chosen from (the same procedure as the deep methods' lambda: the
/// value with the best mean F1 on the validation runs).
#[derive(Clone, Debug, PartialEq)]
pub struct BaselineKnob {
    /// What the value is, for records and messages.
    pub name: &'static str,
    pub grid: Vec<f64>,
}

/// The powers of the learned descriptors' likelihood ratio that
/// validation tries for the learning-free matchers (0: descriptors
/// unused; 1: the ratio as fitted).
pub const DESCRIPTOR_WEIGHTS: [f64; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

impl Method {
    /// Whether validation chooses the weight of learned descriptors in
    /// this baseline's appearance term (MOGM, RGM, GPS+appearance
    /// Hungarian).
    pub fn weighs_descriptors(self) -> bool {
        matches!(self, Method::Mogm | Method::Rgm | Method::GpsAppHungarian)
    }

    /// The baseline's threshold that validation chooses, if it has one:
    /// MOGM's, spectral matching's and RRWM's minimum share of the largest
    /// score (applied after the solution), RGM's price per match (it shapes the
    /// optimisation), a GPS Hungarian's gate on the squared Mahalanobis
    /// distance (the chi-square 2-dof 10 % to 99.9999 % points: from a
    /// gate tight enough for lidar-quality data whose covariances are
    /// not given, 1 m per axis being assumed, to one that gates nothing).
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
            Method::Spectral => knob(
                "min_score",
                &[0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9],
            ),
            // RRWM's reweighted jumps sharpen its scores towards 0 and 1.
            Method::Rrwm => knob(
                "min_score",
                &[0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 0.97, 0.99],
            ),
            Method::Rgm => knob("price_per_match", &[0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.5, 2.0]),
            Method::GpsHungarian | Method::GpsAppHungarian => knob(
                "gate_chi2",
                &[
                    0.21, 0.71, 1.39, 2.41, 3.22, 4.61, 5.99, 9.21, 13.82, 18.42, 23.03, 27.63,
                ],
            ),
            _ => None,
        }
    }
}
