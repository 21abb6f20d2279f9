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
//! cells a graph uses.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation;

use super::init::Source;
use crate::matching::deep::features::NODE_FEATURES;
use crate::matching::deep::graph::{GraphInput, KERNEL, KERNEL_2D, LengthGraph, OffsetGraph};
use crate::matching::deep::kernels::spline::Cells;

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
}

impl GraphTensors {
    /// Graphs over 2-D offsets padded to the largest, with every kernel
    /// cell (training: the gradient of a cell selection costs more than
    /// the messages it saves).
    pub(crate) fn new(graphs: &[&OffsetGraph], device: &Device) -> Self {
        let edges = graphs.iter().map(|g| g.weighted_edges()).collect();
        Self::padded(graphs, edges, (0..KERNEL_2D).collect(), true, device)
    }

    /// One graph with only the kernel cells some edge uses (inference).
    #[cfg(test)]
    pub(crate) fn used_cells(g: &OffsetGraph, device: &Device) -> Self {
        let used = g.used_cells().0;
        Self::padded(&[g], vec![g.weighted_edges()], used, true, device)
    }

    /// Graphs over edge lengths (knots from 0 to `scale_m`) padded to the
    /// largest (at least one node), every knot a cell.
    pub(crate) fn lengths(graphs: &[&LengthGraph], scale_m: f64, device: &Device) -> Self {
        let edges = graphs.iter().map(|g| g.weighted_edges(scale_m)).collect();
        Self::padded(graphs, edges, (0..KERNEL).collect(), false, device)
    }

    /// `graphs` with their weighted edges (i, j, kernel cells), padded to
    /// the largest (at least one node), the messages of the kernel cells
    /// `cells` (ascending); `by_cell`: with [`Self::mixing_by_cell`].
    fn padded<const D: usize, const B: usize>(
        graphs: &[&GraphInput<D>],
        edges: Vec<Vec<(usize, usize, Cells<B>)>>,
        cells: Vec<usize>,
        by_cell: bool,
        device: &Device,
    ) -> Self {
        let b = graphs.len();
        let n = graphs.iter().map(|g| g.n).max().unwrap_or(0).max(1);
        let f = graphs.first().map_or(NODE_FEATURES, |g| g.node_width);
        debug_assert!(graphs.iter().all(|g| g.node_width == f));
        let c = cells.len();
        let mut position = [0usize; KERNEL_2D];
        for (p, &k) in cells.iter().enumerate() {
            position[k] = p;
        }
        let mut x = vec![0f32; b * n * f];
        let mut mixing = vec![0f32; b * n * n * c];
        let mut by_cells = vec![0f32; if by_cell { b * n * n * c } else { 0 }];
        let mut node_mask = vec![0f32; b * n];
        for (k, (g, edges)) in graphs.iter().zip(&edges).enumerate() {
            x[k * n * f..k * n * f + g.n * f].copy_from_slice(&g.node_features);
            node_mask[k * n..k * n + g.n].fill(1.0);
            let block = k * n * n * c..(k + 1) * n * n * c;
            for &(i, j, weights) in edges {
                for (cell, w) in weights {
                    mixing[block.start + i * c * n + j * c + position[cell]] += w;
                    if by_cell {
                        by_cells[block.start + (i * c + position[cell]) * n + j] += w;
                    }
                }
            }
        }
        let tensor =
            |v: Vec<f32>, shape: [usize; 4]| Tensor::from_data(TensorData::new(v, shape), device);
        Self {
            counts: graphs.iter().map(|g| g.n).collect(),
            x: tensor(x, [b, 1, n, f]),
            cells: Tensor::from_data(
                TensorData::new(cells.iter().map(|&k| k as i64).collect(), [c]),
                device,
            ),
            mixing: tensor(mixing, [b, 1, n, n * c]),
            mixing_by_cell: by_cell.then(|| tensor(by_cells, [b, 1, n * c, n])),
            node_mask: tensor(node_mask, [b, 1, n, 1]),
            edges: edges.iter().map(Vec::len).sum(),
        }
    }

