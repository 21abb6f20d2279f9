//! Each method's runner: the matcher built with its settings and what
//! validation found for it ([`Found`]: a deep method's choice of lambda,
//! decision rule, operating point and temperature, a baseline's
//! threshold), as given or as the models folder records it (read through
//! `io`). The settings are the config's, never written into.

use std::collections::BTreeMap;

use super::RunError;
use crate::config::Settings;
use crate::evaluate::CorrespondenceSource;
use crate::io::{self, WeightsError};
use crate::matching::deep::arch::MaskScope;
use crate::matching::deep::decision::{Decision, KindLambdas};
use crate::matching::{
    self, BaselineChoice, BaselineValues, BuildError, DecisionChoice, DeepChoice, LambdaChoice,
    Method, MethodKind, Trained,
};

/// What the methods of a run take beside its settings: what validation
/// found for them, given in memory. A method not listed runs as its
/// settings say: a deep method with its configured lambda and rule or the
/// models folder's validated ones ([`choice_for`]), a baseline at its
/// a-priori threshold or at the models folder's (`[matching] baselines`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Found {
    /// Each deep method's lambda, decision rule, operating point and
    /// temperature.
    pub deep: BTreeMap<Method, DeepChoice>,
    /// Each baseline's threshold (and descriptor weight).
    pub baselines: BaselineValues,
}

impl Found {
    /// Every deep method among `methods` deciding by assignment with no
    /// threshold, which counts every pair at every rule and lambda (what
    /// validation chooses among); the temperature and the masks trained
    /// with as the models folder records them.
    pub fn counting_every_rule(settings: &Settings, methods: &[Method]) -> Result<Self, RunError> {
        let every = (
            LambdaChoice::Fixed(f64::INFINITY),
            DecisionChoice::Fixed(Decision::Assignment),
        );
        let deep = methods
            .iter()
            .filter(|m| matches!(m.kind(), MethodKind::Deep))
            .map(|&m| Ok((m, choice_as(settings, m, every)?)))
            .collect::<Result<_, RunError>>()?;
        Ok(Self {
            deep,
            baselines: BaselineValues::new(),
        })
    }

    /// The baselines at `values`, the deep methods as their settings say.
    pub fn baselines_at(values: BaselineValues) -> Self {
        Self {
            deep: BTreeMap::new(),
            baselines: values,
        }
    }
}

/// How a deep method decides: its entropy threshold and decision rule as
/// configured, or as `coid train` chose them on the validation runs, and
/// the calibration temperature fitted there (recorded beside the weights;
/// 1 when the models folder records none).
pub fn choice_for(settings: &Settings, method: Method) -> Result<DeepChoice, RunError> {
    let m = &settings.matching;
    choice_as(settings, method, (m.lambda, m.decision))
}

/// [`choice_for`] with `lambda` and `decision` in place of the config's.
fn choice_as(
    settings: &Settings,
    method: Method,
    (lambda, decision): (LambdaChoice, DecisionChoice),
) -> Result<DeepChoice, RunError> {
    let m = &settings.matching;
    if method == Method::CoidPaperRule {
        let validated = io::read_validated(&m.models_dir, method).ok();
        let masks = validated.map_or(MaskScope::PerNode, |v| v.trained_masks);
        return Ok(DeepChoice::paper_rule(masks));
    }
    let validated = match (lambda, decision) {
        // Only the temperature is read: without it, the probabilities as
        // they are.
        (LambdaChoice::Fixed(_), DecisionChoice::Fixed(_)) => {
            io::read_validated(&m.models_dir, method).ok()
        }
        _ => Some(io::read_validated(&m.models_dir, method)?),
    };
    let missing = |what: &str| {
        RunError::Weights(WeightsError {
            method: method.as_str(),
            path: m.models_dir.join(format!("{}.toml", method.as_str())),
            reason: format!(
                "no validated_{what}: set [matching] {what}, or run `coid train --validate-only`"
            ),
        })
    };
    let lambdas = match lambda {
        LambdaChoice::Fixed(v) => KindLambdas::all(v),
        LambdaChoice::Validated => validated
            .and_then(|v| v.lambdas)
            .ok_or_else(|| missing("lambda"))?,
    };
    let decision_rule = match decision {
        DecisionChoice::Fixed(d) => d,
        DecisionChoice::Validated => validated
            .and_then(|v| v.decision)
            .ok_or_else(|| missing("decision"))?,
    };
    let temperature = validated
        .as_ref()
        .and_then(|v| v.temperature)
        .unwrap_or(1.0);
    // The operating point goes with the validated rule; a configured rule
    // decides every pair it chooses.
    let min_probability = match decision {
        DecisionChoice::Fixed(_) => 0.0,
        DecisionChoice::Validated => validated.as_ref().map_or(0.0, |v| v.min_probability),
    };
    Ok(DeepChoice {
        lambda: lambdas.get(m.uncertainty),
        lambdas,
        decision: decision_rule,
        min_probability,
        temperature,
        trained_masks: validated.map_or(MaskScope::PerNode, |v| v.trained_masks),
    })
}

