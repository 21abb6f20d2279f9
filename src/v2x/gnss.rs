//! GNSS pose error correlated in time: a first-order Gauss-Markov process
//! per axis (x, y, heading), `e(t + dt) = a e(t) + sqrt(1 - a²) sigma w`,
//! `a = exp(-dt / tau)`, started from its stationary distribution, so
//! every step has the level's sigma and errors decorrelate over `tau`.
//! `tau = 0` gives independent errors per step (today's model).

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::geometry::{Pose2, Vec2};
use crate::sensor::PoseNoiseLevel;

/// A vehicle's GNSS error at one time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GnssError {
    pub position_m: Vec2,
    pub heading_rad: f64,
}

impl GnssError {
    /// The pose the GNSS reports for `truth`.
    pub fn apply(&self, truth: &Pose2) -> Pose2 {
        Pose2::new(
            truth.position_m() + self.position_m,
            truth.heading_rad() + self.heading_rad,
        )
    }
}

/// The error `dt_s` after `previous` (or a first one, stationary), with
/// correlation time `tau_s`; draws three normals, always.
pub fn next_error(
    previous: Option<GnssError>,
    dt_s: f64,
    tau_s: f64,
    level: &PoseNoiseLevel,
    rng: &mut impl Rng,
) -> GnssError {
    let mut w = || -> f64 { StandardNormal.sample(rng) };
    let (wx, wy, wh) = (w(), w(), w());
    let a = match previous {
        Some(_) if tau_s > 0.0 => (-dt_s.max(0.0) / tau_s).exp(),
        _ => 0.0,
    };
    let b = (1.0 - a * a).sqrt();
    let prev = previous.unwrap_or_default();
    let (sp, sh) = (level.position_sigma_m, level.heading_sigma_rad);
    GnssError {
        position_m: Vec2::new(
            a * prev.position_m.x + b * sp * wx,
            a * prev.position_m.y + b * sp * wy,
        ),
        heading_rad: a * prev.heading_rad + b * sh * wh,
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::sensor::PoseNoiseLabel;

    /// The process keeps the level's sigma at every step and its lag
    /// correlation is exp(-dt / tau); tau = 0 is white.
    #[test]
    fn gauss_markov_keeps_sigma_and_correlates_over_tau() {
        let level = PoseNoiseLevel {
            label: PoseNoiseLabel::Gps,
            position_sigma_m: 1.2,
            heading_sigma_rad: 0.0035,
        };
        let series = |tau: f64| {
            let mut r = ChaCha8Rng::seed_from_u64(3);
            let mut e = None;
            (0..200_000)
                .map(|_| {
                    let n = next_error(e, 0.1, tau, &level, &mut r);
                    e = Some(n);
                    n.position_m.x
                })
                .collect::<Vec<f64>>()
        };
        for (tau, expect) in [(2.0, (-0.1f64 / 2.0).exp()), (0.0, 0.0)] {
            let x = series(tau);
            let n = x.len() as f64;
            let var = x.iter().map(|v| v * v).sum::<f64>() / n;
            let lag = x.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (n - 1.0) / var;
            assert!(
                (var.sqrt() - 1.2).abs() < 0.04,
                "tau {tau}: sigma {}",
                var.sqrt()
            );
            assert!(
                (lag - expect).abs() < 0.02,
                "tau {tau}: lag {lag} vs {expect}"
            );
        }
    }
}
