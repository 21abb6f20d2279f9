//! The network (burn): Psi, two [`SplineConv`]s (hidden 256, output 32)
//! each followed by ReLU and dropout 0.4, embeds each vehicle's graph;
//! the pair part scores every pair as the shared pair log-likelihood
//! ([`crate::matching::likelihood`], the one GPS+appearance Hungarian
//! decides on), scaled, plus a gated residual: the similarity `H H'^T`
//! (Eq. 2), a small MLP on the pair's features, and the DGMC
//! neighbourhood consensus `phi(D)` (Eq. 3: random node indicators pushed
//! through the soft correspondence of the full scores, embedded by a
//! consensus `SplineConv`, compared, and scored by an MLP with dropout
//! 0.2); each node's "no match" score is a learned common score plus a
//! gated per-node score from where the node lies for both vehicles. The
//! gates start at 0 and the scale at 1: an untrained network scores every
//! pair exactly as the likelihood does, and learns only what improves on
//! it.
//!
//! Training pairs are padded to a common size and run as one tensor pass;
//! padding is masked out of messages, consensus, Sinkhorn (zero
//! marginals) and losses. The T Monte Carlo samples are the second
//! dimension (`[B, T, ...]`); the first layer, whose input does not
//! depend on any mask, is computed once.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation;

use super::init::{Init, Source};
use super::masks::{Masks, PairMasks};
use super::sinkhorn::{BLOCKED, log_sinkhorn};
use super::spline::{GraphTensors, SplineConv};
use crate::matching::deep::arch::Architecture;
use crate::matching::deep::features::{DUST_FEATURES, PAIR_FEATURES, PairInput};
use crate::matching::deep::ours;
#[cfg(test)]
use crate::matching::deep::ours::Combination;
use crate::matching::deep::params::{ParamSpec, Params};

/// The pair inputs of a batch as tensors (see [`super::features::PairInput`]).
pub(crate) struct PairTensors {
    /// `[B, 1, N1, N2]` the shared log-likelihood (0 where blocked).
    pub(crate) ll: Tensor<4>,
    /// `[B, 1, N1, N2]` true where the pair is gated or a node is padding.
    pub(crate) blocked: Tensor<4, Bool>,
    /// `[B, N1, N2, PAIR_FEATURES]`
    pub(crate) pair_features: Tensor<4>,
    /// `[B, N1, DUST_FEATURES]` and `[B, N2, DUST_FEATURES]`.
    pub(crate) dust_features: [Tensor<3>; 2],
}

impl PairTensors {
    /// Pair inputs padded to `n1 x n2`.
    pub(crate) fn new(inputs: &[&PairInput], [n1, n2]: [usize; 2], device: &Device) -> Self {
        let b = inputs.len();
        let (fp, fd) = (PAIR_FEATURES, DUST_FEATURES);
        let mut ll = vec![0f32; b * n1 * n2];
        let mut blocked = vec![true; b * n1 * n2];
        let mut pair = vec![0f32; b * n1 * n2 * fp];
        let mut dust1 = vec![0f32; b * n1 * fd];
        let mut dust2 = vec![0f32; b * n2 * fd];
        for (k, p) in inputs.iter().enumerate() {
            for i in 0..p.n1 {
                for j in 0..p.n2 {
                    let at = k * n1 * n2 + i * n2 + j;
                    if let Some(v) = p.log_likelihood[i * p.n2 + j] {
                        ll[at] = v as f32;
                        blocked[at] = false;
                    }
                    let src = (i * p.n2 + j) * fp;
                    pair[at * fp..(at + 1) * fp].copy_from_slice(&p.pair_features[src..src + fp]);
                }
            }
            dust1[k * n1 * fd..k * n1 * fd + p.n1 * fd].copy_from_slice(&p.dust_features[0]);
            dust2[k * n2 * fd..k * n2 * fd + p.n2 * fd].copy_from_slice(&p.dust_features[1]);
        }
        Self {
            ll: Tensor::from_data(TensorData::new(ll, [b, 1, n1, n2]), device),
            blocked: Tensor::from_data(TensorData::new(blocked, [b, 1, n1, n2]), device),
            pair_features: Tensor::from_data(TensorData::new(pair, [b, n1, n2, fp]), device),
            dust_features: [
                Tensor::from_data(TensorData::new(dust1, [b, n1, fd]), device),
                Tensor::from_data(TensorData::new(dust2, [b, n2, fd]), device),
            ],
        }
    }
}

