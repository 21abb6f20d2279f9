//! Dropout masks as tensors, from the values the shell's streams draw
//! ([`crate::matching::deep::mc::draws`]): burn's `Dropout` is a no-op
//! outside autodiff training, and MC dropout needs masks at inference.
//! What training and the tensor reference of inference apply.

use burn::prelude::*;
use rand_chacha::ChaCha8Rng;

use crate::matching::deep::arch::{Architecture, MaskScope};
pub(crate) use crate::matching::deep::mc::draws::MaskDraw;
#[cfg(test)]
use crate::matching::deep::mc::draws::dropout_mask_16;
use crate::matching::deep::mc::draws::{dropout_mask, indicator_values};

/// The dropout masks of one training forward pass with T samples (values
/// 0 or 1 / (1 - p), inverted dropout).
pub(crate) struct Masks {
    /// `[B, T, N1, hidden]`, `[B, T, N2, hidden]`.
    pub(crate) conv1: [Tensor<4>; 2],
    /// `[B, T, N1, out]`, `[B, T, N2, out]`.
    pub(crate) conv2: [Tensor<4>; 2],
    pub(crate) pair: PairMasks,
}

/// The masks of the pair part of a forward pass: consensus dropout and
/// the random node indicators.
pub(crate) struct PairMasks {
    /// `[B, T, N1, N2, consensus_dim]`.
    pub(crate) phi: Tensor<5>,
    /// `[B, 1, N1, consensus_dim]`.
    pub(crate) indicators: Tensor<4>,
}

/// A `[B, T, N, D]` mask tensor.
fn mask4(
    rng: &mut ChaCha8Rng,
    draw: MaskDraw,
    shape: [usize; 4],
    p: f64,
    device: &Device,
) -> Tensor<4> {
    let len = shape.iter().product();
    Tensor::from_data(TensorData::new(draw(rng, len, p), shape), device)
}

/// All masks of one training forward pass over a batch of `b` pairs with
/// `t` samples each, graphs padded to `n1` and `n2` nodes, from one
/// stream: per node and unit, or (Eq. 8,
/// [`MaskScope::Shared`]) one mask per pair and sample over each layer's
/// units, the same for every node of both graphs and every pair entry.
pub(crate) fn draw_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [b, t, n1, n2]: [usize; 4],
    scope: MaskScope,
    device: &Device,
) -> Masks {
    let (h, o, p) = (arch.hidden, arch.out, arch.dropout_conv);
    if scope == MaskScope::Shared {
        let conv1 = mask4(rng, dropout_mask, [b, t, 1, h], p, device);
        let conv2 = mask4(rng, dropout_mask, [b, t, 1, o], p, device);
        let r = arch.consensus_dim;
        let phi = if arch.has_consensus() {
            let v = dropout_mask(rng, b * t * r, arch.dropout_phi);
            Tensor::<5>::from_data(TensorData::new(v, [b, t, 1, 1, r]), device)
                .expand([b, t, n1, n2, r])
        } else {
            Tensor::<5>::ones([1, 1, 1, 1, 1], device)
        };
        return Masks {
            conv1: [n1, n2].map(|n| conv1.clone().expand([b, t, n, h])),
            conv2: [n1, n2].map(|n| conv2.clone().expand([b, t, n, o])),
            pair: PairMasks {
                phi,
                indicators: indicators(rng, arch, [b, n1], device),
            },
        };
    }
    let conv1 = [
        mask4(rng, dropout_mask, [b, t, n1, h], p, device),
        mask4(rng, dropout_mask, [b, t, n2, h], p, device),
    ];
    let conv2 = [
        mask4(rng, dropout_mask, [b, t, n1, o], p, device),
        mask4(rng, dropout_mask, [b, t, n2, o], p, device),
    ];
    let pair = draw_pair_masks(rng, arch, [b, t, n1, n2], dropout_mask, device);
    Masks { conv1, conv2, pair }
}

/// The conv dropout masks of one vehicle's embedding with `t` samples,
/// `[1, t, n, hidden]` and `[1, t, n, out]`: a mask per node and unit
/// ([`MaskScope::PerNode`]), or one per sample and unit repeated over the
/// nodes ([`MaskScope::Shared`]; with the same stream for every graph,
/// every graph then sees the same weights in sample t).
#[cfg(test)]
pub(crate) fn draw_embedding_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [t, n]: [usize; 2],
    scope: MaskScope,
    device: &Device,
) -> (Tensor<4>, Tensor<4>) {
    let p = arch.dropout_conv;
    let rows = match scope {
        MaskScope::PerNode => n,
        MaskScope::Shared => 1,
    };
    let (m1, m2) = (
        mask4(rng, dropout_mask_16, [1, t, rows, arch.hidden], p, device),
        mask4(rng, dropout_mask_16, [1, t, rows, arch.out], p, device),
    );
    (
        m1.expand([1, t, n, arch.hidden]),
        m2.expand([1, t, n, arch.out]),
    )
}

