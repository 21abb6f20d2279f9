//! The matchers together: labels, permutations, what each reads.

use super::deep::arch::MaskScope;
use super::deep::decision::KindLambdas;
use super::testkit::{self, Side};
use super::*;
use crate::geometry::Vec2;
use crate::traffic::ObjectClass;

/// A deep method's weights with `choice` (none for the other methods).
fn trained(weights: Option<&[u8]>, choice: DeepChoice) -> Option<Trained<'_>> {
    weights.map(|weights| Trained {
        weights,
        choice,
        appearance_width: crate::sensor::AppearanceWidth::NONE,
        shape: deep::arch::NetworkShape::default(),
    })
}

fn settings() -> MatchingSettings {
    MatchingSettings {
        methods: vec![],
        baselines: BaselineChoice::APriori,
        gate_chi2: 9.21,
        models_dir: PathBuf::new(),
        mc_samples: 20,
        dropout_masks: MaskChoice::AsTrained,
        mc_dropout: None,
        lambda: LambdaChoice::Fixed(0.7),
        decision: DecisionChoice::Fixed(Decision::Assignment),
        uncertainty: UncertaintyKind::Total,
        sender_as_node: true,
        multi_vehicle: MultiVehicle::Pairwise,
        rematch: 0,
        indicators: crate::matching::deep::arch::IndicatorScope::PerSample,
    }
}

const CHOICE: DeepChoice = DeepChoice {
    lambda: 0.7,
    lambdas: KindLambdas::all(0.7),
    decision: Decision::Assignment,
    min_probability: 0.0,
    temperature: 1.0,
    trained_masks: MaskScope::PerNode,
};

fn built(method: Method) -> Box<dyn Matcher> {
    build(method, &settings(), (None, None), 1).unwrap()
}

#[test]
fn every_learning_free_matcher_matches_a_moved_copy_of_a_scene_to_itself() {
    for method in [
        Method::Mogm,
        Method::Rgm,
        Method::Spectral,
        Method::Rrwm,
        Method::GpsHungarian,
        Method::GpsAppHungarian,
    ] {
        assert_eq!(
            testkit::self_match(built(method).as_ref()),
            (1.0, 0),
            "{method:?}"
        );
    }
}

/// A vehicle's detections in another order: `order[k]` is the old
/// index of new detection k.
fn permuted(side: &Side, order: &[usize]) -> Side {
    Side {
        detections: order.iter().map(|&k| side.detections[k].clone()).collect(),
        objects: order.iter().map(|&k| side.objects[k]).collect(),
        graph: side.graph.permuted(order),
        pose: side.pose,
        level: side.level,
    }
}

/// Permuting one vehicle's detections permutes every method's matches
/// (and a deep method's distribution) and changes nothing else, bit for
/// bit: with one pass and with match-align-rematch, on a scene with GPS
/// error, look-alikes and objects only one vehicle sees.
#[test]
fn permuting_detections_permutes_every_methods_matches_and_nothing_else() {
    let mut world = testkit::world_objects();
    world.extend(
        testkit::world_objects()
            .iter()
            .map(|&(p, c, col)| (p + Vec2::new(30.0, -25.0), c, col)),
    );
    let all: Vec<usize> = (0..world.len()).collect();
    let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
    let mut b = Side::of(
        testkit::POSE_B,
        &world,
        &[3, 9, 12, 0, 5, 14, 2, 10, 7],
        testkit::GPS,
    );
    b.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(1.5, -1.0), -2.395);
    let order_a: Vec<usize> = (0..a.detections.len()).rev().collect();
    let order_b = [4, 0, 8, 2, 6, 1, 7, 3, 5];
    for rematch in [0, 2] {
        let s = MatchingSettings {
            rematch,
            ..settings()
        };
        for &method in Method::all() {
            if matches!(method, Method::Oracle | Method::External) {
                continue;
            }
            let weights = (method.kind() == MethodKind::Deep)
                .then(|| deep::opened_weights(method.weights_owner(), 3));
            let all_pairs = DeepChoice {
                lambda: f64::INFINITY,
                lambdas: KindLambdas::all(f64::INFINITY),
                ..CHOICE
            };
            let m = build(
                method,
                &s,
                (trained(weights.as_deref(), all_pairs), None),
                1,
            )
            .unwrap();
            let before = m.identify(&a.view(), &b.view());
            let (pa, pb) = (permuted(&a, &order_a), permuted(&b, &order_b));
            let after = m.identify(&pa.view(), &pb.view());
            // Map the permuted answer back to the original indices.
            let mut back: Vec<Correspondence> = after
                .matches
                .iter()
                .map(|c| Correspondence {
                    a: order_a[c.a],
                    b: order_b[c.b],
                    ..*c
                })
                .collect();
            back.sort_by_key(|c| c.a);
            assert_eq!(back, before.matches, "{method:?}, rematch {rematch}");
            // An untrained published network sends every node to its
            // dustbin; its distribution is compared below.
            let published = method.kind() == MethodKind::Deep && method.architecture().is_none();
            assert!(
                !before.matches.is_empty() || method == Method::Rgm || published,
                "{method:?}"
            );
            if let (Some(d0), Some(d1)) = (&before.distribution, &after.distribution) {
                let (ra, rb) = (inverse(&order_a), inverse(&order_b));
                assert_eq!(&d1.relabelled(&ra, &rb), d0, "{method:?}");
            }
        }
    }
}

