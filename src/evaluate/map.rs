//! `[matching] multi_vehicle = "map"`: each vehicle of a frame is matched
//! once, against an object map, instead of once per peer.
//!
//! The vehicles are taken in id order. The map starts empty. Each vehicle
//! sees the objects of the map that a vehicle it exchanges with (one of
//! its instance peers, already matched) contributed, expressed in the
//! frame of the nearest such peer (the anchor, by reported GPS
//! positions): each object at the fusion (Eq. 14-16) of its members'
//! detections moved into that frame with the GPS relative-pose
//! uncertainty, with the appearance of its first detection, and kept when
//! it could be one of the vehicle's detections (position and appearance
//! gates of the shared likelihood, [`VIEW_GATE_CHI2`]: the system uses
//! GPS to pick the part of the map to match, for every method). The
//! method matches the vehicle against that view
//! like against a peer (any method: it is one more pair of views); every
//! matched detection joins its object, every other one starts a new one.
//! The cost is one matching per vehicle, however many peers it has.
//!
//! Two detections then match exactly when they belong to one object, so
//! the result is consistent across vehicles by construction. A join is
//! recorded as a correspondence with the object's first detection, with
//! the method's probability; pairs of later members get the product along
//! that chain ([`Association::matches_between`]).

use std::collections::BTreeMap;

use super::estimates::measured;
use super::frame::FrameVehicles;
use super::{CorrespondenceSource, PairAtLevel, Side};
use crate::fusion::{Measurement, fuse, relative_pose_prior};
use crate::geometry::Vec2;
use crate::graph::SceneGraph;
use crate::matching::claim;
use crate::matching::likelihood::{LikelihoodTerms, pair_terms};
use crate::matching::synchronize::PairwiseMatches;
use crate::matching::{Correspondence, MatchView, gps_relative_pose};
use crate::sensor::{Detection, DetectionTruth, Observation, ObservationTruth, PoseNoiseLevel};

/// A map object is in a vehicle's view when it could be one of the
/// vehicle's detections: the squared Mahalanobis distance of the two
/// (both covariances, the GPS relative pose's included) within this gate
/// (99.9 %, 2 dof; wider than the matchers' own 99 %), and a compatible
/// appearance.
const VIEW_GATE_CHI2: f64 = 13.82;

/// A detection of the frame: (vehicle index, detection index).
type Member = (usize, usize);

/// The correspondences that build the frame's map, as pairwise matches
/// between each object's first detection and every later one (vehicle
/// indices of `vehicles`, the smaller first): their transitive closure is
/// the map's objects.
pub(super) fn joins(
    pairs: &[PairAtLevel],
    source: &CorrespondenceSource,
    vehicles: &FrameVehicles,
) -> Vec<PairwiseMatches> {
    let frame = Frame::new(pairs, vehicles);
    let mut objects: Vec<Vec<Member>> = Vec::new();
    let mut joins: BTreeMap<(usize, usize), Vec<Correspondence>> = BTreeMap::new();
    for v in 0..frame.sides.len() {
        let side = frame.sides[v];
        let matched: Vec<(usize, Correspondence)> = match frame.view(v, &objects) {
            Some(view) => {
                let pair = PairAtLevel {
                    instance: usize::MAX,
                    first: view.side(),
                    second: side,
                    level: frame.level,
                };
                source
                    .identify(&pair)
                    .matches
                    .into_iter()
                    .map(|c| (view.objects[c.a], c))
                    .collect()
            }
            None => Vec::new(),
        };
        let mut joined = vec![false; side.obs.detections.len()];
        for (o, c) in matched {
            let (first_v, first_d) = objects[o][0];
            joins.entry((first_v, v)).or_default().push(Correspondence {
                a: first_d,
                b: c.b,
                ..c
            });
            objects[o].push((v, c.b));
            joined[c.b] = true;
        }
        for (d, _) in joined.iter().enumerate().filter(|(_, j)| !**j) {
            objects.push(vec![(v, d)]);
        }
    }
    joins
        .into_iter()
        .map(|((first, second), mut matches)| {
            matches.sort_by_key(|c| c.a);
            PairwiseMatches {
                first,
                second,
                matches,
            }
        })
        .collect()
}

/// Each frame vehicle's side at this level, and whom it exchanges with.
struct Frame<'a> {
    sides: Vec<Side<'a>>,
    /// `peers[v]`: the vehicles that share an instance with `v`.
    peers: Vec<Vec<usize>>,
    level: PoseNoiseLevel,
}

