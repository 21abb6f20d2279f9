//! Each baseline's threshold (and, on a dataset with learned
//! descriptors, its descriptor weight) chosen on the validation runs,
//! never on the test runs, as the deep methods' lambdas are.

use std::collections::BTreeMap;

use super::{eval_run_into, validation_runs};
use crate::config::Settings;
use crate::matching::{BaselineValue, DESCRIPTOR_WEIGHTS, Method};
use crate::pipeline::{self, RunError, Warnings};
use crate::sensor::PoseNoiseLabel;
use crate::tables::{MethodLevel, RunEval};

/// One baseline's threshold as [`tune_baselines`] chose it.
#[derive(Clone, Debug, PartialEq)]
pub struct TunedBaseline {
    pub method: Method,
    /// What the value is ([`crate::matching::BaselineKnob::name`]).
    pub parameter: &'static str,
    pub value: f64,
    /// The power of learned descriptors' likelihood ratio chosen with it
    /// (MOGM and RGM on a dataset with descriptors).
    pub descriptor_weight: Option<f64>,
    /// Its mean F1 over the validation runs (of the mean over the levels).
    pub f1: f64,
    /// The value fixed before any data was seen, and its mean F1.
    pub a_priori: f64,
    pub f1_a_priori: f64,
    /// Said when the value is the first or last of its grid (the data may
    /// want one beyond it).
    pub note: Option<String>,
}

/// The mean over runs of each run's mean F1 over `levels` (runs and
/// levels without pairs to find or found left out).
fn mean_f1(runs: &[RunEval], levels: &[PoseNoiseLabel], m: Method) -> f64 {
    let per_run: Vec<f64> = runs
        .iter()
        .filter_map(|r| {
            let f: Vec<f64> = levels
                .iter()
                .filter_map(|&l| r.table1.get(&MethodLevel::new(m, l)).map(|c| c.f1()))
                .filter(|f| f.is_finite())
                .collect();
            (!f.is_empty()).then(|| f.iter().sum::<f64>() / f.len() as f64)
        })
        .collect();
    per_run.iter().sum::<f64>() / per_run.len().max(1) as f64
}

/// The a-priori threshold of baseline `m` (what it runs with when no
/// value is given).
fn a_priori_value(settings: &Settings, m: Method) -> f64 {
    settings.matching.a_priori_value(m)
}

/// Chooses each baseline's threshold among `[matching] methods` on the
/// validation runs, never on the test runs, as the deep methods' lambda:
/// every value of its grid ([`Method::baseline_knob`]) runs on every
/// validation run, and the value with the best mean F1 (over the runs,
/// of the mean over the pose-noise levels) wins, the a-priori value on
/// ties, else the earlier one of the grid. Values that shape the
/// optimisation (RGM's price, the gates) are run, not re-decided. On a
/// dataset with learned descriptors, the descriptor weight of MOGM, RGM
/// and GPS+appearance Hungarian
/// ([`crate::matching::DESCRIPTOR_WEIGHTS`]) is chosen first, the same
/// way at the a-priori threshold (1, the ratio as fitted, on ties), and
/// the threshold then with it. `progress(pass, passes)` after each pass
/// over the runs.
pub fn tune_baselines(
    settings: &Settings,
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(usize, usize),
) -> Result<Vec<TunedBaseline>, RunError> {
    let knobs: Vec<(Method, crate::matching::BaselineKnob)> = settings
        .matching
        .methods
        .iter()
        .filter_map(|&m| m.baseline_knob().map(|k| (m, k)))
        .collect();
    if knobs.is_empty() {
        return Ok(Vec::new());
    }
    let weighs = settings
        .dataset
        .as_ref()
        .map_or(!settings.appearance.appearance_width().is_none(), |d| {
            d.descriptor_law.is_some()
        });
    let weighed: Vec<Method> = knobs
        .iter()
        .map(|(m, _)| *m)
        .filter(|m| weighs && m.weighs_descriptors())
        .collect();
    let grid_passes = 1 + knobs.iter().map(|(_, k)| k.grid.len()).max().unwrap_or(0);
    let weight_passes = if weighed.is_empty() {
        0
    } else {
        DESCRIPTOR_WEIGHTS.len()
    };
    let mut passes = Passes {
        validation: validation_runs(settings)?,
        settings,
        run: (threads, warnings),
        done: 0,
        total: weight_passes + grid_passes,
        progress,
    };
    let weights = descriptor_weights(&mut passes, &weighed)?;
    let at = |m: Method, value: f64| BaselineValue {
        value,
        descriptor_weight: weights.get(&m).copied().unwrap_or(1.0),
    };
    // Pass 0 runs the a-priori values that are not in their grid; pass k
    // the k-th value of each grid.
    let off_grid = |m: Method, k: &crate::matching::BaselineKnob| {
        !k.grid.contains(&a_priori_value(settings, m))
    };
    let mut f1: BTreeMap<(Method, usize), f64> = BTreeMap::new();
    for pass in 0..grid_passes {
        let mut values = BTreeMap::new();
        for (m, k) in &knobs {
            match pass.checked_sub(1) {
                None if off_grid(*m, k) => {
                    values.insert(*m, at(*m, a_priori_value(settings, *m)));
                }
                Some(i) if i < k.grid.len() => {
                    values.insert(*m, at(*m, k.grid[i]));
                }
                _ => {}
            }
        }
        for (m, f) in passes.run(&values)? {
            f1.insert((m, pass), f);
        }
    }
    Ok(knobs
        .into_iter()
        .map(|(m, k)| {
            let mut t = best_of_grid(settings, m, &k, &f1);
            t.descriptor_weight = weights.get(&m).copied();
            t
        })
        .collect())
}

