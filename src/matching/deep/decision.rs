//! From Monte Carlo samples of the soft assignment to correspondences: the
//! mean assignment E[Y] (paper Eq. 9), per-pair uncertainties (Eq. 10 and
//! its epistemic/aleatoric split, paper Table 3), the one-to-one decision
//! with "no match", and the removal of uncertain pairs (threshold lambda).
//! Plain `f32` arrays; no tensors.
//!
//! Entropy scale: each pair (i, j) is a binary event "i matches j" with
//! probability p = E[Y]_ij, and its uncertainty is the binary entropy of p
//! in bits, which lies in [0, 1] (0 = certain either way, 1 = p of 0.5).
//! That is the scale the paper's lambda = 0.7 fits. The three kinds of
//! Table 3 are Depeweg et al.'s decomposition, all on the samples as the
//! network gives them (one scale): total = the entropy of the mean
//! H(E[p_t]) (Eq. 10); aleatoric = the mean entropy of the samples
//! E[H(p_t)] (expected data uncertainty); epistemic = total - aleatoric,
//! the mutual information between the pair's outcome and the weights
//! (>= 0 because entropy is concave; zero when every sample agrees).
//! Thresholding removes a pair whose uncertainty of the chosen kind is at
//! least lambda, whatever its probability.
//!
//! Calibration: a temperature `tau`, fitted on validation runs (log loss
//! of the decided pairs), maps a pair's E[Y] to the probability it
//! reports, `sigmoid(logit(p) / tau)`. The map is monotone and keeps 0.5
//! where it is, so it changes no decision and no ranking; it calibrates
//! the reported probability only, never the uncertainties.

use crate::matching::{Correspondence, binary_entropy_bits};

crate::label_enum! { "uncertainty";
    /// Which uncertainty the threshold applies to.
    #[strum(serialize_all = "lowercase")]
    pub enum UncertaintyKind {
        /// Entropy of the mean (Eq. 10): aleatoric + epistemic.
        #[strum(serialize = "entropy")]
        Total,
        Epistemic,
        Aleatoric,
    }
}

/// A threshold lambda per uncertainty type (infinite: no threshold), as
/// validation chooses them: Table 3 thresholds each type at its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KindLambdas([f64; 3]);

impl KindLambdas {
    /// The same lambda for every type (a configured number).
    pub const fn all(lambda: f64) -> Self {
        Self([lambda; 3])
    }

    /// Builds them from the lambda of each type.
    pub fn from_fn(mut f: impl FnMut(UncertaintyKind) -> f64) -> Self {
        Self(UncertaintyKind::VARIANTS_ARRAY.map(&mut f))
    }

    /// From the lambda of each type in [`UncertaintyKind`]'s order.
    pub fn from_values(values: [f64; 3]) -> Self {
        Self(values)
    }

    pub fn get(&self, kind: UncertaintyKind) -> f64 {
        self.0[kind as usize]
    }

    /// Every type's lambda, in [`UncertaintyKind`]'s order.
    pub fn values(&self) -> [f64; 3] {
        self.0
    }
}

impl UncertaintyKind {
    /// Every type, in declaration order (total, epistemic, aleatoric).
    pub const VARIANTS_ARRAY: [UncertaintyKind; 3] = [
        UncertaintyKind::Total,
        UncertaintyKind::Epistemic,
        UncertaintyKind::Aleatoric,
    ];
}

crate::label_enum! { "decision";
    /// How a deep method chooses its pairs from the MC samples.
    #[strum(serialize_all = "lowercase")]
    pub enum Decision {
        /// The optimal one-to-one assignment of the mean scores (the shared
        /// likelihood plus the mean learned residual), with the gates of
        /// the likelihood: GPS+appearance Hungarian's decision on the
        /// network's scores.
        Assignment,
        /// i and j are paired when each is the other's most likely partner
        /// in E[Y], dustbins included.
        Mutual,
        /// i and j are paired when each is the other's most likely partner
        /// among the real nodes of E[Y], the dustbins left out: SuperGlue's
        /// rule (Sarlin et al. 2020), whose minimum probability (the
        /// operating point validation chooses) decides what is "no match".
        #[strum(serialize = "mutual-real")]
        MutualReal,
    }
}

