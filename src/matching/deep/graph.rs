//! One vehicle's graph as a network reads it ([`GraphInput`]), as plain
//! numbers: node attributes (the paper's A, [`node_attributes`]), the
//! directed edges of its scene graph and each edge's pseudo-coordinates
//! `D` wide, with the degree-1 open B-spline basis over them (SplineCNN,
//! Fey et al. 2018; the paper's Phi(E_ij), Eq. 1), [`KERNEL`] knots per
//! dimension, weighted by the destination's in-degree (mean aggregation).
//!
//! - `ours` reads 2-D pseudo-coordinates ([`OffsetGraph`]): the edge vector
//!   rotated into world-aligned axes with the vehicle's *reported* heading
//!   (GPS position error does not enter). The knots sit where edges are,
//!   not on an even grid: at 0, +-the median and +-the 95th percentile of
//!   the edges' larger world-axis component over the training family
//!   ([`KNOTS_M`]; `coid train` records the measured values in each model's
//!   toml, `edge_median_m` and `edge_p95_m`); longer components are
//!   clipped onto the outer knot. 4 non-zero basis weights per edge.
//! - the published networks read edge lengths ([`LengthGraph`]), which a
//!   rigid motion of the body frame (two vehicles' frames differ by an
//!   unknown one) leaves unchanged: `KERNEL` knots evenly from 0 to a
//!   scale, 2 non-zero basis weights per edge, longer edges clipped (a
//!   fixed scale: PyG's `Distance` transform divides by each graph's
//!   longest edge instead, which changes with every detection added or
//!   dropped).

use crate::geometry::{Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::matching::deep::arch::NetworkGraph;
use crate::matching::deep::features::{NODE_FEATURES, node_attributes};
use crate::matching::deep::kernels::spline::Cells;
use crate::sensor::{AppearanceWidth, Detection};

/// B-spline knots per pseudo-coordinate dimension (paper: 5).
pub(crate) const KERNEL: usize = 5;
/// Kernel weights per edge: `KERNEL^2` for 2-D pseudo-coordinates.
pub(crate) const KERNEL_2D: usize = KERNEL * KERNEL;
/// The knots per axis of 2-D pseudo-coordinates, in metres: 0, +-median
/// and +-95th percentile of the edges' larger world-axis component over
/// the training family (17.7 m and 48.1 m measured on
/// `sumo_nets/family/train` s000-s007 and the default intersection).
pub(crate) const KNOTS_M: [f64; KERNEL] = [-48.0, -18.0, 0.0, 18.0, 48.0];
/// Longer edge components are clipped onto the outer knots.
pub(crate) const MAX_EDGE_M: f64 = KNOTS_M[KERNEL - 1];

/// One vehicle's graph with `D`-wide pseudo-coordinates per edge. Every
/// undirected edge appears twice, once per direction; message `e` goes
/// from `src[e]` to `dst[e]`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct GraphInput<const D: usize> {
    pub(crate) n: usize,
    /// `n x node_width`, row-major ([`node_attributes`]).
    pub(crate) node_features: Vec<f32>,
    /// Attributes per node: `NODE_FEATURES` plus the appearance vector's
    /// width where the network reads one.
    pub(crate) node_width: usize,
    pub(crate) src: Vec<usize>,
    pub(crate) dst: Vec<usize>,
    /// Each directed edge's pseudo-coordinates in metres.
    pub(crate) edge_m: Vec<[f64; D]>,
}

/// `ours`'s graph: each edge vector in world-aligned axes.
pub(crate) type OffsetGraph = GraphInput<2>;
/// The published networks' graph: each edge's length `E_ij = ||v_i -
/// v_j||` (Section 3.1).
pub(crate) type LengthGraph = GraphInput<1>;

impl<const D: usize> GraphInput<D> {
    pub(crate) fn edge_count(&self) -> usize {
        self.src.len()
    }

    /// Incoming edges of each node (mean aggregation divides by these).
    pub(crate) fn in_degrees(&self) -> Vec<usize> {
        let mut deg = vec![0; self.n];
        for &i in &self.dst {
            deg[i] += 1;
        }
        deg
    }
}

