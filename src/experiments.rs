//! Multi-run work built on the pipeline: collecting labelled training pairs
//! from the training runs, training a deep method, and evaluating every
//! method on one test run for the paper's tables. Every instance goes
//! through [`evaluate::evaluate`]; the training labels are the oracle's
//! pairs. No file IO here beyond what `pipeline` reads.

use crate::config::Settings;
use crate::evaluate::{self, Runner};
use crate::fusion::FusionSettings;
use crate::matching::Method;
use crate::matching::deep::train::{self, Example, TrainOptions, TrainReport};
use crate::pipeline::{self, Progress, RunError};
use crate::tables::{RunEval, lambda_grid};

/// The settings of run `seed`: traffic and sensor seeds both set to it.
pub fn settings_for_seed(settings: &Settings, seed: u64) -> Settings {
    let mut s = settings.clone();
    s.seeds.traffic = seed;
    s.seeds.sensor = seed;
    s
}

/// Labelled pairs from every training run, at every configured pose-noise
/// level (the same pair under each level's GPS error, so the network learns
/// how far to trust the GPS position prior). `progress(run, runs, examples
/// so far)`.
pub fn collect_examples(
    settings: &Settings,
    mut progress: impl FnMut(usize, usize, usize),
) -> Result<Vec<Example>, RunError> {
    let seeds = &settings.train.traffic_seeds;
    // Labels only: the oracle's pairs, nothing fused.
    let no_fusion = FusionSettings {
        variants: vec![],
        align_min_matches: settings.fusion.align_min_matches,
    };
    let mut examples = Vec::new();
    for (k, &seed) in seeds.iter().enumerate() {
        let run = settings_for_seed(settings, seed);
        pipeline::simulate(
            &run,
            |_: Progress| {},
            |inst| {
                for level in &settings.pose_noise {
                    let pair = inst.at_level(seed, level);
                    let labels = evaluate::evaluate(&pair, &Runner::Oracle, &no_fusion);
                    let truth = &labels.identification.matches;
                    examples.extend(train::example(&pair.first.view, &pair.second.view, truth));
                }
                Ok(())
            },
        )?;
        progress(k + 1, seeds.len(), examples.len());
    }
    Ok(examples)
}

/// Trains one deep method on the collected examples; returns its weights
/// (bytes) and loss curve.
pub fn train_method(
    settings: &Settings,
    method: Method,
    examples: &[Example],
    progress: impl FnMut(usize, usize, f32),
) -> Result<(Vec<u8>, TrainReport), String> {
    let opts = TrainOptions {
        epochs: settings.train.epochs,
        learning_rate: settings.train.learning_rate,
        seed: settings.train.seed,
    };
    train::train(method, examples, &opts, progress)
}

/// Evaluates `methods` on one test run (`settings` already carries the
/// run's seeds): every instance, every pose-noise level; deep methods are
/// also counted at every threshold of the lambda sweep.
pub fn eval_run(
    settings: &Settings,
    methods: &[Method],
    progress: impl FnMut(Progress),
) -> Result<RunEval, RunError> {
    let runners = pipeline::runners(settings, methods)?;
    let grid = lambda_grid(settings.matching.lambda);
    let mut out = RunEval::default();
    let stats = pipeline::simulate(settings, progress, |inst| {
        for level in &settings.pose_noise {
            let pair = inst.at_level(settings.seeds.sensor, level);
            for runner in &runners {
                let e = evaluate::evaluate(&pair, runner, &settings.fusion);
                out.record(
                    &e,
                    level.label,
                    (pair.first.truth, pair.second.truth),
                    &grid,
                );
            }
        }
        Ok(())
    })?;
    out.instances = stats.n_instances;
    Ok(out)
}
