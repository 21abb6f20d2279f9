//! Cycle-consistent association across N vehicles (permutation
//! synchronisation). Pairwise matching of three vehicles can contradict
//! itself (a~b, b~c, a not~ c, or a chain that joins two detections of one
//! vehicle); [`synchronize`] turns the pairwise correspondences of any
//! method into one assignment of every detection to an object, at most one
//! detection per vehicle per object, unmatched allowed. Two detections are
//! then matched exactly when they belong to the same object, so the result
//! is consistent by construction.
//!
//! How: the correspondences are edges of a graph over all detections of the
//! frame, weighted by their probability. Taken in order of decreasing
//! probability, each edge joins the objects of its two detections unless
//! the joined object would hold two detections of one vehicle (Kruskal's
//! algorithm with a cannot-link per vehicle: a greedy rounding of
//! permutation synchronisation). A contradiction is thus resolved against
//! its least probable link. We first tried CLEAR-style spectral clustering
//! (Fathian et al., 2020: the number of objects at the largest eigengap of
//! the normalised Laplacian, pivots, an assignment per vehicle): on the
//! hand-made cases below it split chains of partial views (a~b, a~c, no
//! b~c) into single detections, because the eigengap of a path does not
//! count it as one object. Pure computation, deterministic.

use std::collections::{BTreeMap, BTreeSet};

use super::{Correspondence, binary_entropy_bits};

/// The pairwise result of one vehicle pair of the frame.
#[derive(Clone, Debug, PartialEq)]
pub struct PairwiseMatches {
    /// Vehicle indices (into the frame's detection counts), `first < second`.
    pub first: usize,
    pub second: usize,
    /// Detection `a` of `first` is detection `b` of `second`.
    pub matches: Vec<Correspondence>,
}

/// A detection of the frame: (vehicle index, detection index).
pub type Node = (usize, usize);

/// One object per detection: the consistent assignment.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Association {
    /// `object[v][d]`: the object of detection `d` of vehicle `v`; objects
    /// are numbered 0.. in order of their first detection.
    pub object: Vec<Vec<usize>>,
}

impl Association {
    /// Each detection an object of its own.
    pub fn singletons(n_detections: &[usize]) -> Self {
        let mut next = 0;
        let object = n_detections
            .iter()
            .map(|&n| {
                let ids: Vec<usize> = (next..next + n).collect();
                next += n;
                ids
            })
            .collect();
        Self { object }
    }

    /// The transitive closure of pairwise matches (connected components):
    /// how pairwise matching groups detections when taken at its word. It
    /// may put two detections of one vehicle into one object.
    pub fn closure(n_detections: &[usize], pairs: &[PairwiseMatches]) -> Self {
        let index = NodeIndex::new(n_detections);
        let mut uf = UnionFind::new(index.len());
        for p in pairs {
            for c in &p.matches {
                uf.union(index.of((p.first, c.a)), index.of((p.second, c.b)));
            }
        }
        let roots: Vec<usize> = (0..index.len()).map(|i| uf.find(i)).collect();
        Self::from_labels(n_detections, &index, &roots)
    }

    /// Objects numbered in order of first appearance of each label.
    fn from_labels(n_detections: &[usize], index: &NodeIndex, labels: &[usize]) -> Self {
        let mut renumber: BTreeMap<usize, usize> = BTreeMap::new();
        let object = n_detections
            .iter()
            .enumerate()
            .map(|(v, &n)| {
                (0..n)
                    .map(|d| {
                        let next = renumber.len();
                        *renumber.entry(labels[index.of((v, d))]).or_insert(next)
                    })
                    .collect()
            })
            .collect();
        Self { object }
    }

    /// Whether two detections belong to the same object.
    pub fn same(&self, x: Node, y: Node) -> bool {
        self.object[x.0][x.1] == self.object[y.0][y.1]
    }

    /// Whether every object has at most one detection per vehicle.
    pub fn is_consistent(&self) -> bool {
        self.object.iter().all(|ids| {
            let set: BTreeSet<usize> = ids.iter().copied().collect();
            set.len() == ids.len()
        })
    }

    /// The correspondences between vehicles `first` and `second` this
    /// association implies, sorted by `a`. A pair the method matched keeps
    /// its probability; a pair joined only through other vehicles gets the
    /// probability of the most probable chain of matched pairs that links
    /// them inside the object (0.5, a coin flip, if none does).
    pub fn matches_between(
        &self,
        first: usize,
        second: usize,
        pairs: &[PairwiseMatches],
    ) -> Vec<Correspondence> {
        self.between(first, second, &ChainProbabilities::new(self, pairs))
    }

