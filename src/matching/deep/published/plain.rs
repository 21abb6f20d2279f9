//! GCN-GM's and DGMC's inference under shared masks (Eq. 8: one dropout
//! mask over psi_1's hidden channels per sample, the same for every node
//! of both graphs), in plain Rust: what [`super::model::PublishedNet`]
//! computes through the tensors (the reference it is held equal to, and
//! what training and per-node masks use), for one pair and its `T`
//! samples.
//!
//! What is done differently, exactly up to float rounding:
//! - psi_1's second layer multiplies only the hidden channels a sample
//!   keeps (the mask's value folded into the kept rows of its weights,
//!   gathered once per matcher), and a graph's embedding does not depend
//!   on its partner, so [`super::PublishedMatcher`] keeps it for the
//!   graph's other pairs;
//! - every normalisation is Sinkhorn in the scaling domain, in f64
//!   ([`sinkhorn_probabilities`]: one `exp` per entry instead of two per
//!   entry and iteration), the same iterations as the log-domain tensor
//!   version up to its f32 rounding;
//! - DGMC's consensus MLP's first layer is linear before its bias, so
//!   `(o_s,i - o_t,j) W = o_s,i W - o_t,j W`: `n1 + n2` products per
//!   sample and step instead of `n1 n2`; psi_2 runs on every sample's
//!   indicators in one product per layer;
//! - neighbours are mixed along the edges, not through a dense matrix.

use super::graph::{PaperGraph, length_basis};
use crate::matching::deep::dense::matmul;
use crate::matching::deep::features::KERNEL;
use crate::matching::deep::plain_pair::{PlainLinear, lane_sum, relu, similarity};
use crate::matching::deep::sinkhorn::sinkhorn_probabilities;

/// An edge into row `dst` from row `src` of stacked graphs, with its two
/// knots' basis weights over the destination's in-degree.
type Edge = (usize, usize, [(usize, f32); 2]);

/// The edges of `g` with its nodes at rows `offset..`, as the tensor
/// path's mixing matrix weighs them.
fn edges(g: &PaperGraph, scale_m: f64, offset: usize) -> Vec<Edge> {
    let deg = g.in_degrees();
    (0..g.edge_count())
        .map(|e| {
            let (i, j) = (g.dst[e], g.src[e]);
            let basis = length_basis(f64::from(g.length_m[e]), scale_m);
            let w = basis.map(|(knot, b)| (knot, (b / deg[i] as f64) as f32));
            (offset + i, offset + j, w)
        })
        .collect()
}

/// `edges` repeated for `blocks` stacked copies of a graph of `n` nodes.
fn repeated(edges: &[Edge], n: usize, blocks: usize) -> Vec<Edge> {
    (0..blocks)
        .flat_map(|b| {
            edges
                .iter()
                .map(move |&(i, j, w)| (i + b * n, j + b * n, w))
        })
        .collect()
}

/// A 1-D spline convolution as plain numbers: the root's and each knot's
/// weights side by side, `[in, (1 + KERNEL) out]`, and the bias.
pub(super) struct Conv1d {
    d_in: usize,
    d_out: usize,
    joined: Vec<f32>,
    bias: Vec<f32>,
}

impl Conv1d {
    /// From the layer's `root` `[in, out]`, `weight` `[in, KERNEL out]`
    /// and `bias` `[out]`.
    pub(super) fn new(root: &[f32], weight: &[f32], bias: Vec<f32>) -> Self {
        let d_out = bias.len();
        let d_in = root.len() / d_out.max(1);
        let mut joined = Vec::with_capacity(d_in * (1 + KERNEL) * d_out);
        for u in 0..d_in {
            joined.extend_from_slice(&root[u * d_out..(u + 1) * d_out]);
            joined.extend_from_slice(&weight[u * KERNEL * d_out..(u + 1) * KERNEL * d_out]);
        }
        Self {
            d_in,
            d_out,
            joined,
            bias,
        }
    }

