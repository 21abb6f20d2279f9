//! The plain learning-free graph matchers: spectral matching (Leordeanu &
//! Hebert 2005) and reweighted random walks (RRWM, Cho et al. 2010), on a
//! geometry-only affinity.
//!
//! A candidate is a pair (i, a) of a detection of the first vehicle and one
//! of the second with the same detected class; nothing else of their
//! appearance is read. Two candidates (i, a) and (j, b) (i != j, a != b)
//! have affinity `exp(-(|i-j| - |a-b|)^2 / (2 var))`, the edge lengths'
//! agreement over every pair of nodes (no graph, no range cut), `var` from
//! the four detections' covariances as for MOGM
//! ([`learning_free::build`]); the diagonal is 0. Both see the paper's
//! inputs only (no pose).
//!
//! Spectral: the affinity's principal eigenvector, scaled to max 1, as the
//! candidates' scores. RRWM: the random walk with Sinkhorn-reweighted jumps
//! exactly as pygmtools 0.6 implements it ([`rrwm`]), its scores scaled to
//! max 1. Both then take the one-to-one assignment of the largest total
//! score (Hungarian) and keep its pairs scoring at least `min_score`, the
//! one threshold validation chooses.

use nalgebra::{DMatrix, DVector};

use super::learning_free::{AffinityProblem, length_agreement, principal_eigenvector};
use super::{Correspondence, Identification, MatchView, Matcher, Method};
use crate::fusion::PoseEstimate;

/// The geometry-only affinity of the module docs.
pub fn plain_affinity(first: &MatchView, second: &MatchView) -> AffinityProblem {
    let (n, m) = (first.detections.len(), second.detections.len());
    let mut candidates = Vec::new();
    for (i, di) in first.detections.iter().enumerate() {
        for (a, da) in second.detections.iter().enumerate() {
            if di.appearance.class == da.appearance.class {
                candidates.push((i, a));
            }
        }
    }
    let affinity = length_agreement(first, second, &candidates, f64::INFINITY);
    AffinityProblem {
        candidates,
        affinity,
        n_first: n,
        n_second: m,
    }
}

/// The one-to-one assignment of the largest total score over the
/// candidates (scores scaled to max 1), its pairs below `min_score` left
/// out.
fn assign(problem: &AffinityProblem, scores: &[f64], min_score: f64) -> Identification {
    let (n, m) = (problem.n_first, problem.n_second);
    let mut gain = vec![0.0; n * m];
    let mut index = vec![usize::MAX; n * m];
    for (c, &(i, a)) in problem.candidates.iter().enumerate() {
        gain[i * m + a] = scores[c];
        index[i * m + a] = c;
    }
    let mut out = Vec::new();
    if let Ok((rows, cols)) = lsap::solve(n, m, &gain, true) {
        for (i, a) in rows.into_iter().zip(cols) {
            let c = index[i * m + a];
            if c == usize::MAX || scores[c] <= 0.0 || scores[c] < min_score {
                continue;
            }
            out.push(Correspondence::with_probability(i, a, scores[c]));
        }
    }
    out.sort_by_key(|c| c.a);
    Identification::matches_only(out)
}

/// Spectral matching on the plain affinity, Hungarian, a threshold.
pub struct Spectral {
    /// Share of the largest eigenvector entry a pair needs to be kept.
    pub min_score: f64,
}

impl Default for Spectral {
    fn default() -> Self {
        Self { min_score: 0.5 }
    }
}

impl Matcher for Spectral {
    fn method(&self) -> Method {
        Method::Spectral
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        _: &PoseEstimate,
    ) -> Identification {
        let problem = plain_affinity(first, second);
        let x = principal_eigenvector(&problem.affinity);
        assign(&problem, &x, self.min_score)
    }
}

/// RRWM's constants, pygmtools' defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RrwmParams {
    pub max_iter: usize,
    /// Sinkhorn iterations per jump (rows and columns alternately).
    pub sk_iter: usize,
    /// Weight of the reweighted jump.
    pub alpha: f64,
    /// Inflation of the scores before the Sinkhorn (a temperature 1/beta).
    pub beta: f64,
}

impl Default for RrwmParams {
    fn default() -> Self {
        Self {
            max_iter: 50,
            sk_iter: 20,
            alpha: 0.2,
            beta: 30.0,
        }
    }
}

