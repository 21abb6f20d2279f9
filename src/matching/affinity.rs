//! Learning-free graph matching on a pairwise affinity matrix: the shared
//! machinery of MOGM and RGM.
//!
//! A candidate is a pair (i, a) of a detection of the first vehicle and one
//! of the second whose appearance is compatible. The affinity between two
//! candidates (i, a) and (j, b) scores how well the edge i-j agrees with the
//! edge a-b in length (second order: distances) and in direction (the edge's
//! bearing in the world, from each vehicle's reported heading: GPS heading
//! noise is 0.2 deg, position noise does not enter). The diagonal holds the
//! appearance similarity (first order). Nothing here uses the vehicles'
//! reported positions: the graph structure must carry the match.

use nalgebra::DMatrix;

use super::MatchView;
use crate::geometry::{Vec2, wrap_angle};
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
}

impl Default for AffinityParams {
    fn default() -> Self {
        Self {
            min_appearance: 0.05,
            max_edge_m: 60.0,
        }
    }
}

/// Appearance similarity in [0, 1]: class agreement (confusable classes
/// count a little), colour and size closeness.
pub fn appearance_similarity(x: &Appearance, y: &Appearance) -> f64 {
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

/// An edge between two detections as seen in the world: length, bearing
/// (reported heading plus the edge's direction in the ego frame), and the
/// variances of both from the two detections' covariances.
struct EdgeView {
    length_m: f64,
    bearing_rad: f64,
    length_var_m2: f64,
    bearing_var_rad2: f64,
}

fn edge(p: &Detection, q: &Detection, heading_rad: f64) -> EdgeView {
    let d = q.position_m - p.position_m;
    let length_m = d.norm().max(1e-3);
    let u = d / length_m;
    let perp = Vec2::new(-u.y, u.x);
    let cov = p.cov_m2 + q.cov_m2;
    EdgeView {
        length_m,
        bearing_rad: heading_rad + d.y.atan2(d.x),
        length_var_m2: (u.transpose() * cov * u)[(0, 0)],
        bearing_var_rad2: (perp.transpose() * cov * perp)[(0, 0)] / (length_m * length_m),
    }
}

pub fn build(first: &MatchView, second: &MatchView, params: &AffinityParams) -> AffinityProblem {
    let (n, m) = (first.detections.len(), second.detections.len());
    let mut candidates = Vec::new();
    let mut unary = Vec::new();
    for (i, di) in first.detections.iter().enumerate() {
        for (a, da) in second.detections.iter().enumerate() {
            let s = appearance_similarity(&di.appearance, &da.appearance);
            if s >= params.min_appearance {
                candidates.push((i, a));
                unary.push(s);
            }
        }
    }
    let k = candidates.len();
    let mut affinity = DMatrix::zeros(k, k);
    let h1 = first.pose_reported.heading_rad();
    let h2 = second.pose_reported.heading_rad();
    let heading_var =
        first.pose_noise.heading_sigma_rad.powi(2) + second.pose_noise.heading_sigma_rad.powi(2);
    for u in 0..k {
        affinity[(u, u)] = unary[u];
        let (i, a) = candidates[u];
        for v in (u + 1)..k {
            let (j, b) = candidates[v];
            if i == j || a == b {
                continue; // one-to-one: conflicting candidates never agree
            }
            let e1 = edge(&first.detections[i], &first.detections[j], h1);
            let e2 = edge(&second.detections[a], &second.detections[b], h2);
            if e1.length_m > params.max_edge_m || e2.length_m > params.max_edge_m {
                continue;
            }
            let length_var = e1.length_var_m2 + e2.length_var_m2;
            let length = (-(e1.length_m - e2.length_m).powi(2) / (2.0 * length_var)).exp();
            let bearing_var = e1.bearing_var_rad2 + e2.bearing_var_rad2 + heading_var;
            let angle =
                (-wrap_angle(e1.bearing_rad - e2.bearing_rad).powi(2) / (2.0 * bearing_var)).exp();
            let w = length * angle * (unary[u] * unary[v]).sqrt();
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

/// Principal eigenvector of the (non-negative) affinity by power iteration,
/// scaled to max 1 (spectral matching, Leordeanu & Hebert 2005).
pub fn principal_eigenvector(affinity: &DMatrix<f64>) -> Vec<f64> {
    let k = affinity.nrows();
    if k == 0 {
        return Vec::new();
    }
    let mut x = nalgebra::DVector::from_element(k, 1.0 / (k as f64).sqrt());
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