/// The summary of T samples of a soft assignment with dustbins, and the
/// pairs a decision chose from them before any threshold.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchDistribution {
    pub n1: usize,
    pub n2: usize,
    /// `(n1 + 1) x (n2 + 1)` row-major mean assignment; the last row and
    /// column are the dustbins ("no match").
    pub mean: Vec<f32>,
    /// `n1 x n2` mean over samples of each sample's binary entropy (bits).
    pub aleatoric: Vec<f32>,
    /// The optimal assignment of the mean scores, `(i, j)` sorted by `i`
    /// (what [`Decision::Assignment`] pairs before any threshold).
    pub assigned: Vec<(usize, usize)>,
    /// The rule [`Self::decide`] applies.
    pub decision: Decision,
    /// The calibration temperature of the reported probabilities (1: as
    /// they are).
    pub temperature: f64,
    /// The operating point: every rule decides only pairs whose E[Y] is at
    /// least this (0: every pair the rule chooses).
    pub min_probability: f32,
}

/// The uncertainty of `kind` of a pair with mean probability `p` (E[Y])
/// and mean sample entropy `aleatoric` (bits): the binary entropy of `p`
/// (total), `aleatoric` (capped at the total, which it can pass only by
/// rounding), or their difference (epistemic, the mutual information).
pub fn pair_uncertainty(p: f64, aleatoric: f64, kind: UncertaintyKind) -> f64 {
    let total = binary_entropy_bits(p);
    let aleatoric = aleatoric.clamp(0.0, total);
    match kind {
        UncertaintyKind::Total => total,
        UncertaintyKind::Aleatoric => aleatoric,
        UncertaintyKind::Epistemic => total - aleatoric,
    }
}

/// `sigmoid(logit(p) / tau)`: a probability calibrated by a temperature.
/// The temperatures validation may fit: 1/1000 to 1000.
pub const TEMPERATURE_RANGE: (f64, f64) = (1e-3, 1e3);

/// Why a fitted temperature is not a calibration, if it is not: at an end
/// of [`TEMPERATURE_RANGE`] (at the top, the decided pairs are mostly
/// wrong and every probability is pushed towards 1/2).
pub fn temperature_at_bound(t: f64) -> Option<String> {
    let (lo, hi) = TEMPERATURE_RANGE;
    (t <= lo * 1.01 || t >= hi / 1.01).then(|| {
        format!(
            "the temperature {t:.3} lies at an end of the range fitted ({lo} to {hi}): the \
             decided pairs' probabilities cannot be calibrated by a temperature"
        )
    })
}

pub fn calibrated(p: f64, temperature: f64) -> f64 {
    if temperature == 1.0 || p <= 0.0 || p >= 1.0 {
        return p;
    }
    let logit = (p / (1.0 - p)).ln() / temperature;
    1.0 / (1.0 + (-logit).exp())
}

impl MatchDistribution {
    /// Summarises `samples`, each `(n1 + 1) x (n2 + 1)` row-major; nothing
    /// decided yet.
    pub fn from_samples(n1: usize, n2: usize, samples: &[Vec<f32>]) -> Self {
        let cols = n2 + 1;
        let mut mean = vec![0f32; (n1 + 1) * cols];
        let mut aleatoric = vec![0f32; n1 * n2];
        let t = samples.len().max(1) as f32;
        for s in samples {
            for (m, v) in mean.iter_mut().zip(s) {
                *m += v / t;
            }
            for i in 0..n1 {
                for j in 0..n2 {
                    aleatoric[i * n2 + j] +=
                        binary_entropy_bits(f64::from(s[i * cols + j])) as f32 / t;
                }
            }
        }
        Self {
            n1,
            n2,
            mean,
            aleatoric,
            assigned: Vec::new(),
            decision: Decision::Mutual,
            temperature: 1.0,
            min_probability: 0.0,
        }
    }