/// RRWM on an `n1 x n2` assignment whose candidates `candidates` (pairs
/// (i, a)) have affinity `k` (symmetric, non-negative, `k x k`); every
/// other entry of the `n1 n2 x n1 n2` affinity is 0. Returns the soft
/// assignment `n1 x n2` (entries summing to 1), the computation of
/// pygmtools 0.6's `rrwm` (numpy backend) step for step: the affinity
/// divided by its largest row sum (plus 1e-5 times the smallest), a uniform
/// start, then up to `max_iter` rounds of a random-walk step (L1
/// normalised), a jump to the log-domain Sinkhorn of the scores inflated to
/// a maximum of `beta` (rows of the smaller side first), mixed in with
/// weight `alpha`, and L1 normalisation, until the change from the walk's
/// step is below 1e-5. One departure: where the walk step is all zero (no
/// two candidates agree), the walk keeps its state instead of dividing by
/// zero.
pub fn rrwm(
    candidates: &[(usize, usize)],
    k: &DMatrix<f64>,
    n1: usize,
    n2: usize,
    params: &RrwmParams,
) -> DMatrix<f64> {
    let cells = n1 * n2;
    if cells == 0 {
        return DMatrix::zeros(n1, n2);
    }
    // Column-major vectorisation, pygmtools' (index a * n1 + i).
    let cell = |(i, a): (usize, usize)| a * n1 + i;
    let row_sums: Vec<f64> = k.row_iter().map(|r| r.sum()).collect();
    let d_max = row_sums.iter().cloned().fold(0.0, f64::max);
    let d_min = if candidates.len() < cells {
        0.0 // the rows of non-candidates
    } else {
        row_sums.iter().cloned().fold(f64::INFINITY, f64::min)
    };
    let scale = d_max + d_min * 1e-5;
    let k = if scale > 0.0 { k / scale } else { k.clone() };
    let mut v = DVector::from_element(cells, 1.0 / cells as f64);
    for _ in 0..params.max_iter {
        let on_candidates =
            DVector::from_iterator(candidates.len(), candidates.iter().map(|&c| v[cell(c)]));
        let walked = &k * on_candidates;
        let mut step = DVector::zeros(cells);
        for (c, &pair) in candidates.iter().enumerate() {
            step[cell(pair)] = walked[c];
        }
        let l1 = step.abs().sum();
        let last = if l1 > 0.0 { step.clone() } else { v.clone() };
        if l1 > 0.0 {
            v = step / l1;
        }
        let s = DMatrix::from_column_slice(n1, n2, v.as_slice());
        let max = s.max();
        let s = if max > 0.0 {
            s * (params.beta / max)
        } else {
            s
        };
        let jump = log_sinkhorn(&s, params.sk_iter);
        v = DVector::from_column_slice(jump.as_slice()) * params.alpha + v * (1.0 - params.alpha);
        let l1 = v.abs().sum();
        v /= l1;
        if (&v - &last).norm() < 1e-5 {
            break;
        }
    }
    DMatrix::from_column_slice(n1, n2, v.as_slice())
}

/// pygmtools' Sinkhorn on log-scores `s` (tau 1): with the smaller side as
/// rows, `iters` alternate normalisations, rows first.
fn log_sinkhorn(s: &DMatrix<f64>, iters: usize) -> DMatrix<f64> {
    let transposed = s.ncols() < s.nrows();
    let mut log = if transposed { s.transpose() } else { s.clone() };
    let lse = |xs: &mut dyn Iterator<Item = f64>| {
        let xs: Vec<f64> = xs.collect();
        let max = xs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        max + xs.iter().map(|x| (x - max).exp()).sum::<f64>().ln()
    };
    for it in 0..iters {
        if it % 2 == 0 {
            for r in 0..log.nrows() {
                let z = lse(&mut log.row(r).iter().cloned());
                log.row_mut(r).add_scalar_mut(-z);
            }
        } else {
            for c in 0..log.ncols() {
                let z = lse(&mut log.column(c).iter().cloned());
                log.column_mut(c).add_scalar_mut(-z);
            }
        }
    }
    let p = log.map(f64::exp);
    if transposed { p.transpose() } else { p }
}

