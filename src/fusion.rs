//! Multi-vehicle fusion of matched measurements (paper Section 3.4,
//! Eq. 14-16) and, beyond the paper, refinement of the relative pose between
//! two vehicles from the objects they both matched.
//!
//! Pure computation on nalgebra types; every position and covariance is in
//! one common frame, stated by the caller.

use nalgebra::{Matrix2, Matrix3, Vector3};

use crate::geometry::{Cov2, Pose2, Vec2, wrap_angle};

crate::label_enum! { "fusion variant";
    /// How the matched measurements are fused.
    #[strum(serialize_all = "lowercase")]
    pub enum FusionVariant {
        /// Paper Eq. 14-16 with the relative pose from both vehicles' GPS.
        Paper,
        /// The relative pose refined from the matched objects first ([`align`]).
        Aligned,
    }
}

/// `[fusion]`: which variants are reported, and when alignment applies.
#[derive(Clone, Debug, PartialEq)]
pub struct FusionSettings {
    pub variants: Vec<FusionVariant>,
    /// The aligned variant falls back to the GPS pose below this many
    /// matched objects.
    pub align_min_matches: usize,
}

/// One vehicle's measurement of an object, already in the common frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurement {
    pub position_m: Vec2,
    pub cov_m2: Cov2,
}

impl Measurement {
    /// The measurement of a point given in `pose`'s body frame, expressed in
    /// the parent frame: the covariance rotates with the point (`sigma` of
    /// Eq. 15).
    pub fn moved(&self, pose: &Pose2) -> Measurement {
        Measurement {
            position_m: pose.to_parent(&self.position_m),
            cov_m2: pose.cov_to_parent(&self.cov_m2),
        }
    }
}

/// The fused estimate of one object.
#[derive(Clone, Debug, PartialEq)]
pub struct Fused {
    /// Eq. 15.
    pub position_m: Vec2,
    /// Eq. 16.
    pub cov_m2: Cov2,
    /// Eq. 14, one gain per measurement, in input order; they sum to I.
    pub gains: Vec<Matrix2<f64>>,
}

/// Fuses N >= 1 measurements of one object (all in the same frame):
/// `P = (sum_n P_n^-1)^-1`, `M_i = P P_i^-1`, `v = sum_i M_i v_i`.
/// `None` when a covariance (or the information sum) is singular.
pub fn fuse(measurements: &[Measurement]) -> Option<Fused> {
    if measurements.is_empty() {
        return None;
    }
    let infos: Vec<Matrix2<f64>> = measurements
        .iter()
        .map(|m| m.cov_m2.try_inverse())
        .collect::<Option<_>>()?;
    let info_sum = infos.iter().fold(Matrix2::zeros(), |s, i| s + i);
    let cov = info_sum.try_inverse()?;
    let gains: Vec<Matrix2<f64>> = infos.iter().map(|i| cov * i).collect();
    let position_m = gains
        .iter()
        .zip(measurements)
        .fold(Vec2::zeros(), |s, (g, m)| s + g * m.position_m);
    // Symmetrise against round-off.
    let cov_m2 = (cov + cov.transpose()) * 0.5;
    Some(Fused {
        position_m,
        cov_m2,
        gains,
    })
}

/// The chi-square probability beyond which matched measurements are
/// taken to disagree more than their covariances allow
/// ([`consistency_scale`]): the textbook 99 %, fixed before any data was
/// looked at.
pub const CONSISTENCY_GATE_PROB: f64 = 0.99;

/// How much the measurements' covariances must grow for their spread about
/// the fused position to be believable: `q = sum_i (v_i - v)^T P_i^-1
/// (v_i - v)` is chi-square with `2 (N - 1)` degrees of freedom when every
/// covariance is the truth and every measurement is of the same object (for
/// two, `d^T (P_1 + P_2)^-1 d` of their difference `d`). Beyond the
/// [`CONSISTENCY_GATE_PROB`] quantile the covariances are scaled by the
/// maximum-likelihood factor `q / (2 (N - 1))`, below it by 1. Scaling
/// every covariance by one factor keeps the gains and the fused position
/// and scales Eq. 16's covariance by it: the claim grows where the inputs
/// disagree (a wrong match, a report too confident), as an adaptive filter
/// scales its covariance by the innovation. 1 for one measurement.
pub fn consistency_scale(measurements: &[Measurement], fused: &Fused) -> f64 {
    let dof = 2 * measurements.len().saturating_sub(1);
    if dof == 0 {
        return 1.0;
    }
    let q: f64 = measurements
        .iter()
        .map(|m| {
            let d = m.position_m - fused.position_m;
            m.cov_m2
                .try_inverse()
                .map_or(f64::INFINITY, |inv| (d.transpose() * inv * d)[(0, 0)])
        })
        .sum();
    if q > consistency_gate(dof) {
        q / dof as f64
    } else {
        1.0
    }
}