impl OffsetGraph {
    /// `detections`' graph for a network that reads appearance vectors
    /// `appearance_width` wide, the edges rotated with the heading of
    /// `pose_reported`; each node's incoming edges in neighbour order.
    pub(crate) fn offsets(
        detections: &[Detection],
        graph: &SceneGraph,
        pose_reported: &Pose2,
        appearance_width: AppearanceWidth,
    ) -> Self {
        let heading = Pose2::new(Vec2::zeros(), pose_reported.heading_rad());
        let (mut src, mut dst, mut edge_m) = (Vec::new(), Vec::new(), Vec::new());
        for (i, nb) in graph.neighbours().iter().enumerate() {
            for &j in nb {
                let d = heading.to_parent(&(graph.positions_m[j] - graph.positions_m[i]));
                src.push(j);
                dst.push(i);
                edge_m.push([d.x, d.y]);
            }
        }
        Self {
            n: detections.len(),
            node_features: node_attributes(detections, appearance_width),
            node_width: NODE_FEATURES + appearance_width.get(),
            src,
            dst,
            edge_m,
        }
    }

    /// Edge `e`'s 4 kernel cells with a non-zero basis weight, and those
    /// weights (they sum to 1).
    pub(crate) fn basis(&self, e: usize) -> Cells<4> {
        let [x, y] = self.edge_m[e];
        offset_basis(&Vec2::new(x, y)).map(|(k, w)| (k, w as f32))
    }

    /// Every edge `(destination, source, cells)` in edge order, each
    /// cell's basis weight over the destination's in-degree.
    pub(crate) fn weighted_edges(&self) -> Vec<(usize, usize, Cells<4>)> {
        let deg = self.in_degrees();
        (0..self.edge_count())
            .map(|e| {
                let (i, j) = (self.dst[e], self.src[e]);
                let inv_deg = 1.0 / deg[i] as f32;
                (i, j, self.basis(e).map(|(k, w)| (k, w * inv_deg)))
            })
            .collect()
    }

    /// The kernel cells some edge uses (ascending), and each cell's place
    /// among them.
    pub(crate) fn used_cells(&self) -> (Vec<usize>, [usize; KERNEL_2D]) {
        let mut used = [false; KERNEL_2D];
        for e in 0..self.edge_count() {
            for (k, _) in self.basis(e) {
                used[k] = true;
            }
        }
        let cells: Vec<usize> = (0..KERNEL_2D).filter(|&k| used[k]).collect();
        let mut position = [0usize; KERNEL_2D];
        for (p, &k) in cells.iter().enumerate() {
            position[k] = p;
        }
        (cells, position)
    }
}

impl LengthGraph {
    /// The graph of `detections` (body frame) that a published network of
    /// graph `kind` convolves over: their scene graph (Delaunay over the
    /// same positions, [`SceneGraph::delaunay`]) or every pair of them,
    /// for a psi_1 that reads appearance vectors `appearance_width` wide.
    pub(crate) fn lengths(
        detections: &[Detection],
        graph: &SceneGraph,
        kind: NetworkGraph,
        appearance_width: AppearanceWidth,
    ) -> Self {
        debug_assert_eq!(detections.len(), graph.node_count());
        let features = node_attributes(detections, appearance_width);
        let width = NODE_FEATURES + appearance_width.get();
        match kind {
            NetworkGraph::Delaunay => Self::with_features(features, width, graph),
            NetworkGraph::Complete => {
                let p = &graph.positions_m;
                let edges: Vec<_> = (0..p.len())
                    .flat_map(|a| (a + 1..p.len()).map(move |b| (a, b, (p[a] - p[b]).norm())))
                    .collect();
                Self::from_edges(features, width, &edges)
            }
        }
    }

    /// The Delaunay graph of `detections` (body frame).
    #[cfg(test)]
    pub(crate) fn delaunay(detections: &[Detection]) -> Result<Self, crate::graph::GraphError> {
        let positions: Vec<Vec2> = detections.iter().map(|d| d.position_m).collect();
        let graph = SceneGraph::delaunay(&positions)?;
        Ok(Self::lengths(
            detections,
            &graph,
            NetworkGraph::Delaunay,
            AppearanceWidth::NONE,
        ))
    }

    /// Node attributes `features` (`n x node_width`) on `graph`, each
    /// undirected edge's two directions in turn; lengths are read as
    /// float32, as DGMC's `edge_attr`.
    pub(crate) fn with_features(features: Vec<f32>, node_width: usize, graph: &SceneGraph) -> Self {
        assert_eq!(
            features.len(),
            graph.node_count() * node_width,
            "node attributes"
        );
        let edges: Vec<_> = graph.edges.iter().map(|e| (e.a, e.b, e.length_m)).collect();
        Self::from_edges(features, node_width, &edges)
    }

