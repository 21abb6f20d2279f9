//! What the deep matcher sees of one vehicle's scene graph, as plain `f32`
//! arrays (no tensors here): node attributes (the paper's A) and, for the
//! SplineCNN layers, the degree-normalised B-spline basis of every edge's
//! pseudo-coordinates (the paper's Phi(E_ij), Eq. 1).
//!
//! Pseudo-coordinates: the edge vector i -> j rotated into world-aligned
//! axes with the vehicle's *reported* heading (GPS heading noise is 0.2 deg;
//! GPS position error does not enter). Open B-splines of degree 1 with
//! `KERNEL` knots per axis (SplineCNN, Fey et al. 2018) give 4 non-zero
//! basis weights per edge. The knots sit where edges actually are, not on
//! an even grid over one junction's extent: at 0, at +-the median and at
//! +-the 95th percentile of the edges' larger world-axis component, as
//! measured over the training family (`coid train` records the measured
//! values in each model's toml, `edge_median_m` and `edge_p95_m`); longer
//! components are clipped onto the outer knot.

use crate::fusion::PoseEstimate;
use crate::geometry::{Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::matching::MatchView;
use crate::matching::learning_free::appearance_similarity;
use crate::matching::likelihood::{LikelihoodTerms, pair_terms};
use crate::sensor::{AppearanceWidth, Detection};
use crate::traffic::ObjectClass;

/// B-spline knots per pseudo-coordinate dimension (paper: 5).
pub(crate) const KERNEL: usize = 5;
/// Kernel weights per edge: `KERNEL^2` for 2-D pseudo-coordinates.
pub(crate) const KERNEL_2D: usize = KERNEL * KERNEL;
/// Node attribute length without appearance vectors: class one-hot (7),
/// colour (3), size (3). A network that reads a dataset's appearance
/// vectors (`appearance_width` wide) has these first, then the vector.
pub(crate) const NODE_FEATURES: usize = 13;
/// The knots per axis, in metres: 0, +-median and +-95th percentile of the
/// edges' larger world-axis component over the training family (17.7 m
/// and 48.1 m measured on `sumo_nets/family/train` s000-s007 and the
/// default intersection).
pub(crate) const KNOTS_M: [f64; KERNEL] = [-48.0, -18.0, 0.0, 18.0, 48.0];
/// Longer edge components are clipped onto the outer knots.
pub(crate) const MAX_EDGE_M: f64 = KNOTS_M[KERNEL - 1];

/// One vehicle's graph, ready for the network. Every undirected edge
/// appears twice, once per direction; message `e` goes from `src[e]` to
/// `dst[e]`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct GraphInput {
    pub(crate) n: usize,
    /// `n x node_width`, row-major ([`push_node_features`]).
    pub(crate) node_features: Vec<f32>,
    /// Attributes per node: `NODE_FEATURES` plus the appearance vector's
    /// width where the network reads one.
    pub(crate) node_width: usize,
    pub(crate) src: Vec<i64>,
    pub(crate) dst: Vec<i64>,
    /// `E x 4`: the kernel indices with non-zero basis weight per edge.
    pub(crate) basis_index: Vec<i64>,
    /// `E x 4`: those basis weights (they sum to 1 per edge).
    pub(crate) basis_weight: Vec<f32>,
    /// `n x E`, row-major: `1 / deg(i)` where `dst[e] == i` (mean
    /// aggregation of incoming messages).
    pub(crate) aggregate: Vec<f32>,
    /// `E`: each edge vector in world-aligned axes (metres), before
    /// scaling; kept for the edge-length statistics of `coid train`.
    pub(crate) edge_world_m: Vec<[f32; 2]>,
}

impl GraphInput {
    /// The kernel cells some edge uses (ascending), and each cell's place
    /// among them.
    pub(crate) fn used_cells(&self) -> (Vec<usize>, [usize; KERNEL_2D]) {
        let mut used = [false; KERNEL_2D];
        for &k in &self.basis_index {
            used[k as usize] = true;
        }
        let cells: Vec<usize> = (0..KERNEL_2D).filter(|&k| used[k]).collect();
        let mut position = [0usize; KERNEL_2D];
        for (p, &k) in cells.iter().enumerate() {
            position[k] = p;
        }
        (cells, position)
    }