/// The covariance a fused estimate `fused` can claim when the match it
/// fused is right only with `probability` (the matching method's own): the
/// mixture of two hypotheses about the committed estimate's error. Right:
/// Eq. 16's covariance times the inputs' [`consistency_scale`] `scale`.
/// Wrong: the ego's own measurement `own` is the object's only evidence, so
/// the error is its error plus the pull of the fusion, `P_own + (v -
/// v_own)(v - v_own)^T`: the covariance probabilistic data association
/// gives an estimate committed to one hypothesis. With probability 1 it is
/// the scaled Eq. 16; it stays honest only as far as the method's
/// probabilities are calibrated.
pub fn hedged_covariance(own: &Measurement, fused: &Fused, scale: f64, probability: f64) -> Cov2 {
    let p = probability.clamp(0.0, 1.0);
    let pull = fused.position_m - own.position_m;
    fused.cov_m2 * (scale * p) + (own.cov_m2 + pull * pull.transpose()) * (1.0 - p)
}

/// The [`CONSISTENCY_GATE_PROB`] quantile of the chi-square distribution
/// with `dof` degrees of freedom (statrs), computed once for the first
/// sixteen measurements' `dof` (the fusion asks for it per object).
fn consistency_gate(dof: usize) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    let quantile = |dof: usize| {
        ChiSquared::new(dof as f64).map_or(f64::INFINITY, |d| d.inverse_cdf(CONSISTENCY_GATE_PROB))
    };
    let table = TABLE.get_or_init(|| (0..=30).map(quantile).collect());
    table.get(dof).copied().unwrap_or_else(|| quantile(dof))
}

/// Covariance intersection of N >= 1 measurements whose errors may be
/// correlated in unknown ways (a shared GNSS error, a track sent again):
/// `P^-1 = sum_i w_i P_i^-1`, `v = P sum_i w_i P_i^-1 v_i`, with weights
/// `w_i >= 0` summing to 1 that minimise the trace of `P` (golden-section
/// moves toward one vertex of the simplex at a time). Never claims more
/// than any convex combination of the inputs; with one measurement, it is
/// that measurement. The gains are `w_i P P_i^-1`.
pub fn covariance_intersection(measurements: &[Measurement]) -> Option<Fused> {
    let infos: Vec<Matrix2<f64>> = measurements
        .iter()
        .map(|m| m.cov_m2.try_inverse())
        .collect::<Option<_>>()?;
    let n = infos.len();
    if n == 0 {
        return None;
    }
    let trace = |w: &[f64]| {
        let info = infos
            .iter()
            .zip(w)
            .fold(Matrix2::zeros(), |s, (i, &w)| s + i * w);
        info.try_inverse().map_or(f64::INFINITY, |p| p.trace())
    };
    // From equal weights, move toward one vertex at a time (the trace of
    // P is convex in w) while the trace falls.
    let mut w = vec![1.0 / n as f64; n];
    for _ in 0..50 {
        let before = trace(&w);
        for i in 0..n {
            let toward = |t: f64| {
                let mut v: Vec<f64> = w.iter().map(|x| x * (1.0 - t)).collect();
                v[i] += t;
                v
            };
            let t = golden_min(|t| trace(&toward(t)), 0.0, 1.0);
            w = toward(t);
        }
        if before - trace(&w) <= 1e-13 * before.abs().max(1e-300) {
            break;
        }
    }
    let info = infos
        .iter()
        .zip(&w)
        .fold(Matrix2::zeros(), |s, (i, &w)| s + i * w);
    let cov = info.try_inverse()?;
    let gains: Vec<Matrix2<f64>> = infos.iter().zip(&w).map(|(i, &w)| cov * i * w).collect();
    let position_m = gains
        .iter()
        .zip(measurements)
        .fold(Vec2::zeros(), |s, (g, m)| s + g * m.position_m);
    Some(Fused {
        position_m,
        cov_m2: (cov + cov.transpose()) * 0.5,
        gains,
    })
}

