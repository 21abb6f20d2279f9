//! A deep method over its training seeds: the runs' counts with the weights
//! of each seed (`RunEval::by_seed`), per run averaged over the seeds (what
//! Table 1's row and the paired differences take), and the spread of the
//! seeds' own means over the runs.

use super::Inputs;
use super::record::MethodLevel;
use crate::evaluate::PairCounts;

/// The spread over training seeds of a row's F1 (each seed's mean over
/// the runs).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct SeedSpread {
    pub seeds: Vec<u64>,
    /// Each seed's mean F1 over the runs, in the order of `seeds`.
    pub f1: Vec<f64>,
}

impl SeedSpread {
    /// The sample standard deviation over the seeds (NaN for one).
    pub(super) fn sd(&self) -> f64 {
        let n = self.f1.len();
        if n < 2 {
            return f64::NAN;
        }
        let mean = self.f1.iter().sum::<f64>() / n as f64;
        let ss: f64 = self.f1.iter().map(|v| (v - mean).powi(2)).sum();
        (ss / (n - 1) as f64).sqrt()
    }

    pub(super) fn min(&self) -> f64 {
        self.f1.iter().copied().fold(f64::NAN, f64::min)
    }

    pub(super) fn max(&self) -> f64 {
        self.f1.iter().copied().fold(f64::NAN, f64::max)
    }

    /// The seeds as text, `7 8 9`.
    pub(super) fn label(&self) -> String {
        let seeds: Vec<String> = self.seeds.iter().map(u64::to_string).collect();
        seeds.join(" ")
    }
}

impl Inputs<'_> {
    /// The training seeds the runs evaluated `key` with (empty unless
    /// `[eval] training_seeds` asked for them).
    pub(super) fn seeds(&self, key: MethodLevel) -> Vec<u64> {
        let mut seeds: Vec<u64> = self
            .runs
            .iter()
            .flat_map(|r| r.by_seed.keys())
            .filter(|(k, _)| *k == key)
            .map(|&(_, s)| s)
            .collect();
        seeds.sort_unstable();
        seeds.dedup();
        seeds
    }

    /// A metric of `key` in every run (NaN where undefined, so that runs
    /// stay aligned): with several training seeds, the mean over the seeds
    /// whose value is defined in that run; else the run's own counts.
    pub(super) fn per_run_over_seeds(
        &self,
        key: MethodLevel,
        metric: impl Fn(&PairCounts) -> f64,
    ) -> Vec<f64> {
        let seeds = self.seeds(key);
        self.runs
            .iter()
            .map(|r| {
                if seeds.is_empty() {
                    return r.table1.get(&key).map_or(f64::NAN, &metric);
                }
                finite_mean(
                    seeds
                        .iter()
                        .filter_map(|&s| r.by_seed.get(&(key, s)).map(&metric)),
                )
            })
            .collect()
    }

    /// The F1 of `key` with the weights of training seed `seed` in every
    /// run (NaN where undefined).
    pub(super) fn f1_per_run_of_seed(&self, key: MethodLevel, seed: u64) -> Vec<f64> {
        self.runs
            .iter()
            .map(|r| r.by_seed.get(&(key, seed)).map_or(f64::NAN, PairCounts::f1))
            .collect()
    }

    /// The spread of `key`'s F1 over its training seeds, if the runs
    /// evaluated it per seed (with one seed: no standard deviation).
    pub(super) fn seed_spread(&self, key: MethodLevel) -> Option<SeedSpread> {
        let seeds = self.seeds(key);
        if seeds.is_empty() {
            return None;
        }
        let f1 = seeds
            .iter()
            .map(|&s| finite_mean(self.f1_per_run_of_seed(key, s)))
            .collect();
        Some(SeedSpread { seeds, f1 })
    }
}

/// The mean of the finite `values` (NaN when there is none).
fn finite_mean(values: impl IntoIterator<Item = f64>) -> f64 {
    let (sum, n) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 { f64::NAN } else { sum / n as f64 }
}