    /// Node attributes `features` (`n x node_width`) and undirected edges
    /// `(a, b, length)`, each in turn in both directions.
    pub(crate) fn from_edges(
        features: Vec<f32>,
        node_width: usize,
        edges: &[(usize, usize, f64)],
    ) -> Self {
        let n = features.len() / node_width.max(1);
        let (mut src, mut dst, mut edge_m) = (Vec::new(), Vec::new(), Vec::new());
        for &(a, b, length_m) in edges {
            for (from, to) in [(a, b), (b, a)] {
                src.push(from);
                dst.push(to);
                edge_m.push([f64::from(length_m as f32)]);
            }
        }
        Self {
            n,
            node_features: features,
            node_width,
            src,
            dst,
            edge_m,
        }
    }

    /// Every edge `(destination, source, cells)` in edge order on knots up
    /// to `scale_m`, each knot's basis weight over the destination's
    /// in-degree.
    pub(crate) fn weighted_edges(&self, scale_m: f64) -> Vec<(usize, usize, Cells<2>)> {
        let deg = self.in_degrees();
        (0..self.edge_count())
            .map(|e| {
                let (i, j) = (self.dst[e], self.src[e]);
                let basis = length_basis(self.edge_m[e][0], scale_m);
                (i, j, basis.map(|(k, b)| (k, (b / deg[i] as f64) as f32)))
            })
            .collect()
    }
}

/// Degree-1 B-spline weights of an edge component (metres) on the knots
/// [`KNOTS_M`]: the two active knots and their weights (clipped at the
/// ends).
fn offset_component_basis(d_m: f64) -> [(usize, f64); 2] {
    let d = d_m.clamp(KNOTS_M[0], KNOTS_M[KERNEL - 1]);
    let left = (0..KERNEL - 1)
        .rfind(|&k| KNOTS_M[k] <= d)
        .unwrap_or(0)
        .min(KERNEL - 2);
    let frac = (d - KNOTS_M[left]) / (KNOTS_M[left + 1] - KNOTS_M[left]);
    [(left, 1.0 - frac), (left + 1, frac)]
}

/// The 4 non-zero (kernel cell, weight) pairs of an edge vector given in
/// world-aligned axes.
pub(crate) fn offset_basis(d_world_m: &Vec2) -> [(usize, f64); 4] {
    let bx = offset_component_basis(d_world_m.x);
    let by = offset_component_basis(d_world_m.y);
    [
        (bx[0].0 * KERNEL + by[0].0, bx[0].1 * by[0].1),
        (bx[0].0 * KERNEL + by[1].0, bx[0].1 * by[1].1),
        (bx[1].0 * KERNEL + by[0].0, bx[1].1 * by[0].1),
        (bx[1].0 * KERNEL + by[1].0, bx[1].1 * by[1].1),
    ]
}

