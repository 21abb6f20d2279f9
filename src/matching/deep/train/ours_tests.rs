//! `ours` in the MC shell: dropout really varies the samples, shared
//! masks repeat by seed, weights survive bytes, an untrained network
//! decides as GPS+appearance Hungarian, shared embeddings change no bit.

use super::backend::device;
use super::ours_net::OursNet;
use super::spline::GraphTensors;
use super::weights::{from_bytes, to_bytes};
use crate::geometry::Vec2;
use crate::matching::deep::arch::{Architecture, MaskScope};
use crate::matching::deep::cost::GraphShape;
use crate::matching::deep::cost::inference_macs;
use crate::matching::deep::graph::OffsetGraph;
use crate::matching::deep::mc::Inference;
use crate::matching::deep::mc::McMatcher;
use crate::matching::deep::ours::{self, Ours, PlainSpline, first_layer};
use crate::matching::deep::params::Params;
use crate::matching::deep::tests::queue_scene;
use crate::matching::gps_hungarian::GpsHungarian;
use crate::matching::likelihood::LikelihoodTerms;
use crate::matching::likelihood::assign;
use crate::matching::testkit::{self, GPS, Side};
use crate::matching::{Matcher, Method};
use burn::prelude::*;

const RUN: Inference = Inference {
    seed: 3,
    masks: MaskScope::PerNode,
    ..Inference::MC_DROPOUT
};

/// An untrained network whose gates are open (as after the first
/// training steps), so that the residual and its dropout count.
fn opened(arch: Architecture, seed: u64) -> McMatcher<Ours> {
    opened_as(arch, seed, RUN)
}

fn opened_as(arch: Architecture, seed: u64, run: Inference) -> McMatcher<Ours> {
    let p = opened_params(&arch, seed, 1.0);
    McMatcher::new(Method::Ours, Ours::new(&p, arch, run), run)
}

/// The seeded parameters of `arch` with both gates at `gate`.
fn opened_params(arch: &Architecture, seed: u64, gate: f32) -> Params {
    let mut p = Params::seeded(&ours::spec(arch), seed);
    p.set("gate", &[gate]);
    p.set("dust_gate", &[gate]);
    p
}

/// The MC samples of the moved-copy scene.
fn mc_samples(m: &McMatcher<Ours>) -> Vec<Vec<f32>> {
    let (a, b) = testkit::moved_copy();
    let (va, vb) = (a.view(), b.view());
    let relative = crate::matching::gps_relative_pose(&va, &vb);
    let s = m.samples(&va, &vb, &relative);
    assert_eq!(s.assignments.len(), 20);
    s.assignments
}

/// Largest per-entry variance across samples.
fn max_variance(samples: &[Vec<f32>]) -> f64 {
    let t = samples.len() as f64;
    (0..samples[0].len())
        .map(|k| {
            let mean = samples.iter().map(|s| f64::from(s[k])).sum::<f64>() / t;
            samples
                .iter()
                .map(|s| (f64::from(s[k]) - mean).powi(2))
                .sum::<f64>()
                / t
        })
        .fold(0.0, f64::max)
}

#[test]
fn mc_dropout_samples_really_differ_at_inference() {
    let v = max_variance(&mc_samples(&opened(Architecture::default(), 3)));
    assert!(
        v > 1e-4,
        "p > 0 must give varying samples (max variance {v})"
    );
    let without = Architecture {
        dropout_conv: 0.0,
        dropout_phi: 0.0,
        ..Architecture::default()
    };
    let samples = mc_samples(&opened(without, 3));
    assert!(
        samples.iter().all(|s| *s == samples[0]),
        "p = 0 must give identical samples"
    );
}

/// Eq. 8's shared masks: the samples still vary, the same seed gives
/// the same samples, and they are other draws than per-node masks.
#[test]
fn shared_dropout_masks_vary_by_sample_and_repeat_by_seed() {
    let shared = |seed| {
        let run = Inference {
            masks: MaskScope::Shared,
            seed,
            ..RUN
        };
        mc_samples(&opened_as(Architecture::default(), 3, run))
    };
    let s = shared(3);
    assert!(max_variance(&s) > 1e-4);
    assert_eq!(s, shared(3));
    assert_ne!(s, shared(4));
    assert_ne!(s, mc_samples(&opened(Architecture::default(), 3)));
}

