//! The camera stand-in: what a connected vehicle's cameras detect in one
//! traffic frame, with occlusion, distance-dependent noise, misses, false
//! positives and appearance descriptors that do not identify objects alone;
//! and the GPS pose each vehicle reports.
//!
//! Pure computation: a frame and a seeded stream in, a [`Sensed`] out. What
//! the vehicle knows ([`Observation`]: detections in its body frame, x
//! forward, y left, metres) is kept apart from what only the simulator
//! knows ([`ObservationTruth`]: the true object behind each detection and the
//! ego's true pose), so that matchers, which receive observations, cannot
//! reach the truth by construction.
//!
//! `camera`: the paper's camera model (frustum, 2.5-D occlusion, range and
//! bearing noise, misses, false positives, appearance). `fleet`: which
//! vehicles carry the rig and which of them exchange detections.
//! `profile`: detectors from published figures. `boxes`: each
//! detection's reported heading and speed. This file: what a detection
//! and an observation are, and the GPS pose a vehicle reports.

pub(crate) mod boxes;
mod camera;
mod fleet;
pub mod gnss;
mod levels;
pub(crate) mod profile;
pub mod reid;

pub use gnss::reported_pose;
pub use levels::PoseNoiseLabel;

use rand::Rng;

use crate::geometry::{Cov2, Pose2, Vec2};
use crate::traffic::{ObjectClass, TrafficObject};

pub(crate) use camera::{observe, visible_fraction};
pub(crate) use fleet::{ConnectedSelection, LinkSettings};

/// `[camera]`: the camera rig every connected vehicle carries.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Horizontal field of view of each camera (OpenCDA uses 100 deg, DMGM
    /// 120, Artery 60).
    pub(crate) fov_rad: f64,
    /// Detection range (OpenCDA 50 m, Artery 80 m).
    pub(crate) range_m: f64,
    /// Height of the camera above the ground (a roof-line camera on a car).
    pub(crate) height_m: f64,
    /// One camera per entry, yawed from the vehicle's heading; the cameras
    /// sit at the front bumper.
    pub(crate) yaw_offsets_rad: Vec<f64>,
}

/// `[sensor]`: the detector stand-in. The defaults (`configs/default.toml`)
/// are calibrated so the mean single-vehicle displacement error on the
/// default scenario is about 2.0 m (docs/results.md, "Calibration of the
/// sensor noise").
#[derive(Clone, Debug, PartialEq)]
pub struct SensorSettings {
    /// An object is detected only when at least this share of its footprint
    /// samples (centre, corners, edge midpoints) is in view and unblocked.
    pub(crate) min_visible_fraction: f64,
    /// Sight lines aim at this fraction of the object's height: a car hides a
    /// car or a person behind it, not the upper half of a truck.
    pub(crate) aim_height_fraction: f64,
    /// Range noise standard deviation: `base + per_m * distance`.
    pub(crate) range_sigma_base_m: f64,
    pub(crate) range_sigma_per_m: f64,
    /// Bearing noise standard deviation: `base + per_m * distance`.
    pub(crate) bearing_sigma_base_rad: f64,
    pub(crate) bearing_sigma_per_m_rad: f64,
    /// Miss probability: base, plus a share growing linearly to
    /// `miss_prob_at_max_range` at the camera's range, plus
    /// `miss_prob_occlusion * (1 - visible fraction)`.
    pub(crate) miss_prob_base: f64,
    pub(crate) miss_prob_at_max_range: f64,
    pub(crate) miss_prob_occlusion: f64,
    /// Mean number of false positives per camera and frame (Poisson).
    pub(crate) false_positives_per_frame: f64,
    /// Probability that the detector reports the confusable class.
    pub(crate) class_confusion_prob: f64,
    /// Colour noise per channel (RGB in [0, 1]) at zero distance; doubles at
    /// the camera's range.
    pub(crate) colour_sigma: f64,
    /// View-dependent brightness: colours scale by a factor drawn uniformly
    /// from `1 +- lighting_spread`.
    pub(crate) lighting_spread: f64,
    /// Relative noise on the measured length, width and height.
    pub(crate) size_sigma_fraction: f64,
    /// What a road user whose demand gives no colour looks like.
    pub(crate) unset_colours: crate::traffic::UnsetColours,
    /// The errors of the boxes' heading and speed (the paper's model).
    pub(crate) boxes: boxes::BoxErrors,
}

