//! `train`: the deep matchers on the training runs (weights, record and
//! loss curve into the models folder), then each one's temperature,
//! decision rule and lambda and the baselines' thresholds chosen on the
//! validation runs ([`crate::training`] does the work). Several methods
//! train at once in child processes (burn's CPU backend trains on one
//! core), whose progress lines the caller's [`TrainView`] shows.

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::ConfigSource;
use crate::config::{Overrides, Settings};
use crate::experiments;
use crate::matching::{Method, MethodKind};
use crate::pipeline::Warnings;
use crate::training::{self, SeedRun};

/// A training (or a validation of trained weights) to run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrainRequest {
    /// A file, or the defaults (`None`): its child processes read it.
    pub config: Option<PathBuf>,
    /// The models folder [default: `results/<config stem>-models`,
    /// `results/<dataset folder>-models`, or `<models_dir>/rank1-<R>` for
    /// a point of the re-identification sweep].
    pub out: Option<PathBuf>,
    /// Write into a models folder coid wrote that is there.
    pub force: bool,
    /// Only these methods [default: `[train] methods`, and the baselines
    /// of `[matching] methods` to tune].
    pub methods: Vec<Method>,
    /// Child processes [default: every core].
    pub workers: Option<usize>,
    /// Choose no temperature, rule, lambda or threshold.
    pub skip_validation: bool,
    /// Train nothing: choose them for the weights in the models folder.
    pub validate_only: bool,
    /// Train with these seeds instead of `[train] seed`.
    pub seeds: Vec<u64>,
    /// Train and validate on a dataset's runs.
    pub dataset: Option<PathBuf>,
    /// Train at this rank-1 of the re-identification descriptor.
    pub reid_rank1: Option<f64>,
    /// Train the networks without the descriptor.
    pub without_descriptor: bool,
}

/// What a training wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainReport {
    /// The models folder.
    pub folder: PathBuf,
    /// What was trained, in one line (where the models are, how long it
    /// took); none for a validation only.
    pub line: Option<String>,
}

/// How a training shows what it does: the training's own progress
/// ([`training::Report`]), lines for the user, the passes over the
/// validation runs, and the lines of its child processes.
pub trait TrainView: training::Report {
    /// A line for the user.
    fn note(&mut self, text: &str);
    /// `done` of `total` validation runs through while a temperature,
    /// rule and lambda are chosen.
    fn validating(&mut self, done: usize, total: usize);
    /// `done` of `total` values of the baselines' grids run.
    fn tuning(&mut self, done: usize, total: usize);
    /// The validation or tuning pass ended.
    fn passed(&mut self);
    /// `n` child processes train, each with its own progress.
    fn children(&mut self, n: usize);
    /// Child `k` printed `line` (a [`training::ChildMessage`]).
    fn child_line(&mut self, k: usize, line: &str);
    /// Child `k` ended.
    fn child_done(&mut self, k: usize);
}

/// Trains (or only validates) the methods of `request` and writes the
/// models folder.
///
/// # Errors
/// A bad option (a seed or method named twice, a variant or a baseline
/// to train, a rank-1 that is no rate), the configuration, the dataset,
/// the models folder, a run or a child process fails.
pub fn train(request: &TrainRequest, view: &mut impl TrainView) -> anyhow::Result<TrainReport> {
    let config = ConfigSource::from(request.config.clone());
    let path = config.path();
    let mut settings = loaded(request, &config)?;
    settings = experiments::calibrated(&settings, |_, _| {})?;
    let models_dir = match &request.dataset {
        Some(d) => {
            settings = experiments::with_dataset(&settings, d)?;
            super::dataset_out_dir(request.out.clone(), d, "-models")
        }
        None => match (request.reid_rank1, &request.out) {
            (Some(r), None) => {
                super::reid_sweep::point_models_dir(&settings.matching.models_dir, r)
            }
            _ => super::out_dir(request.out.clone(), &config, "-models"),
        },
    };
    training::check_models_folder(&models_dir, request.validate_only, request.force)?;
    if let Some(s) = super::first_repeat(&request.seeds) {
        anyhow::bail!("--seed lists {s} twice");
    }
    let checks = (request.validate_only, request.force);
    let source = source(request, &path, request.without_descriptor);
    let seeds = training::seed_runs(source, &settings, &request.seeds, &models_dir, checks)?;
    // The baselines have no training seed: tuned with [train] seed's run.
    let tunes_baselines = seeds.iter().any(|s| s.dir == models_dir);
    let (methods, baselines) = methods_of(request, &settings)?;
    let started = std::time::Instant::now();
    let warnings = Warnings::default();
    let baselines: &[Method] = if tunes_baselines { &baselines } else { &[] };
    let pass = Pass {
        request,
        config: &path,
        methods: &methods,
        warnings: &warnings,
    };
    if request.validate_only {
        for s in &seeds {
            validate(&pass, s, view)?;
        }
        tune_baselines(&pass, (&settings, &models_dir), baselines, view)?;
        return Ok(TrainReport {
            folder: models_dir,
            line: None,
        });
    }
    // A simulated descriptor the networks may read: validation decides
    // whether they do.
    let chooses = settings.dataset.is_none()
        && !settings.appearance_width().is_none()
        && !request.skip_validation
        && !methods.is_empty();
    if chooses {
        choose_descriptor(&pass, &models_dir, &seeds, view)?;
    } else {
        pass.train(&models_dir, &seeds, request.without_descriptor, view)?;
        if !request.skip_validation {
            for s in &seeds {
                validate(&pass, s, view)?;
            }
        }
    }
    if !request.skip_validation {
        tune_baselines(&pass, (&settings, &models_dir), baselines, view)?;
    }
    let line = format!(
        "coid: training took {:.1} min in all; models in {}",
        started.elapsed().as_secs_f64() / 60.0,
        written(&models_dir, &seeds, settings.train.seed)
    );
    Ok(TrainReport {
        folder: models_dir,
        line: Some(line),
    })
}

