//! The SplineCNN layer (Fey et al. 2018, paper Eq. 1) and the graphs it
//! runs on: [`GraphTensors`] holds graphs as tensors, padded to a common
//! node count, with each edge's degree-1 open B-spline weights over its
//! pseudo-coordinates (2-D offsets: `KERNEL` knots per dimension; or edge
//! lengths: `KERNEL` knots) mixed into dense matrices; [`SplineConv`] is
//! mean aggregation over the neighbours with a weight matrix per kernel
//! cell, plus a root weight, computed as two dense products (in whichever
//! order costs less for the project's network, weights first for the
//! published ones); [`SplineCnn`] is the stack of DGMC's public code
//! (`SplineCNN`): two convolutions each followed by ReLU, optionally the
//! input and every layer's output concatenated (`cat`), then a final
//! linear layer. The reference of inference computes only the kernel
//! cells a graph uses, and keeps their weights per cell set
//! ([`CellWeights`]).

use std::sync::Arc;

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation;

use super::init::Source;
use crate::matching::deep::features::NODE_FEATURES;
#[cfg(test)]
use crate::matching::deep::graph::length_basis;
use crate::matching::deep::graph::{KERNEL, KERNEL_2D, LengthGraph, OffsetGraph};

/// Graphs as tensors, padded to a common node count `N` (a batch of
/// training pairs' graphs, or one graph at inference, `B = 1`).
pub(crate) struct GraphTensors {
    /// Real nodes of each graph.
    pub(crate) counts: Vec<usize>,
    /// `[B, 1, N, F]` node attributes (zeros for padding).
    pub(crate) x: Tensor<4>,
    /// The kernel cells whose messages are computed (ascending), as
    /// indices `[C]`: all of them, or only those some edge uses.
    pub(crate) cells: Tensor<1, Int>,
    /// `[B, 1, N, N * C]`: entry `[b, 0, i, j C + c]` is the basis weight
    /// of cell `cells[c]` of edge j -> i over the degree of i (zero when j
    /// is not a neighbour of i, and for padding). Columns run node-major
    /// so that the messages `x W` need only a reshape.
    pub(crate) mixing: Tensor<4>,
    /// `[B, 1, N * C, N]`: the same weights with rows (i, cell) and
    /// columns j, for layers that mix neighbours before their weights
    /// (over 2-D offsets only).
    pub(crate) mixing_by_cell: Option<Tensor<4>>,
    /// `[B, 1, N, 1]`: 1 for a real node, 0 for padding.
    pub(crate) node_mask: Tensor<4>,
    /// Directed edges over the whole batch (0: no messages at all).
    pub(crate) edges: usize,
    /// Bit k set when kernel cell k is in `cells`.
    #[cfg_attr(
        not(test),
        allow(dead_code, reason = "the tensor reference's cell cache")
    )]
    pub(crate) cell_mask: u32,
    /// The spline layers' weights of exactly these cells, when the caller
    /// has them ([`super::OursNet::cell_weights`]); else each
    /// layer selects them.
    pub(crate) weights: Option<Arc<CellWeights>>,
}

/// Every spline layer's weights of one set of kernel cells (`[in, C *
/// out]` each): what [`SplineConv::forward`] would select, kept by a
/// caller that sees the same cell set many times (inference).
pub(crate) struct CellWeights {
    /// The cell set, as [`GraphTensors::cell_mask`].
    #[cfg_attr(
        not(test),
        allow(dead_code, reason = "the tensor reference's cell cache")
    )]
    pub(crate) cell_mask: u32,
    pub(crate) conv1: Tensor<2>,
    pub(crate) conv2: Tensor<2>,
    pub(crate) consensus: Option<Tensor<2>>,
}

impl GraphTensors {
    /// Graphs over 2-D offsets padded to the largest, with every kernel
    /// cell (training: the gradient of a cell selection costs more than
    /// the messages it saves).
    pub(crate) fn new(graphs: &[&OffsetGraph], device: &Device) -> Self {
        Self::with_cells(graphs, [true; KERNEL_2D], device)
    }

    /// One graph with only the kernel cells some edge uses (inference).
    #[cfg(test)]
    pub(crate) fn used_cells(g: &OffsetGraph, device: &Device) -> Self {
        let mut used = [false; KERNEL_2D];
        for k in g.used_cells().0 {
            used[k] = true;
        }
        Self::with_cells(&[g], used, device)
    }