/// `[appearance]`: what road users look like beyond the demand, and what
/// a detection's appearance says. The default (no catalogue, no
/// descriptor) is the demand's sizes and colours and the class, colour
/// and size a detector reports.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AppearanceSettings {
    /// `vehicles = "catalogue"`: the catalogue vehicles are drawn from.
    pub catalogue: Option<std::sync::Arc<crate::traffic::catalogue::Catalogue>>,
    /// `descriptor = "reid"`: a re-identification descriptor beside the
    /// class, colour and size.
    pub reid: Option<reid::ReidSettings>,
}

impl AppearanceSettings {
    /// Whether nothing differs from the default.
    pub fn is_default(&self) -> bool {
        self.catalogue.is_none() && self.reid.is_none()
    }

    /// Whether a descriptor is asked for and not yet calibrated.
    pub fn uncalibrated(&self) -> bool {
        self.reid.as_ref().is_some_and(|r| r.calibration.is_none())
    }

    /// The width of the descriptor the sensor gives detections, once
    /// calibrated with a cosine that tells objects apart.
    pub fn appearance_width(&self) -> AppearanceWidth {
        self.reid
            .as_ref()
            .filter(|r| r.calibration.as_ref().is_some_and(|c| c.law.is_some()))
            .map_or(AppearanceWidth::NONE, |r| AppearanceWidth::new(r.width))
    }
}

/// The width of the appearance vectors (a re-identification descriptor, a
/// dataset's learned features) that detections carry and a network reads
/// beside class, colour and size: none, or a positive number of values.
/// One value under one name, derived once (`Settings::appearance_width`,
/// a record's architecture) and passed on; written as its number (a
/// record leaves out none).
#[derive(Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct AppearanceWidth(Option<std::num::NonZeroUsize>);

impl AppearanceWidth {
    /// No appearance vectors.
    pub const NONE: Self = Self(None);

    /// `width` values per node (0: none).
    pub fn new(width: usize) -> Self {
        Self(std::num::NonZeroUsize::new(width))
    }

    /// Values per node (0: none).
    pub fn get(self) -> usize {
        self.0.map_or(0, std::num::NonZeroUsize::get)
    }

    /// Whether there are none.
    pub fn is_none(&self) -> bool {
        self.0.is_none()
    }

    /// The width, if there is one.
    pub fn width(self) -> Option<usize> {
        self.0.map(std::num::NonZeroUsize::get)
    }
}

/// As the optional width it stands for (`Some(900)`, `None`): a config's
/// digest hashes this text.
impl std::fmt::Debug for AppearanceWidth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.width().fmt(f)
    }
}

impl serde::Serialize for AppearanceWidth {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u64(self.get() as u64)
    }
}

impl<'de> serde::Deserialize<'de> for AppearanceWidth {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let w = u64::deserialize(d)?;
        usize::try_from(w)
            .map(Self::new)
            .map_err(|_| serde::de::Error::custom(format!("{w} values per node")))
    }
}

/// One pose-noise level: every connected vehicle's reported pose is its true
/// pose plus Gaussian errors, drawn afresh per step or drifting with a
/// correlation time.
#[derive(Clone, Copy, PartialEq)]
pub struct PoseNoiseLevel {
    pub label: PoseNoiseLabel,
    /// Standard deviation of the error along each of x and y.
    pub position_sigma_m: f64,
    pub heading_sigma_rad: f64,
    /// The level's own GNSS correlation time (s) [default: `[v2x]
    /// gnss_correlation_s`, [`PoseNoiseLevel::correlation_s`]].
    pub correlation_s: Option<f64>,
}

impl PoseNoiseLevel {
    /// The level's GNSS correlation time (s): its own, else `default_s`
    /// (`[v2x] gnss_correlation_s`); 0 draws the error afresh per step.
    pub fn correlation_s(&self, default_s: f64) -> f64 {
        self.correlation_s.unwrap_or(default_s)
    }
}