    /// The layer on the input rows `kept` only, each row of weights times
    /// `scale`: a dropout mask over the input folded in.
    fn kept(&self, kept: &[usize], scale: f32) -> Self {
        let width = (1 + KERNEL) * self.d_out;
        let joined = kept
            .iter()
            .flat_map(|&u| {
                self.joined[u * width..(u + 1) * width]
                    .iter()
                    .map(|w| w * scale)
            })
            .collect();
        Self {
            d_in: kept.len(),
            d_out: self.d_out,
            joined,
            bias: self.bias.clone(),
        }
    }

    /// `relu(root x_i + sum_edges w x_j W_knot + bias)` of the stacked
    /// rows `x` (`[rows, in]`), into `out` (`[rows, out]`).
    fn relu_forward(&self, x: &[f32], rows: usize, edges: &[Edge], out: &mut Vec<f32>) {
        let (d, width) = (self.d_out, (1 + KERNEL) * self.d_out);
        let mut y = vec![0f32; rows * width];
        if rows > 0 && self.d_in > 0 {
            matmul(rows, self.d_in, width, x, &self.joined, &mut y);
        }
        let mut messages = vec![0f32; rows * d];
        for &(i, j, cells) in edges {
            for (knot, w) in cells {
                let from = &y[j * width + (1 + knot) * d..j * width + (2 + knot) * d];
                for (m, v) in messages[i * d..(i + 1) * d].iter_mut().zip(from) {
                    *m += w * v;
                }
            }
        }
        out.clear();
        out.extend((0..rows * d).map(|k| {
            let (r, o) = (k / d, k % d);
            relu((y[r * width + o] + messages[k]) + self.bias[o])
        }));
    }
}

/// `x W + b` of the stacked rows `x` (`[rows, in]`).
fn linear_rows(l: &PlainLinear, x: &[f32], rows: usize) -> Vec<f32> {
    let mut out = vec![0f32; rows * l.d_out];
    if rows > 0 {
        matmul(rows, l.d_in, l.d_out, x, &l.weight, &mut out);
    }
    for row in out.chunks_mut(l.d_out) {
        for (o, b) in row.iter_mut().zip(&l.bias) {
            *o += b;
        }
    }
    out
}

/// DGMC's `SplineCNN` as plain numbers (psi_1 without `cat`, psi_2 with).
pub(super) struct PlainCnn {
    pub conv1: Conv1d,
    pub conv2: Conv1d,
    pub last: PlainLinear,
    pub cat: bool,
}

impl PlainCnn {
    /// psi_2 on the stacked rows `x` (`[rows, in]`, no dropout).
    fn forward(&self, x: &[f32], rows: usize, edges: &[Edge]) -> Vec<f32> {
        let (mut h1, mut h2) = (Vec::new(), Vec::new());
        self.conv1.relu_forward(x, rows, edges, &mut h1);
        self.conv2.relu_forward(&h1, rows, edges, &mut h2);
        if !self.cat {
            return linear_rows(&self.last, &h2, rows);
        }
        let (a, b, c) = (self.conv1.d_in, self.conv1.d_out, self.conv2.d_out);
        let mut joined = Vec::with_capacity(rows * (a + b + c));
        for r in 0..rows {
            joined.extend_from_slice(&x[r * a..(r + 1) * a]);
            joined.extend_from_slice(&h1[r * b..(r + 1) * b]);
            joined.extend_from_slice(&h2[r * c..(r + 1) * c]);
        }
        linear_rows(&self.last, &joined, rows)
    }
}

/// The network's parameters as plain numbers.
pub(super) struct PlainWeights {
    pub psi1: PlainCnn,
    /// psi_2 and the consensus MLP (DGMC).
    pub consensus: Option<(PlainCnn, PlainLinear, PlainLinear)>,
    pub dustbin: f32,
}

