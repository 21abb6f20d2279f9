//! Evaluation of one instance: the one place that runs a method on a pair
//! of vehicles, counts its correspondences against the truth (precision,
//! recall) and fuses what it matched (displacement errors, single vs
//! fused). `run`, `eval`, `render` and the training-data collection all go
//! through [`evaluate`]. Pure computation; the protocol is written down in
//! docs/protocol.md.
//!
//! This module, the oracle and the pictures are the only readers of the
//! ground truth ([`ObservationTruth`]); matchers receive [`MatchView`]s.

mod map;

use std::collections::BTreeMap;

use crate::fusion::{FusionSettings, FusionVariant, Measurement, align, fuse, relative_pose_prior};
use crate::geometry::Vec2;
use crate::matching::synchronize::{
    Association, PairwiseMatches, TripleCounts, synchronize, triple_consistency,
};
use crate::matching::{
    Correspondence, Identification, MatchView, Matcher, Method, MultiVehicle, oracle,
};
use crate::sensor::{Observation, ObservationTruth, PoseNoiseLabel, PoseNoiseLevel};

/// `[eval]`: the test runs of `coid eval`.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalSettings {
    /// Traffic (= sensor) seeds of the test runs; disjoint from the
    /// training runs.
    pub traffic_seeds: Vec<u64>,
    /// More scenarios (config files) to test on, each on `traffic_seeds`;
    /// disjoint from the training and validation scenarios.
    pub scenarios: Vec<std::path::PathBuf>,
}

/// Correspondence counts of one or more instances.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairCounts {
    /// Pairs the method identified.
    pub identified: usize,
    /// Identified pairs whose two detections are the same true object.
    pub correct: usize,
    /// True covisible pairs: same object detected by both vehicles.
    pub ground_truth: usize,
}

impl PairCounts {
    pub fn add(&mut self, other: PairCounts) {
        self.identified += other.identified;
        self.correct += other.correct;
        self.ground_truth += other.ground_truth;
    }

    /// correct / identified; undefined (NaN) when nothing was identified:
    /// a method that claims nothing has made no correct claim either.
    pub fn precision(&self) -> f64 {
        if self.identified == 0 {
            f64::NAN
        } else {
            self.correct as f64 / self.identified as f64
        }
    }

    /// correct / ground truth; undefined (NaN) when there was nothing to
    /// find.
    pub fn recall(&self) -> f64 {
        if self.ground_truth == 0 {
            f64::NAN
        } else {
            self.correct as f64 / self.ground_truth as f64
        }
    }

    /// The harmonic mean of precision and recall, from the counts:
    /// `2 correct / (identified + ground truth)`. Defined whenever either
    /// count is (0 when nothing was identified but there was something to
    /// find); NaN only when both are 0.
    pub fn f1(&self) -> f64 {
        let denominator = self.identified + self.ground_truth;
        if denominator == 0 {
            f64::NAN
        } else {
            2.0 * self.correct as f64 / denominator as f64
        }
    }
}

/// Number of true pairs: the same object behind a node of each vehicle
/// (camera detections, and a sender's own node with the peer's detection
/// of it).
pub fn covisible_pairs(first: &ObservationTruth, second: &ObservationTruth) -> usize {
    oracle::true_pairs(first, second).len()
}

/// Whether both vehicles' cameras detect a common object (the paper's CAD
/// rule for an instance; senders' own nodes do not count).
pub fn share_a_detected_object(first: &ObservationTruth, second: &ObservationTruth) -> bool {
    first.detections.iter().any(|d| {
        !d.sender
            && d.object_id.as_deref().is_some_and(|id| {
                second
                    .detections
                    .iter()
                    .any(|e| !e.sender && e.object_id.as_deref() == Some(id))
            })
    })
}

/// Whether `c` pairs two detections of the same real object.
pub fn is_correct(first: &ObservationTruth, second: &ObservationTruth, c: &Correspondence) -> bool {
    let a = first.object_id(c.a);
    a.is_some() && a == second.object_id(c.b)
}

/// Counts `matches` against the truth.
pub fn count_pairs(
    first: &ObservationTruth,
    second: &ObservationTruth,
    matches: &[Correspondence],
) -> PairCounts {
    let correct = matches
        .iter()
        .filter(|c| is_correct(first, second, c))
        .count();
    PairCounts {
        identified: matches.len(),
        correct,
        ground_truth: covisible_pairs(first, second),
    }
}

/// One vehicle of an instance at one pose-noise level: what it knows (its
/// view, with the GPS pose of that level) and the truth beside it.
#[derive(Clone, Copy, Debug)]
pub struct Side<'a> {
    pub view: MatchView<'a>,
    pub obs: &'a Observation,
    pub truth: &'a ObservationTruth,
}

/// An instance (a step and a pair of connected vehicles) at one pose-noise
/// level.
#[derive(Clone, Copy, Debug)]
pub struct PairAtLevel<'a> {
    /// The instance's running index within its run.
    pub instance: usize,
    pub first: Side<'a>,
    pub second: Side<'a>,
    pub level: PoseNoiseLevel,
}

/// How a method runs: from what the vehicles know, from the truth, or
/// from a file.
pub enum Runner {
    Matcher(Box<dyn Matcher>),
    /// The true correspondences ([`oracle::true_pairs`]).
    Oracle,
    /// Correspondences made elsewhere (`coid score`), for one run.
    External(ExternalMatches),
}

/// One run's correspondences made elsewhere: per (instance, pose-noise
/// level), pairs of the instance's first and second vehicle's nodes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExternalMatches {
    pub by_instance: BTreeMap<(usize, PoseNoiseLabel), Vec<Correspondence>>,
}

