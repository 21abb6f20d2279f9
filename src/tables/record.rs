//! What one test run contributes to the tables: [`RunEval`], pooled within
//! the run. Each of its maps has one typed key: a method at a level
//! ([`MethodLevel`]), under a decision rule ([`RuleKey`]), at a threshold
//! of the lambda grid ([`ThresholdKey`]); a summary row's [`RowKey`] for
//! the displacement errors, with a seen-by group for fusion from every
//! view ([`ViewKey`]).

use std::collections::BTreeMap;

use crate::evaluate::{Consistency, MethodEval, PairCounts, ViewEstimate, count_pairs, is_correct};
use crate::fusion::FusionVariant;
use crate::matching::Method;
use crate::matching::deep::decision::{Decision, MatchDistribution, UncertaintyKind};
use crate::report::{ObjectErrors, RowKey, ScoredPair, ViewSums, seen_by_group};
use crate::sensor::{ObservationTruth, PoseNoiseLabel};

/// A method at a pose-noise level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct MethodLevel {
    pub method: Method,
    pub pose_noise: PoseNoiseLabel,
}

impl MethodLevel {
    pub fn new(method: Method, pose_noise: PoseNoiseLabel) -> Self {
        Self { method, pose_noise }
    }

    /// Each of `methods` at each of `levels` it is read at: a method on
    /// the paper's inputs, the same at every level, at the first only.
    pub fn read_at(methods: &[Method], levels: &[PoseNoiseLabel]) -> Vec<Self> {
        let mut keys = Vec::new();
        for &method in methods {
            let take = if method.inputs() == crate::matching::Inputs::Paper {
                1
            } else {
                levels.len()
            };
            keys.extend(levels.iter().take(take).map(|&l| Self::new(method, l)));
        }
        keys
    }

    /// Its Table 1 F1 in each of `evals` that has it.
    pub fn f1_per_run(self, evals: &[RunEval]) -> Vec<f64> {
        evals
            .iter()
            .filter_map(|e| e.table1.get(&self).map(PairCounts::f1))
            .collect()
    }

    /// The method under `decision` at this level.
    pub fn rule(self, decision: Decision) -> RuleKey {
        RuleKey { at: self, decision }
    }

    /// The summary row of this method and level with `fusion`.
    pub fn row(self, fusion: FusionVariant) -> RowKey {
        RowKey {
            method: self.method,
            pose_noise: self.pose_noise,
            fusion,
        }
    }
}

/// A deep method's decision rule at a pose-noise level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct RuleKey {
    pub at: MethodLevel,
    pub decision: Decision,
}

impl RuleKey {
    /// Thresholded on the uncertainty `kind` at the `lambda_index`-th
    /// lambda of the grid.
    pub fn threshold(self, kind: UncertaintyKind, lambda_index: usize) -> ThresholdKey {
        ThresholdKey {
            rule: self,
            kind,
            lambda_index,
        }
    }
}

/// A deep method's decision rule at a level, its pairs kept where the
/// uncertainty `kind` is below the `lambda_index`-th lambda of the grid
/// ([`super::lambda_grid`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct ThresholdKey {
    pub rule: RuleKey,
    pub kind: UncertaintyKind,
    pub lambda_index: usize,
}

/// Fusion from every view: a summary row and the objects seen by `seen_by`
/// vehicles ([`seen_by_group`]: 1, 2, 3, 4 for four or more).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct ViewKey {
    pub row: RowKey,
    pub seen_by: usize,
}

/// A pose-noise level with a fusion variant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct LevelFusion {
    pub pose_noise: PoseNoiseLabel,
    pub fusion: FusionVariant,
}

/// Every object's single and fused displacement error (m), in the same
/// order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorSamples {
    pub single_m: Vec<f64>,
    pub fused_m: Vec<f64>,
}

