//! The training losses on a batch's mean assignment E[Y] over its MC
//! samples: the pair term ([`PairLoss`]: the SuperGlue-style likelihood
//! of the true assignment with dustbins, or the paper's Eq. 11) and the
//! paper's Eq. 12 (`L_non`) and Eq. 13 (`L_unc`), on labels as tensors
//! whose padding counts for nothing.

use burn::prelude::*;

use crate::matching::deep::arch::{LossTerms, PairLoss};

/// The labels of a batch as tensors.
pub(crate) struct LabelTensors {
    /// `[B, N1, N2]` 1 for a true pair that passes the gates.
    pub(crate) y: Tensor<3>,
    /// `[B, N1]`, `[B, N2]`: 1 for a real node with no true partner.
    pub(crate) free: [Tensor<2>; 2],
    /// `[B, N1, N2]` 1 where row i or column j is a non-covisible object.
    pub(crate) non: Tensor<3>,
    /// `[B, N1, N2]` 1 for an entry between real nodes.
    pub(crate) real: Tensor<3>,
    /// `[B]` per pair: true pairs, free nodes, real entries (each >= 1).
    pub(crate) counts: [Tensor<1>; 3],
}

/// The mean training loss of a batch. `log_assign`: `[B, T, N1 + 1, N2 +
/// 1]`. With P = E[Y], the mean assignment over the T samples:
/// - the pair term ([`PairLoss`]);
/// - `L_non = -log(mean(exp(-P o N)))` over the real entries (Eq. 12);
/// - `L_unc = -log(mean(exp(-H(P))))` with H the binary entropy in bits
///   (Eq. 13), on the mean of the T samples.
pub(crate) fn loss(log_assign: Tensor<4>, labels: &LabelTensors, terms: LossTerms) -> Tensor<1> {
    let [b, _, r, c] = log_assign.dims();
    let (n1, n2) = (r - 1, c - 1);
    let p_full = log_assign.exp().mean_dim(1).reshape([b, r, c]); // [B, N1 + 1, N2 + 1]
    let p = p_full.clone().slice([0..b, 0..n1, 0..n2]);
    let log = |t: Tensor<3>| t.clamp_min(1e-9).log();
    let per_pair = |t: Tensor<3>| t.sum_dims_squeeze::<1, usize>(&[1, 2]); // [B]
    let [n_true, n_free, n_real] = labels.counts.clone();
    let mut total = match terms.pairs {
        PairLoss::Likelihood => {
            let pairs = -per_pair(log(p.clone()) * labels.y.clone()) / n_true;
            let rows = log(p_full.clone().slice([0..b, 0..n1, n2..c])).reshape([b, n1]);
            let cols = log(p_full.slice([0..b, n1..r, 0..n2])).reshape([b, n2]);
            let [f1, f2] = labels.free.clone();
            let free = -((rows * f1).sum_dim(1) + (cols * f2).sum_dim(1)).reshape([b]) / n_free;
            // Halves of equal weight; a pair with no free node (or no true
            // pair) has that half at 0 and is weighed as such.
            (pairs + free) * 0.5
        }
        PairLoss::Paper => {
            let matched = per_pair(p.clone() * labels.y.clone()) / n_true;
            -matched.clamp_min(1e-9).log()
        }
    };
    if terms.non {
        total = total + non_term(p.clone(), &labels.non, &labels.real, n_real.clone());
    }
    if terms.unc {
        total = total + unc_term(p, &labels.real, n_real);
    }
    total.mean()
}

/// Eq. 12 per pair of the batch: `-log(mean(exp(-P o N)))` over the real
/// entries, with P `[B, N1, N2]` the mean assignment's real block, N 1
/// where row i or column j is a non-covisible object, `n_real` `[B]` the
/// real entries of each pair.
pub(crate) fn non_term(
    p: Tensor<3>,
    non: &Tensor<3>,
    real: &Tensor<3>,
    n_real: Tensor<1>,
) -> Tensor<1> {
    let per_pair = |t: Tensor<3>| t.sum_dims_squeeze::<1, usize>(&[1, 2]);
    let kept = per_pair((-(p * non.clone())).exp() * real.clone());
    -(kept / n_real).log()
}

