//! Boxes, not points: the heading and speed a detector reports with each
//! detection, with their own errors. They are drawn after the
//! detections, from a stream of their own, so that switching them on or
//! off, or changing their errors, leaves every position, miss and false
//! positive as it was.

use std::collections::HashMap;

use rand::Rng;

use super::Sensed;
use crate::geometry::wrap_angle;
use crate::traffic::TrafficFrame;

/// An object's box as a detector reports it: its heading in the
/// observer's body frame (radians, counter-clockwise from the observer's
/// x axis; a detector sometimes confuses front and back, so it may be off
/// by pi) and its speed over ground (m/s, never negative).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    pub(crate) heading_rad: f64,
    pub(crate) speed_mps: f64,
}

/// The errors of a detector's heading and speed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BoxErrors {
    /// Standard deviation of the heading error (Gaussian).
    pub(crate) heading_sigma_rad: f64,
    /// Probability that a box's heading is reported the wrong way round
    /// (off by pi).
    pub(crate) heading_flip_prob: f64,
    /// Standard deviation of the speed error (Gaussian; the reported
    /// speed is clipped at 0).
    pub(crate) speed_sigma_mps: f64,
}

/// Gives every detection of `sensed` (made by `frame.objects[ego_index]`)
/// its reported box: the true heading (in the ego's body frame) and speed
/// of the object behind it with `errors`, or, behind a false positive, a
/// heading uniform over the circle and a speed of |N(0, sigma)|. Draws come
/// from `rng`, two or three per detection in detection order. Detections
/// that already carry a box (a sender's own node) keep it.
pub(crate) fn add_motion(
    sensed: &mut Sensed,
    frame: &TrafficFrame,
    ego_index: usize,
    errors: &BoxErrors,
    rng: &mut impl Rng,
) {
    let ego_heading = frame.objects[ego_index].pose.heading_rad();
    let wanted: HashMap<&str, usize> = sensed
        .truth
        .detections
        .iter()
        .filter_map(|t| t.object_id.as_deref())
        .map(|id| (id, usize::MAX))
        .collect();
    let mut at = wanted;
    for (k, o) in frame.objects.iter().enumerate() {
        if let Some(slot) = at.get_mut(o.id.as_str()) {
            *slot = k;
        }
    }
    let detections = &mut sensed.observation.detections;
    for (d, truth) in detections.iter_mut().zip(&sensed.truth.detections) {
        if d.motion.is_some() {
            continue;
        }
        let normal = |rng: &mut _| rng_normal(rng);
        let (e_heading, u_flip, e_speed) = (normal(rng), rng.random::<f64>(), normal(rng));
        let object = truth
            .object_id
            .as_deref()
            .and_then(|id| at.get(id))
            .and_then(|&k| frame.objects.get(k));
        d.motion = Some(match object {
            Some(o) => {
                let flip = if u_flip < errors.heading_flip_prob {
                    std::f64::consts::PI
                } else {
                    0.0
                };
                Motion {
                    heading_rad: wrap_angle(
                        o.pose.heading_rad() - ego_heading
                            + errors.heading_sigma_rad * e_heading
                            + flip,
                    ),
                    speed_mps: (o.speed_mps + errors.speed_sigma_mps * e_speed).max(0.0),
                }
            }
            None => Motion {
                heading_rad: wrap_angle(std::f64::consts::TAU * u_flip),
                speed_mps: (errors.speed_sigma_mps * e_speed).abs(),
            },
        });
    }
}