/// What one test run contributes to the tables.
#[derive(Clone, Debug, Default)]
pub struct RunEval {
    /// Table 1: each method with its default decision.
    pub table1: BTreeMap<MethodLevel, PairCounts>,
    /// Deep methods without thresholding, per decision rule.
    pub unthresholded: BTreeMap<RuleKey, PairCounts>,
    /// Deep methods thresholded, per rule, uncertainty type and lambda.
    pub thresholded: BTreeMap<ThresholdKey, PairCounts>,
    /// Each deep method's own decision rule, as it ran.
    pub decisions: BTreeMap<Method, Decision>,
    /// With [`RunEval::keeping_pairs`]: every decided pair of the deep
    /// methods under each rule, before any threshold (validation).
    pub decided: Option<BTreeMap<RuleKey, Vec<DecidedPair>>>,
    /// Displacement errors per summary row over the object sets of the
    /// protocol.
    pub errors: BTreeMap<RowKey, ObjectErrors>,
    /// Every object's single and fused error of the full method (`ours`),
    /// for the error CDFs.
    pub ours_errors: BTreeMap<LevelFusion, ErrorSamples>,
    /// Every identified pair of each method (its default decision), for
    /// calibration.
    pub scored: BTreeMap<MethodLevel, Vec<ScoredPair>>,
    /// Calibration on one common set of pairs: in every instance, the
    /// pairs any deep method decided, each scored by every deep method's
    /// own probability (made by [`RunEval::close_common`]).
    pub common: BTreeMap<MethodLevel, Vec<ScoredPair>>,
    /// The deep methods' probabilities per instance and level until the
    /// run's common set is made.
    pending: BTreeMap<(PoseNoiseLabel, usize), PendingInstance>,
    /// Consistency across vehicles of each method's decided matches.
    pub consistency: BTreeMap<MethodLevel, Consistency>,
    /// Fusion from every view.
    pub views: BTreeMap<ViewKey, ViewSums>,
    /// Table 1's counts of each deep method with the weights of each
    /// training seed evaluated (`[eval] training_seeds`: the models
    /// folder's own and the others'); empty when one seed was.
    pub by_seed: BTreeMap<(MethodLevel, u64), PairCounts>,
    pub instances: usize,
}

/// One instance at one level while its run goes on: which of its pairs
/// are true, which any deep method decided, and each deep method's
/// calibrated probability of every pair (`n1 x n2`, row-major).
#[derive(Clone, Debug, Default)]
struct PendingInstance {
    truth: Vec<bool>,
    decided: std::collections::BTreeSet<usize>,
    probabilities: Vec<(Method, Vec<f32>)>,
}

/// One pair a deep method's rule decided on, before any threshold: what
/// validation needs to calibrate and threshold it afresh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecidedPair {
    /// E[Y] of the pair (uncalibrated).
    pub p: f32,
    /// Its aleatoric uncertainty (bits).
    pub aleatoric: f32,
    pub correct: bool,
}

impl RunEval {
    /// An empty run that also keeps every decided pair (validation).
    pub fn keeping_pairs() -> Self {
        Self {
            decided: Some(BTreeMap::new()),
            ..Self::default()
        }
    }

    /// Adds one method's all-view estimates of one frame at one level.
    pub fn record_views(
        &mut self,
        method: Method,
        level: PoseNoiseLabel,
        views: &[(FusionVariant, Vec<ViewEstimate>)],
    ) {
        let at = MethodLevel::new(method, level);
        for (variant, estimates) in views {
            for v in estimates {
                let key = ViewKey {
                    row: at.row(*variant),
                    seen_by: seen_by_group(v.seen_by),
                };
                self.views.entry(key).or_default().add(v);
            }
        }
    }

    /// Keeps a deep method's probabilities of every pair of one instance
    /// (`instance`, its index in the run) at one level, and the pairs it
    /// decided, for the common pair set.
    pub fn record_candidates(
        &mut self,
        e: &MethodEval,
        level: PoseNoiseLabel,
        instance: usize,
        (ta, tb): (&ObservationTruth, &ObservationTruth),
    ) {
        let Some(dist) = &e.identification.distribution else {
            return;
        };
        let (n1, n2) = (dist.n1, dist.n2);
        let pending = self.pending.entry((level, instance)).or_default();
        if pending.truth.is_empty() {
            pending.truth = (0..n1 * n2)
                .map(|k| {
                    let a = ta.object_id(k / n2);
                    a.is_some() && a == tb.object_id(k % n2)
                })
                .collect();
        }
        let matches = &e.identification.matches;
        pending
            .decided
            .extend(matches.iter().map(|c| c.a * n2 + c.b));
        let p = (0..n1 * n2)
            .map(|k| dist.probability(k / n2, k % n2) as f32)
            .collect();
        pending.probabilities.push((e.method, p));
    }

