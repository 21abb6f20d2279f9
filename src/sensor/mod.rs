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

pub mod boxes;
pub mod profile;

use rand::Rng;
use rand_distr::{Distribution, Normal, Poisson};

use crate::geometry::{Cov2, Pose2, Vec2, wrap_angle};
use crate::rng::{self, Purpose};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

/// `[connected]`: which vehicles carry the camera rig.
#[derive(Clone, Debug, PartialEq)]
pub enum ConnectedSelection {
    /// These SUMO vehicle ids carry the camera rig.
    Ids(Vec<String>),
    /// This share of the vehicles (cars, vans, trucks, buses), drawn per
    /// vehicle id from the sensor seed.
    Penetration(f64),
}

impl ConnectedSelection {
    /// Whether `obj` carries the rig (penetration draws are named by the
    /// vehicle id, so they do not depend on the order vehicles appear in).
    pub fn carries_rig(&self, sensor_seed: u64, obj: &TrafficObject) -> bool {
        match self {
            ConnectedSelection::Ids(ids) => ids.contains(&obj.id),
            ConnectedSelection::Penetration(p) => {
                obj.class.can_be_connected()
                    && rng::unit(sensor_seed, Purpose::Penetration, &[rng::hash_str(&obj.id)]) < *p
            }
        }
    }
}

/// `[connected] comm_range_m`, `max_peers`: which connected vehicles
/// exchange detections (a V2X link), from their true positions. Both unset
/// (the default): every pair does.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkSettings {
    /// Vehicles farther apart than this do not exchange (metres).
    pub comm_range_m: Option<f64>,
    /// Each vehicle exchanges with at most this many peers, nearest first
    /// (ties by position in the list): a pair is linked when each is among
    /// the other's nearest peers in range.
    pub max_peers: Option<usize>,
}

impl LinkSettings {
    /// The links among vehicles at `positions_m` (one frame's).
    pub fn links(&self, positions_m: &[Vec2]) -> Links {
        let n = positions_m.len();
        let dist = |i: usize, j: usize| (positions_m[i] - positions_m[j]).norm();
        let in_range = |i: usize, j: usize| self.comm_range_m.is_none_or(|r| dist(i, j) <= r);
        let mut linked = vec![false; n * n];
        for i in 0..n {
            let mut peers: Vec<usize> = (0..n).filter(|&j| j != i && in_range(i, j)).collect();
            if let Some(k) = self.max_peers {
                peers.sort_by(|&a, &b| dist(i, a).total_cmp(&dist(i, b)).then(a.cmp(&b)));
                peers.truncate(k);
            }
            for j in peers {
                linked[i * n + j] = true;
            }
        }
        Links { n, linked }
    }
}

/// Which vehicles of a frame exchange detections ([`LinkSettings::links`]).
#[derive(Clone, Debug)]
pub struct Links {
    n: usize,
    /// Row i: the peers i selected.
    linked: Vec<bool>,
}

impl Links {
    /// Whether `i` and `j` exchange detections (each selected the other).
    pub fn linked(&self, i: usize, j: usize) -> bool {
        self.linked[i * self.n + j] && self.linked[j * self.n + i]
    }
}

/// `[camera]`: the camera rig every connected vehicle carries.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Horizontal field of view of each camera (OpenCDA uses 100 deg, DMGM
    /// 120, Artery 60).
    pub fov_rad: f64,
    /// Detection range (OpenCDA 50 m, Artery 80 m).
    pub range_m: f64,
    /// Height of the camera above the ground (a roof-line camera on a car).
    pub height_m: f64,
    /// One camera per entry, yawed from the vehicle's heading; the cameras
    /// sit at the front bumper.
    pub yaw_offsets_rad: Vec<f64>,
}

