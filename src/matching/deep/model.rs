//! The network (burn): the only code in the crate that sees tensors.
//!
//! - `SplineConv`: a SplineCNN layer (Fey et al. 2018) with degree-1 open
//!   B-splines over 2-D pseudo-coordinates, `KERNEL` knots per dimension,
//!   mean aggregation and a root weight (paper Eq. 1).
//! - Psi: two `SplineConv`s (hidden 256, output 32), each followed by ReLU
//!   and dropout 0.4.
//! - Similarity `S = H H'^T` (Eq. 2), plus the DGMC neighbourhood consensus
//!   `phi(D)` (Eq. 3): random node indicators pushed through the soft
//!   correspondence, embedded by a consensus `SplineConv`, compared, and
//!   scored by an MLP with dropout 0.2.
//! - Log-domain Sinkhorn with a learnable dustbin row and column (Eq. 4
//!   with "no match", as SuperGlue). Inference runs the same iterations
//!   without tensors, in the scaling domain ([`sinkhorn_probabilities`]).
//!
//! Dropout masks are drawn by the caller from a seeded stream and applied
//! here as tensors, on any device: burn's `Dropout` is a no-op outside
//! autodiff training, and MC dropout needs masks at inference. The T Monte
//! Carlo samples are a leading batch dimension; the first layer, whose input
//! does not depend on any mask, is computed once.
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

use super::features::{GraphInput, KERNEL_2D};
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

/// One graph as tensors on a device.
pub struct GraphTensors {
    pub n: usize,
    pub e: usize,
    /// `[1, N, F]`
    pub x: Tensor<3>,
    /// The kernel cells whose messages are computed (ascending), as
    /// indices `[C]`: all of them, or only those some edge of this graph
    /// uses (the others contribute nothing).
    pub cells: Tensor<1, Int>,
    /// `[1, N, N * C]`: entry `[i, j C + c]` is the basis weight of cell
    /// `cells[c]` of edge j -> i over the degree of i (zero when j is not a
    /// neighbour of i). Columns run node-major so that the messages `x W`
    /// (`[T, N, C * out]`) need only a reshape.
    pub mixing: Tensor<3>,
    /// Bit k set when kernel cell k is in `cells`.
    pub cell_mask: u32,
    /// The spline layers' weights of exactly these cells, when the caller
    /// has them ([`Network::cell_weights`]); else each layer selects them.
    pub weights: Option<Arc<CellWeights>>,
}

/// Every spline layer's weights of one set of kernel cells (`[1, in, C *
/// out]` each): what [`SplineConv::forward`] would select, kept by a caller
/// that sees the same cell set many times (inference).
pub struct CellWeights {
    /// The cell set, as [`GraphTensors::cell_mask`].
    cell_mask: u32,
    conv1: Tensor<3>,
    conv2: Tensor<3>,
    consensus: Option<Tensor<3>>,
}

impl GraphTensors {
    /// With every kernel cell (training: the gradient of a cell selection
    /// costs more than the messages it saves).
    pub fn new(g: &GraphInput, device: &Device) -> Self {
        Self::with_cells(g, [true; KERNEL_2D], device)
    }

    /// With only the kernel cells some edge uses (inference).
    pub fn used_cells(g: &GraphInput, device: &Device) -> Self {
        let mut used = [false; KERNEL_2D];
        for &k in &g.basis_index {
            used[k as usize] = true;
        }
        Self::with_cells(g, used, device)
    }

    fn with_cells(g: &GraphInput, used: [bool; KERNEL_2D], device: &Device) -> Self {
        let (n, e) = (g.n, g.edge_count());
        let f = g.node_features.len() / n.max(1);
        let cells: Vec<i64> = (0..KERNEL_2D as i64)
            .filter(|&k| used[k as usize])
            .collect();
        let c = cells.len();
        let mut position = [0usize; KERNEL_2D];
        for (p, &k) in cells.iter().enumerate() {
            position[k as usize] = p;
        }
        let mut mixing = vec![0f32; n * c * n];
        for k in 0..e {
            let (i, j) = (g.dst[k] as usize, g.src[k] as usize);
            let inv_deg = g.aggregate[i * e + k];
            for b in 0..4 {
                let cell = position[g.basis_index[4 * k + b] as usize];
                mixing[i * c * n + j * c + cell] += g.basis_weight[4 * k + b] * inv_deg;
            }
        }
        Self {
            n,
            e,
            x: Tensor::from_data(TensorData::new(g.node_features.clone(), [1, n, f]), device),
            cell_mask: cells.iter().map(|&k| 1u32 << k).sum(),
            cells: Tensor::from_data(TensorData::new(cells, [c]), device),
            mixing: Tensor::from_data(TensorData::new(mixing, [1, n, c * n]), device),
            weights: None,
        }
    }

