//! A re-identification descriptor (`[appearance] descriptor = "reid"`):
//! what a re-identification network's features would say about each
//! detection, as a vector of configurable width whose cross-view quality
//! is calibrated to a target.
//!
//! A detection's descriptor is its road user's look plus noise. The look
//! is a sum of fixed directions of the descriptor space (drawn once from
//! named streams, the same in every run): its class, its model (from the
//! catalogue, else its SUMO type) as seen from the front, the side or the
//! rear (blended by the angle at which the camera sees it), its paint (a
//! fixed projection of the RGB colour, so that white and silver are
//! close) and the vehicle's own features (per id and traffic seed: the
//! number plate, dirt, a roof box). The noise is Gaussian with standard
//! deviation `sigma exp(d / range + 1 - visible)`, so it grows with
//! distance and occlusion. Each view adds a bias of its own (a direction
//! and a strength drawn per camera and step, `bias` at most: the
//! lighting and exposure every detection of one image shares), which
//! moves all of a view's similarities together. Calibration
//! ([`calibrate`]) chooses `sigma` and `bias` on the validation runs so
//! that the cross-view rank-1 rate and the same/different AUROC
//! ([`figures`]) meet their targets.

use crate::geometry::Vec2;
use crate::rng::{self, Purpose};
use crate::traffic::{ObjectClass, TrafficFrame};

use super::{DescriptorLaw, Sensed};

mod calibration;

pub(crate) use self::calibration::describe_detections;
pub use self::calibration::{
    DescribedViews, ReidError, ScoredScene, SightingPair, calibrate, figures, labelled_pairs,
};

/// `[appearance] descriptor = "reid"`: the descriptor's width and the
/// figures it is calibrated to, and the calibration once made.
#[derive(Clone, Debug, PartialEq)]
pub struct ReidSettings {
    pub width: usize,
    pub target: ReidTarget,
    /// Made on the validation runs ([`calibrate`]) before any run uses the
    /// descriptor.
    pub calibration: Option<ReidCalibration>,
}

/// The cross-view figures a descriptor is calibrated to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReidTarget {
    pub rank1: f64,
    /// `None`: only the rank-1 rate is calibrated, the views carry no
    /// bias.
    pub auroc: Option<f64>,
}

/// The noise of the descriptor: standard deviation `sigma exp(spoil)`
/// per unit of the look's scale (`spoil = d / range + 1 - visible`), and
/// the largest strength of a view's bias.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReidNoise {
    pub sigma: f64,
    pub bias: f64,
}

/// A calibration: the noise, what the cosine says (fitted on the same
/// validation pairs; `None` when it tells nothing apart) and the figures
/// measured at the noise.
#[derive(Clone, Debug, PartialEq)]
pub struct ReidCalibration {
    pub noise: ReidNoise,
    pub law: Option<DescriptorLaw>,
    pub figures: ReidFigures,
}

/// How well descriptors re-identify objects across two views.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReidFigures {
    /// The share of objects seen in both views whose partner is the most
    /// similar (by cosine) of the other view's detections.
    pub rank1: f64,
    /// The probability that a same-object pair is more similar than a
    /// pair of different objects (or a false positive).
    pub auroc: f64,
    /// Objects seen in both views, counted from each side.
    pub queries: usize,
    /// The mean number of candidates a query is ranked among.
    pub candidates: f64,
    /// Mean cosine of same-object pairs and of the others.
    pub same_cos: f64,
    pub different_cos: f64,
}

/// The largest view bias calibration tries.
const MAX_BIAS: f64 = 30.0;

/// Weights of the look's parts [assume: chosen so that a model and a
/// paint together say about as much as the vehicle's own features; the
/// noise, calibrated, decides how much of it survives].
const CLASS_WEIGHT: f64 = 0.5;
const MODEL_WEIGHT: f64 = 1.0;
/// How much the model's look differs between front, side and rear.
const VIEW_WEIGHT: f64 = 0.6;
const PAINT_WEIGHT: f64 = 0.8;
const INDIVIDUAL_WEIGHT: f64 = 1.5;

/// The seed of the descriptor space's fixed directions (not a run's: the
/// same "network" describes every run).
const SPACE_SEED: u64 = 0x5EED_0052;

