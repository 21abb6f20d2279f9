//! Multi-run work built on the pipeline: collecting labelled training pairs
//! from the training runs, training a deep method, and evaluating every
//! method on one test run for the paper's tables. Every instance goes
//! through [`evaluate::evaluate`]; the training labels are the oracle's
//! pairs. No file IO here beyond what `pipeline` reads.

use std::collections::BTreeMap;
use std::path::Path;

use crate::config::{DatasetSource, Settings};
use crate::dataset::Dataset;
use crate::dataset::read::RunInfo;
use crate::evaluate::PairCounts;
use crate::evaluate::{self, CorrespondenceSource, ExternalMatches};
use crate::fusion::FusionSettings;
use crate::matching::deep::decision::{
    Decision, KindLambdas, UncertaintyKind, calibrated, pair_uncertainty,
};
use crate::matching::deep::train::{self, Example, TrainOptions, TrainProgress, TrainReport};
use crate::matching::{
    BaselineValue, DESCRIPTOR_WEIGHTS, DecisionChoice, LambdaChoice, Method, MethodKind,
    MethodLambdas,
};
use crate::pipeline::{self, Progress, RunError, Warnings};
use crate::sensor::PoseNoiseLabel;
use crate::tables::{DecidedPair, MethodLevel, RuleKey, RunEval, lambda_grid};

/// The settings of run `seed`: traffic and sensor seeds both set to it.
pub fn settings_for_seed(settings: &Settings, seed: u64) -> Settings {
    let mut s = settings.clone();
    s.seeds.traffic = seed;
    s.seeds.sensor = seed;
    s
}