/// `[sensor]`: the detector stand-in. The defaults (`configs/default.toml`)
/// are calibrated so the mean single-vehicle displacement error on the
/// default scenario is about 2.0 m (docs/results.md, "Calibration of the
/// sensor noise").
#[derive(Clone, Debug, PartialEq)]
pub struct SensorSettings {
    /// An object is detected only when at least this share of its footprint
    /// samples (centre, corners, edge midpoints) is in view and unblocked.
    pub min_visible_fraction: f64,
    /// Sight lines aim at this fraction of the object's height: a car hides a
    /// car or a person behind it, not the upper half of a truck.
    pub aim_height_fraction: f64,
    /// Range noise standard deviation: `base + per_m * distance`.
    pub range_sigma_base_m: f64,
    pub range_sigma_per_m: f64,
    /// Bearing noise standard deviation: `base + per_m * distance`.
    pub bearing_sigma_base_rad: f64,
    pub bearing_sigma_per_m_rad: f64,
    /// Miss probability: base, plus a share growing linearly to
    /// `miss_prob_at_max_range` at the camera's range, plus
    /// `miss_prob_occlusion * (1 - visible fraction)`.
    pub miss_prob_base: f64,
    pub miss_prob_at_max_range: f64,
    pub miss_prob_occlusion: f64,
    /// Mean number of false positives per camera and frame (Poisson).
    pub false_positives_per_frame: f64,
    /// Probability that the detector reports the confusable class.
    pub class_confusion_prob: f64,
    /// Colour noise per channel (RGB in [0, 1]) at zero distance; doubles at
    /// the camera's range.
    pub colour_sigma: f64,
    /// View-dependent brightness: colours scale by a factor drawn uniformly
    /// from `1 +- lighting_spread`.
    pub lighting_spread: f64,
    /// Relative noise on the measured length, width and height.
    pub size_sigma_fraction: f64,
    /// What a road user whose demand gives no colour looks like.
    pub unset_colours: crate::traffic::UnsetColours,
    /// The errors of the boxes' heading and speed (the paper's model).
    pub boxes: boxes::BoxErrors,
}

crate::label_enum! { "pose-noise level";
    /// The pose-noise levels results are reported at.
    #[strum(serialize_all = "lowercase")]
    pub enum PoseNoiseLabel {
        /// Perfect self-localisation.
        None,
        /// RTK-class GNSS: 0.2 m / 0.2 deg by default.
        Rtk,
        /// Plain GPS as in the DMGM data: 1.2 m / 0.2 deg by default.
        Gps,
    }
}

impl PoseNoiseLabel {
    /// The level's part of a pose-noise stream name (frozen: changing it
    /// changes every result).
    pub fn stream_code(self) -> u64 {
        match self {
            PoseNoiseLabel::None => 0,
            PoseNoiseLabel::Rtk => 1,
            PoseNoiseLabel::Gps => 2,
        }
    }
}

/// One pose-noise level: every connected vehicle's reported pose is its true
/// pose plus independent Gaussian errors, per step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseNoiseLevel {
    pub label: PoseNoiseLabel,
    /// Standard deviation of the error along each of x and y.
    pub position_sigma_m: f64,
    pub heading_sigma_rad: f64,
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
    pub ego_id: String,
    pub detections: Vec<Detection>,
}

/// Evaluation only: what lies behind one detection.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectionTruth {
    /// SUMO id of the detected object; `None` for a false positive.
    pub object_id: Option<String>,
    /// The object's true centre, world frame; `None` for a false positive.
    pub position_m: Option<Vec2>,
    /// The share of footprint samples that were visible (0 for a false
    /// positive, 1 for a sender's own node).
    pub visible_fraction: f64,
    /// Whether this is the sender's own node (its self-report), not a
    /// camera detection.
    pub sender: bool,
}

/// Evaluation only: the truth beside an [`Observation`], one entry per
/// detection in the same order.
#[derive(Clone, Debug, PartialEq)]
pub struct ObservationTruth {
    /// The ego's true centre pose, world frame.
    pub ego_pose: Pose2,
    pub detections: Vec<DetectionTruth>,
}

impl ObservationTruth {
    /// The true object id behind detection `k` (`None`: false positive).
    pub fn object_id(&self, k: usize) -> Option<&str> {
        self.detections[k].object_id.as_deref()
    }

    /// The index of the detection of object `id`, if this vehicle detected it.
    pub fn find(&self, id: &str) -> Option<usize> {
        self.detections
            .iter()
            .position(|d| d.object_id.as_deref() == Some(id))
    }
}

/// One vehicle's sensing at one step: what it knows, and the truth beside it.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensed {
    pub observation: Observation,
    pub truth: ObservationTruth,
    /// Evaluation only: every object the cameras could see at this step
    /// (in view, visible enough), detected or missed: the ground truth a
    /// tracker is scored against.
    pub visible: Vec<VisibleObject>,
}

/// Evaluation only: an object a camera could see.
#[derive(Clone, Debug, PartialEq)]
pub struct VisibleObject {
    pub object_id: String,
    /// True centre, world frame.
    pub position_m: Vec2,
    /// The share of its footprint samples the camera saw.
    pub visible_fraction: f64,
}

