//! Ground-plane geometry: poses, frame changes, covariance transport and the
//! two primitive intersection tests the sensor model needs.
//!
//! Conventions used everywhere outside the bridge: metres, radians, a
//! right-handed ground plane (x east, y north in the world frame), headings
//! counter-clockwise from +x. A body frame has +x forward and +y to the left.

use nalgebra::{Isometry2, Matrix2, Rotation2, Vector2};

/// A position or displacement on the ground plane, in metres.
pub type Vec2 = Vector2<f64>;
/// A 2x2 position covariance, in square metres.
pub type Cov2 = Matrix2<f64>;

/// A rigid pose on the ground plane: where a body frame sits in its parent
/// frame (position in metres, heading in radians, counter-clockwise from +x).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose2 {
    iso: Isometry2<f64>,
}

impl Pose2 {
    pub fn new(position_m: Vec2, heading_rad: f64) -> Self {
        Self {
            iso: Isometry2::new(position_m, heading_rad),
        }
    }

    pub fn identity() -> Self {
        Self::new(Vec2::zeros(), 0.0)
    }

    pub fn position_m(&self) -> Vec2 {
        self.iso.translation.vector
    }

    /// Heading in (-pi, pi].
    pub fn heading_rad(&self) -> f64 {
        self.iso.rotation.angle()
    }

    /// Unit vector along the body's +x axis, in the parent frame.
    pub fn forward(&self) -> Vec2 {
        self.iso.rotation * Vec2::x()
    }

    /// A point given in this body's frame, expressed in the parent frame.
    pub fn to_parent(&self, p_body_m: &Vec2) -> Vec2 {
        self.iso
            .transform_point(&nalgebra::Point2::from(*p_body_m))
            .coords
    }

    /// A point given in the parent frame, expressed in this body's frame.
    pub fn to_body(&self, p_parent_m: &Vec2) -> Vec2 {
        self.iso
            .inverse_transform_point(&nalgebra::Point2::from(*p_parent_m))
            .coords
    }

    /// A covariance given in this body's frame, expressed in the parent frame
    /// (rotation only: translation does not change a covariance).
    pub fn cov_to_parent(&self, cov_body_m2: &Cov2) -> Cov2 {
        rotate_cov(cov_body_m2, self.heading_rad())
    }

    /// `self * child`: the child's pose (given in this body's frame) in the
    /// parent frame.
    pub fn compose(&self, child: &Pose2) -> Pose2 {
        Pose2 {
            iso: self.iso * child.iso,
        }
    }

    pub fn inverse(&self) -> Pose2 {
        Pose2 {
            iso: self.iso.inverse(),
        }
    }

    /// The pose of `other` seen from `self`'s frame (both given in the same
    /// parent frame): `self^-1 * other`.
    pub fn relative(&self, other: &Pose2) -> Pose2 {
        self.inverse().compose(other)
    }
}

/// `R cov R^T` for a rotation by `angle_rad`.
pub fn rotate_cov(cov_m2: &Cov2, angle_rad: f64) -> Cov2 {
    let r = Rotation2::new(angle_rad).into_inner();
    r * cov_m2 * r.transpose()
}

/// Wraps an angle into (-pi, pi].
pub fn wrap_angle(angle_rad: f64) -> f64 {
    let a = angle_rad.rem_euclid(std::f64::consts::TAU);
    if a > std::f64::consts::PI {
        a - std::f64::consts::TAU
    } else {
        a
    }
}

