//! The network (burn): the only code in the crate that sees tensors.
//!
//! - `SplineConv`: a SplineCNN layer (Fey et al. 2018) with degree-1 open
//!   B-splines over 2-D pseudo-coordinates, `KERNEL` knots per dimension,
//!   mean aggregation and a root weight (paper Eq. 1).
//! - Psi: two `SplineConv`s (hidden 256, output 32), each followed by ReLU
//!   and dropout 0.4.
//! - Scores: the shared pair log-likelihood ([`crate::matching::likelihood`],
//!   the one GPS+appearance Hungarian decides on), scaled, plus a gated
//!   residual: the similarity `H H'^T` (Eq. 2), a small MLP on the pair's
//!   features, and the DGMC neighbourhood consensus `phi(D)` (Eq. 3:
//!   random node indicators pushed through the soft correspondence of the
//!   full scores, embedded by a consensus `SplineConv`, compared, and scored
//!   by an MLP with dropout 0.2). The gate starts at 0 and the scale at 1:
//!   an untrained network scores every pair exactly as the likelihood
//!   does, and learns only what improves on it.
//! - Log-domain Sinkhorn with a dustbin row and column (Eq. 4 with "no
//!   match", as SuperGlue), whose entries are a learned common score plus a
//!   gated per-node score from where the node lies for both vehicles.
//!   Inference runs the same iterations without tensors, in the scaling
//!   domain ([`sinkhorn_probabilities`]).
//! - Batches: training pairs are padded to a common size and run as one
//!   tensor pass; padding is masked out of messages, consensus, Sinkhorn
//!   (zero marginals) and losses.
//!
//! Dropout masks are drawn by the caller from a seeded stream and applied
//! here as tensors, on any device: burn's `Dropout` is a no-op outside
//! autodiff training, and MC dropout needs masks at inference. The T Monte
//! Carlo samples are the second dimension (`[B, T, ...]`); the first
//! layer, whose input does not depend on any mask, is computed once.
//!
//! Initial weights come from named streams ([`Init`]), one per parameter,
//! never from burn's own generator. Weights leave and enter as bytes
//! (burn's burnpack format, [`to_bytes`] / [`from_bytes`]); files are the
//! caller's business.

use burn::module::{Param, ParamId};
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation;
use rand::Rng;
use std::sync::Arc;

use super::features::{DUST_FEATURES, GraphInput, KERNEL_2D, PAIR_FEATURES, PairInput};
use crate::rng::{self, Purpose};

/// Where a new network's weights come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Init {
    /// Uniform draws from the stream `(seed, WeightInit, hash(parameter
    /// name))`: the same seed gives the same weights, whatever else was
    /// drawn before.
    Seeded(u64),
    /// Zeros: a skeleton about to receive trained weights.
    Zeros,
}

impl Init {
    /// A tensor of `shape` drawn uniformly from `(-bound, bound)`.
    fn uniform<const D: usize>(
        self,
        name: &str,
        shape: [usize; D],
        bound: f64,
        device: &Device,
    ) -> Tensor<D> {
        match self {
            Init::Seeded(seed) if bound > 0.0 => {
                let mut s = rng::stream(seed, Purpose::WeightInit, &[rng::hash_str(name)]);
                let n = shape.iter().product();
                let v: Vec<f32> = (0..n)
                    .map(|_| s.random_range(-bound..bound) as f32)
                    .collect();
                Tensor::from_data(TensorData::new(v, shape), device)
            }
            _ => Tensor::zeros(shape, device),
        }
    }

    /// The parameter `name`, drawn uniformly from `(-bound, bound)`.
    fn param<const D: usize>(
        self,
        name: &str,
        shape: [usize; D],
        bound: f64,
        device: &Device,
    ) -> Param<Tensor<D>> {
        named_param(name, self.uniform(name, shape, bound, device))
    }

    /// A linear layer `[d_in] -> [d_out]` initialised like burn's default
    /// (weight and bias uniform in `+-1/sqrt(d_in)`).
    fn linear(self, name: &str, d_in: usize, d_out: usize, device: &Device) -> Linear {
        let b = 1.0 / (d_in as f64).sqrt();
        Linear {
            weight: self.param(&format!("{name}.weight"), [d_in, d_out], b, device),
            bias: Some(self.param(&format!("{name}.bias"), [d_out], b, device)),
        }
    }
}

/// A trainable parameter whose id is derived from its name (burn draws
/// ids at random, which would make saved weights differ from run to run).
fn named_param<const D: usize>(name: &str, value: Tensor<D>) -> Param<Tensor<D>> {
    // Through `Parameter`: a tensor without autodiff is left as it is.
    let value = <Tensor<D> as burn::module::Parameter>::set_require_grad(value, true);
    Param::initialized(ParamId::from(rng::hash_str(name)), value)
}

