//! The published networks on synthetic scenes: graphs matched to rigidly
//! moved copies of themselves (held out from training), and a mirrored
//! chain that psi_1 alone cannot resolve but consensus can.

use rand::Rng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

use super::published_net::{PublishedNet, draw_masks};
use super::spline::GraphTensors;
use super::weights::{module_bytes as to_bytes, published_from_bytes as from_bytes};
use crate::geometry::{Pose2, Vec2};
use crate::graph::SceneGraph;
use crate::matching::deep::arch::{Backbone, LossTerms, MaskScope, PairLoss};
use crate::matching::deep::arch::{PublishedConfig, PublishedKind};
use crate::matching::deep::cost::published_macs;
use crate::matching::deep::decision::MatchDistribution;
use crate::matching::deep::graph::LengthGraph;
use crate::matching::deep::mc::{Inference, McMatcher};
use crate::matching::deep::published::Published;
use crate::matching::deep::train::init::Init;
use crate::matching::deep::train::published::{PublishedTrainer, TrainPair};
use crate::matching::testkit::detection;
use crate::matching::testkit::{self, GPS, Side};
use crate::matching::{Matcher, Method};
use crate::rng::{self, Purpose};
use crate::sensor::Detection;
use crate::traffic::ObjectClass;

/// A few appearances, so that look-alikes are common and structure counts.
const PALETTE: [(ObjectClass, [f64; 3]); 6] = [
    (ObjectClass::Car, [0.95, 0.95, 0.95]),
    (ObjectClass::Car, [0.1, 0.1, 0.1]),
    (ObjectClass::Car, [0.7, 0.1, 0.1]),
    (ObjectClass::Truck, [0.9, 0.9, 0.9]),
    (ObjectClass::Pedestrian, [0.2, 0.2, 0.6]),
    (ObjectClass::Bicycle, [0.7, 0.1, 0.1]),
];

fn stream(part: &str) -> ChaCha8Rng {
    rng::stream(33, Purpose::Training, &[rng::hash_str(part)])
}

fn object(rng: &mut ChaCha8Rng, at: Vec2) -> Detection {
    let (class, colour) = PALETTE[rng.random_range(0..PALETTE.len())];
    detection(at, class, colour)
}

/// Points in a disc of 40 m, at least 4 m apart.
fn scatter(rng: &mut ChaCha8Rng, n: usize, near: &[Vec2]) -> Vec<Vec2> {
    let mut out: Vec<Vec2> = Vec::new();
    while out.len() < n {
        let (r, a) = (
            40.0 * rng.random::<f64>().sqrt(),
            rng.random_range(0.0..2.0 * PI),
        );
        let p = Vec2::new(r * a.cos(), r * a.sin());
        if near.iter().chain(&out).all(|q| (p - q).norm() > 4.0) {
            out.push(p);
        }
    }
    out
}

/// The second vehicle's view of `objects`: `kept` of them (indices) and
/// `extra` detections it alone sees, all moved by one random rigid motion
/// (a new body frame), listed in a random order; with the true partner of
/// each object. An exact copy (everything kept, nothing added) keeps the
/// first graph's edges (a rigid motion leaves a Delaunay triangulation as
/// it is; recomputed, rounding could flip the edges of a degenerate one,
/// collinear points or cocircular quadruples).
fn moved_copy(
    rng: &mut ChaCha8Rng,
    objects: &[Detection],
    kept: &[usize],
    extra: Vec<Detection>,
) -> TrainPair {
    let frame = Pose2::new(
        Vec2::new(rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0)),
        rng.random_range(-PI..PI),
    );
    let exact = extra.is_empty() && kept.len() == objects.len();
    let mut seen: Vec<(Option<usize>, Detection)> = kept
        .iter()
        .map(|&k| (Some(k), objects[k].clone()))
        .chain(extra.into_iter().map(|d| (None, d)))
        .collect();
    seen.shuffle(rng);
    let order: Vec<usize> = seen.iter().map(|(k, _)| k.unwrap_or(0)).collect();
    let mut partner = vec![None; objects.len()];
    let second: Vec<Detection> = seen
        .into_iter()
        .enumerate()
        .map(|(j, (k, mut d))| {
            if let Some(k) = k {
                partner[k] = Some(j);
            }
            d.position_m = frame.to_parent(&d.position_m);
            d
        })
        .collect();
    let first = LengthGraph::delaunay(objects).unwrap();
    let second = if exact {
        let positions: Vec<Vec2> = objects.iter().map(|d| d.position_m).collect();
        let mut graph = SceneGraph::delaunay(&positions).unwrap().permuted(&order);
        graph.positions_m = second.iter().map(|d| d.position_m).collect();
        LengthGraph::lengths(
            &second,
            &graph,
            crate::matching::deep::arch::NetworkGraph::Delaunay,
            crate::sensor::AppearanceWidth::NONE,
        )
    } else {
        LengthGraph::delaunay(&second).unwrap()
    };
    TrainPair {
        first,
        second,
        partner,
    }
}