    /// With the spline layers' weights of this graph's cells; weights of
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

    /// `x: [T, N, in] -> [T, N, out]`:
    /// `root x_i + mean_j sum_k B_k(u_ij) W_k x_j + b`, as two dense
    /// products: `XW = x [W_k ..]` for every kernel cell the graph uses at
    /// once, then the neighbour-and-cell mixing `A [N C]` (degree-normalised
    /// basis weights of every edge) against `XW` read as one row per
    /// (neighbour, cell).
    ///
    /// `selected`: this layer's weights of the graph's cells, if the caller
    /// keeps them ([`CellWeights`]).
    pub fn forward(
        &self,
        x: Tensor<3>,
        g: &GraphTensors,
        selected: Option<&Tensor<3>>,
    ) -> Tensor<3> {
        let d_out = self.d_out;
        let [t, n, _] = x.dims();
        let root = x.clone().matmul(self.root.val().unsqueeze::<3>()); // [T, N, out]
        let bias = self.bias.val().reshape([1, 1, d_out]);
        if g.e == 0 {
            return root + bias;
        }
        let c = g.cells.dims()[0];
        let w = match selected {
            Some(w) => w.clone(),
            None => self.cell_weights(&g.cells),
        };
        let xw = x.matmul(w).reshape([t, n * c, d_out]); // rows (j, cell), no copy
        root + g.mixing.clone().matmul(xw) + bias // [1, N, N C] x [T, N C, out]
    }

    /// The weights of the kernel cells `cells`, `[1, in, C * out]`.
    fn cell_weights(&self, cells: &Tensor<1, Int>) -> Tensor<3> {
        let c = cells.dims()[0];
        if c == KERNEL_2D {
            return self.weight.val().unsqueeze::<3>();
        }
        let d_in = self.root.val().dims()[0];
        self.weight
            .val()
            .reshape([d_in, KERNEL_2D, self.d_out])
            .select(1, cells.clone())
            .reshape([1, d_in, c * self.d_out])
    }
}

/// Architecture and regularisation of one matcher variant.
#[derive(Clone, Copy, Debug, PartialEq)]
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
    /// Beyond the paper: subtract a learned multiple of the GPS position
    /// cost ([`super::features::position_cost`]) from the similarity, so the
    /// network can weigh where the vehicles say the objects are against what
    /// they look like and how they are arranged.
    pub gps_prior: bool,
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
            gps_prior: true,
        }
    }
}

/// The masks of the pair part of a forward pass: consensus dropout and
/// the random node indicators.
pub struct PairMasks {
    /// `[T, N1, N2, consensus_dim]`.
    pub phi: Tensor<4>,
    /// `[1, N1, consensus_dim]`.
    pub indicators: Tensor<3>,
}

/// The dropout masks of one forward pass with T samples (values 0 or
/// 1 / (1 - p), inverted dropout).
pub struct Masks {
    /// `[T, N1, hidden]`, `[T, N1, out]`, and the same for graph 2.
    pub conv1: [Tensor<3>; 2],
    pub conv2: [Tensor<3>; 2],
    /// `[T, N1, N2, consensus_dim]`.
    pub phi: Tensor<4>,
    /// `[1, N1, consensus_dim]` random node indicators for the consensus.
    pub indicators: Tensor<3>,
}