/// The score of a gated or padded entry, in the log domain: its
/// probability under Sinkhorn is `exp(-1e4)`, zero in `f32`.
pub const BLOCKED: f32 = -1.0e4;

/// Graphs as tensors, padded to a common node count `N` (a batch of
/// training pairs' graphs, or one graph at inference, `B = 1`).
pub struct GraphBatch {
    /// Real nodes of each graph.
    pub counts: Vec<usize>,
    /// `[B, 1, N, F]` node attributes (zeros for padding).
    pub x: Tensor<4>,
    /// The kernel cells whose messages are computed (ascending), as
    /// indices `[C]`: all of them, or only those some edge uses.
    pub cells: Tensor<1, Int>,
    /// `[B, 1, N, N * C]`: entry `[b, 0, i, j C + c]` is the basis weight
    /// of cell `cells[c]` of edge j -> i over the degree of i (zero when j
    /// is not a neighbour of i, and for padding). Columns run node-major
    /// so that the messages `x W` need only a reshape.
    pub mixing: Tensor<4>,
    /// `[B, 1, N * C, N]`: the same weights with rows (i, cell) and
    /// columns j, for layers that mix neighbours before their weights.
    pub mixing_by_cell: Tensor<4>,
    /// `[B, 1, N, 1]`: 1 for a real node, 0 for padding.
    pub node_mask: Tensor<4>,
    /// Directed edges over the whole batch (0: no messages at all).
    pub edges: usize,
    /// Bit k set when kernel cell k is in `cells`.
    pub cell_mask: u32,
    /// The spline layers' weights of exactly these cells, when the caller
    /// has them ([`Network::cell_weights`]); else each layer selects them.
    pub weights: Option<Arc<CellWeights>>,
}

/// Every spline layer's weights of one set of kernel cells (`[in, C *
/// out]` each): what [`SplineConv::forward`] would select, kept by a
/// caller that sees the same cell set many times (inference).
pub struct CellWeights {
    /// The cell set, as [`GraphBatch::cell_mask`].
    cell_mask: u32,
    conv1: Tensor<2>,
    conv2: Tensor<2>,
    consensus: Option<Tensor<2>>,
}

impl GraphBatch {
    /// Graphs padded to the largest, with every kernel cell (training:
    /// the gradient of a cell selection costs more than the messages it
    /// saves).
    pub fn new(graphs: &[&GraphInput], device: &Device) -> Self {
        Self::with_cells(graphs, [true; KERNEL_2D], device)
    }

    /// One graph with only the kernel cells some edge uses (inference).
    pub fn used_cells(g: &GraphInput, device: &Device) -> Self {
        let mut used = [false; KERNEL_2D];
        for &k in &g.basis_index {
            used[k as usize] = true;
        }
        Self::with_cells(&[g], used, device)
    }

    fn with_cells(graphs: &[&GraphInput], used: [bool; KERNEL_2D], device: &Device) -> Self {
        let b = graphs.len();
        let n = graphs.iter().map(|g| g.n).max().unwrap_or(0).max(1);
        let f = super::features::NODE_FEATURES;
        let cells: Vec<i64> = (0..KERNEL_2D as i64)
            .filter(|&k| used[k as usize])
            .collect();
        let c = cells.len();
        let mut position = [0usize; KERNEL_2D];
        for (p, &k) in cells.iter().enumerate() {
            position[k as usize] = p;
        }
        let mut x = vec![0f32; b * n * f];
        let mut mixing = vec![0f32; b * n * n * c];
        let mut by_cell = vec![0f32; b * n * n * c];
        let mut node_mask = vec![0f32; b * n];
        let mut edges = 0;
        for (k, g) in graphs.iter().enumerate() {
            x[k * n * f..k * n * f + g.n * f].copy_from_slice(&g.node_features);
            node_mask[k * n..k * n + g.n].fill(1.0);
            let e = g.edge_count();
            edges += e;
            let block = k * n * n * c..(k + 1) * n * n * c;
            let (m, t) = (&mut mixing[block.clone()], &mut by_cell[block]);
            for edge in 0..e {
                let (i, j) = (g.dst[edge] as usize, g.src[edge] as usize);
                let inv_deg = g.aggregate[i * e + edge];
                for q in 0..4 {
                    let cell = position[g.basis_index[4 * edge + q] as usize];
                    let w = g.basis_weight[4 * edge + q] * inv_deg;
                    m[i * c * n + j * c + cell] += w;
                    t[(i * c + cell) * n + j] += w;
                }
            }
        }
        Self {
            counts: graphs.iter().map(|g| g.n).collect(),
            x: Tensor::from_data(TensorData::new(x, [b, 1, n, f]), device),
            cell_mask: cells.iter().map(|&k| 1u32 << k).sum(),
            cells: Tensor::from_data(TensorData::new(cells, [c]), device),
            mixing: Tensor::from_data(TensorData::new(mixing, [b, 1, n, n * c]), device),
            mixing_by_cell: Tensor::from_data(TensorData::new(by_cell, [b, 1, n * c, n]), device),
            node_mask: Tensor::from_data(TensorData::new(node_mask, [b, 1, n, 1]), device),
            edges,
            weights: None,
        }
    }