    pub(crate) fn edge_count(&self) -> usize {
        self.src.len()
    }
}

/// Appends `d`'s node attributes: class one-hot, colour and size, then,
/// for a network that reads appearance vectors `appearance_width` wide
/// (0: none), the detection's vector (zeros for a node without one).
/// Callers check that the data carries vectors of that width before a
/// network reads it ([`check_appearance`]).
pub(crate) fn push_node_features(
    d: &Detection,
    appearance_width: AppearanceWidth,
    out: &mut Vec<f32>,
) {
    let mut f = [0f32; NODE_FEATURES];
    let class = ObjectClass::ALL
        .iter()
        .position(|&c| c == d.appearance.class)
        .unwrap_or(0);
    f[class] = 1.0;
    for k in 0..3 {
        f[7 + k] = d.appearance.colour_rgb[k] as f32;
    }
    f[10] = (d.appearance.length_m / 10.0) as f32;
    f[11] = (d.appearance.width_m / 3.0) as f32;
    f[12] = (d.appearance.height_m / 4.0) as f32;
    out.extend_from_slice(&f);
    if let Some(appearance_width) = appearance_width.width() {
        match d.appearance.descriptor.as_ref().map(|v| &v.values[..]) {
            Some(values) => {
                assert_eq!(
                    values.len(),
                    appearance_width,
                    "appearance vectors of the network's width (checked before it runs)"
                );
                out.extend_from_slice(values);
            }
            // A node without one among described nodes (a sender's
            // self-report): zeros, as coid's exports write it.
            None => out.extend(std::iter::repeat_n(0.0, appearance_width)),
        }
    }
}

/// Node attributes of `detections`, `n x (NODE_FEATURES +
/// appearance_width)` row-major ([`push_node_features`]).
pub(crate) fn node_attributes(
    detections: &[Detection],
    appearance_width: AppearanceWidth,
) -> Vec<f32> {
    let mut out = Vec::with_capacity(detections.len() * (NODE_FEATURES + appearance_width.get()));
    for d in detections {
        push_node_features(d, appearance_width, &mut out);
    }
    out
}

/// Why a network that reads appearance vectors `network_width` wide (0:
/// none) cannot read data whose vectors are `data_width` wide (`None`:
/// the data has none a method may use); `None` when it can. A network
/// without vectors reads any data (and leaves its vectors alone).
pub fn check_appearance(network: AppearanceWidth, data: AppearanceWidth) -> Option<String> {
    match (network.get(), data.width()) {
        (0, _) => None,
        (w, Some(d)) if w == d => None,
        (w, Some(d)) => Some(format!(
            "the network reads appearance vectors {w} wide; this data's are {d} wide"
        )),
        (w, None) => Some(format!(
            "the network reads appearance vectors {w} wide; this data has none (a dataset's \
             vectors are used when they tell same and different objects apart on its \
             validation runs)"
        )),
    }
}

/// Degree-1 B-spline weights of an edge component (metres) on the knots
/// `KNOTS_M`: the two active knots and their weights (clipped at the ends).
fn linear_basis(d_m: f64) -> [(usize, f64); 2] {
    let d = d_m.clamp(KNOTS_M[0], KNOTS_M[KERNEL - 1]);
    let left = (0..KERNEL - 1)
        .rfind(|&k| KNOTS_M[k] <= d)
        .unwrap_or(0)
        .min(KERNEL - 2);
    let frac = (d - KNOTS_M[left]) / (KNOTS_M[left + 1] - KNOTS_M[left]);
    [(left, 1.0 - frac), (left + 1, frac)]
}

/// The 4 non-zero (kernel index, weight) pairs of an edge vector given in
/// world-aligned axes.
pub(crate) fn edge_basis(d_world_m: &Vec2) -> [(usize, f64); 4] {
    let bx = linear_basis(d_world_m.x);
    let by = linear_basis(d_world_m.y);
    [
        (bx[0].0 * KERNEL + by[0].0, bx[0].1 * by[0].1),
        (bx[0].0 * KERNEL + by[1].0, bx[0].1 * by[1].1),
        (bx[1].0 * KERNEL + by[0].0, bx[1].1 * by[0].1),
        (bx[1].0 * KERNEL + by[1].0, bx[1].1 * by[1].1),
    ]
}