#[derive(Module, Debug)]
pub struct Network {
    conv1: SplineConv,
    conv2: SplineConv,
    consensus_conv: Option<SplineConv>,
    phi_in: Option<Linear>,
    phi_out: Option<Linear>,
    /// Dustbin score (Sinkhorn's "no match" row and column), `[1]`.
    dustbin: Param<Tensor<1>>,
    /// Log of the weight of the GPS position cost, `[1]` (unused when the
    /// architecture has no GPS prior).
    log_position_weight: Param<Tensor<1>>,
    gps_prior: bool,
}

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
        Self {
            conv1: SplineConv::new("conv1", arch.node_features, arch.hidden, init, device),
            conv2: SplineConv::new("conv2", arch.hidden, arch.out, init, device),
            consensus_conv,
            phi_in,
            phi_out,
            dustbin: named_param("dustbin", Tensor::ones([1], device)),
            log_position_weight: named_param("log_position_weight", Tensor::zeros([1], device)),
            gps_prior: arch.gps_prior,
        }
    }

    /// Psi: node embeddings `[T, N, out]` for T dropout samples.
    pub fn embed(&self, g: &GraphTensors, mask1: Tensor<3>, mask2: Tensor<3>) -> Tensor<3> {
        // The first layer's input is the same for every sample: compute once.
        let w = g.weights.as_deref();
        let h = activation::relu(self.conv1.forward(g.x.clone(), g, w.map(|w| &w.conv1)));
        let h = h * mask1; // [T, N, hidden]
        activation::relu(self.conv2.forward(h, g, w.map(|w| &w.conv2))) * mask2 // [T, N, out]
    }

    /// Every spline layer's weights of the kernel cells of `g`, for
    /// [`GraphTensors::with_weights`] on graphs with the same cells.
    pub fn cell_weights(&self, g: &GraphTensors) -> CellWeights {
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

    /// Log of the soft assignment with dustbins, `[T, N1 + 1, N2 + 1]`.
    /// Both graphs must have at least one node. `position_cost`: `[1, N1, N2]`.
    pub fn forward(
        &self,
        g1: &GraphTensors,
        g2: &GraphTensors,
        masks: Masks,
        position_cost: Tensor<3>,
        sinkhorn_iters: usize,
    ) -> Tensor<3> {
        let [c1a, c1b] = masks.conv1;
        let [c2a, c2b] = masks.conv2;
        let h1 = self.embed(g1, c1a, c2a); // [T, N1, out]
        let h2 = self.embed(g2, c1b, c2b); // [T, N2, out]
        let pair = PairMasks {
            phi: masks.phi,
            indicators: masks.indicators,
        };
        let scores = self.pair_scores((&h1, g1), (&h2, g2), pair, position_cost);
        log_sinkhorn(scores, self.dustbin.val(), sinkhorn_iters)
    }

    /// The learned dustbin score (Sinkhorn's "no match" entry).
    pub fn dustbin_score(&self) -> f32 {
        self.dustbin.val().into_scalar::<f32>()
    }

    /// The scores Sinkhorn normalises, `[T, N1, N2]`: similarity,
    /// neighbourhood consensus and GPS term from both graphs' embeddings
    /// ([`Self::embed`]); [`Self::forward`] and inference share it.
    pub fn pair_scores(
        &self,
        first: (&Tensor<3>, &GraphTensors),
        second: (&Tensor<3>, &GraphTensors),
        masks: PairMasks,
        position_cost: Tensor<3>,
    ) -> Tensor<3> {
        let ((h1, g1), (h2, g2)) = (first, second);
        let mut s = h1.clone().matmul(h2.clone().swap_dims(1, 2)); // [T, N1, N2]
        if let (Some(conv), Some(phi_in), Some(phi_out)) =
            (&self.consensus_conv, &self.phi_in, &self.phi_out)
        {
            let [t, n1, n2] = s.dims();
            let soft = activation::softmax(s.clone(), 2); // [T, N1, N2]
            let r1 = masks.indicators; // [1, N1, r]
            let r2 = soft.swap_dims(1, 2).matmul(r1.clone()); // [T, N2, r]
            let w = |g: &GraphTensors| g.weights.as_ref().and_then(|w| w.consensus.clone());
            let z1 = activation::relu(conv.forward(r1, g1, w(g1).as_ref())); // [1, N1, r]
            let z2 = activation::relu(conv.forward(r2, g2, w(g2).as_ref())); // [T, N2, r]
            let d = z1.unsqueeze_dim::<4>(2) - z2.unsqueeze_dim::<4>(1); // [T, N1, N2, r]
            let hidden = activation::relu(phi_in.forward(d)) * masks.phi; // [T, N1, N2, r]
            s = s + phi_out.forward(hidden).reshape([t, n1, n2]);
        }
        if self.gps_prior {
            let w = self.log_position_weight.val().exp().reshape([1, 1, 1]);
            s = s - position_cost * w;
        }
        s
    }
}