    /// Nodes per graph after padding.
    pub fn n(&self) -> usize {
        self.x.dims()[2]
    }

    /// With the spline layers' weights of this batch's cells; weights of
    /// another cell set are ignored (the layers then select their own).
    pub fn with_weights(mut self, weights: Arc<CellWeights>) -> Self {
        if weights.cell_mask == self.cell_mask {
            self.weights = Some(weights);
        }
        self
    }
}

#[derive(Module, Debug)]
pub struct SplineConv {
    /// `[in, KERNEL_2D * out]`: the kernel cells' weight matrices side by
    /// side.
    weight: Param<Tensor<2>>,
    /// `[in, out]`
    root: Param<Tensor<2>>,
    /// `[out]`
    bias: Param<Tensor<1>>,
    d_out: usize,
}

impl SplineConv {
    /// A layer named `name` (the parameter names of its streams).
    pub fn new(name: &str, d_in: usize, d_out: usize, init: Init, device: &Device) -> Self {
        // Uniform(+-1/sqrt(fan_in)) with the fan-in of one kernel cell.
        let b = 1.0 / (d_in as f64).sqrt();
        let weight = [d_in, KERNEL_2D * d_out];
        Self {
            weight: init.param(&format!("{name}.weight"), weight, b, device),
            root: init.param(&format!("{name}.root"), [d_in, d_out], b, device),
            bias: named_param(&format!("{name}.bias"), Tensor::zeros([d_out], device)),
            d_out,
        }
    }

    /// `x: [B, T, N, in] -> [B, T, N, out]` (T samples of each graph):
    /// `root x_i + mean_j sum_k B_k(u_ij) W_k x_j + b`, as two dense
    /// products in the cheaper order: with more inputs than outputs,
    /// `XW = x [W_k ..]` for every kernel cell of the batch at once, then
    /// the neighbour-and-cell mixing `A [N C]` against `XW` read as one row
    /// per (neighbour, cell); with fewer, the mixing first (`A` by cell
    /// against x, one row per (node, cell)), then the cells' weights
    /// stacked.
    ///
    /// `selected`: this layer's weights of the batch's cells in the order's
    /// layout, if the caller keeps them ([`CellWeights`]).
    pub fn forward(&self, x: Tensor<4>, g: &GraphBatch, selected: Option<&Tensor<2>>) -> Tensor<4> {
        let d_out = self.d_out;
        let [b, t, n, d_in] = x.dims();
        // Every node of every graph and sample as one row: one large
        // product with the shared weights instead of B T small ones.
        let rows = x.clone().reshape([b * t * n, d_in]);
        let root = rows
            .clone()
            .matmul(self.root.val())
            .reshape([b, t, n, d_out]);
        let bias = self.bias.val().reshape([1, 1, 1, d_out]);
        if g.edges == 0 {
            return root + bias;
        }
        let c = g.cells.dims()[0];
        let w = match selected {
            Some(w) => w.clone(),
            None => self.cell_weights(&g.cells),
        };
        let messages = if self.mixes_first() {
            let mixed = g.mixing_by_cell.clone().matmul(x); // [B, T, N C, in]
            mixed
                .reshape([b * t * n, c * d_in])
                .matmul(w)
                .reshape([b, t, n, d_out])
        } else {
            let xw = rows.matmul(w).reshape([b, t, n * c, d_out]); // rows (j, cell), no copy
            g.mixing.clone().matmul(xw) // [B, 1, N, N C] x [B, T, N C, out]
        };
        root + messages + bias
    }

    /// Whether the neighbours are mixed before the weights (fewer inputs
    /// than outputs).
    fn mixes_first(&self) -> bool {
        self.root.val().dims()[0] < self.d_out
    }

    /// The weights of the kernel cells `cells` in the layout of
    /// [`Self::forward`]'s order: `[in, C * out]`, or `[C * in, out]`
    /// when it mixes first.
    fn cell_weights(&self, cells: &Tensor<1, Int>) -> Tensor<2> {
        let c = cells.dims()[0];
        let d_in = self.root.val().dims()[0];
        let w = self.weight.val().reshape([d_in, KERNEL_2D, self.d_out]);
        let w = if c == KERNEL_2D {
            w
        } else {
            w.select(1, cells.clone())
        };
        if self.mixes_first() {
            w.swap_dims(0, 1).reshape([c * d_in, self.d_out])
        } else {
            w.reshape([d_in, c * self.d_out])
        }
    }
}