impl From<Option<PathBuf>> for ConfigSource {
    fn from(config: Option<PathBuf>) -> Self {
        config.map_or(ConfigSource::Defaults, ConfigSource::File)
    }
}

/// The configuration of `request` with its rank-1 and descriptor choice
/// set over it, refused when it asks for a rank-1 without a descriptor.
fn loaded(request: &TrainRequest, config: &ConfigSource) -> anyhow::Result<Settings> {
    if let Some(r) = request.reid_rank1
        && !(r > 0.0 && r < 1.0)
    {
        anyhow::bail!("--reid-rank1 must be a rate in (0, 1), got {r}");
    }
    super::parallel("workers", request.workers)?;
    let overrides = Overrides {
        reid_rank1: request.reid_rank1,
        appearance_vectors: request.without_descriptor.then_some(false),
        ..Default::default()
    };
    let settings = config.load(&overrides)?;
    if request.reid_rank1.is_some() && settings.appearance.reid.is_none() {
        anyhow::bail!(
            "--reid-rank1 sets the re-identification descriptor's rank-1: {} sets \
             [appearance] descriptor = \"none\"",
            config.shown()
        );
    }
    Ok(settings)
}

/// What the training reads ([`training::TrainSource`]), with or
/// `without` the descriptor.
fn source<'a>(
    request: &'a TrainRequest,
    config: &'a Path,
    without: bool,
) -> training::TrainSource<'a> {
    training::TrainSource {
        config,
        dataset: request.dataset.as_deref(),
        reid_rank1: request.reid_rank1,
        without_descriptor: without,
    }
}

/// The weights `[train] start_from` names for each of `methods`, read
/// before any run is simulated.
fn check_start(settings: &Settings, methods: &[Method]) -> anyhow::Result<()> {
    if let Some(dir) = &settings.train.start_from {
        for &m in methods {
            crate::io::read_weights(dir, m)
                .map_err(|e| anyhow::anyhow!("[train] start_from: {e}"))?;
        }
    }
    Ok(())
}

/// The deep methods to train (or validate) and the baselines to tune:
/// `methods` split by kind, else `[train] methods` and the baselines of
/// `[matching] methods`; refused when `methods` names a method twice, a
/// variant, or a baseline to train, or when the weights training is to
/// start from are missing.
fn methods_of(
    request: &TrainRequest,
    settings: &Settings,
) -> anyhow::Result<(Vec<Method>, Vec<Method>)> {
    let asked = &request.methods;
    super::no_repeats("--methods", asked)?;
    if let Some(m) = asked.iter().find(|m| m.is_variant()) {
        anyhow::bail!(
            "'{}' runs the weights of '{}': train or validate '{}'",
            m.as_str(),
            m.weights_owner().as_str(),
            m.weights_owner().as_str()
        );
    }
    let (methods, baselines) = if asked.is_empty() {
        let tuned = settings.matching.methods.iter();
        let tuned = tuned.filter(|m| m.baseline_knob().is_some());
        (settings.train.methods.clone(), tuned.copied().collect())
    } else {
        let (deep, other): (Vec<Method>, Vec<Method>) = asked
            .iter()
            .partition(|m| matches!(m.kind(), MethodKind::Deep));
        (deep, other)
    };
    if let Some(m) = baselines.iter().find(|m| m.baseline_knob().is_none()) {
        anyhow::bail!("'{}' is not a trainable (deep) method", m.as_str());
    }
    if let Some(m) = baselines
        .first()
        .filter(|_| !request.validate_only && !asked.is_empty())
    {
        anyhow::bail!(
            "'{}' is not a trainable (deep) method; `coid train --validate-only --methods {}` \
             chooses its threshold on the validation runs",
            m.as_str(),
            m.as_str()
        );
    }
    if !request.validate_only {
        check_start(settings, &methods)?;
    }
    Ok((methods, baselines))
}