/// The choice of every deep method among `methods` ([`choice_for`]).
pub fn choices(
    settings: &Settings,
    methods: &[Method],
) -> Result<BTreeMap<Method, DeepChoice>, RunError> {
    methods
        .iter()
        .filter(|m| matches!(m.kind(), MethodKind::Deep))
        .map(|&m| Ok((m, choice_for(settings, m)?)))
        .collect()
}

/// How `method` runs with `settings` and nothing found in memory
/// ([`runner_with`]).
pub fn runner(settings: &Settings, method: Method) -> Result<CorrespondenceSource, RunError> {
    runner_with(settings, &Found::default(), method)
}

/// How `method` runs with `settings` and `found`: deep methods get their
/// weights from `[matching] models_dir` and their lambda and decision rule
/// from `found` or [`choice_for`]; MC-dropout masks are seeded with the
/// sensor seed. A baseline runs at its threshold in `found`, else with
/// `baselines = "validated"` at the models folder's `baselines.toml`,
/// else at its a-priori value.
pub fn runner_with(
    settings: &Settings,
    found: &Found,
    method: Method,
) -> Result<CorrespondenceSource, RunError> {
    if method == Method::Oracle {
        return Ok(CorrespondenceSource::Oracle);
    }
    let m = &settings.matching;
    let tuned = match found.baselines.get(&method) {
        Some(v) => Some(*v),
        None if m.baselines == BaselineChoice::Validated && method.baseline_knob().is_some() => {
            io::read_baselines(&m.models_dir, &[method])?
                .get(&method)
                .copied()
        }
        None => None,
    };
    let deep = if let MethodKind::Deep = method.kind() {
        let choice = match found.deep.get(&method) {
            Some(c) => *c,
            None => choice_for(settings, method)?,
        };
        Some((io::read_weights(&m.models_dir, method)?, choice))
    } else {
        None
    };
    if let Some((w, _)) = &deep {
        let data = match &settings.dataset {
            Some(d) => d.usable_appearance_width(),
            None => settings.appearance.appearance_width(),
        };
        if let Some(reason) = matching::deep::check_appearance(w.appearance_width, data) {
            return Err(RunError::Weights(WeightsError {
                method: method.as_str(),
                path: io::weights_path(&m.models_dir, method),
                reason,
            }));
        }
    }
    let trained = deep.as_ref().map(|(w, choice)| Trained {
        weights: &w.bytes,
        choice: *choice,
        appearance_width: w.appearance_width,
        shape: w.shape,
    });
    let matcher = matching::build(method, m, (trained, tuned), settings.seeds.sensor).map_err(
        |e| match e {
            BuildError::BadWeights {
                method: label,
                reason,
            } => RunError::Weights(WeightsError {
                method: label,
                path: io::weights_path(&m.models_dir, method),
                reason,
            }),
            other => RunError::Build(other),
        },
    )?;
    Ok(CorrespondenceSource::Matcher(matcher))
}

/// The runners of `methods`, in order, with nothing found in memory.
pub fn runners(
    settings: &Settings,
    methods: &[Method],
) -> Result<Vec<CorrespondenceSource>, RunError> {
    runners_with(settings, &Found::default(), methods)
}

