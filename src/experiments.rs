//! Multi-run work built on the pipeline: collecting labelled training pairs
//! from the training runs, training a deep method, and evaluating every
//! method on one test run for the paper's tables. Every instance goes
//! through [`evaluate::evaluate`]; the training labels are the oracle's
//! pairs. No file IO here beyond what `pipeline` reads.

use std::collections::BTreeMap;

use crate::config::Settings;
use crate::evaluate::{self, Runner};
use crate::fusion::FusionSettings;
use crate::matching::deep::decision::Decision;
use crate::matching::deep::train::{self, Example, TrainOptions, TrainProgress, TrainReport};
use crate::matching::{DecisionChoice, LambdaChoice, Method};
use crate::pipeline::{self, Progress, RunError};
use crate::tables::{RunEval, lambda_grid};

/// The settings of run `seed`: traffic and sensor seeds both set to it.
pub fn settings_for_seed(settings: &Settings, seed: u64) -> Settings {
    let mut s = settings.clone();
    s.seeds.traffic = seed;
    s.seeds.sensor = seed;
    s
}

/// The training runs: every training seed of the config's own scenario,
/// then the first `runs_per_scenario` training seeds of each scenario of
/// `[train] scenarios`.
/// Instances at most every `[train] sample_every_s`.
pub fn training_runs(settings: &Settings) -> Result<Vec<Settings>, RunError> {
    let t = &settings.train;
    Ok(sampled_for_training(runs_of(
        settings,
        &t.traffic_seeds,
        &t.scenarios,
    )?))
}

/// The validation runs as the training loss sees them (early stopping):
/// instances at most every `[train] sample_every_s`, like training runs.
pub fn validation_loss_runs(settings: &Settings) -> Result<Vec<Settings>, RunError> {
    Ok(sampled_for_training(validation_runs(settings)?))
}

fn sampled_for_training(mut runs: Vec<Settings>) -> Vec<Settings> {
    for r in &mut runs {
        r.scenario.sample_every_s = r.scenario.sample_every_s.max(r.train.sample_every_s);
    }
    runs
}

/// The validation runs: every validation seed of the config's own
/// scenario, then the first `runs_per_scenario` validation seeds of each
/// scenario of `[train] validation_scenarios`.
pub fn validation_runs(settings: &Settings) -> Result<Vec<Settings>, RunError> {
    let t = &settings.train;
    runs_of(settings, &t.validation_seeds, &t.validation_scenarios)
}

fn runs_of(
    settings: &Settings,
    seeds: &[u64],
    scenarios: &[std::path::PathBuf],
) -> Result<Vec<Settings>, RunError> {
    let mut runs: Vec<Settings> = seeds
        .iter()
        .map(|&s| settings_for_seed(settings, s))
        .collect();
    let first = &seeds[..settings.train.runs_per_scenario.min(seeds.len())];
    for path in scenarios {
        let other = settings.with_scenario_of(path)?;
        runs.extend(first.iter().map(|&s| settings_for_seed(&other, s)));
    }
    Ok(runs)
}

/// Labelled pairs from every run of `runs`, at every configured pose-noise
/// level (the same pair under each level's GPS error, so the network learns
/// how far to trust the GPS position prior). `progress(run, runs, examples
/// so far)`.
pub fn collect_examples(
    runs: &[Settings],
    mut progress: impl FnMut(usize, usize, usize),
) -> Result<Vec<Example>, RunError> {
    let mut examples = Vec::new();
    for (k, run) in runs.iter().enumerate() {
        // Labels only: the oracle's pairs, nothing fused.
        let no_fusion = FusionSettings {
            variants: vec![],
            align_min_matches: run.fusion.align_min_matches,
        };
        let seed = run.seeds.sensor;
        pipeline::simulate(
            run,
            |_: Progress| {},
            |inst| {
                for level in &run.pose_noise {
                    let pair = inst.at_level(seed, level);
                    let labels = evaluate::evaluate(&pair, &Runner::Oracle, &no_fusion);
                    let truth = &labels.identification.matches;
                    examples.extend(train::example(&pair.first.view, &pair.second.view, truth));
                }
                Ok(())
            },
        )?;
        progress(k + 1, runs.len(), examples.len());
    }
    Ok(examples)
}

