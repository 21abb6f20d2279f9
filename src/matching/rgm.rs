//! RGM: learning-free regularised graph matching that allows non-covisible
//! objects. Maximises `x^T M x - lambda * sum(x)` over one-to-one partial
//! assignments `x` (the L1 term makes "no match" the better choice for a
//! candidate unsupported by the rest of the graph) with the integer
//! projected fixed point method (IPFP, Leordeanu et al. 2009): each step
//! solves the linearised problem exactly (optimal partial assignment with
//! the `lambda` price per match, `lsap`) and line-searches towards it.

use nalgebra::DVector;

use super::affinity::{self, AffinityParams, AffinityProblem};
use super::{Correspondence, MatchView, Matcher, Method, binary_entropy_bits};

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

fn objective(m: &nalgebra::DMatrix<f64>, x: &DVector<f64>, lambda: f64) -> f64 {
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

    fn match_pair(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence> {
        let problem = affinity::build(first, second, &self.params);
        let k = problem.candidates.len();
        if k == 0 {
            return Vec::new();
        }
        let mm = &problem.affinity;
        let mut x = DVector::from_vec(affinity::principal_eigenvector(mm));
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
                let p = x[c].clamp(0.0, 1.0);
                Correspondence {
                    a,
                    b,
                    probability: p,
                    uncertainty: binary_entropy_bits(p),
                }
            })
            .collect();
        out.sort_by_key(|c| c.a);
        out
    }
}