/// As derived, the correlation time shown only when the level has its own
/// (settings' digests without one stay as they were).
impl std::fmt::Debug for PoseNoiseLevel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("PoseNoiseLevel");
        d.field("label", &self.label)
            .field("position_sigma_m", &self.position_sigma_m)
            .field("heading_sigma_rad", &self.heading_sigma_rad);
        if let Some(tau) = &self.correlation_s {
            d.field("correlation_s", tau);
        }
        d.finish()
    }
}

/// What the detector reports about an object's look: class (sometimes
/// confused), colour under the scene's lighting, and a noisy size. Many cars
/// share class, colour and size, so this alone does not identify an object.
#[derive(Clone, Debug, PartialEq)]
pub struct Appearance {
    pub class: ObjectClass,
    /// Observed colour, RGB in [0, 1].
    pub colour_rgb: [f64; 3],
    pub length_m: f64,
    pub width_m: f64,
    pub height_m: f64,
    /// A learned appearance descriptor (a re-identification network's
    /// features), where the source gives one: a dataset read from
    /// elsewhere; coid's sensor model makes none.
    pub descriptor: Option<Descriptor>,
}

/// A learned appearance descriptor and what its cosine similarity says
/// ([`DescriptorLaw`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Descriptor {
    pub values: std::sync::Arc<[f32]>,
    pub law: DescriptorLaw,
}

/// What the cosine similarity of two descriptors says about whether they
/// show one object, fitted on validation data: the log-likelihood ratio
/// `slope (cos - neutral)` (same object against two different ones), 0 at
/// the `neutral` similarity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DescriptorLaw {
    pub slope: f64,
    pub neutral: f64,
}

impl Descriptor {
    /// The cosine similarity of two descriptors (0 when either is zero).
    pub fn cosine(&self, other: &Descriptor) -> f64 {
        cosine(&self.values, &other.values)
    }

    /// The likelihood ratio of one object against two, from their cosine
    /// similarity: `exp(slope (cos - neutral))` (above 1 for pairs more
    /// alike than the neutral similarity).
    pub fn likelihood_ratio(&self, other: &Descriptor) -> f64 {
        let law = self.law;
        (law.slope.max(0.0) * (self.cosine(other) - law.neutral)).exp()
    }

    /// The likelihood ratio of two identical descriptors: the most any
    /// pair gets.
    pub fn most_alike_ratio(&self) -> f64 {
        let law = self.law;
        (law.slope.max(0.0) * (1.0 - law.neutral)).exp()
    }
}

/// The cosine similarity of two vectors (0 when either is zero).
pub fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let (mut ab, mut aa, mut bb) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        let (x, y) = (f64::from(*x), f64::from(*y));
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    if aa == 0.0 || bb == 0.0 {
        0.0
    } else {
        ab / (aa.sqrt() * bb.sqrt())
    }
}

/// One detection in one vehicle's body frame: what the vehicle knows.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// Measured object centre, ego body frame.
    pub position_m: Vec2,
    /// Covariance of `position_m` from the same noise model that drew it.
    pub cov_m2: Cov2,
    pub appearance: Appearance,
    /// The box's heading (body frame) and speed as the detector reports
    /// them; `None` where the source reports no box (a V2X track, a map
    /// view, a test).
    pub motion: Option<boxes::Motion>,
}

/// Everything one connected vehicle perceives at one step.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    pub(crate) ego_id: String,
    pub(crate) detections: Vec<Detection>,
}

/// Evaluation only: what lies behind one detection.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DetectionTruth {
    /// SUMO id of the detected object; `None` for a false positive.
    pub(crate) object_id: Option<String>,
    /// The object's true centre, world frame; `None` for a false positive.
    pub(crate) position_m: Option<Vec2>,
    /// The share of footprint samples that were visible (0 for a false
    /// positive, 1 for a sender's own node).
    pub(crate) visible_fraction: f64,
    /// Whether this is the sender's own node (its self-report), not a
    /// camera detection.
    pub(crate) sender: bool,
}