/// Architecture and regularisation of one matcher variant.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Architecture {
    pub node_features: usize,
    pub hidden: usize,
    pub out: usize,
    pub dropout_conv: f64,
    /// DGMC neighbourhood consensus on (`dgmc`, `ours`, ablations) or off
    /// (`gcn-gm`).
    pub consensus: bool,
    pub consensus_dim: usize,
    pub dropout_phi: f64,
    pub sinkhorn_iters: usize,
    /// Whether the shared likelihood has its position term (and the
    /// network sees where each node lies from the other vehicle): every
    /// deep method but `ours-noprior`, the paper's network as published,
    /// which must match on appearance and structure.
    pub positions: bool,
    /// Hidden units of the pair MLP and of the "no match" MLP.
    pub pair_hidden: usize,
}

impl Default for Architecture {
    fn default() -> Self {
        Self {
            node_features: super::features::NODE_FEATURES,
            hidden: 256,
            out: 32,
            dropout_conv: 0.4,
            consensus: true,
            consensus_dim: 32,
            dropout_phi: 0.2,
            sinkhorn_iters: 20,
            positions: true,
            pair_hidden: 32,
        }
    }
}

/// The pair inputs of a batch as tensors (see [`super::features::PairInput`]).
pub struct PairTensors {
    /// `[B, 1, N1, N2]` the shared log-likelihood (0 where blocked).
    pub ll: Tensor<4>,
    /// `[B, 1, N1, N2]` true where the pair is gated or a node is padding.
    pub blocked: Tensor<4, Bool>,
    /// `[B, N1, N2, PAIR_FEATURES]`
    pub pair_features: Tensor<4>,
    /// `[B, N1, DUST_FEATURES]` and `[B, N2, DUST_FEATURES]`.
    pub dust_features: [Tensor<3>; 2],
}

impl PairTensors {
    /// Pair inputs padded to `n1 x n2`.
    pub fn new(inputs: &[&PairInput], [n1, n2]: [usize; 2], device: &Device) -> Self {
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

/// The masks of the pair part of a forward pass: consensus dropout and
/// the random node indicators.
pub struct PairMasks {
    /// `[B, T, N1, N2, consensus_dim]`.
    pub phi: Tensor<5>,
    /// `[B, 1, N1, consensus_dim]`.
    pub indicators: Tensor<4>,
}

/// What the pair part of the network says, before its gates: the
/// residual of every pair in every sample, `[B, T, N1, N2]`, and the
/// learned "no match" score of every node, `[B, 1, N1]` and `[B, 1, N2]`.
pub struct PairOutput {
    pub residual: Tensor<4>,
    pub dust: [Tensor<3>; 2],
}

/// The scalar parameters that combine the shared likelihood with what the
/// network learned: score = `scale` ll + `gate` residual; a node's "no
/// match" score = `dustbin` + `dust_gate` (its learned score). At
/// initialisation scale is 1 and both gates 0: the scores are the shared
/// likelihood itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Combination {
    pub scale: f32,
    pub gate: f32,
    pub dustbin: f32,
    pub dust_gate: f32,
}

#[derive(Module, Debug)]
pub struct Network {
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

/// The dustbin score before training: a pair is more likely matched than
/// not about where its log-likelihood passes this (a squared Mahalanobis
/// distance of 6 at identical looks).
const INITIAL_DUSTBIN: f32 = -3.0;

impl Network {
    pub fn new(arch: &Architecture, init: Init, device: &Device) -> Self {
        let r = arch.consensus_dim;
        let (consensus_conv, phi_in, phi_out) = if arch.consensus {
            (
                Some(SplineConv::new("consensus_conv", r, r, init, device)),
                Some(init.linear("phi_in", r, r, device)),
                Some(init.linear("phi_out", r, 1, device)),
            )
        } else {
            (None, None, None)
        };
        let scalar = |name: &str, v: f32| {
            named_param(
                name,
                Tensor::from_data(TensorData::new(vec![v], [1]), device),
            )
        };
        let h = arch.pair_hidden;
        Self {
            conv1: SplineConv::new("conv1", arch.node_features, arch.hidden, init, device),
            conv2: SplineConv::new("conv2", arch.hidden, arch.out, init, device),
            consensus_conv,
            phi_in,
            phi_out,
            pair_in: init.linear("pair_in", PAIR_FEATURES, h, device),
            pair_out: init.linear("pair_out", h, 1, device),
            dust_in: init.linear("dust_in", DUST_FEATURES, h, device),
            dust_out: init.linear("dust_out", h, 1, device),
            log_scale: scalar("log_scale", 0.0),
            gate: scalar("gate", 0.0),
            dustbin: scalar("dustbin", INITIAL_DUSTBIN),
            dust_gate: scalar("dust_gate", 0.0),
        }
    }

