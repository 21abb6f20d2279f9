//! A frame's decisions across vehicles: every instance of one step at one
//! pose-noise level identified together, made consistent across vehicles
//! as `[matching] multi_vehicle` says (pairwise, synchronised, or matched
//! against the frame's object map, [`super::map`]), scored for their
//! consistency ([`Consistency`]: triple chains, the implied objects as a
//! clustering), then counted and fused pair by pair and over every view.

use super::counts::{PairCounts, count_pairs};
use super::estimates::{FusionContext, ViewEstimate, all_views};
use super::pair::{MethodEval, score};
use super::{CorrespondenceSource, PairAtLevel, map};
use crate::fusion::{FusionSettings, FusionVariant};
use crate::matching::synchronize::{
    Association, PairwiseMatches, TripleCounts, synchronize, triple_consistency,
};
use crate::matching::{Correspondence, Identification, Method, MultiVehicle};

/// How consistent one method's matches of a frame are across vehicles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Consistency {
    /// Chains x~y~z over vehicle triples whose three pairs are instances,
    /// and how many of them the third pair contradicts.
    pub triples: TripleCounts,
    /// The objects the matches imply (the transitive closure of the pairs
    /// for `pairwise`, the synchronised assignment otherwise), scored as a
    /// clustering: over every pair of detections of an instance's two
    /// vehicles, "same object" against the truth (pair-counting precision,
    /// recall and F1).
    pub objects: PairCounts,
}

impl Consistency {
    pub fn add(&mut self, other: Consistency) {
        self.triples.add(other.triples);
        self.objects.add(other.objects);
    }
}

/// What one method did on the instances of one frame at one pose-noise
/// level.
#[derive(Clone, Debug)]
pub struct FrameEval {
    pub method: Method,
    /// One per instance, in input order.
    pub pairs: Vec<MethodEval>,
    pub consistency: Consistency,
    /// Per configured fusion variant, every (ego, object) of the frame
    /// fused from all the views matched to it.
    pub views: Vec<(FusionVariant, Vec<ViewEstimate>)>,
}

/// Identifies every instance of one frame (`pairs`: one step, one
/// pose-noise level, vehicles ordered by id within each pair) with
/// `source` and, with `multi_vehicle = synchronized`, replaces each pair's
/// matches by those of one consistent assignment of the frame's
/// detections to objects before counting and fusing; with `map`, matches
/// each vehicle once against the frame's object map instead ([`map`]) and
/// scores every pair by the objects it implies. With two vehicles all
/// modes agree with [`super::evaluate`] up to the probabilities of pairs
/// the association dropped.
pub fn evaluate_frame(
    pairs: &[PairAtLevel],
    source: &CorrespondenceSource,
    fusion: &FusionSettings,
    multi_vehicle: MultiVehicle,
) -> FrameEval {
    let method = source.method();
    let vehicles = FrameVehicles::new(pairs);
    let Decided {
        identifications,
        pairwise: decided,
        association,
    } = decide(pairs, source, &vehicles, multi_vehicle);
    let consistency = Consistency {
        triples: triple_consistency(&decided),
        objects: pairs
            .iter()
            .map(|p| object_counts(p, &association, &vehicles))
            .fold(PairCounts::default(), |mut acc, c| {
                acc.add(c);
                acc
            }),
    };
    let scored: Vec<MethodEval> = pairs
        .iter()
        .zip(identifications)
        .map(|(p, id)| score(p, method, id, fusion))
        .collect();
    let views = fusion
        .variants
        .iter()
        .map(|&variant| {
            let ctx = FusionContext::new(variant, fusion);
            (variant, all_views(pairs, &scored, &vehicles.ids, &ctx))
        })
        .collect();
    FrameEval {
        method,
        pairs: scored,
        consistency,
        views,
    }
}

/// What a method decided on a frame's instances.
struct Decided {
    /// One per instance, in input order, oriented as the instance.
    identifications: Vec<Identification>,
    /// The same matches between frame vehicle indices.
    pairwise: Vec<PairwiseMatches>,
    /// The objects they imply.
    association: Association,
}

