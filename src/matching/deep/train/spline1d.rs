//! SplineCNN over edge lengths (Fey et al. 2018): [`GraphTensors`] holds
//! graphs as tensors, padded to a common node count, with each edge's 1-D
//! B-spline weights (`published::graph::length_basis`) mixed into one dense
//! matrix; [`SplineConv1d`] is PyG's `SplineConv` with `dim = 1`,
//! `kernel_size = 5`, degree 1, mean aggregation, a root weight and a bias;
//! [`SplineCnn`] is the stack of DGMC's public code (`SplineCNN`): two
//! convolutions each followed by ReLU, optionally the input and every
//! layer's output concatenated (`cat`), then a final linear layer.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation;

use super::init::Source;
use crate::matching::deep::features::{KERNEL, NODE_FEATURES};
use crate::matching::deep::published::PaperGraph;
use crate::matching::deep::published::graph::length_basis;

/// Graphs as tensors, padded to a common node count `N`.
pub(crate) struct GraphTensors {
    /// Real nodes of each graph.
    pub(crate) counts: Vec<usize>,
    /// `[B, 1, N, F]` node attributes (zeros for padding), `F` the graphs'
    /// node width.
    pub(crate) x: Tensor<4>,
    /// `[B, 1, N, N * KERNEL]`: entry `[b, 0, i, j KERNEL + k]` is the basis
    /// weight of knot k of edge j -> i over the in-degree of i (zero when j
    /// is not a neighbour of i, and for padding).
    pub(crate) mixing: Tensor<4>,
    /// `[B, 1, N, 1]`: 1 for a real node, 0 for padding.
    pub(crate) node_mask: Tensor<4>,
}

impl GraphTensors {
    /// `graphs` padded to the largest (at least one node), edge lengths on
    /// knots from 0 to `scale_m`.
    pub(crate) fn new(graphs: &[&PaperGraph], scale_m: f64, device: &Device) -> Self {
        let b = graphs.len();
        let n = graphs.iter().map(|g| g.n).max().unwrap_or(0).max(1);
        let f = graphs.first().map_or(NODE_FEATURES, |g| g.node_width);
        debug_assert!(graphs.iter().all(|g| g.node_width == f));
        let k = KERNEL;
        let mut x = vec![0f32; b * n * f];
        let mut mixing = vec![0f32; b * n * n * k];
        let mut node_mask = vec![0f32; b * n];
        for (p, g) in graphs.iter().enumerate() {
            x[p * n * f..p * n * f + g.n * f].copy_from_slice(&g.node_features);
            node_mask[p * n..p * n + g.n].fill(1.0);
            let deg = g.in_degrees();
            let m = &mut mixing[p * n * n * k..(p + 1) * n * n * k];
            for e in 0..g.edge_count() {
                let (i, j) = (g.dst[e], g.src[e]);
                for (knot, w) in length_basis(f64::from(g.length_m[e]), scale_m) {
                    m[i * n * k + j * k + knot] += (w / deg[i] as f64) as f32;
                }
            }
        }
        Self {
            counts: graphs.iter().map(|g| g.n).collect(),
            x: Tensor::from_data(TensorData::new(x, [b, 1, n, f]), device),
            mixing: Tensor::from_data(TensorData::new(mixing, [b, 1, n, n * k]), device),
            node_mask: Tensor::from_data(TensorData::new(node_mask, [b, 1, n, 1]), device),
        }
    }

    /// Nodes per graph after padding.
    pub(crate) fn n(&self) -> usize {
        self.x.dims()[2]
    }
}

/// `SplineConv` over 1-D pseudo-coordinates: `x_i' = root x_i + mean_j
/// sum_k B_k(|e_ij|) W_k x_j + bias`.
#[derive(Module, Debug)]
pub(crate) struct SplineConv1d {
    /// `[in, KERNEL * out]`: the knots' weight matrices side by side.
    weight: Param<Tensor<2>>,
    /// `[in, out]`
    root: Param<Tensor<2>>,
    /// `[out]`
    bias: Param<Tensor<1>>,
    d_out: usize,
}

impl SplineConv1d {
    /// The layer `name` of `src` (`<name>.weight`, `.root`, `.bias`).
    pub(crate) fn from(src: &Source, name: &str) -> Self {
        let bias: Param<Tensor<1>> = src.param(&format!("{name}.bias"));
        Self {
            d_out: bias.val().dims()[0],
            weight: src.param(&format!("{name}.weight")),
            root: src.param(&format!("{name}.root")),
            bias,
        }
    }

    /// A fresh layer `name`, `d_in -> d_out` (tests).
    #[cfg(test)]
    pub(crate) fn new(
        name: &str,
        d_in: usize,
        d_out: usize,
        init: super::init::Init,
        device: &Device,
    ) -> Self {
        let specs = crate::matching::deep::params::spline_conv(name, "", [d_in, d_out], KERNEL);
        let params = init.params(&specs);
        Self::from(
            &Source {
                params: &params,
                specs: &specs,
                device,
            },
            name,
        )
    }