    fn with_cells(graphs: &[&OffsetGraph], used: [bool; KERNEL_2D], device: &Device) -> Self {
        let b = graphs.len();
        let n = graphs.iter().map(|g| g.n).max().unwrap_or(0).max(1);
        let f = graphs.first().map_or(NODE_FEATURES, |g| g.node_width);
        debug_assert!(graphs.iter().all(|g| g.node_width == f));
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
            edges += g.edge_count();
            let block = k * n * n * c..(k + 1) * n * n * c;
            let (m, t) = (&mut mixing[block.clone()], &mut by_cell[block]);
            for (i, j, cells) in g.weighted_edges() {
                for (cell, w) in cells {
                    m[i * c * n + j * c + position[cell]] += w;
                    t[(i * c + position[cell]) * n + j] += w;
                }
            }
        }
        Self {
            counts: graphs.iter().map(|g| g.n).collect(),
            x: Tensor::from_data(TensorData::new(x, [b, 1, n, f]), device),
            cell_mask: cells.iter().map(|&k| 1u32 << k).sum(),
            cells: Tensor::from_data(TensorData::new(cells, [c]), device),
            mixing: Tensor::from_data(TensorData::new(mixing, [b, 1, n, n * c]), device),
            mixing_by_cell: Some(Tensor::from_data(
                TensorData::new(by_cell, [b, 1, n * c, n]),
                device,
            )),
            node_mask: Tensor::from_data(TensorData::new(node_mask, [b, 1, n, 1]), device),
            edges,
            weights: None,
        }
    }

    /// Graphs over edge lengths (knots from 0 to `scale_m`) padded to the
    /// largest (at least one node), every knot a cell.
    pub(crate) fn lengths(graphs: &[&LengthGraph], scale_m: f64, device: &Device) -> Self {
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
            let m = &mut mixing[p * n * n * k..(p + 1) * n * n * k];
            for (i, j, knots) in g.weighted_edges(scale_m) {
                for (knot, w) in knots {
                    m[i * n * k + j * k + knot] += w;
                }
            }
        }
        Self {
            counts: graphs.iter().map(|g| g.n).collect(),
            x: Tensor::from_data(TensorData::new(x, [b, 1, n, f]), device),
            cells: Tensor::from_data(TensorData::new((0..k as i64).collect(), [k]), device),
            mixing: Tensor::from_data(TensorData::new(mixing, [b, 1, n, n * k]), device),
            mixing_by_cell: None,
            node_mask: Tensor::from_data(TensorData::new(node_mask, [b, 1, n, 1]), device),
            edges: graphs.iter().map(|g| g.edge_count()).sum(),
            cell_mask: (1u32 << k) - 1,
            weights: None,
        }
    }

    /// Nodes per graph after padding.
    pub(crate) fn n(&self) -> usize {
        self.x.dims()[2]
    }

    /// With the spline layers' weights of this batch's cells; weights of
    /// another cell set are ignored (the layers then select their own).
    #[cfg(test)]
    pub(crate) fn with_weights(mut self, weights: Arc<CellWeights>) -> Self {
        if weights.cell_mask == self.cell_mask {
            self.weights = Some(weights);
        }
        self
    }
}

/// The spline convolution (PyG's `SplineConv`, degree 1, mean
/// aggregation, a root weight and a bias) over 2-D offsets (25 kernel
/// cells) or edge lengths (5 knots, `dim = 1`): `x_i' = root x_i +
/// mean_j sum_k B_k(u_ij) W_k x_j + bias`.
#[derive(Module, Debug)]
pub(crate) struct SplineConv {
    /// `[in, cells * out]`: the kernel cells' weight matrices side by
    /// side.
    weight: Param<Tensor<2>>,
    /// `[in, out]`
    root: Param<Tensor<2>>,
    /// `[out]`
    bias: Param<Tensor<1>>,
    d_out: usize,
    /// Whether the products run in the cheaper order (the project's
    /// network); else weights first (the published networks, as DGMC's
    /// code runs them).
    cheaper_order: bool,
}

impl SplineConv {
    /// The layer `name` of `src` (`<name>.weight`, `.root`, `.bias`),
    /// its products in the cheaper order or weights first.
    pub(crate) fn from(src: &Source, name: &str, cheaper_order: bool) -> Self {
        let bias: Param<Tensor<1>> = src.param(&format!("{name}.bias"));
        Self {
            d_out: bias.val().dims()[0],
            weight: src.param(&format!("{name}.weight")),
            root: src.param(&format!("{name}.root")),
            bias,
            cheaper_order,
        }
    }