fn inverse(p: &[usize]) -> Vec<usize> {
    let mut q = vec![0; p.len()];
    for (k, &i) in p.iter().enumerate() {
        q[i] = k;
    }
    q
}

#[test]
fn graph_matchers_find_nothing_in_unrelated_scenes() {
    // The second vehicle sees other objects of other classes elsewhere.
    let objects = testkit::world_objects();
    let others: Vec<(Vec2, ObjectClass, [f64; 3])> = objects
        .iter()
        .map(|&(p, c, col)| {
            let class = if c == ObjectClass::Pedestrian {
                ObjectClass::Bus
            } else {
                ObjectClass::Pedestrian
            };
            (Vec2::new(p.y * 1.7, -p.x * 0.6), class, col)
        })
        .collect();
    let idx: Vec<usize> = (0..objects.len()).collect();
    let a = Side::of(testkit::POSE_A, &objects, &idx, testkit::EXACT);
    let b = Side::of(testkit::POSE_B, &others, &idx, testkit::EXACT);
    // RGM prices every match, so unsupported pairs stay unmatched.
    let rgm = built(Method::Rgm).identify(&a.view(), &b.view());
    assert!(rgm.matches.is_empty());
    // Spectral matching (MOGM) has no absolute "no match": it keeps the
    // strongest compatible candidates (here: the first vehicle's
    // pedestrian and bicycle, both compatible with the second's
    // pedestrians), a known weakness of the method.
    let mogm = built(Method::Mogm).identify(&a.view(), &b.view());
    assert!(mogm.matches.len() <= 2);
}

#[test]
fn the_oracle_is_not_a_matcher_and_deep_methods_need_weights() {
    assert!(matches!(
        build(Method::Oracle, &settings(), (None, None), 1),
        Err(BuildError::Oracle)
    ));
    let e = build(Method::Ours, &settings(), (None, None), 1)
        .err()
        .unwrap();
    assert_eq!(e.to_string(), "'ours' needs trained weights");
    let e = build(
        Method::Ours,
        &settings(),
        (trained(Some(b"not a burnpack"), CHOICE), None),
        1,
    )
    .err()
    .unwrap();
    assert!(
        e.to_string().starts_with("'ours': the weights do not fit"),
        "{e}"
    );
}

#[test]
fn method_labels_are_the_published_ones_in_table_order() {
    let labels: Vec<&str> = Method::all().iter().map(|m| m.as_str()).collect();
    assert_eq!(
        labels,
        [
            "coid",
            "coid-t1",
            "coid-paper-rule",
            "coid+non",
            "coid+unc",
            "dgmc",
            "gcn-gm",
            "mogm",
            "rgm",
            "spectral",
            "rrwm",
            "ours",
            "ours-t1",
            "coid+non+gps",
            "coid+unc+gps",
            "dgmc+gps",
            "gcn-gm+gps",
            "gps-hungarian",
            "gps-app-hungarian",
            "oracle",
            "external"
        ]
    );
}

/// A single-pass variant is its owner's weights run once with every
/// dropout off (T = 1; the consensus's random indicators are still
/// drawn): exactly the owner with one sample at rate 0, under its own
/// label, with no epistemic uncertainty (its one sample's entropy is
/// the mean's), where the owner's MC dropout has some.
#[test]
fn single_pass_variants_are_one_pass_without_epistemic_uncertainty() {
    let world = testkit::world_objects();
    let all: Vec<usize> = (0..world.len()).collect();
    let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
    let b = Side::of(testkit::POSE_B, &world, &[3, 0, 5, 2, 7, 6], testkit::GPS);
    let one_pass = MatchingSettings {
        mc_samples: 1,
        mc_dropout: Some(0.0),
        ..settings()
    };
    for (one, owner) in [
        (Method::CoidT1, Method::Coid),
        (Method::OursT1, Method::Ours),
    ] {
        let weights = deep::opened_weights(owner, 3);
        let dist = |m: Method, s: &MatchingSettings| {
            let matcher = build(m, s, (trained(Some(&weights), CHOICE), None), 1).unwrap();
            assert_eq!(matcher.method(), m);
            matcher
                .identify(&a.view(), &b.view())
                .distribution
                .expect("a deep method's distribution")
        };
        let single = dist(one, &settings());
        assert_eq!(single, dist(owner, &one_pass), "{one:?}");
        let epistemic = |d: &MatchDistribution| {
            let pairs = (0..d.n1).flat_map(|i| (0..d.n2).map(move |j| (i, j)));
            pairs
                .map(|(i, j)| d.uncertainty(i, j, UncertaintyKind::Epistemic))
                .fold(0.0, f64::max)
        };
        assert!(epistemic(&single) < 1e-5, "{one:?}");
        assert!(epistemic(&dist(owner, &settings())) > 1e-3, "{owner:?}");
    }
}