/// One detection as the descriptor sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct Sighting {
    /// The detected object (its id's hash; `None` for a false positive):
    /// labels for calibration only.
    pub object: Option<u64>,
    pub class: ObjectClass,
    /// The model's name in the descriptor space (catalogue index or SUMO
    /// type).
    pub model_key: u64,
    /// The paint, RGB in [0, 1].
    pub colour_rgb: [f64; 3],
    /// The vehicle's own features (per id and traffic seed).
    pub individual_key: u64,
    /// Where the camera is as the object sees it: 0 ahead (its front is
    /// seen), pi behind (its rear), +-pi/2 beside it.
    pub view_rad: f64,
    /// `d / range + 1 - visible fraction`: what makes the noise grow.
    pub spoil: f64,
    /// The name of its noise stream.
    pub noise_key: u64,
    /// The view it belongs to (camera and step): the name of the view's
    /// bias.
    pub view_key: u64,
}

/// A fixed direction of the descriptor space: N(0, 1/width) per entry.
fn direction(parts: &[u64], width: usize) -> Vec<f64> {
    let mut s = rng::stream(SPACE_SEED, Purpose::ReidLook, parts);
    normals(&mut s, width)
}

fn normals(s: &mut impl rand::Rng, width: usize) -> Vec<f64> {
    let scale = 1.0 / (width as f64).sqrt();
    (0..width)
        .map(|_| scale * s.sample::<f64, _>(rand_distr::StandardNormal))
        .collect()
}

fn add(v: &mut [f64], w: f64, d: &[f64]) {
    for (x, y) in v.iter_mut().zip(d) {
        *x += w * y;
    }
}

/// The look of a sighting, before noise.
pub fn look(s: &Sighting, width: usize) -> Vec<f64> {
    let mut v = vec![0.0; width];
    let class = ObjectClass::ALL
        .iter()
        .position(|c| *c == s.class)
        .unwrap_or(0) as u64;
    add(&mut v, CLASS_WEIGHT, &direction(&[1, class], width));
    add(&mut v, MODEL_WEIGHT, &direction(&[2, s.model_key], width));
    let (c, sn) = (s.view_rad.cos(), s.view_rad.sin());
    let views = [
        (c.max(0.0).powi(2), 3),
        (sn * sn, 4),
        ((-c).max(0.0).powi(2), 5),
    ];
    for (w, code) in views {
        if w > 0.0 {
            add(
                &mut v,
                MODEL_WEIGHT * VIEW_WEIGHT * w,
                &direction(&[code, s.model_key], width),
            );
        }
    }
    let paint_scale = PAINT_WEIGHT / 3f64.sqrt();
    for (k, c) in s.colour_rgb.iter().enumerate() {
        add(
            &mut v,
            paint_scale * (2.0 * c - 1.0),
            &direction(&[7, k as u64], width),
        );
    }
    add(
        &mut v,
        INDIVIDUAL_WEIGHT,
        &direction(&[6, s.individual_key], width),
    );
    v
}

/// The sighting's noise direction (unscaled).
fn noise(s: &Sighting, width: usize) -> Vec<f64> {
    let mut stream = rng::stream(SPACE_SEED, Purpose::ReidNoise, &[s.noise_key]);
    normals(&mut stream, width)
}

fn noise_scale(s: &Sighting, n: ReidNoise) -> f64 {
    n.sigma * s.spoil.exp()
}

/// The direction of a view's bias (unscaled).
fn view_bias(s: &Sighting, width: usize) -> Vec<f64> {
    let mut stream = rng::stream(SPACE_SEED, Purpose::ReidNoise, &[1, s.view_key]);
    normals(&mut stream, width)
}

/// The strength of a view's bias: `bias` times a share drawn per view.
fn bias_scale(s: &Sighting, n: ReidNoise) -> f64 {
    n.bias * rng::unit(SPACE_SEED, Purpose::ReidNoise, &[2, s.view_key])
}

/// The descriptor of a sighting at `noise`: its look plus the noise and
/// its view's bias, scaled to unit length.
pub fn describe(s: &Sighting, width: usize, n: ReidNoise) -> Vec<f32> {
    let mut v = look(s, width);
    add(&mut v, noise_scale(s, n), &noise(s, width));
    add(&mut v, bias_scale(s, n), &view_bias(s, width));
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-12);
    v.iter().map(|x| (x / norm) as f32).collect()
}