#[test]
fn weights_as_bytes_give_identical_outputs() {
    let arch = Architecture::default();
    let m = opened(arch, 11);
    let p = opened_params(&arch, 11, 1.0);
    let specs = ours::spec(&arch);
    let bytes = to_bytes(&OursNet::from_params(&arch, &p, &specs, &device())).unwrap();
    let ours = Ours::from_weights(arch, &bytes, RUN).unwrap();
    let loaded = McMatcher::new(Method::Ours, ours, RUN);
    let (a, b) = testkit::moved_copy();
    let (va, vb) = (a.view(), b.view());
    let relative = crate::matching::gps_relative_pose(&va, &vb);
    assert_eq!(
        m.distribution(&va, &vb, &relative),
        loaded.distribution(&va, &vb, &relative)
    );
    // gcn-gm has no consensus: the weights of `ours` do not fit it.
    let fits = |d: Method| {
        crate::matching::deep::matcher(
            d,
            crate::sensor::AppearanceWidth::NONE,
            crate::matching::deep::arch::NetworkShape::default(),
            &bytes,
            RUN,
        )
        .is_ok()
    };
    assert!(!fits(Method::GcnGmGps));
    // gcn-gm (as published) is not this network at all.
    assert!(!fits(Method::GcnGm));
}

/// Untrained, every variant with positions scores each pair by the
/// shared likelihood alone, so that its assignment is GPS+appearance
/// Hungarian's, pair for pair, on scenes with GPS error, look-alikes
/// and objects only one vehicle sees; `ours-noprior` is the
/// appearance-only Hungarian. With the gates open it is not.
#[test]
fn untrained_decides_exactly_as_gps_appearance_hungarian() {
    let scene = queue_scene();
    let mut world = testkit::world_objects();
    world.extend(
        scene
            .iter()
            .map(|&(p, c, col)| (p + Vec2::new(40.0, 40.0), c, col)),
    );
    let all: Vec<usize> = (0..world.len()).collect();
    let a = Side::of(testkit::POSE_A, &world, &all, GPS);
    let mut b = Side::of(
        testkit::POSE_B,
        &world,
        &[3, 9, 12, 0, 5, 14, 2, 10, 7, 16],
        GPS,
    );
    b.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(2.0, -1.0), -2.39);
    let (va, vb) = (a.view(), b.view());
    let hungarian = |appearance_only: bool| {
        let relative = crate::matching::gps_relative_pose(&va, &vb);
        let terms = LikelihoodTerms {
            position: !appearance_only,
            ..LikelihoodTerms::full(9.21)
        };
        let s: Vec<Option<f64>> =
            crate::matching::likelihood::pair_terms(&va, &vb, &relative, &terms)
                .iter()
                .map(|p| p.map(|p| p.log_likelihood()))
                .collect();
        assign(va.detections.len(), vb.detections.len(), &s)
    };
    let pairs = |m: &dyn Matcher| -> Vec<(usize, usize)> {
        m.identify(&va, &vb)
            .matches
            .iter()
            .map(|c| (c.a, c.b))
            .collect()
    };
    let expected = pairs(&GpsHungarian {
        gate_chi2: 9.21,
        appearance: true,
        descriptor_weight: 1.0,
    });
    assert_eq!(expected, hungarian(false));
    assert!(expected.len() >= 6, "{expected:?}");
    for method in [
        Method::Ours,
        Method::CoidNonGps,
        Method::CoidUncGps,
        Method::DgmcGps,
        Method::GcnGmGps,
    ] {
        let m = crate::matching::deep::untrained(method, 5, RUN);
        assert_eq!(pairs(&*m), expected, "{method:?}");
    }
    // Without the position term: an appearance-only Hungarian.
    let arch = Architecture {
        positions: false,
        ..Architecture::default()
    };
    let noprior = McMatcher::new(Method::Ours, Ours::untrained(arch, 5, RUN), RUN);
    assert_eq!(pairs(&noprior), hungarian(true));
    assert_ne!(hungarian(true), expected);
    let arch = Architecture::default();
    let p = opened_params(&arch, 5, 30.0);
    let loud = McMatcher::new(Method::Ours, Ours::new(&p, arch, RUN), RUN);
    assert_ne!(pairs(&loud), expected);
}

/// Three vehicles, three pairs: sharing each vehicle's embedding across
/// its pairs gives the same bits as computing it for every pair, and
/// it is reused (each vehicle is in two pairs).
#[test]
fn shared_embeddings_are_bit_identical_to_the_per_pair_path() {
    let objects = testkit::world_objects();
    let all: Vec<usize> = (0..objects.len()).collect();
    let sides = [
        Side::of(testkit::POSE_A, &objects, &all, GPS),
        Side::of(testkit::POSE_B, &objects, &[5, 2, 7, 0, 3, 6, 1, 4], GPS),
        Side::of((20.0, 40.0, -1.2), &objects, &[1, 3, 4, 6, 7], GPS),
    ];
    let pairs = [(0, 1), (0, 2), (1, 2)];
    let run = |m: &McMatcher<Ours>| -> Vec<Vec<Vec<f32>>> {
        pairs
            .iter()
            .map(|&(i, j)| {
                let (a, b) = (sides[i].view(), sides[j].view());
                m.samples(&a, &b, &crate::matching::gps_relative_pose(&a, &b))
                    .assignments
            })
            .collect()
    };
    let shared = opened(Architecture::default(), 4);
    let per_pair = opened(Architecture::default(), 4).without_shared_embeddings();
    let (a, b) = (run(&shared), run(&per_pair));
    assert_eq!(a, b);
    assert_eq!(shared.shared_embeddings(), 3);
    assert_eq!(per_pair.shared_embeddings(), 0);
    // Each counts what it multiplied: every pair part, and each
    // vehicle's embedding once (shared) or once per pair.
    let arch = Architecture::default();
    let shape = |k: usize| GraphShape::of(&sides[k].view());
    let macs = |i: usize, j: usize| inference_macs(&arch, shape(i), shape(j), 20);
    let parts: u64 = pairs.iter().map(|&(i, j)| macs(i, j).shared_pair()).sum();
    let embedded = |k: usize| macs(k, k).embeddings[0];
    let once: u64 = (0..3).map(embedded).sum();
    assert_eq!(shared.network_macs(), parts + once);
    assert_eq!(per_pair.network_macs(), parts + 2 * once);
    // The MC samples differ from each other (dropout is on).
    assert_ne!(a[0][0], a[0][1]);
}

