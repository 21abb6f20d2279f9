//! `coid train`: the deep matchers on the training runs; weights, config
//! and loss curve into the models folder, then each one's lambda chosen on
//! the validation runs. Several methods train at once in child `coid
//! train` processes (burn's CPU backend trains on one core), which report
//! their progress to this one as lines on stdout.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{ConfigArg, QuietArg, label_arg, progress_bar};
use crate::batch;
use crate::config::Settings;
use crate::experiments;
use crate::io::{self, TrainingRecord};
use crate::matching::{Method, MethodKind, deep};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArg,
    /// The models folder written: weights (<method>.bpk), their record
    /// (<method>.toml: architecture, training and validation settings,
    /// loss per epoch, validated temperature, decision rule and lambda)
    /// and loss curve (<method>_loss.csv) [default: results/<config file
    /// stem>-models]. Point [matching] models_dir at it to use the
    /// weights; `--out models --force` in the checkout replaces the
    /// shipped ones.
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Write into the models folder although it exists (its weights of the
    /// trained methods are replaced; with --validate-only, their records
    /// are updated).
    #[arg(long)]
    force: bool,
    /// Train only these methods [default: [train] methods].
    #[arg(long, value_delimiter = ',', value_parser = label_arg::<Method>("method"))]
    methods: Vec<Method>,
    /// Worker processes, 1 to 1024: methods trained at once, each group in
    /// its own process (the weights do not depend on this; never more than
    /// the methods) [default: the number of cores].
    #[arg(long, short, value_parser = super::in_range(1, super::MAX_PARALLEL))]
    workers: Option<usize>,
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
    /// Lines on stdout for a parent process: `collect <run> <runs>`,
    /// `progress <method> <step> <steps> <loss>`, `note <text>`.
    Lines,
    Quiet,
}

impl Show {
    fn note(self, text: &str) {
        match self {
            Show::Lines => println!("note {text}"),
            _ => eprintln!("{text}"),
        }
    }
}

