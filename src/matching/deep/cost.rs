//! The arithmetic of one MC-dropout inference, counted from the shapes of
//! [`super::network::Network`]'s products: multiply-adds (MACs) of the
//! matrix products (and of Sinkhorn's kernel products), per stage. Element
//! work (biases, ReLU, masks, softmax) is left out: it is a few per cent.
//! `cargo bench --bench matcher` holds the measured time against it and
//! against the machine's matrix-multiply peak.
//!
//! Every count follows the products as the network computes them today:
//! dense neighbour mixing over the `C` kernel cells the graph uses
//! (`spline.rs`), the first layer once for all samples, the second per
//! sample, consensus on the first graph's indicators once and on the
//! second's per sample.

use super::arch::{Architecture, PublishedConfig};
use super::features::{DUST_FEATURES, NODE_FEATURES, PAIR_FEATURES};
use super::graph::{KERNEL, KERNEL_2D, OffsetGraph};
use crate::matching::MatchView;

/// One graph as the network sees it: its nodes and the kernel cells its
/// edges use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GraphShape {
    pub nodes: usize,
    pub cells: usize,
    /// Directed edges.
    pub edges: usize,
}

impl GraphShape {
    /// A vehicle's view as the matcher builds its graph: the kernel cells
    /// of every edge's basis.
    pub fn of(view: &MatchView) -> Self {
        Self::of_input(&OffsetGraph::offsets(
            view.detections,
            view.graph,
            &view.pose_reported,
            crate::sensor::AppearanceWidth::NONE,
        ))
    }

    /// The graph the matcher built.
    pub(crate) fn of_input(g: &OffsetGraph) -> Self {
        Self {
            nodes: g.n,
            cells: g.used_cells().0.len(),
            edges: g.edge_count(),
        }
    }
}

/// Multiply-adds of one inference, per stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct InferenceMacs {
    /// The node embeddings of each graph (both spline convolutions).
    pub embeddings: [u64; 2],
    /// Pair and "no match" MLPs, similarity, consensus.
    pub pair: u64,
    /// Sinkhorn's kernel products, every iteration and sample.
    pub sinkhorn: u64,
}

impl InferenceMacs {
    /// A pair whose vehicles are new: both embeddings and the pair part.
    pub fn new_pair(&self) -> u64 {
        self.embeddings[0] + self.embeddings[1] + self.shared_pair()
    }

    /// A pair whose vehicles are already embedded: the pair part alone.
    pub fn shared_pair(&self) -> u64 {
        self.pair + self.sinkhorn
    }
}

/// The MACs of `ours`'s network ([`Architecture`]) on graphs `first` and
/// `second` with `samples` MC-dropout samples.
pub fn inference_macs(
    arch: &Architecture,
    first: GraphShape,
    second: GraphShape,
    samples: usize,
) -> InferenceMacs {
    let t = samples as u64;
    let (n1, n2) = (first.nodes as u64, second.nodes as u64);
    let embed = |g: GraphShape| {
        spline_conv(1, g, arch.node_features(), arch.hidden)
            + spline_conv(t, g, arch.hidden, arch.out)
    };
    let hp = arch.pair_hidden as u64;
    let mlps =
        n1 * n2 * (PAIR_FEATURES as u64 * hp + hp) + (n1 + n2) * (DUST_FEATURES as u64 * hp + hp);
    let similarity = t * n1 * n2 * arch.out as u64;
    let consensus = if arch.has_consensus() {
        let r = arch.consensus_dim as u64;
        t * n2 * n1 * r // soft^T r1
            + spline_conv(1, first, arch.consensus_dim, arch.consensus_dim)
            + spline_conv(t, second, arch.consensus_dim, arch.consensus_dim)
            + t * n1 * n2 * (r * r + r) // phi_in, phi_out
    } else {
        0
    };
    InferenceMacs {
        embeddings: [embed(first), embed(second)],
        pair: mlps + similarity + consensus,
        sinkhorn: t * arch.sinkhorn_iters as u64 * 2 * (n1 + 1) * (n2 + 1),
    }
}

