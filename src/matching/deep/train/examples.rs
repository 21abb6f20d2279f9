//! Labelled training pairs, as plain data (no tensors): an [`Example`]
//! holds both vehicles' views, owned, and which of their detections are
//! the same object (the caller supplies them: the oracle's pairs); a
//! [`Prepared`] pair is the network's input for an architecture (both
//! graphs, the pair input) with its labels; [`EdgeStats`] say how the
//! examples' edges fill the pseudo-coordinate range.

use crate::geometry::Pose2;
use crate::graph::SceneGraph;
use crate::matching::deep::arch::{Architecture, likelihood_terms};
use crate::matching::deep::features::{PairInput, pair_input};
use crate::matching::deep::graph::{MAX_EDGE_M, OffsetGraph};
use crate::matching::{MatchView, gps_relative_pose};
use crate::sensor::{Detection, PoseNoiseLevel};

/// One vehicle's side of a training pair, owned.
#[derive(Clone, Debug, PartialEq)]
pub struct OwnedView {
    pub detections: Vec<Detection>,
    pub graph: SceneGraph,
    pub pose_reported: Pose2,
    pub pose_noise: PoseNoiseLevel,
}

impl OwnedView {
    pub fn of(view: &MatchView) -> Self {
        Self {
            detections: view.detections.to_vec(),
            graph: view.graph.clone(),
            pose_reported: view.pose_reported,
            pose_noise: view.pose_noise,
        }
    }

    pub fn view(&self) -> MatchView<'_> {
        MatchView {
            detections: &self.detections,
            graph: &self.graph,
            pose_reported: self.pose_reported,
            pose_noise: self.pose_noise,
        }
    }
}

/// One training pair: what both vehicles know, and which of their
/// detections are the same object.
#[derive(Clone, Debug, PartialEq)]
pub struct Example {
    pub first: OwnedView,
    pub second: OwnedView,
    /// `(a, b)`: detection `a` of the first vehicle is detection `b` of
    /// the second.
    pub true_pairs: Vec<(usize, usize)>,
}

/// A training pair from two views and their true correspondences; `None`
/// when a side is empty or nothing is shared (such a pair teaches nothing
/// about matching).
pub fn example(
    first: &MatchView,
    second: &MatchView,
    true_pairs: &[crate::matching::Correspondence],
) -> Option<Example> {
    if first.detections.is_empty() || second.detections.is_empty() || true_pairs.is_empty() {
        return None;
    }
    Some(Example {
        first: OwnedView::of(first),
        second: OwnedView::of(second),
        true_pairs: true_pairs.iter().map(|c| (c.a, c.b)).collect(),
    })
}

/// A pair made ready for the network: both graphs, the pair input of the
/// architecture, and the labels.
#[derive(Clone, Debug, PartialEq)]
pub struct Prepared {
    pub(crate) g1: OffsetGraph,
    pub(crate) g2: OffsetGraph,
    pub(crate) pair: PairInput,
    /// `n1 x n2`: 1 for a true pair that passes the gates.
    pub y: Vec<f32>,
    /// Per node of each side: 1 when it has no true partner.
    pub free: [Vec<f32>; 2],
    /// `n1 x n2`: 1 where row i or column j is a non-covisible object (a
    /// false positive counts as non-covisible).
    pub non: Vec<f32>,
}

impl Example {
    /// The network's inputs and labels with the likelihood of `arch` (a
    /// true pair that its gates close is neither a target nor "no match":
    /// no scoring can pair it).
    pub fn prepare(&self, arch: &Architecture, gate_chi2: f64) -> Prepared {
        let (a, b) = (self.first.view(), self.second.view());
        let (n1, n2) = (a.detections.len(), b.detections.len());
        let relative = gps_relative_pose(&a, &b);
        let pair = pair_input(&a, &b, &relative, &likelihood_terms(arch, gate_chi2));
        let mut partner_of_row: Vec<Option<usize>> = vec![None; n1];
        let mut col_has = vec![false; n2];
        for &(i, j) in &self.true_pairs {
            partner_of_row[i] = Some(j);
            col_has[j] = true;
        }
        let mut y = vec![0f32; n1 * n2];
        let mut non = vec![0f32; n1 * n2];
        for i in 0..n1 {
            for j in 0..n2 {
                if partner_of_row[i] == Some(j) && pair.log_likelihood[i * n2 + j].is_some() {
                    y[i * n2 + j] = 1.0;
                }
                if partner_of_row[i].is_none() || !col_has[j] {
                    non[i * n2 + j] = 1.0;
                }
            }
        }
        let flag = |b: bool| if b { 0.0 } else { 1.0 };
        Prepared {
            g1: OffsetGraph::offsets(
                a.detections,
                a.graph,
                &a.pose_reported,
                arch.appearance_width(),
            ),
            g2: OffsetGraph::offsets(
                b.detections,
                b.graph,
                &b.pose_reported,
                arch.appearance_width(),
            ),
            pair,
            y,
            free: [
                partner_of_row.iter().map(|p| flag(p.is_some())).collect(),
                col_has.iter().map(|&h| flag(h)).collect(),
            ],
            non,
        }
    }
}

/// How the training graphs' edge vectors fill the pseudo-coordinate range
/// (`MAX_EDGE_M` per axis): the median and 95th percentile of
/// each edge's larger absolute world-axis component, and the share of
/// edges beyond the range (clipped onto its border).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EdgeStats {
    pub median_m: f64,
    pub p95_m: f64,
    pub clipped_share: f64,
}

impl EdgeStats {
    pub fn of(examples: &[Example]) -> Self {
        let mut m: Vec<f64> = Vec::new();
        for e in examples {
            for side in [&e.first, &e.second] {
                let none = crate::sensor::AppearanceWidth::NONE;
                let g =
                    OffsetGraph::offsets(&side.detections, &side.graph, &side.pose_reported, none);
                m.extend(g.edge_m.iter().map(|&[x, y]| x.abs().max(y.abs())));
            }
        }
        if m.is_empty() {
            return Self::default();
        }
        m.sort_by(f64::total_cmp);
        let at = |q: f64| m[((m.len() - 1) as f64 * q).round() as usize];
        let clipped = m.iter().filter(|&&x| x > MAX_EDGE_M).count();
        Self {
            median_m: at(0.5),
            p95_m: at(0.95),
            clipped_share: clipped as f64 / m.len() as f64,
        }
    }
}
