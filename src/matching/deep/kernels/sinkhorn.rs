//! Sinkhorn with a dustbin row and column (paper Eq. 4 with "no match",
//! as SuperGlue) for inference on one pair without tensors, in the
//! scaling domain ([`sinkhorn_probabilities`]), falling back to the log
//! domain where the scaling kernel underflows. The iterations of the
//! log-domain tensor version that training differentiates
//! ([`crate::matching::deep::train::sinkhorn::log_sinkhorn`]), which the
//! tests hold it to.

/// The score of a gated or padded entry, in the log domain: its
/// probability under Sinkhorn is `exp(-1e4)`, zero in `f32`.
pub(crate) const BLOCKED: f32 = -1.0e4;

/// Samples normalised side by side, one in each lane of a register.
const LANES: usize = 4;

/// One value of each of [`LANES`] samples.
type Lanes = [f64; LANES];

/// `out[c] = sum_r m[r, c] weights[r]`, lane by lane, for the row-major
/// `m` (`weights.len()` rows of `out.len()`), each sum in order of `r`
/// from 0 (the same bits as a sequential sum of one sample), 4 columns
/// at a time held in registers.
#[inline(always)]
fn weighted_rows(m: &[Lanes], weights: &[Lanes], out: &mut [Lanes]) {
    let width = out.len();
    let mut base = 0;
    while base + 4 <= width {
        columns::<4>(m, weights, base, out);
        base += 4;
    }
    while base < width {
        columns::<1>(m, weights, base, out);
        base += 1;
    }
}

/// [`weighted_rows`] for the `B` columns from `base`.
#[inline(always)]
fn columns<const B: usize>(m: &[Lanes], weights: &[Lanes], base: usize, out: &mut [Lanes]) {
    let width = out.len();
    let mut acc = [[0f64; LANES]; B];
    for (r, w) in weights.iter().enumerate() {
        let row = &m[r * width + base..r * width + base + B];
        for (a, x) in acc.iter_mut().zip(row) {
            for l in 0..LANES {
                a[l] += x[l] * w[l];
            }
        }
    }
    out[base..base + B].copy_from_slice(&acc);
}