/// The rigid pose that best maps points given in a body frame onto the
/// same points in the parent frame (`pairs`: (body, parent)), in the least
/// squares sense (2-D Kabsch): the heading from the centred points' summed
/// cross and dot products, the position from the centroids. `None` without
/// points; with one point, or all at one place, the heading is 0.
pub fn fit_rigid(pairs: &[(Vec2, Vec2)]) -> Option<Pose2> {
    if pairs.is_empty() {
        return None;
    }
    let n = pairs.len() as f64;
    let body = pairs.iter().map(|p| p.0).sum::<Vec2>() / n;
    let parent = pairs.iter().map(|p| p.1).sum::<Vec2>() / n;
    let (mut cross, mut dot) = (0.0, 0.0);
    for (b, p) in pairs {
        let (b, p) = (b - body, p - parent);
        cross += b.x * p.y - b.y * p.x;
        dot += b.dot(&p);
    }
    let heading = if cross == 0.0 && dot == 0.0 {
        0.0
    } else {
        cross.atan2(dot)
    };
    let rotated = Rotation2::new(heading) * body;
    Some(Pose2::new(parent - rotated, heading))
}

/// An oriented rectangle (a vehicle's or person's footprint).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrientedBox {
    /// Centre pose in the world frame.
    pub pose: Pose2,
    pub length_m: f64,
    pub width_m: f64,
}

impl OrientedBox {
    /// The four corners in the world frame, counter-clockwise from
    /// front-left.
    pub fn corners(&self) -> [Vec2; 4] {
        let (hl, hw) = (self.length_m / 2.0, self.width_m / 2.0);
        [
            Vec2::new(hl, hw),
            Vec2::new(-hl, hw),
            Vec2::new(-hl, -hw),
            Vec2::new(hl, -hw),
        ]
        .map(|c| self.pose.to_parent(&c))
    }

    /// Radius of the circle around the centre that holds the whole box.
    pub fn bounding_radius_m(&self) -> f64 {
        0.5 * self.length_m.hypot(self.width_m)
    }

    /// Where the segment `from -> to` (world frame) first enters the box, as
    /// the fraction of the way along the segment; `None` when it misses.
    /// A segment that starts inside the box enters at 0.
    pub fn segment_entry(&self, from: &Vec2, to: &Vec2) -> Option<f64> {
        let a = self.pose.to_body(from);
        let b = self.pose.to_body(to);
        let d = b - a;
        let half = [self.length_m / 2.0, self.width_m / 2.0];
        let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
        for axis in 0..2 {
            if d[axis].abs() < 1e-12 {
                if a[axis].abs() > half[axis] {
                    return None;
                }
                continue;
            }
            let ta = (-half[axis] - a[axis]) / d[axis];
            let tb = (half[axis] - a[axis]) / d[axis];
            let (lo, hi) = if ta < tb { (ta, tb) } else { (tb, ta) };
            t0 = t0.max(lo);
            t1 = t1.min(hi);
            if t0 > t1 {
                return None;
            }
        }
        Some(t0)
    }
}

/// A simple polygon (a building footprint), vertices in the world frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Polygon {
    pub vertices_m: Vec<Vec2>,
}

impl Polygon {
    /// Even-odd point-in-polygon test.
    pub fn contains(&self, p: &Vec2) -> bool {
        let v = &self.vertices_m;
        let mut inside = false;
        let mut j = v.len().wrapping_sub(1);
        for i in 0..v.len() {
            let (a, b) = (v[i], v[j]);
            if (a.y > p.y) != (b.y > p.y) && p.x < (b.x - a.x) * (p.y - a.y) / (b.y - a.y) + a.x {
                inside = !inside;
            }
            j = i;
        }
        inside
    }

    /// Whether the segment `from -> to` touches the polygon's area.
    pub fn blocks_segment(&self, from: &Vec2, to: &Vec2) -> bool {
        if self.contains(from) || self.contains(to) {
            return true;
        }
        let v = &self.vertices_m;
        (0..v.len()).any(|i| segments_intersect(from, to, &v[i], &v[(i + 1) % v.len()]))
    }

    /// Centre and radius of a circle that holds the whole polygon.
    pub fn bounding_circle(&self) -> (Vec2, f64) {
        let n = self.vertices_m.len().max(1) as f64;
        let c = self.vertices_m.iter().fold(Vec2::zeros(), |s, p| s + p) / n;
        let r = self
            .vertices_m
            .iter()
            .map(|p| (p - c).norm())
            .fold(0.0, f64::max);
        (c, r)
    }
}