pub fn train(a: Args) -> anyhow::Result<()> {
    let config = a.config.path();
    let settings = Settings::load(&config)?;
    let models_dir = super::out_dir(a.out.clone(), &config, "-models");
    if a.validate_only && !models_dir.is_dir() {
        anyhow::bail!(
            "no models folder {} to validate (give the folder with --out)",
            models_dir.display()
        );
    }
    io::check_extendable(
        &models_dir,
        io::ResultKind::Models,
        io::Existing::when(a.force),
    )?;
    super::no_repeats("--methods", &a.methods)?;
    let methods = if a.methods.is_empty() {
        settings.train.methods.clone()
    } else {
        a.methods.clone()
    };
    if let Some(m) = methods
        .iter()
        .find(|m| !matches!(m.kind(), MethodKind::Deep(_)))
    {
        anyhow::bail!("'{}' is not a trainable (deep) method", m.as_str());
    }
    let show = match (a.progress_lines, a.quiet.quiet) {
        (true, _) => Show::Lines,
        (false, true) => Show::Quiet,
        (false, false) => Show::Bars,
    };
    let workers = a
        .workers
        .unwrap_or_else(super::cores)
        .clamp(1, methods.len().max(1));
    let started = std::time::Instant::now();
    if a.validate_only {
        return validate(&settings, &models_dir, &methods, show == Show::Bars);
    }
    if workers > 1 {
        train_in_children(&a, &models_dir, &methods, workers)?;
    } else {
        train_here(&settings, &methods, &models_dir, show)?;
    }
    if !a.skip_validation {
        validate(&settings, &models_dir, &methods, show == Show::Bars)?;
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

/// Collects the data and trains `methods` one after another in this
/// process, writing each model (without its lambda).
fn train_here(
    settings: &Settings,
    methods: &[Method],
    models_dir: &Path,
    show: Show,
) -> anyhow::Result<()> {
    let training = experiments::training_runs(settings)?;
    let examples = collect(&training, "training", show)?;
    show.note(&format!(
        "coid: {} training pairs from {} runs",
        examples.len(),
        training.len()
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
    for &method in methods {
        train_one(settings, method, (&examples, &validation), models_dir, show)?;
    }
    Ok(())
}

/// Trains `methods` in `workers` child processes (method k in group k mod
/// workers), showing one progress bar per child.
fn train_in_children(
    a: &Args,
    models_dir: &Path,
    methods: &[Method],
    workers: usize,
) -> anyhow::Result<()> {
    let exe = std::env::current_exe().context("cannot locate the coid executable")?;
    let groups: Vec<Vec<Method>> = (0..workers)
        .map(|g| methods.iter().copied().skip(g).step_by(workers).collect())
        .collect();
    let jobs: Vec<Vec<OsString>> = groups
        .iter()
        .map(|group| {
            let names: Vec<&str> = group.iter().map(|m| m.as_str()).collect();
            let mut args: Vec<OsString> = vec!["train".into(), "--config".into()];
            args.push(a.config.path().into());
            args.push("--out".into());
            args.push(models_dir.into());
            args.push("--methods".into());
            args.push(names.join(",").into());
            for flag in [
                "--workers",
                "1",
                "--force",
                "--skip-validation",
                "--progress-lines",
            ] {
                args.push(flag.into());
            }
            args
        })
        .collect();
    let bars = if a.quiet.quiet {
        indicatif::MultiProgress::with_draw_target(indicatif::ProgressDrawTarget::hidden())
    } else {
        indicatif::MultiProgress::new()
    };
    let style = indicatif::ProgressStyle::with_template(
        "{spinner} {prefix:<9} [{bar:30}] {pos}/{len} {msg} eta {eta}",
    )
    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
    .progress_chars("=> ");
    let pbs: Vec<indicatif::ProgressBar> = groups
        .iter()
        .map(|_| {
            let pb = bars.add(indicatif::ProgressBar::new(0));
            pb.set_style(style.clone());
            pb.set_prefix("starting");
            pb
        })
        .collect();
    let on_line = |k: usize, line: &str| {
        let pb = &pbs[k];
        let mut w = line.split_whitespace();
        match w.next() {
            Some("collect") => {
                pb.set_prefix("data");
                pb.set_message("runs collected");
                pb.set_position(w.next().and_then(|x| x.parse().ok()).unwrap_or(0));
                pb.set_length(w.next().and_then(|x| x.parse().ok()).unwrap_or(0));
            }
            Some("progress") => {
                let method = w.next().unwrap_or("?").to_owned();
                if pb.prefix() != method {
                    pb.reset();
                    pb.set_prefix(method);
                }
                pb.set_position(w.next().and_then(|x| x.parse().ok()).unwrap_or(0));
                pb.set_length(w.next().and_then(|x| x.parse().ok()).unwrap_or(0));
                pb.set_message(format!("steps, loss {}", w.next().unwrap_or("?")));
            }
            Some("note") => bars.suspend(|| eprintln!("{}", line[4..].trim())),
            _ => {}
        }
    };
    let failures = batch::run_children(&exe, &jobs, workers, on_line, |k, ok| {
        pbs[k].finish_and_clear();
        ok
    })
    .context("cannot start a training process")?;
    if let Some(f) = failures.first() {
        let names: Vec<&str> = groups[f.run].iter().map(|m| m.as_str()).collect();
        anyhow::bail!("training {} failed: {}", names.join(", "), f.message);
    }
    Ok(())
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
            println!("collect {k} {n_runs}");
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
        };
        io::record_validation(models_dir, method, &validation)?;
        eprintln!(
            "coid: {}: temperature {:.2}, decision {}, lambda {} (mean F1 {:.3} on the \
             validation runs)",
            method.as_str(),
            c.temperature,
            c.decision.as_str(),
            if c.lambda.is_finite() {
                format!("{:.2}", c.lambda)
            } else {
                "none".to_owned()
            },
            c.f1
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
            println!(
                "progress {} {step} {total} {:.3}",
                self.method.as_str(),
                self.smooth
            );
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
