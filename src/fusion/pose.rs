//! A pose with its uncertainty ([`PoseEstimate`]): what a GNSS receiver
//! claims ([`PoseClaim`]), the relative pose of two reported poses
//! ([`relative_pose_prior`]), and a measurement moved with an uncertain pose
//! ([`Measurement::moved_uncertain`]).

use nalgebra::{Matrix2, Matrix3, Vector3};

use super::Measurement;
use crate::geometry::{Pose2, Vec2};

/// A pose with its uncertainty: the covariance of `(x m, y m, heading rad)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseEstimate {
    pub pose: Pose2,
    pub cov: Matrix3<f64>,
}

impl PoseEstimate {
    /// Independent errors: `position_sigma_m` per axis, `heading_sigma_rad`.
    pub fn diagonal(pose: Pose2, position_sigma_m: f64, heading_sigma_rad: f64) -> Self {
        let (p, h) = (position_sigma_m.powi(2), heading_sigma_rad.powi(2));
        Self {
            pose,
            cov: Matrix3::from_diagonal(&Vector3::new(p, p, h)),
        }
    }
}

/// `(-v.y, v.x)`: the derivative of `R(theta) v` with respect to `theta`.
pub(super) fn perp(v: &Vec2) -> Vec2 {
    Vec2::new(-v.y, v.x)
}

/// What a GNSS receiver claims of the pose it reports: independent
/// Gaussian errors of `position_sigma_m` per axis and `heading_sigma_rad`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseClaim {
    pub position_sigma_m: f64,
    pub heading_sigma_rad: f64,
}

/// The pose of vehicle b in vehicle a's frame from both GPS poses, each
/// with the errors its receiver claims (`a`, `b`). With `t` the relative
/// position, `dt = R_a^T (dp_b - dp_a) - dh_a perp(t)` and
/// `dtheta = dh_b - dh_a`, so `cov(t) = (s_pa^2 + s_pb^2) I + s_ha^2
/// perp(t) perp(t)^T`, `var(theta) = s_ha^2 + s_hb^2` and `cov(t, theta) =
/// s_ha^2 perp(t)`: a's heading error swings b about a.
pub fn relative_pose_prior(
    a_reported: &Pose2,
    b_reported: &Pose2,
    a: PoseClaim,
    b: PoseClaim,
) -> PoseEstimate {
    let pose = a_reported.relative(b_reported);
    let (spa2, sha2) = (a.position_sigma_m.powi(2), a.heading_sigma_rad.powi(2));
    let (spb2, shb2) = (b.position_sigma_m.powi(2), b.heading_sigma_rad.powi(2));
    let lever = perp(&pose.position_m());
    let mut cov = Matrix3::zeros();
    let ct = Matrix2::identity() * (spa2 + spb2) + lever * lever.transpose() * sha2;
    cov.fixed_view_mut::<2, 2>(0, 0).copy_from(&ct);
    cov.fixed_view_mut::<2, 1>(0, 2).copy_from(&(lever * sha2));
    cov.fixed_view_mut::<1, 2>(2, 0)
        .copy_from(&(lever.transpose() * sha2));
    cov[(2, 2)] = sha2 + shb2;
    PoseEstimate { pose, cov }
}

impl Measurement {
    /// The measurement of a point given in the body frame of an uncertain
    /// pose, in the parent frame: the covariance rotates with the point and
    /// gains the pose's own uncertainty, `J cov J^T` with
    /// `J = [I, perp(R p)]` (position error, and heading error times the
    /// lever arm).
    pub fn moved_uncertain(&self, pose: &PoseEstimate) -> Measurement {
        let moved = self.moved(&pose.pose);
        let lever = perp(&(moved.position_m - pose.pose.position_m()));
        let j = nalgebra::Matrix2x3::new(1.0, 0.0, lever.x, 0.0, 1.0, lever.y);
        let added = j * pose.cov * j.transpose();
        Measurement {
            position_m: moved.position_m,
            cov_m2: moved.cov_m2 + (added + added.transpose()) * 0.5,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Cov2;

    /// The pose term of `moved_uncertain` against Monte Carlo: two GPS
    /// receivers with independent errors of their own sizes (b's heading
    /// far worse, as at low speed), a point seen by b, moved into a's
    /// frame with the relative pose both report.
    #[test]
    fn the_pose_term_matches_sampled_gps_errors() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let claim = |position_sigma_m, heading_sigma_rad| PoseClaim {
            position_sigma_m,
            heading_sigma_rad,
        };
        let (ca, cb) = (claim(1.2, 0.05), claim(0.8, 0.15));
        let a_true = Pose2::new(Vec2::new(10.0, -5.0), 0.4);
        let b_true = Pose2::new(Vec2::new(45.0, 20.0), 2.5);
        let p_b = Vec2::new(25.0, 8.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut noisy = |p: &Pose2, c: PoseClaim| {
            let np = Normal::new(0.0, c.position_sigma_m).unwrap();
            let nh = Normal::new(0.0, c.heading_sigma_rad).unwrap();
            let d = Vec2::new(np.sample(&mut rng), np.sample(&mut rng));
            Pose2::new(p.position_m() + d, p.heading_rad() + nh.sample(&mut rng))
        };
        let n = 40_000;
        let xs: Vec<Vec2> = (0..n)
            .map(|_| {
                let a = noisy(&a_true, ca);
                a.relative(&noisy(&b_true, cb)).to_parent(&p_b)
            })
            .collect();
        let mean = xs.iter().fold(Vec2::zeros(), |s, x| s + x) / n as f64;
        let emp = xs.iter().fold(Matrix2::zeros(), |s, x| {
            s + (x - mean) * (x - mean).transpose()
        }) / n as f64;
        let prior = relative_pose_prior(&a_true, &b_true, ca, cb);
        let point = Measurement {
            position_m: p_b,
            cov_m2: Cov2::zeros(),
        };
        let predicted = point.moved_uncertain(&prior).cov_m2;
        assert!(
            (emp - predicted).norm() < 0.05 * predicted.norm(),
            "sampled {emp} vs predicted {predicted}"
        );
        // The lever arm matters: heading error alone moves a far point.
        let sp2 = ca.position_sigma_m.powi(2) + cb.position_sigma_m.powi(2);
        assert!(predicted.trace() > 2.0 * sp2);
        // No pose error, no pose term.
        let exact = PoseEstimate::diagonal(prior.pose, 0.0, 0.0);
        assert_eq!(point.moved_uncertain(&exact), point.moved(&prior.pose));
    }
}
