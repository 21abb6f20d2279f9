//! GCN-GM and DGMC as published (Fey et al. 2018, 2020), our own
//! code after the papers and the structure of DGMC's public code, on the
//! paper's inputs only: each vehicle's detections in its own body frame,
//! appearance attributes, Delaunay graphs with edge lengths. No GPS pose, no
//! heading, no likelihood prior: nothing here shares `ours`'s network.
//!
//! - `graph`: [`PaperGraph`] (plain Rust) and the 1-D B-spline basis over
//!   edge length.
//! - `conv`: the graphs as tensors, `SplineConv` over edge length, DGMC's
//!   `SplineCNN` stack.
//! - `model`: [`PublishedNet`]. GCN-GM: psi_1 (two SplineConvs, 256 and
//!   32 channels, each followed by ReLU, dropout 0.4 once on the 256
//!   hidden channels, DGMC's final linear layer 32 -> 32),
//!   `S_0 = Sinkhorn(H_s H_t^T)`. DGMC: the same `S_0`, then L
//!   steps of `R_t = S^T R_s` (random node indicators), `o = psi_2(R)` on
//!   both graphs (two SplineConvs of `rnd_dim`, input and outputs
//!   concatenated, a final linear layer, as DGMC's psi_2), `S_hat +=
//!   MLP(o_s,i - o_t,j)`, renormalised.
//! - `inference`: the same network in plain Rust, for every mask scope.
//! - `network`: [`Published`], the network as the MC shell runs it.
//! - Training (Adam, NLL of the true correspondences on `S_0` and `S_L`;
//!   the paper's method adds its Eq. 12 and 13) is
//!   `crate::matching::deep::train::published`.
//!
//! The paper's method and its ablations (`coid`, `coid+non`, `coid+unc`)
//! are DGMC's network trained with the paper's losses: the paper builds
//! on DGMC (SplineCNN, neighbourhood consensus, Sinkhorn with "no
//! match") and adds the losses, MC dropout and thresholding.
//!
//! Normalisation: Sinkhorn with a dustbin row and column and one learned
//! "no match" score (as the paper's Sinkhorn with "no match", and
//! SuperGlue), not DGMC's row softmax: the two graphs only partly overlap,
//! a softmax over the other graph's nodes forces every node onto some
//! partner, and the decision code ([`crate::matching::deep::decision`])
//! reads `(n1 + 1) x (n2 + 1)` assignments with dustbins. The consensus
//! steps push the indicators through the real block of the same
//! normalised assignment (a node that goes to its dustbin passes on
//! nothing).

mod conv;
mod graph;
mod inference;
mod model;
mod network;

#[cfg(test)]
mod tests;

pub(crate) use self::conv::GraphTensors;
pub(crate) use self::graph::PaperGraph;
pub(crate) use self::model::{PublishedNet, draw_training_masks};
pub(crate) use self::network::Published;

use burn::prelude::*;

use crate::matching::deep::arch::PublishedConfig;
use crate::matching::deep::train::init::Init;

/// The network's weights as bytes (burn's burnpack format).
pub(crate) fn to_bytes(net: &PublishedNet) -> Result<Vec<u8>, String> {
    crate::matching::deep::train::weights::module_bytes(net)
}

/// A network of `cfg` on `device` with the weights of [`to_bytes`];
/// weights that do not fit or are not finite are refused.
pub(crate) fn from_bytes(
    cfg: &PublishedConfig,
    bytes: &[u8],
    device: &Device,
) -> Result<PublishedNet, String> {
    crate::matching::deep::train::weights::load_module(
        PublishedNet::new(cfg, Init::Zeros, device),
        bytes,
    )
}