/// Degree-1 open B-spline weights of an edge of `length_m` on [`KERNEL`]
/// knots evenly spaced from 0 to `scale_m`: the two active knots and their
/// weights, which sum to 1 (lengths beyond the scale are clipped onto the
/// last knot).
pub(crate) fn length_basis(length_m: f64, scale_m: f64) -> [(usize, f64); 2] {
    let v = (length_m / scale_m).clamp(0.0, 1.0) * (KERNEL - 1) as f64;
    let left = (v.floor() as usize).min(KERNEL - 2);
    let frac = v - left as f64;
    [(left, 1.0 - frac), (left + 1, frac)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn offset_basis_is_a_partition_of_unity(x in -100.0..100.0f64, y in -100.0..100.0f64) {
            let b = offset_basis(&Vec2::new(x, y));
            let sum: f64 = b.iter().map(|&(_, w)| w).sum();
            prop_assert!((sum - 1.0).abs() < 1e-12);
            prop_assert!(b.iter().all(|&(k, w)| k < KERNEL_2D && (0.0..=1.0).contains(&w)));
        }

        #[test]
        fn length_basis_is_a_partition_of_unity(d in -5.0..200.0f64, scale in 10.0..100.0f64) {
            let b = length_basis(d, scale);
            prop_assert!((b[0].1 + b[1].1 - 1.0).abs() < 1e-12);
            prop_assert!(b.iter().all(|&(k, w)| k < KERNEL && (0.0..=1.0).contains(&w)));
            prop_assert_eq!(b[1].0, b[0].0 + 1);
        }
    }

    #[test]
    fn offset_knots_are_hit_exactly_and_interpolated_between() {
        for (k, &t) in KNOTS_M.iter().enumerate() {
            let b = offset_component_basis(t);
            let w: f64 = b.iter().filter(|&&(i, _)| i == k).map(|&(_, w)| w).sum();
            assert!((w - 1.0).abs() < 1e-12, "knot {k}");
        }
        // Halfway between the centre and the median knot.
        assert_eq!(
            offset_component_basis(KNOTS_M[3] / 2.0),
            [(2, 0.5), (3, 0.5)]
        );
        // Clipped beyond the outer knots.
        let outer = offset_component_basis(KNOTS_M[KERNEL - 1]);
        assert_eq!(offset_component_basis(500.0), outer);
        assert_eq!(
            offset_component_basis(-500.0),
            offset_component_basis(KNOTS_M[0])
        );
        // A zero edge sits on the centre cell.
        let centre = (KERNEL / 2) * KERNEL + KERNEL / 2;
        let b = offset_basis(&Vec2::zeros());
        let w: f64 = b
            .iter()
            .filter(|&&(k, _)| k == centre)
            .map(|&(_, w)| w)
            .sum();
        assert!((w - 1.0).abs() < 1e-12);
    }

    #[test]
    fn length_knots_are_hit_exactly_and_longer_edges_clipped() {
        let scale = 60.0;
        for k in 0..KERNEL {
            let b = length_basis(scale * k as f64 / (KERNEL - 1) as f64, scale);
            let w: f64 = b.iter().filter(|&&(i, _)| i == k).map(|&(_, w)| w).sum();
            assert!((w - 1.0).abs() < 1e-12, "knot {k}: {b:?}");
        }
        assert_eq!(length_basis(7.5, 60.0), [(0, 0.5), (1, 0.5)]);
        assert_eq!(length_basis(500.0, 60.0), length_basis(60.0, 60.0));
    }

    /// Every node averages its incoming messages: its edges' weights over
    /// every cell sum to 1, in both graphs, and each undirected edge runs
    /// both ways.
    #[test]
    fn every_node_averages_its_incoming_messages() {
        use crate::matching::testkit;
        let objects = testkit::world_objects();
        let dets = testkit::Side::of(
            testkit::POSE_A,
            &objects[..4],
            &[0, 1, 2, 3],
            testkit::EXACT,
        )
        .detections;
        let positions: Vec<Vec2> = dets.iter().map(|d| d.position_m).collect();
        let g = SceneGraph::delaunay(&positions).unwrap();
        let pose = Pose2::new(Vec2::new(5.0, 5.0), 0.7);
        let offsets = OffsetGraph::offsets(&dets, &g, &pose, AppearanceWidth::NONE);
        let lengths =
            LengthGraph::lengths(&dets, &g, NetworkGraph::Delaunay, AppearanceWidth::NONE);
        assert_eq!(offsets.node_features.len(), 4 * NODE_FEATURES);
        let mut sums = [vec![0f32; 4], vec![0f32; 4]];
        for (i, _, cells) in offsets.weighted_edges() {
            sums[0][i] += cells.iter().map(|c| c.1).sum::<f32>();
        }
        for (i, _, cells) in lengths.weighted_edges(30.0) {
            sums[1][i] += cells.iter().map(|c| c.1).sum::<f32>();
        }
        for (graph, edges) in [
            (&sums[0], offsets.edge_count()),
            (&sums[1], lengths.edge_count()),
        ] {
            assert_eq!(edges, 2 * g.edges.len());
            assert!(graph.iter().all(|s| (s - 1.0).abs() < 1e-5), "{graph:?}");
        }
    }

    /// A complete network graph joins every pair of nodes both ways, each
    /// edge carrying the pair's distance, whatever the Delaunay graph
    /// leaves out.
    #[test]
    fn a_complete_network_graph_joins_every_pair_by_its_distance() {
        use crate::matching::testkit;
        let objects = testkit::world_objects();
        let dets = testkit::Side::of(
            testkit::POSE_A,
            &objects[..5],
            &[0, 1, 2, 3, 4],
            testkit::EXACT,
        )
        .detections;
        let positions: Vec<Vec2> = dets.iter().map(|d| d.position_m).collect();
        let g = SceneGraph::delaunay(&positions).unwrap();
        let complete =
            LengthGraph::lengths(&dets, &g, NetworkGraph::Complete, AppearanceWidth::NONE);
        assert_eq!(complete.edge_count(), 5 * 4);
        let mut seen = std::collections::BTreeSet::new();
        for e in 0..complete.edge_count() {
            let (a, b) = (complete.src[e], complete.dst[e]);
            assert_ne!(a, b);
            assert!(seen.insert((a, b)), "edge {a}->{b} twice");
            let d = f64::from((positions[a] - positions[b]).norm() as f32);
            assert_eq!(complete.edge_m[e], [d]);
        }
        let delaunay =
            LengthGraph::lengths(&dets, &g, NetworkGraph::Delaunay, AppearanceWidth::NONE);
        assert!(delaunay.edge_count() < complete.edge_count());
        for (i, _, cells) in complete.weighted_edges(30.0) {
            assert!(i < 5 && cells.iter().all(|c| c.1 >= 0.0));
        }
    }
}