/// The minimum of a unimodal `f` on `[lo, hi]` by golden-section search.
fn golden_min(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..80 {
        if fc <= fd {
            hi = d;
            (d, fd) = (c, fc);
            c = hi - g * (hi - lo);
            fc = f(c);
        } else {
            lo = c;
            (c, fc) = (d, fd);
            d = lo + g * (hi - lo);
            fd = f(d);
        }
    }
    let mid = (lo + hi) / 2.0;
    // The ends may be the minimum (one measurement dominates).
    [0.0, 1.0, mid]
        .into_iter()
        .min_by(|&a, &b| f(a).total_cmp(&f(b)))
        .unwrap_or(mid)
}

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
fn perp(v: &Vec2) -> Vec2 {
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

/// Result of [`align`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    /// The second vehicle's pose in the first vehicle's frame, with its
    /// posterior covariance (or the prior's, when the prior was kept).
    pub estimate: PoseEstimate,
    /// False when there were too few matches and the prior was kept.
    pub refined: bool,
}

/// Smallest prior sigmas: a perfect GPS still leaves the problem well posed.
const MIN_POSITION_SIGMA_M: f64 = 0.01;
const MIN_HEADING_SIGMA_RAD: f64 = 1e-4;
/// Huber threshold on the Mahalanobis residual: pairs beyond it (likely
/// wrong matches) get less weight.
const HUBER_K: f64 = 2.5;

/// The information (inverse covariance) of a prior, floored so that a
/// perfect GPS still leaves the problem well posed.
fn prior_information(prior: &PoseEstimate) -> Matrix3<f64> {
    let floor = Matrix3::from_diagonal(&Vector3::new(
        MIN_POSITION_SIGMA_M.powi(2),
        MIN_POSITION_SIGMA_M.powi(2),
        MIN_HEADING_SIGMA_RAD.powi(2),
    ));
    (prior.cov + floor)
        .try_inverse()
        .unwrap_or_else(|| floor.try_inverse().unwrap_or_else(Matrix3::identity))
}

/// The Gauss-Newton system of [`align`] at `x = (tx, ty, theta)`: the
/// Hessian (prior plus Huber-weighted pairs) and the gradient.
fn normal_equations(
    pairs: &[(Measurement, Measurement)],
    prior_info: &Matrix3<f64>,
    x0: &Vector3<f64>,
    x: &Vector3<f64>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let pose = Pose2::new(Vec2::new(x[0], x[1]), x[2]);
    let mut h = *prior_info;
    let mut dx0 = x - x0;
    dx0[2] = wrap_angle(dx0[2]);
    let mut g = -(prior_info * dx0);
    for (m1, m2) in pairs {
        let moved = m2.moved(&pose);
        let r = m1.position_m - moved.position_m;
        let Some(w) = (m1.cov_m2 + moved.cov_m2).try_inverse() else {
            continue;
        };
        let maha = (r.transpose() * w * r)[(0, 0)].max(0.0).sqrt();
        let huber = if maha <= HUBER_K { 1.0 } else { HUBER_K / maha };
        let w = w * huber;
        // d(R p2 + t)/d(tx, ty, theta)
        let lever = perp(&(moved.position_m - pose.position_m()));
        let j = nalgebra::Matrix2x3::new(1.0, 0.0, lever.x, 0.0, 1.0, lever.y);
        h += j.transpose() * w * j;
        g += j.transpose() * w * r;
    }
    (h, g)
}