/// The soft assignments of an untrained network: one `(n1 + 1) x (n2 +
/// 1)` matrix per sample whose real rows and columns sum to 1, different
/// samples under MC dropout, the same bytes from the same seed and stream,
/// and everything in the dustbins when a side has no detection.
#[test]
fn assignments_are_per_sample_doubly_stochastic_with_dustbins() {
    let mut rng = stream("random scenes");
    let p = random_pair(&mut rng, 2);
    let (n1, n2) = (p.first.n, p.second.n);
    for cfg in [PublishedConfig::new(PublishedKind::GcnGm), dgmc()] {
        let net = PublishedNet::new(
            &cfg,
            Init::Seeded(1),
            &crate::matching::deep::train::backend::device(),
        );
        let draw = |mc_dropout: bool| {
            let sampling = Sampling {
                samples: 3,
                mc_dropout,
            };
            sample_assignments(
                &net,
                &cfg,
                [&p.first, &p.second],
                sampling,
                &mut stream("s"),
            )
        };
        let s = draw(true);
        assert_eq!(s.len(), 3);
        for m in &s {
            assert_eq!(m.len(), (n1 + 1) * (n2 + 1));
            for i in 0..n1 {
                let row: f32 = m[i * (n2 + 1)..(i + 1) * (n2 + 1)].iter().sum();
                assert!((row - 1.0).abs() < 1e-3, "row {i}: {row}");
            }
            for j in 0..n2 {
                let col: f32 = (0..=n1).map(|i| m[i * (n2 + 1) + j]).sum();
                assert!((col - 1.0).abs() < 1e-3, "column {j}: {col}");
            }
        }
        assert_ne!(s[0], s[1], "MC dropout samples differ");
        assert_eq!(s, draw(true), "same stream, same samples");
        let again = PublishedNet::new(
            &cfg,
            Init::Seeded(1),
            &crate::matching::deep::train::backend::device(),
        );
        assert_eq!(to_bytes(&net).unwrap(), to_bytes(&again).unwrap());
        let loaded = from_bytes(
            &cfg,
            &to_bytes(&net).unwrap(),
            &crate::matching::deep::train::backend::device(),
        )
        .unwrap();
        let sampling = Sampling {
            samples: 2,
            mc_dropout: true,
        };
        let pair = [&p.first, &p.second];
        assert_eq!(
            sample_assignments(&loaded, &cfg, pair, sampling, &mut stream("s")),
            sample_assignments(&net, &cfg, pair, sampling, &mut stream("s")),
        );
        let empty = LengthGraph::delaunay(&[]).unwrap();
        let none = sample_assignments(&net, &cfg, [&p.first, &empty], sampling, &mut rng);
        let d = MatchDistribution::from_samples(n1, 0, &none);
        assert!(d.decide(None).is_empty());
        assert!((0..n1).all(|i| none[0][i] == 1.0));
    }
}

/// What the networks see of a scene does not change when the body frame
/// moves: node attributes and edge lengths of a rigidly moved copy are
/// those of the original (up to rounding).
#[test]
fn paper_graphs_are_invariant_to_rigid_motions() {
    let mut rng = stream("random scenes");
    let objects: Vec<Detection> = scatter(&mut rng, 12, &[])
        .into_iter()
        .map(|p| object(&mut rng, p))
        .collect();
    let frame = Pose2::new(Vec2::new(-17.0, 40.0), 2.1);
    let moved: Vec<Detection> = objects
        .iter()
        .map(|d| Detection {
            position_m: frame.to_parent(&d.position_m),
            ..d.clone()
        })
        .collect();
    let (a, b) = (
        LengthGraph::delaunay(&objects).unwrap(),
        LengthGraph::delaunay(&moved).unwrap(),
    );
    assert_eq!(a.node_features, b.node_features);
    assert_eq!((&a.src, &a.dst), (&b.src, &b.dst));
    for ([x], [y]) in a.edge_m.iter().zip(&b.edge_m) {
        assert!((x - y).abs() < 1e-4, "{x} vs {y}");
    }
}