/// What the pair part of the network says, before its gates: the
/// residual of every pair in every sample, `[B, T, N1, N2]`, and the
/// learned "no match" score of every node, `[B, 1, N1]` and `[B, 1, N2]`.
pub(crate) struct PairOutput {
    pub(crate) residual: Tensor<4>,
    pub(crate) dust: [Tensor<3>; 2],
}

#[derive(Module, Debug)]
pub(crate) struct OursNet {
    conv1: SplineConv,
    conv2: SplineConv,
    consensus_conv: Option<SplineConv>,
    phi_in: Option<Linear>,
    phi_out: Option<Linear>,
    pair_in: Linear,
    pair_out: Linear,
    dust_in: Linear,
    dust_out: Linear,
    /// Log of the likelihood's scale, `[1]` (0: the likelihood as is).
    log_scale: Param<Tensor<1>>,
    /// The residual's gate, `[1]` (0 at initialisation).
    gate: Param<Tensor<1>>,
    /// The common "no match" score (Sinkhorn's dustbin), `[1]`.
    dustbin: Param<Tensor<1>>,
    /// The learned per-node "no match" score's gate, `[1]` (0 at
    /// initialisation).
    dust_gate: Param<Tensor<1>>,
}

impl OursNet {
    /// A fresh network of `arch` (`init`), or a skeleton for weights.
    pub(crate) fn new(arch: &Architecture, init: Init, device: &Device) -> Self {
        let specs = ours::spec(arch);
        Self::from_params(arch, &init.params(&specs), &specs, device)
    }

    /// The network of `arch` with the parameters `params` (of `specs`,
    /// [`ours::spec`]).
    pub(crate) fn from_params(
        arch: &Architecture,
        params: &Params,
        specs: &[ParamSpec],
        device: &Device,
    ) -> Self {
        let src = Source {
            params,
            specs,
            device,
        };
        let c = arch.has_consensus();
        Self {
            conv1: SplineConv::from(&src, "conv1", true),
            conv2: SplineConv::from(&src, "conv2", true),
            consensus_conv: c.then(|| SplineConv::from(&src, "consensus_conv", true)),
            phi_in: c.then(|| src.linear("phi_in")),
            phi_out: c.then(|| src.linear("phi_out")),
            pair_in: src.linear("pair_in"),
            pair_out: src.linear("pair_out"),
            dust_in: src.linear("dust_in"),
            dust_out: src.linear("dust_out"),
            log_scale: src.param("log_scale"),
            gate: src.param("gate"),
            dustbin: src.param("dustbin"),
            dust_gate: src.param("dust_gate"),
        }
    }

    /// The same network with its gates opened to `gate` (residual and
    /// per-node "no match" scores): what training does first, for tests
    /// of the gated parts without training.
    #[cfg(test)]
    pub(crate) fn with_gates(self, gate: f32) -> Self {
        self.with_gate_values(gate, gate)
    }

    /// The same network with the residual's gate at `gate` and the
    /// per-node "no match" score's at `dust_gate`.
    #[cfg(test)]
    pub(crate) fn with_gate_values(mut self, gate: f32, dust_gate: f32) -> Self {
        let device = self.gate.val().device();
        let value = |v: f32| Tensor::from_data(TensorData::new(vec![v], [1]), &device);
        self.gate = super::init::named_param("gate", value(gate));
        self.dust_gate = super::init::named_param("dust_gate", value(dust_gate));
        self
    }

    /// The scalar parameters, read once (inference).
    #[cfg(test)]
    pub(crate) fn combination(&self) -> Combination {
        let read = |p: &Param<Tensor<1>>| p.val().into_scalar::<f32>();
        Combination {
            scale: read(&self.log_scale).exp(),
            gate: read(&self.gate),
            dustbin: read(&self.dustbin),
            dust_gate: read(&self.dust_gate),
        }
    }