    /// [`Self::matches_between`] for every vehicle pair of `pairs`, in
    /// order: what the association says each pair matched.
    pub fn implied(&self, pairs: &[PairwiseMatches]) -> Vec<PairwiseMatches> {
        let wanted: Vec<(usize, usize)> = pairs.iter().map(|p| (p.first, p.second)).collect();
        self.implied_for(&wanted, pairs)
    }

    /// [`Self::matches_between`] for every vehicle pair of `wanted`
    /// (`first < second`), in order, with the probabilities of the chains
    /// of `pairs`.
    pub fn implied_for(
        &self,
        wanted: &[(usize, usize)],
        pairs: &[PairwiseMatches],
    ) -> Vec<PairwiseMatches> {
        let chains = ChainProbabilities::new(self, pairs);
        wanted
            .iter()
            .map(|&(first, second)| PairwiseMatches {
                first,
                second,
                matches: self.between(first, second, &chains),
            })
            .collect()
    }

    fn between(
        &self,
        first: usize,
        second: usize,
        chains: &ChainProbabilities,
    ) -> Vec<Correspondence> {
        let mut out = Vec::new();
        for (a, &oa) in self.object[first].iter().enumerate() {
            let Some(b) = self.object[second].iter().position(|&ob| ob == oa) else {
                continue;
            };
            let probability = chains.best((first, a), (second, b));
            out.push(Correspondence {
                a,
                b,
                probability,
                uncertainty: if probability < 0.5 {
                    1.0
                } else {
                    binary_entropy_bits(probability)
                },
            });
        }
        out
    }
}

/// Consistent objects from the pairwise correspondences of one frame
/// (`n_detections[v]`: the detection count of vehicle v). Pairs not
/// listed in `pairs` were not matched.
pub fn synchronize(n_detections: &[usize], pairs: &[PairwiseMatches]) -> Association {
    let index = NodeIndex::new(n_detections);
    let mut edges: Vec<(f64, usize, usize)> = pairs
        .iter()
        .flat_map(|p| {
            let index = &index;
            p.matches.iter().map(move |c| {
                let (i, j) = (index.of((p.first, c.a)), index.of((p.second, c.b)));
                (c.probability, i.min(j), i.max(j))
            })
        })
        .collect();
    // Most probable first; ties in node order, so the result is unique.
    edges.sort_by(|x, y| y.0.total_cmp(&x.0).then((x.1, x.2).cmp(&(y.1, y.2))));
    let mut uf = UnionFind::new(index.len());
    let mut vehicles: Vec<BTreeSet<usize>> = index.nodes.iter().map(|n| [n.0].into()).collect();
    for (_, i, j) in edges {
        let (ri, rj) = (uf.find(i), uf.find(j));
        if ri == rj || !vehicles[ri].is_disjoint(&vehicles[rj]) {
            continue;
        }
        uf.union(ri, rj);
        let (root, other) = (ri.min(rj), ri.max(rj));
        let moved = std::mem::take(&mut vehicles[other]);
        vehicles[root].extend(moved);
    }
    let roots: Vec<usize> = (0..index.len()).map(|i| uf.find(i)).collect();
    Association::from_labels(n_detections, &index, &roots)
}

/// Detections numbered 0.. over all vehicles, vehicle by vehicle.
struct NodeIndex {
    offset: Vec<usize>,
    nodes: Vec<Node>,
}

impl NodeIndex {
    fn new(n_detections: &[usize]) -> Self {
        let mut offset = Vec::with_capacity(n_detections.len());
        let mut nodes = Vec::new();
        for (v, &n) in n_detections.iter().enumerate() {
            offset.push(nodes.len());
            nodes.extend((0..n).map(|d| (v, d)));
        }
        Self { offset, nodes }
    }
    fn of(&self, node: Node) -> usize {
        self.offset[node.0] + node.1
    }
    fn len(&self) -> usize {
        self.nodes.len()
    }
}

/// The most probable chain of matched pairs between two detections of one
/// object (products of probabilities, inside the object).
struct ChainProbabilities {
    best: BTreeMap<(Node, Node), f64>,
}