/// The MACs of a published network (GCN-GM, or DGMC's network: DGMC and
/// the paper's method) with `samples` MC-dropout samples on graphs of
/// `nodes` nodes, as its plain inference path
/// (`published::inference`) computes it: psi_1's first
/// layer once per graph, its second per sample (under masks per node
/// every hidden channel, under shared masks the kept ones, expected), the
/// root's and every knot's products for every row; per consensus step
/// psi_2's first product on the source's indicators with the folded
/// `W_x W_in` columns beside it, the target's as `S^T` times the
/// source's (or `S^T R_s` times the weights when the source has more
/// than `rnd_dim` nodes), both graphs' second convolution and the folded
/// last-and-first layers on `[h1, h2]`, the consensus MLP's last layer
/// per node pair ([`super::published::plain::PlainConsensus`]); Sinkhorn
/// after `S_0` and every step. Neighbourhood sums along the edges are
/// element work (left out).
pub fn published_macs(
    cfg: &PublishedConfig,
    [n1, n2]: [usize; 2],
    samples: usize,
    per_node: bool,
) -> InferenceMacs {
    let t = samples as u64;
    let (a, b) = (n1 as u64, n2 as u64);
    let cells = 1 + KERNEL as u64;
    let (h, o, r) = (cfg.hidden as u64, cfg.out as u64, cfg.consensus_dim as u64);
    let kept = if per_node {
        h
    } else {
        ((1.0 - cfg.dropout_conv) * h as f64).round() as u64
    };
    let embed = |n: u64| n * NODE_FEATURES as u64 * cells * h + t * n * (kept * cells * o + o * o);
    // psi_2's first product: root, knots and the folded `W_x W_in`.
    let first = cells * r + r;
    let target_first = if a <= r {
        t * b * a * first
    } else {
        t * a * b * r + t * b * r * first
    };
    let rest = |n: u64| t * n * (r * cells * r + 2 * r * r);
    let steps = cfg.consensus_steps() as u64;
    let step = t * a * r * first + target_first + rest(a) + rest(b) + t * a * b * r;
    InferenceMacs {
        embeddings: [embed(a), embed(b)],
        pair: t * a * b * o + steps * step,
        sinkhorn: (1 + steps) * t * cfg.sinkhorn_iters as u64 * 2 * (a + 1) * (b + 1),
    }
}

/// The expected multiply-adds of graph `g`'s embedding with the second
/// layer in plain Rust under shared masks (`ours::second_layer`): the
/// first layer as the tensors do it, then per sample only the kept input
/// units (a share `1 - p` of them) times the kept outputs of the root and
/// every kernel cell, and the mixing along the edges (4 cells each).
pub fn plain_embedding_macs(arch: &Architecture, g: GraphShape, samples: usize) -> f64 {
    let keep = 1.0 - arch.dropout_conv;
    let (k, o) = (keep * arch.hidden as f64, keep * arch.out as f64);
    let per_sample = g.nodes as f64 * k * (1 + KERNEL_2D) as f64 * o + 4.0 * g.edges as f64 * o;
    spline_conv(1, g, arch.node_features(), arch.hidden) as f64 + samples as f64 * per_sample
}

