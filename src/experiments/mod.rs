//! Multi-run work built on the pipeline: collecting labelled training pairs
//! from the training runs, training a deep method, and evaluating every
//! method on one test run for the paper's tables. Every instance goes
//! through [`evaluate::evaluate`]; the training labels are the oracle's
//! pairs. No file IO here beyond what `pipeline` reads.

mod baselines;
mod choices;

use std::path::Path;

pub use self::baselines::{TunedBaseline, tune_baselines};
pub use self::choices::{Chosen, validate};

use crate::config::{DatasetSource, Settings};
use crate::dataset::Dataset;
use crate::dataset::read::RunInfo;
use crate::evaluate::{self, CorrespondenceSource, ExternalMatches};
use crate::fusion::FusionSettings;
use crate::matching::deep::train::{self, Example, TrainOptions, TrainProgress, TrainReport};
use crate::matching::{Method, MethodKind, MethodLambdas};
use crate::pipeline::{self, Progress, RunError, Warnings};
use crate::sensor::reid::ReidCalibration;
use crate::tables::{RunEval, lambda_grid};

/// The settings of run `seed` ([`Settings::for_seed`]).
pub fn settings_for_seed(settings: &Settings, seed: u64) -> Settings {
    settings.for_seed(seed)
}

/// `settings` reading their instances from the dataset in `dir` instead
/// of simulating them: its pose-noise levels replace the config's (each
/// with the accuracy of its first row), its splits make the runs.
pub fn with_dataset(settings: &Settings, dir: &Path) -> Result<Settings, RunError> {
    let d = Dataset::open(dir).map_err(|e| RunError::Dataset {
        dir: dir.display().to_string(),
        why: e.to_string(),
    })?;
    // The records and reports name the runs by their seeds.
    let seeds = |split: &str| -> Vec<u64> {
        d.runs
            .iter()
            .filter(|r| r.split == split)
            .map(|r| r.seed)
            .collect()
    };
    let descriptor_law = descriptor_law(&d).map_err(|e| RunError::Dataset {
        dir: dir.display().to_string(),
        why: e.to_string(),
    })?;
    let source = DatasetSource {
        dir: dir.to_owned(),
        split: None,
        run: None,
        descriptor_law,
        appearance_width: d.appearance_width,
    };
    Ok(settings.reading_dataset(
        [seeds("train"), seeds("validation"), seeds("test")],
        d.levels.clone(),
        source,
    ))
}

/// What the dataset's appearance vectors say
/// ([`crate::matching::descriptor::fit_law`]), fitted on every pair of
/// nodes of the two vehicles of its validation runs' instances (never its
/// test runs); `None` without vectors or validation runs.
fn descriptor_law(
    d: &Dataset,
) -> Result<Option<crate::sensor::DescriptorLaw>, crate::dataset::read::DatasetError> {
    if d.appearance_width.is_none() {
        return Ok(None);
    }
    let mut pairs = Vec::new();
    for (k, _) in d
        .runs
        .iter()
        .enumerate()
        .filter(|(_, r)| r.split == "validation")
    {
        for inst in d.run(k)?.instances {
            let [a, b] = &inst.sides;
            for x in &a.nodes {
                for y in &b.nodes {
                    let described = |a: &Option<std::sync::Arc<[f32]>>| {
                        a.clone().filter(|v| v.iter().any(|x| *x != 0.0))
                    };
                    if let (Some(u), Some(v)) = (described(&x.appearance), described(&y.appearance))
                    {
                        let same = !x.object_id.is_empty() && x.object_id == y.object_id;
                        pairs.push((crate::sensor::cosine(&u, &v), same));
                    }
                }
            }
        }
    }
    Ok(crate::matching::descriptor::fit_law(&pairs))
}

/// Calibrates `[appearance] descriptor = "reid"` on the validation runs
/// ([`validation_runs`]; never a test run): their views' sightings
/// ([`pipeline::sighting_pairs`]), the noise that meets the target
/// ([`crate::sensor::reid::calibrate`]) and what the cosine says there
/// ([`crate::matching::descriptor::fit_law`], on every pair of the same
/// views). `None` without the descriptor, when it is calibrated already,
/// or with a dataset (which brings its own vectors); the runs that use it
/// take [`Settings::with_descriptor_calibration`]. `on_run(done, total)`
/// follows the runs.
pub fn calibrate_appearance(
    settings: &Settings,
    mut on_run: impl FnMut(usize, usize),
) -> Result<Option<ReidCalibration>, RunError> {
    let Some(reid) = &settings.appearance.reid else {
        return Ok(None);
    };
    if !settings.appearance.uncalibrated() || settings.dataset.is_some() {
        return Ok(None);
    }
    let runs = validation_runs(settings)?;
    let mut pairs = Vec::new();
    on_run(0, runs.len());
    for (k, run) in runs.iter().enumerate() {
        pairs.extend(pipeline::sighting_pairs(run)?.0);
        on_run(k + 1, runs.len());
    }
    let (noise, figures, scored) = crate::sensor::reid::calibrate(&pairs, reid.width, reid.target)
        .map_err(|e| RunError::Calibration(e.to_string()))?;
    let law = crate::matching::descriptor::fit_law(&crate::sensor::reid::labelled_pairs(&scored));
    Ok(Some(ReidCalibration {
        noise,
        law,
        figures,
    }))
}