impl ChainProbabilities {
    fn new(association: &Association, pairs: &[PairwiseMatches]) -> Self {
        let mut members: BTreeMap<usize, Vec<Node>> = BTreeMap::new();
        for (v, ids) in association.object.iter().enumerate() {
            for (d, &o) in ids.iter().enumerate() {
                members.entry(o).or_default().push((v, d));
            }
        }
        let mut direct: BTreeMap<(Node, Node), f64> = BTreeMap::new();
        for p in pairs {
            for c in &p.matches {
                let (x, y) = ((p.first, c.a), (p.second, c.b));
                if association.same(x, y) {
                    direct.insert((x.min(y), x.max(y)), c.probability);
                }
            }
        }
        let mut best = BTreeMap::new();
        for (&(x, y), &p) in &direct {
            best.insert((x, y), p);
            best.insert((y, x), p);
        }
        let mut chained = BTreeMap::new();
        for nodes in members.values().filter(|n| n.len() > 1) {
            // Floyd-Warshall on max-product over the object's few nodes.
            let n = nodes.len();
            let mut p = vec![vec![0.0f64; n]; n];
            for x in 0..n {
                for y in 0..n {
                    let key = (nodes[x].min(nodes[y]), nodes[x].max(nodes[y]));
                    p[x][y] = direct.get(&key).copied().unwrap_or(0.0);
                }
            }
            for z in 0..n {
                for x in 0..n {
                    for y in 0..n {
                        p[x][y] = p[x][y].max(p[x][z] * p[z][y]);
                    }
                }
            }
            for x in 0..n {
                for y in 0..n {
                    chained.insert((nodes[x], nodes[y]), p[x][y]);
                }
            }
        }
        for (key, p) in chained {
            best.entry(key).or_insert(p);
        }
        Self { best }
    }
    fn best(&self, x: Node, y: Node) -> f64 {
        match self.best.get(&(x, y)) {
            Some(&p) if p > 0.0 => p,
            _ => 0.5,
        }
    }
}

/// Union-find with path halving; the smaller index becomes the root.
struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
        }
    }
    fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }
    fn union(&mut self, x: usize, y: usize) {
        let (rx, ry) = (self.find(x), self.find(y));
        if rx != ry {
            self.parent[rx.max(ry)] = rx.min(ry);
        }
    }
}

/// Chains of two matched pairs across three vehicles whose three vehicle
/// pairs were all matched, and how many of them the third pair breaks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TripleCounts {
    /// (x, y, z) on three distinct vehicles with x~y and y~z (each chain
    /// once per middle detection and unordered ends).
    pub chains: usize,
    /// Of those, the ones where x and z are not matched.
    pub inconsistent: usize,
}

impl TripleCounts {
    pub fn add(&mut self, other: TripleCounts) {
        self.chains += other.chains;
        self.inconsistent += other.inconsistent;
    }
    /// inconsistent / chains; NaN without any chain.
    pub fn share(&self) -> f64 {
        if self.chains == 0 {
            f64::NAN
        } else {
            self.inconsistent as f64 / self.chains as f64
        }
    }
}