/// A random scene of 10-14 objects and a rigidly moved copy with `changed`
/// of them dropped and as many others added.
fn random_pair(rng: &mut ChaCha8Rng, changed: usize) -> TrainPair {
    let n = rng.random_range(10..=14);
    let objects: Vec<Detection> = scatter(rng, n, &[])
        .into_iter()
        .map(|p| object(rng, p))
        .collect();
    let mut kept: Vec<usize> = (0..n).collect();
    kept.shuffle(rng);
    kept.truncate(n - changed);
    let positions: Vec<Vec2> = objects.iter().map(|d| d.position_m).collect();
    let extra = scatter(rng, changed, &positions)
        .into_iter()
        .map(|p| object(rng, p))
        .collect();
    moved_copy(rng, &objects, &kept, extra)
}

/// A chain along x, `spacing_m` apart: `arm` look-alikes (`filler`), the
/// anchors `a` and `b`, `arm` look-alikes again. Mirror images of each
/// other but for the anchors: psi_1 sees two hops, so the look-alikes more
/// than two hops from both anchors have the same embedding as their mirror
/// images (only the anchors, further away, tell them apart).
fn mirrored_chain(spacing_m: f64, arm: usize, [a, b, filler]: [usize; 3]) -> Vec<Detection> {
    (0..2 * arm + 2)
        .map(|k| {
            let look = match k {
                k if k == arm => a,
                k if k == arm + 1 => b,
                _ => filler,
            };
            let (class, colour) = PALETTE[look];
            detection(Vec2::new(spacing_m * k as f64, 0.0), class, colour)
        })
        .collect()
}

/// A random mirrored chain and its rigidly moved copy.
fn chain_pair(rng: &mut ChaCha8Rng) -> TrainPair {
    let mut looks: Vec<usize> = (0..PALETTE.len()).collect();
    looks.shuffle(rng);
    let chain = mirrored_chain(
        rng.random_range(8.0..14.0),
        rng.random_range(2..=4),
        [looks[0], looks[1], looks[2]],
    );
    let all: Vec<usize> = (0..chain.len()).collect();
    moved_copy(rng, &chain, &all, Vec::new())
}

fn trained(cfg: PublishedConfig, pairs: &[TrainPair], epochs: usize) -> PublishedNet {
    trained_with(PublishedTrainer::new(cfg, 7), pairs, epochs)
}

fn trained_with(mut trainer: PublishedTrainer, pairs: &[TrainPair], epochs: usize) -> PublishedNet {
    let cfg = trainer.cfg;
    let losses = trainer.fit(pairs, epochs, 8, 1e-3).unwrap();
    eprintln!("{:?}: losses {:?}", cfg.kind, losses);
    assert!(losses.last() < losses.first(), "{losses:?}");
    trainer.network()
}

/// The mean assignment over `samples` samples, `(n1 + 1) x (n2 + 1)`.
fn mean_assignment(net: &PublishedNet, cfg: &PublishedConfig, p: &TrainPair) -> MatchDistribution {
    let mut rng = stream("inference");
    let sampling = Sampling {
        samples: 8,
        mc_dropout: false,
    };
    let s = sample_assignments(net, cfg, [&p.first, &p.second], sampling, &mut rng);
    MatchDistribution::from_samples(p.first.n, p.second.n, &s)
}

/// Of the true pairs, the share the decision code finds; and the number
/// of pairs it makes that are wrong.
fn accuracy(d: &MatchDistribution, p: &TrainPair) -> (f64, usize) {
    let decided = d.decide(None);
    let right = decided
        .iter()
        .filter(|c| p.partner[c.a] == Some(c.b))
        .count();
    let truth = p.partner.iter().flatten().count();
    (right as f64 / truth as f64, decided.len() - right)
}

/// The mean accuracy and the wrong pairs over `tests` held-out scenes
/// with `changed` objects dropped and as many added.
fn held_out(net: &PublishedNet, cfg: &PublishedConfig, changed: usize) -> (f64, usize) {
    let mut rng = stream("held-out scenes");
    let (mut acc, mut wrong, tests) = (0.0, 0, 8);
    for _ in 0..tests {
        let p = random_pair(&mut rng, changed);
        let (a, w) = accuracy(&mean_assignment(net, cfg, &p), &p);
        (acc, wrong) = (acc + a / f64::from(tests), wrong + w);
    }
    (acc, wrong)
}

