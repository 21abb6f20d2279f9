//! MOGM: learning-free multi-order graph matching. First order: appearance;
//! second order: edge lengths and edge directions (see [`super::affinity`]).
//! Solved by spectral matching (principal eigenvector of the affinity) and a
//! greedy one-to-one discretisation; candidates whose eigenvector entry is
//! below `min_score` of the largest stay unmatched ("no match").

use super::affinity::{self, AffinityParams};
use super::{Correspondence, MatchView, Matcher, Method, binary_entropy_bits};

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

    fn match_pair(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence> {
        let problem = affinity::build(first, second, &self.params);
        let x = affinity::principal_eigenvector(&problem.affinity);
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
            out.push(Correspondence {
                a,
                b,
                probability: x[c],
                uncertainty: binary_entropy_bits(x[c]),
            });
        }
        out.sort_by_key(|c| c.a);
        out
    }
}