impl ExternalMatches {
    /// The correspondences of `pair`'s instance at its level, those that
    /// name nodes it has ([`ExternalMatches::check`] refuses the others).
    fn for_pair(&self, pair: &PairAtLevel) -> Vec<Correspondence> {
        let (n1, n2) = (
            pair.first.view.detections.len(),
            pair.second.view.detections.len(),
        );
        self.by_instance
            .get(&(pair.instance, pair.level.label))
            .map(|m| m.iter().filter(|c| c.a < n1 && c.b < n2).copied().collect())
            .unwrap_or_default()
    }

    /// Why the correspondences do not fit a frame's instances, if they do
    /// not: a node index beyond what a vehicle detected.
    pub fn check(&self, pairs: &[PairAtLevel]) -> Result<(), String> {
        for pair in pairs {
            let key = (pair.instance, pair.level.label);
            let (n1, n2) = (
                pair.first.view.detections.len(),
                pair.second.view.detections.len(),
            );
            for c in self.by_instance.get(&key).into_iter().flatten() {
                if c.a >= n1 || c.b >= n2 {
                    return Err(format!(
                        "instance {} has {n1} and {n2} nodes, but a match pairs nodes {} and {}",
                        pair.instance, c.a, c.b
                    ));
                }
            }
        }
        Ok(())
    }

    /// Why the correspondences do not fit a run of `n_instances`
    /// instances, if they do not.
    pub fn check_instances(&self, n_instances: usize) -> Result<(), String> {
        match self.by_instance.keys().map(|k| k.0).max() {
            Some(i) if i >= n_instances => Err(format!(
                "the run has {n_instances} instances, but matches name instance {i}"
            )),
            _ => Ok(()),
        }
    }
}

impl Runner {
    pub fn method(&self) -> Method {
        match self {
            Runner::Matcher(m) => m.method(),
            Runner::Oracle => Method::Oracle,
            Runner::External(_) => Method::External,
        }
    }

    pub fn identify(&self, pair: &PairAtLevel) -> Identification {
        match self {
            Runner::Matcher(m) => m.identify(&pair.first.view, &pair.second.view),
            Runner::Oracle => {
                Identification::plain(oracle::true_pairs(pair.first.truth, pair.second.truth))
            }
            Runner::External(e) => Identification::plain(e.for_pair(pair)),
        }
    }
}

/// One (ego, object) estimate of one instance, all positions in the world
/// frame: estimates live in the ego's frame and are placed in the world with
/// the ego's true pose, so the error is what the ego gets wrong about the
/// object relative to itself. There is one for every real object the ego
/// detects, whatever the method did: the object set is the same for every
/// method.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectEstimate {
    pub ego_id: String,
    pub peer_id: String,
    pub object_id: String,
    /// Whether the peer detects the object too.
    pub covisible: bool,
    /// Whether the method paired the ego's detection with one of the
    /// peer's; if not, the fused estimate is the single one.
    pub matched: bool,
    /// Whether it was paired with the peer's detection of the same object.
    pub match_correct: bool,
    /// Whether the relative pose was refined from matches (aligned variant).
    pub pose_refined: bool,
    pub truth_m: Vec2,
    pub single_m: Vec2,
    pub fused_m: Vec2,
}

impl ObjectEstimate {
    pub fn single_error_m(&self) -> f64 {
        (self.single_m - self.truth_m).norm()
    }
    pub fn fused_error_m(&self) -> f64 {
        (self.fused_m - self.truth_m).norm()
    }
}

/// What one method did on one instance at one pose-noise level.
#[derive(Clone, Debug)]
pub struct MethodEval {
    pub method: Method,
    pub identification: Identification,
    pub counts: PairCounts,
    /// Per configured fusion variant, both vehicles' estimates (the first
    /// vehicle's objects, then the second's).
    pub fused: Vec<(FusionVariant, Vec<ObjectEstimate>)>,
}

/// Runs `runner` on `pair`, counts its correspondences and fuses them with
/// every variant of `fusion`.
pub fn evaluate(pair: &PairAtLevel, runner: &Runner, fusion: &FusionSettings) -> MethodEval {
    score(pair, runner.method(), runner.identify(pair), fusion)
}

/// Counts `identification`'s correspondences on `pair` and fuses them.
fn score(
    pair: &PairAtLevel,
    method: Method,
    identification: Identification,
    fusion: &FusionSettings,
) -> MethodEval {
    let matches = &identification.matches;
    let counts = count_pairs(pair.first.truth, pair.second.truth, matches);
    let ab: Vec<(usize, usize)> = matches.iter().map(|c| (c.a, c.b)).collect();
    let ba: Vec<(usize, usize)> = matches.iter().map(|c| (c.b, c.a)).collect();
    let fused = fusion
        .variants
        .iter()
        .map(|&variant| {
            let fuse_for = |ego: &Side, peer: &Side, pairs: &[(usize, usize)]| {
                let ctx = FusionContext {
                    level: &pair.level,
                    variant,
                    align_min_matches: fusion.align_min_matches,
                };
                fuse_for_ego(ego, peer, pairs, &ctx)
            };
            let mut est = fuse_for(&pair.first, &pair.second, &ab);
            est.extend(fuse_for(&pair.second, &pair.first, &ba));
            (variant, est)
        })
        .collect();
    MethodEval {
        method,
        identification,
        counts,
        fused,
    }
}

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