/// The consensus MLP's dropout mask of one pair at inference, `[1, t,
/// n1, n2, consensus_dim]`: per pair entry and unit, or one per sample and
/// unit ([`MaskScope::Shared`], from a stream the same for every pair).
#[cfg(test)]
pub(crate) fn draw_phi_mask(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [t, n1, n2]: [usize; 3],
    scope: MaskScope,
    device: &Device,
) -> Tensor<5> {
    let r = arch.consensus_dim;
    let [a, b] = match scope {
        MaskScope::PerNode => [n1, n2],
        MaskScope::Shared => [1, 1],
    };
    Tensor::<5>::from_data(
        TensorData::new(
            dropout_mask_16(rng, t * a * b * r, arch.dropout_phi),
            [1, t, a, b, r],
        ),
        device,
    )
    .expand([1, t, n1, n2, r])
}

/// The consensus masks of `b` pairs with `t` samples each: the phi
/// dropout (drawn by `draw`: the training or the inference mask) and the
/// random node indicators.
pub(crate) fn draw_pair_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [b, t, n1, n2]: [usize; 4],
    draw: MaskDraw,
    device: &Device,
) -> PairMasks {
    let r = arch.consensus_dim;
    let phi = if arch.has_consensus() {
        Tensor::<5>::from_data(
            TensorData::new(
                draw(rng, b * t * n1 * n2 * r, arch.dropout_phi),
                [b, t, n1, n2, r],
            ),
            device,
        )
    } else {
        Tensor::<5>::ones([1, 1, 1, 1, 1], device)
    };
    PairMasks {
        phi,
        indicators: indicators(rng, arch, [b, n1], device),
    }
}

/// The consensus's random node indicators of `b` first graphs of `n1`
/// nodes, `[B, 1, N1, consensus_dim]`, standard normal.
fn indicators(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [b, n1]: [usize; 2],
    device: &Device,
) -> Tensor<4> {
    let r = arch.consensus_dim;
    let v = indicator_values(rng, b * n1 * r);
    Tensor::from_data(TensorData::new(v, [b, 1, n1, r]), device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Eq. 8's masks: in each sample one mask over a layer's units, the
    /// same for every node; per-node masks differ between nodes.
    #[test]
    fn shared_masks_are_one_draw_per_sample_and_unit() {
        let arch = Architecture::default();
        let device = crate::matching::deep::train::backend::device();
        let rows = |scope| {
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let (m1, _) = draw_embedding_masks(&mut rng, &arch, [4, 5], scope, &device);
            let v = m1.try_into_vec_as::<f32>().unwrap();
            let h = arch.hidden;
            // Sample 2's rows, one per node.
            (0..5)
                .map(|i| v[(2 * 5 + i) * h..(2 * 5 + i + 1) * h].to_vec())
                .collect::<Vec<_>>()
        };
        let shared = rows(MaskScope::Shared);
        assert!(shared.iter().all(|r| *r == shared[0]));
        assert!(shared[0].contains(&0.0) && shared[0].iter().any(|&x| x > 1.0));
        let per_node = rows(MaskScope::PerNode);
        assert!(per_node.iter().any(|r| *r != per_node[0]));
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let phi = draw_phi_mask(&mut rng, &arch, [2, 3, 4], MaskScope::Shared, &device);
        let v = phi.try_into_vec_as::<f32>().unwrap();
        let r = arch.consensus_dim;
        let first = &v[..r];
        assert!((0..12).all(|k| &v[k * r..(k + 1) * r] == first));
    }

    /// Training with Eq. 8's masks: in each pair's sample one mask over a
    /// layer's units, the same for every node of both graphs and every
    /// pair entry; other pairs and samples draw their own. Per-node
    /// training masks differ between nodes.
    #[test]
    fn shared_training_masks_are_one_draw_per_pair_and_sample() {
        let arch = Architecture::default();
        let device = crate::matching::deep::train::backend::device();
        let (b, t, n1, n2, h) = (2, 3, 4, 5, arch.hidden);
        let draw = |scope| {
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            draw_masks(&mut rng, &arch, [b, t, n1, n2], scope, &device)
        };
        let m = draw(MaskScope::Shared);
        let g1 = m.conv1[0].clone().try_into_vec_as::<f32>().unwrap();
        let g2 = m.conv1[1].clone().try_into_vec_as::<f32>().unwrap();
        let row1 = |pair: usize, sample: usize, node: usize| {
            let at = ((pair * t + sample) * n1 + node) * h;
            g1[at..at + h].to_vec()
        };
        let row2 = |pair: usize, sample: usize, node: usize| {
            let at = ((pair * t + sample) * n2 + node) * h;
            g2[at..at + h].to_vec()
        };
        for (pair, sample) in [(0, 0), (1, 2)] {
            let first = row1(pair, sample, 0);
            assert!((0..n1).all(|i| row1(pair, sample, i) == first));
            assert!((0..n2).all(|j| row2(pair, sample, j) == first));
        }
        assert_ne!(row1(0, 0, 0), row1(0, 1, 0), "samples draw their own");
        assert_ne!(row1(0, 0, 0), row1(1, 0, 0), "pairs draw their own");
        let r = arch.consensus_dim;
        let phi = m.pair.phi.try_into_vec_as::<f32>().unwrap();
        assert!((0..n1 * n2).all(|k| phi[k * r..(k + 1) * r] == phi[..r]));
        let per_node = draw(MaskScope::PerNode);
        let v = per_node.conv1[0].clone().try_into_vec_as::<f32>().unwrap();
        assert_ne!(v[..h], v[h..2 * h]);
    }
}