/// The runners of `methods` with `found` ([`runner_with`]), in order.
pub fn runners_with(
    settings: &Settings,
    found: &Found,
    methods: &[Method],
) -> Result<Vec<CorrespondenceSource>, RunError> {
    methods
        .iter()
        .map(|&m| runner_with(settings, found, m))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::deep::decision::Decision;
    use crate::pipeline::tests::settings;

    /// Settings whose models folder holds nothing.
    fn without_models(dir: &tempfile::TempDir) -> Settings {
        let mut s = settings();
        s.matching.models_dir = dir.path().to_owned();
        s
    }

    /// The oracle is no matcher; the methods that are not deep build
    /// without weights (at their a-priori thresholds; validated ones need
    /// the models folder's record); a deep method without weights is an
    /// error that names its file.
    #[test]
    fn only_deep_methods_need_weights() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = without_models(&dir);
        assert!(matches!(
            runner(&s, Method::Oracle),
            Ok(CorrespondenceSource::Oracle)
        ));
        s.matching.baselines = BaselineChoice::Validated;
        assert!(matches!(
            runner(&s, Method::Mogm),
            Err(RunError::Baselines(_))
        ));
        s.matching.baselines = BaselineChoice::APriori;
        for m in [Method::GpsHungarian, Method::GpsAppHungarian, Method::Mogm] {
            assert!(
                matches!(runner(&s, m), Ok(CorrespondenceSource::Matcher(_))),
                "{m:?}"
            );
        }
        match runner(&s, Method::Ours) {
            Err(RunError::Weights(e)) => assert_eq!(e.method, "ours"),
            Err(e) => panic!("{e}"),
            Ok(_) => panic!("ours built without weights"),
        }
        let all = runners(&s, &[Method::Oracle, Method::GpsHungarian]).unwrap();
        assert_eq!(all.len(), 2);
    }

    /// A configured lambda and decision rule are used as they are (the
    /// temperature 1 without a record); a validated one must be recorded.
    #[test]
    fn a_deep_method_decides_as_configured_or_as_validated() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = without_models(&dir);
        s.matching.lambda = LambdaChoice::Fixed(0.4);
        s.matching.decision = DecisionChoice::Fixed(Decision::Mutual);
        let c = choice_for(&s, Method::Ours).unwrap();
        assert_eq!(
            (c.lambda, c.decision, c.temperature),
            (0.4, Decision::Mutual, 1.0)
        );
        s.matching.lambda = LambdaChoice::Validated;
        assert!(matches!(
            choice_for(&s, Method::Ours),
            Err(RunError::Weights(_))
        ));
    }

    /// What validation found, given in memory, wins over the config and
    /// the models folder; the settings are left as they were. Counting
    /// every rule decides by assignment with no threshold and keeps the
    /// recorded temperature; a baseline's value given runs even when the
    /// config asks for the models folder's.
    #[test]
    fn what_was_found_travels_beside_the_settings() {
        let s = settings();
        let before = s.clone();
        let methods = [Method::Ours, Method::Mogm, Method::Oracle];
        let counting = Found::counting_every_rule(&s, &methods).unwrap();
        let c = counting.deep[&Method::Ours];
        assert_eq!(
            (c.lambda, c.decision),
            (f64::INFINITY, Decision::Assignment)
        );
        assert_eq!(
            c.temperature,
            choice_for(&s, Method::Ours).unwrap().temperature
        );
        assert_eq!(counting.deep.len(), 1);
        let dir = tempfile::tempdir().unwrap();
        let mut empty = without_models(&dir);
        empty.matching.baselines = BaselineChoice::Validated;
        assert!(runner(&empty, Method::Mogm).is_err());
        let given = Found::baselines_at(BaselineValues::from([(
            Method::Mogm,
            matching::BaselineValue::at(0.2),
        )]));
        assert!(matches!(
            runner_with(&empty, &given, Method::Mogm),
            Ok(CorrespondenceSource::Matcher(_))
        ));
        assert_eq!(s, before);
    }

    /// Only deep methods have a choice; the shipped models record one for
    /// each of theirs, a lambda in [0, 1] or none (infinite).
    #[test]
    fn the_shipped_models_record_each_deep_methods_choice() {
        let s = settings();
        let methods = [
            Method::Ours,
            Method::GpsHungarian,
            Method::Dgmc,
            Method::Oracle,
        ];
        let c = choices(&s, &methods).unwrap();
        assert_eq!(
            c.keys().copied().collect::<Vec<_>>(),
            [Method::Dgmc, Method::Ours]
        );
        assert!(
            c.values()
                .all(|c| (0.0..=1.0).contains(&c.lambda) || c.lambda == f64::INFINITY)
        );
    }
}