    /// Nodes per graph after padding.
    pub(crate) fn n(&self) -> usize {
        self.x.dims()[2]
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
    pub(crate) fn forward(&self, x: Tensor<4>, g: &GraphTensors) -> Tensor<4> {
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
        let w = self.cell_weights(&g.cells);
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
    fn cell_weights(&self, cells: &Tensor<1, Int>) -> Tensor<2> {
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
    use crate::matching::deep::graph::length_basis;
    use crate::matching::deep::train::init::Init;
    use crate::matching::testkit::graph_input;

    const POINTS: [(f64, f64); 5] = [
        (0.0, 0.0),
        (12.0, 3.0),
        (5.0, 20.0),
        (-9.0, 14.0),
        (30.0, -20.0),
    ];

    /// `out`'s rows `first..` for the graph `g` with inputs `x` equal the
    /// message sum written out per edge: `root x_i + sum over edges j -> i
    /// of 1/deg(i) sum_k b_k W_k x_j` (`basis`: edge e's cells, of
    /// `kernel`; the bias is 0).
    fn assert_per_edge_sum<const D: usize>(
        (conv, kernel): (&SplineConv, usize),
        (out, first): (&[f32], usize),
        (g, x): (&GraphInput<D>, &[f32]),
        basis: impl Fn(usize) -> Vec<(usize, f32)>,
    ) {
        let [w, root] =
            [conv.weight.val(), conv.root.val()].map(|t| t.try_into_vec_as::<f32>().unwrap());
        let (d_out, d_in) = (conv.d_out, root.len() / conv.d_out);
        let deg = g.in_degrees();
        for i in 0..g.n {
            for o in 0..d_out {
                let mut expected: f32 = (0..d_in)
                    .map(|c| x[i * d_in + c] * root[c * d_out + o])
                    .sum();
                for e in (0..g.edge_count()).filter(|&e| g.dst[e] == i) {
                    let j = g.src[e];
                    for (k, b) in basis(e) {
                        let msg: f32 = (0..d_in)
                            .map(|f| x[j * d_in + f] * w[f * kernel * d_out + k * d_out + o])
                            .sum();
                        expected += b * msg / deg[i] as f32;
                    }
                }
                let got = out[(first + i) * d_out + o];
                assert!(
                    (got - expected).abs() < 1e-5,
                    "{d_in} -> {d_out}, node {i}, out {o}: {got} vs {expected}"
                );
            }
        }
    }

    /// Over 2-D offsets, in both orders (weights first, and neighbours
    /// first), with every kernel cell and with the used ones only.
    #[test]
    fn spline_conv_equals_the_per_edge_sum() {
        let device = crate::matching::deep::train::backend::device();
        let input = graph_input(&POINTS);
        let n = input.n;
        for (d_in, d_out) in [(3, 2), (2, 3)] {
            let conv = SplineConv::new("test", [d_in, d_out, KERNEL_2D], Init::Seeded(3), &device);
            assert_eq!(conv.mixes_first(), d_in < d_out);
            let x: Vec<f32> = (0..n * d_in).map(|v| (v as f32 * 0.37).sin()).collect();
            let used = GraphTensors::used_cells(&input, &device);
            assert!(used.cells.dims()[0] < KERNEL_2D, "every cell used");
            for g in [&GraphTensors::new(&[&input], &device), &used] {
                let x_t = Tensor::from_data(TensorData::new(x.clone(), [1, 1, n, d_in]), &device);
                let out: Vec<f32> = conv.forward(x_t, g).try_into_vec_as::<f32>().unwrap();
                let basis = |e| input.basis(e).to_vec();
                assert_per_edge_sum((&conv, KERNEL_2D), (&out, 0), (&input, &x), basis);
            }
        }
    }

    /// Over edge lengths, padding included (a second, larger graph in the
    /// batch).
    #[test]
    fn spline_conv_1d_equals_the_per_edge_sum() {
        let device = crate::matching::deep::train::backend::device();
        let graph = |k: usize| {
            let p: Vec<Vec2> = POINTS[..k].iter().map(|&(x, y)| Vec2::new(x, y)).collect();
            let f: Vec<f32> = (0..k * NODE_FEATURES)
                .map(|v| (v as f32 * 0.37).sin())
                .collect();
            LengthGraph::with_features(f, NODE_FEATURES, &SceneGraph::delaunay(&p).unwrap())
        };
        let (small, large) = (graph(4), graph(5));
        let scale = 25.0;
        let g = GraphTensors::lengths(&[&small, &large], scale, &device);
        let conv = SplineConv::new("test", [NODE_FEATURES, 3, KERNEL], Init::Seeded(3), &device);
        let out: Vec<f32> = conv
            .forward(g.x.clone(), &g)
            .try_into_vec_as::<f32>()
            .unwrap();
        for (p, input) in [&small, &large].into_iter().enumerate() {
            let basis = |e: usize| {
                let cells = length_basis(input.edge_m[e][0], scale);
                cells.iter().map(|&(k, b)| (k, b as f32)).collect()
            };
            let x = &input.node_features;
            assert_per_edge_sum((&conv, KERNEL), (&out, p * 5), (input, x), basis);
        }
    }
}