#[test]
fn empty_sides_send_everything_to_the_dustbin() {
    let m = opened(Architecture::default(), 1);
    let (a, b) = testkit::moved_copy();
    let empty = Side::new(vec![], vec![], b.pose, testkit::EXACT);
    let id = m.identify(&a.view(), &empty.view());
    assert!(id.matches.is_empty());
    let d = id.distribution.unwrap();
    assert!((0..a.detections.len()).all(|i| d.p(i, 0) == 1.0));
}

/// The plain first layer gives burn's first layer bit for bit (the same
/// products through the same kernel in the same order), on the shipped
/// weights, on graphs of 1 to 20 nodes.
#[test]
fn the_plain_first_layer_is_the_tensor_one_bit_for_bit() {
    let weights = include_bytes!("../../../../models/ours.bpk");
    let arch = Architecture::default();
    let net = from_bytes(&arch, weights, &device()).unwrap().valid();
    let p = Params::from_bytes(weights, &ours::spec(&arch)).unwrap();
    let plain = first_layer::FirstLayer::new(PlainSpline::of(&p, "conv1"));
    let mut scenes: Vec<Side> = vec![testkit::moved_copy().0, testkit::moved_copy().1];
    let objects = testkit::world_objects();
    scenes.push(Side::of(testkit::POSE_A, &objects, &[4], GPS));
    scenes.push(Side::of(testkit::POSE_A, &objects, &[0, 3], GPS));
    let scene = queue_scene();
    let all: Vec<usize> = (0..scene.len()).collect();
    scenes.push(Side::of(testkit::POSE_B, &scene, &all, GPS));
    let mut big = testkit::world_objects();
    big.extend(
        scene
            .iter()
            .map(|&(p, c, col)| (p + Vec2::new(40.0, 40.0), c, col)),
    );
    big.extend(
        scene
            .iter()
            .map(|&(p, c, col)| (p + Vec2::new(-30.0, 10.0), c, col)),
    );
    let all: Vec<usize> = (0..big.len().min(20)).collect();
    scenes.push(Side::of(testkit::POSE_B, &big, &all, GPS));
    for side in &scenes {
        let v = side.view();
        let input = OffsetGraph::offsets(
            v.detections,
            v.graph,
            &v.pose_reported,
            crate::sensor::AppearanceWidth::NONE,
        );
        let tensor = net
            .first_layer(&GraphTensors::used_cells(&input, &device()))
            .unwrap();
        let bits = |h: &[f32]| h.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(&plain.forward(&input)),
            bits(&tensor),
            "{} nodes",
            input.n
        );
    }
}

#[test]
fn the_projects_trainer_started_from_weights_holds_them() {
    let opts = |seed| super::TrainOptions {
        epochs: 1,
        learning_rate: 1e-3,
        seed,
        patience: 0,
        loss: crate::matching::deep::arch::PairLoss::Likelihood,
        samples: 1,
        masks: MaskScope::PerNode,
        batch_size: 4,
        gate_chi2: 9.21,
        appearance_width: crate::sensor::AppearanceWidth::NONE,
        no_match: crate::matching::deep::arch::NoMatchWeights::Halves,
        network: crate::matching::deep::arch::NetworkShape::default(),
        augment: super::augment::Augment::default(),
    };
    let other = super::Trainer::new(Method::Ours, &opts(11))
        .unwrap()
        .weights()
        .unwrap();
    let mut t = super::Trainer::new(Method::Ours, &opts(7)).unwrap();
    assert_ne!(t.weights().unwrap(), other);
    t.start_from(&other).unwrap();
    assert_eq!(t.weights().unwrap(), other);
    let e = t.start_from(b"not a burnpack").unwrap_err();
    assert!(e.starts_with("the starting weights do not fit"), "{e}");
}
