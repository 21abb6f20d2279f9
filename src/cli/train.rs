//! `coid train`: the deep matchers on the training runs; weights, config
//! and loss curve into the models folder, then each one's lambda chosen on
//! the validation runs ([`crate::training`] does the work). Several
//! methods train at once in child `coid train` processes (burn's CPU
//! backend trains on one core), which report their progress to this one as
//! messages on stdout ([`ChildMessage`]: one JSON object a line).

use std::path::Path;

use anyhow::Context;
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{ConfigArg, ForceArg, OutArg, QuietArg, WorkersArg, label_arg, progress_bar};
use crate::config::Settings;
use crate::experiments;
use crate::matching::{Method, MethodKind};
use crate::pipeline::Warnings;
use crate::training::{self, ChildMessage, SeedRun, Trained};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArg,
    #[command(flatten)]
    out: OutArg,
    #[command(flatten)]
    force: ForceArg,
    /// Train only these methods [default: [train] methods].
    #[arg(long, value_delimiter = ',', value_parser = label_arg::<Method>("method"))]
    methods: Vec<Method>,
    #[command(flatten)]
    workers: WorkersArg,
    /// Train only: choose no temperature, decision rule or lambda (a
    /// later `coid train --validate-only`, or numbers in [matching], are
    /// then needed).
    #[arg(long, conflicts_with = "validate_only")]
    skip_validation: bool,
    /// Train nothing: choose the temperature, decision rule and lambda of
    /// the weights already in the models folder on the validation runs,
    /// and record them beside the weights.
    #[arg(long)]
    validate_only: bool,
    /// Train (or validate) with these seeds (weight initialisation,
    /// shuffling, training dropout) instead of [train] seed, one model per
    /// method and seed, from one collection of the training data. [train]
    /// seed's weights go into the models folder, every other seed's into
    /// its `seed-<N>/` folder, where `coid eval` finds them ([eval]
    /// training_seeds): `--seed 7,8,9 --out models`.
    #[arg(long, value_delimiter = ',')]
    seed: Vec<u64>,
    /// Train and validate on a dataset's runs instead of simulating (a
    /// folder that `coid export` or `coid convert` wrote): its train runs
    /// train, its validation runs choose; the config gives the methods and
    /// the training recipe. Models go to results/<dataset folder>-models
    /// by default.
    #[arg(long, value_name = "DIR")]
    dataset: Option<std::path::PathBuf>,
    /// Train at this cross-view rank-1 rate of the re-identification
    /// descriptor ([appearance] rank1, with auroc = "free"): a point of
    /// `coid eval --reid-sweep`, whose models go to
    /// `<models_dir>/rank1-<RANK1>` unless --out says otherwise.
    #[arg(long, value_name = "RANK1")]
    reid_rank1: Option<f64>,
    /// Train the deep networks without the re-identification descriptor
    /// (as [train] appearance_vectors = false). Without this flag, a
    /// config with the descriptor trains each network both ways and keeps,
    /// per method, the one with the higher mean F1 on the validation runs.
    #[arg(long)]
    without_descriptor: bool,
    /// Report progress as lines on stdout (for a parent `coid train`).
    #[arg(long, hide = true)]
    progress_lines: bool,
    #[command(flatten)]
    quiet: QuietArg,
}

/// How a command shows its progress.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Show {
    Bars,
    /// [`ChildMessage`]s on stdout, for a parent process.
    Lines,
    Quiet,
}

impl Show {
    fn note(self, text: &str) {
        match self {
            Show::Lines => send(&ChildMessage::Note {
                text: text.to_owned(),
            }),
            _ => eprintln!("{text}"),
        }
    }
}

/// Prints `message` on stdout, as one line (for a parent `coid train`).
fn send(message: &ChildMessage) {
    match message.line() {
        Ok(line) => println!("{line}"),
        Err(e) => eprintln!("coid: cannot report progress: {e}"),
    }
}

/// What the training reads ([`training::TrainSource`]), with or
/// `without` the descriptor.
fn source<'a>(a: &'a Args, config: &'a Path, without: bool) -> training::TrainSource<'a> {
    training::TrainSource {
        config,
        dataset: a.dataset.as_deref(),
        reid_rank1: a.reid_rank1,
        without_descriptor: without,
    }
}