/// Weighted rigid alignment on the ground plane: the pose `(t, theta)` of the
/// second vehicle in the first one's frame that best maps the second
/// vehicle's matched measurements onto the first one's, with
/// `r_k = p1_k - (R p2_k + t)`, weights `(P1_k + R P2_k R^T)^-1` (Huber
/// down-weighted), plus the GPS prior as a Gaussian on `(t, theta)`.
/// Gauss-Newton from the prior; the posterior covariance is the inverse
/// Hessian at the solution. With fewer than `min_matches` pairs the prior
/// is returned unchanged.
pub fn align(
    pairs: &[(Measurement, Measurement)],
    prior: &PoseEstimate,
    min_matches: usize,
) -> Alignment {
    let kept = Alignment {
        estimate: *prior,
        refined: false,
    };
    if pairs.len() < min_matches.max(1) {
        return kept;
    }
    let prior_info = prior_information(prior);
    let x0 = Vector3::new(
        prior.pose.position_m().x,
        prior.pose.position_m().y,
        prior.pose.heading_rad(),
    );
    let mut x = x0;
    for _ in 0..15 {
        let (h, g) = normal_equations(pairs, &prior_info, &x0, &x);
        let Some(step) = h.try_inverse().map(|hi| hi * g) else {
            break;
        };
        x += step;
        if step.norm() < 1e-9 {
            break;
        }
    }
    let (h, _) = normal_equations(pairs, &prior_info, &x0, &x);
    match h.try_inverse() {
        Some(cov) if x.iter().all(|v| v.is_finite()) => Alignment {
            estimate: PoseEstimate {
                pose: Pose2::new(Vec2::new(x[0], x[1]), x[2]),
                cov: (cov + cov.transpose()) * 0.5,
            },
            refined: true,
        },
        _ => kept,
    }
}

#[cfg(test)]
mod tests {
    /// The consistency scale on hand-made pairs: two measurements at the
    /// same place (and one alone) keep Eq. 16's claim; 10 m apart with unit
    /// covariances `q = 100 / 2 = 50`, beyond chi2(2)'s 99 % (9.21), so the
    /// claim grows by `q / 2 = 25`; just inside the gate it stays.
    #[test]
    fn consistency_scale_gives_the_known_results() {
        let at = |x: f64| Measurement {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::identity(),
        };
        let scale = |ms: &[Measurement]| consistency_scale(ms, &fuse(ms).unwrap());
        assert_eq!(scale(&[at(1.0), at(1.0)]), 1.0);
        assert_eq!(scale(&[at(3.0)]), 1.0);
        assert!((scale(&[at(0.0), at(10.0)]) - 25.0).abs() < 1e-9);
        // q = d^2 / 2: d^2 = 18.0 gives q = 9.0 < 9.21; 19.0 gives 9.5.
        assert_eq!(scale(&[at(0.0), at(18f64.sqrt())]), 1.0);
        assert!((scale(&[at(0.0), at(19f64.sqrt())]) - 4.75).abs() < 1e-9);
        // Three measurements: dof 4, gate 13.28; spread q = 2 * 6^2 = 72.
        let three = [at(-6.0), at(0.0), at(6.0)];
        assert!((scale(&three) - 72.0 / 4.0).abs() < 1e-9);
    }

