//! A profile's sensors on a vehicle: what they detect of a frame's
//! objects, with the profile's errors, duplicates, ghosts, clutter and
//! class confusion, as [`crate::sensor::observe`] does for the paper's
//! model.

use rand::Rng;

use super::Mount;
use super::model::{ProfileModel, RigSensor, line_of_sight, persistent_error, unit_error};
use crate::geometry::{Pose2, Vec2};
use crate::sensor::camera::{
    clutter_count, clutter_look, clutter_point, false_positive, note_visible, observe_appearance,
    sensed_from, typical_size_m,
};
use crate::sensor::{
    Appearance, CameraSettings, Detection, DetectionTruth, Sensed, SensorSettings, VisibleObject,
    visible_fraction,
};
use crate::traffic::{ObjectClass, StaticScene, TrafficFrame, TrafficObject};

/// A sensor of an ego at one step under a profile.
struct ProfileSensor<'a> {
    /// The sensor's pose, world frame.
    pose: Pose2,
    /// The sensor's pose in the ego's body frame.
    in_ego: Pose2,
    rig: &'a CameraSettings,
    model: &'a ProfileModel,
    /// `[sensor]` for what the profiles share with the paper's model
    /// (visibility, appearance noise), with class confusion off.
    sensor: &'a SensorSettings,
}

/// The paper's model's sensors: `[camera]`'s cameras, in front.
pub(crate) fn paper_rig(camera: &CameraSettings) -> Vec<RigSensor> {
    camera
        .yaw_offsets_rad
        .iter()
        .map(|&yaw| RigSensor {
            geometry: CameraSettings {
                yaw_offsets_rad: vec![yaw],
                ..camera.clone()
            },
            mount: Mount::Front,
        })
        .collect()
}

/// Where a sensor on `mount` sits in the body frame of a vehicle
/// `length_m` long (metres).
pub(crate) fn sensor_in_body_m(mount: Mount, length_m: f64) -> Vec2 {
    match mount {
        Mount::Front => Vec2::new(length_m / 2.0, 0.0),
        Mount::Roof => Vec2::zeros(),
    }
}

/// Where a sensor sits on `ego`, yawed by `yaw_rad`.
fn sensor_pose(ego: &TrafficObject, mount: Mount, yaw_rad: f64) -> Pose2 {
    ego.pose
        .compose(&Pose2::new(sensor_in_body_m(mount, ego.length_m), yaw_rad))
}

