//! Each deep method's choices on the validation runs, never on the test
//! runs: its decision rule, operating point and lambda (best mean F1),
//! each uncertainty type's own lambda, and its calibration temperature.

use std::collections::BTreeMap;

use super::{eval_run_into, validation_runs};
use crate::config::Settings;
use crate::evaluate::PairCounts;
use crate::matching::deep::decision::{
    Decision, KindLambdas, UncertaintyKind, calibrated, pair_uncertainty,
};
use crate::matching::{Method, MethodKind};
use crate::pipeline::{self, RunError, Warnings};
use crate::sensor::PoseNoiseLabel;
use crate::tables::{DecidedPair, MethodLevel, RuleKey, RunEval, lambda_grid};

/// What the validation runs say about one deep method: the calibration
/// temperature, decision rule and lambda (infinite: no threshold) with
/// the best mean F1 (over the runs, of the mean over pose-noise levels),
/// and that F1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chosen {
    pub temperature: f64,
    /// On the configured uncertainty type.
    pub lambda: f64,
    /// Each uncertainty type's, with the same decision rule.
    pub lambdas: KindLambdas,
    pub decision: Decision,
    /// The operating point chosen with the rule: the least E[Y] of a
    /// decided pair.
    pub min_probability: f64,
    pub f1: f64,
}

/// The operating points validation tries for a deep method's rule (the
/// least E[Y] of a decided pair): the grid of MOGM's `min_score`, 0 (every
/// pair the rule chooses) first.
pub const MIN_PROBABILITIES: [f64; 10] = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// The temperature whose calibrated probabilities have the lowest log
/// loss on `pairs` (the decided pairs of one method and rule), fitted
/// continuously within [`TEMPERATURE_RANGE`]: the log loss is convex in
/// 1/t (a logistic regression on the logit with one weight), so a golden
/// section over ln t finds its minimum. At the range's top the decided
/// pairs are mostly wrong and no temperature calibrates them
/// ([`crate::matching::deep::decision::temperature_at_bound`]).
fn fit_temperature<'a>(pairs: impl Iterator<Item = &'a DecidedPair> + Clone) -> f64 {
    let log_loss = |ln_t: f64| -> f64 {
        let t = ln_t.exp();
        pairs
            .clone()
            .map(|d| {
                let q = calibrated(f64::from(d.p), t).clamp(1e-12, 1.0 - 1e-12);
                -(if d.correct { q } else { 1.0 - q }).ln()
            })
            .sum()
    };
    let range = crate::matching::deep::decision::TEMPERATURE_RANGE;
    let (mut a, mut b) = (range.0.ln(), range.1.ln());
    let phi = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - phi * (b - a), a + phi * (b - a));
    let (mut fc, mut fd) = (log_loss(c), log_loss(d));
    while b - a > 1e-6 {
        if fc <= fd {
            (b, d, fd) = (d, c, fc);
            c = b - phi * (b - a);
            fc = log_loss(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + phi * (b - a);
            fd = log_loss(d);
        }
    }
    // Nothing to calibrate (no pairs, or a flat loss): 1.
    let t = ((a + b) / 2.0).exp();
    if log_loss(t.ln()) < log_loss(0.0) {
        t
    } else {
        1.0
    }
}