/// `detections`' graph for the project's network, which reads appearance
/// vectors `appearance_width` wide (0: none).
pub(crate) fn graph_input(
    detections: &[Detection],
    graph: &SceneGraph,
    pose_reported: &Pose2,
    appearance_width: AppearanceWidth,
) -> GraphInput {
    let n = detections.len();
    let node_feat = node_attributes(detections, appearance_width);
    let neighbours = graph.neighbours();
    let heading = Pose2::new(Vec2::zeros(), pose_reported.heading_rad());
    let (mut src, mut dst, mut basis_index, mut basis_weight, mut edge_world_m) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (i, nb) in neighbours.iter().enumerate() {
        for &j in nb {
            let d_world = heading.to_parent(&(graph.positions_m[j] - graph.positions_m[i]));
            src.push(j as i64);
            dst.push(i as i64);
            edge_world_m.push([d_world.x as f32, d_world.y as f32]);
            for (k, w) in edge_basis(&d_world) {
                basis_index.push(k as i64);
                basis_weight.push(w as f32);
            }
        }
    }
    let e = src.len();
    let mut aggregate = vec![0f32; n * e];
    for (k, &i) in dst.iter().enumerate() {
        let i = i as usize;
        aggregate[i * e + k] = 1.0 / neighbours[i].len() as f32;
    }
    GraphInput {
        n,
        node_features: node_feat,
        node_width: NODE_FEATURES + appearance_width.get(),
        src,
        dst,
        basis_index,
        basis_weight,
        aggregate,
        edge_world_m,
    }
}

/// Pair features per (i, j): see [`pair_input`].
pub(crate) const PAIR_FEATURES: usize = 12;
/// Per-node features of the learned "no match" score: see [`pair_input`].
pub(crate) const DUST_FEATURES: usize = 13;
/// Ranges are given in units of this (the default camera range).
const RANGE_SCALE_M: f64 = 70.0;

/// What the pair part of the network sees of one pair of vehicles, beside
/// the two graphs.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PairInput {
    pub(crate) n1: usize,
    pub(crate) n2: usize,
    /// `n1 x n2` row-major: the shared pair log-likelihood
    /// ([`crate::matching::likelihood`]) where the pair passes its gates.
    pub(crate) log_likelihood: Vec<Option<f64>>,
    /// `n1 x n2 x PAIR_FEATURES`: squared Mahalanobis distance over the
    /// gate (0 without positions), log appearance similarity, same class,
    /// confusable class, absolute colour difference per channel, chroma
    /// difference (colour over its brightness, which lighting scales),
    /// relative length, width and height differences, and the pair's
    /// offset vote ([`offset_votes`]).
    pub(crate) pair_features: Vec<f32>,
    /// `n x DUST_FEATURES` per vehicle: the node's range and bearing (cos,
    /// sin) from its own vehicle; its range and bearing from the other
    /// vehicle, through the relative pose (zeros without positions); its
    /// class, one-hot. What tells whether the other vehicle can see it.
    pub(crate) dust_features: [Vec<f32>; 2],
}

/// The pair input of two views, with `relative` the second vehicle's pose
/// in the first one's frame and `terms` the likelihood's terms and gates.
pub(crate) fn pair_input(
    first: &MatchView,
    second: &MatchView,
    relative: &PoseEstimate,
    terms: &LikelihoodTerms,
) -> PairInput {
    let (n1, n2) = (first.detections.len(), second.detections.len());
    let pairs = pair_terms(first, second, relative, terms);
    let similarity: Vec<f64> = first
        .detections
        .iter()
        .flat_map(|a| {
            second
                .detections
                .iter()
                .map(|b| appearance_similarity(&a.appearance, &b.appearance))
        })
        .collect();
    let votes = offset_votes(first, second, relative, terms, &similarity);
    let mut pair_features = Vec::with_capacity(n1 * n2 * PAIR_FEATURES);
    for (i, a) in first.detections.iter().enumerate() {
        for (j, b) in second.detections.iter().enumerate() {
            let k = i * n2 + j;
            let d2 = pairs[k].map_or(terms.gate_chi2, |t| t.d2);
            let d2 = if terms.position { d2 } else { 0.0 };
            let s = similarity[k].max(1e-6);
            pair_features.extend(appearance_pair(a, b, d2 / terms.gate_chi2, s.ln() / 5.0));
            pair_features.push(votes[k].ln_1p() as f32);
        }
    }
    let inverse = relative.pose.inverse();
    let dust = |view: &MatchView, other: &Pose2| -> Vec<f32> {
        let mut v = Vec::with_capacity(view.detections.len() * DUST_FEATURES);
        for d in view.detections {
            let across = if terms.position {
                other.to_parent(&d.position_m)
            } else {
                Vec2::zeros()
            };
            v.extend(range_bearing(&d.position_m));
            v.extend(range_bearing(&across));
            v.extend(class_one_hot(d));
        }
        v
    };
    PairInput {
        n1,
        n2,
        log_likelihood: pairs
            .iter()
            .map(|p| p.map(|p| p.log_likelihood()))
            .collect(),
        pair_features,
        // A node of the first vehicle in the second one's frame, and back.
        dust_features: [dust(first, &inverse), dust(second, &relative.pose)],
    }
}