    /// The same network with its gates opened to `gate` (residual and
    /// per-node "no match" scores): what training does first, for tests
    /// of the gated parts without training.
    #[cfg(test)]
    pub fn with_gates(mut self, gate: f32) -> Self {
        let device = self.gate.val().device();
        let value = |v: f32| Tensor::from_data(TensorData::new(vec![v], [1]), &device);
        self.gate = named_param("gate", value(gate));
        self.dust_gate = named_param("dust_gate", value(gate));
        self
    }

    /// The scalar parameters, read once (inference).
    pub fn combination(&self) -> Combination {
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
    pub fn embed(&self, g: &GraphBatch, mask1: Tensor<4>, mask2: Tensor<4>) -> Tensor<4> {
        // The first layer's input is the same for every sample: compute once.
        let w = g.weights.as_deref();
        let h = activation::relu(self.conv1.forward(g.x.clone(), g, w.map(|w| &w.conv1)));
        let h = h * mask1; // [B, T, N, hidden]
        activation::relu(self.conv2.forward(h, g, w.map(|w| &w.conv2))) * mask2
    }

    /// Every spline layer's weights of the kernel cells of `g`, for
    /// [`GraphBatch::with_weights`] on graphs with the same cells.
    pub fn cell_weights(&self, g: &GraphBatch) -> CellWeights {
        CellWeights {
            cell_mask: g.cell_mask,
            conv1: self.conv1.cell_weights(&g.cells),
            conv2: self.conv2.cell_weights(&g.cells),
            consensus: self
                .consensus_conv
                .as_ref()
                .map(|c| c.cell_weights(&g.cells)),
        }
    }

    /// The scores Sinkhorn normalises, `[B, T, N1, N2]`: `scale ll + gate
    /// residual`, [`BLOCKED`] where a gate closes or a node is padding.
    pub fn scores(&self, pair: &PairTensors, residual: Tensor<4>) -> Tensor<4> {
        let scale = self.log_scale.val().exp().reshape([1, 1, 1, 1]);
        let gate = self.gate.val().reshape([1, 1, 1, 1]);
        let s = pair.ll.clone() * scale + residual * gate;
        let [b, t, n1, n2] = s.dims();
        s.mask_fill(pair.blocked.clone().expand([b, t, n1, n2]), BLOCKED)
    }

    /// Each node's "no match" score after its gate, `[B, 1, N]`.
    pub fn dust_scores(&self, dust: Tensor<3>) -> Tensor<3> {
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
    pub fn pair(
        &self,
        first: (&Tensor<4>, &GraphBatch),
        second: (&Tensor<4>, &GraphBatch),
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
            let w = |g: &GraphBatch| g.weights.as_ref().and_then(|w| w.consensus.clone());
            let z1 = activation::relu(conv.forward(r1, g1, w(g1).as_ref())); // [B, 1, N1, r]
            let z2 = activation::relu(conv.forward(r2, g2, w(g2).as_ref())); // [B, T, N2, r]
            let d = z1.unsqueeze_dim::<5>(3) - z2.unsqueeze_dim::<5>(2); // [B, T, N1, N2, r]
            let hidden = activation::relu(phi_in.forward(d)) * masks.phi;
            residual = residual + phi_out.forward(hidden).reshape([b, t, n1, n2]);
        }
        PairOutput { residual, dust }
    }

    /// Log of the soft assignment with dustbins, `[B, T, N1 + 1, N2 + 1]`,
    /// for training: embeddings, pair part and Sinkhorn in one pass.
    pub fn forward(
        &self,
        graphs: [&GraphBatch; 2],
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

/// The dropout masks of one training forward pass with T samples (values
/// 0 or 1 / (1 - p), inverted dropout).
pub struct Masks {
    /// `[B, T, N1, hidden]`, `[B, T, N2, hidden]`.
    pub conv1: [Tensor<4>; 2],
    /// `[B, T, N1, out]`, `[B, T, N2, out]`.
    pub conv2: [Tensor<4>; 2],
    pub pair: PairMasks,
}

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
pub fn log_sinkhorn(
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
pub fn sinkhorn_probabilities(
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
    let mut kernel = vec![0f64; rows * cols];
    let (mut u, mut v) = (vec![0f64; rows], vec![1f64; cols]);
    let mut column_sums = vec![0f64; cols];
    for sample in 0..t {
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
                kernel[i * cols + j] = (z(j) - row_max).exp();
            }
        }
        v.fill(1.0);
        for _ in 0..iters {
            for (i, ui) in u.iter_mut().enumerate() {
                let row = &kernel[i * cols..(i + 1) * cols];
                *ui = mu(i) / row.iter().zip(&v).map(|(k, vj)| k * vj).sum::<f64>();
            }
            column_sums.fill(0.0);
            for (row, ui) in kernel.chunks_exact(cols).zip(&u) {
                for (sum, k) in column_sums.iter_mut().zip(row) {
                    *sum += k * ui;
                }
            }
            for (j, vj) in v.iter_mut().enumerate() {
                *vj = nu(j) / column_sums[j];
            }
        }
        for (row, ui) in kernel.chunks_exact(cols).zip(&u) {
            out.extend(
                row.iter()
                    .zip(&v)
                    .map(|(k, vj)| (ui * k * vj * total) as f32),
            );
        }
    }
    out
}

crate::label_enum! { "pair loss";
    /// The term of the loss that teaches which pairs are the same object.
    #[strum(serialize_all = "lowercase")]
    pub enum PairLoss {
        /// The log-likelihood of the true assignment with dustbins
        /// (SuperGlue): `-log P_ij` of every true pair and `-log P` of the
        /// dustbin of every node without a partner, the two halves weighed
        /// equally (each a mean of its own).
        Likelihood,
        /// The paper's Eq. 11: `-log(sum(P o Y*) / n_true)`.
        Paper,
    }
}

/// Which terms a variant trains with: a pair term, and the paper's
/// Eq. 12 (`non`) and Eq. 13 (`unc`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LossTerms {
    pub pairs: PairLoss,
    pub non: bool,
    pub unc: bool,
}

/// The labels of a batch as tensors.
pub struct LabelTensors {
    /// `[B, N1, N2]` 1 for a true pair that passes the gates.
    pub y: Tensor<3>,
    /// `[B, N1]`, `[B, N2]`: 1 for a real node with no true partner.
    pub free: [Tensor<2>; 2],
    /// `[B, N1, N2]` 1 where row i or column j is a non-covisible object.
    pub non: Tensor<3>,
    /// `[B, N1, N2]` 1 for an entry between real nodes.
    pub real: Tensor<3>,
    /// `[B]` per pair: true pairs, free nodes, real entries (each >= 1).
    pub counts: [Tensor<1>; 3],
}

/// The mean training loss of a batch. `log_assign`: `[B, T, N1 + 1, N2 +
/// 1]`. With P = E[Y], the mean assignment over the T samples:
/// - the pair term ([`PairLoss`]);
/// - `L_non = -log(mean(exp(-P o N)))` over the real entries (Eq. 12);
/// - `L_unc = -log(mean(exp(-H(P))))` with H the binary entropy in bits
///   (Eq. 13), on the mean of the T samples.
pub fn loss(log_assign: Tensor<4>, labels: &LabelTensors, terms: LossTerms) -> Tensor<1> {
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
        let kept = per_pair((-(p.clone() * labels.non.clone())).exp() * labels.real.clone());
        total = total - (kept / n_real.clone()).log();
    }
    if terms.unc {
        let q = p.clamp(1e-6, 1.0 - 1e-6);
        let one_minus = q.clone().neg() + 1.0;
        let h =
            -(q.clone() * q.log() + one_minus.clone() * one_minus.log()) / std::f32::consts::LN_2;
        let kept = per_pair(h.neg().exp() * labels.real.clone());
        total = total - (kept / n_real).log();
    }
    total.mean()
}

/// The network's weights as bytes (burn's burnpack format, what a
/// `<method>.bpk` file holds).
pub fn to_bytes(net: &Network) -> Result<Vec<u8>, String> {
    let bytes = net
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| format!("{e:?}"))?;
    Ok(bytes.to_vec())
}

/// A network of architecture `arch` on `device` with the weights of
/// [`to_bytes`]; weights whose scalar parameters are not finite are
/// refused.
pub fn from_bytes(arch: &Architecture, bytes: &[u8], device: &Device) -> Result<Network, String> {
    let record =
        burn::store::ModuleRecord::from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec()))
            .map_err(|e| format!("{e:?}"))?;
    let net = Network::new(arch, Init::Zeros, device)
        .try_load_record(record)
        .map_err(|e| format!("{e:?}"))?;
    let mut finite = AllFinite(true);
    net.visit(&mut finite);
    if !finite.0 {
        return Err("the weights hold a value that is not a finite number".into());
    }
    Ok(net)
}