/// RRWM on the plain affinity, Hungarian, a threshold.
pub struct Rrwm {
    /// Share of the largest soft-assignment entry a pair needs to be kept.
    pub min_score: f64,
    pub params: RrwmParams,
}

impl Default for Rrwm {
    fn default() -> Self {
        Self {
            min_score: 0.5,
            params: RrwmParams::default(),
        }
    }
}

impl Matcher for Rrwm {
    fn method(&self) -> Method {
        Method::Rrwm
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        _: &PoseEstimate,
    ) -> Identification {
        let problem = plain_affinity(first, second);
        if problem.candidates.is_empty() {
            return Identification::matches_only(Vec::new());
        }
        let x = rrwm(
            &problem.candidates,
            &problem.affinity,
            problem.n_first,
            problem.n_second,
            &self.params,
        );
        let raw: Vec<f64> = problem.candidates.iter().map(|&(i, a)| x[(i, a)]).collect();
        let max = raw.iter().cloned().fold(0.0, f64::max);
        let scores: Vec<f64> = if max > 0.0 {
            raw.iter().map(|s| s / max).collect()
        } else {
            raw
        };
        assign(&problem, &scores, self.min_score)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// pygmtools 0.6's `rrwm` and `sm` on seeded instances, written by
    /// `tools/pygmtools_reference/fixture.py`.
    const REFERENCE: &str = include_str!("spectral_reference.json");

    #[derive(serde::Deserialize)]
    struct Reference {
        instances: Vec<Instance>,
    }

    #[derive(serde::Deserialize)]
    struct Instance {
        n1: usize,
        n2: usize,
        candidates: Vec<(usize, usize)>,
        k_column_major: Vec<f64>,
        rrwm_row_major: Vec<f64>,
        sm_row_major: Vec<f64>,
    }

    impl Instance {
        /// The candidates' block of the full affinity.
        fn affinity(&self) -> DMatrix<f64> {
            let cells = self.n1 * self.n2;
            let cell = |(i, a): (usize, usize)| a * self.n1 + i;
            let k = self.candidates.len();
            DMatrix::from_fn(k, k, |u, v| {
                self.k_column_major[cell(self.candidates[u]) * cells + cell(self.candidates[v])]
            })
        }
    }

    #[test]
    fn rrwm_and_spectral_agree_with_pygmtools() {
        let reference: Reference = serde_json::from_str(REFERENCE).unwrap();
        assert_eq!(reference.instances.len(), 6);
        for (n, inst) in reference.instances.iter().enumerate() {
            let k = inst.affinity();
            let x = rrwm(
                &inst.candidates,
                &k,
                inst.n1,
                inst.n2,
                &RrwmParams::default(),
            );
            for i in 0..inst.n1 {
                for a in 0..inst.n2 {
                    let theirs = inst.rrwm_row_major[i * inst.n2 + a];
                    assert!(
                        (x[(i, a)] - theirs).abs() < 1e-9,
                        "instance {n}, ({i}, {a}): rrwm {} vs pygmtools {theirs}",
                        x[(i, a)]
                    );
                }
            }
            // Spectral: the same direction (both scaled to max 1).
            let ours = principal_eigenvector(&k);
            let theirs: Vec<f64> = inst
                .candidates
                .iter()
                .map(|&(i, a)| inst.sm_row_major[i * inst.n2 + a])
                .collect();
            let max = theirs.iter().cloned().fold(0.0, f64::max);
            for (c, (o, t)) in ours.iter().zip(&theirs).enumerate() {
                assert!(
                    (o - t / max).abs() < 1e-4,
                    "instance {n}, candidate {c}: {o} vs {}",
                    t / max
                );
            }
        }
    }

    #[test]
    fn rrwm_without_agreeing_candidates_keeps_its_uniform_start() {
        // Two candidates that conflict: no affinity anywhere.
        let x = rrwm(
            &[(0, 0), (0, 1)],
            &DMatrix::zeros(2, 2),
            1,
            2,
            &RrwmParams::default(),
        );
        assert!(x.iter().all(|v| v.is_finite()));
        assert!((x.sum() - 1.0).abs() < 1e-12);
        assert!((x[(0, 0)] - x[(0, 1)]).abs() < 1e-12);
    }
}
