//! GPS-Hungarian: the second vehicle's detections are moved into the first
//! vehicle's frame with the relative pose both GPS receivers report; pairs
//! cost their squared Mahalanobis distance under the detection covariances
//! plus the pose uncertainty the receivers claim; the assignment is solved
//! optimally (`lsap`, Jonker-Volgenant) and pairs beyond the chi-square gate
//! are dropped. Position only: no appearance, no graph structure.

use super::{Correspondence, Identification, MatchView, Matcher, Method, binary_entropy_bits};
use crate::geometry::{Cov2, Vec2};

pub struct GpsHungarian {
    /// Gate on the squared Mahalanobis distance.
    pub gate_chi2: f64,
}

/// Covariance, in the first vehicle's frame, of where a point at `p_m`
/// lands because of both vehicles' pose errors: each adds its position error
/// (sigma^2 per axis), and each heading error swings the point about the
/// vehicle by `sigma_h * |p|` across the line of sight.
fn pose_induced_cov(p_m: &Vec2, first: &MatchView, second: &MatchView) -> Cov2 {
    let pos_var =
        first.pose_noise.position_sigma_m.powi(2) + second.pose_noise.position_sigma_m.powi(2);
    let head_var =
        first.pose_noise.heading_sigma_rad.powi(2) + second.pose_noise.heading_sigma_rad.powi(2);
    let perp = Vec2::new(-p_m.y, p_m.x);
    Cov2::identity() * pos_var + perp * perp.transpose() * head_var
}

impl Matcher for GpsHungarian {
    fn method(&self) -> Method {
        Method::GpsHungarian
    }

    fn identify(&self, first: &MatchView, second: &MatchView) -> Identification {
        Identification::plain(self.assign(first, second))
    }
}

impl GpsHungarian {
    fn assign(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence> {
        let (n, m) = (first.detections.len(), second.detections.len());
        if n == 0 || m == 0 {
            return Vec::new();
        }
        let rel = first.pose_reported.relative(&second.pose_reported);
        let moved: Vec<(Vec2, Cov2)> = second
            .detections
            .iter()
            .map(|d| (rel.to_parent(&d.position_m), rel.cov_to_parent(&d.cov_m2)))
            .collect();
        // Gated pairs cost more than any pair that passes, so the solver
        // never trades a good pair for a gated one.
        let blocked = self.gate_chi2 * 1e3;
        let mut cost = vec![blocked; n * m];
        let mut d2 = vec![f64::INFINITY; n * m];
        for (i, da) in first.detections.iter().enumerate() {
            for (j, (pb, cb)) in moved.iter().enumerate() {
                let r = da.position_m - pb;
                let s = da.cov_m2 + cb + pose_induced_cov(pb, first, second);
                let Some(s_inv) = s.try_inverse() else {
                    continue;
                };
                let v = (r.transpose() * s_inv * r)[(0, 0)];
                if v.is_finite() && v <= self.gate_chi2 {
                    cost[i * m + j] = v;
                    d2[i * m + j] = v;
                }
            }
        }
        let Ok((rows, cols)) = lsap::solve(n, m, &cost, false) else {
            return Vec::new();
        };
        let mut out: Vec<Correspondence> = rows
            .into_iter()
            .zip(cols)
            .filter(|&(i, j)| d2[i * m + j].is_finite())
            .map(|(a, b)| {
                // Likelihood ratio against the gate: 1 at zero distance,
                // about 0 at the gate.
                let probability = (-0.5 * d2[a * m + b]).exp();
                Correspondence {
                    a,
                    b,
                    probability,
                    uncertainty: binary_entropy_bits(probability),
                }
            })
            .collect();
        out.sort_by_key(|c| c.a);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::testkit::{self, Side};
    use crate::traffic::ObjectClass;

    #[test]
    fn exact_poses_recover_the_true_pairs_and_gate_the_rest() {
        let white = [0.9; 3];
        let world = vec![
            (Vec2::new(10.0, 5.0), ObjectClass::Car, white),
            (Vec2::new(20.0, -3.0), ObjectClass::Car, white),
            (Vec2::new(15.0, 12.0), ObjectClass::Car, white),
            (Vec2::new(-40.0, 0.0), ObjectClass::Car, white),
        ];
        let a = Side::of((0.0, 0.0, 0.0), &world, &[0, 1, 2], testkit::EXACT);
        // The second vehicle sees the last two objects (in the other order)
        // and one object the first does not see.
        let b = Side::of((30.0, 30.0, -2.0), &world, &[2, 3, 1], testkit::EXACT);
        let m = GpsHungarian { gate_chi2: 9.21 }
            .identify(&a.view(), &b.view())
            .matches;
        let pairs: Vec<(usize, usize)> = m.iter().map(|c| (c.a, c.b)).collect();
        assert_eq!(pairs, vec![(1, 2), (2, 0)]);
        assert!(
            m.iter()
                .all(|c| c.probability > 0.99 && c.uncertainty < 0.1)
        );
        let empty = Side::new(vec![], vec![], b.pose, testkit::EXACT);
        let none = GpsHungarian { gate_chi2: 9.21 }.identify(&a.view(), &empty.view());
        assert!(none.matches.is_empty());
    }
}