/// Identifies a frame's instances with `source` as `multi_vehicle` says.
fn decide(
    pairs: &[PairAtLevel],
    source: &CorrespondenceSource,
    vehicles: &FrameVehicles,
    multi_vehicle: MultiVehicle,
) -> Decided {
    if multi_vehicle == MultiVehicle::Map {
        let joins = map::joins(pairs, source, vehicles);
        let association = Association::closure(&vehicles.n_detections, &joins);
        let wanted: Vec<(usize, usize)> = pairs
            .iter()
            .map(|p| {
                let (i, j) = vehicles.indices(p);
                (i.min(j), i.max(j))
            })
            .collect();
        let pairwise = association.implied_for(&wanted, &joins);
        let identifications = pairs
            .iter()
            .zip(&pairwise)
            .map(|(p, m)| Identification::matches_only(vehicles.oriented(p, m)))
            .collect();
        return Decided {
            identifications,
            pairwise,
            association,
        };
    }
    let mut identifications: Vec<Identification> =
        pairs.iter().map(|p| source.identify(p)).collect();
    let pairwise: Vec<PairwiseMatches> = pairs
        .iter()
        .zip(&identifications)
        .map(|(p, id)| vehicles.pairwise(p, id.matches.clone()))
        .collect();
    if multi_vehicle == MultiVehicle::Pairwise {
        let association = Association::closure(&vehicles.n_detections, &pairwise);
        return Decided {
            identifications,
            pairwise,
            association,
        };
    }
    let association = synchronize(&vehicles.n_detections, &pairwise);
    let implied = association.implied(&pairwise);
    for (id, p) in identifications.iter_mut().zip(&implied) {
        id.matches = p.matches.clone();
    }
    Decided {
        identifications,
        pairwise: implied,
        association,
    }
}

/// The connected vehicles of a frame's instances, indexed in id order.
pub(super) struct FrameVehicles<'a> {
    pub(super) ids: Vec<&'a str>,
    n_detections: Vec<usize>,
}

