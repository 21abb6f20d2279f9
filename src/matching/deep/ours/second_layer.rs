//! The second spline convolution at inference under shared dropout masks
//! (Eq. 8: one mask per sample over a layer's units, the same for every
//! node of every graph), in plain Rust: the arithmetic the masks make
//! unnecessary is not done; under masks per node, the tensor layer's
//! products ([`PlainSpline::forward_per_node`]). Training's `OursNet::embed`
//! is the reference both are held to (the path tester).
//!
//! In sample `t` a dropped input unit contributes nothing and a dropped
//! output unit is zeroed after the ReLU, so only the kept rows and columns
//! of the root and cell weights are multiplied: `[n, K_t] x [K_t, (1 +
//! 25) O_t]` (`K_t` about 0.6 of 256 and `O_t` 0.6 of 32), against the
//! dense `[T n, 256] x [256, C 32]` of the tensor path. The weights of
//! each sample are gathered once per matcher (the masks are the same for
//! every graph) and every kernel cell is computed, so a graph's own cell
//! set needs no other copy. The neighbours are then mixed along the
//! edges (4 cells per edge) instead of through a dense `n x n C` matrix.

use crate::matching::deep::graph::{KERNEL_2D, OffsetGraph};
use crate::matching::deep::kernels::matmul;
use crate::matching::deep::kernels::spline::{Cells, Incoming};
use crate::matching::deep::params::Params;

/// One sample's kept units and weights.
struct Sample {
    /// Kept input units (ascending) and the mask's value on them.
    kept_in: Vec<usize>,
    in_scale: f32,
    /// Kept output units (ascending) and the mask's value on them.
    kept_out: Vec<usize>,
    out_scale: f32,
    /// `[K_t, (1 + KERNEL_2D) O_t]`, row-major: per kept input unit, the
    /// root's kept outputs, then each kernel cell's.
    weights: Vec<f32>,
    /// The bias of the kept outputs.
    bias: Vec<f32>,
}

/// A spline layer's weights under `T` shared masks (`relu(conv(h m1)) m2`).
pub(crate) struct SharedMaskConv {
    d_in: usize,
    d_out: usize,
    samples: Vec<Sample>,
}

/// A layer's parameters as plain numbers: `root` `[in, out]`, `weight`
/// `[in, KERNEL_2D * out]` (cell-major within a row), `bias` `[out]`.
pub(crate) struct PlainSpline {
    pub(crate) d_in: usize,
    pub(crate) d_out: usize,
    pub(crate) root: Vec<f32>,
    pub(crate) weight: Vec<f32>,
    pub(crate) bias: Vec<f32>,
}

impl PlainSpline {
    /// The layer `name` of `p` (`<name>.root`, `.weight`, `.bias`).
    pub(crate) fn of(p: &Params, name: &str) -> Self {
        let (shape, root) = p.get(&format!("{name}.root"));
        Self {
            d_in: shape[0],
            d_out: shape[1],
            root: root.to_vec(),
            weight: p.values(&format!("{name}.weight")).to_vec(),
            bias: p.values(&format!("{name}.bias")).to_vec(),
        }
    }

    /// `relu(conv(h m1)) m2` under masks per node and unit, `h` `[n, in]`
    /// the same in every sample, `m1` `[T, n, in]`, `m2` `[T, n, out]`:
    /// `[T, n, out]`. The tensor layer's products: every sample's rows at
    /// once against the root and against the used kernel cells' weights,
    /// then the neighbours mixed through the dense `[n, n C]` matrix.
    pub(crate) fn forward_per_node(
        &self,
        g: &OffsetGraph,
        h: &[f32],
        [m1, m2]: [&[f32]; 2],
    ) -> Vec<f32> {
        let (n, d_in, d_out) = (g.n, self.d_in, self.d_out);
        let t = m1.len() / (n * d_in).max(1);
        let x: Vec<f32> = m1
            .chunks(n * d_in)
            .flat_map(|m| m.iter().zip(h).map(|(m, h)| h * m))
            .collect();
        let mut root = vec![0f32; t * n * d_out];
        matmul(t * n, d_in, d_out, &x, &self.root, &mut root);
        let e = g.edge_count();
        if e > 0 {
            let (cells, position) = g.used_cells();
            let c = cells.len();
            let mut w = vec![0f32; d_in * c * d_out];
            for u in 0..d_in {
                for (p, &k) in cells.iter().enumerate() {
                    let from = u * KERNEL_2D * d_out + k * d_out;
                    let to = u * c * d_out + p * d_out;
                    w[to..to + d_out].copy_from_slice(&self.weight[from..from + d_out]);
                }
            }
            let mut mixing = vec![0f32; n * n * c];
            for (i, j, cells) in g.weighted_edges() {
                for (k, w) in cells {
                    mixing[i * c * n + j * c + position[k]] += w;
                }
            }
            let mut xw = vec![0f32; t * n * c * d_out];
            matmul(t * n, d_in, c * d_out, &x, &w, &mut xw);
            let mut messages = vec![0f32; n * d_out];
            for (s, xw) in xw.chunks(n * c * d_out).enumerate() {
                matmul(n, n * c, d_out, &mixing, xw, &mut messages);
                let rows = &mut root[s * n * d_out..(s + 1) * n * d_out];
                for (r, m) in rows.iter_mut().zip(&messages) {
                    *r += m;
                }
            }
        }
        for (row, m) in root.chunks_exact_mut(d_out).zip(m2.chunks_exact(d_out)) {
            for ((v, b), m) in row.iter_mut().zip(&self.bias).zip(m) {
                let y = *v + b;
                *v = if y <= 0.0 { 0.0 } else { y } * m;
            }
        }
        root
    }
}