    /// A fresh layer `name`, `d_in -> d_out`, of `cells` kernel cells
    /// (tests; the cheaper order over 2-D offsets).
    #[cfg(test)]
    pub(crate) fn new(
        name: &str,
        [d_in, d_out, cells]: [usize; 3],
        init: super::init::Init,
        device: &Device,
    ) -> Self {
        let specs = crate::matching::deep::params::spline_conv(name, "", [d_in, d_out], cells);
        let params = init.params(&specs);
        let src = Source {
            params: &params,
            specs: &specs,
            device,
        };
        Self::from(&src, name, cells == KERNEL_2D)
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
    pub(crate) fn forward(
        &self,
        x: Tensor<4>,
        g: &GraphTensors,
        selected: Option<&Tensor<2>>,
    ) -> Tensor<4> {
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
        if !self.cheaper_order {
            // Rows (j, cell) of x_j W_cell: a reshape, no copy.
            let cells = g.cells.dims()[0];
            let xw = rows
                .matmul(self.weight.val())
                .reshape([b, t, n * cells, d_out]);
            let messages = g.mixing.clone().matmul(xw); // [B, 1, N, N C] x [B, T, N C, out]
            return root + messages + bias;
        }
        if g.edges == 0 {
            return root + bias;
        }
        let c = g.cells.dims()[0];
        let w = match selected {
            Some(w) => w.clone(),
            None => self.cell_weights(&g.cells),
        };
        let messages = if self.mixes_first() {
            let by_cell = g.mixing_by_cell.clone();
            let mixed = by_cell.expect("graphs over 2-D offsets").matmul(x); // [B, T, N C, in]
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

    /// The kernel cells' weight matrices, `[in, KERNEL_2D * out]`.
    #[cfg(test)]
    pub(crate) fn weight(&self) -> Tensor<2> {
        self.weight.val()
    }

    /// Whether the neighbours are mixed before the weights (in the
    /// cheaper order, with fewer inputs than outputs).
    fn mixes_first(&self) -> bool {
        self.cheaper_order && self.root.val().dims()[0] < self.d_out
    }

    /// The weights of the kernel cells `cells` in the layout of
    /// [`Self::forward`]'s order: `[in, C * out]`, or `[C * in, out]`
    /// when it mixes first.
    pub(crate) fn cell_weights(&self, cells: &Tensor<1, Int>) -> Tensor<2> {
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

/// DGMC's `SplineCNN`: two [`SplineConv`]s over edge length with ReLU, then a linear layer
/// on the last layer's output (`cat = false`, psi_1) or on the input and
/// both layers' outputs side by side (`cat = true`, psi_2).
#[derive(Module, Debug)]
pub(crate) struct SplineCnn {
    conv1: SplineConv,
    conv2: SplineConv,
    last: Linear,
    cat: bool,
}

impl SplineCnn {
    /// The stack `name` of `src` (`<name>.conv1`, `.conv2`, `.last`);
    /// `cat`: the last layer reads the input and both outputs.
    pub(crate) fn from(src: &Source, name: &str, cat: bool) -> Self {
        Self {
            conv1: SplineConv::from(src, &format!("{name}.conv1"), false),
            conv2: SplineConv::from(src, &format!("{name}.conv2"), false),
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
        let h1 = activation::relu(self.conv1.forward(x.clone(), g, None));
        let h1 = match mask {
            Some(m) => h1 * m,
            None => h1,
        };
        let h2 = activation::relu(self.conv2.forward(h1.clone(), g, None));
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
    use crate::matching::testkit::graph_input;

    /// The dense spline convolution, in both orders (weights first, and
    /// neighbours first), equals the message sum written out per edge:
    /// `root x_i + sum over edges j -> i of 1/deg(i) sum_c b_c W_(k_c) x_j
    /// + bias` (kernel cell k_c, basis weight b_c).
    #[test]
    fn spline_conv_equals_the_per_edge_sum() {
        let device = crate::matching::deep::train::backend::device();
        let input = graph_input(&[
            (0.0, 0.0),
            (12.0, 3.0),
            (5.0, 20.0),
            (-9.0, 14.0),
            (30.0, -20.0),
        ]);
        let n = input.n;
        for (d_in, d_out) in [(3, 2), (2, 3)] {
            let conv = SplineConv::new(
                "test",
                [d_in, d_out, KERNEL_2D],
                super::super::init::Init::Seeded(3),
                &device,
            );
            assert_eq!(conv.mixes_first(), d_in < d_out);
            let x: Vec<f32> = (0..n * d_in).map(|v| (v as f32 * 0.37).sin()).collect();
            let all = GraphTensors::new(&[&input], &device);
            let used = GraphTensors::used_cells(&input, &device);
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
                        let deg = input.in_degrees();
                        for e in (0..input.edge_count()).filter(|&e| input.dst[e] == i) {
                            let j = input.src[e];
                            let inv_deg = 1.0 / deg[i] as f32;
                            for (k, b) in input.basis(e) {
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
}

#[cfg(test)]
mod tests_1d {
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
            LengthGraph::with_features(f, NODE_FEATURES, &SceneGraph::delaunay(&p).unwrap())
        };
        let (small, large) = (graph(4), graph(5));
        let scale = 25.0;
        let g = GraphTensors::lengths(&[&small, &large], scale, &device);
        let (d_in, d_out) = (NODE_FEATURES, 3);
        let conv = SplineConv::new(
            "test",
            [d_in, d_out, KERNEL],
            super::super::init::Init::Seeded(3),
            &device,
        );
        let out: Vec<f32> = conv
            .forward(g.x.clone(), &g, None)
            .try_into_vec_as::<f32>()
            .unwrap();
        let [w, root] =
            [conv.weight.val(), conv.root.val()].map(|t| t.try_into_vec_as::<f32>().unwrap());
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
                        for (k, b) in length_basis(input.edge_m[e][0], scale) {
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
