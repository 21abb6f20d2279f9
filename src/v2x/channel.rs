//! The radio channel between two connected vehicles: each message to each
//! receiver is lost or delivered after a latency, drawn from a named
//! stream keyed by (generation step, sender, receiver), so the same seed
//! gives the same deliveries whatever else happens.

use rand::Rng;
use rand_distr::{Distribution, Exp};

crate::label_enum! { "loss model";
    /// `[v2x.channel] loss`: which [`LossModel`].
    pub enum LossKind {
        #[strum(serialize = "independent")]
        Independent,
        #[strum(serialize = "distance")]
        Distance,
    }
}

/// How messages are lost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LossModel {
    /// Each message to each receiver independently with this probability.
    Independent { probability: f64 },
    /// Growing with distance: `p0 + (1 - p0) (d / range)²`, certain loss
    /// beyond `range_m`.
    Distance { probability_at_0: f64, range_m: f64 },
}

/// `[v2x.channel]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelSettings {
    /// Fixed part of the latency (s).
    pub latency_s: f64,
    /// Mean of the random part, exponentially distributed (s); 0: none.
    pub jitter_mean_s: f64,
    pub loss: LossModel,
}

impl Default for ChannelSettings {
    fn default() -> Self {
        Self {
            latency_s: 0.1,
            jitter_mean_s: 0.0,
            loss: LossModel::Independent { probability: 0.1 },
        }
    }
}

impl ChannelSettings {
    /// The probability that a message over `distance_m` is lost.
    pub fn loss_probability(&self, distance_m: f64) -> f64 {
        match self.loss {
            LossModel::Independent { probability } => probability,
            LossModel::Distance {
                probability_at_0,
                range_m,
            } => {
                if distance_m >= range_m {
                    1.0
                } else {
                    let r = distance_m / range_m;
                    probability_at_0 + (1.0 - probability_at_0) * r * r
                }
            }
        }
    }

    /// One message over `distance_m`: `None` when lost, else its latency
    /// (s). Draws the loss, then the jitter, always both, so the stream
    /// advances the same way either way.
    pub fn deliver(&self, distance_m: f64, rng: &mut impl Rng) -> Option<f64> {
        let u: f64 = rng.random();
        let jitter = match Exp::new(1.0) {
            Ok(e) if self.jitter_mean_s > 0.0 => e.sample(rng) * self.jitter_mean_s,
            _ => 0.0,
        };
        (u >= self.loss_probability(distance_m)).then_some(self.latency_s + jitter)
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// Same stream, same deliveries; the loss rate and the mean latency
    /// are what the settings say; distance loss is certain beyond range.
    #[test]
    fn deliveries_follow_the_settings_and_the_stream() {
        let c = ChannelSettings {
            latency_s: 0.1,
            jitter_mean_s: 0.05,
            loss: LossModel::Independent { probability: 0.3 },
        };
        let run = |seed| {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            (0..20_000)
                .map(|_| c.deliver(50.0, &mut r))
                .collect::<Vec<_>>()
        };
        let a = run(7);
        assert_eq!(a, run(7));
        assert_ne!(a, run(8));
        let delivered: Vec<f64> = a.iter().flatten().copied().collect();
        let lost = 1.0 - delivered.len() as f64 / a.len() as f64;
        assert!((lost - 0.3).abs() < 0.015, "{lost}");
        let mean = delivered.iter().sum::<f64>() / delivered.len() as f64;
        assert!((mean - 0.15).abs() < 0.003, "{mean}");
        assert!(delivered.iter().all(|&l| l >= 0.1));
        let d = ChannelSettings {
            loss: LossModel::Distance {
                probability_at_0: 0.0,
                range_m: 100.0,
            },
            ..c
        };
        assert_eq!(d.loss_probability(0.0), 0.0);
        assert!((d.loss_probability(50.0) - 0.25).abs() < 1e-12);
        assert_eq!(d.loss_probability(150.0), 1.0);
        let mut r = ChaCha8Rng::seed_from_u64(1);
        assert!((0..100).all(|_| d.deliver(150.0, &mut r).is_none()));
    }
}
