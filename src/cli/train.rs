//! `coid train`: the deep matchers on the training runs; weights, config
//! and loss curve into the models folder.

use std::path::PathBuf;

use anyhow::Context;

use super::{ConfigArg, QuietArg, label_arg, progress_bar};
use crate::config::Settings;
use crate::experiments;
use crate::io::{self, TrainingRecord};
use crate::matching::{Method, deep};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArg,
    /// Models folder [default: [matching] models_dir of the config].
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Train only these methods [default: [train] methods].
    #[arg(long, value_delimiter = ',', value_parser = label_arg::<Method>("method"))]
    methods: Vec<Method>,
    #[command(flatten)]
    quiet: QuietArg,
}

pub fn train(a: Args) -> anyhow::Result<()> {
    let settings = Settings::load(&a.config.config)?;
    let models_dir = a
        .out
        .unwrap_or_else(|| settings.matching.models_dir.clone());
    let methods = if a.methods.is_empty() {
        settings.train.methods.clone()
    } else {
        a.methods
    };
    if let Some(m) = methods.iter().find(|m| deep::variant(**m).is_none()) {
        anyhow::bail!("'{}' is not a trainable (deep) method", m.as_str());
    }
    let training = experiments::training_runs(&settings)?;
    let examples = collect(&training, "training", a.quiet.quiet)?;
    eprintln!(
        "coid: {} training pairs from {} runs",
        examples.len(),
        training.len()
    );
    // The validation runs' pairs, for early stopping only.
    let validation = if settings.train.patience == 0 {
        Vec::new()
    } else {
        collect(
            &experiments::validation_runs(&settings)?,
            "validation",
            a.quiet.quiet,
        )?
    };
    let mut trained = Vec::new();
    for &method in &methods {
        trained.push(train_one(
            &settings,
            method,
            (&examples, &validation),
            &models_dir,
            a.quiet.quiet,
        )?);
    }
    validate(
        &settings,
        &models_dir,
        trained,
        examples.len(),
        a.quiet.quiet,
    )
}

/// The labelled pairs of `runs` (`what`: training or validation), with a
/// progress bar.
fn collect(
    runs: &[Settings],
    what: &str,
    quiet: bool,
) -> anyhow::Result<Vec<deep::train::Example>> {
    let pb = progress_bar(
        quiet,
        runs.len() as u64,
        &format!(
            "{{spinner}} collecting {what} pairs: run {{pos}}/{{len}} [{{bar:30}}] {{msg}} eta {{eta}}"
        ),
    );
    let examples = experiments::collect_examples(runs, |_, _, n| {
        pb.inc(1);
        pb.set_message(format!("{n} pairs"));
    })
    .with_context(|| format!("collecting {what} data failed"))?;
    pb.finish_and_clear();
    Ok(examples)
}

/// One trained method, kept until its validation is recorded.
struct Trained {
    method: Method,
    weights: Vec<u8>,
    report: deep::train::TrainReport,
    seconds: f64,
}

/// Chooses each trained method's lambda on the validation runs and records
/// it beside the weights.
fn validate(
    settings: &Settings,
    models_dir: &std::path::Path,
    trained: Vec<Trained>,
    n_examples: usize,
    quiet: bool,
) -> anyhow::Result<()> {
    let seeds = &settings.train.validation_seeds;
    let pb = progress_bar(
        quiet,
        experiments::validation_runs(settings)?.len() as u64,
        "{spinner} choosing lambda on the validation runs: run {pos}/{len} [{bar:30}] eta {eta}",
    );
    let mut on_models = settings.clone();
    on_models.matching.models_dir = models_dir.to_owned();
    let methods: Vec<Method> = trained.iter().map(|t| t.method).collect();
    let chosen = experiments::validate(&on_models, &methods, |_, _| pb.inc(1))
        .context("validation runs failed")?;
    pb.finish_and_clear();
    for t in trained {
        let c = chosen[&t.method];
        let record = TrainingRecord {
            method: t.method,
            settings,
            n_examples,
            report: &t.report,
            seconds: t.seconds,
            validation: Some(io::Validation {
                lambda: c.lambda,
                f1: c.f1,
                seeds: seeds.clone(),
                uncertainty: settings.matching.uncertainty.as_str(),
            }),
        };
        io::write_model(models_dir, &record, &t.weights)?;
        eprintln!(
            "coid: {}: lambda {:.2} (mean F1 {:.3} on validation runs {seeds:?})",
            t.method.as_str(),
            c.lambda,
            c.f1
        );
    }
    Ok(())
}

fn train_one(
    settings: &Settings,
    method: Method,
    (examples, validation): (&[deep::train::Example], &[deep::train::Example]),
    models_dir: &std::path::Path,
    quiet: bool,
) -> anyhow::Result<Trained> {
    let started = std::time::Instant::now();
    let pb = progress_bar(
        quiet,
        (settings.train.epochs * examples.len()) as u64,
        &format!(
            "{{spinner}} training {:<9} [{{bar:30}}] {{pos}}/{{len}} steps, {{msg}} eta {{eta}}",
            method.as_str()
        ),
    );
    let mut smooth = f32::NAN;
    let (weights, report) =
        experiments::train_method(settings, method, examples, validation, |step, _, loss| {
            smooth = if smooth.is_nan() {
                loss
            } else {
                0.98 * smooth + 0.02 * loss
            };
            pb.set_position(step as u64);
            if step % 20 == 0 {
                pb.set_message(format!("loss {smooth:.3}"));
            }
        })
        .map_err(|e| anyhow::anyhow!("training {} failed: {e}", method.as_str()))?;
    pb.finish_and_clear();
    let record = TrainingRecord {
        method,
        settings,
        n_examples: examples.len(),
        report: &report,
        seconds: started.elapsed().as_secs_f64(),
        validation: None,
    };
    io::write_model(models_dir, &record, &weights)?;
    let losses: Vec<f64> = report
        .epoch_losses
        .iter()
        .map(|l| (l * 1000.0).round() / 1000.0)
        .collect();
    eprintln!(
        "coid: trained {} in {:.0} s ({} steps), loss per epoch {losses:?}; wrote {}",
        method.as_str(),
        record.seconds,
        report.steps,
        io::weights_path(models_dir, method).display()
    );
    Ok(Trained {
        method,
        weights,
        seconds: record.seconds,
        report,
    })
}