/// Where a training wrote: the models folder, and each seed's folder
/// beside it. Seeds other than [train] seed's go to `seed-<N>/`; a user
/// who trained only such a seed would otherwise look for it at the root.
fn written(models_dir: &Path, seeds: &[SeedRun], own: u64) -> String {
    let elsewhere: Vec<String> = seeds
        .iter()
        .filter(|s| s.dir != models_dir)
        .map(|s| format!("seed {}'s in {}", s.settings.train.seed, s.dir.display()))
        .collect();
    let at_root = seeds.iter().any(|s| s.dir == models_dir);
    let dir = models_dir.display();
    match (elsewhere.is_empty(), at_root) {
        (true, _) => dir.to_string(),
        (false, true) => format!("{dir} ({})", elsewhere.join(", ")),
        (false, false) => format!(
            "{dir} ({}; its root holds [train] seed {own}'s, which `coid eval` reads first)",
            elsewhere.join(", ")
        ),
    }
}

/// One training pass: the request, its configuration file, the deep
/// methods, where the runs' warnings go.
struct Pass<'a> {
    request: &'a TrainRequest,
    config: &'a Path,
    methods: &'a [Method],
    warnings: &'a Warnings,
}

impl Pass<'_> {
    /// Trains the methods with every seed of `seeds` into their folders
    /// (with or `without` the descriptor), in child processes when there
    /// are workers for more than one job.
    fn train(
        &self,
        models_dir: &Path,
        seeds: &[SeedRun],
        without: bool,
        view: &mut impl TrainView,
    ) -> anyhow::Result<()> {
        let jobs = self.methods.len() * seeds.len();
        let workers = self
            .request
            .workers
            .unwrap_or_else(super::cores)
            .clamp(1, jobs.max(1));
        if workers > 1 {
            self.train_in_children((models_dir, without), workers, view)
        } else {
            training::train_seeds(seeds, self.methods, self.warnings, view)?;
            Ok(())
        }
    }

    /// Trains the methods with the request's seeds in `workers` child
    /// processes ([`training::child_groups`]).
    fn train_in_children(
        &self,
        (models_dir, without): (&Path, bool),
        workers: usize,
        view: &mut impl TrainView,
    ) -> anyhow::Result<()> {
        let program = crate::batch::Program::this().context("cannot locate the coid executable")?;
        let groups = training::child_groups(self.methods, &self.request.seeds, workers);
        view.children(groups.len());
        let view = std::cell::RefCell::new(view);
        training::train_in_children(
            &program,
            (source(self.request, self.config, without), models_dir),
            &groups,
            workers,
            |child, line| view.borrow_mut().child_line(child, line),
            |child| view.borrow_mut().child_done(child),
        )?;
        Ok(())
    }
}

/// Where the candidate trained with or `without` the descriptor goes.
fn candidate_dir(models_dir: &Path, without: bool) -> PathBuf {
    let name = if without {
        "without-descriptor"
    } else {
        "reading-descriptor"
    };
    models_dir.join("candidates").join(name)
}

/// The runs of `seeds` (whose folders are in `models_dir`) as candidates
/// with or `without` the descriptor: the same settings, already
/// calibrated, each in its folder under [`candidate_dir`] (checked).
fn candidate_runs(
    force: bool,
    (models_dir, seeds): (&Path, &[SeedRun]),
    without: bool,
) -> anyhow::Result<Vec<SeedRun>> {
    seeds
        .iter()
        .map(|s| {
            let within = s.dir.strip_prefix(models_dir).unwrap_or(Path::new(""));
            let dir = candidate_dir(models_dir, without).join(within);
            training::check_models_folder(&dir, false, force)?;
            let settings = s.settings.with_appearance_vectors(!without);
            Ok(SeedRun { settings, dir })
        })
        .collect()
}