/// Evaluation only: the truth beside an [`Observation`], one entry per
/// detection in the same order.
#[derive(Clone, Debug, PartialEq)]
pub struct ObservationTruth {
    /// The ego's true centre pose, world frame.
    pub(crate) ego_pose: Pose2,
    pub(crate) detections: Vec<DetectionTruth>,
}

impl ObservationTruth {
    /// The true object id behind detection `k` (`None`: false positive).
    pub(crate) fn object_id(&self, k: usize) -> Option<&str> {
        self.detections[k].object_id.as_deref()
    }

    /// The index of the detection of object `id`, if this vehicle detected it.
    pub(crate) fn find(&self, id: &str) -> Option<usize> {
        self.detections
            .iter()
            .position(|d| d.object_id.as_deref() == Some(id))
    }
}

/// One vehicle's sensing at one step: what it knows, and the truth beside it.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensed {
    pub(crate) observation: Observation,
    pub(crate) truth: ObservationTruth,
    /// Evaluation only: every object the cameras could see at this step
    /// (in view, visible enough), detected or missed: the ground truth a
    /// tracker is scored against.
    pub(crate) visible: Vec<VisibleObject>,
}

/// Evaluation only: an object a camera could see.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct VisibleObject {
    pub(crate) object_id: String,
    /// True centre, world frame.
    pub(crate) position_m: Vec2,
    /// The share of its footprint samples the camera saw.
    pub(crate) visible_fraction: f64,
}

/// How well a sender knows its own centre in its own body frame: its
/// self-report is exact up to the body's size estimate, so a small
/// position sigma (its world pose error is the GPS's, which the receiver
/// of the message accounts for).
const SENDER_SIGMA_M: f64 = 0.1;

impl Sensed {
    /// Appends the sender's own node: what a V2X message (CAM/CPM) carries
    /// about the sender itself, its centre (the origin of its body frame),
    /// class, colour and size, as one more node of its graph. A peer's
    /// camera detection of the sender then has a true partner.
    pub(crate) fn add_sender(&mut self, ego: &TrafficObject) {
        self.observation.detections.push(Detection {
            position_m: Vec2::zeros(),
            cov_m2: Cov2::identity() * SENDER_SIGMA_M.powi(2),
            appearance: Appearance {
                class: ego.class,
                colour_rgb: ego.colour_rgb.map(|c| f64::from(c) / 255.0),
                length_m: ego.length_m,
                width_m: ego.width_m,
                height_m: ego.height_m,
                descriptor: None,
            },
            motion: Some(boxes::Motion {
                heading_rad: 0.0,
                speed_mps: ego.speed_mps,
            }),
        });
        self.truth.detections.push(DetectionTruth {
            object_id: Some(ego.id.clone()),
            position_m: Some(ego.pose.position_m()),
            visible_fraction: 1.0,
            sender: true,
        });
    }

    /// Its own node, when it has one ([`Sensed::add_sender`]): the
    /// detection and its truth.
    pub(crate) fn own_node(&self) -> Option<(Detection, DetectionTruth)> {
        let k = self.truth.detections.iter().position(|d| d.sender)?;
        Some((
            self.observation.detections[k].clone(),
            self.truth.detections[k].clone(),
        ))
    }
}

impl Sensed {
    /// Lists the detections (and their truths, in step) in a random order
    /// drawn from `rng`: the sensor model finds objects in SUMO's order,
    /// false positives after them and the sender's own node last, and two
    /// vehicles would list their shared objects in the same order. No
    /// matcher may learn from that; after this, no order carries labels.
    pub(crate) fn shuffle(&mut self, rng: &mut impl Rng) {
        let mut order: Vec<usize> = (0..self.observation.detections.len()).collect();
        rand::seq::SliceRandom::shuffle(&mut order[..], rng);
        self.observation.detections = order
            .iter()
            .map(|&k| self.observation.detections[k].clone())
            .collect();
        self.truth.detections = order
            .iter()
            .map(|&k| self.truth.detections[k].clone())
            .collect();
    }
}

