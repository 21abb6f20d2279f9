//! The learning-free graph matchers, MOGM and RGM, and the pairwise
//! affinity they share.
//!
//! A candidate is a pair (i, a) of a detection of the first vehicle and one
//! of the second whose appearance is compatible. The affinity between two
//! candidates (i, a) and (j, b) scores how well the edge i-j agrees with the
//! edge a-b in length (second order: distances, which the unknown rigid
//! motion between the two body frames leaves unchanged). The diagonal holds
//! the appearance similarity (first order). Both see the paper's inputs
//! only: nothing here uses the vehicles' reported positions or headings
//! (an edge's direction would need the heading to compare across frames);
//! the graph structure must carry the match.
//!
//! MOGM: learning-free multi-order graph matching. First order: appearance;
//! second order: edge lengths (see the affinity above).
//! Solved by spectral matching (principal eigenvector of the affinity) and a
//! greedy one-to-one discretisation; candidates whose eigenvector entry is
//! below `min_score` of the largest stay unmatched ("no match").
//!
//! RGM: learning-free regularised graph matching that allows non-covisible
//! objects. Maximises `x^T M x - lambda * sum(x)` over one-to-one partial
//! assignments `x` (the L1 term makes "no match" the better choice for a
//! candidate unsupported by the rest of the graph) with the integer
//! projected fixed point method (IPFP, Leordeanu et al. 2009): each step
//! solves the linearised problem exactly (optimal partial assignment with
//! the `lambda` price per match, `lsap`) and line-searches towards it.

use nalgebra::{DMatrix, DVector};

use super::{Correspondence, Identification, MatchView, Matcher, Method};
use crate::fusion::PoseEstimate;
use crate::sensor::{Appearance, Detection};

/// Constants of the affinity, fixed a priori (not fitted to test data).
/// Disagreement scales come from the detections' own covariances.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffinityParams {
    /// Candidates with appearance similarity below this are not considered.
    pub min_appearance: f64,
    /// Edges longer than this are ignored (far pairs carry little
    /// structure and much noise).
    pub max_edge_m: f64,
    /// The power of the learned descriptors' likelihood ratio in the
    /// appearance similarity (1: the ratio as fitted; 0: descriptors
    /// unused), chosen on validation runs with the threshold.
    pub descriptor_weight: f64,
}

impl Default for AffinityParams {
    fn default() -> Self {
        Self {
            min_appearance: 0.05,
            max_edge_m: 60.0,
            descriptor_weight: 1.0,
        }
    }
}

/// Appearance similarity: class agreement (confusable classes count a
/// little), colour and size closeness, in [0, 1]; where both carry a
/// learned descriptor, times its calibrated likelihood ratio
/// ([`crate::sensor::Descriptor::likelihood_ratio`], which may exceed 1).
pub fn appearance_similarity(x: &Appearance, y: &Appearance) -> f64 {
    weighted_similarity(x, y, 1.0)
}

/// [`appearance_similarity`] with the descriptors' likelihood ratio raised
/// to `descriptor_weight`.
pub fn weighted_similarity(x: &Appearance, y: &Appearance, descriptor_weight: f64) -> f64 {
    let learned = match (&x.descriptor, &y.descriptor) {
        (Some(a), Some(b)) if descriptor_weight != 0.0 => {
            a.likelihood_ratio(b).powf(descriptor_weight)
        }
        _ => 1.0,
    };
    learned * look_similarity(x, y)
}

/// The class, colour and size part of [`appearance_similarity`].
fn look_similarity(x: &Appearance, y: &Appearance) -> f64 {
    let class = if x.class == y.class {
        1.0
    } else if x.class.confusable() == y.class || y.class.confusable() == x.class {
        0.3
    } else {
        0.02
    };
    let dc2: f64 = (0..3)
        .map(|k| (x.colour_rgb[k] - y.colour_rgb[k]).powi(2))
        .sum();
    let colour = (-dc2 / (2.0 * 0.2f64.powi(2))).exp();
    let rel = |p: f64, q: f64| (p - q) / (0.5 * (p + q)).max(0.1);
    let ds2 = rel(x.length_m, y.length_m).powi(2)
        + rel(x.width_m, y.width_m).powi(2)
        + rel(x.height_m, y.height_m).powi(2);
    let size = (-ds2 / (2.0 * 0.25f64.powi(2))).exp();
    class * (0.3 + 0.7 * colour) * (0.3 + 0.7 * size)
}