/// One sighting per detection of `sensed` (in its order), from the truth
/// behind it: `frame` is the step it was sensed at, `ego` the sensing
/// vehicle's index in it, `range_m` its camera's range.
pub fn sightings(
    sensed: &Sensed,
    frame: &TrafficFrame,
    ego: usize,
    range_m: f64,
    seeds: (u64, u64),
) -> Vec<Sighting> {
    let (traffic_seed, sensor_seed) = seeds;
    let ego_obj = &frame.objects[ego];
    let ego_hash = rng::hash_str(&ego_obj.id);
    let ego_at = ego_obj.pose.position_m();
    let obs = &sensed.observation.detections;
    obs.iter()
        .zip(&sensed.truth.detections)
        .map(|(det, truth)| {
            let object = truth
                .object_id
                .as_deref()
                .and_then(|id| frame.find(id))
                .map(|k| &frame.objects[k]);
            match object {
                Some(o) => {
                    let id_hash = rng::hash_str(&o.id);
                    let model_key = match o.model {
                        Some(m) => rng::key(&[1, u64::from(m)]),
                        None => rng::key(&[2, rng::hash_str(&o.type_id)]),
                    };
                    let seen_from = o.pose.to_body(&ego_at);
                    let d = (o.pose.position_m() - ego_at).norm();
                    Sighting {
                        object: Some(id_hash),
                        class: o.class,
                        model_key,
                        colour_rgb: o.colour_rgb.map(|c| f64::from(c) / 255.0),
                        individual_key: rng::key(&[traffic_seed, id_hash]),
                        view_rad: seen_from.y.atan2(seen_from.x),
                        spoil: d / range_m + (1.0 - truth.visible_fraction),
                        noise_key: rng::key(&[sensor_seed, frame.step, ego_hash, id_hash]),
                        view_key: rng::key(&[sensor_seed, frame.step, ego_hash]),
                    }
                }
                None => clutter(det, frame.step, ego_hash, range_m, sensor_seed),
            }
        })
        .collect()
}