/// The validation runs, and how many passes over them are done of all.
struct Passes<'a, P> {
    validation: Vec<Settings>,
    settings: &'a Settings,
    run: (usize, &'a Warnings),
    done: usize,
    total: usize,
    progress: P,
}

impl<P: FnMut(usize, usize)> Passes<'_, P> {
    /// One pass: every validation run with the baselines at `values`.
    fn run(
        &mut self,
        values: &BTreeMap<Method, BaselineValue>,
    ) -> Result<BTreeMap<Method, f64>, RunError> {
        let f1 = validation_f1s(&self.validation, values, self.run, self.settings)?;
        self.done += 1;
        (self.progress)(self.done, self.total);
        Ok(f1)
    }
}

/// The descriptor weight of each of `weighed` with the best mean F1 on the
/// validation runs at its a-priori threshold, the larger weight on ties.
fn descriptor_weights<P: FnMut(usize, usize)>(
    passes: &mut Passes<'_, P>,
    weighed: &[Method],
) -> Result<BTreeMap<Method, f64>, RunError> {
    let mut weights: BTreeMap<Method, (f64, f64)> = BTreeMap::new();
    if weighed.is_empty() {
        return Ok(BTreeMap::new());
    }
    for w in DESCRIPTOR_WEIGHTS {
        let values = weighed
            .iter()
            .map(|&m| {
                let value = a_priori_value(passes.settings, m);
                let v = BaselineValue {
                    value,
                    descriptor_weight: w,
                };
                (m, v)
            })
            .collect();
        for (m, f) in passes.run(&values)? {
            let best = weights.entry(m).or_insert((w, f));
            if f >= best.1 {
                *best = (w, f);
            }
        }
    }
    Ok(weights.into_iter().map(|(m, (w, _))| (m, w)).collect())
}

/// Baseline `m`'s best value of its grid (`f1` by method and pass: pass 0
/// the a-priori value when it is off the grid, pass `i + 1` the grid's
/// `i`-th), the a-priori value on ties.
fn best_of_grid(
    settings: &Settings,
    m: Method,
    k: &crate::matching::BaselineKnob,
    f1: &BTreeMap<(Method, usize), f64>,
) -> TunedBaseline {
    let a_priori = a_priori_value(settings, m);
    let f1_a_priori = match k.grid.iter().position(|&v| v == a_priori) {
        Some(i) => f1[&(m, i + 1)],
        None => f1[&(m, 0)],
    };
    let (mut value, mut best) = (a_priori, f1_a_priori);
    for (i, &v) in k.grid.iter().enumerate() {
        let f = f1[&(m, i + 1)];
        if f > best {
            (value, best) = (v, f);
        }
    }
    let edge = match (k.grid.first(), k.grid.last()) {
        (Some(&first), _) if value == first && value != a_priori => Some("smallest"),
        (_, Some(&last)) if value == last && value != a_priori => Some("largest"),
        _ => None,
    };
    TunedBaseline {
        method: m,
        parameter: k.name,
        value,
        descriptor_weight: None,
        f1: best,
        a_priori,
        f1_a_priori,
        note: edge.map(|e| {
            format!(
                "{value} is the {e} {} of its grid: the data may do better beyond it",
                k.name
            )
        }),
    }
}

/// Every validation run with the baselines at `values`: each method's
/// mean F1 ([`mean_f1`]); none without values.
fn validation_f1s(
    validation: &[Settings],
    values: &BTreeMap<Method, BaselineValue>,
    (threads, warnings): (usize, &Warnings),
    settings: &Settings,
) -> Result<BTreeMap<Method, f64>, RunError> {
    let methods: Vec<Method> = values.keys().copied().collect();
    if methods.is_empty() {
        return Ok(BTreeMap::new());
    }
    let levels: Vec<_> = settings.pose_noise.iter().map(|l| l.label).collect();
    let mut evals = Vec::with_capacity(validation.len());
    let found = pipeline::Found::baselines_at(values.clone());
    for run in validation {
        let runners = pipeline::runners_with(run, &found, &methods)?;
        let no_lambdas = BTreeMap::new();
        evals.push(eval_run_into(
            RunEval::default(),
            run,
            &runners,
            (&no_lambdas, threads),
            warnings,
            |_| {},
        )?);
    }
    Ok(methods
        .iter()
        .map(|&m| (m, mean_f1(&evals, &levels, m)))
        .collect())
}