    /// Everything in the dustbins (a side without detections).
    pub fn all_unmatched(n1: usize, n2: usize) -> Self {
        let mut mean = vec![0f32; (n1 + 1) * (n2 + 1)];
        for i in 0..n1 {
            mean[i * (n2 + 1) + n2] = 1.0;
        }
        for j in 0..n2 {
            mean[n1 * (n2 + 1) + j] = 1.0;
        }
        Self {
            n1,
            n2,
            mean,
            aleatoric: vec![0.0; n1 * n2],
            assigned: Vec::new(),
            decision: Decision::Assignment,
            temperature: 1.0,
            min_probability: 0.0,
        }
    }

    pub fn p(&self, i: usize, j: usize) -> f32 {
        self.mean[i * (self.n2 + 1) + j]
    }

    /// The probability pair (i, j) reports: E[Y]_ij calibrated.
    pub fn probability(&self, i: usize, j: usize) -> f64 {
        calibrated(f64::from(self.p(i, j)), self.temperature)
    }

    /// The total uncertainty of pair (i, j): the binary entropy of its
    /// E[Y], in bits.
    pub fn total(&self, i: usize, j: usize) -> f64 {
        binary_entropy_bits(f64::from(self.p(i, j)))
    }

    /// The uncertainty of `kind` of pair (i, j): [`pair_uncertainty`] of
    /// its E[Y] and mean sample entropy.
    pub fn uncertainty(&self, i: usize, j: usize, kind: UncertaintyKind) -> f64 {
        pair_uncertainty(
            f64::from(self.p(i, j)),
            f64::from(self.aleatoric[i * self.n2 + j]),
            kind,
        )
    }

    /// The mutual-best pairs of E[Y]: each is the other's most likely
    /// partner, among the dustbins too (`dustbins`) or among the real
    /// nodes only.
    pub fn mutual_best(&self, dustbins: bool) -> Vec<(usize, usize)> {
        let (n1, n2) = (self.n1, self.n2);
        let (rows, cols) = if dustbins { (n2 + 1, n1 + 1) } else { (n2, n1) };
        let best_in_row = |i: usize| {
            (0..rows)
                .max_by(|&a, &b| self.p(i, a).total_cmp(&self.p(i, b)).then(b.cmp(&a)))
                .unwrap_or(n2)
        };
        let best_in_col = |j: usize| {
            (0..cols)
                .max_by(|&a, &b| self.p(a, j).total_cmp(&self.p(b, j)).then(b.cmp(&a)))
                .unwrap_or(n1)
        };
        (0..n1)
            .filter_map(|i| {
                let j = best_in_row(i);
                (j < n2 && best_in_col(j) == i).then_some((i, j))
            })
            .collect()
    }

    /// The pairs `decision` chooses at the operating point
    /// (`min_probability`), before any uncertainty threshold.
    pub fn decided(&self, decision: Decision) -> Vec<(usize, usize)> {
        let mut pairs = match decision {
            Decision::Assignment => self.assigned.clone(),
            Decision::Mutual => self.mutual_best(true),
            // A real block's best can be a pair of probability 0 (every
            // entry of its row and column is): SuperGlue keeps only pairs
            // above its threshold, so this rule never pairs those.
            Decision::MutualReal => {
                let mut pairs = self.mutual_best(false);
                pairs.retain(|&(i, j)| self.p(i, j) > 0.0);
                pairs
            }
        };
        if self.min_probability > 0.0 {
            pairs.retain(|&(i, j)| self.p(i, j) >= self.min_probability);
        }
        pairs
    }

    /// The pairs of this distribution's own decision rule whose
    /// uncertainty of `kind` is below `lambda` (all of them without a
    /// threshold; an infinite lambda keeps all).
    pub fn decide(&self, threshold: Option<(UncertaintyKind, f64)>) -> Vec<Correspondence> {
        self.decide_with(self.decision, threshold)
    }