/// Counts the chains x~y~z over vehicle triples whose three pairs are all
/// in `pairs` (the frame's instances), and those with x not~ z.
pub fn triple_consistency(pairs: &[PairwiseMatches]) -> TripleCounts {
    let mut matched: BTreeSet<(Node, Node)> = BTreeSet::new();
    let mut neighbours: BTreeMap<Node, Vec<Node>> = BTreeMap::new();
    for p in pairs {
        for c in &p.matches {
            let (x, y) = ((p.first, c.a), (p.second, c.b));
            matched.insert((x.min(y), x.max(y)));
            neighbours.entry(x).or_default().push(y);
            neighbours.entry(y).or_default().push(x);
        }
    }
    let looked: BTreeSet<(usize, usize)> = pairs.iter().map(|p| (p.first, p.second)).collect();
    let looked_at = |u: usize, v: usize| looked.contains(&(u.min(v), u.max(v)));
    let mut counts = TripleCounts::default();
    for (y, ends) in &neighbours {
        for (k, x) in ends.iter().enumerate() {
            for z in &ends[k + 1..] {
                if x.0 == z.0 || x.0 == y.0 || z.0 == y.0 || !looked_at(x.0, z.0) {
                    continue;
                }
                counts.chains += 1;
                if !matched.contains(&((*x).min(*z), (*x).max(*z))) {
                    counts.inconsistent += 1;
                }
            }
        }
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(first: usize, second: usize, matches: &[(usize, usize, f64)]) -> PairwiseMatches {
        PairwiseMatches {
            first,
            second,
            matches: matches
                .iter()
                .map(|&(a, b, p)| Correspondence {
                    a,
                    b,
                    probability: p,
                    uncertainty: binary_entropy_bits(p),
                })
                .collect(),
        }
    }

    #[test]
    fn consistent_pairwise_matches_are_kept_as_they_are() {
        // Three vehicles see objects X (a0, b0, c0) and Y (a1, b1); c1 is
        // only c's.
        let n = [2, 2, 2];
        let pairs = vec![
            pair(0, 1, &[(0, 0, 0.9), (1, 1, 0.8)]),
            pair(0, 2, &[(0, 0, 0.9)]),
            pair(1, 2, &[(0, 0, 0.7)]),
        ];
        assert_eq!(triple_consistency(&pairs).inconsistent, 0);
        let s = synchronize(&n, &pairs);
        assert!(s.is_consistent());
        assert_eq!(s.object, vec![vec![0, 1], vec![0, 1], vec![0, 2]]);
        for p in &pairs {
            assert_eq!(s.matches_between(p.first, p.second, &pairs), p.matches);
        }
    }

    #[test]
    fn a_contradictory_pair_is_resolved_into_consistent_objects() {
        // Objects X = {a0, b0, c0} and Y = {a1, b1, c1}, matched right by
        // every pair except b~c, which pairs b0 with c1 (a look-alike):
        // a0~b0~c1 and a1~c1 chain a0 and a1, two detections of vehicle a,
        // into one component.
        let n = [2, 2, 2];
        let pairs = vec![
            pair(0, 1, &[(0, 0, 0.9), (1, 1, 0.9)]),
            pair(0, 2, &[(0, 0, 0.9), (1, 1, 0.9)]),
            pair(1, 2, &[(0, 1, 0.6)]),
        ];
        let t = triple_consistency(&pairs);
        assert!(t.inconsistent > 0, "{t:?}");
        let closure = Association::closure(&n, &pairs);
        assert!(!closure.is_consistent());
        let s = synchronize(&n, &pairs);
        assert!(s.is_consistent(), "{:?}", s.object);
        // The well-supported objects win over the one contradictory pair.
        assert_eq!(s.object, vec![vec![0, 1], vec![0, 1], vec![0, 1]]);
        let synced: Vec<PairwiseMatches> = [(0, 1), (0, 2), (1, 2)]
            .iter()
            .map(|&(u, v)| PairwiseMatches {
                first: u,
                second: v,
                matches: s.matches_between(u, v, &pairs),
            })
            .collect();
        assert_eq!(triple_consistency(&synced).inconsistent, 0);
        // b0~c0 was implied through a0 (0.9 * 0.9); b0~c1 is gone.
        let bc = &synced[2].matches;
        assert_eq!(bc.len(), 2);
        assert_eq!((bc[0].a, bc[0].b), (0, 0));
        assert!((bc[0].probability - 0.81).abs() < 1e-12);
        assert_eq!((bc[1].a, bc[1].b), (1, 1));
    }

    #[test]
    fn an_open_chain_closes_into_one_object() {
        // a0~b0 and b0~c0 with a~c never looked at: one object of three.
        let n = [1, 1, 1];
        let pairs = vec![pair(0, 1, &[(0, 0, 0.9)]), pair(1, 2, &[(0, 0, 0.8)])];
        let s = synchronize(&n, &pairs);
        assert_eq!(s.object, vec![vec![0], vec![0], vec![0]]);
        let ac = s.matches_between(0, 2, &pairs);
        assert!((ac[0].probability - 0.72).abs() < 1e-12);
    }

    #[test]
    fn no_matches_leave_every_detection_alone() {
        let n = [3, 0, 2];
        let s = synchronize(&n, &[]);
        assert_eq!(s, Association::singletons(&n));
        assert!(s.matches_between(0, 2, &[]).is_empty());
    }

    proptest::proptest! {
        /// Whatever the pairwise matches, the objects hold one detection
        /// per vehicle at most and the implied pairs have no broken chain.
        #[test]
        fn synchronized_matches_are_always_consistent(
            n in proptest::collection::vec(0usize..5, 3..6),
            raw in proptest::collection::vec((0usize..6, 0usize..6, 0usize..5, 0usize..5, 0.01f64..1.0), 0..40),
        ) {
            let nv = n.len();
            let mut pairs: Vec<PairwiseMatches> = Vec::new();
            for u in 0..nv {
                for v in (u + 1)..nv {
                    // One-to-one matches of this vehicle pair from `raw`.
                    let mut used_a = BTreeSet::new();
                    let mut used_b = BTreeSet::new();
                    let mut m = Vec::new();
                    for &(x, y, a, b, p) in &raw {
                        if (x % nv, y % nv) == (u, v) && a < n[u] && b < n[v]
                            && used_a.insert(a) && used_b.insert(b) {
                            m.push((a, b, p));
                        }
                    }
                    pairs.push(pair(u, v, &m));
                }
            }
            let s = synchronize(&n, &pairs);
            proptest::prop_assert!(s.is_consistent());
            let synced: Vec<PairwiseMatches> = pairs.iter().map(|p| PairwiseMatches {
                first: p.first,
                second: p.second,
                matches: s.matches_between(p.first, p.second, &pairs),
            }).collect();
            proptest::prop_assert_eq!(triple_consistency(&synced).inconsistent, 0);
        }
    }
}