/// Chooses each deep method's calibration temperature, decision rule,
/// operating point and lambda on the validation runs (`[train]
/// validation_seeds` and scenarios, or a dataset's validation runs),
/// never on the test runs: the rule (assignment, mutual best with the
/// dustbins, mutual best of the real nodes), the least E[Y] of a decided
/// pair ([`MIN_PROBABILITIES`]) and the threshold (the grid 0..1 by 0.05
/// and no threshold, on the configured uncertainty type) with the best
/// mean F1, ties going to the rule listed first, then to the smaller
/// operating point and lambda; then with that rule and operating point
/// each uncertainty type's own threshold, the same way; and the
/// temperature with the lowest log loss of the decided pairs (it
/// calibrates the reported probabilities and changes no decision).
/// `progress(run, runs)` after each run.
pub fn validate(
    settings: &Settings,
    methods: &[Method],
    threads: usize,
    warnings: &Warnings,
    mut progress: impl FnMut(usize, usize),
) -> Result<BTreeMap<Method, Chosen>, RunError> {
    // The configured decision is not used: every rule and threshold is
    // counted.
    let counting = pipeline::Found::counting_every_rule(settings, methods)?;
    let validation = validation_runs(settings)?;
    let mut runs = Vec::new();
    for (k, run) in validation.iter().enumerate() {
        let kept = RunEval::keeping_pairs();
        let no_lambdas = BTreeMap::new();
        runs.push(eval_run_into(
            kept,
            run,
            &pipeline::runners_with(run, &counting, methods)?,
            (&no_lambdas, threads),
            warnings,
            |_| {},
        )?);
        progress(k + 1, validation.len());
    }
    let levels: Vec<_> = settings.pose_noise.iter().map(|l| l.label).collect();
    let kind = settings.matching.uncertainty;
    Ok(methods
        .iter()
        .filter(|m| matches!(m.kind(), MethodKind::Deep))
        .map(|&m| (m, choose(&runs, &levels, kind, m)))
        .collect())
}

/// A run's decided pairs of `key` (none when it kept none).
fn decided(r: &RunEval, key: RuleKey) -> &[DecidedPair] {
    r.decided
        .as_ref()
        .and_then(|d| d.get(&key))
        .map_or(&[][..], Vec::as_slice)
}

/// The mean F1 over the validation runs (of the mean over the levels) of
/// method `m` deciding by `decision`, thresholded at `lambda` on the
/// uncertainty `kind`; a run (or level) without pairs to find or found has
/// none.
fn validation_f1(
    runs: &[RunEval],
    levels: &[PoseNoiseLabel],
    m: Method,
    (decision, min_probability): (Decision, f64),
    (kind, lambda): (UncertaintyKind, f64),
) -> f64 {
    let min_p = min_probability as f32;
    let f1_of_run = |r: &RunEval| {
        let f: Vec<f64> = levels
            .iter()
            .filter_map(|&l| {
                let rule = MethodLevel::new(m, l).rule(decision);
                let truth = r.unthresholded.get(&rule)?.ground_truth;
                let kept = decided(r, rule).iter().filter(|d| {
                    let (p, a) = (f64::from(d.p), f64::from(d.aleatoric));
                    d.p >= min_p && pair_uncertainty(p, a, kind) < lambda
                });
                let counts = PairCounts {
                    identified: kept.clone().count(),
                    correct: kept.filter(|d| d.correct).count(),
                    ground_truth: truth,
                };
                Some(counts.f1()).filter(|f| f.is_finite())
            })
            .collect();
        (!f.is_empty()).then(|| f.iter().sum::<f64>() / f.len() as f64)
    };
    let per_run: Vec<f64> = runs.iter().filter_map(f1_of_run).collect();
    per_run.iter().sum::<f64>() / per_run.len().max(1) as f64
}

/// The lambda of the grid (or none) with the best [`validation_f1`], the
/// smaller one on ties, and that F1.
fn best_lambda(f1_at: impl Fn(f64) -> f64) -> (f64, f64) {
    let mut best = (f64::INFINITY, f64::NEG_INFINITY);
    for &lambda in &lambda_grid([]) {
        let f1 = f1_at(lambda);
        if f1 > best.1 {
            best = (lambda, f1);
        }
    }
    best
}