/// `settings` with the descriptor calibrated ([`calibrate_appearance`]),
/// as they are when there is nothing to calibrate.
pub fn calibrated(
    settings: &Settings,
    on_run: impl FnMut(usize, usize),
) -> Result<Settings, RunError> {
    Ok(match calibrate_appearance(settings, on_run)? {
        Some(c) => settings.with_descriptor_calibration(c),
        None => settings.clone(),
    })
}

/// With a dataset ([`with_dataset`]), each of its runs as `runs.parquet`
/// names it, with its settings (its seed as the traffic and sensor seed:
/// the seed of its deep methods' dropout masks); `None` without one.
pub fn dataset_runs(settings: &Settings) -> Result<Option<Vec<(RunInfo, Settings)>>, RunError> {
    let Some(source) = &settings.dataset else {
        return Ok(None);
    };
    let d = Dataset::open(&source.dir).map_err(|e| RunError::Dataset {
        dir: source.dir.display().to_string(),
        why: e.to_string(),
    })?;
    let runs = d
        .runs
        .into_iter()
        .enumerate()
        .map(|(k, r)| {
            let s = settings.of_dataset_run(r.seed, &r.split, k);
            (r, s)
        })
        .collect();
    Ok(Some(runs))
}

/// [`dataset_runs`] of one split; refused when the dataset has none of
/// that split (a command that needs them would otherwise run on nothing).
fn dataset_split(settings: &Settings, split: &str) -> Result<Option<Vec<Settings>>, RunError> {
    let Some(runs) = dataset_runs(settings)? else {
        return Ok(None);
    };
    let mut splits: Vec<&str> = Vec::new();
    for (r, _) in &runs {
        if !splits.contains(&r.split.as_str()) {
            splits.push(&r.split);
        }
    }
    if !splits.contains(&split) {
        let dir = settings
            .dataset
            .as_ref()
            .map(|d| d.dir.display().to_string());
        return Err(RunError::Dataset {
            dir: dir.unwrap_or_default(),
            why: format!(
                "it has no {split} runs, which this command needs (its runs are {}; coid \
                 convert --splits or coid export chose them)",
                splits.join(", ")
            ),
        });
    }
    Ok(Some(
        runs.into_iter()
            .filter(|(r, _)| r.split == split)
            .map(|(_, s)| s)
            .collect(),
    ))
}

