//! Paired differences: each method's F1 minus the strongest baseline's
//! that sees the same inputs (Table 1: the paper's inputs; Table 1b: the
//! reported poses too); the paper's method (`coid`) and `ours` minus every
//! other method that sees what they see (DGMC, GCN-GM, the ablations);
//! and each MC-dropout method's minus its own single pass (`coid`
//! against `coid-t1`), run by run (the same
//! runs, hence the same instances, on both sides), with a percentile
//! bootstrap interval over the runs. Where the interval covers 0 the table
//! says "no difference". A deep method evaluated with several training
//! seeds enters with its mean over the seeds in each run, and the table
//! counts how many seeds are better or worse on their own.

use super::Inputs;
use super::columns::Columns;
use super::record::MethodLevel;
use crate::matching::{Inputs as MethodInputs, Method, MethodKind};
use crate::report::{PairedDifference, Table, mean_ci95, paired_bootstrap};
use crate::sensor::PoseNoiseLabel;

/// The seed of every bootstrap: the same runs give the same interval.
pub(super) const BOOTSTRAP_SEED: u64 = 0x0c01_d5ee_d000_0033;

/// Whether `m` is a baseline a method is compared with: the learning-free
/// and GPS-based methods and the published deep ones, GCN-GM and DGMC
/// (not the oracle, not the paper's method, its ablations or extensions,
/// not an external file).
fn is_baseline(m: Method) -> bool {
    matches!(m.kind(), MethodKind::LearningFree | MethodKind::GpsBased)
        || matches!(m, Method::Dgmc | Method::GcnGm)
}

/// The baseline seeing `inputs` with the highest mean F1 at level `l`
/// (the strongest: the comparison hardest to win), if the runs hold one.
fn strongest_baseline(inp: &Inputs, inputs: MethodInputs, l: PoseNoiseLabel) -> Option<Method> {
    inp.methods
        .iter()
        .copied()
        .filter(|&m| is_baseline(m) && m.inputs() == inputs)
        .map(|m| (m, mean_ci95(&f1_per_run(inp, MethodLevel::new(m, l))).0))
        .filter(|(_, f1)| f1.is_finite())
        .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
        .map(|(m, _)| m)
}

/// The F1 of `key` in every run, NaN where undefined (so that runs stay
/// aligned across methods); over several training seeds, their mean.
fn f1_per_run(inp: &Inputs, key: MethodLevel) -> Vec<f64> {
    inp.per_run_over_seeds(key, crate::evaluate::PairCounts::f1)
}

/// Of `key`'s training seeds (when it has several), how many are better
/// and how many worse than `base` by their own paired interval.
fn seed_verdicts(inp: &Inputs, key: MethodLevel, base: &[f64]) -> (usize, usize) {
    let seeds = inp.seeds(key);
    let signs: Vec<Option<bool>> = seeds
        .iter()
        .map(|&s| paired_bootstrap(&inp.f1_per_run_of_seed(key, s), base, BOOTSTRAP_SEED).sign())
        .collect();
    (
        signs.iter().filter(|s| **s == Some(true)).count(),
        signs.iter().filter(|s| **s == Some(false)).count(),
    )
}

/// Every other method against the strongest baseline, level by level.
pub(super) fn paired(inp: &Inputs) -> Table {
    struct Row {
        key: MethodLevel,
        reference: Method,
        d: PairedDifference,
        /// Training seeds, and of them how many are better and how many
        /// worse on their own.
        seeds: usize,
        verdicts: (usize, usize),
    }
    let mut rows = Vec::new();
    let mut push = |key: MethodLevel, reference: Method| {
        let base = f1_per_run(inp, MethodLevel::new(reference, key.pose_noise));
        rows.push(Row {
            key,
            reference,
            d: paired_bootstrap(&f1_per_run(inp, key), &base, BOOTSTRAP_SEED),
            seeds: inp.seeds(key).len(),
            verdicts: seed_verdicts(inp, key, &base),
        });
    };
    for inputs in [MethodInputs::Paper, MethodInputs::V2xPoses] {
        for &l in &inp.levels {
            let Some(reference) = strongest_baseline(inp, inputs, l) else {
                continue;
            };
            let others = inp
                .methods
                .iter()
                .filter(|&&m| m != reference && m.inputs() == inputs);
            for &m in others {
                push(MethodLevel::new(m, l), reference);
            }
            // The paper's method (on its inputs) and ours (with the poses)
            // against every other method that sees what they see, the
            // published networks and the ablations among them.
            let headline = [Method::Coid, Method::Ours];
            for &m in headline.iter().filter(|m| inp.methods.contains(m)) {
                let others = inp.methods.iter().filter(|&&o| {
                    o != m
                        && o != reference
                        && o.inputs() == m.inputs()
                        && m.inputs() == inputs
                        && !o.single_pass()
                });
                for &o in others {
                    push(MethodLevel::new(m, l), o);
                }
            }
        }
    }
    // What MC dropout buys: each method against its own single pass.
    for &m in &inp.methods {
        let Some(one) = m.single_pass_variant().filter(|v| inp.methods.contains(v)) else {
            continue;
        };
        for &l in &inp.levels {
            push(MethodLevel::new(m, l), one);
        }
    }
    let with_seeds = rows.iter().any(|r| r.seeds > 1);
    let columns = Columns::of(&rows)
        .method_level(|r| r.key)
        .text("inputs", |r| r.key.method.inputs().as_str().to_owned())
        .text("reference", |r| r.reference.as_str().to_owned())
        .count("n_runs", |r| r.d.n)
        .number("f1_difference", |r| r.d.mean)
        .number("f1_difference_lo95", |r| r.d.lo)
        .number("f1_difference_hi95", |r| r.d.hi)
        .text("verdict", |r| {
            match r.d.sign() {
                Some(true) => "better",
                Some(false) => "worse",
                None => "no difference",
            }
            .to_owned()
        });
    if !with_seeds {
        return columns.table();
    }
    columns
        .count("n_training_seeds", |r| r.seeds)
        .count("seeds_better", |r| r.verdicts.0)
        .count("seeds_worse", |r| r.verdicts.1)
        .table()
}