impl SharedMaskConv {
    /// The layer `p` under the masks `mask_in` (`[T, in]`) and `mask_out`
    /// (`[T, out]`), each unit's value 0 (dropped) or the sample's scale.
    pub(crate) fn new(p: &PlainSpline, mask_in: &[f32], mask_out: &[f32]) -> Self {
        let (d_in, d_out) = (p.d_in, p.d_out);
        let t = mask_in.len() / d_in;
        let kept = |m: &[f32]| -> (Vec<usize>, f32) {
            let k: Vec<usize> = (0..m.len()).filter(|&u| m[u] != 0.0).collect();
            let scale = k.first().map_or(0.0, |&u| m[u]);
            (k, scale)
        };
        let samples = (0..t)
            .map(|s| {
                let (kept_in, in_scale) = kept(&mask_in[s * d_in..(s + 1) * d_in]);
                let (kept_out, out_scale) = kept(&mask_out[s * d_out..(s + 1) * d_out]);
                let o = kept_out.len();
                let mut weights = Vec::with_capacity(kept_in.len() * (1 + KERNEL_2D) * o);
                for &u in &kept_in {
                    weights.extend(kept_out.iter().map(|&v| p.root[u * d_out + v]));
                    let row = &p.weight[u * KERNEL_2D * d_out..(u + 1) * KERNEL_2D * d_out];
                    for cell in 0..KERNEL_2D {
                        weights.extend(kept_out.iter().map(|&v| row[cell * d_out + v]));
                    }
                }
                let bias = kept_out.iter().map(|&v| p.bias[v]).collect();
                Sample {
                    kept_in,
                    in_scale,
                    kept_out,
                    out_scale,
                    weights,
                    bias,
                }
            })
            .collect();
        Self {
            d_in,
            d_out,
            samples,
        }
    }

    /// `relu(conv(h m1_t)) m2_t` for every sample `t` of each graph `g`
    /// whose layer input is `h` (`[n, in]`, the same for every sample):
    /// `[T, n, out]` per graph, row-major. The graphs' nodes are stacked
    /// into one product per sample.
    pub(crate) fn forward_many(&self, graphs: &[(&[f32], &OffsetGraph)]) -> Vec<Vec<f32>> {
        let d_out = self.d_out;
        let offsets: Vec<usize> = graphs
            .iter()
            .scan(0, |at, (_, g)| {
                let o = *at;
                *at += g.n;
                Some(o)
            })
            .collect();
        let rows: usize = graphs.iter().map(|(_, g)| g.n).sum();
        let edges: Vec<_> = graphs
            .iter()
            .zip(&offsets)
            .flat_map(|((_, g), &o)| edges(g, o))
            .collect();
        let incoming = Incoming::new(rows, &edges);
        let mut out: Vec<Vec<f32>> = graphs
            .iter()
            .map(|(_, g)| vec![0f32; self.samples.len() * g.n * d_out])
            .collect();
        let (mut x, mut y, mut messages) = (Vec::new(), Vec::new(), Vec::new());
        for (s, sample) in self.samples.iter().enumerate() {
            let (k, o) = (sample.kept_in.len(), sample.kept_out.len());
            let width = (1 + KERNEL_2D) * o;
            x.clear();
            for (h, g) in graphs {
                for i in 0..g.n {
                    let row = &h[i * self.d_in..(i + 1) * self.d_in];
                    x.extend(sample.kept_in.iter().map(|&u| row[u] * sample.in_scale));
                }
            }
            y.clear();
            y.resize(rows * width, 0.0);
            if k > 0 && o > 0 && rows > 0 {
                matmul(rows, k, width, &x, &sample.weights, &mut y);
            }
            // Mix the neighbours' cell outputs into each node's messages.
            messages.resize(rows * o, 0.0);
            incoming.messages(&y, (width, o), &mut messages);
            for ((_, g), (&at, out)) in graphs.iter().zip(offsets.iter().zip(&mut out)) {
                let block = &mut out[s * g.n * d_out..(s + 1) * g.n * d_out];
                for i in 0..g.n {
                    let r = at + i;
                    let root = &y[r * width..r * width + o];
                    for (q, &v) in sample.kept_out.iter().enumerate() {
                        let pre = (root[q] + messages[r * o + q]) + sample.bias[q];
                        block[i * d_out + v] = pre.max(0.0) * sample.out_scale;
                    }
                }
            }
        }
        out
    }
}

/// Graph `g`'s edges into node `i` from node `j`, its nodes at rows
/// `offset..`: each with the basis weight of its four cells over the
/// destination's degree, as the tensor path's mixing matrix holds them.
fn edges(g: &OffsetGraph, offset: usize) -> Vec<(usize, usize, Cells<4>)> {
    let mut edges = g.weighted_edges();
    for (i, j, _) in &mut edges {
        (*i, *j) = (offset + *i, offset + *j);
    }
    edges
}