/// Trains every method (and seed) once reading the re-identification
/// descriptor and once without, each into its candidate folder
/// ([`candidate_dir`]), validates both, and keeps for each method the one
/// with the higher mean F1 over the seeds on the validation runs (without
/// it on ties: the smaller network), copied into `seeds`' folders with
/// the choice in its record.
fn choose_descriptor(
    pass: &Pass,
    models_dir: &Path,
    seeds: &[SeedRun],
    view: &mut impl TrainView,
) -> anyhow::Result<()> {
    // f1[method][0: reading, 1: without], mean over the seeds.
    let mut f1 = vec![[0.0; 2]; pass.methods.len()];
    for (k, without) in [false, true].into_iter().enumerate() {
        let dir = candidate_dir(models_dir, without);
        let how = if without { "without" } else { "reading" };
        view.note(&format!(
            "coid: training {how} the re-identification descriptor into {}",
            dir.display()
        ));
        let candidates = candidate_runs(pass.request.force, (models_dir, seeds), without)?;
        pass.train(&dir, &candidates, without, view)?;
        for s in &candidates {
            for (i, (_, c)) in validate(pass, s, view)?.iter().enumerate() {
                f1[i][k] += c.f1 / candidates.len() as f64;
            }
        }
    }
    for (i, &method) in pass.methods.iter().enumerate() {
        let [f1_reading, f1_without] = f1[i];
        let choice = crate::io::DescriptorChoice {
            reads: f1_reading > f1_without,
            f1_reading,
            f1_without,
        };
        let from = candidate_dir(models_dir, !choice.reads);
        for s in seeds {
            let within = s.dir.strip_prefix(models_dir).unwrap_or(Path::new(""));
            crate::io::adopt_candidate(&from.join(within), &s.dir, method, choice)?;
        }
        view.note(&format!(
            "coid: {}: {} the descriptor (mean F1 on the validation runs {f1_reading:.3} reading \
             it, {f1_without:.3} without)",
            method.as_str(),
            if choice.reads { "reads" } else { "leaves out" },
        ));
    }
    Ok(())
}

/// Chooses each method's temperature, rule and lambda on the validation
/// runs of `run` and records them beside its weights
/// ([`training::validate`]), saying what was chosen.
fn validate(
    pass: &Pass,
    run: &SeedRun,
    view: &mut impl TrainView,
) -> anyhow::Result<Vec<(Method, experiments::Chosen)>> {
    if pass.methods.is_empty() {
        return Ok(Vec::new());
    }
    view.validating(0, experiments::validation_runs(&run.settings)?.len());
    let threads = (super::cores(), pass.warnings);
    let chosen = training::validate(&run.settings, &run.dir, pass.methods, threads, |d, t| {
        view.validating(d, t);
    })?;
    view.passed();
    for line in chosen_lines(&chosen) {
        view.note(&line);
    }
    Ok(chosen)
}

/// One line per method: what the validation runs chose for it (and a
/// note when its temperature lies at an end of the range fitted).
fn chosen_lines(chosen: &[(Method, experiments::Chosen)]) -> Vec<String> {
    let text = |l: f64| {
        if l.is_finite() {
            format!("{l:.2}")
        } else {
            "none".to_owned()
        }
    };
    let mut lines = Vec::new();
    for (method, c) in chosen {
        let [total, epistemic, aleatoric] = c.lambdas.values();
        lines.push(format!(
            "coid: {}: temperature {:.2}, decision {} at E[Y] >= {:.1}, lambda {} (mean F1 \
             {:.3} on the validation runs; entropy {}, epistemic {}, aleatoric {})",
            method.as_str(),
            c.temperature,
            c.decision.as_str(),
            c.min_probability,
            text(c.lambda),
            c.f1,
            text(total),
            text(epistemic),
            text(aleatoric),
        ));
        if let Some(note) = crate::matching::deep::decision::temperature_at_bound(c.temperature) {
            lines.push(format!("coid: {}: note: {note}", method.as_str()));
        }
    }
    lines
}

/// Chooses the thresholds of `baselines` on the validation runs and
/// records them in the models folder's `baselines.toml`
/// ([`training::tune_baselines`]), saying what was chosen.
fn tune_baselines(
    pass: &Pass,
    (settings, models_dir): (&Settings, &Path),
    baselines: &[Method],
    view: &mut impl TrainView,
) -> anyhow::Result<()> {
    if baselines.is_empty() {
        return Ok(());
    }
    view.tuning(0, 0);
    let threads = (super::cores(), pass.warnings);
    let tuned = training::tune_baselines(settings, models_dir, baselines, threads, |d, t| {
        view.tuning(d, t);
    })?;
    view.passed();
    for t in &tuned {
        let weight = t
            .descriptor_weight
            .map(|w| format!(", descriptor weight {w}"))
            .unwrap_or_default();
        view.note(&format!(
            "coid: {}: {} {}{weight} (mean F1 {:.3} on the validation runs; a priori {}: {:.3})",
            t.method.as_str(),
            t.parameter,
            t.value,
            t.f1,
            t.a_priori,
            t.f1_a_priori
        ));
        if let Some(note) = &t.note {
            view.note(&format!("coid: {}: note: {note}", t.method.as_str()));
        }
    }
    Ok(())
}