/// A false positive's sighting: a look of no vehicle (its own model and
/// features, its observed colour), seen from an angle of its own.
fn clutter(
    det: &super::Detection,
    step: u64,
    ego_hash: u64,
    range_m: f64,
    sensor_seed: u64,
) -> Sighting {
    let at: Vec2 = det.position_m;
    let key = rng::key(&[sensor_seed, step, ego_hash, at.x.to_bits(), at.y.to_bits()]);
    Sighting {
        object: None,
        class: det.appearance.class,
        model_key: rng::key(&[3, key]),
        colour_rgb: det.appearance.colour_rgb,
        individual_key: rng::key(&[4, key]),
        view_rad: rng::unit(SPACE_SEED, Purpose::ReidLook, &[8, key]) * std::f64::consts::TAU,
        spoil: at.norm() / range_m + 1.0,
        noise_key: key,
        view_key: rng::key(&[sensor_seed, step, ego_hash]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sighting(object: u64, model: u64, view_rad: f64, spoil: f64, noise_key: u64) -> Sighting {
        Sighting {
            object: Some(object),
            class: ObjectClass::Car,
            model_key: model,
            colour_rgb: [0.9, 0.9, 0.9],
            individual_key: object,
            view_rad,
            spoil,
            noise_key,
            view_key: noise_key / 1000,
        }
    }

    fn cos(a: &[f32], b: &[f32]) -> f64 {
        super::super::cosine(a, b)
    }

    /// A view from the side and one from behind describe one vehicle
    /// differently; two views from one side alike; another vehicle of
    /// the same model and paint, seen from the same side, is less alike
    /// than the vehicle itself from behind.
    #[test]
    fn a_side_view_and_a_rear_view_describe_one_vehicle_differently() {
        let quiet = ReidNoise {
            sigma: 0.0,
            bias: 0.0,
        };
        let w = 128;
        let side = describe(
            &sighting(1, 7, std::f64::consts::FRAC_PI_2, 0.2, 1),
            w,
            quiet,
        );
        let side_again = describe(
            &sighting(1, 7, -std::f64::consts::FRAC_PI_2, 0.9, 2),
            w,
            quiet,
        );
        let rear = describe(&sighting(1, 7, std::f64::consts::PI, 0.2, 3), w, quiet);
        let twin_side = describe(
            &sighting(2, 7, std::f64::consts::FRAC_PI_2, 0.2, 4),
            w,
            quiet,
        );
        assert!((cos(&side, &side_again) - 1.0).abs() < 1e-6);
        let side_rear = cos(&side, &rear);
        assert!(side_rear < 0.97, "{side_rear}");
        // Its own features still tell it from a twin of its model and
        // paint seen from the same side.
        let twin = cos(&side, &twin_side);
        assert!(twin < side_rear, "{twin} vs {side_rear}");
        // Noise: the same view twice is no longer identical, more so far
        // away.
        let noisy = ReidNoise {
            sigma: 0.3,
            bias: 0.0,
        };
        let near = cos(
            &describe(&sighting(1, 7, 1.0, 0.1, 5), w, noisy),
            &describe(&sighting(1, 7, 1.0, 0.1, 6), w, noisy),
        );
        let far = cos(
            &describe(&sighting(1, 7, 1.0, 1.8, 5), w, noisy),
            &describe(&sighting(1, 7, 1.0, 1.8, 6), w, noisy),
        );
        assert!(near < 0.999 && far < near, "{near} {far}");
    }

    /// Known scores give known figures: a partner strictly the most
    /// similar counts, a tie does not; AUROC by ranks, ties a half.
    #[test]
    fn figures_count_rank_one_and_auroc_by_hand() {
        let scene = ScoredScene {
            a: vec![Some(1), Some(2), None],
            b: vec![Some(1), Some(2)],
            // a1: b1 0.9, b2 0.5 (hit); a2: b1 0.7, b2 0.7 (tie: miss);
            // clutter 0.1, 0.2.
            cos: vec![0.9, 0.5, 0.7, 0.7, 0.1, 0.2],
        };
        let f = figures(&[scene]);
        // Queries: a1 (hit), a2 (tie), b1 (0.9 vs 0.7, 0.1: hit), b2 (0.7
        // vs 0.5, 0.2 but 0.7 ties with a2's? b2's partner is a2 at 0.7,
        // others a1 0.5 and clutter 0.2: hit).
        assert_eq!(f.queries, 4);
        assert!((f.rank1 - 0.75).abs() < 1e-12, "{}", f.rank1);
        // Positives 0.9, 0.7; negatives 0.5, 0.7, 0.1, 0.2: 0.9 beats 4,
        // 0.7 beats 3 and ties 1: (4 + 3.5) / 8.
        assert!((f.auroc - 7.5 / 8.0).abs() < 1e-12, "{}", f.auroc);
        assert!((f.candidates - 2.5).abs() < 1e-12);
    }

    /// Scenes of a few cars of a few models, seen from random angles and
    /// distances: calibration meets two different targets within 10 %,
    /// and its fast arithmetic agrees with describing each sighting.
    #[test]
    fn calibration_meets_two_targets_on_synthetic_views() {
        use rand::{Rng, SeedableRng};
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut pairs = Vec::new();
        for scene in 0..150u64 {
            let objects: Vec<u64> = (0..10).map(|k| scene * 100 + k).collect();
            let mut side = |flip: bool| -> Vec<Sighting> {
                let kept: Vec<u64> = objects
                    .iter()
                    .copied()
                    .filter(|_| r.random::<f64>() < 0.75)
                    .collect();
                kept.into_iter()
                    .map(|o| {
                        let mut s = sighting(
                            o,
                            o % 4,
                            r.random::<f64>() * std::f64::consts::TAU,
                            r.random::<f64>() * 1.5,
                            r.random(),
                        );
                        s.view_key = scene * 2 + u64::from(flip);
                        s.colour_rgb = [[0.95; 3], [0.1; 3], [0.45; 3]][(o % 3) as usize];
                        s
                    })
                    .collect()
            };
            let (a, b) = (side(false), side(true));
            pairs.push(SightingPair { a, b });
        }
        let w = 32;
        for target in [
            ReidTarget {
                rank1: 0.39,
                auroc: Some(0.67),
            },
            ReidTarget {
                rank1: 0.7,
                auroc: None,
            },
        ] {
            let (n, f, scored) = calibrate(&pairs, w, target).unwrap();
            assert!(
                (f.rank1 / target.rank1 - 1.0).abs() < 0.1,
                "{target:?}: {f:?}"
            );
            if let Some(a) = target.auroc {
                assert!((f.auroc / a - 1.0).abs() < 0.1, "{target:?}: {f:?}");
            }
            // The arithmetic agrees with the descriptors themselves.
            let p = &pairs[3];
            let da: Vec<Vec<f32>> = p.a.iter().map(|s| describe(s, w, n)).collect();
            let db: Vec<Vec<f32>> = p.b.iter().map(|s| describe(s, w, n)).collect();
            for (i, x) in da.iter().enumerate() {
                for (j, y) in db.iter().enumerate() {
                    let c = scored[3].cos[i * p.b.len() + j];
                    assert!((cos(x, y) - c).abs() < 1e-5, "{} vs {c}", cos(x, y));
                }
            }
        }
        // Below chance among the candidates: out of reach.
        let Err(e) = calibrate(
            &pairs,
            w,
            ReidTarget {
                rank1: 0.01,
                auroc: None,
            },
        ) else {
            panic!("rank-1 0.01 was reached");
        };
        assert!(e.to_string().contains("cannot reach rank-1"), "{e}");
    }
}