/// The candidates and their affinity matrix.
pub struct AffinityProblem {
    /// (i, a) per candidate.
    pub candidates: Vec<(usize, usize)>,
    /// Symmetric, non-negative; diagonal = appearance similarity.
    pub affinity: DMatrix<f64>,
    pub n_first: usize,
    pub n_second: usize,
}

/// An edge between two detections of one vehicle: its length and the
/// variance of the length from the two detections' covariances.
struct EdgeView {
    length_m: f64,
    length_var_m2: f64,
}

fn edge(p: &Detection, q: &Detection) -> EdgeView {
    let d = q.position_m - p.position_m;
    let length_m = d.norm().max(1e-3);
    let u = d / length_m;
    let cov = p.cov_m2 + q.cov_m2;
    EdgeView {
        length_m,
        length_var_m2: (u.transpose() * cov * u)[(0, 0)],
    }
}

pub fn build(first: &MatchView, second: &MatchView, params: &AffinityParams) -> AffinityProblem {
    let (n, m) = (first.detections.len(), second.detections.len());
    let mut candidates = Vec::new();
    let mut unary = Vec::new();
    for (i, di) in first.detections.iter().enumerate() {
        for (a, da) in second.detections.iter().enumerate() {
            let s = weighted_similarity(&di.appearance, &da.appearance, params.descriptor_weight);
            if s >= params.min_appearance {
                candidates.push((i, a));
                unary.push(s);
            }
        }
    }
    let mut affinity = length_agreement(first, second, &candidates, params.max_edge_m);
    for (u, &s) in unary.iter().enumerate() {
        affinity[(u, u)] = s;
        for v in (u + 1)..unary.len() {
            let w = affinity[(u, v)] * (s * unary[v]).sqrt();
            affinity[(u, v)] = w;
            affinity[(v, u)] = w;
        }
    }
    AffinityProblem {
        candidates,
        affinity,
        n_first: n,
        n_second: m,
    }
}

/// How well the edges i-j and a-b of each two candidates (i, a), (j, b)
/// agree in length, `exp(-(|i-j| - |a-b|)^2 / (2 var))` with `var` from
/// the four detections' covariances; 0 on the diagonal, between
/// conflicting candidates (i = j or a = b) and where either edge is longer
/// than `max_edge_m`.
pub(super) fn length_agreement(
    first: &MatchView,
    second: &MatchView,
    candidates: &[(usize, usize)],
    max_edge_m: f64,
) -> DMatrix<f64> {
    let k = candidates.len();
    let mut agreement = DMatrix::zeros(k, k);
    for u in 0..k {
        let (i, a) = candidates[u];
        for v in (u + 1)..k {
            let (j, b) = candidates[v];
            if i == j || a == b {
                continue; // one-to-one: conflicting candidates never agree
            }
            let e1 = edge(&first.detections[i], &first.detections[j]);
            let e2 = edge(&second.detections[a], &second.detections[b]);
            if e1.length_m > max_edge_m || e2.length_m > max_edge_m {
                continue;
            }
            let length_var = e1.length_var_m2 + e2.length_var_m2;
            let length = (-(e1.length_m - e2.length_m).powi(2) / (2.0 * length_var)).exp();
            agreement[(u, v)] = length;
            agreement[(v, u)] = length;
        }
    }
    agreement
}

/// Principal eigenvector of the (non-negative) affinity by power iteration,
/// scaled to max 1 (spectral matching, Leordeanu & Hebert 2005).
pub fn principal_eigenvector(affinity: &DMatrix<f64>) -> Vec<f64> {
    let k = affinity.nrows();
    if k == 0 {
        return Vec::new();
    }
    let mut x = DVector::from_element(k, 1.0 / (k as f64).sqrt());
    for _ in 0..100 {
        let y = affinity * &x;
        let norm = y.norm();
        if norm <= 0.0 {
            break;
        }
        let y = y / norm;
        let delta = (&y - &x).norm();
        x = y;
        if delta < 1e-10 {
            break;
        }
    }
    let max = x.iter().cloned().fold(0.0, f64::max);
    if max > 0.0 {
        x.iter().map(|v| v / max).collect()
    } else {
        vec![0.0; k]
    }
}

// ---------------------------------------------------------------------------
// MOGM
// ---------------------------------------------------------------------------

pub struct Mogm {
    pub params: AffinityParams,
    /// Share of the largest eigenvector entry a pair needs to be kept.
    pub min_score: f64,
}

impl Default for Mogm {
    fn default() -> Self {
        Self {
            params: AffinityParams::default(),
            min_score: 0.3,
        }
    }
}