/// One spline convolution on `rows` copies of graph `g` (1: once for all
/// samples; T: per sample): the root product and, in the order the layer
/// takes ([`super::spline`]: mix the inputs first when they are narrower
/// than the outputs), the cell weights and the dense neighbour mixing.
fn spline_conv(rows: u64, g: GraphShape, d_in: usize, d_out: usize) -> u64 {
    let (n, c, i, o) = (g.nodes as u64, g.cells as u64, d_in as u64, d_out as u64);
    let root = n * i * o;
    let cells = n * c * i * o;
    let mixing = if d_in < d_out {
        n * c * n * i
    } else {
        n * n * c * o
    };
    rows * (root + cells + mixing)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bench's pair (20 and 18 nodes, 23 cells each, T = 20) counted
    /// by hand from the products' shapes, stage by stage (conv1 root,
    /// mixing, cells; conv2 root, cells, mixing; MLPs, similarity,
    /// consensus, Sinkhorn).
    #[test]
    fn the_bench_pair_costs_what_its_shapes_say() {
        let arch = Architecture::default();
        let a = GraphShape {
            nodes: 20,
            cells: 23,
            edges: 98,
        };
        let b = GraphShape {
            nodes: 18,
            cells: 23,
            edges: 86,
        };
        let m = inference_macs(&arch, a, b, 20);
        let conv1 = |n: u64| n * 13 * 256 + n * 23 * n * 13 + n * 23 * 13 * 256;
        let conv2 = |n: u64| 20 * (n * 256 * 32 + n * 256 * 23 * 32 + n * n * 23 * 32);
        assert_eq!(m.embeddings, [conv1(20) + conv2(20), conv1(18) + conv2(18)]);
        assert_eq!(m.embeddings, [86_248_240, 77_082_732]);
        let cons = |rows: u64, n: u64| rows * (n * 32 * 32 + n * 23 * 32 * 32 + n * n * 23 * 32);
        let pair = 20 * 18 * (12 * 32 + 32)
            + 38 * (13 * 32 + 32)
            + 20 * 20 * 18 * 32
            + 20 * 18 * 20 * 32
            + cons(1, 20)
            + cons(20, 18)
            + 20 * 20 * 18 * (32 * 32 + 32);
        assert_eq!(m.pair, pair);
        assert_eq!(m.sinkhorn, 20 * 20 * 2 * 21 * 19);
        assert_eq!(m.shared_pair(), 22_952_544);
        assert_eq!(m.new_pair(), 186_283_516);
        // Without consensus only the MLPs and the similarity remain.
        let plain = Architecture {
            consensus_steps: 0,
            ..arch
        };
        let p = inference_macs(&plain, a, b, 20);
        assert_eq!(
            p.pair,
            20 * 18 * (12 * 32 + 32) + 38 * (13 * 32 + 32) + 20 * 20 * 18 * 32
        );
    }

    /// DGMC's network (the paper's sizes) on the bench's 20 x 18 pair,
    /// T = 20, counted by hand stage by stage; GCN-GM stops after `S_0`.
    #[test]
    fn a_published_pair_costs_what_its_shapes_say() {
        use crate::matching::deep::arch::PublishedKind;
        let dgmc = PublishedConfig::new(PublishedKind::Dgmc);
        let m = published_macs(&dgmc, [20, 18], 20, true);
        let embed = |n: u64| n * 13 * 6 * 256 + 20 * n * (256 * 6 * 32 + 32 * 32);
        assert_eq!(m.embeddings, [embed(20), embed(18)]);
        // Per step: the source's first product (root, 5 knots, W_x W_in:
        // 7 x 32 columns), the target's as S^T times it (20 source rows
        // per value), each graph's second convolution and [h1, h2] W_h
        // W_in, then the MLP's last layer per node pair.
        let rest = |n: u64| 20 * n * (32 * 6 * 32 + 64 * 32);
        let step =
            20 * 20 * 32 * 224 + 20 * 18 * 20 * 224 + rest(20) + rest(18) + 20 * 20 * 18 * 32;
        assert_eq!(m.pair, 20 * 20 * 18 * 32 + 10 * step);
        assert_eq!(m.sinkhorn, 11 * 20 * 20 * 2 * 21 * 19);
        assert_eq!(m.new_pair(), 151_997_344);
        // A source of 40 nodes (more than rnd_dim): the target's first
        // product from S^T R_s.
        let big = published_macs(&dgmc, [40, 18], 20, true);
        let step = 20 * 40 * 32 * 224
            + (20 * 40 * 18 * 32 + 20 * 18 * 32 * 224)
            + rest(40)
            + rest(18)
            + 20 * 40 * 18 * 32;
        assert_eq!(big.pair, 20 * 40 * 18 * 32 + 10 * step);
        // Shared masks: the second layer on the 154 kept channels of 256.
        let shared = published_macs(&dgmc, [20, 18], 20, false);
        assert_eq!(
            shared.embeddings[0],
            20 * 13 * 6 * 256 + 20 * 20 * (154 * 6 * 32 + 32 * 32)
        );
        let gcn = published_macs(
            &PublishedConfig::new(PublishedKind::GcnGm),
            [20, 18],
            20,
            true,
        );
        assert_eq!(gcn.pair, 20 * 20 * 18 * 32);
        assert_eq!(gcn.sinkhorn, 20 * 20 * 2 * 21 * 19);
    }
}