/// One (ego, real object) of a frame, fused from every vehicle that
/// matched it (Eq. 14-16 with N terms), beside the pairwise estimates of
/// the same object: the object set is every real object an ego of the
/// frame detects, the same for every method.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewEstimate {
    pub ego_id: String,
    pub object_id: String,
    /// Vehicles that detect the object: the ego and those of its instance
    /// peers that do (from the truth, the same for every method).
    pub seen_by: usize,
    /// Measurements fused: the ego's and one per peer that matched it.
    pub views: usize,
    pub single_error_m: f64,
    /// The mean pairwise fused error over the ego's instances whose peer
    /// sees the object too (over all its instances when none does): what
    /// fusing with one covisible peer at a time gives.
    pub pairwise_error_m: f64,
    pub fused_error_m: f64,
}

/// Runs `runner` on every instance of one frame (`pairs`: one step, one
/// pose-noise level, vehicles ordered by id within each pair) and, with
/// `multi_vehicle = synchronized`, replaces each pair's matches by those of
/// one consistent assignment of the frame's detections to objects before
/// counting and fusing; with `map`, matches each vehicle once against the
/// frame's object map instead ([`map`]) and scores every pair by the
/// objects it implies. With two vehicles all modes agree with
/// [`evaluate`] up to the probabilities of pairs the association dropped.
pub fn evaluate_frame(
    pairs: &[PairAtLevel],
    runner: &Runner,
    fusion: &FusionSettings,
    multi_vehicle: MultiVehicle,
) -> FrameEval {
    let method = runner.method();
    let vehicles = FrameVehicles::new(pairs);
    let Decided {
        identifications,
        pairwise: decided,
        association,
    } = decide(pairs, runner, &vehicles, multi_vehicle);
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
            let ctx = FusionContext {
                level: &pairs[0].level,
                variant,
                align_min_matches: fusion.align_min_matches,
            };
            (variant, all_views(pairs, &scored, &vehicles, &ctx))
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

/// Runs `runner` on a frame's instances as `multi_vehicle` says.
fn decide(
    pairs: &[PairAtLevel],
    runner: &Runner,
    vehicles: &FrameVehicles,
    multi_vehicle: MultiVehicle,
) -> Decided {
    if multi_vehicle == MultiVehicle::Map {
        let joins = map::joins(pairs, runner, vehicles);
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
            .map(|(p, m)| Identification::plain(vehicles.oriented(p, m)))
            .collect();
        return Decided {
            identifications,
            pairwise,
            association,
        };
    }
    let mut identifications: Vec<Identification> =
        pairs.iter().map(|p| runner.identify(p)).collect();
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

/// Every ego of the frame fuses each real object it detects from all the
/// peers (of its instances) whose detection the decided matches pair with
/// its own; beside it, the mean of the pairwise fused errors of `scored`
/// over the peers that see the object.
fn all_views(
    pairs: &[PairAtLevel],
    scored: &[MethodEval],
    vehicles: &FrameVehicles,
    ctx: &FusionContext,
) -> Vec<ViewEstimate> {
    // Per (ego, object): sums of the pairwise fused errors over the peers
    // that see the object too, and over all peers.
    let mut pairwise: BTreeMap<(&str, &str), [(f64, usize); 2]> = BTreeMap::new();
    for e in scored {
        for (v, est) in &e.fused {
            if *v == ctx.variant {
                for x in est {
                    let sums = pairwise.entry((&x.ego_id, &x.object_id)).or_default();
                    let err = x.fused_error_m();
                    if x.covisible {
                        sums[0].0 += err;
                        sums[0].1 += 1;
                    }
                    sums[1].0 += err;
                    sums[1].1 += 1;
                }
            }
        }
    }
    let mut out = Vec::new();
    for ego_id in &vehicles.ids {
        let mut ego = None;
        let mut peers: Vec<(Side, Vec<(usize, usize)>)> = Vec::new();
        for (p, e) in pairs.iter().zip(scored) {
            let m = &e.identification.matches;
            if p.first.obs.ego_id == *ego_id {
                ego = Some(p.first);
                peers.push((p.second, m.iter().map(|c| (c.a, c.b)).collect()));
            } else if p.second.obs.ego_id == *ego_id {
                ego = Some(p.second);
                peers.push((p.first, m.iter().map(|c| (c.b, c.a)).collect()));
            }
        }
        let Some(ego) = ego else { continue };
        for mut v in fuse_all_views(&ego, &peers, ctx) {
            let [covisible, all] = pairwise[&(v.ego_id.as_str(), v.object_id.as_str())];
            let (sum, n) = if covisible.1 > 0 { covisible } else { all };
            v.pairwise_error_m = sum / n as f64;
            out.push(v);
        }
    }
    out
}

/// `ego`'s estimate of every real object it detects, fused with the
/// matched detection of every peer (`peers`: each with its matched (ego
/// detection, peer detection)), each peer's pose from the variant of
/// `ctx`; the ego's own where no peer matched it. `pairwise_error_m` is
/// left NaN for the caller.
fn fuse_all_views(
    ego: &Side,
    peers: &[(Side, Vec<(usize, usize)>)],
    ctx: &FusionContext,
) -> Vec<ViewEstimate> {
    let poses: Vec<PeerPose> = peers
        .iter()
        .map(|(peer, pairs)| peer_pose(ego, peer, pairs, ctx).1)
        .collect();
    let mut out = Vec::new();
    for (a, id, truth_m) in real_detections(ego) {
        let own = measured(ego.obs, a);
        let mut measurements = vec![own];
        for ((peer, pairs), pose) in peers.iter().zip(&poses) {
            if let Some(&(_, b)) = pairs.iter().find(|(x, _)| *x == a) {
                measurements.push(pose.move_measurement(&measured(peer.obs, b)));
            }
        }
        let fused = if measurements.len() > 1 {
            fuse(&measurements).map_or(own.position_m, |f| f.position_m)
        } else {
            own.position_m
        };
        let error = |p: &Vec2| (ego.truth.ego_pose.to_parent(p) - truth_m).norm();
        out.push(ViewEstimate {
            ego_id: ego.obs.ego_id.clone(),
            object_id: id.to_owned(),
            seen_by: 1 + peers
                .iter()
                .filter(|(peer, _)| peer.truth.find(id).is_some())
                .count(),
            views: measurements.len(),
            single_error_m: error(&own.position_m),
            pairwise_error_m: f64::NAN,
            fused_error_m: error(&fused),
        });
    }
    out
}

/// The connected vehicles of a frame's instances, indexed in id order.
struct FrameVehicles<'a> {
    ids: Vec<&'a str>,
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
    fn indices(&self, pair: &PairAtLevel) -> (usize, usize) {
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
    let i = vehicles.index(&pair.first.obs.ego_id);
    let j = vehicles.index(&pair.second.obs.ego_id);
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

/// How one ego fuses: the pose-noise level, the variant and its setting.
struct FusionContext<'a> {
    level: &'a PoseNoiseLevel,
    variant: FusionVariant,
    align_min_matches: usize,
}

/// Where the peer sits in the ego's frame, as a fusion variant sees it.
enum PeerPose {
    /// From both GPS poses, its uncertainty ignored (the paper).
    Reported(crate::geometry::Pose2),
    /// Refined from the matches, with its covariance.
    Aligned(crate::fusion::PoseEstimate),
}

/// The ego's detections of real objects (false positives have no truth;
/// the ego's own node is not a detection): index, object id, true
/// position (world frame).
fn real_detections<'a>(ego: &Side<'a>) -> impl Iterator<Item = (usize, &'a str, Vec2)> {
    ego.truth
        .detections
        .iter()
        .enumerate()
        .filter(|(_, t)| !t.sender)
        .filter_map(|(a, t)| Some((a, t.object_id.as_deref()?, t.position_m?)))
}

/// Detection `k` of `obs` as a measurement in that vehicle's frame.
fn measured(obs: &Observation, k: usize) -> Measurement {
    Measurement {
        position_m: obs.detections[k].position_m,
        cov_m2: obs.detections[k].cov_m2,
    }
}

impl PeerPose {
    /// A peer's measurement moved into the ego's frame.
    fn move_measurement(&self, m: &Measurement) -> Measurement {
        match self {
            PeerPose::Reported(pose) => m.moved(pose),
            PeerPose::Aligned(estimate) => m.moved_uncertain(estimate),
        }
    }
}

/// Where `peer` sits in `ego`'s frame for the variant of `ctx` (`pairs`:
/// the matched (ego detection, peer detection)), and whether it was
/// refined from the matches.
fn peer_pose(
    ego: &Side,
    peer: &Side,
    pairs: &[(usize, usize)],
    ctx: &FusionContext,
) -> (bool, PeerPose) {
    let prior = relative_pose_prior(
        &ego.view.pose_reported,
        &peer.view.pose_reported,
        ctx.level.position_sigma_m,
        ctx.level.heading_sigma_rad,
    );
    match ctx.variant {
        FusionVariant::Paper => (false, PeerPose::Reported(prior.pose)),
        FusionVariant::Aligned => {
            let matched: Vec<(Measurement, Measurement)> = pairs
                .iter()
                .map(|&(a, b)| (measured(ego.obs, a), measured(peer.obs, b)))
                .collect();
            let al = align(&matched, &prior, ctx.align_min_matches);
            (al.refined, PeerPose::Aligned(al.estimate))
        }
    }
}

/// The estimates of every real object `ego` detected (false positives have
/// no truth; the ego's own node is not a detection): fused with the peer's detection the correspondences pair it
/// with (`pairs` index `(ego detection, peer detection)`), or the ego's own
/// where there is none. `paper` moves the peer's detection with the
/// relative pose of both GPS poses and rotates its covariance (Eq. 14-16);
/// `aligned` refines that pose from the matched pairs and adds the
/// covariance of the refined pose to the moved detection's.
fn fuse_for_ego(
    ego: &Side,
    peer: &Side,
    pairs: &[(usize, usize)],
    ctx: &FusionContext,
) -> Vec<ObjectEstimate> {
    let (refined, peer_pose) = peer_pose(ego, peer, pairs, ctx);
    let moved = |m: &Measurement| peer_pose.move_measurement(m);
    let mut partner: Vec<Option<usize>> = vec![None; ego.obs.detections.len()];
    for &(a, b) in pairs {
        partner[a] = Some(b);
    }
    let to_world = |p: &Vec2| ego.truth.ego_pose.to_parent(p);
    let mut out = Vec::new();
    for (a, id, truth_m) in real_detections(ego) {
        let own = measured(ego.obs, a);
        let fused = partner[a]
            .and_then(|b| fuse(&[own, moved(&measured(peer.obs, b))]))
            .map_or(own.position_m, |f| f.position_m);
        let matched = partner[a].is_some();
        out.push(ObjectEstimate {
            ego_id: ego.obs.ego_id.clone(),
            peer_id: peer.obs.ego_id.clone(),
            object_id: id.to_owned(),
            covisible: peer.truth.find(id).is_some(),
            matched,
            match_correct: partner[a].is_some_and(|b| peer.truth.object_id(b) == Some(id)),
            pose_refined: refined,
            truth_m,
            single_m: to_world(&own.position_m),
            fused_m: to_world(&fused),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;
    use crate::graph::SceneGraph;
    use crate::matching::testkit;
    use crate::sensor::{DetectionTruth, PoseNoiseLabel};

    /// The Delaunay graph of an observation's detections.
    fn graph(o: &Observation) -> SceneGraph {
        let positions: Vec<Vec2> = o.detections.iter().map(|d| d.position_m).collect();
        SceneGraph::delaunay(&positions).unwrap()
    }

    /// An observation of `objects` (id, world position) from `pose`, exact.
    fn sensed(
        ego: &str,
        pose: Pose2,
        objects: &[(Option<&str>, Vec2)],
    ) -> (Observation, ObservationTruth) {
        let class = crate::traffic::ObjectClass::Car;
        let obs = Observation {
            ego_id: ego.into(),
            detections: objects
                .iter()
                .map(|(_, w)| testkit::detection(pose.to_body(w), class, [0.5; 3]))
                .collect(),
        };
        let truth = ObservationTruth {
            ego_pose: pose,
            detections: objects
                .iter()
                .map(|(id, w)| DetectionTruth {
                    object_id: id.map(str::to_owned),
                    position_m: id.map(|_| *w),
                    visible_fraction: 1.0,
                    sender: false,
                })
                .collect(),
        };
        (obs, truth)
    }

    fn corr(a: usize, b: usize) -> Correspondence {
        Correspondence {
            a,
            b,
            probability: 1.0,
            uncertainty: 0.0,
        }
    }

    #[test]
    fn precision_recall_f1() {
        let z = Vec2::zeros();
        let (_, first) = sensed(
            "a",
            Pose2::identity(),
            &[(Some("x"), z), (Some("y"), z), (None, z)],
        );
        let (_, second) = sensed(
            "b",
            Pose2::identity(),
            &[(Some("y"), z), (Some("x"), z), (Some("z"), z)],
        );
        let c = count_pairs(&first, &second, &[corr(0, 1), corr(1, 2), corr(2, 0)]);
        assert_eq!(
            c,
            PairCounts {
                identified: 3,
                correct: 1,
                ground_truth: 2
            }
        );
        assert!((c.precision() - 1.0 / 3.0).abs() < 1e-12);
        assert!((c.recall() - 0.5).abs() < 1e-12);
        assert!((c.f1() - 0.4).abs() < 1e-12);
        // Nothing identified: precision undefined (not 1), recall and F1 0.
        let none = count_pairs(&first, &second, &[]);
        assert!(none.precision().is_nan());
        assert_eq!(none.recall(), 0.0);
        assert_eq!(none.f1(), 0.0);
        assert!(PairCounts::default().f1().is_nan());
    }

    /// The same counts and, per fusion variant, the same estimates of the
    /// same objects (in any order).
    fn assert_same_evaluation(x: &MethodEval, y: &MethodEval) {
        let method = x.method;
        assert_eq!(x.counts, y.counts, "{method:?}");
        assert!(x.counts.identified > 0);
        for ((v, ex), (w, ey)) in x.fused.iter().zip(&y.fused) {
            assert_eq!(v, w);
            let key = |e: &ObjectEstimate| (e.ego_id.clone(), e.object_id.clone());
            let (mut ex, mut ey) = (ex.clone(), ey.clone());
            ex.sort_by_key(key);
            ey.sort_by_key(key);
            assert_eq!(ex.len(), ey.len());
            for (p, q) in ex.iter().zip(&ey) {
                assert_eq!(
                    (key(p), p.matched, p.match_correct),
                    (key(q), q.matched, q.match_correct)
                );
                assert!((p.fused_m - q.fused_m).norm() < 1e-9, "{method:?} {v:?}");
                assert!((p.single_m - q.single_m).norm() < 1e-12);
            }
        }
    }

    /// A learning-free method as the pipeline builds it (canonical order,
    /// two rounds of match-align-rematch).
    fn built(method: Method) -> Runner {
        let settings = crate::matching::MatchingSettings {
            methods: vec![],
            gate_chi2: 9.21,
            models_dir: std::path::PathBuf::new(),
            mc_samples: 20,
            lambda: crate::matching::LambdaChoice::Fixed(0.7),
            decision: crate::matching::DecisionChoice::Validated,
            uncertainty: crate::matching::deep::decision::UncertaintyKind::Total,
            sender_as_node: false,
            multi_vehicle: MultiVehicle::Pairwise,
            rematch: 2,
        };
        let choice = crate::matching::DeepChoice {
            lambda: 0.7,
            decision: crate::matching::deep::decision::Decision::Assignment,
            temperature: 1.0,
        };
        Runner::Matcher(crate::matching::build(method, &settings, choice, 1, None).unwrap())
    }

    /// Permuting one vehicle's detections (with its truth and graph)
    /// changes no count and no estimate of any method, fusion variant
    /// included: under GPS error, with look-alikes and objects only one
    /// vehicle sees, and match-align-rematch on.
    #[test]
    fn permuting_one_vehicles_detections_changes_no_count_and_no_estimate() {
        let pa = Pose2::new(Vec2::new(0.0, 0.0), 0.3);
        let pb = Pose2::new(Vec2::new(40.0, 12.0), 2.6);
        let mut objects: Vec<(Option<&str>, Vec2)> = ["p", "q", "r", "s", "t", "u", "v"]
            .iter()
            .enumerate()
            .map(|(k, id)| {
                (
                    Some(*id),
                    Vec2::new(12.0 + 4.0 * k as f64, (k as f64 * 1.7).sin() * 6.0),
                )
            })
            .collect();
        let (oa, ta) = sensed("a", pa, &objects[..6]);
        objects.push((None, Vec2::new(25.0, 9.0)));
        let (ob, tb) = sensed("b", pb, &objects[1..]);
        let order = [3, 0, 6, 1, 5, 2, 4];
        let (ob2, tb2) = (
            Observation {
                ego_id: ob.ego_id.clone(),
                detections: order.iter().map(|&k| ob.detections[k].clone()).collect(),
            },
            ObservationTruth {
                ego_pose: tb.ego_pose,
                detections: order.iter().map(|&k| tb.detections[k].clone()).collect(),
            },
        );
        let (ga, gb, gb2) = (graph(&oa), graph(&ob), graph(&ob2));
        let gps =
            |p: Pose2, dx: f64| Pose2::new(p.position_m() + Vec2::new(dx, -0.7), p.heading_rad());
        let level = exact_view(&oa, &ga, pa).pose_noise;
        let first = Side {
            view: exact_view(&oa, &ga, gps(pa, 0.4)),
            obs: &oa,
            truth: &ta,
        };
        let second = |obs, truth, graph| Side {
            view: exact_view(obs, graph, gps(pb, -1.1)),
            obs,
            truth,
        };
        let pair = |second| PairAtLevel {
            instance: 0,
            first,
            second,
            level,
        };
        let (before, after) = (pair(second(&ob, &tb, &gb)), pair(second(&ob2, &tb2, &gb2)));
        let fusion = FusionSettings {
            variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
            align_min_matches: 3,
        };
        for runner in [
            built(Method::GpsAppHungarian),
            built(Method::Mogm),
            Runner::Oracle,
        ] {
            let (x, y) = (
                evaluate(&before, &runner, &fusion),
                evaluate(&after, &runner, &fusion),
            );
            assert_same_evaluation(&x, &y);
        }
    }

    #[test]
    fn zero_noise_gives_zero_error_single_and_fused_and_the_oracle_is_perfect() {
        // Two egos with exact measurements and exact poses.
        let pa = Pose2::new(Vec2::new(0.0, 0.0), 0.3);
        let pb = Pose2::new(Vec2::new(30.0, 10.0), 2.0);
        let objects = [
            (Some("x"), Vec2::new(15.0, 8.0)),
            (Some("y"), Vec2::new(20.0, -2.0)),
            (Some("z"), Vec2::new(10.0, 15.0)),
        ];
        let (oa, ta) = sensed("a", pa, &objects);
        let (ob, tb) = sensed("b", pb, &objects);
        let (ga, gb) = (graph(&oa), graph(&ob));
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::None,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
        };
        fn view<'a>(obs: &'a Observation, graph: &'a SceneGraph, pose: Pose2) -> MatchView<'a> {
            MatchView {
                detections: &obs.detections,
                graph,
                pose_reported: pose,
                pose_noise: PoseNoiseLevel {
                    label: PoseNoiseLabel::None,
                    position_sigma_m: 0.0,
                    heading_sigma_rad: 0.0,
                },
            }
        }
        let pair = PairAtLevel {
            instance: 0,
            first: Side {
                view: view(&oa, &ga, pa),
                obs: &oa,
                truth: &ta,
            },
            second: Side {
                view: view(&ob, &gb, pb),
                obs: &ob,
                truth: &tb,
            },
            level,
        };
        let fusion = FusionSettings {
            variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
            align_min_matches: 3,
        };
        let e = evaluate(&pair, &Runner::Oracle, &fusion);
        assert_eq!(
            (e.counts.correct, e.counts.identified, e.counts.ground_truth),
            (3, 3, 3)
        );
        assert_eq!(e.fused.len(), 2);
        for (_, est) in &e.fused {
            assert_eq!(est.len(), 6);
            for x in est {
                assert!(
                    x.single_error_m() < 1e-9 && x.fused_error_m() < 1e-9,
                    "{x:?}"
                );
                assert!(x.match_correct);
            }
        }
    }

    /// A matcher that returns fixed pairs (for property tests).
    struct Fixed(Vec<Correspondence>);

    impl Matcher for Fixed {
        fn method(&self) -> Method {
            Method::Mogm
        }
        fn identify_with(
            &self,
            _: &MatchView,
            _: &MatchView,
            _: &crate::fusion::PoseEstimate,
        ) -> Identification {
            Identification::plain(self.0.clone())
        }
    }

    fn exact_view<'a>(obs: &'a Observation, graph: &'a SceneGraph, pose: Pose2) -> MatchView<'a> {
        MatchView {
            detections: &obs.detections,
            graph,
            pose_reported: pose,
            pose_noise: PoseNoiseLevel {
                label: PoseNoiseLabel::Gps,
                position_sigma_m: 1.2,
                heading_sigma_rad: 0.0035,
            },
        }
    }

    /// Connected vehicles of a hand-made frame (exact views at GPS level).
    struct TestFrame {
        sensed: Vec<(Observation, ObservationTruth)>,
        graphs: Vec<SceneGraph>,
        poses: Vec<Pose2>,
    }

    impl TestFrame {
        fn new(sensed: Vec<(Observation, ObservationTruth)>, poses: &[Pose2]) -> Self {
            let graphs = sensed
                .iter()
                .map(|(o, _)| {
                    let positions: Vec<Vec2> = o.detections.iter().map(|d| d.position_m).collect();
                    SceneGraph::delaunay(&positions).unwrap()
                })
                .collect();
            Self {
                sensed,
                graphs,
                poses: poses.to_vec(),
            }
        }

        fn side(&self, k: usize) -> Side<'_> {
            Side {
                view: exact_view(&self.sensed[k].0, &self.graphs[k], self.poses[k]),
                obs: &self.sensed[k].0,
                truth: &self.sensed[k].1,
            }
        }

        /// (0, 1), (0, 2), (1, 2), ...: every pair, as a frame lists them.
        fn every_pair(&self) -> Vec<PairAtLevel<'_>> {
            let n = self.sensed.len();
            (0..n)
                .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
                .map(|(i, j)| self.pair(i, j))
                .collect()
        }

        fn pair(&self, i: usize, j: usize) -> PairAtLevel<'_> {
            let (first, second) = (self.side(i), self.side(j));
            PairAtLevel {
                instance: 0,
                first,
                second,
                level: first.view.pose_noise,
            }
        }
    }

    /// Pairs by the reported x position of the two egos: (a, b) and
    /// (b, c) right and confident, (a, c) crossed and less sure.
    struct Contradicting;

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
            Identification::plain(if xs == (0.0, 20.0) {
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

    fn paper_fusion() -> FusionSettings {
        FusionSettings {
            variants: vec![FusionVariant::Paper],
            align_min_matches: 3,
        }
    }

    #[test]
    fn a_contradictory_triple_is_counted_and_synchronisation_resolves_it() {
        let frame = three_in_a_row();
        let pairs = frame.every_pair();
        let fusion = paper_fusion();
        let runner = Runner::Matcher(Box::new(Contradicting));
        let pairwise = evaluate_frame(&pairs, &runner, &fusion, MultiVehicle::Pairwise);
        // As decided: (a, c) wrong, so every chain through b is broken;
        // the closure puts all six detections into one object.
        let correct: Vec<usize> = pairwise.pairs.iter().map(|e| e.counts.correct).collect();
        assert_eq!(correct, [2, 0, 2]);
        let t = pairwise.consistency.triples;
        assert_eq!((t.chains, t.inconsistent), (6, 6));
        let o = pairwise.consistency.objects;
        assert_eq!((o.identified, o.correct, o.ground_truth), (12, 6, 6));
        // Synchronised: the weak crossed pairs lose, (a, c) is implied by
        // the chains through b with probability 0.9 * 0.9.
        let synced = evaluate_frame(&pairs, &runner, &fusion, MultiVehicle::Synchronized);
        let correct: Vec<usize> = synced.pairs.iter().map(|e| e.counts.correct).collect();
        assert_eq!(correct, [2, 2, 2]);
        let ac = &synced.pairs[1].identification.matches;
        assert_eq!(
            ac.iter().map(|c| (c.a, c.b)).collect::<Vec<_>>(),
            [(0, 0), (1, 1)]
        );
        assert!((ac[0].probability - 0.81).abs() < 1e-12);
        let t = synced.consistency.triples;
        assert_eq!((t.chains, t.inconsistent), (6, 0));
        let o = synced.consistency.objects;
        assert_eq!((o.identified, o.correct, o.ground_truth), (6, 6, 6));
        // Fused from the consistent matches: exact views, exact result.
        for e in &synced.pairs {
            for x in &e.fused[0].1 {
                assert!(x.match_correct && x.fused_error_m() < 1e-9, "{x:?}");
            }
        }
    }

    /// [`Contradicting`], counting its calls.
    struct Counted(std::sync::Arc<std::sync::atomic::AtomicUsize>);

    impl Matcher for Counted {
        fn method(&self) -> Method {
            Method::Mogm
        }
        fn identify_with(
            &self,
            first: &MatchView,
            second: &MatchView,
            relative: &crate::fusion::PoseEstimate,
        ) -> Identification {
            self.0.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Contradicting.identify_with(first, second, relative)
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
        let calls = std::sync::Arc::default();
        let runner = Runner::Matcher(Box::new(Counted(std::sync::Arc::clone(&calls))));
        let map = evaluate_frame(&pairs, &runner, &fusion, MultiVehicle::Map);
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), 2);
        let correct: Vec<usize> = map.pairs.iter().map(|e| e.counts.correct).collect();
        assert_eq!(correct, [2, 2, 2]);
        let t = map.consistency.triples;
        assert_eq!((t.chains, t.inconsistent), (6, 0));
        let o = map.consistency.objects;
        assert_eq!((o.identified, o.correct, o.ground_truth), (6, 6, 6));
        // Joins are with each object's first detection (a's): (a, c) at
        // c's own probability, (b, c) through a.
        let p = |k: usize| map.pairs[k].identification.matches[0].probability;
        assert!((p(1) - 0.9).abs() < 1e-12 && (p(2) - 0.81).abs() < 1e-12);
        // The oracle finds every pair through the map, too.
        let oracle = evaluate_frame(&pairs, &Runner::Oracle, &fusion, MultiVehicle::Map);
        for e in &oracle.pairs {
            assert_eq!((e.counts.correct, e.counts.identified), (2, 2));
        }
    }

    #[test]
    fn fusion_from_every_view_reduces_to_the_pair_for_two_vehicles() {
        let objects = [
            (Some("x"), Vec2::new(5.0, 8.0)),
            (Some("y"), Vec2::new(12.0, -3.0)),
            (Some("z"), Vec2::new(-4.0, 6.0)),
        ];
        let poses = [(0.0, 0.1), (15.0, 2.0), (-10.0, -1.2)]
            .map(|(x, h)| Pose2::new(Vec2::new(x, -12.0), h));
        // Measurements off by a different vector for every detection.
        let sensed: Vec<(Observation, ObservationTruth)> = ["a", "b", "c"]
            .iter()
            .zip(&poses)
            .enumerate()
            .map(|(v, (id, p))| {
                let (mut obs, truth) = sensed(id, *p, &objects);
                for (k, d) in obs.detections.iter_mut().enumerate() {
                    let t = (3 * v + k) as f64;
                    d.position_m += Vec2::new(0.4 * t.sin(), 0.3 * t.cos());
                }
                (obs, truth)
            })
            .collect();
        let frame = TestFrame::new(sensed, &poses);
        let pair = |i: usize, j: usize| frame.pair(i, j);
        let fusion = FusionSettings {
            variants: vec![FusionVariant::Paper],
            align_min_matches: 3,
        };
        // Two vehicles: every view estimate is the pairwise one.
        let two = evaluate_frame(
            &[pair(0, 1)],
            &Runner::Oracle,
            &fusion,
            MultiVehicle::Pairwise,
        );
        let views = &two.views[0].1;
        assert_eq!(views.len(), 6);
        for v in views {
            assert_eq!((v.views, v.seen_by), (2, 2));
            assert_eq!(v.fused_error_m, v.pairwise_error_m, "{v:?}");
            assert!(v.fused_error_m < v.single_error_m + 0.3);
        }
        // Three vehicles: each ego fuses all three measurements, which is
        // the fusion of the three moved into the world frame.
        let three = [pair(0, 1), pair(0, 2), pair(1, 2)];
        let all = evaluate_frame(&three, &Runner::Oracle, &fusion, MultiVehicle::Pairwise);
        let views = &all.views[0].1;
        assert_eq!(views.len(), 9);
        for v in views {
            assert_eq!((v.views, v.seen_by), (3, 3));
            let k = objects
                .iter()
                .position(|o| o.0 == Some(v.object_id.as_str()))
                .unwrap();
            let world: Vec<Measurement> = (0..3)
                .map(|u| measured(&frame.sensed[u].0, k).moved(&poses[u]))
                .collect();
            let expected = (fuse(&world).unwrap().position_m - objects[k].1).norm();
            assert!(
                (v.fused_error_m - expected).abs() < 1e-9,
                "{v:?} vs {expected}"
            );
            assert!(v.fused_error_m != v.pairwise_error_m);
        }
    }

    proptest::proptest! {
        /// Whatever a method pairs, the object set of the displacement
        /// error (every real object an ego detects) and its single-vehicle
        /// estimates are the same; unmatched objects keep their single
        /// estimate as the fused one.
        #[test]
        fn the_object_set_does_not_depend_on_the_method(
            seen_a in proptest::collection::vec(proptest::bool::ANY, 6),
            seen_b in proptest::collection::vec(proptest::bool::ANY, 6),
            shuffle in proptest::collection::vec(0usize..100, 13),
        ) {
            let world: Vec<(Option<&str>, Vec2)> = ["o0", "o1", "o2", "o3", "o4", "o5"]
                .iter()
                .enumerate()
                .map(|(k, id)| (Some(*id), Vec2::new(10.0 + 4.0 * k as f64, (k as f64 * 1.7).sin() * 9.0)))
                .chain([(None, Vec2::new(25.0, 30.0))]) // a false positive
                .collect();
            let pick = |seen: &[bool]| -> Vec<(Option<&str>, Vec2)> {
                world.iter().enumerate().filter(|(k, _)| *k == 6 || seen[*k]).map(|(_, o)| *o).collect()
            };
            let (pa, pb) = (Pose2::new(Vec2::zeros(), 0.2), Pose2::new(Vec2::new(50.0, 5.0), 2.9));
            let (oa, ta) = sensed("a", pa, &pick(&seen_a));
            let (ob, tb) = sensed("b", pb, &pick(&seen_b));
            let (ga, gb) = (graph(&oa), graph(&ob));
            let pair = PairAtLevel {
                instance: 0,
                first: Side { view: exact_view(&oa, &ga, pa), obs: &oa, truth: &ta },
                second: Side { view: exact_view(&ob, &gb, pb), obs: &ob, truth: &tb },
                level: exact_view(&oa, &ga, pa).pose_noise,
            };
            // A random one-to-one matching, right or wrong.
            let (n, m) = (oa.detections.len(), ob.detections.len());
            let mut cols: Vec<usize> = (0..m).collect();
            for (k, &r) in shuffle.iter().enumerate().take(m) {
                cols.swap(k, r % m);
            }
            let random: Vec<Correspondence> = (0..n.min(m))
                .filter(|i| shuffle[i + 6] % 3 != 0)
                .map(|i| corr(i, cols[i]))
                .collect();
            let fusion = FusionSettings {
                variants: vec![FusionVariant::Paper, FusionVariant::Aligned],
                align_min_matches: 2,
            };
            let runners = [Runner::Oracle, Runner::Matcher(Box::new(Fixed(vec![]))), Runner::Matcher(Box::new(Fixed(random)))];
            let sets: Vec<Vec<(String, String, bool, Vec2)>> = runners
                .iter()
                .flat_map(|r| evaluate(&pair, r, &fusion).fused)
                .map(|(_, est)| {
                    for e in &est {
                        if !e.matched {
                            proptest::prop_assert_eq!(e.fused_m, e.single_m);
                        }
                    }
                    Ok(est.into_iter().map(|e| (e.ego_id, e.object_id, e.covisible, e.single_m)).collect())
                })
                .collect::<Result<_, _>>()?;
            let real = |seen: &[bool]| seen.iter().filter(|s| **s).count();
            proptest::prop_assert_eq!(sets[0].len(), real(&seen_a) + real(&seen_b));
            for s in &sets[1..] {
                proptest::prop_assert_eq!(s, &sets[0]);
            }
        }
    }
}
