//! Log-domain Sinkhorn with a dustbin row and column as tensors (paper
//! Eq. 4 with "no match", as SuperGlue): what training differentiates,
//! batched over padded pairs whose padding has zero marginals.

use burn::prelude::*;

pub(crate) use crate::matching::deep::kernels::sinkhorn::BLOCKED;

/// Log-sum-exp along `dim`, keeping it (size 1).
fn logsumexp<const D: usize>(x: Tensor<D>, dim: usize) -> Tensor<D> {
    let m = x.clone().max_dim(dim).detach();
    (x - m.clone()).exp().sum_dim(dim).log() + m
}

/// Log-domain Sinkhorn with a dustbin row and column (SuperGlue's optimal
/// transport), batched over padded pairs: scores `[B, T, N1, N2]`, each
/// node's "no match" score (`[B, 1, N1]`, `[B, 1, N2]`), the corner's
/// `[1]`, and the real node counts of each pair -> log assignment `[B, T,
/// N1 + 1, N2 + 1]` whose real rows and columns each sum to 1 (dustbin
/// entry included) and whose padding carries nothing.
pub(crate) fn log_sinkhorn(
    scores: Tensor<4>,
    dust: [Tensor<3>; 2],
    corner: Tensor<1>,
    counts: [&[usize]; 2],
    iters: usize,
) -> Tensor<4> {
    let [b, t, n1, n2] = scores.dims();
    let device = scores.device();
    let [d1, d2] = dust;
    let column = d1.reshape([b, 1, n1, 1]).expand([b, t, n1, 1]);
    let row = d2.reshape([b, 1, 1, n2]).expand([b, t, 1, n2]);
    let corner = corner.reshape([1, 1, 1, 1]).expand([b, t, 1, 1]);
    let top = Tensor::cat(vec![scores, column], 3);
    let bottom = Tensor::cat(vec![row, corner], 3);
    let z = Tensor::cat(vec![top, bottom], 2); // [B, T, N1 + 1, N2 + 1]
    let (mut mu, mut nu, mut norm) = (Vec::new(), Vec::new(), Vec::new());
    for (&c1, &c2) in counts[0].iter().zip(counts[1]) {
        let ln = -((c1 + c2) as f32).ln();
        norm.push(ln);
        mu.extend((0..n1).map(|i| if i < c1 { ln } else { BLOCKED }));
        mu.push((c2 as f32).ln() + ln);
        nu.extend((0..n2).map(|j| if j < c2 { ln } else { BLOCKED }));
        nu.push((c1 as f32).ln() + ln);
    }
    let log_mu = Tensor::<4>::from_data(TensorData::new(mu, [b, 1, n1 + 1, 1]), &device);
    let log_nu = Tensor::<4>::from_data(TensorData::new(nu, [b, 1, 1, n2 + 1]), &device);
    let norm = Tensor::<4>::from_data(TensorData::new(norm, [b, 1, 1, 1]), &device);
    let mut u = Tensor::<4>::zeros([b, t, n1 + 1, 1], &device);
    let mut v = Tensor::<4>::zeros([b, t, 1, n2 + 1], &device);
    for _ in 0..iters {
        u = log_mu.clone() - logsumexp(z.clone() + v.clone(), 3);
        v = log_nu.clone() - logsumexp(z.clone() + u.clone(), 2);
    }
    z + u + v - norm
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::deep::kernels::sinkhorn::sinkhorn_probabilities;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn sinkhorn_rows_and_columns_sum_to_one_with_dustbins() {
        let device = crate::matching::deep::train::backend::device();
        let mut r = ChaCha8Rng::seed_from_u64(1);
        let scores: Vec<f32> = (0..48).map(|_| r.random_range(-6.0..6.0)).collect();
        let scores = Tensor::<4>::from_data(TensorData::new(scores, [1, 2, 4, 6]), &device);
        let dust = [4, 6].map(|n| Tensor::<3>::ones([1, 1, n], &device));
        let p = log_sinkhorn(scores, dust, Tensor::ones([1], &device), [&[4], &[6]], 50).exp();
        let v: Vec<f32> = p.try_into_vec_as::<f32>().unwrap();
        for t in 0..2 {
            let at = |i: usize, j: usize| v[t * 35 + i * 7 + j];
            for i in 0..4 {
                let row: f32 = (0..7).map(|j| at(i, j)).sum();
                assert!((row - 1.0).abs() < 1e-3, "row {i}: {row}");
            }
            for j in 0..6 {
                let col: f32 = (0..5).map(|i| at(i, j)).sum();
                assert!((col - 1.0).abs() < 1e-3, "col {j}: {col}");
            }
        }
    }

    /// Dustbin scores hundreds of nats apart (every pair gated) underflow
    /// the scaling domain's kernel; the sample is solved in the log domain
    /// instead: finite, every real row and column summing to 1 (r49_01).
    /// The tensor-free inference Sinkhorn gives the assignment of the
    /// training one (log domain, tensors), on scores from mild to far
    /// apart, with gated entries and per-node "no match" scores, square and
    /// not.
    #[test]
    fn inference_sinkhorn_equals_the_log_domain_one() {
        let device = crate::matching::deep::train::backend::device();
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for (shape, spread, corner) in [
            ([3, 5, 4], 6.0f64, 1.0f64),
            ([2, 7, 9], 60.0, -2.5),
            ([4, 1, 6], 300.0, 4.0),
            ([1, 20, 18], 30.0, 0.3),
        ] {
            let [t, n1, n2] = shape;
            let mut scores: Vec<f64> = (0..t * n1 * n2)
                .map(|_| r.random_range(-spread..spread / 4.0))
                .collect();
            scores[0] = -10.0 * spread; // far below everything else
            scores[1] = f64::NEG_INFINITY; // gated
            let dust = [n1, n2].map(|n| {
                (0..n)
                    .map(|_| corner + r.random_range(-2.0..2.0))
                    .collect::<Vec<f64>>()
            });
            let tensor = |v: Vec<f32>, n: usize| {
                Tensor::<3>::from_data(TensorData::new(v, [1, 1, n]), &device)
            };
            let blocked: Vec<f32> = scores
                .iter()
                .map(|&v| if v.is_finite() { v as f32 } else { BLOCKED })
                .collect();
            let expected = log_sinkhorn(
                Tensor::<4>::from_data(TensorData::new(blocked, [1, t, n1, n2]), &device),
                [
                    tensor(dust[0].iter().map(|&v| v as f32).collect(), n1),
                    tensor(dust[1].iter().map(|&v| v as f32).collect(), n2),
                ],
                Tensor::from_data(TensorData::new(vec![corner as f32], [1]), &device),
                [&[n1], &[n2]],
                20,
            )
            .exp();
            let expected: Vec<f32> = expected.try_into_vec_as::<f32>().unwrap();
            let got = sinkhorn_probabilities(&scores, shape, [&dust[0], &dust[1]], corner, 20);
            assert_eq!(got.len(), t * (n1 + 1) * (n2 + 1));
            for (k, (g, e)) in got.iter().zip(&expected).enumerate() {
                assert!((g - e).abs() < 1e-4, "{shape:?} entry {k}: {g} vs {e}");
            }
            assert_eq!(got[1], 0.0, "a gated pair has no mass");
        }
    }
}