impl<'a> FrameVehicles<'a> {
    fn new(pairs: &[PairAtLevel<'a>]) -> Self {
        let mut sides: Vec<(&'a str, usize)> = pairs
            .iter()
            .flat_map(|p| [p.first, p.second])
            .map(|s| (s.obs.ego_id.as_str(), s.obs.detections.len()))
            .collect();
        sides.sort();
        sides.dedup();
        let (ids, n_detections) = sides.into_iter().unzip();
        Self { ids, n_detections }
    }

    fn index(&self, id: &str) -> usize {
        self.ids
            .binary_search(&id)
            .expect("every side is a frame vehicle")
    }

    /// The frame vehicle indices of a pair's first and second vehicle.
    pub(super) fn indices(&self, pair: &PairAtLevel) -> (usize, usize) {
        (
            self.index(&pair.first.obs.ego_id),
            self.index(&pair.second.obs.ego_id),
        )
    }

    /// Matches between frame vehicle indices (the smaller first) as the
    /// pair's own (`a` a detection of its first vehicle): the inverse of
    /// [`Self::pairwise`].
    fn oriented(&self, pair: &PairAtLevel, m: &PairwiseMatches) -> Vec<Correspondence> {
        let (i, _) = self.indices(pair);
        let mut out: Vec<Correspondence> = if i == m.first {
            m.matches.clone()
        } else {
            m.matches
                .iter()
                .map(|c| Correspondence {
                    a: c.b,
                    b: c.a,
                    ..*c
                })
                .collect()
        };
        out.sort_by_key(|c| c.a);
        out
    }

    /// A pair's matches between frame vehicle indices, the smaller first.
    fn pairwise(&self, pair: &PairAtLevel, matches: Vec<Correspondence>) -> PairwiseMatches {
        let (i, j) = self.indices(pair);
        if i < j {
            PairwiseMatches {
                first: i,
                second: j,
                matches,
            }
        } else {
            let swapped = matches
                .into_iter()
                .map(|c| Correspondence {
                    a: c.b,
                    b: c.a,
                    ..c
                })
                .collect();
            PairwiseMatches {
                first: j,
                second: i,
                matches: swapped,
            }
        }
    }
}

/// Object-level counts on one instance: every (first, second) detection
/// pair the association puts in one object, against the true pairs.
fn object_counts(
    pair: &PairAtLevel,
    association: &Association,
    vehicles: &FrameVehicles,
) -> PairCounts {
    let (first, second) = (pair.first.truth, pair.second.truth);
    let (i, j) = vehicles.indices(pair);
    let mut together = Vec::new();
    for a in 0..first.detections.len() {
        for b in 0..second.detections.len() {
            if association.same((i, a), (j, b)) {
                together.push(Correspondence {
                    a,
                    b,
                    probability: 1.0,
                    uncertainty: 0.0,
                });
            }
        }
    }
    count_pairs(first, second, &together)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;
    use crate::evaluate::testkit::{TestFrame, paper_fusion, sensed};
    use crate::geometry::{Pose2, Vec2};
    use crate::matching::{MatchView, Matcher};
    use crate::sensor::{Observation, ObservationTruth};

    /// Pairs by the reported x position of the two egos: (a, b) and
    /// (b, c) right and confident, (a, c) crossed and less sure; counts
    /// its calls.
    #[derive(Default)]
    struct Contradicting(Arc<AtomicUsize>);

    impl Matcher for Contradicting {
        fn method(&self) -> Method {
            Method::Mogm
        }
        fn identify_with(
            &self,
            first: &MatchView,
            second: &MatchView,
            _: &crate::fusion::PoseEstimate,
        ) -> Identification {
            self.0.fetch_add(1, Ordering::Relaxed);
            let c = |a, b, probability| Correspondence {
                a,
                b,
                probability,
                uncertainty: 0.0,
            };
            let xs = (
                first.pose_reported.position_m().x,
                second.pose_reported.position_m().x,
            );
            Identification::matches_only(if xs == (0.0, 20.0) {
                vec![c(0, 1, 0.6), c(1, 0, 0.6)]
            } else {
                vec![c(0, 0, 0.9), c(1, 1, 0.9)]
            })
        }
    }

    /// Vehicles a, b and c 10 m apart in a row, each seeing objects x and
    /// y exactly.
    fn three_in_a_row() -> TestFrame {
        let objects = [
            (Some("x"), Vec2::new(5.0, 8.0)),
            (Some("y"), Vec2::new(12.0, -3.0)),
        ];
        let poses = [0.0, 10.0, 20.0].map(|x| Pose2::new(Vec2::new(x, -10.0), 0.1));
        let sensed: Vec<(Observation, ObservationTruth)> = ["a", "b", "c"]
            .iter()
            .zip(&poses)
            .map(|(id, p)| sensed(id, *p, &objects))
            .collect();
        TestFrame::new(sensed, &poses)
    }

    /// Correct pairs per instance, (chains, inconsistent chains) and the
    /// implied objects' (identified, correct, ground truth) pairs.
    fn assert_frame(
        f: &FrameEval,
        correct: [usize; 3],
        triples: (usize, usize),
        objects: (usize, usize, usize),
    ) {
        let per_pair: Vec<usize> = f.pairs.iter().map(|e| e.counts.correct).collect();
        assert_eq!(per_pair, correct);
        let (t, o) = (f.consistency.triples, f.consistency.objects);
        assert_eq!((t.chains, t.inconsistent), triples);
        assert_eq!((o.identified, o.correct, o.ground_truth), objects);
    }

    #[test]
    fn a_contradictory_triple_is_counted_and_synchronisation_resolves_it() {
        let frame = three_in_a_row();
        let pairs = frame.every_pair();
        let fusion = paper_fusion();
        let source = CorrespondenceSource::Matcher(Box::<Contradicting>::default());
        let pairwise = evaluate_frame(&pairs, &source, &fusion, MultiVehicle::Pairwise);
        // As decided: (a, c) wrong, so every chain through b is broken;
        // the closure puts all six detections into one object.
        assert_frame(&pairwise, [2, 0, 2], (6, 6), (12, 6, 6));
        // Synchronised: the weak crossed pairs lose, (a, c) is implied by
        // the chains through b with probability 0.9 * 0.9.
        let synced = evaluate_frame(&pairs, &source, &fusion, MultiVehicle::Synchronized);
        assert_frame(&synced, [2, 2, 2], (6, 0), (6, 6, 6));
        let ac = &synced.pairs[1].identification.matches;
        assert_eq!(
            ac.iter().map(|c| (c.a, c.b)).collect::<Vec<_>>(),
            [(0, 0), (1, 1)]
        );
        assert!((ac[0].probability - 0.81).abs() < 1e-12);
        // Fused from the consistent matches: exact views, exact result.
        for e in &synced.pairs {
            for x in &e.fused[0].1 {
                assert!(x.match_correct && x.fused_error_m() < 1e-9, "{x:?}");
            }
        }
    }

    #[test]
    fn the_map_matches_each_vehicle_once_and_is_consistent() {
        let frame = three_in_a_row();
        let pairs = frame.every_pair();
        let fusion = paper_fusion();
        // b meets the map of a (in a's frame), c the map of a and b in the
        // frame of b, its nearest peer: the crossed (a, c) matching, which
        // pairwise matching gets wrong, is never asked for.
        let calls = Arc::default();
        let source = CorrespondenceSource::Matcher(Box::new(Contradicting(Arc::clone(&calls))));
        let map = evaluate_frame(&pairs, &source, &fusion, MultiVehicle::Map);
        assert_eq!(calls.load(Ordering::Relaxed), 2);
        assert_frame(&map, [2, 2, 2], (6, 0), (6, 6, 6));
        // Joins are with each object's first detection (a's): (a, c) at
        // c's own probability, (b, c) through a.
        let p = |k: usize| map.pairs[k].identification.matches[0].probability;
        assert!((p(1) - 0.9).abs() < 1e-12 && (p(2) - 0.81).abs() < 1e-12);
        // The oracle finds every pair through the map, too.
        let oracle = evaluate_frame(
            &pairs,
            &CorrespondenceSource::Oracle,
            &fusion,
            MultiVehicle::Map,
        );
        for e in &oracle.pairs {
            assert_eq!((e.counts.correct, e.counts.identified), (2, 2));
        }
    }
}