/// The methods of Table 1 see the paper's inputs only: another
/// reported pose and another claimed accuracy for either vehicle (the
/// detections, in each body frame, unchanged) change nothing they say,
/// bit for bit; a method with the poses does change.
#[test]
fn the_methods_on_the_papers_inputs_never_read_a_pose() {
    let world = testkit::world_objects();
    let all: Vec<usize> = (0..world.len()).collect();
    let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
    let b = Side::of(testkit::POSE_B, &world, &[3, 0, 5, 2, 7, 6], testkit::GPS);
    let (mut a2, mut b2) = (a.clone(), b.clone());
    a2.pose = crate::geometry::Pose2::new(a.pose.position_m() + Vec2::new(30.0, -8.0), 1.1);
    b2.pose = crate::geometry::Pose2::new(b.pose.position_m() + Vec2::new(-2.0, 4.0), 0.3);
    (a2.level, b2.level) = (testkit::EXACT, testkit::EXACT);
    let s = MatchingSettings {
        rematch: 2,
        ..settings()
    };
    let all_pairs = DeepChoice {
        lambda: f64::INFINITY,
        lambdas: KindLambdas::all(f64::INFINITY),
        ..CHOICE
    };
    let paper: Vec<Method> = Method::all()
        .iter()
        .copied()
        .filter(|m| m.inputs() == Inputs::Paper)
        .collect();
    assert_eq!(paper.len(), 11);
    for method in paper.into_iter().chain([Method::GpsAppHungarian]) {
        let weights = (method.kind() == MethodKind::Deep)
            .then(|| deep::opened_weights(method.weights_owner(), 3));
        let m = build(
            method,
            &s,
            (trained(weights.as_deref(), all_pairs), None),
            1,
        )
        .unwrap();
        let before = m.identify(&a.view(), &b.view());
        let moved = m.identify(&a2.view(), &b2.view());
        if method.inputs() == Inputs::Paper {
            assert_eq!(before, moved, "{method:?}");
        } else {
            assert_ne!(before, moved, "{method:?}");
        }
    }
}

/// A config naming a method that was renamed is refused in one line
/// that names its replacement.
#[test]
fn a_renamed_method_is_refused_with_its_new_name() {
    let e = crate::label::parse::<Method>("method", "ours-noprior").unwrap_err();
    assert!(e.contains("renamed") && e.contains("'coid'"), "{e}");
    assert!(!e.contains('\n'));
    assert_eq!(
        crate::label::parse::<Method>("method", "dgmc+gps"),
        Ok(Method::DgmcGps)
    );
}

#[test]
fn entropy_bounds() {
    assert_eq!(binary_entropy_bits(0.0), 0.0);
    assert_eq!(binary_entropy_bits(1.0), 0.0);
    assert!((binary_entropy_bits(0.5) - 1.0).abs() < 1e-12);
    assert!(binary_entropy_bits(0.9) < binary_entropy_bits(0.7));
}

#[test]
fn the_papers_rule_is_coids_weights_at_lambda_0_7_on_the_total_entropy() {
    let world = testkit::world_objects();
    let all: Vec<usize> = (0..world.len()).collect();
    let a = Side::of(testkit::POSE_A, &world, &all, testkit::GPS);
    let b = Side::of(testkit::POSE_B, &world, &[3, 0, 5, 2, 7, 6], testkit::GPS);
    // The shipped weights: an untrained network sends every node to its
    // dustbin, and no threshold would have a pair to remove.
    let weights = include_bytes!("../../models/coid.bpk");
    let rule = DeepChoice::paper_rule(MaskScope::PerNode);
    assert_eq!((rule.lambda, rule.decision), (0.7, Decision::Assignment));
    let run = |m: Method, uncertainty: UncertaintyKind| {
        let s = MatchingSettings {
            uncertainty,
            ..settings()
        };
        let matcher = build(m, &s, (trained(Some(weights), rule), None), 1).unwrap();
        assert_eq!(matcher.method(), m);
        matcher.identify(&a.view(), &b.view())
    };
    // Whatever type the config thresholds, the rule thresholds the total.
    let paper = run(Method::CoidPaperRule, UncertaintyKind::Epistemic);
    assert_eq!(paper, run(Method::Coid, UncertaintyKind::Total));
    // The assigned pairs with a total entropy below 0.7, and the type
    // matters here: on the epistemic part more pairs would stay.
    let d = paper.distribution.as_ref().unwrap();
    let kept: Vec<(usize, usize)> = (d.assigned.iter().copied())
        .filter(|&(i, j)| d.uncertainty(i, j, UncertaintyKind::Total) < 0.7)
        .collect();
    let pairs: Vec<(usize, usize)> = paper.matches.iter().map(|c| (c.a, c.b)).collect();
    assert_eq!(pairs, kept);
    assert!(!kept.is_empty(), "{d:?}");
    let epistemic = run(Method::Coid, UncertaintyKind::Epistemic);
    assert!(
        epistemic.matches.len() > paper.matches.len(),
        "{epistemic:?}"
    );
}