/// The training runs: every training seed of the config's own scenario,
/// then the first `runs_per_scenario` training seeds of each scenario of
/// `[train] scenarios`.
/// Instances at most every `[train] sample_every_s`.
pub fn training_runs(settings: &Settings) -> Result<Vec<Settings>, RunError> {
    if let Some(runs) = dataset_split(settings, "train")? {
        return Ok(runs);
    }
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

fn sampled_for_training(runs: Vec<Settings>) -> Vec<Settings> {
    runs.iter().map(Settings::sampled_for_training).collect()
}

/// The validation runs: every validation seed of the config's own
/// scenario, then the first `runs_per_scenario` validation seeds of each
/// scenario of `[train] validation_scenarios`.
pub fn validation_runs(settings: &Settings) -> Result<Vec<Settings>, RunError> {
    if let Some(runs) = dataset_split(settings, "validation")? {
        return Ok(runs);
    }
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

/// The test runs, as `coid eval` runs them: every test seed of the
/// config's own scenario, then the same seeds of each scenario of `[eval]
/// scenarios`.
pub fn test_runs(settings: &Settings) -> Result<Vec<Settings>, RunError> {
    if let Some(runs) = dataset_split(settings, "test")? {
        return Ok(runs);
    }
    let seeds = &settings.eval.traffic_seeds;
    let mut runs: Vec<Settings> = seeds
        .iter()
        .map(|&s| settings_for_seed(settings, s))
        .collect();
    for path in &settings.eval.scenarios {
        let other = settings.with_scenario_of(path)?;
        runs.extend(seeds.iter().map(|&s| settings_for_seed(&other, s)));
    }
    Ok(runs)
}

/// Labelled pairs from every run of `runs`, at every configured pose-noise
/// level (the same pair under each level's GPS error, so the network learns
/// how far to trust the GPS position prior). `progress(run, runs, examples
/// so far)`.
pub fn collect_examples(
    runs: &[Settings],
    warnings: &Warnings,
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
            warnings,
            |_: Progress| {},
            |inst| {
                for level in &run.pose_noise {
                    let pair = inst.at_level(seed, level, run.v2x.gnss_heading_speed_sigma_mps);
                    let labels =
                        evaluate::evaluate(&pair, &CorrespondenceSource::Oracle, &no_fusion);
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
/// on `validation` when `[train] patience` > 0), from the weights `start`
/// (the bytes of `[train] start_from`'s `.bpk`) or a seeded start;
/// returns its weights (bytes) and loss curve.
pub fn train_method(
    settings: &Settings,
    method: Method,
    (examples, validation): (&[Example], &[Example]),
    start: Option<&[u8]>,
    progress: &mut impl TrainProgress,
) -> Result<(Vec<u8>, TrainReport), String> {
    let t = &settings.train;
    if method.kind() != MethodKind::Deep {
        return Err(format!("'{}' is not a deep method", method.as_str()));
    }
    let opts = TrainOptions {
        epochs: t.epochs,
        learning_rate: t.learning_rate,
        seed: t.seed,
        patience: t.patience,
        loss: t.loss,
        samples: t.mc_samples,
        masks: method.training_masks(t.dropout_masks, t.paper_dropout_masks),
        batch_size: t.batch_size,
        gate_chi2: settings.matching.gate_chi2,
        appearance_width: settings.appearance_width(),
        no_match: t.no_match,
        network: t.network,
        augment: t.augment,
    };
    train::train(method, examples, validation, &opts, start, progress)
}

/// Evaluates `methods` on one test run (`settings` already carries the
/// run's seeds): every instance, every pose-noise level, frame by frame
/// with `[matching] multi_vehicle`; deep methods are
/// also counted at every threshold of the lambda sweep (whose grid holds
/// `lambdas`).
pub fn eval_run(
    settings: &Settings,
    methods: &[Method],
    lambdas: &MethodLambdas,
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
) -> Result<RunEval, RunError> {
    eval_run_with(
        settings, methods, None, lambdas, threads, warnings, progress,
    )
}

/// [`eval_run`] with, when given, one more method: correspondences made
/// elsewhere for this run (`coid score`), last. Refused when they name an
/// instance or node the run does not have.
pub fn eval_run_with(
    settings: &Settings,
    methods: &[Method],
    external: Option<ExternalMatches>,
    lambdas: &MethodLambdas,
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
) -> Result<RunEval, RunError> {
    let mut runners = pipeline::runners(settings, methods)?;
    runners.extend(external.map(CorrespondenceSource::External));
    let into = RunEval::default();
    eval_run_into(
        into,
        settings,
        &runners,
        (lambdas, threads),
        warnings,
        progress,
    )
}

/// [`eval_run`] of `runners`, adding to `out`.
pub(super) fn eval_run_into(
    mut out: RunEval,
    settings: &Settings,
    runners: &[CorrespondenceSource],
    (lambdas, threads): (&MethodLambdas, usize),
    warnings: &Warnings,
    progress: impl FnMut(Progress),
) -> Result<RunEval, RunError> {
    let grid = lambda_grid(lambdas.values());
    let external = runners.iter().find_map(|r| match r {
        CorrespondenceSource::External(e) => Some(e),
        _ => None,
    });
    let stats = pipeline::evaluate_frames(
        settings,
        runners,
        threads,
        warnings,
        progress,
        |_, pairs, level, f| {
            if let (Some(e), Method::External) = (external, f.method) {
                e.check(pairs).map_err(RunError::Matches)?;
            }
            out.record_consistency(f.method, level, f.consistency);
            out.record_views(f.method, level, &f.views);
            for (pair, e) in pairs.iter().zip(&f.pairs) {
                let truths = (pair.first.truth, pair.second.truth);
                out.record(e, level, truths, &grid);
                out.record_candidates(e, level, pair.instance, truths);
            }
            Ok(())
        },
    )?;
    if let Some(e) = external {
        e.check_instances(stats.n_instances)
            .map_err(RunError::Matches)?;
    }
    out.instances = stats.n_instances;
    out.close_common();
    Ok(out)
}