impl<'a> Frame<'a> {
    fn new(pairs: &[PairAtLevel<'a>], vehicles: &FrameVehicles) -> Self {
        let n = vehicles.ids.len();
        let mut sides: Vec<Option<Side<'a>>> = vec![None; n];
        let mut peers = vec![Vec::new(); n];
        for p in pairs {
            let (i, j) = vehicles.indices(p);
            sides[i] = Some(p.first);
            sides[j] = Some(p.second);
            peers[i].push(j);
            peers[j].push(i);
        }
        Self {
            sides: sides
                .into_iter()
                .map(|s| s.expect("every frame vehicle is in a pair"))
                .collect(),
            peers,
            level: pairs[0].level,
        }
    }

    /// What vehicle `v` sees of the map (`objects`: each object's members,
    /// first detection first), or `None` when nothing is in reach.
    fn view(&self, v: usize, objects: &[Vec<Member>]) -> Option<MapView<'a>> {
        let side = self.sides[v];
        let here = side.view.pose_reported.position_m();
        // The nearest peer already matched is the anchor (ties: lower index).
        let anchor = self.peers[v]
            .iter()
            .copied()
            .filter(|&u| u < v)
            .min_by(|&a, &b| {
                let d = |u: usize| (self.sides[u].view.pose_reported.position_m() - here).norm();
                d(a).total_cmp(&d(b)).then(a.cmp(&b))
            })?;
        let anchor_side = self.sides[anchor];
        // The map is in the anchor's frame: its pose, with the anchor's
        // claim.
        let mut view = MapView::new(anchor_side, anchor_side.view.pose_noise);
        for (o, members) in objects.iter().enumerate() {
            if !members.iter().any(|(u, _)| self.peers[v].contains(u)) {
                continue;
            }
            let Some(placed) = self.place(anchor, members, &mut view.scratch) else {
                continue;
            };
            let (first_v, first_d) = members[0];
            let first = self.sides[first_v];
            view.push(
                o,
                Detection {
                    position_m: placed.position_m,
                    cov_m2: placed.cov_m2,
                    appearance: first.obs.detections[first_d].appearance.clone(),
                    motion: None,
                },
                first.truth.detections[first_d].clone(),
            );
        }
        view.keep_within_reach(&side.view).finish()
    }

    /// An object's position in `anchor`'s frame: its members' detections
    /// moved there with the relative pose of both GPS poses and its
    /// uncertainty, fused.
    fn place(
        &self,
        anchor: usize,
        members: &[Member],
        scratch: &mut Vec<Measurement>,
    ) -> Option<Measurement> {
        let a = &self.sides[anchor].view;
        scratch.clear();
        for &(u, d) in members {
            let side = &self.sides[u];
            let m = measured(side.obs, d);
            scratch.push(if u == anchor {
                m
            } else {
                let rel = relative_pose_prior(
                    &a.pose_reported,
                    &side.view.pose_reported,
                    claim(&a.pose_noise),
                    claim(&side.view.pose_noise),
                );
                m.moved_uncertain(&rel)
            });
        }
        if let [only] = scratch.as_slice() {
            return Some(*only);
        }
        fuse(scratch).map(|f| Measurement {
            position_m: f.position_m,
            cov_m2: f.cov_m2,
        })
    }
}

/// The map as one vehicle sees it: a view like a peer's, in the anchor's
/// frame, with the truth of each object's first detection beside it.
struct MapView<'a> {
    anchor: Side<'a>,
    level: PoseNoiseLevel,
    /// The map object behind each detection of the view.
    objects: Vec<usize>,
    obs: Observation,
    truth: ObservationTruth,
    graph: SceneGraph,
    scratch: Vec<Measurement>,
}

impl<'a> MapView<'a> {
    fn new(anchor: Side<'a>, level: PoseNoiseLevel) -> Self {
        Self {
            anchor,
            level,
            objects: Vec::new(),
            obs: Observation {
                ego_id: format!("map@{}", anchor.obs.ego_id),
                detections: Vec::new(),
            },
            truth: ObservationTruth {
                ego_pose: anchor.truth.ego_pose,
                detections: Vec::new(),
            },
            graph: SceneGraph {
                positions_m: Vec::new(),
                edges: Vec::new(),
            },
            scratch: Vec::new(),
        }
    }

    fn push(&mut self, object: usize, detection: Detection, truth: DetectionTruth) {
        self.objects.push(object);
        self.obs.detections.push(detection);
        self.truth.detections.push(truth);
    }

    /// Only the objects that pass the position and appearance gates of the
    /// shared likelihood with a detection of `vehicle`.
    fn keep_within_reach(mut self, vehicle: &MatchView) -> Self {
        let n = vehicle.detections.len();
        let keep: Vec<bool> = {
            let map = MatchView {
                detections: &self.obs.detections,
                graph: &self.graph,
                pose_reported: self.anchor.view.pose_reported,
                pose_noise: self.level,
            };
            let terms = LikelihoodTerms::full(VIEW_GATE_CHI2);
            let gated = pair_terms(&map, vehicle, &gps_relative_pose(&map, vehicle), &terms);
            gated
                .chunks(n.max(1))
                .map(|row| row.iter().any(Option::is_some))
                .collect()
        };
        let mut k = keep.iter();
        self.objects.retain(|_| *k.next().unwrap_or(&false));
        let mut k = keep.iter();
        self.obs.detections.retain(|_| *k.next().unwrap_or(&false));
        let mut k = keep.iter();
        self.truth
            .detections
            .retain(|_| *k.next().unwrap_or(&false));
        self
    }

    /// The view with its Delaunay graph; `None` when empty (or, should a
    /// fused position not be finite, when it cannot be triangulated).
    fn finish(mut self) -> Option<Self> {
        if self.objects.is_empty() {
            return None;
        }
        let positions: Vec<Vec2> = self.obs.detections.iter().map(|d| d.position_m).collect();
        self.graph = SceneGraph::delaunay(&positions).ok()?;
        Some(self)
    }

    fn side(&self) -> Side<'_> {
        Side {
            view: MatchView {
                detections: &self.obs.detections,
                graph: &self.graph,
                pose_reported: self.anchor.view.pose_reported,
                pose_noise: self.level,
            },
            obs: &self.obs,
            truth: &self.truth,
        }
    }
}