    /// `x: [B, T, N, in] -> [B, T, N, out]` (T samples of each graph; the
    /// graphs' `[B, 1, ...]` mixing is shared by the samples).
    pub(crate) fn forward(&self, x: Tensor<4>, g: &GraphTensors) -> Tensor<4> {
        let [b, t, n, d_in] = x.dims();
        let d_out = self.d_out;
        let rows = x.reshape([b * t * n, d_in]);
        let root = rows
            .clone()
            .matmul(self.root.val())
            .reshape([b, t, n, d_out]);
        // Rows (j, knot) of x_j W_knot: a reshape, no copy.
        let xw = rows
            .matmul(self.weight.val())
            .reshape([b, t, n * KERNEL, d_out]);
        let messages = g.mixing.clone().matmul(xw); // [B, 1, N, N K] x [B, T, N K, out]
        root + messages + self.bias.val().reshape([1, 1, 1, d_out])
    }

    /// The knots' weight matrices, `[in, KERNEL * out]`.
    #[cfg(test)]
    pub(crate) fn weights(&self) -> [Tensor<2>; 2] {
        [self.weight.val(), self.root.val()]
    }
}

/// DGMC's `SplineCNN`: two [`SplineConv1d`]s with ReLU, then a linear layer
/// on the last layer's output (`cat = false`, psi_1) or on the input and
/// both layers' outputs side by side (`cat = true`, psi_2).
#[derive(Module, Debug)]
pub(crate) struct SplineCnn {
    conv1: SplineConv1d,
    conv2: SplineConv1d,
    last: Linear,
    cat: bool,
}

impl SplineCnn {
    /// The stack `name` of `src` (`<name>.conv1`, `.conv2`, `.last`);
    /// `cat`: the last layer reads the input and both outputs.
    pub(crate) fn from(src: &Source, name: &str, cat: bool) -> Self {
        Self {
            conv1: SplineConv1d::from(src, &format!("{name}.conv1")),
            conv2: SplineConv1d::from(src, &format!("{name}.conv2")),
            last: src.linear(&format!("{name}.last")),
            cat,
        }
    }

    /// `x: [B, T0, N, in] -> [B, T, N, out]`. `mask`: an inverted-dropout
    /// mask after the first ReLU (`[B, T, N, hidden]`), which also gives
    /// the T samples of an input shared by all (`T0 = 1`).
    pub(crate) fn forward(
        &self,
        x: Tensor<4>,
        g: &GraphTensors,
        mask: Option<Tensor<4>>,
    ) -> Tensor<4> {
        let h1 = activation::relu(self.conv1.forward(x.clone(), g));
        let h1 = match mask {
            Some(m) => h1 * m,
            None => h1,
        };
        let h2 = activation::relu(self.conv2.forward(h1.clone(), g));
        if self.cat {
            let t = h2.dims()[1];
            let [b, _, n, d] = x.dims();
            let x = x.expand([b, t, n, d]);
            self.last.forward(Tensor::cat(vec![x, h1, h2], 3))
        } else {
            self.last.forward(h2)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Vec2;
    use crate::graph::SceneGraph;

    /// The dense convolution equals the message sum written out per edge:
    /// `root x_i + sum over edges j -> i of 1/deg(i) sum_k b_k W_k x_j +
    /// bias`, padding included (a second, larger graph in the batch).
    #[test]
    fn spline_conv_1d_equals_the_per_edge_sum() {
        let device = crate::matching::deep::train::backend::device();
        let pts = [
            (0.0, 0.0),
            (12.0, 3.0),
            (5.0, 20.0),
            (-9.0, 14.0),
            (30.0, -20.0),
        ];
        let graph = |k: usize| {
            let p: Vec<Vec2> = pts[..k].iter().map(|&(x, y)| Vec2::new(x, y)).collect();
            let f: Vec<f32> = (0..k * NODE_FEATURES)
                .map(|v| (v as f32 * 0.37).sin())
                .collect();
            PaperGraph::with_features(f, NODE_FEATURES, &SceneGraph::delaunay(&p).unwrap())
        };
        let (small, large) = (graph(4), graph(5));
        let scale = 25.0;
        let g = GraphTensors::new(&[&small, &large], scale, &device);
        let (d_in, d_out) = (NODE_FEATURES, 3);
        let conv = SplineConv1d::new(
            "test",
            d_in,
            d_out,
            super::super::init::Init::Seeded(3),
            &device,
        );
        let out: Vec<f32> = conv
            .forward(g.x.clone(), &g)
            .try_into_vec_as::<f32>()
            .unwrap();
        let [w, root] = conv.weights().map(|t| t.try_into_vec_as::<f32>().unwrap());
        for (p, input) in [&small, &large].into_iter().enumerate() {
            let x = &input.node_features;
            let deg = input.in_degrees();
            for i in 0..input.n {
                for o in 0..d_out {
                    let mut expected: f32 = (0..d_in)
                        .map(|c| x[i * d_in + c] * root[c * d_out + o])
                        .sum();
                    for e in (0..input.edge_count()).filter(|&e| input.dst[e] == i) {
                        let j = input.src[e];
                        for (k, b) in length_basis(f64::from(input.length_m[e]), scale) {
                            let msg: f32 = (0..d_in)
                                .map(|f| x[j * d_in + f] * w[f * KERNEL * d_out + k * d_out + o])
                                .sum();
                            expected += b as f32 * msg / deg[i] as f32;
                        }
                    }
                    let got = out[(p * 5 + i) * d_out + o];
                    assert!(
                        (got - expected).abs() < 1e-5,
                        "{p} {i} {o}: {got} vs {expected}"
                    );
                }
            }
        }
    }
}
