//! GCN-GM and DGMC as published (Fey et al. 2018, 2020), our own
//! code after the papers and the structure of DGMC's public code, on the
//! paper's inputs only: each vehicle's detections in its own body frame,
//! appearance attributes, Delaunay graphs with edge lengths. No GPS pose, no
//! heading, no likelihood prior: nothing here shares `ours`'s network.
//!
//! - `inference`: the network in plain Rust, for every mask scope. GCN-GM:
//!   psi_1 (two SplineConvs, 256 and 32 channels, each followed by ReLU,
//!   dropout 0.4 once on the 256 hidden channels, DGMC's final linear
//!   layer 32 -> 32), `S_0 = Sinkhorn(H_s H_t^T)`. DGMC: the same `S_0`,
//!   then L steps of `R_t = S^T R_s` (random node indicators), `o =
//!   psi_2(R)` on both graphs (two SplineConvs of `rnd_dim`, input and
//!   outputs concatenated, a final linear layer, as DGMC's psi_2), `S_hat
//!   += MLP(o_s,i - o_t,j)`, renormalised.
//! - `network`: [`Published`], the network as the MC shell runs it.
//! - here: the network's parameters ([`spec`]).
//! - Training (burn modules, Adam, NLL of the true correspondences on
//!   `S_0` and `S_L`; the paper's method adds its Eq. 12 and 13) is
//!   `crate::matching::deep::train`'s.
//!
//! The paper's method and its ablations (`coid`, `coid+non`, `coid+unc`)
//! are DGMC's network trained with the paper's losses: the paper builds
//! on DGMC (SplineCNN, neighbourhood consensus, Sinkhorn) and adds the
//! losses, MC dropout and thresholding.
//!
//! Normalisation: Sinkhorn with a dustbin row and column and one learned
//! "no match" score (SuperGlue's; neither the paper nor DGMC has a
//! dustbin), not DGMC's row softmax (the paper names Sinkhorn): the two graphs only partly overlap,
//! a softmax over the other graph's nodes forces every node onto some
//! partner, and the decision code ([`crate::matching::deep::decision`])
//! reads `(n1 + 1) x (n2 + 1)` assignments with dustbins. The consensus
//! steps push the indicators through the real block of the same
//! normalised assignment (a node that goes to its dustbin passes on
//! nothing).

mod check;
mod inference;
mod network;

pub use self::check::{GraphParts, PublishedForward};
pub(crate) use self::inference::{Conv1d, PlainCnn, PlainWeights};
pub(crate) use self::network::Published;
#[cfg(test)]
pub(crate) use self::network::{SHARED_MASKS_KEY, pair_key, pair_samples};

use crate::matching::deep::arch::{PublishedConfig, PublishedKind};
use crate::matching::deep::graph::KERNEL;
use crate::matching::deep::params::{self, ParamSpec, Params};

/// The dustbin score before training.
const INITIAL_DUSTBIN: f32 = 1.0;

/// The prefix of the parameters' stream names (`dgmc.`, `gcn_gm.`).
fn stream_prefix(cfg: &PublishedConfig) -> &'static str {
    match cfg.kind {
        PublishedKind::GcnGm => "gcn_gm.",
        PublishedKind::Dgmc => "dgmc.",
    }
}

/// The parameters of DGMC's `SplineCNN` `name`: two spline convolutions
/// over edge length `d_in -> hidden -> out`, then a linear layer to `out`
/// on the last output (`cat = false`) or on the input and both outputs
/// side by side (`cat = true`).
fn cnn(name: &str, prefix: &str, [d_in, hidden, out]: [usize; 3], cat: bool) -> Vec<ParamSpec> {
    let last_in = if cat { d_in + hidden + out } else { out };
    let mut v = params::spline_conv(&format!("{name}.conv1"), prefix, [d_in, hidden], KERNEL);
    v.extend(params::spline_conv(
        &format!("{name}.conv2"),
        prefix,
        [hidden, out],
        KERNEL,
    ));
    v.extend(params::linear(
        &format!("{name}.last"),
        prefix,
        [last_in, out],
    ));
    v
}

/// The parameters of the published network of `cfg`, as its weights file
/// names them: psi_1, and for DGMC psi_2 and the consensus MLP `rnd_dim ->
/// rnd_dim -> 1`; the "no match" score.
pub(crate) fn spec(cfg: &PublishedConfig) -> Vec<ParamSpec> {
    let prefix = stream_prefix(cfg);
    let mut v = cnn(
        "psi1",
        prefix,
        [cfg.node_features(), cfg.hidden, cfg.out],
        false,
    );
    if cfg.kind == PublishedKind::Dgmc {
        let r = cfg.consensus_dim;
        v.extend(cnn("psi2", prefix, [r, r, r], true));
        v.extend(params::linear("mlp_in", prefix, [r, r]));
        v.extend(params::linear("mlp_out", prefix, [r, 1]));
    }
    v.push(params::scalar("dustbin", prefix, INITIAL_DUSTBIN));
    v
}

/// The network's parameters as plain numbers.
pub(crate) fn plain_weights(cfg: &PublishedConfig, p: &Params) -> PlainWeights {
    let conv = |name: &str| {
        Conv1d::new(
            p.values(&format!("{name}.root")),
            p.values(&format!("{name}.weight")),
            p.values(&format!("{name}.bias")).to_vec(),
        )
    };
    let cnn = |name: &str| PlainCnn {
        conv1: conv(&format!("{name}.conv1")),
        conv2: conv(&format!("{name}.conv2")),
        last: p.linear(&format!("{name}.last")),
    };
    PlainWeights {
        psi1: cnn("psi1"),
        consensus: (cfg.kind == PublishedKind::Dgmc)
            .then(|| (cnn("psi2"), p.linear("mlp_in"), p.linear("mlp_out"))),
        dustbin: p.scalar("dustbin"),
    }
}