/// How well a sender knows its own centre in its own body frame: its
/// self-report is exact up to the body's size estimate, so a small
/// position sigma (its world pose error is the GPS's, which the receiver
/// of the message accounts for).
pub const SENDER_SIGMA_M: f64 = 0.1;

impl Sensed {
    /// Appends the sender's own node: what a V2X message (CAM/CPM) carries
    /// about the sender itself, its centre (the origin of its body frame),
    /// class, colour and size, as one more node of its graph. A peer's
    /// camera detection of the sender then has a true partner.
    pub fn add_sender(&mut self, ego: &TrafficObject) {
        self.observation.detections.push(Detection {
            position_m: Vec2::zeros(),
            cov_m2: Cov2::identity() * SENDER_SIGMA_M.powi(2),
            appearance: Appearance {
                class: ego.class,
                colour_rgb: ego.colour_rgb.map(|c| f64::from(c) / 255.0),
                length_m: ego.length_m,
                width_m: ego.width_m,
                height_m: ego.height_m,
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
}

impl Sensed {
    /// Lists the detections (and their truths, in step) in a random order
    /// drawn from `rng`: the sensor model finds objects in SUMO's order,
    /// false positives after them and the sender's own node last, and two
    /// vehicles would list their shared objects in the same order. No
    /// matcher may learn from that; after this, no order carries labels.
    pub fn shuffle(&mut self, rng: &mut impl Rng) {
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

/// Samples on an object's footprint used for the visibility test: centre,
/// corners and edge midpoints, in the body frame of a unit box.
const FOOTPRINT_SAMPLES: [(f64, f64); 9] = [
    (0.0, 0.0),
    (0.5, 0.5),
    (-0.5, 0.5),
    (-0.5, -0.5),
    (0.5, -0.5),
    (0.5, 0.0),
    (-0.5, 0.0),
    (0.0, 0.5),
    (0.0, -0.5),
];

/// A camera's pose in the world frame: at the middle of the ego's front
/// bumper, yawed by `yaw_offset_rad`.
fn camera_pose(ego: &TrafficObject, yaw_offset_rad: f64) -> Pose2 {
    ego.pose.compose(&Pose2::new(
        Vec2::new(ego.length_m / 2.0, 0.0),
        yaw_offset_rad,
    ))
}

fn in_frustum(cam: &Pose2, p_world: &Vec2, camera: &CameraSettings) -> bool {
    let p = cam.to_body(p_world);
    let d = p.norm();
    d > 1e-6 && d <= camera.range_m && p.y.atan2(p.x).abs() <= camera.fov_rad / 2.0
}

/// Share of the target's footprint samples that a camera sees: inside the
/// frustum, and the sight line from the camera (at `camera.height_m`) to the
/// sample (at `aim_height_fraction` of the target's height) passes above or
/// beside every other road user and misses every building.
pub fn visible_fraction(
    cam: &Pose2,
    ego_index: usize,
    target_index: usize,
    frame: &TrafficFrame,
    scene: &StaticScene,
    camera: &CameraSettings,
    sensor: &SensorSettings,
) -> f64 {
    let target = &frame.objects[target_index];
    let cam_xy = cam.position_m();
    let aim_h = sensor.aim_height_fraction * target.height_m;
    let reach = camera.range_m + target.footprint().bounding_radius_m();
    // Candidate occluders: near enough to the camera to matter.
    let occluders: Vec<&TrafficObject> = frame
        .objects
        .iter()
        .enumerate()
        .filter(|&(k, o)| {
            k != ego_index
                && k != target_index
                && (o.pose.position_m() - cam_xy).norm()
                    <= reach + o.footprint().bounding_radius_m()
        })
        .map(|(_, o)| o)
        .collect();
    let buildings: Vec<_> = scene
        .buildings
        .iter()
        .filter(|b| {
            let (c, r) = b.bounding_circle();
            (c - cam_xy).norm() <= reach + r
        })
        .collect();

    let mut visible = 0usize;
    for &(sx, sy) in &FOOTPRINT_SAMPLES {
        let p = target
            .pose
            .to_parent(&Vec2::new(sx * target.length_m, sy * target.width_m));
        if !in_frustum(cam, &p, camera) {
            continue;
        }
        let blocked_by_road_user = occluders.iter().any(|o| {
            let fp = o.footprint();
            if crate::geometry::point_segment_distance(&o.pose.position_m(), &cam_xy, &p)
                > fp.bounding_radius_m()
            {
                return false;
            }
            match fp.segment_entry(&cam_xy, &p) {
                // Height of the sight line where it enters the occluder.
                Some(t) => o.height_m >= camera.height_m + (aim_h - camera.height_m) * t,
                None => false,
            }
        });
        if blocked_by_road_user {
            continue;
        }
        if buildings.iter().any(|b| b.blocks_segment(&cam_xy, &p)) {
            continue;
        }
        visible += 1;
    }
    visible as f64 / FOOTPRINT_SAMPLES.len() as f64
}

/// Range and bearing standard deviations at distance `d_m`.
fn polar_sigmas(d_m: f64, s: &SensorSettings) -> (f64, f64) {
    (
        s.range_sigma_base_m + s.range_sigma_per_m * d_m,
        s.bearing_sigma_base_rad + s.bearing_sigma_per_m_rad * d_m,
    )
}

/// Covariance of a point at range `r_m`, bearing `bearing_rad` (camera frame)
/// with independent range and bearing errors: `J diag(sr^2, sb^2) J^T`.
pub fn polar_covariance(r_m: f64, bearing_rad: f64, sigma_r_m: f64, sigma_b_rad: f64) -> Cov2 {
    let (s, c) = bearing_rad.sin_cos();
    let j = nalgebra::Matrix2::new(c, -r_m * s, s, r_m * c);
    j * Cov2::new(sigma_r_m * sigma_r_m, 0.0, 0.0, sigma_b_rad * sigma_b_rad) * j.transpose()
}

/// Draws a noisy measurement of the camera-frame point `p_cam_m` and returns
/// it with its covariance, both in the camera frame.
fn measure(p_cam_m: &Vec2, s: &SensorSettings, rng: &mut impl Rng) -> (Vec2, Cov2) {
    let d = p_cam_m.norm();
    let b = p_cam_m.y.atan2(p_cam_m.x);
    let (sr, sb) = polar_sigmas(d, s);
    let r = (d + sr * std_normal(rng)).max(0.1);
    let bm = wrap_angle(b + sb * std_normal(rng));
    // The sensor knows only what it measured: its covariance is evaluated
    // at the measured range and bearing.
    let (sr_m, sb_m) = polar_sigmas(r, s);
    (
        Vec2::new(r * bm.cos(), r * bm.sin()),
        polar_covariance(r, bm, sr_m, sb_m),
    )
}

fn std_normal(rng: &mut impl Rng) -> f64 {
    rng.sample::<f64, _>(rand_distr::StandardNormal)
}

fn observe_appearance(
    class: ObjectClass,
    colour_rgb: [u8; 3],
    size_m: [f64; 3],
    d_m: f64,
    camera: &CameraSettings,
    s: &SensorSettings,
    rng: &mut impl Rng,
) -> Appearance {
    let class = if rng.random::<f64>() < s.class_confusion_prob {
        class.confusable()
    } else {
        class
    };
    let light = 1.0 + s.lighting_spread * (2.0 * rng.random::<f64>() - 1.0);
    let sigma_c = s.colour_sigma * (1.0 + d_m / camera.range_m);
    let colour_rgb = colour_rgb
        .map(|c| (f64::from(c) / 255.0 * light + sigma_c * std_normal(rng)).clamp(0.0, 1.0));
    let size = size_m.map(|v| (v * (1.0 + s.size_sigma_fraction * std_normal(rng))).max(0.05));
    Appearance {
        class,
        colour_rgb,
        length_m: size[0],
        width_m: size[1],
        height_m: size[2],
    }
}

/// Typical sizes per class, for false positives.
fn typical_size_m(class: ObjectClass) -> [f64; 3] {
    match class {
        ObjectClass::Car => [4.6, 1.8, 1.5],
        ObjectClass::Van => [5.4, 2.0, 2.3],
        ObjectClass::Truck => [9.5, 2.5, 3.6],
        ObjectClass::Bus => [12.0, 2.55, 3.2],
        ObjectClass::Motorcycle => [2.2, 0.8, 1.5],
        ObjectClass::Bicycle => [1.7, 0.65, 1.7],
        ObjectClass::Pedestrian => [0.3, 0.5, 1.75],
    }
}

/// One camera of an ego at one step, with the settings it works under.
struct Camera<'a> {
    /// The camera's pose, world frame.
    pose: Pose2,
    /// The camera's pose in the ego's body frame.
    in_ego: Pose2,
    camera: &'a CameraSettings,
    sensor: &'a SensorSettings,
}

impl Camera<'_> {
    /// A camera-frame measurement as a detection in the ego's body frame.
    fn detection(&self, p_meas: &Vec2, cov_cam: &Cov2, appearance: Appearance) -> Detection {
        Detection {
            position_m: self.in_ego.to_parent(p_meas),
            cov_m2: self.in_ego.cov_to_parent(cov_cam),
            appearance,
            motion: None,
        }
    }

    /// Tries to detect `frame.objects[k]`: `None` when it is out of view
    /// or hidden; else the object as visible, and its detection unless it
    /// was missed. The stream advances the same way whether or not the
    /// object is missed.
    fn detect(
        &self,
        frame: &TrafficFrame,
        scene: &StaticScene,
        ego_index: usize,
        k: usize,
        rng: &mut impl Rng,
    ) -> Option<(VisibleObject, Option<(Detection, DetectionTruth)>)> {
        let (camera, sensor) = (self.camera, self.sensor);
        let obj = &frame.objects[k];
        // Cheap reject before the sampled visibility test.
        let reach = camera.range_m + obj.footprint().bounding_radius_m();
        if (obj.pose.position_m() - self.pose.position_m()).norm() > reach {
            return None;
        }
        let vis = visible_fraction(&self.pose, ego_index, k, frame, scene, camera, sensor);
        if vis < sensor.min_visible_fraction || vis == 0.0 {
            return None;
        }
        let p_cam = self.pose.to_body(&obj.pose.position_m());
        let d = p_cam.norm();
        let p_miss = (sensor.miss_prob_base
            + sensor.miss_prob_at_max_range * (d / camera.range_m).min(1.0)
            + sensor.miss_prob_occlusion * (1.0 - vis))
            .clamp(0.0, 1.0);
        // Always draw, so the stream advances the same way whatever happens.
        let u: f64 = rng.random();
        let (p_meas, cov_cam) = measure(&p_cam, sensor, rng);
        let size = [obj.length_m, obj.width_m, obj.height_m];
        let appearance =
            observe_appearance(obj.class, obj.colour_rgb, size, d, camera, sensor, rng);
        let object = VisibleObject {
            object_id: obj.id.clone(),
            position_m: obj.pose.position_m(),
            visible_fraction: vis,
        };
        if u < p_miss {
            return Some((object, None));
        }
        let truth = DetectionTruth {
            object_id: Some(obj.id.clone()),
            position_m: Some(obj.pose.position_m()),
            visible_fraction: vis,
            sender: false,
        };
        Some((
            object,
            Some((self.detection(&p_meas, &cov_cam, appearance), truth)),
        ))
    }

    /// False positives of one frame: Poisson many, uniform over the
    /// frustum's area, of any class and colour.
    fn false_positives(&self, rng: &mut impl Rng) -> Vec<(Detection, DetectionTruth)> {
        let (camera, sensor) = (self.camera, self.sensor);
        (0..clutter_count(sensor.false_positives_per_frame, rng))
            .map(|_| {
                let (p_cam, r) = clutter_point(camera, rng);
                let (p_meas, cov_cam) = measure(&p_cam, sensor, rng);
                let (class, colour) = clutter_look(rng);
                let size = typical_size_m(class);
                let appearance = observe_appearance(class, colour, size, r, camera, sensor, rng);
                (
                    self.detection(&p_meas, &cov_cam, appearance),
                    false_positive(),
                )
            })
            .collect()
    }
}

/// How many clutter detections a sensor makes in one frame: Poisson with
/// `mean` (none at 0).
fn clutter_count(mean: f64, rng: &mut impl Rng) -> usize {
    if mean > 0.0 {
        Poisson::new(mean)
            .map(|p| p.sample(rng) as usize)
            .unwrap_or(0)
    } else {
        0
    }
}

/// Where a clutter detection lies: uniform over the sensor's field's area
/// (sensor frame; at least 5 % of the range away), and its range.
fn clutter_point(camera: &CameraSettings, rng: &mut impl Rng) -> (Vec2, f64) {
    let r = camera.range_m * rng.random::<f64>().sqrt().max(0.05);
    let b = camera.fov_rad * (rng.random::<f64>() - 0.5);
    (Vec2::new(r * b.cos(), r * b.sin()), r)
}

/// A clutter detection's class and colour: any.
fn clutter_look(rng: &mut impl Rng) -> (ObjectClass, [u8; 3]) {
    let class = ObjectClass::ALL[rng.random_range(0..ObjectClass::ALL.len())];
    let colour = [rng.random::<u8>(), rng.random::<u8>(), rng.random::<u8>()];
    (class, colour)
}

/// The truth behind a false positive: no object.
fn false_positive() -> DetectionTruth {
    DetectionTruth {
        object_id: None,
        position_m: None,
        visible_fraction: 0.0,
        sender: false,
    }
}

/// What the cameras of `frame.objects[ego_index]` detect, with the truth
/// beside it. All draws come from `rng`, in a fixed order (per camera:
/// objects in frame order, then false positives), so the same stream gives
/// the same observation.
pub fn observe(
    frame: &TrafficFrame,
    scene: &StaticScene,
    ego_index: usize,
    camera: &CameraSettings,
    sensor: &SensorSettings,
    rng: &mut impl Rng,
) -> Sensed {
    let ego = &frame.objects[ego_index];
    let mut found: Vec<(Detection, DetectionTruth)> = Vec::new();
    let mut visible = Vec::new();
    let mut seen = vec![false; frame.objects.len()];
    for &yaw in &camera.yaw_offsets_rad {
        let pose = camera_pose(ego, yaw);
        let cam = Camera {
            pose,
            in_ego: ego.pose.relative(&pose),
            camera,
            sensor,
        };
        for (k, already) in seen.iter_mut().enumerate() {
            if k == ego_index || *already {
                continue;
            }
            if let Some((object, d)) = cam.detect(frame, scene, ego_index, k, rng) {
                // A camera that missed it leaves it to the next camera.
                *already = d.is_some();
                note_visible(&mut visible, object);
                found.extend(d);
            }
        }
        found.extend(cam.false_positives(rng));
    }
    sensed_from(ego, found, visible)
}

/// Adds an object a sensor could see to `visible`, unless another of the
/// ego's sensors already saw it.
fn note_visible(visible: &mut Vec<VisibleObject>, object: VisibleObject) {
    if !visible.iter().any(|v| v.object_id == object.object_id) {
        visible.push(object);
    }
}

/// What `ego`'s sensors found (detections with their truths, in step)
/// and every object they could see, as one [`Sensed`].
fn sensed_from(
    ego: &TrafficObject,
    found: Vec<(Detection, DetectionTruth)>,
    visible: Vec<VisibleObject>,
) -> Sensed {
    let (detections, truths) = found.into_iter().unzip();
    Sensed {
        observation: Observation {
            ego_id: ego.id.clone(),
            detections,
        },
        truth: ObservationTruth {
            ego_pose: ego.pose,
            detections: truths,
        },
        visible,
    }
}

/// The pose a vehicle's GPS reports: the true pose plus independent Gaussian
/// errors on x, y and heading at the given level.
pub fn reported_pose(truth: &Pose2, level: &PoseNoiseLevel, rng: &mut impl Rng) -> Pose2 {
    let n = |sigma: f64, rng: &mut _| {
        if sigma > 0.0 {
            Normal::new(0.0, sigma)
                .map(|d| d.sample(rng))
                .unwrap_or(0.0)
        } else {
            0.0
        }
    };
    let dx = n(level.position_sigma_m, rng);
    let dy = n(level.position_sigma_m, rng);
    let dh = n(level.heading_sigma_rad, rng);
    Pose2::new(
        truth.position_m() + Vec2::new(dx, dy),
        truth.heading_rad() + dh,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Polygon;
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
            label: PoseNoiseLabel::None,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
        };
        let p = reported_pose(&truth, &level, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(p.position_m(), truth.position_m());
        assert!((p.heading_rad() - truth.heading_rad()).abs() < 1e-15);
    }

    #[test]
    fn golden_pose_noise_stream_codes_and_labels() {
        // Part of every pose-noise stream's name: frozen.
        let levels = [
            PoseNoiseLabel::None,
            PoseNoiseLabel::Rtk,
            PoseNoiseLabel::Gps,
        ];
        let codes: Vec<u64> = levels.iter().map(|l| l.stream_code()).collect();
        assert_eq!(codes, vec![0, 1, 2]);
        let labels: Vec<&str> = levels.iter().map(|l| l.as_str()).collect();
        assert_eq!(labels, vec!["none", "rtk", "gps"]);
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