/// The network with `T` samples per pair.
pub(super) struct PlainPublished {
    psi1: PlainCnn,
    samples: usize,
    /// Under shared masks, psi_1's second layer per sample on the kept
    /// hidden channels.
    conv2_kept: Vec<(Vec<usize>, Conv1d)>,
    consensus: Option<(PlainCnn, PlainLinear, PlainLinear)>,
    dustbin: f32,
    steps: usize,
    iters: usize,
    scale_m: f64,
}

impl PlainPublished {
    /// `w` with `samples` samples per pair, under the shared psi_1 masks
    /// `shared` (`[T, hidden]`, each value 0 or the sample's scale) or
    /// masks per node given with each graph ([`Self::embed_per_node`]),
    /// `steps` consensus steps (0 for GCN-GM), `iters` Sinkhorn
    /// iterations and knots up to `scale_m`.
    pub(super) fn new(
        w: PlainWeights,
        samples: usize,
        shared: Option<&[f32]>,
        [steps, iters]: [usize; 2],
        scale_m: f64,
    ) -> Self {
        let hidden = w.psi1.conv1.d_out;
        let conv2_kept = shared
            .unwrap_or_default()
            .chunks(hidden.max(1))
            .map(|m| {
                let kept: Vec<usize> = (0..hidden).filter(|&u| m[u] != 0.0).collect();
                let scale = kept.first().map_or(0.0, |&u| m[u]);
                let layer = w.psi1.conv2.kept(&kept, scale);
                (kept, layer)
            })
            .collect();
        Self {
            psi1: w.psi1,
            samples,
            conv2_kept,
            consensus: w.consensus,
            dustbin: w.dustbin,
            steps,
            iters,
            scale_m,
        }
    }

    /// Samples this network draws.
    pub(super) fn samples(&self) -> usize {
        self.samples
    }

    /// `relu(conv1(x))` of `g`, `[n, hidden]` (the same in every sample),
    /// and `g`'s edges.
    fn first_layer(&self, g: &PaperGraph) -> (Vec<f32>, Vec<Edge>) {
        let e = edges(g, self.scale_m, 0);
        let mut h1 = Vec::new();
        self.psi1
            .conv1
            .relu_forward(&g.node_features, g.n, &e, &mut h1);
        (h1, e)
    }

    /// psi_1's embedding of `g` in every sample under masks per node and
    /// hidden channel (`mask`: `[T, n, hidden]`), `[T, n, out]`: every
    /// sample's rows in one product per layer.
    pub(super) fn embed_per_node(&self, g: &PaperGraph, mask: &[f32]) -> Vec<f32> {
        let (n, t) = (g.n, self.samples);
        let (h1, e) = self.first_layer(g);
        let hidden = self.psi1.conv1.d_out;
        let x: Vec<f32> = mask
            .chunks(hidden.max(1))
            .enumerate()
            .flat_map(|(row, m)| {
                let h = &h1[(row % n.max(1)) * hidden..(row % n.max(1) + 1) * hidden];
                h.iter().zip(m).map(|(v, m)| v * m)
            })
            .collect();
        let mut h2 = Vec::new();
        self.psi1
            .conv2
            .relu_forward(&x, t * n, &repeated(&e, n, t), &mut h2);
        linear_rows(&self.psi1.last, &h2, t * n)
    }

    /// psi_1's embedding of `g` in every sample under the shared masks,
    /// `[T, n, out]`.
    pub(super) fn embed(&self, g: &PaperGraph) -> Vec<f32> {
        let n = g.n;
        let (h1, e) = self.first_layer(g);
        let hidden = self.psi1.conv1.d_out;
        let mut out = Vec::with_capacity(self.samples() * n * self.psi1.last.d_out);
        let (mut x, mut h2) = (Vec::new(), Vec::new());
        for (kept, layer) in &self.conv2_kept {
            x.clear();
            for row in h1.chunks(hidden) {
                x.extend(kept.iter().map(|&u| row[u]));
            }
            layer.relu_forward(&x, n, &e, &mut h2);
            out.extend(linear_rows(&self.psi1.last, &h2, n));
        }
        out
    }