/// Log-sum-exp along `dim`, keeping it (size 1).
fn logsumexp<const D: usize>(x: Tensor<D>, dim: usize) -> Tensor<D> {
    let m = x.clone().max_dim(dim).detach();
    (x - m.clone()).exp().sum_dim(dim).log() + m
}

/// Log-domain Sinkhorn with a dustbin row and column (SuperGlue's optimal
/// transport): scores `[T, N1, N2]`, dustbin score `[1]` -> log assignment
/// `[T, N1 + 1, N2 + 1]` whose real rows and real columns each sum to 1
/// (dustbin entry included); the dustbin row and column absorb the rest.
pub fn log_sinkhorn(scores: Tensor<3>, dustbin: Tensor<1>, iters: usize) -> Tensor<3> {
    let [t, n1, n2] = scores.dims();
    let device = scores.device();
    let alpha = dustbin.reshape([1, 1, 1]);
    let column = alpha.clone().expand([t, n1, 1]);
    let row = alpha.expand([t, 1, n2 + 1]);
    let z = Tensor::cat(vec![Tensor::cat(vec![scores, column], 2), row], 1); // [T, N1+1, N2+1]
    let norm = -((n1 + n2) as f32).ln();
    let mut mu = vec![norm; n1 + 1];
    mu[n1] = (n2 as f32).ln() + norm;
    let mut nu = vec![norm; n2 + 1];
    nu[n2] = (n1 as f32).ln() + norm;
    let log_mu = Tensor::<3>::from_data(TensorData::new(mu, [1, n1 + 1, 1]), &device);
    let log_nu = Tensor::<3>::from_data(TensorData::new(nu, [1, 1, n2 + 1]), &device);
    let mut u = Tensor::<3>::zeros([t, n1 + 1, 1], &device);
    let mut v = Tensor::<3>::zeros([t, 1, n2 + 1], &device);
    for _ in 0..iters {
        u = log_mu.clone() - logsumexp(z.clone() + v.clone(), 2);
        v = log_nu.clone() - logsumexp(z.clone() + u.clone(), 1);
    }
    z + u + v - norm
}

/// [`log_sinkhorn`] for inference, without tensors or gradients: the
/// same iterations in the scaling domain, in f64. `scores` holds T
/// row-major `N1 x N2` blocks; the result holds T row-major
/// `(N1 + 1) x (N2 + 1)` assignments (probabilities, not logs).
///
/// With `K = exp(z - rowmax)` (every row of the padded scores `z` keeps
/// an entry 1, and so does every column: the dustbin row is constant),
/// `u = mu / K v` and `v = nu / K^T u` are `exp` of the log-domain
/// potentials up to the row shift, so `P = u K v / exp(norm)` is the
/// log-domain result up to rounding, with one `exp` per entry instead of
/// two per entry and iteration.
pub fn sinkhorn_probabilities(
    scores: &[f32],
    [t, n1, n2]: [usize; 3],
    dustbin: f32,
    iters: usize,
) -> Vec<f32> {
    debug_assert_eq!(scores.len(), t * n1 * n2);
    let (rows, cols) = (n1 + 1, n2 + 1);
    let norm = -((n1 + n2) as f64).ln();
    let mu = |i: usize| {
        if i == n1 {
            n2 as f64 / (n1 + n2) as f64
        } else {
            norm.exp()
        }
    };
    let nu = |j: usize| {
        if j == n2 {
            n1 as f64 / (n1 + n2) as f64
        } else {
            norm.exp()
        }
    };
    let alpha = f64::from(dustbin);
    let scale = (-norm).exp();
    let mut out = Vec::with_capacity(t * rows * cols);
    let mut kernel = vec![0f64; rows * cols];
    let (mut u, mut v) = (vec![0f64; rows], vec![1f64; cols]);
    let mut column_sums = vec![0f64; cols];
    for sample in 0..t {
        let block = &scores[sample * n1 * n2..(sample + 1) * n1 * n2];
        for i in 0..rows {
            let z = |j: usize| {
                if i < n1 && j < n2 {
                    f64::from(block[i * n2 + j])
                } else {
                    alpha
                }
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
                    .map(|(k, vj)| (ui * k * vj * scale) as f32),
            );
        }
    }
    out
}