/// [`log_sinkhorn`] for inference, one pair, without tensors or
/// gradients: the same iterations in the scaling domain, in f64. `scores`
/// holds T row-major `N1 x N2` blocks (`-inf` where gated); `dust` each
/// node's "no match" score; the result holds T row-major `(N1 + 1) x (N2
/// + 1)` assignments (probabilities, not logs).
///
/// With `K = exp(z - rowmax)` (every row of the padded scores `z` keeps
/// an entry 1), `u = mu / K v` and `v = nu / K^T u` are `exp` of the
/// log-domain potentials up to the row shift, so `P = u K v / exp(norm)`
/// is the log-domain result up to rounding, with one `exp` per entry
/// instead of two per entry and iteration.
///
/// Four samples go through the iterations side by side, one per lane
/// (the last group's spare lanes on a kernel of ones, then dropped): each
/// sample's arithmetic is its own, in the order one sample alone takes.
#[multiversion::multiversion(targets("x86_64+avx+avx2"))]
pub(crate) fn sinkhorn_probabilities(
    scores: &[f64],
    [t, n1, n2]: [usize; 3],
    dust: [&[f64]; 2],
    corner: f64,
    iters: usize,
) -> Vec<f32> {
    debug_assert_eq!(scores.len(), t * n1 * n2);
    let (rows, cols) = (n1 + 1, n2 + 1);
    let total = (n1 + n2) as f64;
    let mu = |i: usize| {
        if i == n1 {
            n2 as f64 / total
        } else {
            1.0 / total
        }
    };
    let nu = |j: usize| {
        if j == n2 {
            n1 as f64 / total
        } else {
            1.0 / total
        }
    };
    let mut out = Vec::with_capacity(t * rows * cols);
    let ones = [1f64; LANES];
    let (mut kernel, mut kernel_t) = (vec![ones; rows * cols], vec![ones; rows * cols]);
    let (mut u, mut v) = (vec![[0f64; LANES]; rows], vec![ones; cols]);
    let mut column_sums = vec![[0f64; LANES]; cols];
    for first in (0..t).step_by(LANES) {
        let lanes = LANES.min(t - first);
        for lane in 0..LANES {
            if lane >= lanes {
                kernel.iter_mut().for_each(|k| k[lane] = 1.0);
                continue;
            }
            let sample = first + lane;
            let block = &scores[sample * n1 * n2..(sample + 1) * n1 * n2];
            for i in 0..rows {
                let z = |j: usize| match (i < n1, j < n2) {
                    (true, true) => block[i * n2 + j],
                    (true, false) => dust[0][i],
                    (false, true) => dust[1][j],
                    (false, false) => corner,
                };
                let row_max = (0..cols).map(z).fold(f64::NEG_INFINITY, f64::max);
                for j in 0..cols {
                    kernel[i * cols + j][lane] = (z(j) - row_max).exp();
                }
            }
        }
        for (i, row) in kernel.chunks_exact(cols).enumerate() {
            for (j, k) in row.iter().enumerate() {
                kernel_t[j * rows + i] = *k;
            }
        }
        v.fill(ones);
        for _ in 0..iters {
            // u_i = sum_j K_ij v_j, from K's transpose.
            weighted_rows(&kernel_t, &v, &mut u);
            for (i, ui) in u.iter_mut().enumerate() {
                let m = mu(i);
                ui.iter_mut().for_each(|x| *x = m / *x);
            }
            weighted_rows(&kernel, &u, &mut column_sums);
            for (j, (vj, sums)) in v.iter_mut().zip(&column_sums).enumerate() {
                let m = nu(j);
                for (x, c) in vj.iter_mut().zip(sums) {
                    *x = m / c;
                }
            }
        }
        for lane in 0..lanes {
            let at = out.len();
            for (row, ui) in kernel.chunks_exact(cols).zip(&u) {
                out.extend(
                    row.iter()
                        .zip(&v)
                        .map(|(k, vj)| (ui[lane] * k[lane] * vj[lane] * total) as f32),
                );
            }
            // Scores far apart (hundreds of nats) underflow the kernel to
            // 0 where the plan needs mass: that sample again in the log
            // domain, which no spread of scores can break.
            if out[at..].iter().any(|p| !p.is_finite()) {
                let sample = first + lane;
                let block = &scores[sample * n1 * n2..(sample + 1) * n1 * n2];
                let p = log_domain_probabilities(block, [n1, n2], dust, corner, iters);
                out.truncate(at);
                out.extend(p.iter().map(|&x| x as f32));
            }
        }
    }
    out
}