    /// Pairs drawn from their own covariances: the scale passes about 1 %
    /// of them and the gated claim's NEES stays near 2. When one in five
    /// pairs is a wrong match (the peer's detection of another object 6 m
    /// away), Eq. 16's NEES is far above 2 and the gated one within 1 to 4.
    #[test]
    fn consistency_scale_keeps_the_claim_honest_under_wrong_matches() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let cov = [
            Cov2::new(1.0, 0.3, 0.3, 0.5),
            Cov2::new(0.4, -0.1, -0.1, 2.0),
        ];
        let mut draw = |c: &Cov2, centre: Vec2| {
            let l = c.cholesky().unwrap().l();
            centre + l * Vec2::new(unit.sample(&mut rng), unit.sample(&mut rng))
        };
        let n = 20_000;
        let (mut scaled, mut nees, mut nees_gated) = (0, [0.0; 2], [0.0; 2]);
        for i in 0..n {
            let wrong = i % 5 == 0;
            let peer_object = if wrong {
                Vec2::new(6.0, 0.0)
            } else {
                Vec2::zeros()
            };
            let ms = [
                Measurement {
                    position_m: draw(&cov[0], Vec2::zeros()),
                    cov_m2: cov[0],
                },
                Measurement {
                    position_m: draw(&cov[1], peer_object),
                    cov_m2: cov[1],
                },
            ];
            let f = fuse(&ms).unwrap();
            let s = consistency_scale(&ms, &f);
            let e = f.position_m;
            let q = (e.transpose() * f.cov_m2.try_inverse().unwrap() * e)[(0, 0)];
            let k = usize::from(wrong);
            nees[k] += q;
            nees_gated[k] += q / s;
            scaled += usize::from(!wrong && s > 1.0);
        }
        let right = (n - n / 5) as f64;
        let passed = scaled as f64 / right;
        assert!((0.007..0.013).contains(&passed), "{passed}");
        let gated_right = nees_gated[0] / right;
        assert!((1.85..2.05).contains(&gated_right), "{gated_right}");
        let all = (nees[0] + nees[1]) / n as f64;
        let all_gated = (nees_gated[0] + nees_gated[1]) / n as f64;
        assert!(all > 4.0, "{all}");
        assert!((1.0..4.0).contains(&all_gated), "{all_gated}");
    }

    /// The hedged claim on hand-made cases: certain, it is Eq. 16's times
    /// the scale; impossible, the ego's own plus the pull of the fusion.
    #[test]
    fn hedged_covariance_gives_the_known_results() {
        let own = Measurement {
            position_m: Vec2::new(0.0, 0.0),
            cov_m2: Cov2::new(2.0, 0.0, 0.0, 1.0),
        };
        let peer = Measurement {
            position_m: Vec2::new(1.0, 0.0),
            cov_m2: Cov2::new(2.0, 0.0, 0.0, 1.0),
        };
        let f = fuse(&[own, peer]).unwrap();
        assert!((hedged_covariance(&own, &f, 1.0, 1.0) - f.cov_m2).norm() < 1e-12);
        assert!((hedged_covariance(&own, &f, 3.0, 1.0) - f.cov_m2 * 3.0).norm() < 1e-12);
        // Fused at (0.5, 0): the pull adds 0.25 along x.
        let wrong = Cov2::new(2.25, 0.0, 0.0, 1.0);
        assert!((hedged_covariance(&own, &f, 1.0, 0.0) - wrong).norm() < 1e-12);
        let half = f.cov_m2 * 0.5 + wrong * 0.5;
        assert!((hedged_covariance(&own, &f, 1.0, 0.5) - half).norm() < 1e-12);
    }

    /// Three in ten matches wrong (the peer's measurement of another
    /// object anywhere in a 40 m square, as likely inside the ego's wide
    /// covariance as anywhere else), each with the probability a
    /// calibrated method would give (the posterior of "same object" with a
    /// prior of 0.7): Eq. 16's NEES is far above 2 (578 here), the hedged
    /// claim's near 2 (2.004), as the mixture is the error's covariance.
    #[test]
    fn the_hedged_claim_is_honest_when_the_probability_is_calibrated() {
        use rand::{Rng, SeedableRng};
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let (p_own, p_peer) = (Cov2::new(4.0, 0.5, 0.5, 2.0), Cov2::new(0.1, 0.0, 0.0, 0.2));
        let sum_inv = (p_own + p_peer).try_inverse().unwrap();
        let density_right = |d: Vec2| {
            (-0.5 * (d.transpose() * sum_inv * d)[(0, 0)]).exp()
                / (2.0 * std::f64::consts::PI * (p_own + p_peer).determinant().sqrt())
        };
        let (prior, half) = (0.7, 20.0);
        let area = (2.0 * half) * (2.0 * half);
        let n = 40_000;
        let (mut eq16, mut hedged) = (0.0, 0.0);
        for _ in 0..n {
            let draw = |c: &Cov2, rng: &mut rand_chacha::ChaCha8Rng| {
                c.cholesky().unwrap().l() * Vec2::new(unit.sample(rng), unit.sample(rng))
            };
            let own = Measurement {
                position_m: draw(&p_own, &mut rng),
                cov_m2: p_own,
            };
            let peer_at = if rng.random::<f64>() < prior {
                draw(&p_peer, &mut rng)
            } else {
                Vec2::new(rng.random_range(-half..half), rng.random_range(-half..half))
            };
            let peer = Measurement {
                position_m: peer_at,
                cov_m2: p_peer,
            };
            let right = prior * density_right(peer_at - own.position_m);
            let probability = right / (right + (1.0 - prior) / area);
            let ms = [own, peer];
            let f = fuse(&ms).unwrap();
            let e = f.position_m;
            let nees = |c: Cov2| (e.transpose() * c.try_inverse().unwrap() * e)[(0, 0)];
            eq16 += nees(f.cov_m2);
            let scale = consistency_scale(&ms, &f);
            hedged += nees(hedged_covariance(&own, &f, scale, probability));
        }
        let (eq16, hedged) = (eq16 / n as f64, hedged / n as f64);
        assert!(eq16 > 10.0, "{eq16}");
        assert!((1.8..2.2).contains(&hedged), "{eq16} {hedged}");
    }

    /// Covariance intersection on hand-made covariances: two mirrored
    /// ellipses meet at w = 1/2 with P = diag(1.6, 1.6); a measurement
    /// that is tighter on every axis takes all the weight; CI is never
    /// tighter than the independent form, and unlike it never claims less
    /// than half the error of two identical, fully correlated copies.
    #[test]
    fn covariance_intersection_gives_the_known_results() {
        let m = |x: f64, a: f64, b: f64| Measurement {
            position_m: Vec2::new(x, 0.0),
            cov_m2: Cov2::new(a, 0.0, 0.0, b),
        };
        let ci = covariance_intersection(&[m(0.0, 1.0, 4.0), m(2.0, 4.0, 1.0)]).unwrap();
        assert!(
            (ci.cov_m2 - Cov2::identity() * 1.6).norm() < 1e-6,
            "{}",
            ci.cov_m2
        );
        assert!((ci.position_m.x - 0.4).abs() < 1e-6, "{}", ci.position_m);
        let ci = covariance_intersection(&[m(0.0, 1.0, 1.0), m(5.0, 4.0, 9.0)]).unwrap();
        assert!((ci.position_m.x).abs() < 1e-6 && (ci.cov_m2 - Cov2::identity()).norm() < 1e-6);
        let same = [m(1.0, 2.0, 2.0), m(1.0, 2.0, 2.0)];
        let (ci, ind) = (
            covariance_intersection(&same).unwrap(),
            fuse(&same).unwrap(),
        );
        assert!((ci.cov_m2 - Cov2::identity() * 2.0).norm() < 1e-9);
        assert!((ind.cov_m2 - Cov2::identity()).norm() < 1e-12);
        let one = covariance_intersection(&[m(3.0, 2.0, 5.0)]).unwrap();
        assert_eq!((one.position_m.x, one.cov_m2[(1, 1)]), (3.0, 5.0));
        let gains = ci.gains.iter().fold(Matrix2::zeros(), |s, g| s + g);
        assert!((gains - Matrix2::identity()).norm() < 1e-9);
    }

    use super::*;
    use proptest::prelude::*;

    fn cov(a: f64, b: f64, c: f64) -> Cov2 {
        // A valid covariance from a lower-triangular factor.
        let l = Matrix2::new(a, 0.0, c, b);
        l * l.transpose() + Cov2::identity() * 1e-3
    }

    proptest! {
        #[test]
        fn gains_sum_to_identity(fs in proptest::collection::vec((0.1..3.0f64, 0.1..3.0f64, -2.0..2.0f64, -20.0..20.0f64, -20.0..20.0f64), 1..6)) {
            let ms: Vec<Measurement> = fs.iter().map(|&(a, b, c, x, y)| Measurement { position_m: Vec2::new(x, y), cov_m2: cov(a, b, c) }).collect();
            let f = fuse(&ms).unwrap();
            let sum = f.gains.iter().fold(Matrix2::zeros(), |s, g| s + g);
            prop_assert!((sum - Matrix2::identity()).norm() < 1e-9);
            // The fused covariance is no larger than any input's.
            for m in &ms {
                prop_assert!(f.cov_m2.trace() <= m.cov_m2.trace() + 1e-9);
            }
        }

        #[test]
        fn agreeing_measurements_fuse_to_the_same_point(x in -50.0..50.0f64, y in -50.0..50.0f64, a in 0.1..3.0f64, b in 0.1..3.0f64) {
            let p = Vec2::new(x, y);
            let ms = [Measurement { position_m: p, cov_m2: cov(a, b, 0.3) }, Measurement { position_m: p, cov_m2: cov(b, a, -0.5) }];
            prop_assert!((fuse(&ms).unwrap().position_m - p).norm() < 1e-9);
        }
    }

    #[test]
    fn equal_covariances_average_and_halve() {
        let c = Cov2::identity() * 4.0;
        let f = fuse(&[
            Measurement {
                position_m: Vec2::new(0.0, 0.0),
                cov_m2: c,
            },
            Measurement {
                position_m: Vec2::new(2.0, 4.0),
                cov_m2: c,
            },
        ])
        .unwrap();
        assert!((f.position_m - Vec2::new(1.0, 2.0)).norm() < 1e-12);
        assert!((f.cov_m2 - Cov2::identity() * 2.0).norm() < 1e-12);
    }

    #[test]
    fn singular_covariance_is_refused() {
        assert!(
            fuse(&[Measurement {
                position_m: Vec2::zeros(),
                cov_m2: Cov2::zeros()
            }])
            .is_none()
        );
        assert!(fuse(&[]).is_none());
    }

    fn scene_pairs(truth: &Pose2, noise: f64) -> Vec<(Measurement, Measurement)> {
        let pts = [
            (5.0, 3.0),
            (20.0, -4.0),
            (12.0, 15.0),
            (30.0, 8.0),
            (8.0, -12.0),
        ];
        pts.iter()
            .enumerate()
            .map(|(k, &(x, y))| {
                let p1 = Vec2::new(x, y);
                let wiggle = Vec2::new((k as f64 * 1.7).sin(), (k as f64 * 2.3).cos()) * noise;
                let p2 = truth.to_body(&p1) + wiggle;
                (
                    Measurement {
                        position_m: p1,
                        cov_m2: Cov2::identity() * 0.25,
                    },
                    Measurement {
                        position_m: p2,
                        cov_m2: Cov2::identity() * 0.25,
                    },
                )
            })
            .collect()
    }

    #[test]
    fn alignment_recovers_the_true_pose_from_a_wrong_prior() {
        let truth = Pose2::new(Vec2::new(40.0, -10.0), 2.2);
        let wrong = Pose2::new(Vec2::new(41.5, -8.8), 2.25);
        let pos_err = |p: &Pose2| (p.position_m() - truth.position_m()).norm();
        let head_err = |p: &Pose2| wrap_angle(p.heading_rad() - truth.heading_rad()).abs();
        // An uninformative prior: exact matches give the exact pose.
        let vague = PoseEstimate::diagonal(wrong, 100.0, 1.0);
        let a = align(&scene_pairs(&truth, 0.0), &vague, 3);
        assert!(a.refined);
        assert!(
            pos_err(&a.estimate.pose) < 0.01 && head_err(&a.estimate.pose) < 1e-3,
            "{:?}",
            a.estimate.pose
        );
        // A GPS-like prior still pulls (this is a MAP estimate, checked
        // against a brute-force minimum: 0.333 m, 0.0102 rad), but the error
        // shrinks several-fold from the prior's 1.92 m / 0.05 rad.
        let gps = PoseEstimate::diagonal(wrong, 1.7, 0.1);
        let a = align(&scene_pairs(&truth, 0.0), &gps, 3);
        assert!(
            (pos_err(&a.estimate.pose) - 0.3333).abs() < 1e-3,
            "{:?}",
            a.estimate.pose
        );
        assert!(
            (head_err(&a.estimate.pose) - 0.01024).abs() < 1e-4,
            "{:?}",
            a.estimate.pose
        );
    }

    #[test]
    fn alignment_falls_back_to_the_prior_with_few_matches() {
        let truth = Pose2::new(Vec2::new(40.0, -10.0), 2.2);
        let prior = PoseEstimate::diagonal(Pose2::new(Vec2::new(41.5, -8.8), 2.2), 1.7, 0.005);
        let pairs = scene_pairs(&truth, 0.0);
        let a = align(&pairs[..2], &prior, 3);
        assert!(!a.refined);
        assert_eq!(a.estimate, prior);
    }

    #[test]
    fn a_tight_prior_wins_over_the_matches() {
        let truth = Pose2::new(Vec2::new(40.0, -10.0), 2.2);
        let prior = PoseEstimate::diagonal(Pose2::new(Vec2::new(40.0, -10.0), 2.2), 0.0, 0.0);
        let a = align(&scene_pairs(&truth, 1.0), &prior, 3);
        assert!((a.estimate.pose.position_m() - truth.position_m()).norm() < 0.02);
    }

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

    #[test]
    fn alignment_shrinks_the_pose_covariance() {
        let truth = Pose2::new(Vec2::new(40.0, -10.0), 2.2);
        let prior = PoseEstimate::diagonal(Pose2::new(Vec2::new(41.5, -8.8), 2.25), 1.7, 0.1);
        let a = align(&scene_pairs(&truth, 0.0), &prior, 3);
        assert!(a.refined);
        for k in 0..3 {
            assert!(
                a.estimate.cov[(k, k)] < 0.25 * prior.cov[(k, k)],
                "{}",
                a.estimate.cov
            );
        }
        assert!(
            a.estimate
                .cov
                .symmetric_eigenvalues()
                .iter()
                .all(|&e| e > 0.0)
        );
    }
}
