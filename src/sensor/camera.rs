//! The paper's camera model: what `[camera]`'s cameras on a vehicle
//! detect in one frame, with 2.5-D occlusion, range and bearing noise
//! reported with the covariance it was drawn from, misses, false positives
//! and appearance; and the pieces the detector profiles share with it.

use rand::Rng;
use rand_distr::{Distribution, Poisson};

use super::{
    Appearance, CameraSettings, Detection, DetectionTruth, Observation, ObservationTruth, Sensed,
    SensorSettings, VisibleObject,
};
use crate::geometry::{Cov2, Pose2, Vec2, wrap_angle};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

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
pub(super) fn camera_pose(ego: &TrafficObject, yaw_offset_rad: f64) -> Pose2 {
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
pub(crate) fn visible_fraction(
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
pub(super) fn polar_sigmas(d_m: f64, s: &SensorSettings) -> (f64, f64) {
    (
        s.range_sigma_base_m + s.range_sigma_per_m * d_m,
        s.bearing_sigma_base_rad + s.bearing_sigma_per_m_rad * d_m,
    )
}

/// Covariance of a point at range `r_m`, bearing `bearing_rad` (camera frame)
/// with independent range and bearing errors: `J diag(sr^2, sb^2) J^T`.
pub(super) fn polar_covariance(
    r_m: f64,
    bearing_rad: f64,
    sigma_r_m: f64,
    sigma_b_rad: f64,
) -> Cov2 {
    let (s, c) = bearing_rad.sin_cos();
    let j = nalgebra::Matrix2::new(c, -r_m * s, s, r_m * c);
    j * Cov2::new(sigma_r_m * sigma_r_m, 0.0, 0.0, sigma_b_rad * sigma_b_rad) * j.transpose()
}

/// Draws a noisy measurement of the camera-frame point `p_cam_m` and returns
/// it with its covariance, both in the camera frame.
pub(super) fn measure(p_cam_m: &Vec2, s: &SensorSettings, rng: &mut impl Rng) -> (Vec2, Cov2) {
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

pub(super) fn observe_appearance(
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
        descriptor: None,
    }
}

/// Typical sizes per class, for false positives.
pub(super) fn typical_size_m(class: ObjectClass) -> [f64; 3] {
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
pub(super) fn clutter_count(mean: f64, rng: &mut impl Rng) -> usize {
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
pub(super) fn clutter_point(camera: &CameraSettings, rng: &mut impl Rng) -> (Vec2, f64) {
    let r = camera.range_m * rng.random::<f64>().sqrt().max(0.05);
    let b = camera.fov_rad * (rng.random::<f64>() - 0.5);
    (Vec2::new(r * b.cos(), r * b.sin()), r)
}

/// A clutter detection's class and colour: any.
pub(super) fn clutter_look(rng: &mut impl Rng) -> (ObjectClass, [u8; 3]) {
    let class = ObjectClass::ALL[rng.random_range(0..ObjectClass::ALL.len())];
    let colour = [rng.random::<u8>(), rng.random::<u8>(), rng.random::<u8>()];
    (class, colour)
}

/// The truth behind a false positive: no object.
pub(super) fn false_positive() -> DetectionTruth {
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
pub(crate) fn observe(
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
pub(super) fn note_visible(visible: &mut Vec<VisibleObject>, object: VisibleObject) {
    if !visible.iter().any(|v| v.object_id == object.object_id) {
        visible.push(object);
    }
}

/// What `ego`'s sensors found (detections with their truths, in step)
/// and every object they could see, as one [`Sensed`].
pub(super) fn sensed_from(
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
