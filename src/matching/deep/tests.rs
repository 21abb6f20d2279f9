//! The path tester: every network's plain inference held to its tensor
//! reference (burn's forward, as training runs it) on the shipped
//! weights, under shared and per-node masks, on graphs of 8,
//! 9, 2 and 1 nodes: the same samples within the network's rounding, the
//! same decided pairs with the same probabilities and uncertainties.

use super::arch::{Backbone, MaskScope};
use super::mc::{Inference, McMatcher, Network, Samples};
use super::ours::Ours;
use super::published::Published;
use super::train::reference::{TensorOurs, TensorPublished};
use crate::geometry::Vec2;
use crate::matching::Method;
use crate::matching::testkit::{self, GPS, Side};
use crate::matching::{Correspondence, Matcher};
use crate::traffic::ObjectClass;

/// The queue scene seen from the second fixture pose.
fn queue() -> Side {
    let scene = queue_scene();
    Side::of(
        testkit::POSE_B,
        &scene,
        &(0..scene.len()).collect::<Vec<_>>(),
        GPS,
    )
}

/// A queue of six cars 5.5 m apart (colours differ), a pedestrian, a
/// truck and a bicycle.
pub(super) fn queue_scene() -> Vec<(Vec2, ObjectClass, [f64; 3])> {
    let colours = [
        [0.95; 3],
        [0.1; 3],
        [0.7, 0.1, 0.1],
        [0.6; 3],
        [0.1, 0.2, 0.7],
        [0.9, 0.8, 0.1],
    ];
    let mut v: Vec<_> = (0..6)
        .map(|k| {
            (
                Vec2::new(10.0 + 5.5 * k as f64, 2.0),
                ObjectClass::Car,
                colours[k],
            )
        })
        .collect();
    v.push((Vec2::new(14.0, 12.0), ObjectClass::Pedestrian, [0.2; 3]));
    v.push((Vec2::new(30.0, -9.0), ObjectClass::Truck, [0.7, 0.1, 0.1]));
    v.push((Vec2::new(24.0, 15.0), ObjectClass::Bicycle, [0.1; 3]));
    v
}

/// The scenes: a moved copy, the same objects against a queue, and two
/// nodes against one (no edge).
fn scenes() -> Vec<(Side, Side)> {
    let objects = testkit::world_objects();
    let side = |at, order: &[usize]| Side::of(at, &objects, order, GPS);
    vec![
        testkit::moved_copy(),
        (side(testkit::POSE_A, &[0, 1, 2, 3, 4, 5, 6, 7]), queue()),
        (
            side(testkit::POSE_A, &[0, 1, 2, 3, 4, 5, 6, 7]),
            side(testkit::POSE_B, &[7, 6, 5, 4, 3, 2, 1, 0]),
        ),
        (side(testkit::POSE_A, &[0, 3]), side(testkit::POSE_B, &[3])),
    ]
}

/// Whether `a` and `b` agree within `tol` of the larger of `|a|` and 1.
fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * a.abs().max(1.0)
}

/// Holds `plain` to `tensor` on every scene (and again with every
/// embedding kept): samples, scores and mean scores within `tol`, the
/// same decided pairs with probabilities and uncertainties within `tol`.
fn holds<P: Network, T: Network>(
    label: &str,
    plain: &McMatcher<P>,
    tensor: &McMatcher<T>,
    tol: f64,
) {
    let scores = |s: &Samples| (s.scores.clone(), s.mean_scores.clone().unwrap_or_default());
    for (a, b) in scenes().iter().chain(&scenes()) {
        let (va, vb) = (a.view(), b.view());
        let relative = crate::matching::gps_relative_pose(&va, &vb);
        let sp = plain.samples(&va, &vb, &relative);
        let st = tensor.samples(&va, &vb, &relative);
        assert_eq!(sp.assignments.len(), 20, "{label}");
        assert_eq!(sp.assignments.len(), st.assignments.len(), "{label}");
        for (p, t) in sp
            .assignments
            .iter()
            .flatten()
            .zip(st.assignments.iter().flatten())
        {
            let (p, t) = (f64::from(*p), f64::from(*t));
            assert!(close(p, t, tol), "{label}: assignment {p} vs {t}");
        }
        let ((ps, pm), (ts, tm)) = (scores(&sp), scores(&st));
        for (p, t) in ps.iter().zip(&ts).chain(pm.iter().zip(&tm)) {
            assert_eq!(p.is_some(), t.is_some(), "{label}: a gate differs");
            if let (Some(p), Some(t)) = (p, t) {
                assert!(close(*p, *t, tol), "{label}: score {p} vs {t}");
            }
        }
        let (mp, mt) = (
            plain.identify(&va, &vb).matches,
            tensor.identify(&va, &vb).matches,
        );
        let pairs = |m: &[Correspondence]| m.iter().map(|c| (c.a, c.b)).collect::<Vec<_>>();
        assert_eq!(pairs(&mp), pairs(&mt), "{label}");
        for (p, t) in mp.iter().zip(&mt) {
            assert!(
                close(p.probability, t.probability, tol),
                "{label}: {p:?} vs {t:?}"
            );
            assert!(
                close(p.uncertainty, t.uncertainty, tol),
                "{label}: {p:?} vs {t:?}"
            );
        }
    }
}

/// Every network x mask scope, on the shipped
/// weights (an untrained network's biases are zero and would hide a bias
/// the plain path forgot). `ours`'s scores and samples within 1e-5;
/// the published networks' within 1e-4 (the f32 log-domain Sinkhorn's
/// own rounding), also with the target's first consensus product
/// multiplied anew (as sources of more than `rnd_dim` nodes take it).
#[test]
fn the_plain_path_of_every_network_equals_its_tensor_reference() {
    let run = |masks| Inference {
        seed: 3,
        masks,
        ..Inference::MC_DROPOUT
    };
    for masks in [MaskScope::Shared, MaskScope::PerNode] {
        let r = run(masks);
        let bytes = include_bytes!("../../../models/ours.bpk");
        let arch = super::arch::Architecture::default();
        let method = crate::matching::Method::Ours;
        let plain = McMatcher::new(method, Ours::from_weights(arch, bytes, r).unwrap(), r);
        let tensor = McMatcher::new(method, TensorOurs::from_weights(arch, bytes, r), r);
        holds(&format!("ours {masks:?}"), &plain, &tensor, 1e-5);
    }
    let shipped: [(Method, &[u8]); 3] = [
        (Method::GcnGm, include_bytes!("../../../models/gcn-gm.bpk")),
        (Method::Dgmc, include_bytes!("../../../models/dgmc.bpk")),
        (Method::Coid, include_bytes!("../../../models/coid.bpk")),
    ];
    for (method, bytes) in shipped {
        let Some(Backbone::Published(cfg)) = method.backbone() else {
            panic!("{method:?} is a published network");
        };
        for masks in [MaskScope::Shared, MaskScope::PerNode] {
            let r = run(masks);
            let network = || Published::from_weights(cfg, bytes, r).unwrap();
            let open = |n| McMatcher::new(method, n, r);
            let label = format!("{method:?} {masks:?}");
            let tensor = McMatcher::new(method, TensorPublished::from_weights(cfg, bytes, r), r);
            holds(&label, &open(network()), &tensor, 1e-4);
            holds(&label, &open(network().never_carry()), &tensor, 1e-4);
        }
    }
}
