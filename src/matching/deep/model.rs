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
//!   with "no match", as SuperGlue).
//!
//! Dropout masks are drawn by the caller from a seeded stream and applied
//! here as tensors, on any device: burn's `Dropout` is a no-op outside
//! autodiff training, and MC dropout needs masks at inference. The T Monte
//! Carlo samples are a leading batch dimension; the first layer, whose input
//! does not depend on any mask, is computed once.

use burn::module::Param;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::{Distribution, activation};

use super::features::{GraphInput, KERNEL_2D};

/// One graph as tensors on a device.
pub struct GraphTensors {
    pub n: usize,
    pub e: usize,
    /// `[1, N, F]`
    pub x: Tensor<3>,
    /// `[1, N, KERNEL_2D * N]`: entry `[i, k N + j]` is the k-th B-spline
    /// basis weight of edge j -> i over the degree of i (zero when j is not
    /// a neighbour of i).
    pub mixing: Tensor<3>,
}

impl GraphTensors {
    pub fn new(g: &GraphInput, device: &Device) -> Self {
        let (n, e) = (g.n, g.edge_count());
        let f = g.node_features.len() / n.max(1);
        let mut mixing = vec![0f32; n * KERNEL_2D * n];
        for k in 0..e {
            let (i, j) = (g.dst[k] as usize, g.src[k] as usize);
            let inv_deg = g.aggregate[i * e + k];
            for c in 0..4 {
                let cell = g.basis_index[4 * k + c] as usize;
                mixing[i * KERNEL_2D * n + cell * n + j] += g.basis_weight[4 * k + c] * inv_deg;
            }
        }
        Self {
            n,
            e,
            x: Tensor::from_data(TensorData::new(g.node_features.clone(), [1, n, f]), device),
            mixing: Tensor::from_data(TensorData::new(mixing, [1, n, KERNEL_2D * n]), device),
        }
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
    pub fn new(d_in: usize, d_out: usize, device: &Device) -> Self {
        // Uniform(+-1/sqrt(fan_in)) with the fan-in of one kernel cell.
        let b = 1.0 / (d_in as f64).sqrt();
        let uniform = Distribution::Uniform(-b, b);
        Self {
            weight: Param::from_tensor(Tensor::random([d_in, KERNEL_2D * d_out], uniform, device)),
            root: Param::from_tensor(Tensor::random([d_in, d_out], uniform, device)),
            bias: Param::from_tensor(Tensor::zeros([d_out], device)),
            d_out,
        }
    }

    /// `x: [T, N, in] -> [T, N, out]`:
    /// `root x_i + mean_j sum_k B_k(u_ij) W_k x_j + b`, as two dense
    /// products: `XW = x [W_1 .. W_K]` for all kernel cells at once, then the
    /// kernel-and-neighbour mixing `A [K N]` (degree-normalised basis
    /// weights of every edge) against `XW` regrouped by kernel cell.
    pub fn forward(&self, x: Tensor<3>, g: &GraphTensors) -> Tensor<3> {
        let d_out = self.d_out;
        let [t, n, _] = x.dims();
        let root = x.clone().matmul(self.root.val().unsqueeze::<3>()); // [T, N, out]
        let bias = self.bias.val().reshape([1, 1, d_out]);
        if g.e == 0 {
            return root + bias;
        }
        let xw = x
            .matmul(self.weight.val().unsqueeze::<3>()) // [T, N, K2 * out]
            .reshape([t, n, KERNEL_2D, d_out])
            .swap_dims(1, 2) // [T, K2, N, out]
            .reshape([t, KERNEL_2D * n, d_out]);
        root + g.mixing.clone().matmul(xw) + bias // [1, N, K2 N] x [T, K2 N, out]
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
    pub fn new(arch: &Architecture, device: &Device) -> Self {
        let (consensus_conv, phi_in, phi_out) = if arch.consensus {
            (
                Some(SplineConv::new(
                    arch.consensus_dim,
                    arch.consensus_dim,
                    device,
                )),
                Some(LinearConfig::new(arch.consensus_dim, arch.consensus_dim).init(device)),
                Some(LinearConfig::new(arch.consensus_dim, 1).init(device)),
            )
        } else {
            (None, None, None)
        };
        Self {
            conv1: SplineConv::new(arch.node_features, arch.hidden, device),
            conv2: SplineConv::new(arch.hidden, arch.out, device),
            consensus_conv,
            phi_in,
            phi_out,
            dustbin: Param::from_tensor(Tensor::ones([1], device)),
            log_position_weight: Param::from_tensor(Tensor::zeros([1], device)),
            gps_prior: arch.gps_prior,
        }
    }

    /// Psi: node embeddings `[T, N, out]` for T dropout samples.
    fn embed(&self, g: &GraphTensors, mask1: Tensor<3>, mask2: Tensor<3>) -> Tensor<3> {
        // The first layer's input is the same for every sample: compute once.
        let h = activation::relu(self.conv1.forward(g.x.clone(), g)) * mask1; // [T, N, hidden]
        activation::relu(self.conv2.forward(h, g)) * mask2 // [T, N, out]
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
        let mut s = h1.matmul(h2.swap_dims(1, 2)); // [T, N1, N2]
        if let (Some(conv), Some(phi_in), Some(phi_out)) =
            (&self.consensus_conv, &self.phi_in, &self.phi_out)
        {
            let [t, n1, n2] = s.dims();
            let soft = activation::softmax(s.clone(), 2); // [T, N1, N2]
            let r1 = masks.indicators; // [1, N1, r]
            let r2 = soft.swap_dims(1, 2).matmul(r1.clone()); // [T, N2, r]
            let z1 = activation::relu(conv.forward(r1, g1)); // [1, N1, r]
            let z2 = activation::relu(conv.forward(r2, g2)); // [T, N2, r]
            let d = z1.unsqueeze_dim::<4>(2) - z2.unsqueeze_dim::<4>(1); // [T, N1, N2, r]
            let hidden = activation::relu(phi_in.forward(d)) * masks.phi; // [T, N1, N2, r]
            s = s + phi_out.forward(hidden).reshape([t, n1, n2]);
        }
        if self.gps_prior {
            let w = self.log_position_weight.val().exp().reshape([1, 1, 1]);
            s = s - position_cost * w;
        }
        log_sinkhorn(s, self.dustbin.val(), sinkhorn_iters)
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

/// Which terms of the paper's loss (Eq. 11-13) a variant trains with;
/// `L_coid` is always on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LossTerms {
    pub non: bool,
    pub unc: bool,
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
    let p = log_assign
        .exp()
        .mean_dim(0)
        .reshape([r, c])
        .slice([0..n1, 0..n2]); // [N1, N2]
    let matched = (p.clone() * y_star).sum() / (n_true.max(1) as f32);
    let mut total = -matched.clamp_min(1e-9).log();
    if terms.non {
        total = total - (-(p.clone() * non)).exp().mean().log();
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

/// Saves the network's weights (burn's own format).
pub fn save(net: &Network, path: &std::path::Path) -> Result<(), String> {
    net.clone().save_file(path).map_err(|e| format!("{e:?}"))
}

/// Loads weights saved by [`save`] into a network of the same architecture
/// on `device`.
pub fn load(
    arch: &Architecture,
    path: &std::path::Path,
    device: &Device,
) -> Result<Network, String> {
    Network::new(arch, device)
        .try_load_file(path)
        .map_err(|e| format!("{e:?}"))
}