/// How much the other candidate pairs agree with each pair's offset (a
/// Hough vote), `n1 x n2`. A pair's offset is the first vehicle's
/// detection minus the second's, moved into the first vehicle's frame by
/// the relative pose: its heading always (GPS gives it to 0.2 deg), its
/// position only when the likelihood has the position term. The true
/// pairs share one offset (the vehicles' relative position, unknown
/// without positions; with them, the error common to the relative pose),
/// so each pair's vote is `sum w_kb exp(-|o_ij - o_kb|^2 / 2 (v_ij +
/// v_kb))` over the other candidates (k != i, b != j) that pass the
/// appearance gate, `w` their appearance similarity and `v` the mean
/// per-axis variance of their two detections. A shared error cancels in
/// the differences, which is what no pair's likelihood alone can use.
pub(crate) fn offset_votes(
    first: &MatchView,
    second: &MatchView,
    relative: &PoseEstimate,
    terms: &LikelihoodTerms,
    similarity: &[f64],
) -> Vec<f64> {
    let (n1, n2) = (first.detections.len(), second.detections.len());
    let pose = if terms.position {
        relative.pose
    } else {
        Pose2::new(Vec2::zeros(), relative.pose.heading_rad())
    };
    let moved: Vec<(Vec2, f64)> = second
        .detections
        .iter()
        .map(|d| {
            let cov = pose.cov_to_parent(&d.cov_m2);
            (pose.to_parent(&d.position_m), cov.trace() / 2.0)
        })
        .collect();
    // Candidates as (i, j, offset, variance, weight), by offset x.
    let mut c: Vec<(usize, usize, Vec2, f64, f64)> = Vec::new();
    for (i, a) in first.detections.iter().enumerate() {
        for (j, (p, v)) in moved.iter().enumerate() {
            let w = similarity[i * n2 + j];
            if w >= terms.min_appearance {
                c.push((i, j, a.position_m - p, a.cov_m2.trace() / 2.0 + v, w));
            }
        }
    }
    c.sort_by(|x, y| x.2.x.total_cmp(&y.2.x));
    let widest = c.iter().map(|x| x.3).fold(0.0, f64::max);
    let mut votes = vec![0.0; n1 * n2];
    for (u, &(i, j, o, v, _)) in c.iter().enumerate() {
        // Candidates further apart in x than 5 sigma add nothing.
        let reach = 5.0 * (v + widest).sqrt();
        let mut sum = 0.0;
        let mut add = |&(k, b, q, w_var, w): &(usize, usize, Vec2, f64, f64)| {
            if k != i && b != j {
                sum += w * (-(o - q).norm_squared() / (2.0 * (v + w_var))).exp();
            }
        };
        c[u + 1..]
            .iter()
            .take_while(|x| x.2.x - o.x <= reach)
            .for_each(&mut add);
        c[..u]
            .iter()
            .rev()
            .take_while(|x| o.x - x.2.x <= reach)
            .for_each(&mut add);
        votes[i * n2 + j] = sum;
    }
    votes
}