    /// The soft assignments of the samples, each `(n1 + 1) x (n2 + 1)`:
    /// `h1` and `h2` the two graphs' embeddings ([`Self::embed`]),
    /// `indicators` one `[T, n1, rnd_dim]` draw per consensus step.
    pub(super) fn assignments(
        &self,
        [(h1, g1), (h2, g2)]: [(&[f32], &PaperGraph); 2],
        indicators: &[Vec<f32>],
    ) -> Vec<Vec<f32>> {
        let (n1, n2, t) = (g1.n, g2.n, self.samples());
        let mut s_hat = similarity(h1, h2, [t, n1, n2]);
        let mut p = self.normalise(&s_hat, [t, n1, n2]);
        if let Some((psi2, mlp_in, mlp_out)) = &self.consensus {
            let r = mlp_in.d_in;
            let (e1, e2) = (
                repeated(&edges(g1, self.scale_m, 0), n1, t),
                repeated(&edges(g2, self.scale_m, 0), n2, t),
            );
            for r_s in indicators.iter().take(self.steps) {
                // r_t = S^T r_s per sample, S the real block of the
                // current assignment.
                let mut r_t = vec![0f32; t * n2 * r];
                for s in 0..t {
                    for i in 0..n1 {
                        let ind = &r_s[(s * n1 + i) * r..(s * n1 + i + 1) * r];
                        for j in 0..n2 {
                            let w = p[(s * (n1 + 1) + i) * (n2 + 1) + j];
                            let out = &mut r_t[(s * n2 + j) * r..(s * n2 + j + 1) * r];
                            for (x, v) in out.iter_mut().zip(ind) {
                                *x += w * v;
                            }
                        }
                    }
                }
                let o_s = psi2.forward(r_s, t * n1, &e1);
                let o_t = psi2.forward(&r_t, t * n2, &e2);
                // MLP(o_s,i - o_t,j) = mlp_out(relu(o_s,i W - o_t,j W + b)).
                let project = |x: &[f32], rows: usize| {
                    let mut out = vec![0f32; rows * mlp_in.d_out];
                    if rows > 0 {
                        matmul(rows, mlp_in.d_in, mlp_in.d_out, x, &mlp_in.weight, &mut out);
                    }
                    out
                };
                let (mut a, b) = (project(&o_s, t * n1), project(&o_t, t * n2));
                let h = mlp_in.d_out;
                for row in a.chunks_mut(h) {
                    for (x, c) in row.iter_mut().zip(&mlp_in.bias) {
                        *x += c;
                    }
                }
                for s in 0..t {
                    for i in 0..n1 {
                        let ai = &a[(s * n1 + i) * h..(s * n1 + i + 1) * h];
                        for j in 0..n2 {
                            let bj = &b[(s * n2 + j) * h..(s * n2 + j + 1) * h];
                            let delta =
                                lane_sum(ai, bj, &mlp_out.weight, |x, y, w| relu(x - y) * w);
                            s_hat[(s * n1 + i) * n2 + j] += delta + mlp_out.bias[0];
                        }
                    }
                }
                p = self.normalise(&s_hat, [t, n1, n2]);
            }
        }
        p.chunks_exact((n1 + 1) * (n2 + 1))
            .map(<[f32]>::to_vec)
            .collect()
    }

    /// Dustbin Sinkhorn of the scores, every node's and the corner's "no
    /// match" score the learned one.
    fn normalise(&self, s_hat: &[f32], [t, n1, n2]: [usize; 3]) -> Vec<f32> {
        let scores: Vec<f64> = s_hat.iter().map(|&v| f64::from(v)).collect();
        let bin = f64::from(self.dustbin);
        let (d1, d2) = (vec![bin; n1], vec![bin; n2]);
        sinkhorn_probabilities(&scores, [t, n1, n2], [&d1, &d2], bin, self.iters)
    }
}
