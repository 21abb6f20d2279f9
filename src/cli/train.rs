//! `coid train`: the deep matchers on the training runs; weights, config
//! and loss curve into the models folder, then each one's lambda chosen on
//! the validation runs. Several methods train at once in child `coid
//! train` processes (burn's CPU backend trains on one core), which report
//! their progress to this one as messages on stdout ([`ChildMessage`]: one
//! JSON object a line).

use std::ffi::OsString;
use std::path::Path;

use anyhow::Context;
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{ConfigArg, ForceArg, OutArg, QuietArg, WorkersArg, label_arg, progress_bar};
use crate::batch;
use crate::config::Settings;
use crate::experiments;
use crate::io::{self, TrainingRecord};
use crate::matching::{Method, MethodKind, deep};

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
            Show::Lines => ChildMessage::Note {
                text: text.to_owned(),
            }
            .send(),
            _ => eprintln!("{text}"),
        }
    }
}

/// What a child `coid train` (`--progress-lines`) tells its parent: one
/// JSON object a line on stdout, `kind` naming the message.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
enum ChildMessage {
    /// Collecting training or validation pairs: `run` of `runs` done.
    Collect { run: usize, runs: usize },
    /// Training `method`: `step` of `steps` done, the smoothed loss (none
    /// when it is not a finite number, which JSON cannot carry).
    Progress {
        method: Method,
        step: usize,
        steps: usize,
        loss: Option<f32>,
    },
    /// A line for the user.
    Note { text: String },
}

impl ChildMessage {
    /// Prints the message on stdout, as one line.
    fn send(&self) {
        match serde_json::to_string(self) {
            Ok(line) => println!("{line}"),
            Err(e) => eprintln!("coid: cannot report progress: {e}"),
        }
    }

    fn parse(line: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(line)
    }
}

/// One training seed of a `coid train`: the settings with it as `[train]
/// seed`, and the folder its models go into.
struct SeedRun {
    settings: Settings,
    dir: std::path::PathBuf,
}

/// Checks that `dir` can take models (or, with `--validate-only`, holds
/// some: validating only adds records beside the weights, so an existing
/// models folder needs no `--force`).
fn models_folder(a: &Args, dir: &Path) -> anyhow::Result<()> {
    if a.validate_only && !dir.is_dir() {
        anyhow::bail!(
            "no models folder {} to validate (give the folder with --out)",
            dir.display()
        );
    }
    io::check_extendable(
        dir,
        io::ResultKind::Models,
        io::Existing::when(a.force.force || a.validate_only),
    )?;
    Ok(())
}

/// The seeds `--seed` asks for (else `[train] seed`), each with its
/// settings and folder: `[train] seed`'s the models folder, every other's
/// its `seed-<N>/` folder; each checked to be extendable.
fn seed_runs(a: &Args, settings: &Settings, models_dir: &Path) -> anyhow::Result<Vec<SeedRun>> {
    if let Some(s) = super::first_repeat(&a.seed) {
        anyhow::bail!("--seed lists {s} twice");
    }
    let own = settings.train.seed;
    let seeds = if a.seed.is_empty() {
        vec![own]
    } else {
        a.seed.clone()
    };
    let config = a.config.path();
    let mut runs = Vec::with_capacity(seeds.len());
    for seed in seeds {
        let dir = if seed == own {
            models_dir.to_owned()
        } else {
            io::seed_models_dir(models_dir, seed)
        };
        models_folder(a, &dir)?;
        let overrides = crate::config::Overrides {
            train_seed: Some(seed),
            ..Default::default()
        };
        runs.push(SeedRun {
            settings: Settings::load_with(&config, &overrides)?,
            dir,
        });
    }
    Ok(runs)
}