#[cfg(test)]
mod tests {
    use super::camera::{camera_pose, measure, polar_sigmas};
    use super::*;
    use crate::geometry::Polygon;
    use crate::traffic::{StaticScene, TrafficFrame};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn car(id: &str, x: f64, y: f64, heading: f64) -> TrafficObject {
        TrafficObject {
            id: id.into(),
            class: ObjectClass::Car,
            pose: Pose2::new(Vec2::new(x, y), heading),
            length_m: 4.6,
            width_m: 1.8,
            height_m: 1.5,
            colour_rgb: [200, 10, 10],
            speed_mps: 0.0,
            type_id: "car".into(),
            model: None,
        }
    }

    fn scene(buildings: Vec<Polygon>) -> StaticScene {
        StaticScene {
            junction_id: "C".into(),
            junction_position_m: Vec2::zeros(),
            buildings,
            lanes: Vec::new(),
        }
    }

    fn frame(objects: Vec<TrafficObject>) -> TrafficFrame {
        TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects,
        }
    }

    /// The sensor these tests use (the shipped defaults' values); the
    /// profiles' tests use it too.
    pub(super) fn sensor() -> SensorSettings {
        SensorSettings {
            min_visible_fraction: 0.3,
            aim_height_fraction: 0.6,
            range_sigma_base_m: 0.3,
            range_sigma_per_m: 0.095,
            bearing_sigma_base_rad: 0.5_f64.to_radians(),
            bearing_sigma_per_m_rad: 0.02_f64.to_radians(),
            miss_prob_base: 0.03,
            miss_prob_at_max_range: 0.15,
            miss_prob_occlusion: 0.3,
            false_positives_per_frame: 0.3,
            class_confusion_prob: 0.1,
            colour_sigma: 0.06,
            lighting_spread: 0.25,
            size_sigma_fraction: 0.1,
            unset_colours: crate::traffic::UnsetColours::Drawn,
            boxes: boxes::BoxErrors {
                heading_sigma_rad: 0.19,
                heading_flip_prob: 0.02,
                speed_sigma_mps: 0.52,
            },
        }
    }

    fn vis(f: &TrafficFrame, sc: &StaticScene, target: usize) -> f64 {
        let cam = CameraSettings {
            fov_rad: 90f64.to_radians(),
            range_m: 70.0,
            height_m: 1.5,
            yaw_offsets_rad: vec![0.0],
        };
        let pose = camera_pose(&f.objects[0], 0.0);
        visible_fraction(&pose, 0, target, f, sc, &cam, &sensor())
    }

    #[test]
    fn clear_view_sees_everything() {
        let f = frame(vec![car("ego", 0.0, 0.0, 0.0), car("a", 20.0, 0.0, 0.0)]);
        assert_eq!(vis(&f, &scene(vec![]), 1), 1.0);
    }

    #[test]
    fn outside_the_frustum_or_range_is_invisible() {
        let f = frame(vec![
            car("ego", 0.0, 0.0, 0.0),
            car("behind", -20.0, 0.0, 0.0),
            car("far", 100.0, 0.0, 0.0),
            car("side", 2.3, 30.0, 0.0),
        ]);
        let sc = scene(vec![]);
        assert_eq!(vis(&f, &sc, 1), 0.0);
        assert_eq!(vis(&f, &sc, 2), 0.0);
        assert_eq!(vis(&f, &sc, 3), 0.0);
    }

    #[test]
    fn a_car_hides_a_car_but_not_a_truck_behind_it() {
        let mut truck = car("truck", 30.0, 0.0, 0.0);
        truck.height_m = 3.6;
        truck.length_m = 9.5;
        truck.width_m = 2.5;
        let f = frame(vec![
            car("ego", 0.0, 0.0, 0.0),
            car("blocker", 12.0, 0.0, 0.0),
            car("hidden", 25.0, 0.0, 0.0),
            truck,
        ]);
        let sc = scene(vec![]);
        assert!(vis(&f, &sc, 2) < 0.3, "{}", vis(&f, &sc, 2));
        assert_eq!(vis(&f, &sc, 3), 1.0);
    }

    #[test]
    fn a_car_partly_behind_another_is_partly_visible() {
        let f = frame(vec![
            car("ego", 0.0, 0.0, 0.0),
            car("blocker", 12.0, 0.0, 0.0),
            car("offset", 30.0, 3.0, 0.0),
        ]);
        let v = vis(&f, &scene(vec![]), 2);
        assert!(v > 0.0 && v < 1.0, "{v}");
    }

    #[test]
    fn buildings_block_sight() {
        let wall = Polygon {
            vertices_m: vec![
                Vec2::new(10.0, -5.0),
                Vec2::new(12.0, -5.0),
                Vec2::new(12.0, 5.0),
                Vec2::new(10.0, 5.0),
            ],
        };
        let mut truck = car("truck", 30.0, 0.0, 0.0);
        truck.height_m = 3.6;
        let f = frame(vec![car("ego", 0.0, 0.0, 0.0), truck]);
        assert_eq!(vis(&f, &scene(vec![wall]), 1), 0.0);
    }

    #[test]
    fn zero_noise_gives_exact_positions_and_same_seed_same_detections() {
        let f = frame(vec![
            car("ego", 5.0, 3.0, 0.4),
            car("a", 25.0, 12.0, 1.0),
            car("b", 30.0, 25.0, 0.0),
        ]);
        let cam = CameraSettings {
            fov_rad: 90f64.to_radians(),
            range_m: 70.0,
            height_m: 1.5,
            yaw_offsets_rad: vec![0.0],
        };
        let quiet = SensorSettings {
            range_sigma_base_m: 0.0,
            range_sigma_per_m: 0.0,
            bearing_sigma_base_rad: 0.0,
            bearing_sigma_per_m_rad: 0.0,
            miss_prob_base: 0.0,
            miss_prob_at_max_range: 0.0,
            miss_prob_occlusion: 0.0,
            false_positives_per_frame: 0.0,
            ..sensor()
        };
        let sc = scene(vec![]);
        let sensed = observe(&f, &sc, 0, &cam, &quiet, &mut ChaCha8Rng::seed_from_u64(1));
        let (obs, truth) = (&sensed.observation, &sensed.truth);
        assert_eq!(obs.detections.len(), 2);
        assert_eq!(truth.detections.len(), 2);
        for (k, d) in obs.detections.iter().enumerate() {
            let object = &f.objects[f.find(truth.object_id(k).unwrap()).unwrap()];
            let world = truth.ego_pose.to_parent(&d.position_m);
            assert!((world - object.pose.position_m()).norm() < 1e-9);
            assert_eq!(
                truth.detections[k].position_m,
                Some(object.pose.position_m())
            );
        }
        let noisy = sensor();
        let a = observe(&f, &sc, 0, &cam, &noisy, &mut ChaCha8Rng::seed_from_u64(9));
        let b = observe(&f, &sc, 0, &cam, &noisy, &mut ChaCha8Rng::seed_from_u64(9));
        assert_eq!(a, b);
    }

    #[test]
    fn noise_grows_with_distance_and_matches_its_covariance() {
        let s = sensor();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for d in [10.0, 50.0] {
            let p = Vec2::new(d, 0.0);
            let n = 4000;
            let errs: Vec<Vec2> = (0..n).map(|_| measure(&p, &s, &mut rng).0 - p).collect();
            let var_x = errs.iter().map(|e| e.x * e.x).sum::<f64>() / n as f64;
            let (sr, _) = polar_sigmas(d, &s);
            // The range error dominates along x at bearing 0.
            assert!(
                (var_x.sqrt() / sr - 1.0).abs() < 0.08,
                "d {d}: {} vs {sr}",
                var_x.sqrt()
            );
        }
        let (near, _) = polar_sigmas(10.0, &s);
        let (far, _) = polar_sigmas(50.0, &s);
        assert!(far > near);
    }

    #[test]
    fn pose_noise_level_none_is_exact() {
        let truth = Pose2::new(Vec2::new(3.0, 4.0), 0.3);
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::NONE,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
            correlation_s: None,
        };
        let p = reported_pose(&truth, &level, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(p.position_m(), truth.position_m());
        assert!((p.heading_rad() - truth.heading_rad()).abs() < 1e-15);
    }

    #[test]
    fn penetration_draws_depend_on_the_vehicle_id_only() {
        let all = ConnectedSelection::Penetration(1.0);
        let none_of_them = ConnectedSelection::Penetration(1e-12);
        let mut person = car("p", 0.0, 0.0, 0.0);
        person.class = ObjectClass::Pedestrian;
        assert!(all.carries_rig(1, &car("a", 0.0, 0.0, 0.0)));
        assert!(!all.carries_rig(1, &person));
        assert!(!none_of_them.carries_rig(1, &car("a", 0.0, 0.0, 0.0)));
        let half = ConnectedSelection::Penetration(0.5);
        let chosen = (0..400)
            .filter(|k| half.carries_rig(3, &car(&format!("v{k}"), 0.0, 0.0, 0.0)))
            .count();
        assert!((150..250).contains(&chosen), "{chosen} of 400");
        let ids = ConnectedSelection::Ids(vec!["a".into()]);
        assert!(ids.carries_rig(1, &car("a", 9.0, 9.0, 0.0)));
        assert!(!ids.carries_rig(1, &car("b", 0.0, 0.0, 0.0)));
    }

    fn linked_pairs(link: LinkSettings, positions: &[(f64, f64)]) -> Vec<(usize, usize)> {
        let p: Vec<Vec2> = positions.iter().map(|&(x, y)| Vec2::new(x, y)).collect();
        let links = link.links(&p);
        let mut out = Vec::new();
        for i in 0..p.len() {
            for j in i + 1..p.len() {
                if links.linked(i, j) {
                    out.push((i, j));
                }
            }
        }
        out
    }

    #[test]
    fn the_communication_range_drops_exactly_the_pairs_beyond_it() {
        // Distances: 0-1 50 m, 0-2 100 m, 0-3 150.5 m, 1-2 50 m,
        // 1-3 100.5 m, 2-3 50.5 m.
        let at = [(0.0, 0.0), (50.0, 0.0), (100.0, 0.0), (150.5, 0.0)];
        let all = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
        assert_eq!(linked_pairs(LinkSettings::default(), &at), all);
        let within = |r: f64| LinkSettings {
            comm_range_m: Some(r),
            max_peers: None,
        };
        // A pair exactly at the range is kept; one just beyond is dropped.
        assert_eq!(
            linked_pairs(within(100.0), &at),
            vec![(0, 1), (0, 2), (1, 2), (2, 3)]
        );
        assert_eq!(
            linked_pairs(within(99.9), &at),
            vec![(0, 1), (1, 2), (2, 3)]
        );
        assert!(linked_pairs(within(10.0), &at).is_empty());
    }

    #[test]
    fn at_most_k_peers_nearest_first_and_both_ways() {
        // 1 is nearest to 0; 2 is nearest to 1 (10 m) and to 3 (20 m).
        let at = [(0.0, 0.0), (30.0, 0.0), (40.0, 0.0), (60.0, 0.0)];
        let k = |k: usize| LinkSettings {
            comm_range_m: None,
            max_peers: Some(k),
        };
        // k = 1: 0 picks 1, 1 picks 2, 2 picks 1, 3 picks 2: only 1-2 is
        // chosen by both.
        assert_eq!(linked_pairs(k(1), &at), vec![(1, 2)]);
        // k = 2: 0 {1, 2}, 1 {2, 0}, 2 {1, 3}, 3 {2, 1}.
        assert_eq!(linked_pairs(k(2), &at), vec![(0, 1), (1, 2), (2, 3)]);
        assert_eq!(linked_pairs(k(3), &at).len(), 6);
        // Range first, then the nearest among those in range.
        let both = LinkSettings {
            comm_range_m: Some(25.0),
            max_peers: Some(1),
        };
        assert_eq!(linked_pairs(both, &at), vec![(1, 2),]);
        // Ties go to the vehicle listed first.
        let tie = [(0.0, 0.0), (-10.0, 0.0), (10.0, 0.0)];
        assert_eq!(linked_pairs(k(1), &tie), vec![(0, 1)]);
    }
}