fn cross(a: &Vec2, b: &Vec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Proper or touching intersection of the closed segments `p1-p2`, `q1-q2`.
pub fn segments_intersect(p1: &Vec2, p2: &Vec2, q1: &Vec2, q2: &Vec2) -> bool {
    let r = p2 - p1;
    let s = q2 - q1;
    let denom = cross(&r, &s);
    let qp = q1 - p1;
    if denom.abs() < 1e-12 {
        // Parallel: intersect only when collinear and overlapping.
        if cross(&qp, &r).abs() > 1e-9 {
            return false;
        }
        let rr = r.dot(&r);
        if rr < 1e-18 {
            return (p1 - q1).norm() < 1e-9;
        }
        let t0 = qp.dot(&r) / rr;
        let t1 = t0 + s.dot(&r) / rr;
        let (lo, hi) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
        return hi >= 0.0 && lo <= 1.0;
    }
    let t = cross(&qp, &s) / denom;
    let u = cross(&qp, &r) / denom;
    (0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)
}

/// Distance from point `p` to the segment `a-b`.
pub fn point_segment_distance(p: &Vec2, a: &Vec2, b: &Vec2) -> f64 {
    let ab = b - a;
    let len2 = ab.dot(&ab);
    let t = if len2 < 1e-18 {
        0.0
    } else {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    };
    (a + ab * t - p).norm()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::FRAC_PI_2;

    fn close(a: &Vec2, b: &Vec2) -> bool {
        (a - b).norm() < 1e-9
    }

    proptest! {
        #[test]
        fn frame_change_round_trips(x in -500.0..500.0f64, y in -500.0..500.0f64, h in -7.0..7.0f64,
                                    px in -100.0..100.0f64, py in -100.0..100.0f64) {
            let pose = Pose2::new(Vec2::new(x, y), h);
            let p = Vec2::new(px, py);
            prop_assert!(close(&pose.to_body(&pose.to_parent(&p)), &p));
            prop_assert!(close(&pose.to_parent(&pose.to_body(&p)), &p));
        }

        #[test]
        fn relative_pose_moves_points_between_frames(ax in -50.0..50.0f64, ay in -50.0..50.0f64, ah in -3.0..3.0f64,
                                                    bx in -50.0..50.0f64, by in -50.0..50.0f64, bh in -3.0..3.0f64,
                                                    px in -30.0..30.0f64, py in -30.0..30.0f64) {
            let a = Pose2::new(Vec2::new(ax, ay), ah);
            let b = Pose2::new(Vec2::new(bx, by), bh);
            let p_in_b = Vec2::new(px, py);
            let world = b.to_parent(&p_in_b);
            prop_assert!(close(&a.relative(&b).to_parent(&p_in_b), &a.to_body(&world)));
        }

        #[test]
        fn rotated_covariance_keeps_trace_and_determinant(s1 in 0.01..10.0f64, s2 in 0.01..10.0f64, c in -0.9..0.9f64, ang in -7.0..7.0f64) {
            let off = c * s1 * s2;
            let cov = Cov2::new(s1 * s1, off, off, s2 * s2);
            let rot = rotate_cov(&cov, ang);
            prop_assert!((rot.trace() - cov.trace()).abs() < 1e-9);
            prop_assert!((rot.determinant() - cov.determinant()).abs() < 1e-9 * (1.0 + cov.determinant()));
            prop_assert!((rot - rot.transpose()).norm() < 1e-12);
            let back = rotate_cov(&rot, -ang);
            prop_assert!((back - cov).norm() < 1e-9);
        }
    }

    #[test]
    fn covariance_rotation_moves_the_long_axis() {
        let cov = Cov2::new(4.0, 0.0, 0.0, 1.0);
        let rot = rotate_cov(&cov, FRAC_PI_2);
        assert!((rot - Cov2::new(1.0, 0.0, 0.0, 4.0)).norm() < 1e-12);
    }

    #[test]
    fn wrap_angle_stays_in_range() {
        for k in -20..20 {
            let a = wrap_angle(0.3 + k as f64 * std::f64::consts::TAU);
            assert!((a - 0.3).abs() < 1e-9);
        }
        assert!((wrap_angle(std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn segment_box_entry() {
        let b = OrientedBox {
            pose: Pose2::new(Vec2::new(10.0, 0.0), FRAC_PI_2),
            length_m: 4.0,
            width_m: 2.0,
        };
        // Box spans x in [9, 11] (width across the heading), y in [-2, 2].
        let t = b
            .segment_entry(&Vec2::new(0.0, 0.0), &Vec2::new(20.0, 0.0))
            .unwrap();
        assert!((t - 0.45).abs() < 1e-12);
        assert!(
            b.segment_entry(&Vec2::new(0.0, 3.0), &Vec2::new(20.0, 3.0))
                .is_none()
        );
        assert!(
            b.segment_entry(&Vec2::new(0.0, 0.0), &Vec2::new(8.0, 0.0))
                .is_none()
        );
        assert_eq!(
            b.segment_entry(&Vec2::new(10.0, 0.0), &Vec2::new(20.0, 0.0)),
            Some(0.0)
        );
    }

    #[test]
    fn polygon_blocks_crossing_segments_only() {
        let square = Polygon {
            vertices_m: vec![
                Vec2::new(0.0, 0.0),
                Vec2::new(2.0, 0.0),
                Vec2::new(2.0, 2.0),
                Vec2::new(0.0, 2.0),
            ],
        };
        assert!(square.contains(&Vec2::new(1.0, 1.0)));
        assert!(!square.contains(&Vec2::new(3.0, 1.0)));
        assert!(square.blocks_segment(&Vec2::new(-1.0, 1.0), &Vec2::new(3.0, 1.0)));
        assert!(!square.blocks_segment(&Vec2::new(-1.0, 3.0), &Vec2::new(3.0, 3.0)));
        assert!(!square.blocks_segment(&Vec2::new(-1.0, -1.0), &Vec2::new(-1.0, 5.0)));
    }

    #[test]
    fn point_segment_distance_cases() {
        let a = Vec2::new(0.0, 0.0);
        let b = Vec2::new(10.0, 0.0);
        assert!((point_segment_distance(&Vec2::new(5.0, 3.0), &a, &b) - 3.0).abs() < 1e-12);
        assert!((point_segment_distance(&Vec2::new(-4.0, 3.0), &a, &b) - 5.0).abs() < 1e-12);
    }

    /// A rigid fit recovers the pose that moved the points, exactly
    /// without noise; one point gives heading 0 and maps it exactly.
    #[test]
    fn a_rigid_fit_recovers_the_pose_that_moved_the_points() {
        let pose = Pose2::new(Vec2::new(12.0, -3.0), 2.5);
        let body = [
            Vec2::new(5.0, 1.0),
            Vec2::new(20.0, -4.0),
            Vec2::new(9.0, 7.0),
        ];
        let pairs: Vec<(Vec2, Vec2)> = body.iter().map(|b| (*b, pose.to_parent(b))).collect();
        let fit = fit_rigid(&pairs).unwrap();
        assert!((fit.position_m() - pose.position_m()).norm() < 1e-9);
        assert!(wrap_angle(fit.heading_rad() - pose.heading_rad()).abs() < 1e-12);
        let one = fit_rigid(&pairs[..1]).unwrap();
        assert_eq!(one.heading_rad(), 0.0);
        assert!((one.to_parent(&body[0]) - pairs[0].1).norm() < 1e-9);
        assert!(fit_rigid(&[]).is_none());
    }
}