/// Trains `cfg` on random scenes (rigidly moved copies with 2 objects
/// dropped and 2 added), then matches held-out scenes to their rigidly
/// moved copies: exact ones (every object kept, listed in another order)
/// almost perfectly, and ones with 2 objects dropped and 2 added (every
/// node whose neighbourhood that changes sees another graph) mostly right,
/// with few wrong pairs.
fn matches_rigidly_moved_copies(cfg: PublishedConfig) {
    let mut rng = stream("random scenes");
    let pairs: Vec<TrainPair> = (0..128).map(|_| random_pair(&mut rng, 2)).collect();
    let net = trained(cfg, &pairs, 30);
    let (exact, exact_wrong) = held_out(&net, &cfg, 0);
    let (partial, partial_wrong) = held_out(&net, &cfg, 2);
    eprintln!(
        "{:?}: accuracy on exact copies {exact:.3} ({exact_wrong} wrong pairs), \
         with 2 dropped and 2 added {partial:.3} ({partial_wrong} wrong pairs)",
        cfg.kind
    );
    assert!(exact >= 0.95 && exact_wrong <= 2, "{exact} {exact_wrong}");
    assert!(
        partial >= 0.8 && partial_wrong <= 12,
        "{partial} {partial_wrong}"
    );
}

/// The paper's Eq. 11 as the pair term (`[train] loss = "paper"`, which
/// reaches the paper's method on DGMC's network) trains GCN-GM's network
/// to find the true pairs of moved copies (no "no match" labels: the
/// wrong pairs of unpartnered nodes are L_non's and the threshold's).
#[test]
fn eq_11_trains_a_published_network_to_match_moved_copies() {
    let cfg = PublishedConfig::new(PublishedKind::GcnGm);
    let terms = LossTerms {
        pairs: PairLoss::Paper,
        non: false,
        unc: false,
    };
    let trainer = PublishedTrainer::with_terms(cfg, terms, 1, MaskScope::PerNode, 7, "eq11");
    let mut rng = stream("random scenes");
    let pairs: Vec<TrainPair> = (0..128).map(|_| random_pair(&mut rng, 2)).collect();
    let net = trained_with(trainer, &pairs, 30);
    let (exact, _) = held_out(&net, &cfg, 0);
    let (partial, _) = held_out(&net, &cfg, 2);
    eprintln!(
        "Eq. 11: accuracy on exact copies {exact:.3}, with 2 dropped and 2 added {partial:.3}"
    );
    assert!(exact >= 0.95 && partial >= 0.8, "{exact} {partial}");
}

#[test]
fn gcn_gm_matches_rigidly_moved_copies() {
    matches_rigidly_moved_copies(PublishedConfig::new(PublishedKind::GcnGm));
}

/// DGMC with 3 consensus steps (10 in DGMC's experiments) to keep the test
/// fast.
fn dgmc() -> PublishedConfig {
    PublishedConfig {
        consensus_steps: 3,
        ..PublishedConfig::new(PublishedKind::Dgmc)
    }
}

#[test]
fn dgmc_matches_rigidly_moved_copies() {
    matches_rigidly_moved_copies(dgmc());
}

/// `S_0` of one pair, one sample without dropout, `(n1 + 1) x (n2 + 1)`.
fn initial_assignment(net: &PublishedNet, cfg: &PublishedConfig, p: &TrainPair) -> Vec<f32> {
    let device = crate::matching::deep::train::backend::device();
    let g1 = GraphTensors::lengths(&[&p.first], cfg.edge_scale_m, &device);
    let g2 = GraphTensors::lengths(&[&p.second], cfg.edge_scale_m, &device);
    let shape = [1, 1, p.first.n, p.second.n];
    let masks = draw_masks(&mut stream("initial"), cfg, shape, false, &device);
    let s0 = net.forward(cfg, [&g1, &g2], masks).initial.exp();
    s0.try_into_vec_as::<f32>().unwrap()
}