/// The seeds `--seed` asks for (else `[train] seed`), each with its
/// settings and folder ([`training::seed_runs`]).
fn seed_runs(a: &Args, settings: &Settings, models_dir: &Path) -> anyhow::Result<Vec<SeedRun>> {
    if let Some(s) = crate::commands::first_repeat(&a.seed) {
        anyhow::bail!("--seed lists {s} twice");
    }
    let checks = (a.validate_only, a.force.force);
    let config = a.config.path();
    Ok(training::seed_runs(
        source(a, &config, a.without_descriptor),
        settings,
        &a.seed,
        models_dir,
        checks,
    )?)
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
/// `--methods` split by kind, else `[train] methods` and the baselines of
/// `[matching] methods`; refused when `--methods` names a method twice,
/// a variant, or a baseline to train, or when the weights training is to
/// start from are missing.
fn methods_of(a: &Args, settings: &Settings) -> anyhow::Result<(Vec<Method>, Vec<Method>)> {
    super::no_repeats("--methods", &a.methods)?;
    if let Some(m) = a.methods.iter().find(|m| m.is_variant()) {
        anyhow::bail!(
            "'{}' runs the weights of '{}': train or validate '{}'",
            m.as_str(),
            m.weights_owner().as_str(),
            m.weights_owner().as_str()
        );
    }
    let (methods, baselines) = if a.methods.is_empty() {
        let tuned = settings.matching.methods.iter();
        let tuned = tuned.filter(|m| m.baseline_knob().is_some());
        (settings.train.methods.clone(), tuned.copied().collect())
    } else {
        let (deep, other): (Vec<Method>, Vec<Method>) = a
            .methods
            .iter()
            .partition(|m| matches!(m.kind(), MethodKind::Deep));
        (deep, other)
    };
    if let Some(m) = baselines.iter().find(|m| m.baseline_knob().is_none()) {
        anyhow::bail!("'{}' is not a trainable (deep) method", m.as_str());
    }
    if let Some(m) = baselines
        .first()
        .filter(|_| !a.validate_only && !a.methods.is_empty())
    {
        anyhow::bail!(
            "'{}' is not a trainable (deep) method; `coid train --validate-only --methods {}` \
             chooses its threshold on the validation runs",
            m.as_str(),
            m.as_str()
        );
    }
    if !a.validate_only {
        check_start(settings, &methods)?;
    }
    Ok((methods, baselines))
}

pub fn train(a: Args) -> anyhow::Result<()> {
    let config = a.config.path();
    if let Some(r) = a.reid_rank1 {
        super::rate_arg("--reid-rank1", r)?;
    }
    let overrides = crate::config::Overrides {
        reid_rank1: a.reid_rank1,
        appearance_vectors: a.without_descriptor.then_some(false),
        ..Default::default()
    };
    let mut settings = Settings::load_with(&config, &overrides)?;
    if a.reid_rank1.is_some() && settings.appearance.reid.is_none() {
        anyhow::bail!(
            "--reid-rank1 sets the re-identification descriptor's rank-1: {} sets [appearance] \
             descriptor = \"none\"",
            a.config.shown()
        );
    }
    settings = experiments::calibrated(&settings, |_, _| {})?;
    let models_dir = match &a.dataset {
        Some(d) => {
            settings = experiments::with_dataset(&settings, d)?;
            super::dataset_out_dir(a.out.out.clone(), d, "-models")
        }
        None => match (a.reid_rank1, &a.out.out) {
            (Some(r), None) => {
                super::reid_sweep::point_models_dir(&settings.matching.models_dir, r)
            }
            _ => super::out_dir(a.out.out.clone(), &config, "-models"),
        },
    };
    training::check_models_folder(&models_dir, a.validate_only, a.force.force)?;
    let seeds = seed_runs(&a, &settings, &models_dir)?;
    // The baselines have no training seed: tuned with [train] seed's run.
    let tunes_baselines = seeds.iter().any(|s| s.dir == models_dir);
    let (methods, baselines) = methods_of(&a, &settings)?;
    let show = match (a.progress_lines, a.quiet.quiet) {
        (true, _) => Show::Lines,
        (false, true) => Show::Quiet,
        (false, false) => Show::Bars,
    };
    let started = std::time::Instant::now();
    let warnings = Warnings::default();
    let bars = (show == Show::Bars, &warnings);
    let baselines: &[Method] = if tunes_baselines { &baselines } else { &[] };
    if a.validate_only {
        for s in &seeds {
            validate(&s.settings, &s.dir, &methods, bars)?;
        }
        return tune_baselines(&settings, &models_dir, baselines, bars);
    }
    // A simulated descriptor the networks may read: validation decides
    // whether they do.
    let chooses = settings.dataset.is_none()
        && !settings.appearance_width().is_none()
        && !a.skip_validation
        && !methods.is_empty();
    let pass = Pass {
        a: &a,
        methods: &methods,
        show,
        warnings: &warnings,
    };
    if chooses {
        choose_descriptor(&pass, &models_dir, &seeds)?;
    } else {
        pass.train(&models_dir, &seeds, a.without_descriptor)?;
        if !a.skip_validation {
            for s in &seeds {
                validate(&s.settings, &s.dir, &methods, bars)?;
            }
        }
    }
    if !a.skip_validation {
        tune_baselines(&settings, &models_dir, baselines, bars)?;
    }
    if show != Show::Lines {
        eprintln!(
            "coid: training took {:.1} min in all; models in {}",
            started.elapsed().as_secs_f64() / 60.0,
            written(&models_dir, &seeds, settings.train.seed)
        );
    }
    Ok(())
}

/// Where a `coid train` wrote: the models folder, and each seed's folder
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

/// One training pass of a `coid train`: its arguments, the deep methods,
/// how progress shows, where the runs' warnings go.
struct Pass<'a> {
    a: &'a Args,
    methods: &'a [Method],
    show: Show,
    warnings: &'a Warnings,
}