    /// [`Self::decide`] with another decision rule.
    pub fn decide_with(
        &self,
        decision: Decision,
        threshold: Option<(UncertaintyKind, f64)>,
    ) -> Vec<Correspondence> {
        self.decided(decision)
            .into_iter()
            .filter(|&(i, j)| {
                threshold.is_none_or(|(kind, lambda)| self.uncertainty(i, j, kind) < lambda)
            })
            .map(|(i, j)| Correspondence {
                a: i,
                b: j,
                probability: self.probability(i, j),
                uncertainty: binary_entropy_bits(self.probability(i, j)),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dist(samples: &[Vec<f32>]) -> MatchDistribution {
        MatchDistribution::from_samples(2, 2, samples)
    }

    #[test]
    fn mutual_best_pairs_and_dustbins() {
        // Rows: node 0 matches column 1; node 1 prefers the dustbin.
        let s = vec![
            0.05, 0.9, 0.05, //
            0.1, 0.2, 0.7, //
            0.85, 0.05, 0.1,
        ];
        let d = dist(&[s]);
        let m = d.decide(None);
        assert_eq!(m.len(), 1);
        assert_eq!((m[0].a, m[0].b), (0, 1));
    }

    /// The real block's mutual best leaves the dustbins out: node 1,
    /// whose dustbin outweighs column 0, is paired with it; the operating
    /// point then keeps only the pairs at or above it, under any rule.
    #[test]
    fn mutual_real_leaves_the_dustbins_out_and_the_operating_point_cuts() {
        let s = vec![
            0.05, 0.9, 0.05, //
            0.3, 0.2, 0.5, //
            0.65, 0.1, 0.25,
        ];
        let mut d = dist(&[s]);
        let pairs = |d: &MatchDistribution, rule| -> Vec<(usize, usize)> {
            d.decide_with(rule, None)
                .iter()
                .map(|c| (c.a, c.b))
                .collect()
        };
        assert_eq!(pairs(&d, Decision::Mutual), [(0, 1)]);
        assert_eq!(pairs(&d, Decision::MutualReal), [(0, 1), (1, 0)]);
        d.min_probability = 0.3;
        assert_eq!(pairs(&d, Decision::MutualReal), [(0, 1), (1, 0)]);
        d.min_probability = 0.31;
        assert_eq!(pairs(&d, Decision::MutualReal), [(0, 1)]);
        d.min_probability = 0.95;
        assert!(pairs(&d, Decision::Mutual).is_empty());
    }

    /// Regression: the real block's mutual best at operating point 0
    /// paired nodes whose E[Y] is 0 (everything in the dustbins).
    #[test]
    fn mutual_real_never_decides_a_pair_of_probability_zero() {
        let s = vec![
            0.0, 1.0, //
            1.0, 0.0,
        ];
        let d = MatchDistribution::from_samples(1, 1, &[s]);
        assert!(d.decide_with(Decision::MutualReal, None).is_empty());
    }

    /// A temperature above 1 pulls probabilities towards 1/2 and lowers
    /// none across it; it changes the entropy, not the decision.
    #[test]
    fn temperature_calibrates_the_probability_not_the_decision() {
        assert_eq!(calibrated(0.8, 1.0), 0.8);
        assert!((calibrated(0.5, 2.0) - 0.5).abs() < 1e-12);
        let (hot, cold) = (calibrated(0.9, 2.0), calibrated(0.9, 0.5));
        assert!(0.5 < hot && hot < 0.9 && cold > 0.9, "{hot} {cold}");
        // logit(0.9) = ln 9; halved: sigmoid(ln 3) = 0.75.
        assert!((hot - 0.75).abs() < 1e-12);
        let s = vec![0.9, 0.0, 0.1, 0.0, 0.7, 0.3, 0.1, 0.3, 0.0];
        let mut d = dist(&[s]);
        let before = d.decide(None);
        d.temperature = 2.0;
        let after = d.decide(None);
        assert_eq!(before.len(), after.len());
        assert!((after[0].probability - 0.75).abs() < 1e-6);
        assert!(after[0].uncertainty > before[0].uncertainty);
    }

    #[test]
    fn uncertainty_split_and_thresholding() {
        // Two samples that disagree completely: each is certain (aleatoric
        // 0), their mean is a coin flip (total 1): all epistemic.
        let a = vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let b = vec![0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let d = dist(&[a.clone(), b]);
        assert!((d.total(0, 0) - 1.0).abs() < 1e-6);
        assert!(d.uncertainty(0, 0, UncertaintyKind::Aleatoric) < 1e-6);
        assert!((d.uncertainty(0, 0, UncertaintyKind::Epistemic) - 1.0).abs() < 1e-6);
        // A certain distribution keeps its pairs under any threshold.
        let sure = dist(&[a]);
        assert_eq!(sure.decide(Some((UncertaintyKind::Total, 0.7))).len(), 2);
        // A 0.6/0.4 pair: total entropy 0.971 bits, removed at lambda 0.7.
        let soft = vec![0.6, 0.0, 0.4, 0.0, 1.0, 0.0, 0.4, 0.0, 0.6];
        let d = dist(&[soft]);
        assert_eq!(d.decide(None).len(), 2);
        let kept = d.decide(Some((UncertaintyKind::Total, 0.7)));
        assert_eq!(kept.len(), 1);
        assert_eq!((kept[0].a, kept[0].b), (1, 1));
    }

    /// Thresholding applies to the uncertainty as it is: an unlikely
    /// mutual-best pair (p = 0.1, 0.47 bits) is kept at lambda 0.7 and
    /// removed at 0.4; nothing collapses at p = 0.5.
    #[test]
    fn an_unlikely_pair_is_thresholded_on_its_entropy() {
        // Row 0's best is column 0 at p = 0.1; everything else prefers
        // the dustbins.
        let s = vec![
            0.1, 0.0, 0.09, //
            0.0, 0.05, 0.95, //
            0.05, 0.95, 0.0,
        ];
        let d = dist(&[s]);
        let h = binary_entropy_bits(0.1);
        assert!((d.uncertainty(0, 0, UncertaintyKind::Total) - h).abs() < 1e-6);
        assert!(d.uncertainty(0, 0, UncertaintyKind::Epistemic).abs() < 1e-6);
        assert_eq!(d.decide(None).len(), 1);
        assert_eq!(d.decide(Some((UncertaintyKind::Total, 0.7))).len(), 1);
        assert!(d.decide(Some((UncertaintyKind::Total, 0.4))).is_empty());
    }

    /// Epistemic uncertainty is the mutual information: zero when every
    /// sample agrees (however uncertain each is), positive when they
    /// disagree, and total = aleatoric + epistemic on one scale.
    #[test]
    fn epistemic_is_zero_when_every_sample_agrees() {
        let soft = vec![0.6, 0.0, 0.4, 0.0, 1.0, 0.0, 0.4, 0.0, 0.6];
        let d = dist(&[soft.clone(), soft.clone(), soft]);
        assert!(d.uncertainty(0, 0, UncertaintyKind::Epistemic).abs() < 1e-6);
        let total = d.uncertainty(0, 0, UncertaintyKind::Total);
        assert!((total - binary_entropy_bits(0.6)).abs() < 1e-6);
        assert!((d.uncertainty(0, 0, UncertaintyKind::Aleatoric) - total).abs() < 1e-6);
        // Two samples at 0.9 and 0.3 (mean 0.6): same total, less
        // aleatoric, the rest epistemic.
        let hi = vec![0.9, 0.0, 0.1, 0.0, 1.0, 0.0, 0.1, 0.0, 0.9];
        let lo = vec![0.3, 0.0, 0.7, 0.0, 1.0, 0.0, 0.7, 0.0, 0.3];
        let d = dist(&[hi, lo]);
        let (t, a, e) = (
            d.uncertainty(0, 0, UncertaintyKind::Total),
            d.uncertainty(0, 0, UncertaintyKind::Aleatoric),
            d.uncertainty(0, 0, UncertaintyKind::Epistemic),
        );
        assert!((t - total).abs() < 1e-6);
        let mean_h = (binary_entropy_bits(0.9) + binary_entropy_bits(0.3)) / 2.0;
        assert!((a - mean_h).abs() < 1e-6, "{a} {mean_h}");
        assert!(e > 0.1 && (t - a - e).abs() < 1e-9, "{e}");
    }
}
