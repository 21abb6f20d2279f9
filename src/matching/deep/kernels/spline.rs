//! A spline convolution's neighbourhood in plain Rust, for either network
//! and either pseudo-coordinate: each node's incoming edges, in edge
//! order, with the `B` kernel cells an edge's pseudo-coordinate gives a
//! non-zero degree-1 B-spline weight (2 over an edge length, 4 over a 2-D
//! offset) and those weights over the node's degree (mean aggregation),
//! as the tensor path's mixing matrix holds them.

/// An edge into a node: its source and its `B` (kernel cell, basis weight
/// over the destination's degree).
pub(crate) type Cells<const B: usize> = [(usize, f32); B];

/// The edges of a graph (or of graphs stacked row after row) grouped by
/// destination, each group in edge order.
pub(crate) struct Incoming<const B: usize> {
    /// Nodes (rows).
    pub(crate) n: usize,
    /// Node `i`'s edges are `from[start[i]..start[i + 1]]`.
    start: Vec<usize>,
    from: Vec<(usize, Cells<B>)>,
}

impl<const B: usize> Incoming<B> {
    /// `n` nodes and their directed `edges` `(destination, source,
    /// cells)`, in edge order.
    pub(crate) fn new(n: usize, edges: &[(usize, usize, Cells<B>)]) -> Self {
        let mut start = vec![0; n + 1];
        for &(i, _, _) in edges {
            start[i + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut next = start.clone();
        let mut from = vec![(0, [(0, 0.0); B]); edges.len()];
        for &(i, j, cells) in edges {
            from[next[i]] = (j, cells);
            next[i] += 1;
        }
        Self { n, start, from }
    }

    /// Node `i`'s incoming edges, in edge order.
    #[inline(always)]
    pub(crate) fn into(&self, i: usize) -> &[(usize, Cells<B>)] {
        &self.from[self.start[i]..self.start[i + 1]]
    }

    /// The neighbourhood sums of rows `y` (`[n, width]`: per row, the
    /// root's `d` products then each kernel cell's) into `m` (`[n, d]`):
    /// `m_i = sum over edges j -> i, in order, of sum_cells w y_j,cell`,
    /// from 0.
    pub(crate) fn messages(&self, y: &[f32], (width, d): (usize, usize), m: &mut [f32]) {
        m.fill(0.0);
        for i in 0..self.n {
            let out = &mut m[i * d..(i + 1) * d];
            for &(j, cells) in self.into(i) {
                for (cell, w) in cells {
                    let at = j * width + (1 + cell) * d;
                    for (a, v) in out.iter_mut().zip(&y[at..at + d]) {
                        *a += w * v;
                    }
                }
            }
        }
    }
}