/// Eq. 13 per pair of the batch: `-log(mean(exp(-H(P))))` over the real
/// entries, H the binary entropy in bits of each entry of P `[B, N1,
/// N2]`.
pub(crate) fn unc_term(p: Tensor<3>, real: &Tensor<3>, n_real: Tensor<1>) -> Tensor<1> {
    let per_pair = |t: Tensor<3>| t.sum_dims_squeeze::<1, usize>(&[1, 2]);
    let q = p.clamp(1e-6, 1.0 - 1e-6);
    let one_minus = q.clone().neg() + 1.0;
    let h = -(q.clone() * q.log() + one_minus.clone() * one_minus.log()) / std::f32::consts::LN_2;
    let kept = per_pair(h.neg().exp() * real.clone());
    -(kept / n_real).log()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two MC samples of a 2 x 2 assignment, whose real blocks average to
    /// P = [[0.7, 0.2], [0.1, 0.6]] and whose dustbins average to 0.1
    /// (rows) and 0.1 (columns), as a batch of one.
    fn two_samples(device: &Device) -> Tensor<4> {
        let samples: Vec<f32> = vec![
            0.8, 0.1, 0.1, 0.1, 0.5, 0.1, 0.1, 0.1, 0.1, // t = 0
            0.6, 0.3, 0.1, 0.1, 0.7, 0.1, 0.1, 0.1, 0.1, // t = 1
        ];
        Tensor::<4>::from_data(TensorData::new(samples, [1, 2, 3, 3]), device).log()
    }

    fn labels(device: &Device, y: [f32; 4], free: [[f32; 2]; 2], non: [f32; 4]) -> LabelTensors {
        let m =
            |v: [f32; 4]| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [1, 2, 2]), device);
        let v = |v: [f32; 2]| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [1, 2]), device);
        let n_true = y.iter().sum::<f32>().max(1.0);
        let n_free = (free[0].iter().sum::<f32>() + free[1].iter().sum::<f32>()).max(1.0);
        let one = |x: f32| Tensor::<1>::from_data(TensorData::new(vec![x], [1]), device);
        LabelTensors {
            y: m(y),
            free: [v(free[0]), v(free[1])],
            non: m(non),
            real: m([1.0; 4]),
            counts: [one(n_true), one(n_free), one(4.0)],
        }
    }

    /// The loss terms on a hand-computed case: object 0 of each side is
    /// the same, object 1 of each side is seen by one vehicle only.
    /// By hand (P above, Y* = [[1, 0], [0, 0]], N = [[0, 1], [1, 1]]):
    /// pair likelihood = (-ln 0.7 + -(ln 0.1 + ln 0.1) / 2) / 2
    /// = (0.356675 + 2.302585) / 2 = 1.329630;
    /// Eq. 11 = -ln 0.7 = 0.356675;
    /// L_non = -ln((1 + e^-0.2 + e^-0.1 + e^-0.6) / 4) = 0.200777;
    /// L_unc = -ln(mean(exp(-H_bits(p)))) over 0.7, 0.2, 0.1, 0.6 = 0.742119.
    #[test]
    fn loss_terms_match_a_hand_computed_two_by_two_case() {
        let device = crate::matching::deep::train::backend::device();
        let l = labels(
            &device,
            [1., 0., 0., 0.],
            [[0., 1.], [0., 1.]],
            [0., 1., 1., 1.],
        );
        let value = |pairs: PairLoss, non: bool, unc: bool| {
            let terms = LossTerms { pairs, non, unc };
            f64::from(loss(two_samples(&device), &l, terms).into_scalar::<f32>())
        };
        let nll = value(PairLoss::Likelihood, false, false);
        assert!((nll - 1.329630).abs() < 1e-5, "pair likelihood {nll}");
        let paper = value(PairLoss::Paper, false, false);
        assert!((paper - 0.356675).abs() < 1e-5, "Eq. 11 {paper}");
        assert!((value(PairLoss::Paper, true, false) - paper - 0.200777).abs() < 1e-5);
        assert!((value(PairLoss::Paper, false, true) - paper - 0.742119).abs() < 1e-5);
        assert!((value(PairLoss::Likelihood, true, true) - nll - 0.200777 - 0.742119).abs() < 1e-5);
        // Every node partnered: the dustbin half is 0 (both true pairs at
        // 0.7 and 0.6: (-ln 0.7 - ln 0.6) / 2 / 2).
        let both = labels(&device, [1., 0., 0., 1.], [[0., 0.], [0., 0.]], [0.; 4]);
        let got = f64::from(
            loss(
                two_samples(&device),
                &both,
                LossTerms {
                    pairs: PairLoss::Likelihood,
                    non: false,
                    unc: false,
                },
            )
            .into_scalar::<f32>(),
        );
        let expected = (-(0.7f64.ln()) - 0.6f64.ln()) / 2.0 / 2.0;
        assert!((got - expected).abs() < 1e-5, "{got} vs {expected}");
    }
}