    /// Psi: node embeddings `[B, T, N, out]` for T dropout samples of each
    /// graph (`mask1`: `[B, T, N, hidden]`, `mask2`: `[B, T, N, out]`).
    pub(crate) fn embed(&self, g: &GraphTensors, mask1: Tensor<4>, mask2: Tensor<4>) -> Tensor<4> {
        // The first layer's input is the same for every sample: compute once.
        let h = activation::relu(self.conv1.forward(g.x.clone(), g));
        let h = h * mask1; // [B, T, N, hidden]
        activation::relu(self.conv2.forward(h, g)) * mask2
    }

    /// The first layer's output `relu(conv1(x))` of a single graph, `[n,
    /// hidden]` row-major: the same for every sample.
    #[cfg(test)]
    pub(crate) fn first_layer(
        &self,
        g: &GraphTensors,
    ) -> Result<Vec<f32>, super::backend::TensorRead> {
        super::backend::values(activation::relu(self.conv1.forward(g.x.clone(), g)))
    }

    /// The scores Sinkhorn normalises, `[B, T, N1, N2]`: `scale ll + gate
    /// residual`, [`BLOCKED`] where a gate closes or a node is padding.
    pub(crate) fn scores(&self, pair: &PairTensors, residual: Tensor<4>) -> Tensor<4> {
        let scale = self.log_scale.val().exp().reshape([1, 1, 1, 1]);
        let gate = self.gate.val().reshape([1, 1, 1, 1]);
        let s = pair.ll.clone() * scale + residual * gate;
        let [b, t, n1, n2] = s.dims();
        s.mask_fill(pair.blocked.clone().expand([b, t, n1, n2]), BLOCKED)
    }

    /// Each node's "no match" score after its gate, `[B, 1, N]`.
    pub(crate) fn dust_scores(&self, dust: Tensor<3>) -> Tensor<3> {
        let gate = self.dust_gate.val().reshape([1, 1, 1]);
        self.dustbin.val().reshape([1, 1, 1]) + dust * gate
    }

    /// The pair part from both graphs' embeddings ([`Self::embed`]): the
    /// residual is the embeddings' similarity `H H'^T` (Eq. 2), a small
    /// MLP on the pair's features, and with consensus the DGMC term
    /// `phi(D)` (Eq. 3) whose soft correspondence is the softmax of the
    /// full scores (likelihood and residual so far, with a "no match"
    /// column), so that consensus starts from where the positions put the
    /// objects.
    pub(crate) fn pair(
        &self,
        first: (&Tensor<4>, &GraphTensors),
        second: (&Tensor<4>, &GraphTensors),
        pair: &PairTensors,
        masks: PairMasks,
    ) -> PairOutput {
        let ((h1, g1), (h2, g2)) = (first, second);
        let mlp = |a: &Linear, b: &Linear, x: Tensor<4>| b.forward(activation::relu(a.forward(x)));
        let [b, n1, n2, _] = pair.pair_features.dims();
        let pair_term =
            mlp(&self.pair_in, &self.pair_out, pair.pair_features.clone()).reshape([b, 1, n1, n2]);
        let dust = |x: &Tensor<3>, n: usize| {
            let x = x.clone().unsqueeze_dim::<4>(1); // [B, 1, N, F]
            mlp(&self.dust_in, &self.dust_out, x).reshape([b, 1, n])
        };
        let dust = [
            dust(&pair.dust_features[0], n1),
            dust(&pair.dust_features[1], n2),
        ];
        let mut residual = h1.clone().matmul(h2.clone().swap_dims(2, 3)) + pair_term; // [B, T, N1, N2]
        if let (Some(conv), Some(phi_in), Some(phi_out)) =
            (&self.consensus_conv, &self.phi_in, &self.phi_out)
        {
            let t = residual.dims()[1];
            let s = self.scores(pair, residual.clone());
            let bin = self
                .dust_scores(dust[0].clone())
                .reshape([b, 1, n1, 1])
                .expand([b, t, n1, 1]);
            let soft = activation::softmax(Tensor::cat(vec![s, bin], 3), 3).slice([
                0..b,
                0..t,
                0..n1,
                0..n2,
            ]); // [B, T, N1, N2]
            let r1 = masks.indicators * g1.node_mask.clone(); // [B, 1, N1, r]
            let r2 = soft.swap_dims(2, 3).matmul(r1.clone()); // [B, T, N2, r]
            let z1 = activation::relu(conv.forward(r1, g1)); // [B, 1, N1, r]
            let z2 = activation::relu(conv.forward(r2, g2)); // [B, T, N2, r]
            let d = z1.unsqueeze_dim::<5>(3) - z2.unsqueeze_dim::<5>(2); // [B, T, N1, N2, r]
            let hidden = activation::relu(phi_in.forward(d)) * masks.phi;
            residual = residual + phi_out.forward(hidden).reshape([b, t, n1, n2]);
        }
        PairOutput { residual, dust }
    }