/// The deep methods to train (or validate) and the baselines to tune:
/// `--methods` split by kind, else `[train] methods` and the baselines of
/// `[matching] methods`; refused when `--methods` names a method twice,
/// a single-pass variant, or a baseline to train.
fn methods_of(a: &Args, settings: &Settings) -> anyhow::Result<(Vec<Method>, Vec<Method>)> {
    super::no_repeats("--methods", &a.methods)?;
    if let Some(m) = a.methods.iter().find(|m| m.single_pass()) {
        anyhow::bail!(
            "'{}' runs the weights and choices of '{}' in one pass: train or validate '{}'",
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
            .partition(|m| matches!(m.kind(), MethodKind::Deep(_)));
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
    Ok((methods, baselines))
}

pub fn train(a: Args) -> anyhow::Result<()> {
    let config = a.config.path();
    let settings = Settings::load(&config)?;
    let models_dir = super::out_dir(a.out.out.clone(), &config, "-models");
    models_folder(&a, &models_dir)?;
    let seeds = seed_runs(&a, &settings, &models_dir)?;
    // The baselines have no training seed: tuned with [train] seed's run.
    let tunes_baselines = seeds.iter().any(|s| s.dir == models_dir);
    let (methods, baselines) = methods_of(&a, &settings)?;
    let show = match (a.progress_lines, a.quiet.quiet) {
        (true, _) => Show::Lines,
        (false, true) => Show::Quiet,
        (false, false) => Show::Bars,
    };
    let jobs = methods.len() * seeds.len();
    let workers = a.workers.get().clamp(1, jobs.max(1));
    let started = std::time::Instant::now();
    let bars = show == Show::Bars;
    let baselines: &[Method] = if tunes_baselines { &baselines } else { &[] };
    if a.validate_only {
        for s in &seeds {
            validate(&s.settings, &s.dir, &methods, bars)?;
        }
        return tune_baselines(&settings, &models_dir, baselines, bars);
    }
    if workers > 1 {
        train_in_children(&a, &models_dir, &methods, workers)?;
    } else {
        train_here(&seeds, &methods, show)?;
    }
    if !a.skip_validation {
        for s in &seeds {
            validate(&s.settings, &s.dir, &methods, bars)?;
        }
        tune_baselines(&settings, &models_dir, baselines, bars)?;
    }
    if show != Show::Lines {
        eprintln!(
            "coid: training took {:.1} min in all; models in {}",
            started.elapsed().as_secs_f64() / 60.0,
            models_dir.display()
        );
    }
    Ok(())
}

/// Collects the data once and trains `methods` with every seed one after
/// another in this process, writing each model (without its lambda). The
/// data does not depend on the training seed.
fn train_here(seeds: &[SeedRun], methods: &[Method], show: Show) -> anyhow::Result<()> {
    let Some(first) = seeds.first() else {
        return Ok(());
    };
    let settings = &first.settings;
    let training = experiments::training_runs(settings)?;
    let examples = collect(&training, "training", show)?;
    show.note(&format!(
        "coid: {} from {}",
        crate::label::counted(examples.len() as u64, "training pair"),
        crate::label::counted(training.len() as u64, "run")
    ));
    // The validation runs' pairs, for early stopping only.
    let validation = if settings.train.patience == 0 {
        Vec::new()
    } else {
        collect(
            &experiments::validation_loss_runs(settings)?,
            "validation",
            show,
        )?
    };
    for s in seeds {
        for &method in methods {
            train_one(&s.settings, method, (&examples, &validation), &s.dir, show)?;
        }
    }
    Ok(())
}

/// Every `n`-th item of `items` from the `k`-th.
fn every<T: Copy>(items: &[T], k: usize, n: usize) -> Vec<T> {
    items.iter().copied().skip(k).step_by(n).collect()
}

/// Trains `methods` with the seeds of `--seed` in `workers` child
/// processes (method k in group k mod workers, with every seed; or, with
/// fewer methods than workers, seed k in group k mod workers, with every
/// method), showing one progress bar per child.
fn train_in_children(
    a: &Args,
    models_dir: &Path,
    methods: &[Method],
    workers: usize,
) -> anyhow::Result<()> {
    let exe = std::env::current_exe().context("cannot locate the coid executable")?;
    let groups: Vec<(Vec<Method>, Vec<u64>)> = (0..workers)
        .map(|g| {
            if methods.len() >= workers {
                (every(methods, g, workers), a.seed.clone())
            } else {
                (methods.to_vec(), every(&a.seed, g, workers))
            }
        })
        .collect();
    let config = a.config.path();
    let jobs: Vec<Vec<OsString>> = groups
        .iter()
        .map(|(group, seeds)| child_args(&config, models_dir, group, seeds))
        .collect();
    let bars = ChildBars::new(groups.len(), a.quiet.quiet);
    let failures = batch::run_children(
        &exe,
        &jobs,
        workers,
        |child, line| bars.show(child, line),
        |child, ok| {
            bars.finish(child);
            ok
        },
    )
    .context("cannot start a training process")?;
    if let Some(f) = failures.first() {
        let (methods, seeds) = &groups[f.run];
        let group = labels(methods).join(", ");
        let seeds = if seeds.is_empty() {
            String::new()
        } else {
            format!(" (seeds {})", seed_list(seeds, ", "))
        };
        anyhow::bail!("training {group}{seeds} failed: {}", f.message);
    }
    Ok(())
}

/// The labels of `methods`.
fn labels(methods: &[Method]) -> Vec<&'static str> {
    methods.iter().map(|m| m.as_str()).collect()
}

/// `seeds` joined by `sep`.
fn seed_list(seeds: &[u64], sep: &str) -> String {
    let seeds: Vec<String> = seeds.iter().map(u64::to_string).collect();
    seeds.join(sep)
}

/// The arguments of the child `coid train` that trains `group` into
/// `models_dir`, reporting [`ChildMessage`]s.
fn child_args(config: &Path, models_dir: &Path, group: &[Method], seeds: &[u64]) -> Vec<OsString> {
    let mut args: Vec<OsString> = vec!["train".into(), "--config".into(), config.into()];
    args.extend(["--out".into(), models_dir.into()]);
    args.extend(["--methods".into(), labels(group).join(",").into()]);
    if !seeds.is_empty() {
        args.extend(["--seed".into(), seed_list(seeds, ",").into()]);
    }
    let flags = [
        "--workers",
        "1",
        "--force",
        "--skip-validation",
        "--progress-lines",
    ];
    args.extend(flags.map(OsString::from));
    args
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

/// The labelled pairs of `runs` (`what`: training or validation), with
/// progress.
fn collect(runs: &[Settings], what: &str, show: Show) -> anyhow::Result<Vec<deep::train::Example>> {
    let pb = progress_bar(
        show != Show::Bars,
        runs.len() as u64,
        &format!(
            "{{spinner}} collecting {what} pairs: run {{pos}}/{{len}} [{{bar:30}}] {{msg}} eta {{eta}}"
        ),
    );
    let examples = experiments::collect_examples(runs, |k, n_runs, n| {
        pb.inc(1);
        pb.set_message(format!("{n} pairs"));
        if show == Show::Lines {
            ChildMessage::Collect {
                run: k,
                runs: n_runs,
            }
            .send();
        }
    })
    .with_context(|| format!("collecting {what} data failed"))?;
    pb.finish_and_clear();
    Ok(examples)
}

/// Chooses each method's lambda on the validation runs and records it
/// beside its weights.
fn validate(
    settings: &Settings,
    models_dir: &Path,
    methods: &[Method],
    bars: bool,
) -> anyhow::Result<()> {
    if methods.is_empty() {
        return Ok(());
    }
    let seeds = &settings.train.validation_seeds;
    let pb = progress_bar(
        !bars,
        experiments::validation_runs(settings)?.len() as u64,
        "{spinner} choosing temperature, decision and lambda on the validation runs: run {pos}/{len} [{bar:30}] eta {eta}",
    );
    let mut on_models = settings.clone();
    on_models.matching.models_dir = models_dir.to_owned();
    let chosen = experiments::validate(&on_models, methods, super::cores(), |_, _| pb.inc(1))
        .context("validation runs failed")?;
    pb.finish_and_clear();
    for &method in methods {
        let c = chosen[&method];
        let validation = io::Validation {
            lambda: c.lambda,
            decision: c.decision,
            temperature: c.temperature,
            f1: c.f1,
            seeds: seeds.clone(),
            uncertainty: settings.matching.uncertainty.as_str(),
            lambdas: c.lambdas,
        };
        io::record_validation(models_dir, method, &validation)?;
        let text = |l: f64| {
            if l.is_finite() {
                format!("{l:.2}")
            } else {
                "none".to_owned()
            }
        };
        let [total, epistemic, aleatoric] = c.lambdas.values();
        eprintln!(
            "coid: {}: temperature {:.2}, decision {}, lambda {} (mean F1 {:.3} on the \
             validation runs; entropy {}, epistemic {}, aleatoric {})",
            method.as_str(),
            c.temperature,
            c.decision.as_str(),
            text(c.lambda),
            c.f1,
            text(total),
            text(epistemic),
            text(aleatoric),
        );
    }
    Ok(())
}

/// Chooses the thresholds of `baselines` on the validation runs and
/// records them in the models folder's `baselines.toml`.
fn tune_baselines(
    settings: &Settings,
    models_dir: &Path,
    baselines: &[Method],
    bars: bool,
) -> anyhow::Result<()> {
    if baselines.is_empty() {
        return Ok(());
    }
    let mut only = settings.clone();
    only.matching.methods = baselines.to_vec();
    let pb = progress_bar(
        !bars,
        0,
        "{spinner} choosing the baselines' thresholds on the validation runs: value {pos}/{len} [{bar:30}] eta {eta}",
    );
    let tuned = experiments::tune_baselines(&only, super::cores(), |pass, passes| {
        pb.set_length(passes as u64);
        pb.set_position(pass as u64);
    })
    .context("validation runs failed")?;
    pb.finish_and_clear();
    let entries: Vec<io::BaselineEntry> = tuned
        .iter()
        .map(|t| io::BaselineEntry {
            method: t.method,
            parameter: t.parameter.to_owned(),
            value: t.value,
            f1: t.f1,
            a_priori: t.a_priori,
            f1_a_priori: t.f1_a_priori,
        })
        .collect();
    io::record_baselines(models_dir, settings, &entries)?;
    for t in &tuned {
        eprintln!(
            "coid: {}: {} {} (mean F1 {:.3} on the validation runs; a priori {}: {:.3})",
            t.method.as_str(),
            t.parameter,
            t.value,
            t.f1,
            t.a_priori,
            t.f1_a_priori
        );
    }
    Ok(())
}

/// Training progress on a bar (or as lines for a parent process), with
/// one line per epoch: the curve as it grows.
struct Progress<'a> {
    pb: indicatif::ProgressBar,
    show: Show,
    method: Method,
    smooth: f32,
    best: f64,
    lines: &'a mut Vec<String>,
}

impl deep::train::TrainProgress for Progress<'_> {
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
            ChildMessage::Progress {
                method: self.method,
                step,
                steps: total,
                loss: Some(self.smooth).filter(|l| l.is_finite()),
            }
            .send();
        }
    }

    fn epoch(&mut self, epoch: usize, train_loss: f64, validation_loss: Option<f64>) {
        let line = match validation_loss {
            Some(v) => {
                let mark = if v < self.best { " (best so far)" } else { "" };
                self.best = self.best.min(v);
                format!(
                    "coid: {} epoch {epoch:>2}: training loss {train_loss:.4}, validation loss {v:.4}{mark}",
                    self.method.as_str()
                )
            }
            None => format!(
                "coid: {} epoch {epoch:>2}: training loss {train_loss:.4}",
                self.method.as_str()
            ),
        };
        self.pb.suspend(|| self.show.note(&line));
        self.lines.push(line);
    }
}