impl ProfileSensor<'_> {
    fn detection(&self, p_sensor: &Vec2, appearance: Appearance) -> Detection {
        Detection {
            position_m: self.in_ego.to_parent(p_sensor),
            cov_m2: self
                .in_ego
                .cov_to_parent(&self.model.nominal_covariance(p_sensor)),
            appearance,
            motion: None,
        }
    }

    /// The appearance the detector reports: the class through the
    /// confusion matrix, colour only if it sees colour.
    fn appearance(
        &self,
        class: ObjectClass,
        colour_rgb: [u8; 3],
        size_m: [f64; 3],
        d_m: f64,
        rng: &mut impl Rng,
    ) -> Appearance {
        let mut a = observe_appearance(class, colour_rgb, size_m, d_m, self.rig, self.sensor, rng);
        let row = &self.model.params.class_confusion[class_index(class)];
        let u: f64 = rng.random();
        let mut acc = 0.0;
        a.class = class;
        for (k, p) in row.iter().enumerate() {
            acc += p;
            if u < acc {
                a.class = ObjectClass::ALL[k];
                break;
            }
        }
        if !self.model.params.sees_colour {
            a.colour_rgb = [0.5; 3];
        }
        a
    }

    /// Measures a point at `p_true` (sensor frame) with the profile's
    /// error: bias, persistent and heavy-tailed parts along and across the
    /// line of sight.
    fn measure(&self, p_true: &Vec2, persistent: [f64; 2], rng: &mut impl Rng) -> Vec2 {
        let p = &self.model.params;
        let d = p_true.norm().max(0.1);
        let (sd, sl) = self.model.axis_sigmas(d);
        let e = unit_error(p, persistent, rng);
        let depth = p.depth_bias_per_m * d + sd * e[0];
        let rot = line_of_sight(p_true);
        p_true + rot * Vec2::new(depth, sl * e[1])
    }

    /// Tries to detect `frame.objects[k]`; as [`crate::sensor::Camera::detect`],
    /// plus the duplicates and ghosts it brings. Draws the same amount
    /// from the stream whatever happens.
    #[allow(clippy::too_many_arguments)]
    fn detect(
        &self,
        frame: &TrafficFrame,
        scene: &StaticScene,
        ego_index: usize,
        k: usize,
        seed: u64,
        rng: &mut impl Rng,
    ) -> Option<(VisibleObject, Vec<(Detection, DetectionTruth)>)> {
        let p = &self.model.params;
        let obj = &frame.objects[k];
        let reach = self.rig.range_m + obj.footprint().bounding_radius_m();
        if (obj.pose.position_m() - self.pose.position_m()).norm() > reach {
            return None;
        }
        let vis = visible_fraction(
            &self.pose,
            ego_index,
            k,
            frame,
            scene,
            self.rig,
            self.sensor,
        );
        if vis < self.sensor.min_visible_fraction || vis == 0.0 {
            return None;
        }
        let centre = self.pose.to_body(&obj.pose.position_m());
        let d = centre.norm();
        let recall = p.recall[self.model.bin(d)] * (1.0 - p.occlusion_recall_loss * (1.0 - vis));
        // The visible part's centre: pulled towards the sensor by a share
        // of the hidden depth extent.
        let rel = obj.pose.heading_rad() - self.pose.heading_rad() - centre.y.atan2(centre.x);
        let extent = (obj.length_m * rel.cos()).abs() + (obj.width_m * rel.sin()).abs();
        let pull = p.partial_shift * (1.0 - vis) * extent / 2.0;
        let seen_centre = centre * ((d - pull).max(0.1 * d) / d.max(1e-9));
        let ego_id = &frame.objects[ego_index].id;
        let persistent =
            persistent_error(seed, ego_id, &obj.id, frame.time_s, p.correlation_time_s);
        let u: f64 = rng.random();
        let measured = self.measure(&seen_centre, persistent, rng);
        let size = [obj.length_m, obj.width_m, obj.height_m];
        let appearance = self.appearance(obj.class, obj.colour_rgb, size, d, rng);
        // A duplicate: the same object again, its own per-frame error.
        let u_dup: f64 = rng.random();
        let dup_at = self.measure(&seen_centre, [0.0, 0.0], rng);
        let dup_look = self.appearance(obj.class, obj.colour_rgb, size, d, rng);
        // A ghost: beside the object.
        let u_ghost: f64 = rng.random();
        let r = p.ghost_distance_m[0]
            + (p.ghost_distance_m[1] - p.ghost_distance_m[0]) * rng.random::<f64>();
        let phi = std::f64::consts::TAU * rng.random::<f64>();
        let ghost_true = centre + Vec2::new(r * phi.cos(), r * phi.sin());
        let ghost_at = self.measure(&ghost_true, [0.0, 0.0], rng);
        let ghost_look = self.appearance(obj.class, obj.colour_rgb, size, d, rng);

        let object = VisibleObject {
            object_id: obj.id.clone(),
            position_m: obj.pose.position_m(),
            visible_fraction: vis,
        };
        if u >= recall {
            return Some((object, Vec::new()));
        }
        let mut out = vec![(
            self.detection(&measured, appearance),
            DetectionTruth {
                object_id: Some(obj.id.clone()),
                position_m: Some(obj.pose.position_m()),
                visible_fraction: vis,
                sender: false,
            },
        )];
        // Duplicates and ghosts are false positives: no object of their own.
        if u_dup < p.duplicate_prob {
            out.push((self.detection(&dup_at, dup_look), false_positive()));
        }
        if u_ghost < p.ghost_prob && ghost_at.norm() <= self.rig.range_m {
            out.push((self.detection(&ghost_at, ghost_look), false_positive()));
        }
        Some((object, out))
    }

    /// Clutter of one frame: Poisson many, uniform over the field's area,
    /// of any class and colour.
    fn clutter(&self, rng: &mut impl Rng) -> Vec<(Detection, DetectionTruth)> {
        let p = &self.model.params;
        (0..clutter_count(p.false_positives_per_frame, rng))
            .map(|_| {
                let (point, r) = clutter_point(self.rig, rng);
                let at = self.measure(&point, [0.0, 0.0], rng);
                let (class, colour) = clutter_look(rng);
                let look = self.appearance(class, colour, typical_size_m(class), r, rng);
                (self.detection(&at, look), false_positive())
            })
            .collect()
    }
}

fn class_index(class: ObjectClass) -> usize {
    ObjectClass::ALL
        .iter()
        .position(|c| *c == class)
        .unwrap_or(0)
}

/// What the sensors of `frame.objects[ego_index]` detect under `model`,
/// with the truth beside it: as [`crate::sensor::observe`], with the profile's
/// sensors and errors. Per-frame draws come from `rng` in a fixed order
/// (per sensor: objects in frame order, then clutter); the persistent
/// error is named by `seed`, the ego, the object and the time.
pub(crate) fn observe_profile(
    frame: &TrafficFrame,
    scene: &StaticScene,
    ego_index: usize,
    model: &ProfileModel,
    sensor: &SensorSettings,
    seed: u64,
    rng: &mut impl Rng,
) -> Sensed {
    let ego = &frame.objects[ego_index];
    let mut found: Vec<(Detection, DetectionTruth)> = Vec::new();
    let mut visible: Vec<VisibleObject> = Vec::new();
    let mut seen = vec![false; frame.objects.len()];
    for rs in model.sensors() {
        let pose = sensor_pose(ego, rs.mount, rs.yaw_rad());
        let s = ProfileSensor {
            pose,
            in_ego: ego.pose.relative(&pose),
            rig: &rs.geometry,
            model,
            sensor,
        };
        for (k, already) in seen.iter_mut().enumerate() {
            if k == ego_index || *already {
                continue;
            }
            if let Some((object, dets)) = s.detect(frame, scene, ego_index, k, seed, rng) {
                *already = !dets.is_empty();
                note_visible(&mut visible, object);
                found.extend(dets);
            }
        }
        found.extend(s.clutter(rng));
    }
    sensed_from(ego, found, visible)
}