fn rng_normal(rng: &mut impl Rng) -> f64 {
    rng.sample::<f64, _>(rand_distr::StandardNormal)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Pose2, Vec2};
    use crate::sensor::tests::sensor;
    use crate::sensor::{CameraSettings, observe};
    use crate::traffic::{ObjectClass, StaticScene, TrafficObject};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn car(id: &str, x: f64, y: f64, heading_rad: f64, speed_mps: f64) -> TrafficObject {
        TrafficObject {
            id: id.into(),
            class: ObjectClass::Car,
            pose: Pose2::new(Vec2::new(x, y), heading_rad),
            length_m: 4.6,
            width_m: 1.8,
            height_m: 1.5,
            colour_rgb: [200, 10, 10],
            speed_mps,
            type_id: "car".into(),
            model: None,
        }
    }

    /// An ego heading 0.3 rad, and a car 25 m ahead of it heading 1.3 rad
    /// at 8 m/s: 1.0 rad in the ego's body frame.
    fn sensed(errors: &BoxErrors, seed: u64) -> Sensed {
        let ego = car("ego", 0.0, 0.0, 0.3, 5.0);
        let ahead = ego.pose.to_parent(&Vec2::new(25.0, 0.0));
        let frame = TrafficFrame {
            step: 0,
            time_s: 0.0,
            objects: vec![ego, car("a", ahead.x, ahead.y, 1.3, 8.0)],
        };
        let scene = StaticScene {
            junction_id: "C".into(),
            junction_position_m: Vec2::zeros(),
            buildings: Vec::new(),
            lanes: Vec::new(),
        };
        let camera = CameraSettings {
            fov_rad: 90f64.to_radians(),
            range_m: 70.0,
            height_m: 1.5,
            yaw_offsets_rad: vec![0.0],
        };
        let mut quiet = sensor();
        quiet.miss_prob_base = 0.0;
        quiet.miss_prob_at_max_range = 0.0;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut s = observe(&frame, &scene, 0, &camera, &quiet, &mut rng);
        s.add_sender(&frame.objects[0]);
        let mut boxes = ChaCha8Rng::seed_from_u64(seed + 1_000_000);
        add_motion(&mut s, &frame, 0, errors, &mut boxes);
        s
    }

    #[test]
    fn boxes_report_the_heading_in_the_body_frame_with_their_errors() {
        let errors = BoxErrors {
            heading_sigma_rad: 0.1,
            heading_flip_prob: 0.05,
            speed_sigma_mps: 0.5,
        };
        let exact = BoxErrors {
            heading_sigma_rad: 0.0,
            heading_flip_prob: 0.0,
            speed_sigma_mps: 0.0,
        };
        let (mut flips, mut n) = (0, 0);
        let (mut sq_heading, mut sq_speed) = (0.0, 0.0);
        for seed in 0..3000 {
            let s = sensed(&errors, seed);
            let e = sensed(&exact, seed);
            // The boxes' errors move no detection and change nothing else.
            for (a, b) in s
                .observation
                .detections
                .iter()
                .zip(&e.observation.detections)
            {
                assert_eq!(a.position_m, b.position_m);
                assert_eq!(a.appearance, b.appearance);
            }
            for (d, t) in s.observation.detections.iter().zip(&s.truth.detections) {
                let m = d.motion.expect("every sensed detection has a box");
                assert!(m.speed_mps >= 0.0 && m.heading_rad.abs() <= std::f64::consts::PI);
                match t.object_id.as_deref() {
                    Some("a") => {
                        let e = wrap_angle(m.heading_rad - 1.0);
                        if e.abs() > std::f64::consts::FRAC_PI_2 {
                            flips += 1;
                        } else {
                            sq_heading += e * e;
                            sq_speed += (m.speed_mps - 8.0).powi(2);
                            n += 1;
                        }
                    }
                    // The sender's own node: its own heading and speed.
                    Some("ego") => assert_eq!((m.heading_rad, m.speed_mps), (0.0, 5.0)),
                    _ => {}
                }
            }
            let a = e
                .truth
                .detections
                .iter()
                .position(|t| t.object_id.as_deref() == Some("a"));
            let m = e.observation.detections[a.unwrap()].motion.unwrap();
            assert!((m.heading_rad - 1.0).abs() < 1e-12 && (m.speed_mps - 8.0).abs() < 1e-12);
        }
        let flip_share = f64::from(flips) / f64::from(flips + n);
        assert!((flip_share - 0.05).abs() < 0.012, "flips {flip_share}");
        let sd_heading = (sq_heading / f64::from(n)).sqrt();
        let sd_speed = (sq_speed / f64::from(n)).sqrt();
        assert!((sd_heading - 0.1).abs() < 0.006, "heading sd {sd_heading}");
        assert!((sd_speed - 0.5).abs() < 0.03, "speed sd {sd_speed}");
    }
}
