//! The profiles through their public surface: calibration, the error
//! components one at a time, persistence, duplicates and ghosts, the
//! confusion matrix, fleets, rigs, and the parameters refused by name.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::model::persistent_error;
use super::*;
use crate::geometry::{Pose2, Vec2};
use crate::sensor::tests::sensor;
use crate::sensor::{CameraSettings, Sensed};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

/// A camera-like profile: depth bias, heavy tails, persistence.
fn params() -> ProfileParams {
    let mut identity = [[0.0; 7]; 7];
    for (k, row) in identity.iter_mut().enumerate() {
        row[k] = 1.0;
    }
    ProfileParams {
        fov_rad: 90f64.to_radians(),
        range_m: 60.0,
        height_m: 1.5,
        mount: Mount::Front,
        yaw_offsets_rad: vec![0.0],
        bin_edges_m: vec![20.0, 40.0, 60.0],
        recall: vec![0.9, 0.7, 0.4],
        mean_error_m: vec![0.4, 1.0, 2.0],
        depth_to_lateral: 3.0,
        depth_bias_per_m: 0.01,
        tail_dof: 4.0,
        persistent_share: 0.5,
        correlation_time_s: 2.0,
        partial_shift: 0.5,
        occlusion_recall_loss: 0.5,
        false_positives_per_frame: 0.0,
        duplicate_prob: 0.0,
        ghost_prob: 0.0,
        ghost_distance_m: [1.0, 3.0],
        class_confusion: identity,
        sees_colour: true,
        boxes: crate::sensor::boxes::BoxErrors {
            heading_sigma_rad: 0.1,
            heading_flip_prob: 0.02,
            speed_sigma_mps: 0.5,
        },
    }
}

fn car(id: &str, x: f64, y: f64) -> TrafficObject {
    TrafficObject {
        id: id.into(),
        class: ObjectClass::Car,
        pose: Pose2::new(Vec2::new(x, y), 0.0),
        length_m: 4.6,
        width_m: 1.8,
        height_m: 1.5,
        colour_rgb: [200, 10, 10],
        speed_mps: 0.0,
        type_id: "car".into(),
        model: None,
    }
}

fn scene() -> StaticScene {
    StaticScene {
        junction_id: "C".into(),
        junction_position_m: Vec2::zeros(),
        buildings: Vec::new(),
        lanes: Vec::new(),
    }
}

/// Errors (sensor frame: x along the line of sight) of one detection
/// of a lone car at `x_m`, over `frames` independent objects.
fn errors(model: &ProfileModel, x_m: f64, frames: u64) -> Vec<Vec2> {
    let sensor = sensor();
    (0..frames)
        .filter_map(|k| {
            let mut f = TrafficFrame {
                step: 0,
                time_s: 0.0,
                objects: vec![car("ego", 0.0, 0.0), car(&format!("o{k}"), x_m, 0.0)],
            };
            f.objects[0].length_m = 0.0; // the sensor at the ego's centre
            let mut rng = ChaCha8Rng::seed_from_u64(k);
            let s = observe_profile(&f, &scene(), 0, model, &sensor, 7, &mut rng);
            let d = s.observation.detections.first()?;
            Some(d.position_m - Vec2::new(x_m, 0.0))
        })
        .collect()
}

#[test]
fn the_mean_translation_error_is_the_published_one_per_bin() {
    let model = ProfileModel::new(params()).unwrap();
    for (x, target) in [(10.0, 0.4), (30.0, 1.0), (50.0, 2.0)] {
        let e = errors(&model, x, 6000);
        let mean = e.iter().map(|v| v.norm()).sum::<f64>() / e.len() as f64;
        assert!(
            (mean / target - 1.0).abs() < 0.05,
            "{x} m: {mean} vs {target}"
        );
    }
}

/// The reported covariance is not the error's distribution: biased in
/// depth, heavier tails than a Gaussian of the same variance.
#[test]
fn the_nominal_covariance_is_not_the_error_distribution() {
    let model = ProfileModel::new(params()).unwrap();
    let e = errors(&model, 50.0, 6000);
    let n = e.len() as f64;
    let mean_depth = e.iter().map(|v| v.x).sum::<f64>() / n;
    assert!((mean_depth - 0.5).abs() < 0.15, "bias {mean_depth}");
    let cov = model.nominal_covariance(&Vec2::new(50.0, 0.0));
    let nees: Vec<f64> = e
        .iter()
        .map(|v| (v.transpose() * cov.try_inverse().unwrap() * v)[(0, 0)])
        .collect();
    // Beyond the Gaussian's 99.9 % NEES (13.8): far more than 0.1 %.
    let beyond = nees.iter().filter(|&&x| x > 13.8).count() as f64 / n;
    assert!(beyond > 0.004, "tail share {beyond}");
}