impl Matcher for Mogm {
    fn method(&self) -> Method {
        Method::Mogm
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        _: &PoseEstimate,
    ) -> Identification {
        let problem = build(first, second, &self.params);
        let x = principal_eigenvector(&problem.affinity);
        let mut order: Vec<usize> = (0..x.len()).collect();
        // Stable order: by score, then by candidate index.
        order.sort_by(|&p, &q| x[q].total_cmp(&x[p]).then(p.cmp(&q)));
        let mut used_a = vec![false; problem.n_first];
        let mut used_b = vec![false; problem.n_second];
        let mut out = Vec::new();
        for c in order {
            if x[c] < self.min_score {
                break;
            }
            let (a, b) = problem.candidates[c];
            if used_a[a] || used_b[b] {
                continue;
            }
            used_a[a] = true;
            used_b[b] = true;
            out.push(Correspondence::with_probability(a, b, x[c]));
        }
        out.sort_by_key(|c| c.a);
        Identification::matches_only(out)
    }
}

// ---------------------------------------------------------------------------
// RGM
// ---------------------------------------------------------------------------

pub struct Rgm {
    pub params: AffinityParams,
    /// Price of one match in units of affinity. Above the largest possible
    /// appearance similarity (1), so that appearance alone never pays for a
    /// match: a pair needs support from consistent edges.
    pub lambda: f64,
}

impl Default for Rgm {
    fn default() -> Self {
        Self {
            params: AffinityParams::default(),
            lambda: 1.2,
        }
    }
}

fn objective(m: &DMatrix<f64>, x: &DVector<f64>, lambda: f64) -> f64 {
    x.dot(&(m * x)) - lambda * x.sum()
}

/// The best one-to-one partial assignment for per-candidate gains, each match
/// costing `lambda`; as an indicator vector over the candidates.
fn project(problem: &AffinityProblem, gains: &DVector<f64>, lambda: f64) -> DVector<f64> {
    let (n, m) = (problem.n_first, problem.n_second);
    let mut gain = vec![0.0; n * m];
    let mut index = vec![usize::MAX; n * m];
    for (c, &(i, a)) in problem.candidates.iter().enumerate() {
        gain[i * m + a] = (gains[c] - lambda).max(0.0);
        index[i * m + a] = c;
    }
    let mut b = DVector::zeros(problem.candidates.len());
    if let Ok((rows, cols)) = lsap::solve(n, m, &gain, true) {
        for (i, a) in rows.into_iter().zip(cols) {
            if gain[i * m + a] > 0.0 && index[i * m + a] != usize::MAX {
                b[index[i * m + a]] = 1.0;
            }
        }
    }
    b
}

impl Matcher for Rgm {
    fn method(&self) -> Method {
        Method::Rgm
    }

    fn identify_with(
        &self,
        first: &MatchView,
        second: &MatchView,
        _: &PoseEstimate,
    ) -> Identification {
        let problem = build(first, second, &self.params);
        let k = problem.candidates.len();
        if k == 0 {
            return Identification::matches_only(Vec::new());
        }
        let mm = &problem.affinity;
        let mut x = DVector::from_vec(principal_eigenvector(mm));
        let mut best = DVector::zeros(k);
        let mut best_score = 0.0; // the empty assignment
        for _ in 0..50 {
            // Gradient of the objective is 2 M x - lambda; the linearised
            // problem ranks candidates by (M x) with price lambda / 2.
            let gains = mm * &x;
            let b = project(&problem, &gains, self.lambda / 2.0);
            let score = objective(mm, &b, self.lambda);
            if score > best_score {
                best_score = score;
                best = b.clone();
            }
            let d = &b - &x;
            let slope = 2.0 * x.dot(&(mm * &d)) - self.lambda * d.sum();
            let curve = 2.0 * d.dot(&(mm * &d));
            let t = if curve >= 0.0 {
                1.0
            } else {
                (-slope / curve).clamp(0.0, 1.0)
            };
            let step = &d * t;
            x += &step;
            if step.norm() < 1e-9 {
                break;
            }
        }
        let mut out: Vec<Correspondence> = (0..k)
            .filter(|&c| best[c] > 0.5)
            .map(|c| {
                let (a, b) = problem.candidates[c];
                // Confidence: the relaxed solution's weight on this pair.
                Correspondence::with_probability(a, b, x[c].clamp(0.0, 1.0))
            })
            .collect();
        out.sort_by_key(|c| c.a);
        Identification::matches_only(out)
    }
}