/// Trains one deep method on the collected examples (with early stopping
/// on `validation` when `[train] patience` > 0); returns its weights
/// (bytes) and loss curve.
pub fn train_method(
    settings: &Settings,
    method: Method,
    examples: &[Example],
    validation: &[Example],
    progress: &mut impl TrainProgress,
) -> Result<(Vec<u8>, TrainReport), String> {
    let t = &settings.train;
    let opts = TrainOptions {
        epochs: t.epochs,
        learning_rate: t.learning_rate,
        seed: t.seed,
        patience: t.patience,
        loss: t.loss,
        samples: t.mc_samples,
        batch_size: t.batch_size,
        gate_chi2: settings.matching.gate_chi2,
    };
    train::train(method, examples, validation, &opts, progress)
}

/// Evaluates `methods` on one test run (`settings` already carries the
/// run's seeds): every instance, every pose-noise level, frame by frame
/// with `[matching] multi_vehicle`; deep methods are
/// also counted at every threshold of the lambda sweep (whose grid holds
/// `lambdas`).
pub fn eval_run(
    settings: &Settings,
    methods: &[Method],
    lambdas: &BTreeMap<Method, f64>,
    progress: impl FnMut(Progress),
) -> Result<RunEval, RunError> {
    let runners = pipeline::runners(settings, methods)?;
    let grid = lambda_grid(lambdas.values());
    let mut out = RunEval::default();
    let stats = pipeline::evaluate_frames(settings, &runners, progress, |_, pairs, level, f| {
        out.record_consistency(f.method, level, f.consistency);
        out.record_views(f.method, level, &f.views);
        for (pair, e) in pairs.iter().zip(&f.pairs) {
            out.record(e, level, (pair.first.truth, pair.second.truth), &grid);
        }
    })?;
    out.instances = stats.n_instances;
    Ok(out)
}

/// What the validation runs say about one deep method: the decision rule
/// and lambda (infinite: no threshold) with the best mean F1 (over the
/// runs, of the mean over pose-noise levels), and that F1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chosen {
    pub lambda: f64,
    pub decision: Decision,
    pub f1: f64,
}

/// Chooses each deep method's decision rule and lambda on the validation
/// runs (`[train] validation_seeds` and scenarios), never on the test
/// runs: both rules, the grid 0..1 by 0.05 and no threshold, the
/// configured uncertainty type; ties go to the assignment rule, then to
/// the smaller lambda. `progress(run, runs)` after each run.
pub fn validate(
    settings: &Settings,
    methods: &[Method],
    mut progress: impl FnMut(usize, usize),
) -> Result<BTreeMap<Method, Chosen>, RunError> {
    // The default decision is not used: every rule and threshold is counted.
    let mut s = settings.clone();
    s.matching.lambda = LambdaChoice::Fixed(f64::INFINITY);
    s.matching.decision = DecisionChoice::Fixed(Decision::Assignment);
    let validation = validation_runs(&s)?;
    let mut runs = Vec::new();
    for (k, run) in validation.iter().enumerate() {
        runs.push(eval_run(run, methods, &BTreeMap::new(), |_| {})?);
        progress(k + 1, validation.len());
    }
    let grid = lambda_grid(&[]);
    let kind = settings.matching.uncertainty;
    let mean_f1 = |m: Method, d: Decision, k: usize| {
        let per_run: Vec<f64> = runs
            .iter()
            .map(|r| {
                let f: Vec<f64> = settings
                    .pose_noise
                    .iter()
                    .filter_map(|l| r.thresholded.get(&(m, l.label, d, kind, k)).map(|c| c.f1()))
                    .collect();
                f.iter().sum::<f64>() / f.len().max(1) as f64
            })
            .collect();
        per_run.iter().sum::<f64>() / per_run.len().max(1) as f64
    };
    Ok(methods
        .iter()
        .filter(|m| crate::matching::deep::variant(**m).is_some())
        .map(|&m| {
            let mut best = Chosen {
                lambda: grid[0],
                decision: Decision::Assignment,
                f1: f64::NEG_INFINITY,
            };
            for decision in [Decision::Assignment, Decision::Mutual] {
                for (k, &lambda) in grid.iter().enumerate() {
                    let f1 = mean_f1(m, decision, k);
                    if f1 > best.f1 {
                        best = Chosen {
                            lambda,
                            decision,
                            f1,
                        };
                    }
                }
            }
            (m, best)
        })
        .collect())
}