/// The same object seen 0.1 s apart: the errors are correlated by the
/// persistent share (0.5 x exp(-0.1 / 2)); another object's are not.
#[test]
fn consecutive_frames_share_the_persistent_error() {
    let model = ProfileModel::new(params()).unwrap();
    let sensor = sensor();
    let depth_error = |obj: u64, time_s: f64, stream: u64| {
        let f = TrafficFrame {
            step: 0,
            time_s,
            objects: vec![
                TrafficObject {
                    length_m: 0.0,
                    ..car("ego", 0.0, 0.0)
                },
                car(&format!("o{obj}"), 30.0, 0.0),
            ],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(stream);
        let s = observe_profile(&f, &scene(), 0, &model, &sensor, 7, &mut rng);
        s.observation
            .detections
            .first()
            .map(|d| d.position_m.x - 30.0)
    };
    let pairs: Vec<(f64, f64)> = (0..4000u64)
        .filter_map(|o| {
            Some((
                depth_error(o, 50.0, 2 * o)?,
                depth_error(o, 50.1, 2 * o + 1)?,
            ))
        })
        .collect();
    let corr = |pairs: &[(f64, f64)]| {
        let n = pairs.len() as f64;
        let (ma, mb) = (
            pairs.iter().map(|p| p.0).sum::<f64>() / n,
            pairs.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let cov = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum::<f64>();
        let va = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum::<f64>();
        let vb = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum::<f64>();
        cov / (va * vb).sqrt()
    };
    let same = corr(&pairs);
    assert!(
        (same - 0.5 * (-0.05f64).exp()).abs() < 0.06,
        "same object: {same}"
    );
    let shifted: Vec<(f64, f64)> = pairs
        .iter()
        .zip(pairs.iter().skip(1))
        .map(|(a, b)| (a.0, b.1))
        .collect();
    assert!(
        corr(&shifted).abs() < 0.06,
        "other objects: {}",
        corr(&shifted)
    );
}

#[test]
fn with_gaussian_parameters_the_nominal_covariance_is_the_truth() {
    let mut p = params();
    p.depth_bias_per_m = 0.0;
    p.tail_dof = 1e6;
    p.persistent_share = 0.0;
    let model = ProfileModel::new(p).unwrap();
    let e = errors(&model, 30.0, 6000);
    let cov = model.nominal_covariance(&Vec2::new(30.0, 0.0));
    let mean_nees = e
        .iter()
        .map(|v| (v.transpose() * cov.try_inverse().unwrap() * v)[(0, 0)])
        .sum::<f64>()
        / e.len() as f64;
    assert!((mean_nees - 2.0).abs() < 0.1, "{mean_nees}");
}

#[test]
fn the_persistent_error_is_stationary_and_decorrelates_over_its_time() {
    let tau = 2.0;
    let at = |obj: u64, t: f64| persistent_error(3, "ego", &format!("o{obj}"), t, tau)[0];
    let n = 4000;
    let x0: Vec<f64> = (0..n).map(|o| at(o, 100.0)).collect();
    let var = x0.iter().map(|x| x * x).sum::<f64>() / n as f64;
    assert!((var - 1.0).abs() < 0.08, "variance {var}");
    for (lag, expected) in [(0.1, (-0.05f64).exp()), (tau, (-1f64).exp()), (10.0, 0.0)] {
        let corr = (0..n)
            .map(|o| x0[o as usize] * at(o, 100.0 + lag))
            .sum::<f64>()
            / n as f64;
        assert!(
            (corr - expected).abs() < 0.06,
            "lag {lag}: {corr} vs {expected}"
        );
    }
    // A pure function of its name.
    assert_eq!(at(5, 12.3), at(5, 12.3));
    assert_eq!(persistent_error(3, "ego", "x", 1.0, 0.0), [0.0, 0.0]);
}

/// What a sensor at the ego's centre makes of one car 15 m ahead.
fn sense_a_lone_car(model: &ProfileModel) -> Sensed {
    let mut f = TrafficFrame {
        step: 0,
        time_s: 0.0,
        objects: vec![car("ego", 0.0, 0.0), car("a", 15.0, 0.0)],
    };
    f.objects[0].length_m = 0.0;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    observe_profile(&f, &scene(), 0, model, &sensor(), 7, &mut rng)
}

#[test]
fn duplicates_and_ghosts_are_false_positives_beside_the_object() {
    let mut p = params();
    p.duplicate_prob = 1.0;
    p.ghost_prob = 1.0;
    p.recall = vec![1.0; 3];
    let model = ProfileModel::new(p).unwrap();
    let s = sense_a_lone_car(&model);
    let ids: Vec<_> = s
        .truth
        .detections
        .iter()
        .map(|t| t.object_id.clone())
        .collect();
    assert_eq!(ids, vec![Some("a".to_owned()), None, None]);
    for d in &s.observation.detections {
        assert!((d.position_m - Vec2::new(15.0, 0.0)).norm() < 6.0);
    }
}

#[test]
fn the_confusion_matrix_decides_the_reported_class_and_a_lidar_sees_no_colour() {
    let mut p = params();
    p.recall = vec![1.0; 3];
    p.class_confusion[0] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]; // a car is always a van
    p.sees_colour = false;
    let model = ProfileModel::new(p).unwrap();
    let s = sense_a_lone_car(&model);
    let a = &s.observation.detections[0].appearance;
    assert_eq!(a.class, ObjectClass::Van);
    assert_eq!(a.colour_rgb, [0.5; 3]);
}

/// In a mixed fleet each vehicle carries the profile its id draws, at
/// every step, in the configured shares; without a mix, `profile`.
#[test]
fn a_mixed_fleet_draws_each_vehicles_profile_by_its_id() {
    let model = ProfileModel::new(params()).unwrap();
    let mut d = DetectorSettings {
        profile: DetectorProfile::Paper,
        mix: vec![
            (DetectorProfile::Camera, 0.7),
            (DetectorProfile::Lidar, 0.3),
        ],
        by_type: Vec::new(),
        camera: model.clone(),
        lidar: model,
        rigs: Vec::new(),
        rig_by_type: Vec::new(),
    };
    let n = 20_000;
    let lidar = (0..n)
        .filter(|k| d.profile_of(5, &format!("veh{k}"), "car") == DetectorProfile::Lidar)
        .count() as f64
        / f64::from(n);
    assert!((lidar - 0.3).abs() < 0.015, "lidar share {lidar}");
    assert_eq!(
        d.profile_of(5, "veh7", "car"),
        d.profile_of(5, "veh7", "car")
    );
    assert!(!d.is_paper());
    d.by_type = vec![("bus_cv".into(), DetectorProfile::Lidar)];
    assert_eq!(d.profile_of(5, "veh7", "bus_cv"), DetectorProfile::Lidar);
    d.mix.clear();
    assert_eq!(d.profile_of(5, "veh7", "car"), DetectorProfile::Paper);
    assert!(!d.is_paper());
    d.by_type.clear();
    assert!(d.is_paper());
}

/// The clean profile: Gaussian, white, unbiased, no false positives,
/// no confusion, nothing for partly hidden objects.
fn clean() -> ProfileParams {
    let mut p = params();
    p.depth_bias_per_m = 0.0;
    p.tail_dof = 1e6;
    p.persistent_share = 0.0;
    p.partial_shift = 0.0;
    p.occlusion_recall_loss = 0.0;
    p
}

/// What one profile does to a lone car 30 m ahead, over `N` cars each
/// seen twice 0.1 s apart.
#[derive(Debug, PartialEq)]
struct Signature {
    recall: f64,
    mean_depth_error_m: f64,
    /// Share of NEES (against the nominal covariance) beyond the
    /// Gaussian's 99.9 % point.
    tail_share: f64,
    /// Correlation of the depth errors of one car 0.1 s apart.
    lag_correlation: f64,
    false_positives_per_frame: f64,
    wrong_class_share: f64,
}

fn signature(p: ProfileParams) -> Signature {
    const N: u64 = 3000;
    let model = ProfileModel::new(p).unwrap();
    let cov_inv = model
        .nominal_covariance(&Vec2::new(30.0, 0.0))
        .try_inverse()
        .unwrap();
    let see = |obj: u64, time_s: f64, stream: u64| {
        let f = TrafficFrame {
            step: 0,
            time_s,
            objects: vec![
                TrafficObject {
                    length_m: 0.0,
                    ..car("ego", 0.0, 0.0)
                },
                car(&format!("o{obj}"), 30.0, 0.0),
            ],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(stream);
        observe_profile(&f, &scene(), 0, &model, &sensor(), 7, &mut rng)
    };
    let (mut found, mut fp, mut wrong) = (0usize, 0usize, 0usize);
    let mut errors = Vec::new();
    let mut pairs = Vec::new();
    for o in 0..N {
        let mut depth = [None, None];
        for (i, t) in [50.0, 50.1].into_iter().enumerate() {
            let s = see(o, t, 2 * o + i as u64);
            for (d, truth) in s.observation.detections.iter().zip(&s.truth.detections) {
                if truth.object_id.is_none() {
                    fp += 1;
                    continue;
                }
                found += 1;
                wrong += usize::from(d.appearance.class != ObjectClass::Car);
                let e = d.position_m - Vec2::new(30.0, 0.0);
                errors.push(e);
                depth[i] = Some(e.x);
            }
        }
        if let [Some(a), Some(b)] = depth {
            pairs.push((a, b));
        }
    }
    let n = errors.len() as f64;
    let mean = |v: &mut dyn Iterator<Item = f64>, n: f64| v.sum::<f64>() / n;
    let (ma, mb) = (
        mean(&mut pairs.iter().map(|p| p.0), pairs.len() as f64),
        mean(&mut pairs.iter().map(|p| p.1), pairs.len() as f64),
    );
    let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
    let va: f64 = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum();
    let vb: f64 = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum();
    Signature {
        recall: found as f64 / (2 * N) as f64,
        mean_depth_error_m: mean(&mut errors.iter().map(|e| e.x), n),
        tail_share: errors
            .iter()
            .filter(|e| (e.transpose() * cov_inv * *e)[(0, 0)] > 13.8)
            .count() as f64
            / n,
        lag_correlation: cov / (va * vb).sqrt(),
        false_positives_per_frame: fp as f64 / (2 * N) as f64,
        wrong_class_share: wrong as f64 / n,
    }
}

/// Each error component switched on alone, from the clean profile,
/// moves its own statistic and leaves the others where the clean
/// profile has them (within sampling noise); the components for
/// partly hidden objects change nothing for a car in plain view.
#[test]
fn each_error_component_alone_changes_what_it_should_and_nothing_else() {
    let base = signature(clean());
    assert!(base.mean_depth_error_m.abs() < 0.06, "{base:?}");
    assert!(base.tail_share < 0.004, "{base:?}");
    assert!(base.lag_correlation.abs() < 0.05, "{base:?}");
    assert_eq!(base.false_positives_per_frame, 0.0);
    assert_eq!(base.wrong_class_share, 0.0);
    type Edit = fn(&mut ProfileParams);
    let cases: [(&str, Edit); 8] = [
        ("depth bias", |p| p.depth_bias_per_m = 0.01),
        ("heavy tails", |p| p.tail_dof = 3.0),
        ("persistent error", |p| p.persistent_share = 0.6),
        ("duplicates", |p| p.duplicate_prob = 0.5),
        ("ghosts", |p| p.ghost_prob = 0.5),
        ("class confusion", |p| {
            p.class_confusion[0] = [0.8, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0]
        }),
        ("partial shift", |p| p.partial_shift = 1.0),
        ("occlusion recall loss", |p| p.occlusion_recall_loss = 1.0),
    ];
    for (name, edit) in cases {
        let mut p = clean();
        edit(&mut p);
        let s = signature(p);
        let moved = |a: f64, b: f64, tol: f64| (a - b).abs() > tol;
        let changed = [
            ("recall", moved(s.recall, base.recall, 0.0)),
            (
                "bias",
                moved(s.mean_depth_error_m, base.mean_depth_error_m, 0.1),
            ),
            ("tails", moved(s.tail_share, base.tail_share, 0.004)),
            (
                "persistence",
                moved(s.lag_correlation, base.lag_correlation, 0.1),
            ),
            (
                "false positives",
                moved(s.false_positives_per_frame, 0.0, 0.0),
            ),
            ("class", moved(s.wrong_class_share, 0.0, 0.0)),
        ];
        let expected: &[&str] = match name {
            "depth bias" => &["bias"],
            "heavy tails" => &["tails"],
            "persistent error" => &["persistence"],
            "duplicates" | "ghosts" => &["false positives"],
            "class confusion" => &["class"],
            _ => &[],
        };
        let got: Vec<&str> = changed.iter().filter(|c| c.1).map(|c| c.0).collect();
        assert_eq!(got, expected, "{name}: {s:?} against {base:?}");
        if expected.is_empty() {
            assert_eq!(s, base, "{name} changed a car in plain view");
        }
    }
}

/// A car half hidden behind another: its detection lies closer to the
/// sensor by `partial_shift` x the hidden share x half its depth
/// extent; the car in front, in plain view, does not move.
#[test]
fn a_partly_hidden_objects_centre_shifts_toward_the_sensor() {
    let frame = TrafficFrame {
        step: 0,
        time_s: 0.0,
        objects: vec![
            TrafficObject {
                length_m: 0.0,
                ..car("ego", 0.0, 0.0)
            },
            car("front", 10.0, 0.9),
            car("hidden", 20.0, 0.0),
        ],
    };
    let model = |shift: f64| {
        let mut p = clean();
        p.recall = vec![1.0; 3];
        p.partial_shift = shift;
        ProfileModel::new(p).unwrap()
    };
    let (without, with) = (model(0.0), model(1.0));
    let sense = |shift: f64, seed: u64| {
        let model = if shift > 0.0 { &with } else { &without };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        observe_profile(&frame, &scene(), 0, model, &sensor(), 7, &mut rng)
    };
    let at = |s: &Sensed, id: &str| {
        let k = s
            .truth
            .detections
            .iter()
            .position(|t| t.object_id.as_deref() == Some(id))
            .unwrap();
        (
            s.observation.detections[k].position_m,
            s.truth.detections[k].visible_fraction,
        )
    };
    let (mut closer, mut n) = (0.0, 0.0);
    let mut vis = 0.0;
    for seed in 0..2000 {
        let (off, on) = (sense(0.0, seed), sense(1.0, seed));
        assert_eq!(at(&off, "front"), at(&on, "front"));
        let (p_off, v) = at(&off, "hidden");
        let (p_on, _) = at(&on, "hidden");
        closer += p_off.norm() - p_on.norm();
        n += 1.0;
        vis = v;
    }
    assert!(vis > 0.2 && vis < 0.8, "visible fraction {vis}");
    let expected = (1.0 - vis) * 4.6 / 2.0;
    let closer = closer / n;
    assert!(
        (closer / expected - 1.0).abs() < 0.1,
        "{closer} m closer, expected {expected} m"
    );
}

/// A rig's sensors each look from their own pose: a rear camera sees
/// the car behind, which the profile's one front camera cannot; a
/// sensor reaching beyond the range bins is refused.
#[test]
fn a_rig_senses_with_its_own_sensors() {
    let mut p = params();
    p.recall = vec![1.0; 3];
    let front = ProfileModel::new(p).unwrap();
    let sensor_at = |yaw_deg: f64, range_m: f64| RigSensor {
        geometry: CameraSettings {
            fov_rad: 90f64.to_radians(),
            range_m,
            height_m: 1.5,
            yaw_offsets_rad: vec![yaw_deg.to_radians()],
        },
        mount: Mount::Roof,
    };
    let both = front
        .with_rig(vec![sensor_at(0.0, 60.0), sensor_at(180.0, 60.0)])
        .unwrap();
    let frame = TrafficFrame {
        step: 0,
        time_s: 0.0,
        objects: vec![car("ego", 0.0, 0.0), car("behind", -20.0, 0.0)],
    };
    let ids = |m: &ProfileModel| {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let s = observe_profile(&frame, &scene(), 0, m, &sensor(), 7, &mut rng);
        s.truth
            .detections
            .iter()
            .filter_map(|t| t.object_id.clone())
            .collect::<Vec<_>>()
    };
    assert!(ids(&front).is_empty());
    assert_eq!(ids(&both), vec!["behind".to_owned()]);
    assert_eq!(front.sensors().len(), 1);
    assert_eq!(both.sensors().len(), 2);
    let e = front.with_rig(vec![sensor_at(0.0, 61.0)]).unwrap_err();
    assert_eq!(e.field, "sensors", "{e}");
    assert!(front.with_rig(Vec::new()).is_err());
}

#[test]
fn unusable_parameters_are_refused_by_name() {
    type Edit = Box<dyn Fn(&mut ProfileParams)>;
    let cases: Vec<(&str, Edit)> = vec![
        (
            "recall",
            Box::new(|p| p.recall.pop().map(|_| ()).unwrap_or(())),
        ),
        ("tail_dof", Box::new(|p| p.tail_dof = 2.0)),
        (
            "bin_edges_m",
            Box::new(|p| p.bin_edges_m = vec![20.0, 10.0, 60.0]),
        ),
        ("bin_edges_m", Box::new(|p| p.range_m = 80.0)),
        ("mean_error_m", Box::new(|p| p.depth_bias_per_m = 0.1)),
        (
            "class_confusion",
            Box::new(|p| p.class_confusion[2][2] = 0.5),
        ),
        ("ghost_prob", Box::new(|p| p.ghost_prob = 1.5)),
        (
            "correlation_time_s",
            Box::new(|p| p.correlation_time_s = 0.0),
        ),
    ];
    for (field, edit) in cases {
        let mut p = params();
        edit(&mut p);
        let e = ProfileModel::new(p).unwrap_err();
        assert_eq!(e.field, field, "{e}");
    }
}
