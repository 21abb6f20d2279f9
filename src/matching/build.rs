//! Building a method's [`Matcher`] from the settings, its weights and its
//! validated choice.

use super::deep::arch::MaskScope;
use super::deep::decision::{Decision, KindLambdas, UncertaintyKind};
use super::{
    BaselineValue, GpsHungarian, Matcher, MatchingSettings, Method, MethodKind, Mogm, Rgm, Rrwm,
    Spectral, deep, drive,
};

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
    /// The operating point: the least E[Y] of a decided pair (0: every
    /// pair the rule chooses).
    pub min_probability: f64,
    /// The calibration temperature of the reported probabilities (1: as
    /// they are).
    pub temperature: f64,
    /// The dropout masks the weights were trained with (their record's).
    pub trained_masks: MaskScope,
}

/// The paper's fixed threshold on the total entropy (l. 343: best at 0.7
/// in its sensitivity analysis).
pub const PAPER_LAMBDA: f64 = 0.7;

impl DeepChoice {
    /// The paper's fixed rule ([`Method::CoidPaperRule`]): the one-to-one
    /// assignment of E[Y] (Eq. 4), pairs with total entropy `>=`
    /// [`PAPER_LAMBDA`] removed, probabilities as they are, every pair the
    /// assignment makes decided; with the masks the weights were trained
    /// with.
    pub fn paper_rule(trained_masks: MaskScope) -> Self {
        Self {
            lambda: PAPER_LAMBDA,
            lambdas: KindLambdas::all(PAPER_LAMBDA),
            decision: Decision::Assignment,
            min_probability: 0.0,
            temperature: 1.0,
            trained_masks,
        }
    }
}

/// Each deep method's threshold of every uncertainty type.
pub type MethodLambdas = std::collections::BTreeMap<Method, KindLambdas>;

/// The thresholds of the deep methods' choices (what the tables and the
/// lambda grid need of them).
pub fn method_lambdas(choices: &std::collections::BTreeMap<Method, DeepChoice>) -> MethodLambdas {
    choices.iter().map(|(&m, c)| (m, c.lambdas)).collect()
}

/// What a deep method runs with: its trained weights (the bytes of
/// `<method>.bpk`) and its choice of lambda, decision rule and
/// temperature.
#[derive(Clone, Copy, Debug)]
pub struct Trained<'a> {
    pub weights: &'a [u8],
    pub choice: DeepChoice,
    /// The width of the appearance vectors the network reads (0: none).
    pub appearance_width: crate::sensor::AppearanceWidth,
    /// A published network's graph and indicator width.
    pub shape: deep::arch::NetworkShape,
}

/// Builds the matcher of a method, in canonical node order and with the
/// configured rounds of match-align-rematch. Deep methods need what they
/// were trained to (`trained`; the other methods read nothing of it); a
/// baseline runs with `tuned` (what validation found for it), else its
/// a-priori threshold. MC-dropout masks are drawn from streams seeded
/// with `dropout_seed`.
pub fn build(
    method: Method,
    settings: &MatchingSettings,
    (trained, tuned): (Option<Trained<'_>>, Option<BaselineValue>),
    dropout_seed: u64,
) -> Result<Box<dyn Matcher>, BuildError> {
    let BaselineValue {
        value,
        descriptor_weight,
    } = settings.baseline(tuned, method);
    let inner: Box<dyn Matcher> = match method.kind() {
        MethodKind::LearningFree if method == Method::Mogm => {
            let mut m = Mogm {
                min_score: value,
                ..Mogm::default()
            };
            m.params.descriptor_weight = descriptor_weight;
            Box::new(m)
        }
        MethodKind::LearningFree if method == Method::Spectral => {
            Box::new(Spectral { min_score: value })
        }
        MethodKind::LearningFree if method == Method::Rrwm => Box::new(Rrwm {
            min_score: value,
            ..Rrwm::default()
        }),
        MethodKind::LearningFree => {
            let mut m = Rgm {
                lambda: value,
                ..Rgm::default()
            };
            m.params.descriptor_weight = descriptor_weight;
            Box::new(m)
        }
        MethodKind::GpsBased => Box::new(GpsHungarian {
            gate_chi2: value,
            appearance: method == Method::GpsAppHungarian,
            descriptor_weight,
        }),
        MethodKind::Oracle => return Err(BuildError::Oracle),
        MethodKind::External => return Err(BuildError::External),
        MethodKind::Deep => {
            let Trained {
                weights: bytes,
                choice,
                appearance_width,
                shape,
            } = trained.ok_or(BuildError::NoWeights(method.as_str()))?;
            // The paper's rule thresholds the total entropy, whatever
            // type the config names.
            let kind = if method == Method::CoidPaperRule {
                UncertaintyKind::Total
            } else {
                settings.uncertainty
            };
            let threshold = method
                .thresholds_by_default()
                .then_some((kind, choice.lambda));
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
                min_probability: choice.min_probability as f32,
                temperature: choice.temperature,
                seed: dropout_seed,
                masks: settings.dropout_masks.resolve(choice.trained_masks),
                dropout,
                gate_chi2: settings.gate_chi2,
                indicators: settings.indicators,
            };
            deep::matcher(method, appearance_width, shape, bytes, run).map_err(|reason| {
                BuildError::BadWeights {
                    method: method.as_str(),
                    reason,
                }
            })?
        }
    };
    Ok(Box::new(drive::Driven::new(inner, settings.rematch)))
}