/// One sample of [`sinkhorn_probabilities`] in the log domain, as
/// [`log_sinkhorn`] iterates (in f64, without tensors): the `(N1 + 1) x
/// (N2 + 1)` assignment, row-major. Every row and column holds its
/// finite dustbin, so no potential becomes infinite whatever the spread
/// of the scores.
fn log_domain_probabilities(
    block: &[f64],
    [n1, n2]: [usize; 2],
    dust: [&[f64]; 2],
    corner: f64,
    iters: usize,
) -> Vec<f64> {
    let (rows, cols) = (n1 + 1, n2 + 1);
    let z = |i: usize, j: usize| match (i < n1, j < n2) {
        (true, true) => block[i * n2 + j],
        (true, false) => dust[0][i],
        (false, true) => dust[1][j],
        (false, false) => corner,
    };
    let ln_total = ((n1 + n2) as f64).ln();
    let log_mu = |i: usize| if i == n1 { (n2 as f64).ln() } else { 0.0 } - ln_total;
    let log_nu = |j: usize| if j == n2 { (n1 as f64).ln() } else { 0.0 } - ln_total;
    let lse = |x: &mut dyn Iterator<Item = f64>| {
        let x: Vec<f64> = x.collect();
        let m = x.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if m == f64::NEG_INFINITY {
            return m;
        }
        m + x.iter().map(|v| (v - m).exp()).sum::<f64>().ln()
    };
    let (mut u, mut v) = (vec![0.0; rows], vec![0.0; cols]);
    for _ in 0..iters {
        for (i, ui) in u.iter_mut().enumerate() {
            *ui = log_mu(i) - lse(&mut (0..cols).map(|j| z(i, j) + v[j]));
        }
        for (j, vj) in v.iter_mut().enumerate() {
            *vj = log_nu(j) - lse(&mut (0..rows).map(|i| z(i, j) + u[i]));
        }
    }
    (0..rows)
        .flat_map(|i| (0..cols).map(move |j| (i, j)))
        .map(|(i, j)| (z(i, j) + u[i] + v[j] + ln_total).exp())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn scores_hundreds_of_nats_apart_give_a_finite_plan() {
        let (n1, n2) = (4, 10);
        let scores = vec![f64::NEG_INFINITY; n1 * n2];
        let d1 = [-7.67, -11.6, -14.5, 217.6];
        let d2 = [
            338.9, 265.6, -9.68, -11.5, -10.8, -11.0, 141.6, 332.7, 294.0, 708.2,
        ];
        let p = sinkhorn_probabilities(&scores, [1, n1, n2], [&d1, &d2], -2.84, 100);
        assert!(p.iter().all(|x| x.is_finite()), "{p:?}");
        let at = |i: usize, j: usize| f64::from(p[i * (n2 + 1) + j]);
        for i in 0..n1 {
            let row: f64 = (0..=n2).map(|j| at(i, j)).sum();
            assert!((row - 1.0).abs() < 1e-4, "row {i}: {row}");
        }
        for j in 0..n2 {
            let col: f64 = (0..=n1).map(|i| at(i, j)).sum();
            assert!((col - 1.0).abs() < 1e-4, "column {j}: {col}");
        }
        // Where the scaling domain is fine, the log domain agrees.
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let scores: Vec<f64> = (0..n1 * n2).map(|_| r.random_range(-8.0..4.0)).collect();
        let (d1, d2) = ([0.5; 4], [0.2; 10]);
        let scaled = sinkhorn_probabilities(&scores, [1, n1, n2], [&d1, &d2], 0.0, 100);
        let logged = log_domain_probabilities(&scores, [n1, n2], [&d1, &d2], 0.0, 100);
        for (a, b) in scaled.iter().zip(&logged) {
            assert!((f64::from(*a) - b).abs() < 1e-5, "{a} vs {b}");
        }
    }

    /// Samples normalised side by side (four to a register) give each the
    /// bits it gets alone, whatever its place and its neighbours: T = 6
    /// (a full group and a partial one) against each sample on its own.
    #[test]
    fn a_sample_normalised_beside_others_gets_the_bits_it_gets_alone() {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let [t, n1, n2] = [6, 5, 7];
        let mut scores: Vec<f64> = (0..t * n1 * n2)
            .map(|_| r.random_range(-20.0..5.0))
            .collect();
        scores[3] = f64::NEG_INFINITY;
        let dust = [n1, n2].map(|n| {
            (0..n)
                .map(|_| r.random_range(-1.0..1.0))
                .collect::<Vec<_>>()
        });
        let together = sinkhorn_probabilities(&scores, [t, n1, n2], [&dust[0], &dust[1]], 0.5, 20);
        let size = (n1 + 1) * (n2 + 1);
        for s in 0..t {
            let alone = sinkhorn_probabilities(
                &scores[s * n1 * n2..(s + 1) * n1 * n2],
                [1, n1, n2],
                [&dust[0], &dust[1]],
                0.5,
                20,
            );
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&together[s * size..(s + 1) * size]),
                bits(&alone),
                "sample {s}"
            );
        }
    }
}