    /// Makes the run's common pair set: in every instance and level, the
    /// pairs any deep method decided, each scored by every deep method's
    /// probability (its uncertainty `1 - p`, so that the AUROC is that of
    /// the probability for telling true pairs from false ones).
    pub fn close_common(&mut self) {
        for ((level, _), pending) in std::mem::take(&mut self.pending) {
            for (method, p) in &pending.probabilities {
                let scored = pending.decided.iter().map(|&k| ScoredPair {
                    probability: f64::from(p[k]),
                    uncertainty: 1.0 - f64::from(p[k]),
                    correct: pending.truth[k],
                });
                self.common
                    .entry(MethodLevel::new(*method, level))
                    .or_default()
                    .extend(scored);
            }
        }
    }

    /// Adds one method's consistency on one frame at one level.
    pub fn record_consistency(&mut self, method: Method, level: PoseNoiseLabel, c: Consistency) {
        let at = MethodLevel::new(method, level);
        self.consistency.entry(at).or_default().add(c);
    }

    /// Counts one distribution's pairs under `rule` without a threshold and
    /// at every threshold of `grid` and every uncertainty type.
    fn record_thresholds(
        &mut self,
        rule: RuleKey,
        (ta, tb): (&ObservationTruth, &ObservationTruth),
        dist: &MatchDistribution,
        grid: &[f64],
    ) {
        let pairs = dist.decide_with(rule.decision, None);
        let before = count_pairs(ta, tb, &pairs);
        self.unthresholded.entry(rule).or_default().add(before);
        let correct: Vec<bool> = pairs.iter().map(|c| is_correct(ta, tb, c)).collect();
        if let Some(decided) = &mut self.decided {
            decided
                .entry(rule)
                .or_default()
                .extend(pairs.iter().zip(&correct).map(|(c, &correct)| DecidedPair {
                    p: dist.p(c.a, c.b),
                    aleatoric: dist.aleatoric[c.a * dist.n2 + c.b],
                    correct,
                }));
        }
        for kind in UncertaintyKind::VARIANTS_ARRAY {
            let u: Vec<f64> = pairs
                .iter()
                .map(|c| dist.uncertainty(c.a, c.b, kind))
                .collect();
            for (lambda_index, &lambda) in grid.iter().enumerate() {
                let kept = u.iter().zip(&correct).filter(|&(&u, _)| u < lambda);
                let counts = PairCounts {
                    identified: kept.clone().count(),
                    correct: kept.filter(|&(_, &c)| c).count(),
                    ground_truth: before.ground_truth,
                };
                self.thresholded
                    .entry(rule.threshold(kind, lambda_index))
                    .or_default()
                    .add(counts);
            }
        }
    }

    /// Adds one method's evaluation of one instance at one level; deep
    /// methods also count every threshold of `grid` and every uncertainty
    /// type on the same distribution.
    pub fn record(
        &mut self,
        e: &MethodEval,
        level: PoseNoiseLabel,
        truths: (&ObservationTruth, &ObservationTruth),
        grid: &[f64],
    ) {
        let (ta, tb) = truths;
        let at = MethodLevel::new(e.method, level);
        if let Some(dist) = &e.identification.distribution {
            self.decisions.insert(e.method, dist.decision);
            for decision in [Decision::Assignment, Decision::Mutual, Decision::MutualReal] {
                self.record_thresholds(at.rule(decision), truths, dist, grid);
            }
        }
        self.table1.entry(at).or_default().add(e.counts);
        let scored = e.identification.matches.iter().map(|c| ScoredPair {
            probability: c.probability,
            uncertainty: c.uncertainty,
            correct: is_correct(ta, tb, c),
        });
        self.scored.entry(at).or_default().extend(scored);
        for (variant, est) in &e.fused {
            if e.method == Method::Ours {
                let key = LevelFusion {
                    pose_noise: level,
                    fusion: *variant,
                };
                let samples = self.ours_errors.entry(key).or_default();
                samples
                    .single_m
                    .extend(est.iter().map(|x| x.single_error_m()));
                samples
                    .fused_m
                    .extend(est.iter().map(|x| x.fused_error_m()));
            }
            self.errors.entry(at.row(*variant)).or_default().record(est);
        }
    }
}