/// Whether every float parameter of a module is finite.
struct AllFinite(bool);

impl burn::module::ModuleVisitor for AllFinite {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.0 {
            let data = param.val().into_data();
            self.0 = data.iter::<f32>().all(f32::is_finite);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Pose2, Vec2};
    use crate::graph::SceneGraph;
    use rand::SeedableRng;

    fn graph_input(points: &[(f64, f64)]) -> GraphInput {
        let positions: Vec<Vec2> = points.iter().map(|&(x, y)| Vec2::new(x, y)).collect();
        let scene = SceneGraph::delaunay(&positions).unwrap();
        let detections: Vec<crate::sensor::Detection> = positions
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let class = crate::traffic::ObjectClass::ALL[k % 7];
                crate::matching::testkit::detection(*p, class, [0.1 * k as f64 % 1.0; 3])
            })
            .collect();
        super::super::features::graph_input(&detections, &scene, &Pose2::new(Vec2::zeros(), 0.4))
    }

    /// The tensor-free inference Sinkhorn gives the assignment of the
    /// training one (log domain, tensors), on scores from mild to far
    /// apart, with gated entries and per-node "no match" scores, square and
    /// not.
    #[test]
    fn weights_that_are_not_finite_do_not_load() {
        let arch = Architecture::default();
        let device = Device::flex();
        let fine = Network::new(&arch, Init::Seeded(3), &device);
        assert!(from_bytes(&arch, &to_bytes(&fine).unwrap(), &device).is_ok());
        let broken = Network::new(&arch, Init::Seeded(3), &device).with_gates(f32::NAN);
        let e = from_bytes(&arch, &to_bytes(&broken).unwrap(), &device).unwrap_err();
        assert!(e.contains("not a finite number"), "{e}");
    }

    #[test]
    fn inference_sinkhorn_equals_the_log_domain_one() {
        let device = Device::flex();
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
        let device = Device::flex();
        let arch = Architecture {
            dropout_conv: 0.0,
            dropout_phi: 0.0,
            ..Architecture::default()
        };
        let mut net = Network::new(&arch, Init::Seeded(2), &device);
        // Open the gates so that the residual and the learned "no match"
        // scores count.
        net.gate = named_param(
            "gate",
            Tensor::from_data(TensorData::new(vec![0.3f32], [1]), &device),
        );
        net.dust_gate = named_param(
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
            let g1: Vec<&GraphInput> = which.iter().map(|&k| &graphs[k][0]).collect();
            let g2: Vec<&GraphInput> = which.iter().map(|&k| &graphs[k][1]).collect();
            let (b1, b2) = (GraphBatch::new(&g1, &device), GraphBatch::new(&g2, &device));
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

    /// Kept cell weights give the embedding the layers give by selecting
    /// their own; weights kept for another cell set are ignored.
    #[test]
    fn kept_cell_weights_change_nothing_and_foreign_ones_are_ignored() {
        let device = Device::flex();
        let graph = |points: &[(f64, f64)]| GraphBatch::used_cells(&graph_input(points), &device);
        let near = [(0.0, 0.0), (12.0, 3.0), (5.0, 20.0), (-9.0, 14.0)];
        let far = [(0.0, 0.0), (45.0, -30.0), (-40.0, 44.0), (10.0, 60.0)];
        let arch = Architecture::default();
        let net = Network::new(&arch, Init::Seeded(5), &device);
        let (a, b) = (graph(&near), graph(&far));
        assert_ne!(a.cell_mask, b.cell_mask);
        let (kept_a, kept_b) = (
            Arc::new(net.cell_weights(&a)),
            Arc::new(net.cell_weights(&b)),
        );
        let embed = |g: &GraphBatch| -> Vec<f32> {
            let ones = |d: usize| Tensor::<4>::ones([1, 2, g.n(), d], &device);
            let h = net.embed(g, ones(arch.hidden), ones(arch.out));
            h.try_into_vec_as::<f32>().unwrap()
        };
        let own = embed(&a);
        assert_eq!(embed(&graph(&near).with_weights(kept_a)), own);
        let foreign = graph(&near).with_weights(kept_b);
        assert!(foreign.weights.is_none());
        assert_eq!(embed(&foreign), own);
    }

    /// The dense spline convolution, in both orders (weights first, and
    /// neighbours first), equals the message sum written out per edge:
    /// `root x_i + sum over edges j -> i of 1/deg(i) sum_c b_c W_(k_c) x_j
    /// + bias` (kernel cell k_c, basis weight b_c).
    #[test]
    fn spline_conv_equals_the_per_edge_sum() {
        let device = Device::flex();
        let input = graph_input(&[
            (0.0, 0.0),
            (12.0, 3.0),
            (5.0, 20.0),
            (-9.0, 14.0),
            (30.0, -20.0),
        ]);
        let n = input.n;
        for (d_in, d_out) in [(3, 2), (2, 3)] {
            let conv = SplineConv::new("test", d_in, d_out, Init::Seeded(3), &device);
            assert_eq!(conv.mixes_first(), d_in < d_out);
            let x: Vec<f32> = (0..n * d_in).map(|v| (v as f32 * 0.37).sin()).collect();
            let all = GraphBatch::new(&[&input], &device);
            let used = GraphBatch::used_cells(&input, &device);
            assert!(used.cells.dims()[0] < KERNEL_2D, "every cell used");
            let kept = conv.cell_weights(&used.cells); // as an inference cache keeps them
            for (g, selected) in [(&all, None), (&used, None), (&used, Some(&kept))] {
                let out = conv.forward(
                    Tensor::from_data(TensorData::new(x.clone(), [1, 1, n, d_in]), &device),
                    g,
                    selected,
                );
                let out: Vec<f32> = out.try_into_vec_as::<f32>().unwrap();
                let w: Vec<f32> = conv.weight.val().try_into_vec_as::<f32>().unwrap();
                let root: Vec<f32> = conv.root.val().try_into_vec_as::<f32>().unwrap();
                for i in 0..n {
                    for o in 0..d_out {
                        let mut expected: f32 = (0..d_in)
                            .map(|c| x[i * d_in + c] * root[c * d_out + o])
                            .sum();
                        for e in 0..input.edge_count() {
                            if input.dst[e] as usize != i {
                                continue;
                            }
                            let j = input.src[e] as usize;
                            let inv_deg = input.aggregate[i * input.edge_count() + e];
                            for c in 0..4 {
                                let k = input.basis_index[4 * e + c] as usize;
                                let b = input.basis_weight[4 * e + c];
                                let msg: f32 = (0..d_in)
                                    .map(|f| {
                                        x[j * d_in + f] * w[f * KERNEL_2D * d_out + k * d_out + o]
                                    })
                                    .sum();
                                expected += inv_deg * b * msg;
                            }
                        }
                        let got = out[i * d_out + o];
                        assert!(
                            (got - expected).abs() < 1e-5,
                            "{d_in} -> {d_out}, node {i}, out {o}: {got} vs {expected}"
                        );
                    }
                }
            }
        }
    }

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
        let device = Device::flex();
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

    #[test]
    fn seeded_initialisation_is_named_per_parameter() {
        let device = Device::flex();
        let arch = Architecture::default();
        let bytes = |init| to_bytes(&Network::new(&arch, init, &device)).unwrap();
        // Same seed, same weights (and the same bytes: parameter ids are
        // named too); another seed, other weights.
        assert_eq!(bytes(Init::Seeded(4)), bytes(Init::Seeded(4)));
        assert_ne!(bytes(Init::Seeded(4)), bytes(Init::Seeded(5)));
        // A parameter's draws do not depend on which other layers exist:
        // the first layer is the same with and without consensus.
        let first_layer = |consensus: bool| {
            let a = Architecture {
                consensus,
                ..Architecture::default()
            };
            let net = Network::new(&a, Init::Seeded(4), &device);
            net.conv1.weight.val().try_into_vec_as::<f32>().unwrap()
        };
        assert_eq!(first_layer(true), first_layer(false));
        // The gates start closed and the scale at 1.
        let c = Network::new(&arch, Init::Seeded(4), &device).combination();
        assert_eq!((c.scale, c.gate, c.dust_gate), (1.0, 0.0, 0.0));
    }

    #[test]
    fn weights_survive_bytes_and_bad_bytes_are_refused() {
        let device = Device::flex();
        let arch = Architecture::default();
        let net = Network::new(&arch, Init::Seeded(9), &device);
        let bytes = to_bytes(&net).unwrap();
        let back = from_bytes(&arch, &bytes, &device).unwrap();
        assert_eq!(to_bytes(&back).unwrap(), bytes);
        assert!(from_bytes(&arch, b"junk", &device).is_err());
        // Weights of another architecture do not fit.
        let other = Architecture {
            consensus: false,
            ..arch
        };
        let other_bytes = to_bytes(&Network::new(&other, Init::Seeded(9), &device)).unwrap();
        assert!(from_bytes(&arch, &other_bytes, &device).is_err());
        // A gate that is not a number is refused.
        let mut broken = Network::new(&arch, Init::Seeded(9), &device);
        broken.gate = named_param(
            "gate",
            Tensor::from_data(TensorData::new(vec![f32::NAN], [1]), &device),
        );
        let e = from_bytes(&arch, &to_bytes(&broken).unwrap(), &device)
            .err()
            .unwrap();
        assert!(e.contains("finite"), "{e}");
    }
}
