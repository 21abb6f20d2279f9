//! The paper's inputs to the published networks, as plain `f32` arrays (no
//! tensors here): each vehicle's detections in its own body frame, their
//! appearance attributes (the paper's A) and the Delaunay graph over their
//! positions with each edge's length `E_ij = ||v_i - v_j||` (Section 3.1).
//!
//! Node attributes are [`features::node_features`]: class one-hot (7),
//! colour (3) and size (3): appearance only; nothing in them depends on
//! where the vehicle is, where it faces, or where the object lies. What
//! `features.rs` also builds for the project's own network (edge vectors
//! turned into world-aligned axes with the reported heading, the pair
//! likelihood through the GPS relative pose, offset votes, range and
//! bearing from either vehicle) is left out: the published networks see no
//! pose and no heading. Positions enter only through edge lengths, which a
//! rigid motion of the body frame (two vehicles' frames differ by an
//! unknown one) leaves unchanged.
//!
//! The B-spline kernel therefore runs over 1-D pseudo-coordinates, the
//! edge length: degree-1 open B-splines with [`KERNEL`] knots evenly from
//! 0 to a scale (SplineCNN's `kernel_size = 5`; PyG's `Distance` transform
//! divides by the largest edge of each graph instead, which would change
//! with every detection added or dropped, so the scale is fixed here and
//! longer edges are clipped onto the last knot).

use crate::graph::SceneGraph;
use crate::matching::deep::features::{KERNEL, NODE_FEATURES, node_attributes};
use crate::sensor::{AppearanceWidth, Detection};

/// One vehicle's graph on the paper's inputs. Every undirected edge appears
/// twice, once per direction; message `e` goes from `src[e]` to `dst[e]`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PaperGraph {
    pub(crate) n: usize,
    /// `n x node_width`, row-major: appearance only.
    pub(crate) node_features: Vec<f32>,
    /// Attributes per node (`NODE_FEATURES` and the appearance vector's
    /// width, if psi_1 reads one).
    pub(crate) node_width: usize,
    pub(crate) src: Vec<usize>,
    pub(crate) dst: Vec<usize>,
    /// `E`: each directed edge's length in metres (the paper's `E_ij`).
    pub(crate) length_m: Vec<f32>,
}

impl PaperGraph {
    /// The graph of `detections` (body frame) on their scene graph
    /// (Delaunay over the same positions, [`SceneGraph::delaunay`]), for
    /// a psi_1 that reads appearance vectors `appearance_width` wide (0:
    /// none).
    pub(crate) fn new(
        detections: &[Detection],
        graph: &SceneGraph,
        appearance_width: AppearanceWidth,
    ) -> Self {
        debug_assert_eq!(detections.len(), graph.node_count());
        let features = node_attributes(detections, appearance_width);
        Self::with_features(features, NODE_FEATURES + appearance_width.get(), graph)
    }

    /// The Delaunay graph of `detections` (body frame).
    #[cfg(test)]
    pub(crate) fn delaunay(detections: &[Detection]) -> Result<Self, crate::graph::GraphError> {
        let positions: Vec<crate::geometry::Vec2> =
            detections.iter().map(|d| d.position_m).collect();
        let none = AppearanceWidth::NONE;
        Ok(Self::new(
            detections,
            &SceneGraph::delaunay(&positions)?,
            none,
        ))
    }

    /// Node attributes `features` (`n x node_width`) on `graph`.
    pub(crate) fn with_features(features: Vec<f32>, node_width: usize, graph: &SceneGraph) -> Self {
        let n = graph.node_count();
        assert_eq!(features.len(), n * node_width, "node attributes");
        let (mut src, mut dst, mut length_m) = (Vec::new(), Vec::new(), Vec::new());
        for e in &graph.edges {
            for (from, to) in [(e.a, e.b), (e.b, e.a)] {
                src.push(from);
                dst.push(to);
                length_m.push(e.length_m as f32);
            }
        }
        Self {
            n,
            node_features: features,
            node_width,
            src,
            dst,
            length_m,
        }
    }

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
        fn length_basis_is_a_partition_of_unity(d in -5.0..200.0f64, scale in 10.0..100.0f64) {
            let b = length_basis(d, scale);
            prop_assert!((b[0].1 + b[1].1 - 1.0).abs() < 1e-12);
            prop_assert!(b.iter().all(|&(k, w)| k < KERNEL && (0.0..=1.0).contains(&w)));
            prop_assert_eq!(b[1].0, b[0].0 + 1);
        }
    }

    #[test]
    fn knots_are_hit_exactly_and_longer_edges_clipped() {
        let scale = 60.0;
        for k in 0..KERNEL {
            let b = length_basis(scale * k as f64 / (KERNEL - 1) as f64, scale);
            let w: f64 = b.iter().filter(|&&(i, _)| i == k).map(|&(_, w)| w).sum();
            assert!((w - 1.0).abs() < 1e-12, "knot {k}: {b:?}");
        }
        assert_eq!(length_basis(7.5, 60.0), [(0, 0.5), (1, 0.5)]);
        assert_eq!(length_basis(500.0, 60.0), length_basis(60.0, 60.0));
    }
}
