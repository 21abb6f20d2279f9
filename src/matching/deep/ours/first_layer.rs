//! The first spline convolution at inference, `relu(conv1(x))`, in plain
//! Rust: its input (the node attributes) depends on no mask, so it is
//! computed once per graph for every sample. The same products as the
//! tensor layer (training's `SplineConv::forward`, which mixes the
//! neighbours before its weights because it has fewer inputs than
//! outputs) in the same order, through the same `gemm` kernel: the root
//! product, the neighbours mixed by kernel cell, the used cells' weights,
//! then `(root + messages) + bias`.

use super::second_layer::PlainSpline;
use crate::matching::deep::graph::{KERNEL_2D, OffsetGraph};
use crate::matching::deep::kernels::matmul;

/// The first layer's weights as plain numbers.
pub(crate) struct FirstLayer {
    layer: PlainSpline,
}

impl FirstLayer {
    pub(crate) fn new(layer: PlainSpline) -> Self {
        Self { layer }
    }

    /// `relu(conv1(x))` of `g`, `[n, out]` row-major.
    pub(crate) fn forward(&self, g: &OffsetGraph) -> Vec<f32> {
        let (n, d_in, d_out) = (g.n.max(1), self.layer.d_in, self.layer.d_out);
        debug_assert_eq!(g.node_width, d_in, "node attributes as wide as the layer");
        let mut x = vec![0f32; n * d_in];
        x[..g.node_features.len()].copy_from_slice(&g.node_features);
        let mut root = vec![0f32; n * d_out];
        matmul(n, d_in, d_out, &x, &self.layer.root, &mut root);
        let bias = &self.layer.bias;
        if g.edge_count() > 0 {
            let messages = self.messages(g, &x, n);
            for (r, m) in root.iter_mut().zip(&messages) {
                *r += m;
            }
        }
        for row in root.chunks_exact_mut(d_out) {
            for (v, b) in row.iter_mut().zip(bias) {
                let y = *v + b;
                *v = if y <= 0.0 { 0.0 } else { y };
            }
        }
        root.truncate(g.n * d_out);
        root
    }

    /// The neighbours' messages `[n, out]`: the basis weights over the
    /// degree by (node, used cell) against `x`, then against the used
    /// cells' weights stacked.
    fn messages(&self, g: &OffsetGraph, x: &[f32], n: usize) -> Vec<f32> {
        let (d_in, d_out) = (self.layer.d_in, self.layer.d_out);
        let (cells, position) = g.used_cells();
        let c = cells.len();
        let mut by_cell = vec![0f32; n * c * n];
        for (i, j, cells) in g.weighted_edges() {
            for (k, w) in cells {
                by_cell[(i * c + position[k]) * n + j] += w;
            }
        }
        let mut mixed = vec![0f32; n * c * d_in];
        matmul(n * c, n, d_in, &by_cell, x, &mut mixed);
        // The used cells' weights, rows (cell, input unit).
        let mut w = Vec::with_capacity(c * d_in * d_out);
        for &k in &cells {
            for f in 0..d_in {
                let row = f * KERNEL_2D * d_out + k * d_out;
                w.extend_from_slice(&self.layer.weight[row..row + d_out]);
            }
        }
        let mut messages = vec![0f32; n * d_out];
        matmul(n, c * d_in, d_out, &mixed, &w, &mut messages);
        messages
    }
}