/// `settings` reading their instances from the dataset in `dir` instead
/// of simulating them: its pose-noise levels replace the config's (each
/// with the accuracy of its first row), its splits make the runs.
pub fn with_dataset(settings: &Settings, dir: &Path) -> Result<Settings, RunError> {
    let d = Dataset::open(dir).map_err(|e| RunError::Dataset {
        dir: dir.display().to_string(),
        why: e.to_string(),
    })?;
    let mut s = settings.clone();
    // The records and reports name the runs by their seeds.
    let seeds = |split: &str| -> Vec<u64> {
        d.runs
            .iter()
            .filter(|r| r.split == split)
            .map(|r| r.seed)
            .collect()
    };
    s.train.traffic_seeds = seeds("train");
    s.train.validation_seeds = seeds("validation");
    s.eval.traffic_seeds = seeds("test");
    let descriptor_law = descriptor_law(&d).map_err(|e| RunError::Dataset {
        dir: dir.display().to_string(),
        why: e.to_string(),
    })?;
    s.pose_noise = d.levels;
    s.dataset = Some(DatasetSource {
        dir: dir.to_owned(),
        split: None,
        run: None,
        descriptor_law,
        appearance_width: d.appearance_width,
    });
    Ok(s)
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
/// views). Nothing to do without the descriptor, when it is calibrated
/// already, or with a dataset (which brings its own vectors).
/// `on_run(done, total)` follows the runs.
pub fn calibrate_appearance(
    settings: &mut Settings,
    mut on_run: impl FnMut(usize, usize),
) -> Result<(), RunError> {
    if !settings.appearance.uncalibrated() || settings.dataset.is_some() {
        return Ok(());
    }
    let runs = validation_runs(settings)?;
    let mut pairs = Vec::new();
    on_run(0, runs.len());
    for (k, run) in runs.iter().enumerate() {
        pairs.extend(pipeline::sighting_pairs(run)?.0);
        on_run(k + 1, runs.len());
    }
    let Some(reid) = settings.appearance.reid.as_mut() else {
        return Ok(());
    };
    let (noise, figures, scored) = crate::sensor::reid::calibrate(&pairs, reid.width, reid.target)
        .map_err(|e| RunError::Calibration(e.to_string()))?;
    let law = crate::matching::descriptor::fit_law(&crate::sensor::reid::labelled_pairs(&scored));
    reid.calibration = Some(crate::sensor::reid::ReidCalibration {
        noise,
        law,
        figures,
    });
    Ok(())
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
            let mut s = settings_for_seed(settings, r.seed);
            s.dataset = Some(DatasetSource {
                split: Some(r.split.clone()),
                run: Some(k),
                ..source.clone()
            });
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
    let MethodKind::Deep(deep) = method.kind() else {
        return Err(format!("'{}' is not a deep method", method.as_str()));
    };
    let opts = TrainOptions {
        epochs: t.epochs,
        learning_rate: t.learning_rate,
        seed: t.seed,
        patience: t.patience,
        loss: t.loss,
        samples: t.mc_samples,
        masks: deep.training_masks(t.dropout_masks, t.paper_dropout_masks),
        batch_size: t.batch_size,
        gate_chi2: settings.matching.gate_chi2,
        appearance_width: settings.appearance_width(),
        no_match: t.no_match,
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
fn eval_run_into(
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

/// What the validation runs say about one deep method: the calibration
/// temperature, decision rule and lambda (infinite: no threshold) with
/// the best mean F1 (over the runs, of the mean over pose-noise levels),
/// and that F1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chosen {
    pub temperature: f64,
    /// On the configured uncertainty type.
    pub lambda: f64,
    /// Each uncertainty type's, with the same decision rule.
    pub lambdas: KindLambdas,
    pub decision: Decision,
    /// The operating point chosen with the rule: the least E[Y] of a
    /// decided pair.
    pub min_probability: f64,
    pub f1: f64,
}

/// The operating points validation tries for a deep method's rule (the
/// least E[Y] of a decided pair): the grid of MOGM's `min_score`, 0 (every
/// pair the rule chooses) first.
pub const MIN_PROBABILITIES: [f64; 10] = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// The temperature whose calibrated probabilities have the lowest log
/// loss on `pairs` (the decided pairs of one method and rule), fitted
/// continuously within [`TEMPERATURE_RANGE`]: the log loss is convex in
/// 1/t (a logistic regression on the logit with one weight), so a golden
/// section over ln t finds its minimum. At the range's top the decided
/// pairs are mostly wrong and no temperature calibrates them
/// ([`crate::matching::deep::decision::temperature_at_bound`]).
fn fit_temperature<'a>(pairs: impl Iterator<Item = &'a DecidedPair> + Clone) -> f64 {
    let log_loss = |ln_t: f64| -> f64 {
        let t = ln_t.exp();
        pairs
            .clone()
            .map(|d| {
                let q = calibrated(f64::from(d.p), t).clamp(1e-12, 1.0 - 1e-12);
                -(if d.correct { q } else { 1.0 - q }).ln()
            })
            .sum()
    };
    let range = crate::matching::deep::decision::TEMPERATURE_RANGE;
    let (mut a, mut b) = (range.0.ln(), range.1.ln());
    let phi = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - phi * (b - a), a + phi * (b - a));
    let (mut fc, mut fd) = (log_loss(c), log_loss(d));
    while b - a > 1e-6 {
        if fc <= fd {
            (b, d, fd) = (d, c, fc);
            c = b - phi * (b - a);
            fc = log_loss(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + phi * (b - a);
            fd = log_loss(d);
        }
    }
    // Nothing to calibrate (no pairs, or a flat loss): 1.
    let t = ((a + b) / 2.0).exp();
    if log_loss(t.ln()) < log_loss(0.0) {
        t
    } else {
        1.0
    }
}

/// Chooses each deep method's calibration temperature, decision rule,
/// operating point and lambda on the validation runs (`[train]
/// validation_seeds` and scenarios, or a dataset's validation runs),
/// never on the test runs: the rule (assignment, mutual best with the
/// dustbins, mutual best of the real nodes), the least E[Y] of a decided
/// pair ([`MIN_PROBABILITIES`]) and the threshold (the grid 0..1 by 0.05
/// and no threshold, on the configured uncertainty type) with the best
/// mean F1, ties going to the rule listed first, then to the smaller
/// operating point and lambda; then with that rule and operating point
/// each uncertainty type's own threshold, the same way; and the
/// temperature with the lowest log loss of the decided pairs (it
/// calibrates the reported probabilities and changes no decision).
/// `progress(run, runs)` after each run.
pub fn validate(
    settings: &Settings,
    methods: &[Method],
    threads: usize,
    warnings: &Warnings,
    mut progress: impl FnMut(usize, usize),
) -> Result<BTreeMap<Method, Chosen>, RunError> {
    // The default decision is not used: every rule and threshold is counted.
    let mut s = settings.clone();
    s.matching.lambda = LambdaChoice::Fixed(f64::INFINITY);
    s.matching.decision = DecisionChoice::Fixed(Decision::Assignment);
    let validation = validation_runs(&s)?;
    let mut runs = Vec::new();
    for (k, run) in validation.iter().enumerate() {
        let kept = RunEval::keeping_pairs();
        let no_lambdas = BTreeMap::new();
        runs.push(eval_run_into(
            kept,
            run,
            &pipeline::runners(run, methods)?,
            (&no_lambdas, threads),
            warnings,
            |_| {},
        )?);
        progress(k + 1, validation.len());
    }
    let levels: Vec<_> = settings.pose_noise.iter().map(|l| l.label).collect();
    let kind = settings.matching.uncertainty;
    Ok(methods
        .iter()
        .filter(|m| matches!(m.kind(), MethodKind::Deep(_)))
        .map(|&m| (m, choose(&runs, &levels, kind, m)))
        .collect())
}

/// A run's decided pairs of `key` (none when it kept none).
fn decided(r: &RunEval, key: RuleKey) -> &[DecidedPair] {
    r.decided
        .as_ref()
        .and_then(|d| d.get(&key))
        .map_or(&[][..], Vec::as_slice)
}

/// The mean F1 over the validation runs (of the mean over the levels) of
/// method `m` deciding by `decision`, thresholded at `lambda` on the
/// uncertainty `kind`; a run (or level) without pairs to find or found has
/// none.
fn validation_f1(
    runs: &[RunEval],
    levels: &[PoseNoiseLabel],
    m: Method,
    (decision, min_probability): (Decision, f64),
    (kind, lambda): (UncertaintyKind, f64),
) -> f64 {
    let min_p = min_probability as f32;
    let f1_of_run = |r: &RunEval| {
        let f: Vec<f64> = levels
            .iter()
            .filter_map(|&l| {
                let rule = MethodLevel::new(m, l).rule(decision);
                let truth = r.unthresholded.get(&rule)?.ground_truth;
                let kept = decided(r, rule).iter().filter(|d| {
                    let (p, a) = (f64::from(d.p), f64::from(d.aleatoric));
                    d.p >= min_p && pair_uncertainty(p, a, kind) < lambda
                });
                let counts = PairCounts {
                    identified: kept.clone().count(),
                    correct: kept.filter(|d| d.correct).count(),
                    ground_truth: truth,
                };
                Some(counts.f1()).filter(|f| f.is_finite())
            })
            .collect();
        (!f.is_empty()).then(|| f.iter().sum::<f64>() / f.len() as f64)
    };
    let per_run: Vec<f64> = runs.iter().filter_map(f1_of_run).collect();
    per_run.iter().sum::<f64>() / per_run.len().max(1) as f64
}

/// The lambda of the grid (or none) with the best [`validation_f1`], the
/// smaller one on ties, and that F1.
fn best_lambda(f1_at: impl Fn(f64) -> f64) -> (f64, f64) {
    let mut best = (f64::INFINITY, f64::NEG_INFINITY);
    for &lambda in &lambda_grid([]) {
        let f1 = f1_at(lambda);
        if f1 > best.1 {
            best = (lambda, f1);
        }
    }
    best
}

/// The temperature, rule, operating point and lambda of [`validate`] for
/// one method: the rule, operating point and lambda on the configured
/// uncertainty `kind`, then, with that rule and operating point, each
/// uncertainty type's own lambda.
fn choose(runs: &[RunEval], levels: &[PoseNoiseLabel], kind: UncertaintyKind, m: Method) -> Chosen {
    let mut best = Chosen {
        temperature: 1.0,
        lambda: f64::INFINITY,
        lambdas: KindLambdas::all(f64::INFINITY),
        decision: Decision::Assignment,
        min_probability: 0.0,
        f1: f64::NEG_INFINITY,
    };
    for decision in [Decision::Assignment, Decision::Mutual, Decision::MutualReal] {
        for min_probability in MIN_PROBABILITIES {
            let rule = (decision, min_probability);
            let (lambda, f1) =
                best_lambda(|lambda| validation_f1(runs, levels, m, rule, (kind, lambda)));
            if f1 > best.f1 {
                best = Chosen {
                    lambda,
                    decision,
                    min_probability,
                    f1,
                    ..best
                };
            }
        }
    }
    let min_p = best.min_probability as f32;
    let all = runs.iter().flat_map(|r| {
        levels.iter().flat_map(move |&l| {
            decided(r, MethodLevel::new(m, l).rule(best.decision))
                .iter()
                .filter(move |d| d.p >= min_p)
        })
    });
    best.temperature = fit_temperature(all);
    let rule = (best.decision, best.min_probability);
    best.lambdas = KindLambdas::from_fn(|k| {
        best_lambda(|lambda| validation_f1(runs, levels, m, rule, (k, lambda))).0
    });
    best
}

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
    let mut none = settings.matching.clone();
    none.baseline_values.clear();
    none.baseline_value(m)
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
        .map_or(settings.appearance.descriptor_width() > 0, |d| {
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
    for run in validation {
        let mut s = run.clone();
        s.matching.baselines = crate::matching::BaselineChoice::APriori;
        s.matching.baseline_values = values.clone();
        let runners = pipeline::runners(&s, &methods)?;
        let no_lambdas = BTreeMap::new();
        evals.push(eval_run_into(
            RunEval::default(),
            &s,
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

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(p: f32, right: usize, wrong: usize) -> Vec<DecidedPair> {
        let pair = |correct| DecidedPair {
            p,
            aleatoric: 0.0,
            correct,
        };
        (0..right)
            .map(|_| pair(true))
            .chain((0..wrong).map(|_| pair(false)))
            .collect()
    }

    /// Pairs at E[Y] = 0.9 that are right 9 times in 10 keep their
    /// probability (temperature 1); right 3 times in 4, they are
    /// overconfident and the fit cools them to about 0.75 (ln 9 / ln 3 =
    /// 2); right 99 times in 100, underconfident (below 1).
    #[test]
    fn the_temperature_fit_calibrates_the_decided_pairs() {
        let fit = |right, wrong| fit_temperature(pairs(0.9, right, wrong).iter());
        assert!((fit(90, 10) - 1.0).abs() < 0.02, "{}", fit(90, 10));
        let hot = fit(75, 25);
        assert!((hot - 2.0).abs() < 0.05, "{hot}");
        assert!((calibrated(0.9, hot) - 0.75).abs() < 0.01);
        assert!(fit(99, 1) < 0.7);
    }

    /// Validation chooses the operating point with the rule: when the
    /// dustbins keep a method from deciding pairs that are mostly right
    /// (E[Y] 0.3 here) and the real block's mutual best holds them with
    /// wrong ones at lower E[Y] (0.15), the mutual best of the real nodes
    /// with the least operating point that drops the wrong ones wins; no
    /// entropy threshold can (both lie on the same side of 1/2).
    #[test]
    fn validation_chooses_the_operating_point_with_the_rule() {
        let at = MethodLevel::new(Method::Coid, PoseNoiseLabel::Gps);
        let mut run = RunEval::keeping_pairs();
        let confident = pairs(0.8, 10, 0);
        let mut real = confident.clone();
        real.extend(pairs(0.3, 5, 0));
        real.extend(pairs(0.15, 0, 10));
        let decided = run.decided.as_mut().unwrap();
        for (rule, kept) in [
            (Decision::Assignment, &confident),
            (Decision::Mutual, &confident),
            (Decision::MutualReal, &real),
        ] {
            decided.insert(at.rule(rule), kept.clone());
            let truth = PairCounts {
                ground_truth: 20,
                ..PairCounts::default()
            };
            run.unthresholded.insert(at.rule(rule), truth);
        }
        let c = choose(
            &[run],
            &[PoseNoiseLabel::Gps],
            UncertaintyKind::Total,
            Method::Coid,
        );
        assert_eq!(c.decision, Decision::MutualReal);
        assert_eq!(c.min_probability, 0.2);
        assert!((c.f1 - 2.0 * 0.75 / 1.75).abs() < 1e-9, "{}", c.f1);
    }
}
