//! Dropout masks, drawn by the caller from a seeded stream and applied as
//! tensors on any device (burn's `Dropout` is a no-op outside autodiff
//! training, and MC dropout needs masks at inference): inverted dropout
//! (0 or 1 / (1 - p)) with one draw per unit for training and two units
//! per draw at inference, and the consensus' random node indicators.

use burn::prelude::*;
use rand::{Rng, RngCore};
use rand_chacha::ChaCha8Rng;

use super::arch::{Architecture, MaskScope};

/// The dropout masks of one training forward pass with T samples (values
/// 0 or 1 / (1 - p), inverted dropout).
pub struct Masks {
    /// `[B, T, N1, hidden]`, `[B, T, N2, hidden]`.
    pub conv1: [Tensor<4>; 2],
    /// `[B, T, N1, out]`, `[B, T, N2, out]`.
    pub conv2: [Tensor<4>; 2],
    pub pair: PairMasks,
}

/// The masks of the pair part of a forward pass: consensus dropout and
/// the random node indicators.
pub struct PairMasks {
    /// `[B, T, N1, N2, consensus_dim]`.
    pub phi: Tensor<5>,
    /// `[B, 1, N1, consensus_dim]`.
    pub indicators: Tensor<4>,
}

/// Draws inverted-dropout masks (0 or 1 / (1 - p)) of the given shape.
fn dropout_mask(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    // Compare raw 32-bit draws with the keep threshold: one draw per unit.
    let threshold = (keep * 4_294_967_296.0).min(f64::from(u32::MAX)) as u32;
    let mut out = vec![0f32; len];
    for v in out.iter_mut() {
        if rng.next_u32() < threshold {
            *v = scale;
        }
    }
    out
}

/// Inference masks: [`dropout_mask`] with two units per 32-bit draw (the
/// keep probability rounded to 1/65536: 0.8 becomes 0.800003), half the
/// random numbers of the training masks.
pub(super) fn dropout_mask_16(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    let threshold = (keep * 65_536.0).round().min(65_536.0) as u32;
    let mut words = vec![0u32; len.div_ceil(2)];
    rng.fill(&mut words[..]);
    let mut out = vec![0f32; 2 * words.len()];
    for (o, &w) in out.chunks_exact_mut(2).zip(&words) {
        o[0] = scale * f32::from(u8::from((w & 0xFFFF) < threshold));
        o[1] = scale * f32::from(u8::from((w >> 16) < threshold));
    }
    out.truncate(len);
    out
}

/// A mask draw: the training or the inference one.
pub(super) type MaskDraw = fn(&mut ChaCha8Rng, usize, f64) -> Vec<f32>;

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
pub(super) fn draw_masks(
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
        let phi = if arch.consensus {
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
pub(super) fn draw_embedding_masks(
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

/// The values of [`draw_embedding_masks`]'s shared masks (`[t, hidden]`
/// and `[t, out]`, drawn in the same order from the same stream): what
/// the plain second layer ([`super::shared_conv`]) multiplies with.
pub(super) fn shared_embedding_mask_values(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    t: usize,
) -> (Vec<f32>, Vec<f32>) {
    let p = arch.dropout_conv;
    let m1 = dropout_mask_16(rng, t * arch.hidden, p);
    let m2 = dropout_mask_16(rng, t * arch.out, p);
    (m1, m2)
}

/// The consensus MLP's dropout mask of one pair at inference, `[1, t,
/// n1, n2, consensus_dim]`: per pair entry and unit, or one per sample and
/// unit ([`MaskScope::Shared`], from a stream the same for every pair).
pub(super) fn draw_phi_mask(
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
pub(super) fn draw_pair_masks(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    [b, t, n1, n2]: [usize; 4],
    draw: MaskDraw,
    device: &Device,
) -> PairMasks {
    let r = arch.consensus_dim;
    let phi = if arch.consensus {
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

/// `len` standard normals, as [`draw_pair_masks`] draws the consensus
/// indicators (`[n1, consensus_dim]` of one pair, row-major).
pub(super) fn indicator_values(rng: &mut ChaCha8Rng, len: usize) -> Vec<f32> {
    let normal = rand_distr::StandardNormal;
    (0..len)
        .map(|_| rng.sample::<f64, _>(normal) as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn dropout_masks_have_the_right_rate_and_scale() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let m = dropout_mask(&mut rng, 100_000, 0.4);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.6).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.6).abs() < 1e-6));
        assert!(dropout_mask(&mut rng, 10, 0.0).iter().all(|&v| v == 1.0));
        let m = dropout_mask_16(&mut rng, 100_001, 0.2);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.8).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.8).abs() < 1e-6));
        assert!(dropout_mask_16(&mut rng, 7, 0.0).iter().all(|&v| v == 1.0));
    }

    /// Eq. 8's masks: in each sample one mask over a layer's units, the
    /// same for every node; per-node masks differ between nodes.
    #[test]
    fn shared_masks_are_one_draw_per_sample_and_unit() {
        let arch = Architecture::default();
        let device = Device::flex();
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
        let device = Device::flex();
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