/// A mirrored chain (3 look-alikes, two different anchors, 3 look-alikes)
/// matched to a rigidly moved copy of itself. The two ends are three hops
/// from the anchors: psi_1 (two layers) gives each end the embedding of the
/// other, so `S_0` splits each end evenly between its partner and its
/// mirror image, in GCN-GM and in DGMC's own psi_1 alike, however either
/// was trained. Their neighbours are told apart (two hops from an
/// anchor); DGMC's consensus pushes indicator functions through those
/// correspondences and must resolve the ends. Both networks are trained on
/// the same random mirrored chains (arms of 2 to 4 look-alikes).
#[test]
fn dgmc_consensus_resolves_what_gcn_gm_cannot() {
    let mut rng = stream("chains");
    let pairs: Vec<TrainPair> = (0..96).map(|_| chain_pair(&mut rng)).collect();
    let gcn_cfg = PublishedConfig::new(PublishedKind::GcnGm);
    let gcn = trained(gcn_cfg, &pairs, 30);
    let dgmc_cfg = dgmc();
    let dgmc = trained(dgmc_cfg, &pairs, 30);
    let chain = mirrored_chain(10.5, 3, [3, 2, 0]);
    let all: Vec<usize> = (0..chain.len()).collect();
    let p = moved_copy(&mut stream("held-out chain"), &chain, &all, Vec::new());
    let partner = |i: usize| p.partner[i].unwrap();
    let ends = [0, chain.len() - 1];
    let mirror = |i: usize| chain.len() - 1 - i;
    let cols = p.second.n + 1;
    for (name, s0) in [
        ("GCN-GM", initial_assignment(&gcn, &gcn_cfg, &p)),
        ("DGMC's S_0", initial_assignment(&dgmc, &dgmc_cfg, &p)),
    ] {
        for i in ends {
            let (right, mirrored) = (s0[i * cols + partner(i)], s0[i * cols + partner(mirror(i))]);
            eprintln!("{name}: end {i}: {right:.3} to its partner, {mirrored:.3} to its mirror");
            assert!(
                (right - mirrored).abs() < 0.02 && right < 0.6,
                "{name} told end {i} apart"
            );
        }
    }
    let gcn_d = mean_assignment(&gcn, &gcn_cfg, &p);
    let decided = gcn_d.decide(None);
    for i in (0..chain.len()).filter(|i| !ends.contains(i)) {
        // Trained: everything but the ends is right.
        assert!(
            decided.iter().any(|c| (c.a, c.b) == (i, partner(i))),
            "GCN-GM node {i}"
        );
    }
    let d = mean_assignment(&dgmc, &dgmc_cfg, &p);
    for i in ends {
        let right = d.probability(i, partner(i));
        eprintln!("DGMC: end {i}: {right:.3} to its partner");
        assert!(right > 0.8, "DGMC end {i}: {right}");
    }
    let (acc, wrong) = accuracy(&d, &p);
    assert_eq!((acc, wrong), (1.0, 0), "DGMC on the whole chain");
}

/// How many samples to draw, and whether with MC dropout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Sampling {
    samples: usize,
    mc_dropout: bool,
}

/// The soft assignment of `first` to `second`, one per sample: each a
/// row-major `(n1 + 1) x (n2 + 1)` matrix of probabilities whose last row
/// and column are the dustbins, as
/// [`crate::matching::deep::decision::MatchDistribution::from_samples`]
/// takes them. Masks and indicators come from `rng`; the network should be
/// on a device without autodiff (`net.valid()`).
fn sample_assignments(
    net: &PublishedNet,
    cfg: &PublishedConfig,
    [first, second]: [&LengthGraph; 2],
    sampling: Sampling,
    rng: &mut ChaCha8Rng,
) -> Vec<Vec<f32>> {
    let (n1, n2, t) = (first.n, second.n, sampling.samples);
    if n1 == 0 || n2 == 0 {
        // Everything in the dustbins.
        let mut s = vec![0f32; (n1 + 1) * (n2 + 1)];
        (0..n1).for_each(|i| s[i * (n2 + 1) + n2] = 1.0);
        (0..n2).for_each(|j| s[n1 * (n2 + 1) + j] = 1.0);
        return vec![s; t];
    }
    let device = crate::matching::deep::train::backend::device();
    let g1 = GraphTensors::lengths(&[first], cfg.edge_scale_m, &device);
    let g2 = GraphTensors::lengths(&[second], cfg.edge_scale_m, &device);
    let masks = draw_masks(rng, cfg, [1, t, n1, n2], sampling.mc_dropout, &device);
    let p = net.forward(cfg, [&g1, &g2], masks).last().exp();
    let v: Vec<f32> = p.try_into_vec_as::<f32>().expect("f32 assignments");
    v.chunks_exact((n1 + 1) * (n2 + 1))
        .map(<[f32]>::to_vec)
        .collect()
}