/// The appearance part of one pair's features, after the two given ones.
fn appearance_pair(a: &Detection, b: &Detection, d2_over_gate: f64, log_s: f64) -> [f32; 11] {
    let (x, y) = (&a.appearance, &b.appearance);
    let colour = |k: usize| (x.colour_rgb[k] - y.colour_rgb[k]).abs();
    let chroma = |c: &[f64; 3]| {
        let mean = (c[0] + c[1] + c[2]) / 3.0;
        c.map(|v| v / mean.max(0.05))
    };
    let (cx, cy) = (chroma(&x.colour_rgb), chroma(&y.colour_rgb));
    let chroma_diff = (0..3).map(|k| (cx[k] - cy[k]).powi(2)).sum::<f64>().sqrt();
    let rel = |p: f64, q: f64| (p - q).abs() / (0.5 * (p + q)).max(0.1);
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    [
        d2_over_gate,
        log_s,
        flag(x.class == y.class),
        flag(x.class.confusable() == y.class || y.class.confusable() == x.class),
        colour(0),
        colour(1),
        colour(2),
        chroma_diff.min(3.0),
        rel(x.length_m, y.length_m),
        rel(x.width_m, y.width_m),
        rel(x.height_m, y.height_m),
    ]
    .map(|v| v as f32)
}

/// Range (in units of the default camera range) and bearing (cos, sin)
/// of a point in a body frame; the bearing of the origin is (1, 0).
fn range_bearing(p: &Vec2) -> [f32; 3] {
    let r = p.norm();
    let (c, s) = if r > 1e-9 {
        (p.x / r, p.y / r)
    } else {
        (1.0, 0.0)
    };
    [(r / RANGE_SCALE_M) as f32, c as f32, s as f32]
}