/// The temperature, rule, operating point and lambda of [`validate`] for
/// one method: the rule, operating point and lambda on the configured
/// uncertainty `kind`, then, with that rule and operating point, each
/// uncertainty type's own lambda.
fn choose(runs: &[RunEval], levels: &[PoseNoiseLabel], kind: UncertaintyKind, m: Method) -> Chosen {
    let mut best = Chosen {
        temperature: 1.0,
        lambda: f64::INFINITY,
        lambdas: KindLambdas::all(f64::INFINITY),
        decision: Decision::Assignment,
        min_probability: 0.0,
        f1: f64::NEG_INFINITY,
    };
    for decision in [Decision::Assignment, Decision::Mutual, Decision::MutualReal] {
        for min_probability in MIN_PROBABILITIES {
            let rule = (decision, min_probability);
            let (lambda, f1) =
                best_lambda(|lambda| validation_f1(runs, levels, m, rule, (kind, lambda)));
            if f1 > best.f1 {
                best = Chosen {
                    lambda,
                    decision,
                    min_probability,
                    f1,
                    ..best
                };
            }
        }
    }
    let min_p = best.min_probability as f32;
    let all = runs.iter().flat_map(|r| {
        levels.iter().flat_map(move |&l| {
            decided(r, MethodLevel::new(m, l).rule(best.decision))
                .iter()
                .filter(move |d| d.p >= min_p)
        })
    });
    best.temperature = fit_temperature(all);
    let rule = (best.decision, best.min_probability);
    best.lambdas = KindLambdas::from_fn(|k| {
        best_lambda(|lambda| validation_f1(runs, levels, m, rule, (k, lambda))).0
    });
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(p: f32, right: usize, wrong: usize) -> Vec<DecidedPair> {
        let pair = |correct| DecidedPair {
            p,
            aleatoric: 0.0,
            correct,
        };
        (0..right)
            .map(|_| pair(true))
            .chain((0..wrong).map(|_| pair(false)))
            .collect()
    }

    /// Pairs at E[Y] = 0.9 that are right 9 times in 10 keep their
    /// probability (temperature 1); right 3 times in 4, they are
    /// overconfident and the fit cools them to about 0.75 (ln 9 / ln 3 =
    /// 2); right 99 times in 100, underconfident (below 1).
    #[test]
    fn the_temperature_fit_calibrates_the_decided_pairs() {
        let fit = |right, wrong| fit_temperature(pairs(0.9, right, wrong).iter());
        assert!((fit(90, 10) - 1.0).abs() < 0.02, "{}", fit(90, 10));
        let hot = fit(75, 25);
        assert!((hot - 2.0).abs() < 0.05, "{hot}");
        assert!((calibrated(0.9, hot) - 0.75).abs() < 0.01);
        assert!(fit(99, 1) < 0.7);
    }

    /// Validation chooses the operating point with the rule: when the
    /// dustbins keep a method from deciding pairs that are mostly right
    /// (E[Y] 0.3 here) and the real block's mutual best holds them with
    /// wrong ones at lower E[Y] (0.15), the mutual best of the real nodes
    /// with the least operating point that drops the wrong ones wins; no
    /// entropy threshold can (both lie on the same side of 1/2).
    #[test]
    fn validation_chooses_the_operating_point_with_the_rule() {
        let at = MethodLevel::new(Method::Coid, PoseNoiseLabel::GPS);
        let mut run = RunEval::keeping_pairs();
        let confident = pairs(0.8, 10, 0);
        let mut real = confident.clone();
        real.extend(pairs(0.3, 5, 0));
        real.extend(pairs(0.15, 0, 10));
        let decided = run.decided.as_mut().unwrap();
        for (rule, kept) in [
            (Decision::Assignment, &confident),
            (Decision::Mutual, &confident),
            (Decision::MutualReal, &real),
        ] {
            decided.insert(at.rule(rule), kept.clone());
            let truth = PairCounts {
                ground_truth: 20,
                ..PairCounts::default()
            };
            run.unthresholded.insert(at.rule(rule), truth);
        }
        let c = choose(
            &[run],
            &[PoseNoiseLabel::GPS],
            UncertaintyKind::Total,
            Method::Coid,
        );
        assert_eq!(c.decision, Decision::MutualReal);
        assert_eq!(c.min_probability, 0.2);
        assert!((c.f1 - 2.0 * 0.75 / 1.75).abs() < 1e-9, "{}", c.f1);
    }
}