/// Which terms of the paper's loss (Eq. 11-13) a variant trains with;
/// `L_coid` is always on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LossTerms {
    pub non: bool,
    pub unc: bool,
    /// Supervise "no match": `-mean(log P_dustbin)` over the rows and
    /// columns without a true partner (SuperGlue-style), a mean of its own
    /// so that it weighs as much as the true pairs however many there are.
    pub dustbin: bool,
}

/// The training loss of one pair. `log_assign`: `[T, N1 + 1, N2 + 1]`;
/// `y_star`: `[N1, N2]` true correspondences; `non`: `[N1, N2]`, 1 where
/// row i or column j is a non-covisible object; `n_true`: number of true
/// pairs (at least 1).
///
/// With P = E[Y] the mean assignment over the T samples (real block):
/// - `L_coid = -log(sum(P o Y*) / n_true)`: Eq. 11 with S o E(Y) read as the
///   Sinkhorn-normalised match probability and the sum averaged over the
///   true pairs, so that the log's argument lies in [0, 1];
/// - `L_non = -log(mean(exp(-P o N)))` (Eq. 12);
/// - `L_unc = -log(mean(exp(-H(P))))` with H the binary entropy in bits
///   (Eq. 13).
pub fn loss(
    log_assign: Tensor<3>,
    y_star: Tensor<2>,
    non: Tensor<2>,
    n_true: usize,
    terms: LossTerms,
) -> Tensor<1> {
    let [_, r, c] = log_assign.dims();
    let (n1, n2) = (r - 1, c - 1);
    let p_full = log_assign.exp().mean_dim(0).reshape([r, c]); // [N1 + 1, N2 + 1]
    let p = p_full.clone().slice([0..n1, 0..n2]); // [N1, N2]
    let y_star_full = y_star.clone();
    let matched = (p.clone() * y_star).sum() / (n_true.max(1) as f32);
    let mut total = -matched.clamp_min(1e-9).log();
    if terms.non {
        total = total - (-(p.clone() * non)).exp().mean().log();
    }
    if terms.dustbin {
        total = total + dustbin_term(&p_full, &y_star_full, n_true);
    }
    if terms.unc {
        let q = p.clamp(1e-6, 1.0 - 1e-6);
        let one_minus = q.clone().neg() + 1.0;
        let h =
            -(q.clone() * q.log() + one_minus.clone() * one_minus.log()) / std::f32::consts::LN_2;
        total = total - h.neg().exp().mean().log();
    }
    total
}

