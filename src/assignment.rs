//! The optimal one-to-one assignment with gates (Jonker-Volgenant through
//! `lsap`): the matchers' decision on a pair likelihood and the trackers'
//! data association use the same solver.

/// The optimal one-to-one assignment of an `n x m` row-major score matrix
/// (`None`: gated): as many pairs as the gates allow, and among those the
/// largest total score (Jonker-Volgenant, `lsap`). Returns the pairs
/// `(i, j)`, gated ones never, sorted by `i`. On a matcher's pair
/// log-likelihood (`matching::likelihood`)
/// this is GPS+appearance Hungarian's decision; on a tracker's
/// Mahalanobis scores, its data association.
pub fn assign(n: usize, m: usize, scores: &[Option<f64>]) -> Vec<(usize, usize)> {
    debug_assert_eq!(scores.len(), n * m);
    if n == 0 || m == 0 {
        return Vec::new();
    }
    // Cost = -2 score (the "-2 ln L" of a likelihood). A gated pair costs
    // more than any set of pairs that pass, so the solver never trades a
    // pair that passes for a gated one.
    let costs = || scores.iter().flatten().map(|s| -2.0 * s);
    let (lo, hi) = costs().fold((0.0f64, 0.0f64), |(lo, hi), c| (lo.min(c), hi.max(c)));
    let blocked = (hi - lo + 1.0) * (n.min(m) as f64 + 1.0) + hi.abs();
    let cost: Vec<f64> = scores
        .iter()
        .map(|s| s.map_or(blocked, |s| -2.0 * s))
        .collect();
    let Ok((rows, cols)) = lsap::solve(n, m, &cost, false) else {
        return Vec::new();
    };
    let mut out: Vec<(usize, usize)> = rows
        .into_iter()
        .zip(cols)
        .filter(|&(i, j)| scores[i * m + j].is_some())
        .collect();
    out.sort_unstable();
    out
}
