//! The camera stand-in: what a connected vehicle's cameras detect in one
//! traffic frame, with occlusion, distance-dependent noise, misses, false
//! positives and appearance descriptors that do not identify objects alone.
//!
//! Pure computation: a frame and a seeded stream in, an [`Observation`] out.
//! Detections are in the ego's body frame (x forward, y left, metres), which
//! is what the vehicle itself knows; the ego's GPS pose is added per noise
//! level by [`reported_pose`].

use rand::Rng;
use rand_distr::{Distribution, Normal, Poisson};

use crate::config::{CameraSettings, PoseNoiseLevel, SensorSettings};
use crate::geometry::{Cov2, Pose2, Vec2, wrap_angle};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

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

/// One detection in one vehicle's body frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// Measured object centre, ego body frame.
    pub position_m: Vec2,
    /// Covariance of `position_m` from the same noise model that drew it.
    pub cov_m2: Cov2,
    pub appearance: Appearance,
    /// Evaluation only: the SUMO id of the object, `None` for a false
    /// positive. Matchers other than the oracle must not read it.
    pub truth_id: Option<String>,
    /// Evaluation only: the share of footprint samples that were visible.
    pub visible_fraction: f64,
}

/// Everything one connected vehicle perceives at one step.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    pub ego_id: String,
    /// Evaluation only: the ego's true centre pose, world frame.
    pub ego_pose_true: Pose2,
    pub detections: Vec<Detection>,
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

/// What the cameras of `frame.objects[ego_index]` detect. All draws come
/// from `rng`, in a fixed order (objects in frame order, then false
/// positives), so the same stream gives the same observation.
pub fn observe(
    frame: &TrafficFrame,
    scene: &StaticScene,
    ego_index: usize,
    camera: &CameraSettings,
    sensor: &SensorSettings,
    rng: &mut impl Rng,
) -> Observation {
    let ego = &frame.objects[ego_index];
    let mut detections = Vec::new();
    let mut seen = vec![false; frame.objects.len()];
    for &yaw in &camera.yaw_offsets_rad {
        let cam = camera_pose(ego, yaw);
        let cam_in_ego = ego.pose.relative(&cam);
        for (k, obj) in frame.objects.iter().enumerate() {
            if k == ego_index || seen[k] {
                continue;
            }
            // Cheap reject before the sampled visibility test.
            let reach = camera.range_m + obj.footprint().bounding_radius_m();
            if (obj.pose.position_m() - cam.position_m()).norm() > reach {
                continue;
            }
            let vis = visible_fraction(&cam, ego_index, k, frame, scene, camera, sensor);
            if vis < sensor.min_visible_fraction || vis == 0.0 {
                continue;
            }
            let p_cam = cam.to_body(&obj.pose.position_m());
            let d = p_cam.norm();
            let p_miss = (sensor.miss_prob_base
                + sensor.miss_prob_at_max_range * (d / camera.range_m).min(1.0)
                + sensor.miss_prob_occlusion * (1.0 - vis))
                .clamp(0.0, 1.0);
            // Always draw, so the stream advances the same way whatever happens.
            let u: f64 = rng.random();
            let (p_meas, cov_cam) = measure(&p_cam, sensor, rng);
            let appearance = observe_appearance(
                obj.class,
                obj.colour_rgb,
                [obj.length_m, obj.width_m, obj.height_m],
                d,
                camera,
                sensor,
                rng,
            );
            if u < p_miss {
                continue;
            }
            seen[k] = true;
            detections.push(Detection {
                position_m: cam_in_ego.to_parent(&p_meas),
                cov_m2: cam_in_ego.cov_to_parent(&cov_cam),
                appearance,
                truth_id: Some(obj.id.clone()),
                visible_fraction: vis,
            });
        }
        // False positives: uniform over the frustum's area.
        let n_fp = if sensor.false_positives_per_frame > 0.0 {
            Poisson::new(sensor.false_positives_per_frame)
                .map(|p| p.sample(rng) as usize)
                .unwrap_or(0)
        } else {
            0
        };
        for _ in 0..n_fp {
            let r = camera.range_m * rng.random::<f64>().sqrt().max(0.05);
            let b = camera.fov_rad * (rng.random::<f64>() - 0.5);
            let p_cam = Vec2::new(r * b.cos(), r * b.sin());
            let (p_meas, cov_cam) = measure(&p_cam, sensor, rng);
            let class = ObjectClass::ALL[rng.random_range(0..ObjectClass::ALL.len())];
            let colour = [rng.random::<u8>(), rng.random::<u8>(), rng.random::<u8>()];
            let appearance =
                observe_appearance(class, colour, typical_size_m(class), r, camera, sensor, rng);
            detections.push(Detection {
                position_m: cam_in_ego.to_parent(&p_meas),
                cov_m2: cam_in_ego.cov_to_parent(&cov_cam),
                appearance,
                truth_id: None,
                visible_fraction: 0.0,
            });
        }
    }
    Observation {
        ego_id: ego.id.clone(),
        ego_pose_true: ego.pose,
        detections,
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

    fn vis(f: &TrafficFrame, sc: &StaticScene, target: usize) -> f64 {
        let cam = CameraSettings {
            fov_rad: 90f64.to_radians(),
            range_m: 70.0,
            height_m: 1.5,
            yaw_offsets_rad: vec![0.0],
        };
        let pose = camera_pose(&f.objects[0], 0.0);
        visible_fraction(&pose, 0, target, f, sc, &cam, &SensorSettings::default())
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
            ..SensorSettings::default()
        };
        let sc = scene(vec![]);
        let obs = observe(&f, &sc, 0, &cam, &quiet, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(obs.detections.len(), 2);
        for d in &obs.detections {
            let truth = &f.objects[f.find(d.truth_id.as_deref().unwrap()).unwrap()];
            let world = obs.ego_pose_true.to_parent(&d.position_m);
            assert!((world - truth.pose.position_m()).norm() < 1e-9);
        }
        let noisy = SensorSettings::default();
        let a = observe(&f, &sc, 0, &cam, &noisy, &mut ChaCha8Rng::seed_from_u64(9));
        let b = observe(&f, &sc, 0, &cam, &noisy, &mut ChaCha8Rng::seed_from_u64(9));
        assert_eq!(a, b);
    }

    #[test]
    fn noise_grows_with_distance_and_matches_its_covariance() {
        let s = SensorSettings::default();
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
            label: crate::config::PoseNoiseLabel::None,
            position_sigma_m: 0.0,
            heading_sigma_rad: 0.0,
        };
        let p = reported_pose(&truth, &level, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(p.position_m(), truth.position_m());
        assert!((p.heading_rad() - truth.heading_rad()).abs() < 1e-15);
    }
}