/// A matcher counts what its network multiplies: a new pair as
/// `published_macs` counts it (masks per node: both embeddings and
/// the pair part), the same pair at another pose-noise level (kept)
/// nothing more; under shared masks a graph already embedded only
/// the pair part.
#[test]
fn a_matcher_counts_what_its_network_multiplies() {
    let Some(Backbone::Published(cfg)) = Method::Dgmc.backbone() else {
        panic!("DGMC is a published network");
    };
    let bytes = include_bytes!("../../../../models/dgmc.bpk");
    let objects = testkit::world_objects();
    let side = |at, order: &[usize]| Side::of(at, &objects, order, GPS);
    let (a, b) = (
        side(testkit::POSE_A, &[0, 1, 2, 3, 4, 5]),
        side(testkit::POSE_B, &[5, 4, 3, 2, 1]),
    );
    let c = side(testkit::POSE_B, &[0, 2, 4, 6]);
    let (va, vb, vc) = (a.view(), b.view(), c.view());
    for masks in [MaskScope::PerNode, MaskScope::Shared] {
        let run = Inference {
            masks,
            ..Inference::MC_DROPOUT
        };
        let network = Published::from_weights(cfg, bytes, run).unwrap();
        let m = McMatcher::new(Method::Dgmc, network, run);
        assert_eq!(m.network_macs(), 0);
        m.identify(&va, &vb);
        let ab = published_macs(&cfg, [6, 5], 20, masks == MaskScope::PerNode);
        assert_eq!(m.network_macs(), ab.new_pair(), "{masks:?}");
        m.identify(&va, &vb);
        assert_eq!(m.network_macs(), ab.new_pair(), "{masks:?}: kept");
        m.identify(&va, &vc);
        let ac = published_macs(&cfg, [6, 4], 20, masks == MaskScope::PerNode);
        let more = match masks {
            MaskScope::PerNode => ac.new_pair(),
            MaskScope::Shared => ac.shared_pair() + ac.embeddings[1],
        };
        assert_eq!(m.network_macs(), ab.new_pair() + more, "{masks:?}");
    }
}

#[test]
fn a_published_trainer_started_from_weights_holds_them() {
    let cfg = PublishedConfig::new(PublishedKind::Dgmc);
    let other = PublishedTrainer::new(cfg, 11).weights().unwrap();
    let mut t = PublishedTrainer::new(cfg, 7);
    assert_ne!(t.weights().unwrap(), other);
    t.start_from(&other).unwrap();
    assert_eq!(t.weights().unwrap(), other);
    let e = t.start_from(b"not a burnpack").unwrap_err();
    assert!(e.starts_with("the starting weights do not fit"), "{e}");
}

/// `[matching] indicators = "per-pair"`: with every dropout off, a
/// pair's samples differ only in DGMC's indicators, so drawn once per
/// pair they are one answer T times; drawn per sample they differ.
/// With dropout on, shared indicators still leave the masks' variation.
#[test]
fn indicators_drawn_per_pair_leave_the_samples_differing_in_their_masks_alone() {
    use crate::matching::deep::arch::IndicatorScope;
    let Some(Backbone::Published(cfg)) = Method::Coid.backbone() else {
        panic!("coid is a published network");
    };
    let bytes = include_bytes!("../../../../models/coid.bpk");
    let objects = testkit::world_objects();
    let a = Side::of(testkit::POSE_A, &objects, &[0, 1, 2, 3, 4, 5], GPS);
    let b = Side::of(testkit::POSE_B, &objects, &[5, 4, 3, 2, 1], GPS);
    let (va, vb) = (a.view(), b.view());
    let relative = crate::matching::gps_relative_pose(&va, &vb);
    let samples = |indicators, dropout| {
        let run = Inference {
            masks: MaskScope::PerNode,
            samples: 4,
            dropout,
            indicators,
            ..Inference::MC_DROPOUT
        };
        let network = Published::from_weights(cfg, bytes, run).unwrap();
        McMatcher::new(Method::Coid, network, run)
            .samples(&va, &vb, &relative)
            .assignments
    };
    let spread = |s: &[Vec<f32>]| {
        s.iter()
            .flat_map(|x| x.iter().zip(&s[0]).map(|(v, w)| (v - w).abs()))
            .fold(0f32, f32::max)
    };
    let pair = samples(IndicatorScope::PerPair, Some(0.0));
    assert_eq!(spread(&pair), 0.0, "one draw of indicators, no dropout");
    let sample = samples(IndicatorScope::PerSample, Some(0.0));
    assert!(spread(&sample) > 1e-3, "{}", spread(&sample));
    let masked = samples(IndicatorScope::PerPair, None);
    assert!(spread(&masked) > 1e-3, "{}", spread(&masked));
}
