//! Each method's runner: the matcher built with its settings, a deep
//! method's weights and its choice of lambda, decision rule and
//! temperature (configured, or validated by `coid train`, read through
//! `io`).

use std::collections::BTreeMap;

use super::RunError;
use crate::config::Settings;
use crate::evaluate::CorrespondenceSource;
use crate::io::{self, WeightsError};
use crate::matching::deep::arch::MaskScope;
use crate::matching::deep::decision::KindLambdas;
use crate::matching::{
    self, BaselineChoice, BuildError, DecisionChoice, DeepChoice, LambdaChoice, Method, MethodKind,
    Trained,
};

/// How a deep method decides: its entropy threshold and decision rule as
/// configured, or as `coid train` chose them on the validation runs, and
/// the calibration temperature fitted there (recorded beside the weights;
/// 1 when the models folder records none).
pub fn choice_for(settings: &Settings, method: Method) -> Result<DeepChoice, RunError> {
    let m = &settings.matching;
    if method == Method::CoidPaperRule {
        let validated = io::read_validated(&m.models_dir, method).ok();
        let masks = validated.map_or(MaskScope::PerNode, |v| v.trained_masks);
        return Ok(DeepChoice::paper_rule(masks));
    }
    let validated = match (m.lambda, m.decision) {
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
    let lambdas = match m.lambda {
        LambdaChoice::Fixed(v) => KindLambdas::all(v),
        LambdaChoice::Validated => validated
            .and_then(|v| v.lambdas)
            .ok_or_else(|| missing("lambda"))?,
    };
    let lambda = lambdas.get(m.uncertainty);
    let decision = match m.decision {
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
    let min_probability = match m.decision {
        DecisionChoice::Fixed(_) => 0.0,
        DecisionChoice::Validated => validated.as_ref().map_or(0.0, |v| v.min_probability),
    };
    Ok(DeepChoice {
        lambda,
        lambdas,
        decision,
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

/// How `method` runs with `settings`: deep methods get their weights from
/// `[matching] models_dir` and their lambda and decision rule
/// ([`choice_for`]); MC-dropout masks are seeded with the sensor seed.
/// The baselines run at the thresholds `settings.matching.baseline_values`
/// holds, or with `baselines = "validated"` at those of the models
/// folder's `baselines.toml`.
pub fn runner(settings: &Settings, method: Method) -> Result<CorrespondenceSource, RunError> {
    if method == Method::Oracle {
        return Ok(CorrespondenceSource::Oracle);
    }
    let mut m = settings.matching.clone();
    if m.baselines == BaselineChoice::Validated && method.baseline_knob().is_some() {
        m.baseline_values = io::read_baselines(&m.models_dir, &[method])?;
    }
    let m = &m;
    let deep = if let MethodKind::Deep = method.kind() {
        Some((
            io::read_weights(&m.models_dir, method)?,
            choice_for(settings, method)?,
        ))
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
    let matcher =
        matching::build(method, m, trained, settings.seeds.sensor).map_err(|e| match e {
            BuildError::BadWeights {
                method: label,
                reason,
            } => RunError::Weights(WeightsError {
                method: label,
                path: io::weights_path(&m.models_dir, method),
                reason,
            }),
            other => RunError::Build(other),
        })?;
    Ok(CorrespondenceSource::Matcher(matcher))
}

/// The runners of `methods`, in order.
pub fn runners(
    settings: &Settings,
    methods: &[Method],
) -> Result<Vec<CorrespondenceSource>, RunError> {
    methods.iter().map(|&m| runner(settings, m)).collect()
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
