//! The two published networks as one burn module: GCN-GM (psi_1 and the
//! Sinkhorn-normalised similarity `S_0`) and DGMC (the same `S_0`, then `L`
//! consensus steps with psi_2 on random node indicator functions, giving
//! `S_L`), as training runs them, and their dropout masks and indicators
//! as tensors.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::init::{Init, Source};
use super::sinkhorn::{BLOCKED, log_sinkhorn};
use super::spline::{GraphTensors, SplineCnn};
use crate::matching::deep::arch::{MaskScope, PublishedConfig, PublishedKind};
use crate::matching::deep::mc::draws::dropout_mask_16;
use crate::matching::deep::params::{ParamSpec, Params};
use crate::matching::deep::published;

#[derive(Module, Debug)]
pub(crate) struct PublishedNet {
    psi1: SplineCnn,
    /// DGMC's second network on the indicator functions (`cat = true`).
    psi2: Option<SplineCnn>,
    /// DGMC's MLP on the consensus differences: `rnd_dim -> rnd_dim -> 1`.
    mlp_in: Option<Linear>,
    mlp_out: Option<Linear>,
    /// The "no match" score of every node and of the corner, `[1]`.
    dustbin: Param<Tensor<1>>,
}

/// The dropout masks and indicators of one forward pass over `B` pairs
/// with `T` samples each (values 0 or 1 / (1 - p)).
pub(crate) struct PublishedMasks {
    /// psi_1's masks of the first and second graphs, `[B, T, N1, hidden]`
    /// and `[B, T, N2, hidden]`.
    pub(crate) psi1: [Tensor<4>; 2],
    /// One `[B, T, N1, rnd_dim]` standard-normal draw per consensus step.
    pub(crate) indicators: Vec<Tensor<4>>,
}

/// The normalised assignments, log, `[B, T, N1 + 1, N2 + 1]` with a
/// dustbin row and column: `S_0`, and `S_L` after consensus (DGMC).
pub(crate) struct Assignments {
    pub(crate) initial: Tensor<4>,
    pub(crate) refined: Option<Tensor<4>>,
}

impl Assignments {
    /// The network's answer: `S_L` when there is one, else `S_0`.
    #[cfg(test)]
    pub(crate) fn last(self) -> Tensor<4> {
        self.refined.unwrap_or(self.initial)
    }
}

impl PublishedNet {
    /// A fresh network of `cfg` (`init`), or a skeleton for weights.
    pub(crate) fn new(cfg: &PublishedConfig, init: Init, device: &Device) -> Self {
        let specs = published::spec(cfg);
        Self::from_params(cfg, &init.params(&specs), &specs, device)
    }

    /// The network of `cfg` with the parameters `params` (of `specs`,
    /// [`published::spec`]).
    pub(crate) fn from_params(
        cfg: &PublishedConfig,
        params: &Params,
        specs: &[ParamSpec],
        device: &Device,
    ) -> Self {
        let src = Source {
            params,
            specs,
            device,
        };
        let consensus = cfg.kind == PublishedKind::Dgmc;
        Self {
            psi1: SplineCnn::from(&src, "psi1", false),
            psi2: consensus.then(|| SplineCnn::from(&src, "psi2", true)),
            mlp_in: consensus.then(|| src.linear("mlp_in")),
            mlp_out: consensus.then(|| src.linear("mlp_out")),
            dustbin: src.param("dustbin"),
        }
    }

    /// Log assignments of `B` pairs (`graphs[0]` the first graphs,
    /// `graphs[1]` the second), T samples each as the masks say.
    pub(crate) fn forward(
        &self,
        cfg: &PublishedConfig,
        graphs: [&GraphTensors; 2],
        masks: PublishedMasks,
    ) -> Assignments {
        let [g1, g2] = graphs;
        let [m1, m2] = masks.psi1;
        let h1 = self.psi1.forward(g1.x.clone(), g1, Some(m1)); // [B, T, N1, out]
        let h2 = self.psi1.forward(g2.x.clone(), g2, Some(m2)); // [B, T, N2, out]
        let blocked = blocked(g1, g2);
        let mut s_hat = h1.matmul(h2.swap_dims(2, 3)); // [B, T, N1, N2]
        let initial = self.normalise(cfg, s_hat.clone(), &blocked, [g1, g2]);
        let (Some(psi2), Some(mlp_in), Some(mlp_out)) = (&self.psi2, &self.mlp_in, &self.mlp_out)
        else {
            return Assignments {
                initial,
                refined: None,
            };
        };
        let [b, t, n1, n2] = s_hat.dims();
        let mut current = initial.clone();
        for r_s in masks.indicators {
            let s = current.exp().slice([0..b, 0..t, 0..n1, 0..n2]);
            let r_s = r_s * g1.node_mask.clone(); // [B, T, N1, R]
            let r_t = s.swap_dims(2, 3).matmul(r_s.clone()); // [B, T, N2, R]
            let o_s = psi2.forward(r_s, g1, None);
            let o_t = psi2.forward(r_t, g2, None);
            let d = o_s.unsqueeze_dim::<5>(3) - o_t.unsqueeze_dim::<5>(2); // [B, T, N1, N2, R]
            let delta = mlp_out.forward(activation::relu(mlp_in.forward(d)));
            s_hat = s_hat + delta.reshape([b, t, n1, n2]);
            current = self.normalise(cfg, s_hat.clone(), &blocked, [g1, g2]);
        }
        Assignments {
            initial,
            refined: Some(current),
        }
    }