/// `-mean(log P)` of the dustbin entries of the rows and columns of the
/// mean assignment `p_full` (`[N1 + 1, N2 + 1]`) that have no true
/// partner in `y_star`; 0 when every row and column has one.
fn dustbin_term(p_full: &Tensor<2>, y_star: &Tensor<2>, n_true: usize) -> Tensor<1> {
    let [r, c] = p_full.dims();
    let (n1, n2) = (r - 1, c - 1);
    let unmatched = (n1 + n2).saturating_sub(2 * n_true);
    let device = p_full.device();
    if unmatched == 0 {
        return Tensor::<1>::zeros([1], &device);
    }
    let log = |t: Tensor<2>| t.clamp_min(1e-9).log();
    let row_free = y_star.clone().sum_dim(1).neg() + 1.0; // [N1, 1]
    let col_free = y_star.clone().sum_dim(0).neg() + 1.0; // [1, N2]
    let rows = (log(p_full.clone().slice([0..n1, n2..c])) * row_free).sum();
    let cols = (log(p_full.clone().slice([n1..r, 0..n2])) * col_free).sum();
    -(rows + cols) / (unmatched as f32)
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
/// [`to_bytes`].
pub fn from_bytes(arch: &Architecture, bytes: &[u8], device: &Device) -> Result<Network, String> {
    let record =
        burn::store::ModuleRecord::from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec()))
            .map_err(|e| format!("{e:?}"))?;
    Network::new(arch, Init::Zeros, device)
        .try_load_record(record)
        .map_err(|e| format!("{e:?}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// The tensor-free inference Sinkhorn gives the assignment of the
    /// training one (log domain, tensors), on scores from mild to far
    /// apart (a row or column far below the dustbin), square and not.
    #[test]
    fn inference_sinkhorn_equals_the_log_domain_one() {
        let device = Device::flex();
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for (shape, spread, dustbin) in [
            ([3, 5, 4], 6.0f32, 1.0f32),
            ([2, 7, 9], 60.0, -2.5),
            ([4, 1, 6], 300.0, 4.0),
            ([1, 20, 18], 30.0, 0.3),
        ] {
            let [t, n1, n2] = shape;
            let mut scores: Vec<f32> = (0..t * n1 * n2)
                .map(|_| r.random_range(-spread..spread / 4.0))
                .collect();
            scores[0] = -10.0 * spread; // far below everything else
            let expected = log_sinkhorn(
                Tensor::<3>::from_data(TensorData::new(scores.clone(), shape), &device),
                Tensor::from_data(TensorData::new(vec![dustbin], [1]), &device),
                20,
            )
            .exp();
            let expected: Vec<f32> = expected.try_into_vec_as::<f32>().unwrap();
            let got = sinkhorn_probabilities(&scores, shape, dustbin, 20);
            assert_eq!(got.len(), t * (n1 + 1) * (n2 + 1));
            for (k, (g, e)) in got.iter().zip(&expected).enumerate() {
                assert!((g - e).abs() < 1e-4, "{shape:?} entry {k}: {g} vs {e}");
            }
        }
    }

    /// Kept cell weights give the embedding the layers give by selecting
    /// their own; weights kept for another cell set are ignored.
    #[test]
    fn kept_cell_weights_change_nothing_and_foreign_ones_are_ignored() {
        use crate::geometry::{Pose2, Vec2};
        use crate::graph::SceneGraph;
        let device = Device::flex();
        let graph = |points: &[(f64, f64)]| {
            let positions: Vec<Vec2> = points.iter().map(|&(x, y)| Vec2::new(x, y)).collect();
            let scene = SceneGraph::delaunay(&positions).unwrap();
            let detections: Vec<crate::sensor::Detection> = positions
                .iter()
                .map(|p| {
                    let class = crate::traffic::ObjectClass::Car;
                    crate::matching::testkit::detection(*p, class, [0.3; 3])
                })
                .collect();
            let input = super::super::features::graph_input(
                &detections,
                &scene,
                &Pose2::new(Vec2::zeros(), 0.4),
            );
            GraphTensors::used_cells(&input, &device)
        };
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
        let embed = |g: &GraphTensors| -> Vec<f32> {
            let ones = |d: usize| Tensor::<3>::ones([2, g.n, d], &device);
            let h = net.embed(g, ones(arch.hidden), ones(arch.out));
            h.try_into_vec_as::<f32>().unwrap()
        };
        let own = embed(&a);
        assert_eq!(embed(&graph(&near).with_weights(kept_a)), own);
        let foreign = graph(&near).with_weights(kept_b);
        assert!(foreign.weights.is_none());
        assert_eq!(embed(&foreign), own);
    }

    /// The dense spline convolution equals the message sum written out per
    /// edge: `root x_i + sum over edges j -> i of 1/deg(i) sum_c b_c
    /// W_(k_c) x_j + bias` (kernel cell k_c, basis weight b_c).
    #[test]
    fn spline_conv_equals_the_per_edge_sum() {
        use crate::geometry::Vec2;
        use crate::graph::SceneGraph;
        let device = Device::flex();
        let positions = [
            (0.0, 0.0),
            (12.0, 3.0),
            (5.0, 20.0),
            (-9.0, 14.0),
            (30.0, -20.0),
        ]
        .map(|(x, y)| Vec2::new(x, y));
        let graph = SceneGraph::delaunay(&positions).unwrap();
        let detections: Vec<crate::sensor::Detection> = positions
            .iter()
            .map(|p| {
                crate::matching::testkit::detection(*p, crate::traffic::ObjectClass::Car, [0.3; 3])
            })
            .collect();
        let input = super::super::features::graph_input(
            &detections,
            &graph,
            &crate::geometry::Pose2::new(Vec2::zeros(), 0.4),
        );
        let (d_in, d_out, n) = (3, 2, input.n);
        let conv = SplineConv::new("test", d_in, d_out, Init::Seeded(3), &device);
        let x: Vec<f32> = (0..n * d_in).map(|v| (v as f32 * 0.37).sin()).collect();
        let all = GraphTensors::new(&input, &device);
        let used = GraphTensors::used_cells(&input, &device);
        assert!(used.cells.dims()[0] < KERNEL_2D, "every cell used");
        let kept = conv.cell_weights(&used.cells); // as an inference cache keeps them
        for (g, selected) in [(&all, None), (&used, None), (&used, Some(&kept))] {
            let out = conv.forward(
                Tensor::from_data(TensorData::new(x.clone(), [1, n, d_in]), &device),
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
                                .map(|f| x[j * d_in + f] * w[f * KERNEL_2D * d_out + k * d_out + o])
                                .sum();
                            expected += inv_deg * b * msg;
                        }
                    }
                    let got = out[i * d_out + o];
                    assert!(
                        (got - expected).abs() < 1e-5,
                        "node {i}, out {o}: {got} vs {expected}"
                    );
                }
            }
        }
    }

    /// Two MC samples of a 2 x 2 assignment (dustbins padded with 0.1),
    /// whose real blocks average to P = [[0.7, 0.2], [0.1, 0.6]].
    fn two_samples(device: &Device) -> Tensor<3> {
        let samples: Vec<f32> = vec![
            0.8, 0.1, 0.1, 0.1, 0.5, 0.1, 0.1, 0.1, 0.1, // t = 0
            0.6, 0.3, 0.1, 0.1, 0.7, 0.1, 0.1, 0.1, 0.1, // t = 1
        ];
        Tensor::<3>::from_data(TensorData::new(samples, [2, 3, 3]), device).log()
    }

    /// The loss terms on a hand-computed case: object 0 of each side is
    /// the same, object 1 of each side is seen by one vehicle only.
    /// By hand (P above, Y* = [[1, 0], [0, 0]], N = [[0, 1], [1, 1]]):
    /// L_coid = -ln 0.7 = 0.356675;
    /// L_non = -ln((1 + e^-0.2 + e^-0.1 + e^-0.6) / 4) = 0.200777;
    /// L_unc = -ln(mean(exp(-H_bits(p)))) over 0.7, 0.2, 0.1, 0.6 = 0.742119.
    #[test]
    fn loss_terms_match_a_hand_computed_two_by_two_case() {
        let device = Device::flex();
        let y = Tensor::<2>::from_data(TensorData::new(vec![1f32, 0., 0., 0.], [2, 2]), &device);
        let non = Tensor::<2>::from_data(TensorData::new(vec![0f32, 1., 1., 1.], [2, 2]), &device);
        let value = |non_term: bool, unc_term: bool| {
            let terms = LossTerms {
                non: non_term,
                unc: unc_term,
                dustbin: false,
            };
            f64::from(
                loss(two_samples(&device), y.clone(), non.clone(), 1, terms).into_scalar::<f32>(),
            )
        };
        let coid = value(false, false);
        assert!((coid - 0.356675).abs() < 1e-5, "L_coid {coid}");
        assert!((value(true, false) - coid - 0.200777).abs() < 1e-5);
        assert!((value(false, true) - coid - 0.742119).abs() < 1e-5);
        assert!((value(true, true) - 1.299571).abs() < 1e-5);
    }

    /// The dustbin term by hand: one true pair (0, 0), so row 1 and
    /// column 1 have no partner; their dustbin probabilities are 0.1 in
    /// both samples: -(ln 0.1 + ln 0.1) / 2 = ln 10. With every row and
    /// column matched it vanishes.
    #[test]
    fn dustbin_loss_of_a_hand_made_case() {
        let device = Device::flex();
        let matrix = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [2, 2]), &device);
        let value = |y: Vec<f32>, n_true: usize, dustbin: bool| {
            let terms = LossTerms {
                non: false,
                unc: false,
                dustbin,
            };
            let non = matrix(vec![0.; 4]);
            f64::from(
                loss(two_samples(&device), matrix(y), non, n_true, terms).into_scalar::<f32>(),
            )
        };
        let one = vec![1., 0., 0., 0.];
        let extra = value(one.clone(), 1, true) - value(one, 1, false);
        assert!(
            (extra - std::f64::consts::LN_10).abs() < 1e-5,
            "dustbin term {extra}"
        );
        let both = vec![1., 0., 0., 1.];
        assert!((value(both.clone(), 2, true) - value(both, 2, false)).abs() < 1e-9);
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
    }
}