fn class_one_hot(d: &Detection) -> [f32; 7] {
    let mut f = [0f32; 7];
    if let Some(k) = ObjectClass::ALL
        .iter()
        .position(|&c| c == d.appearance.class)
    {
        f[k] = 1.0;
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn basis_is_a_partition_of_unity(x in -100.0..100.0f64, y in -100.0..100.0f64) {
            let b = edge_basis(&Vec2::new(x, y));
            let sum: f64 = b.iter().map(|&(_, w)| w).sum();
            prop_assert!((sum - 1.0).abs() < 1e-12);
            prop_assert!(b.iter().all(|&(k, w)| k < KERNEL_2D && (0.0..=1.0).contains(&w)));
        }
    }

    #[test]
    fn knots_are_hit_exactly_and_interpolated_between() {
        for (k, &t) in KNOTS_M.iter().enumerate() {
            let b = linear_basis(t);
            let w: f64 = b.iter().filter(|&&(i, _)| i == k).map(|&(_, w)| w).sum();
            assert!((w - 1.0).abs() < 1e-12, "knot {k}");
        }
        // Halfway between the centre and the median knot.
        let b = linear_basis(KNOTS_M[3] / 2.0);
        assert_eq!(b, [(2, 0.5), (3, 0.5)]);
        // Clipped beyond the outer knots.
        assert_eq!(linear_basis(500.0), linear_basis(KNOTS_M[KERNEL - 1]));
        assert_eq!(linear_basis(-500.0), linear_basis(KNOTS_M[0]));
    }

    #[test]
    fn zero_edge_sits_on_the_centre_knot() {
        let b = edge_basis(&Vec2::zeros());
        let centre = (KERNEL / 2) * KERNEL + KERNEL / 2;
        let w: f64 = b
            .iter()
            .filter(|&&(k, _)| k == centre)
            .map(|&(_, w)| w)
            .sum();
        assert!((w - 1.0).abs() < 1e-12);
    }

    /// True pairs share one offset, so they vote for each other: with the
    /// GPS 2 m off (positions) and without positions at all (only the
    /// heading), every true pair gets more votes than any wrong pair of its
    /// row, among look-alikes.
    #[test]
    fn true_pairs_get_the_offset_votes() {
        use crate::matching::gps_relative_pose;
        use crate::matching::likelihood::LikelihoodTerms;
        use crate::matching::testkit::{self, GPS, Side};
        let world = testkit::world_objects();
        let all: Vec<usize> = (0..world.len()).collect();
        let a = Side::of(testkit::POSE_A, &world, &all, GPS);
        let mut b = Side::of(testkit::POSE_B, &world, &[5, 2, 7, 0, 3, 6, 1, 4], GPS);
        b.pose = Pose2::new(
            b.pose.position_m() + Vec2::new(2.0, -0.5),
            b.pose.heading_rad(),
        );
        let (va, vb) = (a.view(), b.view());
        let similarity: Vec<f64> = a
            .detections
            .iter()
            .flat_map(|x| {
                b.detections.iter().map(|y| {
                    crate::matching::learning_free::appearance_similarity(
                        &x.appearance,
                        &y.appearance,
                    )
                })
            })
            .collect();
        let n2 = b.detections.len();
        for position in [true, false] {
            let terms = LikelihoodTerms {
                position,
                ..LikelihoodTerms::full(9.21)
            };
            let votes = offset_votes(&va, &vb, &gps_relative_pose(&va, &vb), &terms, &similarity);
            for (i, object) in a.objects.iter().enumerate() {
                let j = b.objects.iter().position(|o| o == object).unwrap();
                let truth = votes[i * n2 + j];
                let best_wrong = (0..n2)
                    .filter(|&k| k != j)
                    .map(|k| votes[i * n2 + k])
                    .fold(0.0, f64::max);
                assert!(
                    truth > best_wrong,
                    "position {position}, row {i}: {truth} vs {best_wrong}"
                );
            }
        }
    }

    #[test]
    fn every_node_averages_its_incoming_messages() {
        let pts = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(10.0, 0.0),
            Vec2::new(3.0, 8.0),
        ];
        let g = SceneGraph::delaunay(&pts).unwrap();
        use crate::matching::testkit;
        let objects = testkit::world_objects();
        let dets = testkit::Side::of(testkit::POSE_A, &objects[..3], &[0, 1, 2], testkit::EXACT)
            .detections;
        let input = graph_input(
            &dets,
            &g,
            &Pose2::new(Vec2::new(5.0, 5.0), 0.7),
            crate::sensor::AppearanceWidth::NONE,
        );
        let e = input.edge_count();
        assert_eq!(e, 2 * g.edges.len());
        for i in 0..3 {
            let row = &input.aggregate[i * e..(i + 1) * e];
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        for w in input.basis_weight.chunks(4) {
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
        assert_eq!(input.node_features.len(), 3 * NODE_FEATURES);
    }

    /// A network that reads appearance vectors gets each node's vector
    /// after class, colour and size; one that does not reads none of it.
    #[test]
    fn node_attributes_carry_the_appearance_vector_after_class_colour_and_size() {
        use crate::matching::testkit;
        let objects = testkit::world_objects();
        let mut dets =
            testkit::Side::of(testkit::POSE_A, &objects[..2], &[0, 1], testkit::EXACT).detections;
        let law = crate::sensor::DescriptorLaw {
            slope: 1.0,
            neutral: 0.5,
        };
        for (k, d) in dets.iter_mut().enumerate() {
            d.appearance.descriptor = Some(crate::sensor::Descriptor {
                values: vec![k as f32, 2.0, 3.0].into(),
                law,
            });
        }
        let without = node_attributes(&dets, crate::sensor::AppearanceWidth::NONE);
        assert_eq!(without.len(), 2 * NODE_FEATURES);
        let with = node_attributes(&dets, crate::sensor::AppearanceWidth::new(3));
        assert_eq!(with.len(), 2 * (NODE_FEATURES + 3));
        for k in 0..2 {
            let row = &with[k * (NODE_FEATURES + 3)..(k + 1) * (NODE_FEATURES + 3)];
            assert_eq!(
                row[..NODE_FEATURES],
                without[k * NODE_FEATURES..(k + 1) * NODE_FEATURES]
            );
            assert_eq!(row[NODE_FEATURES..], [k as f32, 2.0, 3.0]);
        }
        assert_eq!(
            check_appearance(
                crate::sensor::AppearanceWidth::NONE,
                crate::sensor::AppearanceWidth::NONE
            ),
            None
        );
        assert_eq!(
            check_appearance(
                crate::sensor::AppearanceWidth::new(3),
                crate::sensor::AppearanceWidth::new(3)
            ),
            None
        );
        assert!(
            check_appearance(
                crate::sensor::AppearanceWidth::new(3),
                crate::sensor::AppearanceWidth::new(4)
            )
            .unwrap()
            .contains("4 wide")
        );
        assert!(
            check_appearance(
                crate::sensor::AppearanceWidth::new(3),
                crate::sensor::AppearanceWidth::NONE
            )
            .unwrap()
            .contains("has none")
        );
    }
}