    /// Log of the soft assignment with dustbins, `[B, T, N1 + 1, N2 + 1]`,
    /// for training: embeddings, pair part and Sinkhorn in one pass.
    pub(crate) fn forward(
        &self,
        graphs: [&GraphTensors; 2],
        pair: &PairTensors,
        masks: Masks,
        sinkhorn_iters: usize,
    ) -> Tensor<4> {
        let [g1, g2] = graphs;
        let [c1a, c1b] = masks.conv1;
        let [c2a, c2b] = masks.conv2;
        let h1 = self.embed(g1, c1a, c2a);
        let h2 = self.embed(g2, c1b, c2b);
        let out = self.pair((&h1, g1), (&h2, g2), pair, masks.pair);
        let scores = self.scores(pair, out.residual);
        let [d1, d2] = out.dust.map(|d| self.dust_scores(d));
        log_sinkhorn(
            scores,
            [d1, d2],
            self.dustbin.val(),
            [&g1.counts, &g2.counts],
            sinkhorn_iters,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::deep::graph::OffsetGraph;
    use crate::matching::deep::train::weights::to_bytes;
    use crate::matching::testkit::graph_input;
    use rand::{Rng, SeedableRng};

    /// A pair input with random likelihoods (every fourth pair gated) and
    /// features.
    fn random_pair(n1: usize, n2: usize, seed: u64) -> PairInput {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        PairInput {
            n1,
            n2,
            log_likelihood: (0..n1 * n2)
                .map(|k| (k % 4 != 1).then(|| r.random_range(-6.0..0.0)))
                .collect(),
            pair_features: (0..n1 * n2 * PAIR_FEATURES)
                .map(|_| r.random_range(0.0..1.0))
                .collect(),
            dust_features: [n1, n2].map(|n| {
                (0..n * DUST_FEATURES)
                    .map(|_| r.random_range(0.0..1.0))
                    .collect()
            }),
        }
    }

    /// Consensus indicators `[b, 1, n1, r]` that depend on the node only,
    /// zero on padding.
    fn node_indicators([b, n1, r]: [usize; 3], counts: &[usize], device: &Device) -> Tensor<4> {
        let v: Vec<f32> = (0..b * n1 * r)
            .map(|k| {
                let (pair, node, dim) = (k / (n1 * r), (k / r) % n1, k % r);
                if node < counts[pair] {
                    ((node * 7 + dim) as f32 * 0.37).sin()
                } else {
                    0.0
                }
            })
            .collect();
        Tensor::<4>::from_data(TensorData::new(v, [b, 1, n1, r]), device)
    }

    /// Two pairs of different sizes in one padded batch give each pair's
    /// log assignment as it is alone, and the padding carries no mass.
    #[test]
    fn a_padded_batch_equals_its_pairs_alone() {
        let device = crate::matching::deep::train::backend::device();
        let arch = Architecture {
            dropout_conv: 0.0,
            dropout_phi: 0.0,
            ..Architecture::default()
        };
        let mut net = OursNet::new(&arch, Init::Seeded(2), &device);
        // Open the gates so that the residual and the learned "no match"
        // scores count.
        net.gate = crate::matching::deep::train::init::named_param(
            "gate",
            Tensor::from_data(TensorData::new(vec![0.3f32], [1]), &device),
        );
        net.dust_gate = crate::matching::deep::train::init::named_param(
            "dust_gate",
            Tensor::from_data(TensorData::new(vec![0.5f32], [1]), &device),
        );
        let small = [
            graph_input(&[(0.0, 0.0), (10.0, 2.0), (3.0, 9.0)]),
            graph_input(&[(1.0, 1.0), (9.0, 3.0)]),
        ];
        let large = [
            graph_input(&[
                (0.0, 0.0),
                (12.0, 3.0),
                (5.0, 20.0),
                (-9.0, 14.0),
                (30.0, -20.0),
            ]),
            graph_input(&[(2.0, 0.0), (11.0, 4.0), (6.0, 18.0), (-8.0, 12.0)]),
        ];
        let pairs = [random_pair(3, 2, 1), random_pair(5, 4, 2)];
        let graphs = [&small, &large];
        let run = |which: &[usize]| -> Vec<Vec<f32>> {
            let g1: Vec<&OffsetGraph> = which.iter().map(|&k| &graphs[k][0]).collect();
            let g2: Vec<&OffsetGraph> = which.iter().map(|&k| &graphs[k][1]).collect();
            let (b1, b2) = (
                GraphTensors::new(&g1, &device),
                GraphTensors::new(&g2, &device),
            );
            let (n1, n2) = (b1.n(), b2.n());
            let inputs: Vec<&PairInput> = which.iter().map(|&k| &pairs[k]).collect();
            let tensors = PairTensors::new(&inputs, [n1, n2], &device);
            let b = which.len();
            let ones = |n: usize, d: usize| Tensor::<4>::ones([b, 2, n, d], &device);
            let masks = Masks {
                conv1: [ones(n1, arch.hidden), ones(n2, arch.hidden)],
                conv2: [ones(n1, arch.out), ones(n2, arch.out)],
                pair: PairMasks {
                    phi: Tensor::ones([b, 2, n1, n2, arch.consensus_dim], &device),
                    indicators: node_indicators([b, n1, arch.consensus_dim], &b1.counts, &device),
                },
            };
            let p = net.forward([&b1, &b2], &tensors, masks, 20).exp();
            let v: Vec<f32> = p.try_into_vec_as::<f32>().unwrap();
            // Per pair, sample 0, its real rows and columns with dustbins.
            which
                .iter()
                .enumerate()
                .map(|(slot, &k)| {
                    let (m1, m2) = (pairs[k].n1, pairs[k].n2);
                    let at = |i: usize, j: usize| v[((slot * 2) * (n1 + 1) + i) * (n2 + 1) + j];
                    let rows = (0..m1).chain([n1]);
                    rows.flat_map(|i| (0..m2).chain([n2]).map(move |j| (i, j)))
                        .map(|(i, j)| at(i, j))
                        .collect()
                })
                .collect()
        };
        let together = run(&[0, 1]);
        let alone = [run(&[0]).remove(0), run(&[1]).remove(0)];
        for (t, a) in together.iter().zip(&alone) {
            assert_eq!(t.len(), a.len());
            for (x, y) in t.iter().zip(a) {
                assert!((x - y).abs() < 1e-5, "{x} vs {y}");
            }
        }
        // The small pair's rows are real rows of the padded batch: each
        // sums to 1 without the padded columns.
        let m2 = pairs[0].n2 + 1;
        for row in together[0].chunks(m2).take(pairs[0].n1) {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-3, "{row:?}");
        }
    }

    #[test]
    fn seeded_initialisation_is_named_per_parameter() {
        let device = crate::matching::deep::train::backend::device();
        let arch = Architecture::default();
        let bytes = |init| to_bytes(&OursNet::new(&arch, init, &device)).unwrap();
        // Same seed, same weights (and the same bytes: parameter ids are
        // named too); another seed, other weights.
        assert_eq!(bytes(Init::Seeded(4)), bytes(Init::Seeded(4)));
        assert_ne!(bytes(Init::Seeded(4)), bytes(Init::Seeded(5)));
        // A parameter's draws do not depend on which other layers exist:
        // the first layer is the same with and without consensus.
        let first_layer = |consensus: bool| {
            let a = Architecture {
                consensus_steps: usize::from(consensus),
                ..Architecture::default()
            };
            let net = OursNet::new(&a, Init::Seeded(4), &device);
            net.conv1.weight().try_into_vec_as::<f32>().unwrap()
        };
        assert_eq!(first_layer(true), first_layer(false));
        // The gates start closed and the scale at 1.
        let c = OursNet::new(&arch, Init::Seeded(4), &device).combination();
        assert_eq!((c.scale, c.gate, c.dust_gate), (1.0, 0.0, 0.0));
    }
}
