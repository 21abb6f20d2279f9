//! Scene graphs: Delaunay triangulation (spade) over one vehicle's detection
//! positions, edges weighted by length (paper Section 3.1, Eq. 1 text).
//!
//! 0, 1, 2 and 3 nodes, collinear points and repeated positions are normal
//! cases: fewer than three non-collinear points give a path (or nothing), and
//! a repeated position is tied to its twin by a zero-length edge.

use spade::{DelaunayTriangulation, Point2, Triangulation};

use crate::geometry::Vec2;

/// An undirected edge between two nodes with its length in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Edge {
    pub a: usize,
    pub b: usize,
    pub length_m: f64,
}

/// Nodes are detections (in the order given), positions in the ego frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneGraph {
    pub positions_m: Vec<Vec2>,
    /// Each undirected edge once, `a < b`, sorted.
    pub edges: Vec<Edge>,
}

/// A position spade cannot triangulate (not finite, or too large).
#[derive(Debug, thiserror::Error)]
#[error("cannot triangulate node {index} at ({x}, {y}): {reason}")]
pub struct GraphError {
    pub index: usize,
    pub x: f64,
    pub y: f64,
    pub reason: String,
}

impl SceneGraph {
    pub fn delaunay(positions_m: &[Vec2]) -> Result<SceneGraph, GraphError> {
        let mut tri: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::new();
        // spade index of each vertex -> the first node placed there.
        let mut owner: Vec<usize> = Vec::new();
        let mut edges = Vec::new();
        for (i, p) in positions_m.iter().enumerate() {
            let handle = tri.insert(Point2::new(p.x, p.y)).map_err(|e| GraphError {
                index: i,
                x: p.x,
                y: p.y,
                reason: format!("{e:?}"),
            })?;
            let v = handle.index();
            if v < owner.len() {
                // Same position as an earlier node: tie the two together.
                edges.push(Edge {
                    a: owner[v],
                    b: i,
                    length_m: 0.0,
                });
            } else {
                owner.push(i);
            }
        }
        for e in tri.undirected_edges() {
            let [va, vb] = e.vertices();
            let (a, b) = (owner[va.fix().index()], owner[vb.fix().index()]);
            let (a, b) = if a < b { (a, b) } else { (b, a) };
            edges.push(Edge {
                a,
                b,
                length_m: (positions_m[a] - positions_m[b]).norm(),
            });
        }
        edges.sort_by_key(|e| (e.a, e.b));
        Ok(SceneGraph {
            positions_m: positions_m.to_vec(),
            edges,
        })
    }

    pub fn node_count(&self) -> usize {
        self.positions_m.len()
    }

    /// The same graph with its nodes listed in `order` (new node k is old
    /// node `order[k]`; `order` is a permutation of the nodes).
    pub fn permuted(&self, order: &[usize]) -> SceneGraph {
        debug_assert_eq!(order.len(), self.node_count());
        let mut new_index = vec![0; order.len()];
        for (k, &old) in order.iter().enumerate() {
            new_index[old] = k;
        }
        let mut edges: Vec<Edge> = self
            .edges
            .iter()
            .map(|e| {
                let (a, b) = (new_index[e.a], new_index[e.b]);
                Edge {
                    a: a.min(b),
                    b: a.max(b),
                    length_m: e.length_m,
                }
            })
            .collect();
        edges.sort_by_key(|e| (e.a, e.b));
        SceneGraph {
            positions_m: order.iter().map(|&k| self.positions_m[k]).collect(),
            edges,
        }
    }

    /// Neighbour lists, one per node.
    pub fn neighbours(&self) -> Vec<Vec<usize>> {
        let mut n = vec![Vec::new(); self.node_count()];
        for e in &self.edges {
            n[e.a].push(e.b);
            n[e.b].push(e.a);
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn pts(v: &[(f64, f64)]) -> Vec<Vec2> {
        v.iter().map(|&(x, y)| Vec2::new(x, y)).collect()
    }

    fn pairs(g: &SceneGraph) -> Vec<(usize, usize)> {
        g.edges.iter().map(|e| (e.a, e.b)).collect()
    }

    #[test]
    fn small_graphs() {
        assert!(SceneGraph::delaunay(&[]).unwrap().edges.is_empty());
        assert!(
            SceneGraph::delaunay(&pts(&[(1.0, 2.0)]))
                .unwrap()
                .edges
                .is_empty()
        );
        let two = SceneGraph::delaunay(&pts(&[(0.0, 0.0), (3.0, 4.0)])).unwrap();
        assert_eq!(pairs(&two), vec![(0, 1)]);
        assert!((two.edges[0].length_m - 5.0).abs() < 1e-12);
        let three = SceneGraph::delaunay(&pts(&[(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)])).unwrap();
        assert_eq!(pairs(&three), vec![(0, 1), (0, 2), (1, 2)]);
    }

    #[test]
    fn collinear_points_form_a_path() {
        let g =
            SceneGraph::delaunay(&pts(&[(0.0, 0.0), (2.0, 0.0), (1.0, 0.0), (3.0, 0.0)])).unwrap();
        assert_eq!(pairs(&g), vec![(0, 2), (1, 2), (1, 3)]);
    }

    #[test]
    fn repeated_positions_are_tied_with_zero_length() {
        let g = SceneGraph::delaunay(&pts(&[(0.0, 0.0), (5.0, 0.0), (0.0, 0.0)])).unwrap();
        assert_eq!(pairs(&g), vec![(0, 1), (0, 2)]);
        assert_eq!(g.edges[1].length_m, 0.0);
    }

    #[test]
    fn a_permuted_graph_is_the_same_graph_relabelled() {
        let p = pts(&[
            (0.0, 0.0),
            (10.0, 1.0),
            (4.0, 9.0),
            (-3.0, 6.0),
            (8.0, -7.0),
        ]);
        let g = SceneGraph::delaunay(&p).unwrap();
        let order = [3, 0, 4, 1, 2];
        let moved: Vec<Vec2> = order.iter().map(|&k| p[k]).collect();
        assert_eq!(g.permuted(&order), SceneGraph::delaunay(&moved).unwrap());
        assert_eq!(g.permuted(&[0, 1, 2, 3, 4]), g);
    }

    #[test]
    fn non_finite_positions_are_errors() {
        assert!(SceneGraph::delaunay(&pts(&[(0.0, 0.0), (f64::NAN, 1.0)])).is_err());
    }

    proptest! {
        /// Delaunay of n >= 3 points in general position is planar and
        /// connected: n - 1 <= |E| <= 3n - 6, and every node has a neighbour.
        #[test]
        fn edge_count_is_planar_and_connected(raw in proptest::collection::vec((-50.0..50.0f64, -50.0..50.0f64), 3..30)) {
            let g = SceneGraph::delaunay(&pts(&raw)).unwrap();
            let n = raw.len();
            prop_assert!(g.edges.len() >= n - 1);
            prop_assert!(g.edges.len() <= 3 * n - 3);
            prop_assert!(g.neighbours().iter().all(|nb| !nb.is_empty()));
            for e in &g.edges {
                prop_assert!(e.a < e.b);
                prop_assert!((e.length_m - (g.positions_m[e.a] - g.positions_m[e.b]).norm()).abs() < 1e-12);
            }
        }
    }
}