    /// Dustbin Sinkhorn of the scores `[B, T, N1, N2]`, padding blocked.
    fn normalise(
        &self,
        cfg: &PublishedConfig,
        scores: Tensor<4>,
        blocked: &Tensor<4, Bool>,
        [g1, g2]: [&GraphTensors; 2],
    ) -> Tensor<4> {
        let [b, t, n1, n2] = scores.dims();
        let scores = scores.mask_fill(blocked.clone().expand([b, t, n1, n2]), BLOCKED);
        let bin = self.dustbin.val();
        let dust = [n1, n2].map(|n| bin.clone().reshape([1, 1, 1]).expand([b, 1, n]));
        log_sinkhorn(
            scores,
            dust,
            bin,
            [&g1.counts, &g2.counts],
            cfg.sinkhorn_iters,
        )
    }
}

/// `[B, 1, N1, N2]`: true where either node is padding.
fn blocked(g1: &GraphTensors, g2: &GraphTensors) -> Tensor<4, Bool> {
    let [n1, n2] = [g1.n(), g2.n()];
    let mut v = Vec::with_capacity(g1.counts.len() * n1 * n2);
    for (&c1, &c2) in g1.counts.iter().zip(&g2.counts) {
        for i in 0..n1 {
            v.extend((0..n2).map(|j| i >= c1 || j >= c2));
        }
    }
    let b = g1.counts.len();
    Tensor::from_data(TensorData::new(v, [b, 1, n1, n2]), &g1.x.device())
}

/// The dropout of psi_1's hidden channels in one forward pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Dropout {
    /// Every mask 1 (one deterministic pass per sample).
    Off,
    /// At this rate, drawn as `scope` says: a mask per node and channel,
    /// or (Eq. 8) one mask over the channels per sample, shared by every
    /// node of every graph.
    On(f64, MaskScope),
}

/// psi_1's masks of `b` pairs of graphs padded to `n1` and `n2` nodes,
/// `t` samples each, from `rng`: `[B, T, N1, hidden]` and `[B, T, N2,
/// hidden]`, values 0 or 1 / (1 - p).
pub(crate) fn draw_psi1_masks(
    rng: &mut ChaCha8Rng,
    cfg: &PublishedConfig,
    [b, t, n1, n2]: [usize; 4],
    dropout: Dropout,
    device: &Device,
) -> [Tensor<4>; 2] {
    let d = cfg.hidden;
    match dropout {
        Dropout::Off => [n1, n2].map(|n| Tensor::ones([b, t, n, d], device)),
        Dropout::On(p, MaskScope::PerNode) => [n1, n2].map(|n| {
            let shape = [b, t, n, d];
            let v = dropout_mask_16(rng, shape.iter().product(), p);
            Tensor::<4>::from_data(TensorData::new(v, shape), device)
        }),
        Dropout::On(p, MaskScope::Shared) => {
            let v = dropout_mask_16(rng, t * d, p);
            let m = Tensor::<4>::from_data(TensorData::new(v, [1, t, 1, d]), device);
            [n1, n2].map(|n| m.clone().expand([b, t, n, d]))
        }
    }
}

/// DGMC's random node indicators of the first graphs, one standard-normal
/// `[B, T, N1, rnd_dim]` draw per consensus step.
pub(crate) fn draw_indicators(
    rng: &mut ChaCha8Rng,
    cfg: &PublishedConfig,
    [b, t, n1]: [usize; 3],
    device: &Device,
) -> Vec<Tensor<4>> {
    let r = cfg.consensus_dim;
    (0..cfg.consensus_steps())
        .map(|_| {
            let v: Vec<f32> = (0..b * t * n1 * r)
                .map(|_| rng.sample::<f64, _>(rand_distr::StandardNormal) as f32)
                .collect();
            Tensor::from_data(TensorData::new(v, [b, t, n1, r]), device)
        })
        .collect()
}

/// Masks and indicators for `b` pairs of graphs padded to `n1` and `n2`
/// nodes, `t` samples each, all from `rng`; without `dropout` every mask
/// is 1 (the indicators are random all the same). Masks per node at the
/// configured rate.
pub(crate) fn draw_masks(
    rng: &mut ChaCha8Rng,
    cfg: &PublishedConfig,
    [b, t, n1, n2]: [usize; 4],
    dropout: bool,
    device: &Device,
) -> PublishedMasks {
    let dropout = if dropout {
        Dropout::On(cfg.dropout_conv, MaskScope::PerNode)
    } else {
        Dropout::Off
    };
    let psi1 = draw_psi1_masks(rng, cfg, [b, t, n1, n2], dropout, device);
    let indicators = draw_indicators(rng, cfg, [b, t, n1], device);
    PublishedMasks { psi1, indicators }
}

/// The masks and indicators of one training pass over `b` pairs, `t`
/// samples each: psi_1's masks per node and channel, or (Eq. 8,
/// [`MaskScope::Shared`]) one mask per pair and sample over the channels,
/// the same for every node of both graphs.
pub(crate) fn draw_training_masks(
    rng: &mut ChaCha8Rng,
    cfg: &PublishedConfig,
    [b, t, n1, n2]: [usize; 4],
    scope: MaskScope,
    device: &Device,
) -> PublishedMasks {
    match scope {
        MaskScope::PerNode => draw_masks(rng, cfg, [b, t, n1, n2], true, device),
        MaskScope::Shared => {
            let d = cfg.hidden;
            let v = dropout_mask_16(rng, b * t * d, cfg.dropout_conv);
            let m = Tensor::<4>::from_data(TensorData::new(v, [b, t, 1, d]), device);
            let psi1 = [n1, n2].map(|n| m.clone().expand([b, t, n, d]));
            let indicators = draw_indicators(rng, cfg, [b, t, n1], device);
            PublishedMasks { psi1, indicators }
        }
    }
}