impl Pass<'_> {
    /// Trains the methods with every seed of `seeds` into their folders
    /// (with or `without` the descriptor), in child processes when there
    /// are workers for more than one job.
    fn train(&self, models_dir: &Path, seeds: &[SeedRun], without: bool) -> anyhow::Result<()> {
        let jobs = self.methods.len() * seeds.len();
        let workers = self.a.workers.get().clamp(1, jobs.max(1));
        if workers > 1 {
            train_in_children(self.a, (models_dir, without), self.methods, workers)
        } else {
            let mut shown = Shown::new(self.show);
            training::train_seeds(seeds, self.methods, self.warnings, &mut shown)?;
            Ok(())
        }
    }
}

/// Where the candidate trained with or `without` the descriptor goes.
fn candidate_dir(models_dir: &Path, without: bool) -> std::path::PathBuf {
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
    a: &Args,
    (models_dir, seeds): (&Path, &[SeedRun]),
    without: bool,
) -> anyhow::Result<Vec<SeedRun>> {
    seeds
        .iter()
        .map(|s| {
            let within = s.dir.strip_prefix(models_dir).unwrap_or(Path::new(""));
            let dir = candidate_dir(models_dir, without).join(within);
            training::check_models_folder(&dir, false, a.force.force)?;
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
fn choose_descriptor(pass: &Pass, models_dir: &Path, seeds: &[SeedRun]) -> anyhow::Result<()> {
    let bars = (pass.show == Show::Bars, pass.warnings);
    // f1[method][0: reading, 1: without], mean over the seeds.
    let mut f1 = vec![[0.0; 2]; pass.methods.len()];
    for (k, without) in [false, true].into_iter().enumerate() {
        let dir = candidate_dir(models_dir, without);
        let how = if without { "without" } else { "reading" };
        pass.show.note(&format!(
            "coid: training {how} the re-identification descriptor into {}",
            dir.display()
        ));
        let candidates = candidate_runs(pass.a, (models_dir, seeds), without)?;
        pass.train(&dir, &candidates, without)?;
        for s in &candidates {
            for (i, (_, c)) in validate(&s.settings, &s.dir, pass.methods, bars)?
                .iter()
                .enumerate()
            {
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
        pass.show.note(&format!(
            "coid: {}: {} the descriptor (mean F1 on the validation runs {f1_reading:.3} reading \
             it, {f1_without:.3} without)",
            method.as_str(),
            if choice.reads { "reads" } else { "leaves out" },
        ));
    }
    Ok(())
}

/// Trains `methods` with the seeds of `--seed` in `workers` child
/// processes ([`training::child_groups`]), showing one progress bar per
/// child.
fn train_in_children(
    a: &Args,
    (models_dir, without): (&Path, bool),
    methods: &[Method],
    workers: usize,
) -> anyhow::Result<()> {
    let program = crate::batch::Program::this().context("cannot locate the coid executable")?;
    let groups = training::child_groups(methods, &a.seed, workers);
    let bars = ChildBars::new(groups.len(), a.quiet.quiet);
    let config = a.config.path();
    training::train_in_children(
        &program,
        (source(a, &config, without), models_dir),
        &groups,
        workers,
        |child, line| bars.show(child, line),
        |child| bars.finish(child),
    )?;
    Ok(())
}

/// One progress bar per child process, moved by its messages.
struct ChildBars {
    bars: MultiProgress,
    child: Vec<ProgressBar>,
}

impl ChildBars {
    fn new(children: usize, quiet: bool) -> Self {
        let bars = if quiet {
            MultiProgress::with_draw_target(ProgressDrawTarget::hidden())
        } else {
            MultiProgress::new()
        };
        let style = ProgressStyle::with_template(
            "{spinner} {prefix:<9} [{bar:30}] {pos}/{len} {msg} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
        let child = (0..children)
            .map(|_| {
                let pb = bars.add(ProgressBar::new(0));
                pb.set_style(style.clone());
                pb.set_prefix("starting");
                pb
            })
            .collect();
        Self { bars, child }
    }

    /// Shows a line child `k` printed: its message, or why it is none.
    fn show(&self, k: usize, line: &str) {
        match ChildMessage::parse(line) {
            Ok(message) => self.apply(k, message),
            Err(e) => self.note(&format!(
                "coid: training process {} printed a line that is not a progress message ({e}): {line}",
                k + 1
            )),
        }
    }

    fn apply(&self, k: usize, message: ChildMessage) {
        let pb = &self.child[k];
        match message {
            ChildMessage::Collect { run, runs } => {
                pb.set_prefix("data");
                pb.set_message("runs collected");
                pb.set_position(run as u64);
                pb.set_length(runs as u64);
            }
            ChildMessage::Progress {
                method,
                step,
                steps,
                loss,
            } => {
                if pb.prefix() != method.as_str() {
                    pb.reset();
                    pb.set_prefix(method.as_str());
                }
                pb.set_position(step as u64);
                pb.set_length(steps as u64);
                let loss = loss.map_or_else(|| "?".to_owned(), |l| format!("{l:.3}"));
                pb.set_message(format!("steps, loss {loss}"));
            }
            ChildMessage::Note { text } => self.note(&text),
        }
    }

    /// A line on stderr, above the bars.
    fn note(&self, text: &str) {
        self.bars.suspend(|| eprintln!("{text}"));
    }

    fn finish(&self, k: usize) {
        self.child[k].finish_and_clear();
    }
}

/// Chooses each method's lambda on the validation runs and records it
/// beside its weights ([`training::validate`]); `bars`: whether to show
/// progress bars, and what the runs' warnings are said to.
fn validate(
    settings: &Settings,
    models_dir: &Path,
    methods: &[Method],
    (bars, warnings): (bool, &Warnings),
) -> anyhow::Result<Vec<(Method, experiments::Chosen)>> {
    if methods.is_empty() {
        return Ok(Vec::new());
    }
    let pb = progress_bar(
        !bars,
        experiments::validation_runs(settings)?.len() as u64,
        "{spinner} choosing temperature, decision and lambda on the validation runs: run {pos}/{len} [{bar:30}] eta {eta}",
    );
    let run = (super::cores(), warnings);
    let chosen = training::validate(settings, models_dir, methods, run, |_, _| pb.inc(1))?;
    pb.finish_and_clear();
    show_chosen(&chosen);
    Ok(chosen)
}

/// One line per method: what the validation runs chose for it.
fn show_chosen(chosen: &[(Method, experiments::Chosen)]) {
    let text = |l: f64| {
        if l.is_finite() {
            format!("{l:.2}")
        } else {
            "none".to_owned()
        }
    };
    for (method, c) in chosen {
        let [total, epistemic, aleatoric] = c.lambdas.values();
        eprintln!(
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
        );
        if let Some(note) = crate::matching::deep::decision::temperature_at_bound(c.temperature) {
            eprintln!("coid: {}: note: {note}", method.as_str());
        }
    }
}

/// Chooses the thresholds of `baselines` on the validation runs and
/// records them in the models folder's `baselines.toml`
/// ([`training::tune_baselines`]); `bars` as [`validate`] takes them.
fn tune_baselines(
    settings: &Settings,
    models_dir: &Path,
    baselines: &[Method],
    (bars, warnings): (bool, &Warnings),
) -> anyhow::Result<()> {
    if baselines.is_empty() {
        return Ok(());
    }
    let pb = progress_bar(
        !bars,
        0,
        "{spinner} choosing the baselines' thresholds on the validation runs: value {pos}/{len} [{bar:30}] eta {eta}",
    );
    let run = (super::cores(), warnings);
    let tuned = training::tune_baselines(settings, models_dir, baselines, run, |pass, passes| {
        pb.set_length(passes as u64);
        pb.set_position(pass as u64);
    })?;
    pb.finish_and_clear();
    for t in &tuned {
        let weight = t
            .descriptor_weight
            .map(|w| format!(", descriptor weight {w}"))
            .unwrap_or_default();
        eprintln!(
            "coid: {}: {} {}{weight} (mean F1 {:.3} on the validation runs; a priori {}: {:.3})",
            t.method.as_str(),
            t.parameter,
            t.value,
            t.f1,
            t.a_priori,
            t.f1_a_priori
        );
        if let Some(note) = &t.note {
            eprintln!("coid: {}: note: {note}", t.method.as_str());
        }
    }
    Ok(())
}

/// How training in this process shows its progress: a bar for the data
/// collection and one per method (or lines for a parent process), with one
/// line per epoch: the curve as it grows.
struct Shown {
    show: Show,
    pb: ProgressBar,
    method: Method,
    smooth: f32,
    best: f64,
}

impl Shown {
    fn new(show: Show) -> Self {
        Self {
            show,
            pb: ProgressBar::hidden(),
            method: Method::Ours,
            smooth: f32::NAN,
            best: f64::INFINITY,
        }
    }
}

impl training::Report for Shown {
    fn collecting(&mut self, what: &str, runs: usize) {
        self.pb = progress_bar(
            self.show != Show::Bars,
            runs as u64,
            &format!(
                "{{spinner}} collecting {what} pairs: run {{pos}}/{{len}} [{{bar:30}}] {{msg}} eta {{eta}}"
            ),
        );
    }

    fn collected(&mut self, run: usize, runs: usize, examples: usize) {
        self.pb.inc(1);
        self.pb.set_message(format!("{examples} pairs"));
        if self.show == Show::Lines {
            send(&ChildMessage::Collect { run, runs });
        }
    }

    fn collected_all(&mut self) {
        self.pb.finish_and_clear();
    }

    fn training_data(&mut self, examples: usize, runs: usize) {
        self.show.note(&format!(
            "coid: {} from {}",
            crate::label::counted(examples as u64, "training pair"),
            crate::label::counted(runs as u64, "run")
        ));
    }

    fn training(&mut self, method: Method) {
        self.pb = progress_bar(
            self.show != Show::Bars,
            0,
            &format!(
                "{{spinner}} training {:<12} [{{bar:30}}] {{pos}}/{{len}} steps, {{msg}} eta {{eta}}",
                method.as_str()
            ),
        );
        self.method = method;
        self.smooth = f32::NAN;
        self.best = f64::INFINITY;
    }

    fn step(&mut self, step: usize, total: usize, loss: f32) {
        self.smooth = if self.smooth.is_nan() {
            loss
        } else {
            0.95 * self.smooth + 0.05 * loss
        };
        self.pb.set_length(total as u64);
        self.pb.set_position(step as u64);
        if step.is_multiple_of(10) {
            self.pb.set_message(format!("loss {:.3}", self.smooth));
        }
        if self.show == Show::Lines && (step.is_multiple_of(20) || step == total) {
            send(&ChildMessage::Progress {
                method: self.method,
                step,
                steps: total,
                loss: Some(self.smooth).filter(|l| l.is_finite()),
            });
        }
    }

    fn epoch(&mut self, epoch: usize, train_loss: f64, validation_loss: Option<f64>) {
        let method = self.method.as_str();
        let line = match validation_loss {
            Some(v) => {
                let mark = if v < self.best { " (best so far)" } else { "" };
                self.best = self.best.min(v);
                format!(
                    "coid: {method} epoch {epoch:>2}: training loss {train_loss:.4}, validation loss {v:.4}{mark}"
                )
            }
            None => format!("coid: {method} epoch {epoch:>2}: training loss {train_loss:.4}"),
        };
        self.pb.suspend(|| self.show.note(&line));
    }

    fn trained(&mut self, t: &Trained) {
        self.pb.finish_and_clear();
        self.show.note(&format!(
            "coid: trained {} in {:.1} min ({} steps{}); wrote {} and its loss curve {}",
            t.method.as_str(),
            t.seconds / 60.0,
            t.steps,
            t.best_epoch
                .map_or(String::new(), |e| format!(", kept epoch {e}")),
            t.weights.display(),
            t.loss_curve.display()
        ));
    }
}