fn train_one(
    settings: &Settings,
    method: Method,
    (examples, validation): (&[deep::train::Example], &[deep::train::Example]),
    models_dir: &Path,
    show: Show,
) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let pb = progress_bar(
        show != Show::Bars,
        0,
        &format!(
            "{{spinner}} training {:<12} [{{bar:30}}] {{pos}}/{{len}} steps, {{msg}} eta {{eta}}",
            method.as_str()
        ),
    );
    let mut lines = Vec::new();
    let mut progress = Progress {
        pb: pb.clone(),
        show,
        method,
        smooth: f32::NAN,
        best: f64::INFINITY,
        lines: &mut lines,
    };
    let (weights, report) =
        experiments::train_method(settings, method, examples, validation, &mut progress)
            .map_err(|e| anyhow::anyhow!("training {} failed: {e}", method.as_str()))?;
    pb.finish_and_clear();
    let record = TrainingRecord {
        method,
        settings,
        n_examples: examples.len(),
        report: &report,
        seconds: started.elapsed().as_secs_f64(),
    };
    io::write_model(models_dir, &record, &weights)?;
    show.note(&format!(
        "coid: trained {} in {:.1} min ({} steps{}); wrote {} and its loss curve {}",
        method.as_str(),
        record.seconds / 60.0,
        report.steps,
        report
            .best_epoch
            .map_or(String::new(), |e| format!(", kept epoch {e}")),
        io::weights_path(models_dir, method).display(),
        models_dir
            .join(format!("{}_loss.csv", method.as_str()))
            .display()
    ));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each message is one JSON line that reads back as itself (a note's
    /// line breaks escaped); a line that is not a whole, known message is
    /// an error, never a default.
    #[test]
    fn child_messages_are_json_lines_and_bad_lines_are_errors() {
        let messages = [
            ChildMessage::Collect { run: 3, runs: 7 },
            ChildMessage::Progress {
                method: Method::GcnGm,
                step: 20,
                steps: 100,
                loss: Some(0.409),
            },
            ChildMessage::Progress {
                method: Method::Dgmc,
                step: 1,
                steps: 1,
                loss: None,
            },
            ChildMessage::Note {
                text: "coid: two\nlines".into(),
            },
        ];
        for m in messages {
            let line = serde_json::to_string(&m).unwrap();
            assert!(!line.contains('\n'), "{line}");
            assert_eq!(ChildMessage::parse(&line).unwrap(), m);
        }
        let line = serde_json::to_string(&ChildMessage::Collect { run: 1, runs: 2 }).unwrap();
        assert_eq!(line, r#"{"kind":"collect","run":1,"runs":2}"#);
        for bad in [
            "progress gcn-gm 1 2 0.5",
            r#"{"kind":"collect","run":1}"#,
            r#"{"kind":"collect","run":-1,"runs":2}"#,
            r#"{"kind":"collect","run":1,"runs":2,"typo":0}"#,
            r#"{"kind":"progress","method":"nope","step":1,"steps":1,"loss":null}"#,
            r#"{"kind":"shout","text":"hi"}"#,
        ] {
            assert!(ChildMessage::parse(bad).is_err(), "{bad}");
        }
    }
}
