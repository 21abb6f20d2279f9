//! `coid train` below the command line: every training seed's settings and
//! models folder ([`seed_runs`]); one collection of the training data for
//! every seed, then each method trained and written with its record
//! ([`train_seeds`], its progress told to a [`Report`]); groups of methods
//! trained in child `coid train` processes ([`child_groups`],
//! [`train_in_children`]) that tell their parent how they progress as
//! [`ChildMessage`] lines; and the choices made on the validation runs,
//! recorded beside the weights ([`validate`], [`tune_baselines`]).

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use crate::batch;
use crate::config::{ConfigError, Overrides, Settings};
use crate::experiments::{self, Chosen, TunedBaseline};
use crate::io::{self, OutputError, TrainingRecord};
use crate::matching::Method;
use crate::matching::deep::train::{Example, TrainProgress};
use crate::pipeline::{RunError, Warnings};

#[derive(Debug, thiserror::Error)]
pub enum TrainingError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    Run(#[from] RunError),
    #[error("no models folder {} to validate (give the folder with --out)", .0.display())]
    NoModels(PathBuf),
    #[error("collecting {what} data failed")]
    Collect {
        what: &'static str,
        #[source]
        source: RunError,
    },
    #[error("training {method} failed: {reason}")]
    Train {
        method: &'static str,
        reason: String,
    },
    #[error("validation runs failed")]
    Validation(#[source] RunError),
    #[error("cannot start a training process")]
    Start(#[source] std::io::Error),
    #[error("training {group}{seeds} failed: {message}")]
    Child {
        group: String,
        seeds: String,
        message: String,
    },
}

/// What a child `coid train` (`--progress-lines`) tells its parent: one
/// JSON object a line on stdout, `kind` naming the message.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ChildMessage {
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
    /// The message as one line of JSON.
    pub fn line(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string(self)
    }

    /// A line a child printed, read back; an error unless it is one whole,
    /// known message.
    pub fn parse(line: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(line)
    }
}

/// One training seed of a `coid train`: the settings with it as `[train]
/// seed`, and the folder its models go into.
pub struct SeedRun {
    pub settings: Settings,
    pub dir: PathBuf,
}

/// Checks that `dir` can take models (or, when `validate_only`, holds
/// some: validating only adds records beside the weights, so an existing
/// models folder needs no `force`).
pub fn check_models_folder(
    dir: &Path,
    validate_only: bool,
    force: bool,
) -> Result<(), TrainingError> {
    if validate_only && !dir.is_dir() {
        return Err(TrainingError::NoModels(dir.to_owned()));
    }
    io::check_extendable(
        dir,
        io::ResultKind::Models,
        io::Existing::when(force || validate_only),
    )?;
    Ok(())
}

/// What a training reads: the config, the dataset it trains on instead of
/// simulating, and the re-identification descriptor's rank-1 set over the
/// config (`coid train --reid-rank1`).
#[derive(Clone, Copy, Debug)]
pub struct TrainSource<'a> {
    pub config: &'a Path,
    pub dataset: Option<&'a Path>,
    pub reid_rank1: Option<f64>,
    /// Train without the descriptor (`[train] appearance_vectors =
    /// false`, `coid train --without-descriptor`).
    pub without_descriptor: bool,
}

/// The runs of `seeds` (none: `[train] seed` alone), each with the
/// settings of `config` with it as `[train] seed` and its folder:
/// `[train] seed`'s the models folder `models_dir`, every other's its
/// `seed-<N>/` folder; each folder checked ([`check_models_folder`]).
pub fn seed_runs(
    source: TrainSource,
    settings: &Settings,
    seeds: &[u64],
    models_dir: &Path,
    (validate_only, force): (bool, bool),
) -> Result<Vec<SeedRun>, TrainingError> {
    let own = settings.train.seed;
    let seeds = if seeds.is_empty() {
        vec![own]
    } else {
        seeds.to_vec()
    };
    let mut runs = Vec::with_capacity(seeds.len());
    for seed in seeds {
        let dir = if seed == own {
            models_dir.to_owned()
        } else {
            io::seed_models_dir(models_dir, seed)
        };
        check_models_folder(&dir, validate_only, force)?;
        let overrides = Overrides {
            train_seed: Some(seed),
            reid_rank1: source.reid_rank1,
            appearance_vectors: source.without_descriptor.then_some(false),
            ..Default::default()
        };
        let loaded = Settings::load_with(source.config, &overrides)?;
        let mut settings =
            experiments::calibrated(&loaded, |_, _| {}).map_err(TrainingError::Validation)?;
        if let Some(d) = source.dataset {
            settings =
                experiments::with_dataset(&settings, d).map_err(TrainingError::Validation)?;
        }
        runs.push(SeedRun { settings, dir });
    }
    Ok(runs)
}

/// What [`train_seeds`] tells as it goes; the command shows it (bars,
/// lines for a parent process, or nothing).
pub trait Report {
    /// Collecting the `what` (training or validation) pairs of `runs`
    /// runs begins.
    fn collecting(&mut self, what: &str, runs: usize);
    /// `run` of `runs` collected, `examples` pairs so far.
    fn collected(&mut self, run: usize, runs: usize, examples: usize);
    /// The collection ended.
    fn collected_all(&mut self);
    /// The training data: `examples` pairs from `runs` runs.
    fn training_data(&mut self, examples: usize, runs: usize);
    /// Training `method` begins.
    fn training(&mut self, method: Method);
    /// Its step `step` of `total`, at `loss`.
    fn step(&mut self, step: usize, total: usize, loss: f32);
    /// Its epoch `epoch` ended, with these losses.
    fn epoch(&mut self, epoch: usize, train_loss: f64, validation_loss: Option<f64>);
    /// It is trained and written.
    fn trained(&mut self, model: &Trained);
}

/// A [`Report`] as the training loop's progress.
struct Steps<'a, R>(&'a mut R);

impl<R: Report> TrainProgress for Steps<'_, R> {
    fn step(&mut self, step: usize, total: usize, loss: f32) {
        self.0.step(step, total, loss);
    }

    fn epoch(&mut self, epoch: usize, train_loss: f64, validation_loss: Option<f64>) {
        self.0.epoch(epoch, train_loss, validation_loss);
    }
}

/// A method trained and written into its models folder.
pub struct Trained {
    pub method: Method,
    pub seconds: f64,
    pub steps: usize,
    /// The epoch whose weights were kept (early stopping).
    pub best_epoch: Option<usize>,
    pub weights: PathBuf,
    pub loss_curve: PathBuf,
}

/// Collects the data once and trains `methods` with every seed of `seeds`
/// one after another in this process, writing each model (without its
/// choices) into its seed's folder. The data does not depend on the
/// training seed.
pub fn train_seeds(
    seeds: &[SeedRun],
    methods: &[Method],
    warnings: &Warnings,
    report: &mut impl Report,
) -> Result<(), TrainingError> {
    let Some(first) = seeds.first() else {
        return Ok(());
    };
    let settings = &first.settings;
    let training = experiments::training_runs(settings)?;
    let examples = collect(&training, "training", warnings, report)?;
    report.training_data(examples.len(), training.len());
    // The validation runs' pairs, for early stopping only.
    let validation = if settings.train.patience == 0 {
        Vec::new()
    } else {
        let runs = experiments::validation_loss_runs(settings)?;
        collect(&runs, "validation", warnings, report)?
    };
    for s in seeds {
        for &method in methods {
            let model = train_one(
                &s.settings,
                method,
                (&examples, &validation),
                &s.dir,
                report,
            )?;
            report.trained(&model);
        }
    }
    Ok(())
}

/// The labelled pairs of `runs` (`what`: training or validation).
fn collect(
    runs: &[Settings],
    what: &'static str,
    warnings: &Warnings,
    report: &mut impl Report,
) -> Result<Vec<Example>, TrainingError> {
    report.collecting(what, runs.len());
    let examples = experiments::collect_examples(runs, warnings, |k, n_runs, n| {
        report.collected(k, n_runs, n);
    })
    .map_err(|source| TrainingError::Collect { what, source })?;
    report.collected_all();
    Ok(examples)
}

/// The bytes of the weights `[train] start_from` holds for `method`
/// (`None`: a seeded start), checked to read what this training reads.
fn start_weights(settings: &Settings, method: Method) -> Result<Option<Vec<u8>>, String> {
    let Some(dir) = &settings.train.start_from else {
        return Ok(None);
    };
    let w = io::read_weights(dir, method).map_err(|e| format!("[train] start_from: {e}"))?;
    let width = settings.appearance_width();
    if w.appearance_width != width {
        return Err(format!(
            "[train] start_from: the weights of '{}' in {} read appearance vectors {} wide, \
             this training {}",
            method.as_str(),
            dir.display(),
            w.appearance_width.get(),
            width.get()
        ));
    }
    Ok(Some(w.bytes))
}

/// Trains `method` and writes its weights, record and loss curve into
/// `models_dir`.
fn train_one(
    settings: &Settings,
    method: Method,
    (examples, validation): (&[Example], &[Example]),
    models_dir: &Path,
    report: &mut impl Report,
) -> Result<Trained, TrainingError> {
    let started = std::time::Instant::now();
    report.training(method);
    let fail = |reason| TrainingError::Train {
        method: method.as_str(),
        reason,
    };
    let start = start_weights(settings, method).map_err(fail)?;
    let (weights, train_report) = experiments::train_method(
        settings,
        method,
        (examples, validation),
        start.as_deref(),
        &mut Steps(report),
    )
    .map_err(fail)?;
    let record = TrainingRecord {
        method,
        settings,
        n_examples: examples.len(),
        report: &train_report,
        seconds: started.elapsed().as_secs_f64(),
        start: start.as_deref(),
    };
    io::write_model(models_dir, &record, &weights)?;
    Ok(Trained {
        method,
        seconds: record.seconds,
        steps: train_report.steps,
        best_epoch: train_report.best_epoch,
        weights: io::weights_path(models_dir, method),
        loss_curve: models_dir.join(format!("{}_loss.csv", method.as_str())),
    })
}

/// The methods and seeds one child `coid train` trains.
pub struct ChildGroup {
    pub methods: Vec<Method>,
    /// Its seeds (none: `[train] seed`).
    pub seeds: Vec<u64>,
}

/// `methods` and `seeds` in `workers` groups: method k in group k mod
/// workers, with every seed; or, with fewer methods than workers, seed k
/// in group k mod workers, with every method.
pub fn child_groups(methods: &[Method], seeds: &[u64], workers: usize) -> Vec<ChildGroup> {
    (0..workers)
        .map(|g| {
            if methods.len() >= workers {
                ChildGroup {
                    methods: every(methods, g, workers),
                    seeds: seeds.to_vec(),
                }
            } else {
                ChildGroup {
                    methods: methods.to_vec(),
                    seeds: every(seeds, g, workers),
                }
            }
        })
        .collect()
}

/// Every `n`-th item of `items` from the `k`-th.
fn every<T: Copy>(items: &[T], k: usize, n: usize) -> Vec<T> {
    items.iter().copied().skip(k).step_by(n).collect()
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

/// The arguments of the child `coid train` of `config` that trains
/// `group` into `models_dir`, reporting [`ChildMessage`]s.
fn child_args(source: TrainSource, models_dir: &Path, group: &ChildGroup) -> Vec<OsString> {
    let mut args: Vec<OsString> = vec!["train".into(), "--config".into(), source.config.into()];
    if let Some(d) = source.dataset {
        args.extend(["--dataset".into(), d.into()]);
    }
    if let Some(r) = source.reid_rank1 {
        args.extend(["--reid-rank1".into(), r.to_string().into()]);
    }
    if source.without_descriptor {
        args.push("--without-descriptor".into());
    }
    args.extend(["--out".into(), models_dir.into()]);
    args.extend(["--methods".into(), labels(&group.methods).join(",").into()]);
    if !group.seeds.is_empty() {
        args.extend(["--seed".into(), seed_list(&group.seeds, ",").into()]);
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

/// Trains `groups` in child `coid train` processes of `program` (`workers`
/// at a time) from `config` into `models_dir`: `on_line(group, line)`
/// receives each line a child prints, `on_end(group)` is called as each
/// ends. The first group that failed is the error.
pub fn train_in_children(
    program: &batch::Program,
    (source, models_dir): (TrainSource, &Path),
    groups: &[ChildGroup],
    workers: usize,
    on_line: impl FnMut(usize, &str),
    mut on_end: impl FnMut(usize),
) -> Result<(), TrainingError> {
    let jobs: Vec<Vec<OsString>> = groups
        .iter()
        .map(|g| child_args(source, models_dir, g))
        .collect();
    let failures = batch::run_children(program, &jobs, workers, on_line, |child, ok| {
        on_end(child);
        ok
    })
    .map_err(TrainingError::Start)?;
    if let Some(f) = failures.first() {
        let g = &groups[f.run];
        let seeds = if g.seeds.is_empty() {
            String::new()
        } else {
            format!(" (seeds {})", seed_list(&g.seeds, ", "))
        };
        return Err(TrainingError::Child {
            group: labels(&g.methods).join(", "),
            seeds,
            message: f.message.clone(),
        });
    }
    Ok(())
}

/// Chooses each of `methods`' temperature, decision rule and lambda on
/// the validation runs of `settings` with the weights of `models_dir`
/// (`progress` after each run), and records them beside its weights.
pub fn validate(
    settings: &Settings,
    models_dir: &Path,
    methods: &[Method],
    (threads, warnings): (usize, &Warnings),
    progress: impl FnMut(usize, usize),
) -> Result<Vec<(Method, Chosen)>, TrainingError> {
    let on_models = settings.with_models(models_dir);
    let chosen = experiments::validate(&on_models, methods, threads, warnings, progress)
        .map_err(TrainingError::Validation)?;
    let mut out = Vec::with_capacity(methods.len());
    for &method in methods {
        let c = chosen[&method];
        let validation = io::Validation {
            lambda: c.lambda,
            decision: c.decision,
            min_probability: c.min_probability,
            temperature: c.temperature,
            f1: c.f1,
            seeds: settings.train.validation_seeds.clone(),
            uncertainty: settings.matching.uncertainty.as_str(),
            lambdas: c.lambdas,
        };
        io::record_validation(models_dir, method, &validation)?;
        out.push((method, c));
    }
    Ok(out)
}

/// Chooses the thresholds of `baselines` on the validation runs of
/// `settings` (`progress(pass, passes)`) and records them in the models
/// folder's `baselines.toml`.
pub fn tune_baselines(
    settings: &Settings,
    models_dir: &Path,
    baselines: &[Method],
    (threads, warnings): (usize, &Warnings),
    progress: impl FnMut(usize, usize),
) -> Result<Vec<TunedBaseline>, TrainingError> {
    let only = settings.with_methods(baselines);
    let tuned = experiments::tune_baselines(&only, threads, warnings, progress)
        .map_err(TrainingError::Validation)?;
    let entries: Vec<io::BaselineEntry> = tuned
        .iter()
        .map(|t| io::BaselineEntry {
            method: t.method,
            parameter: t.parameter.to_owned(),
            value: t.value,
            descriptor_weight: t.descriptor_weight,
            f1: t.f1,
            a_priori: t.a_priori,
            f1_a_priori: t.f1_a_priori,
            note: t.note.clone(),
        })
        .collect();
    io::record_baselines(models_dir, settings, &entries)?;
    Ok(tuned)
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
            let line = m.line().unwrap();
            assert!(!line.contains('\n'), "{line}");
            assert_eq!(ChildMessage::parse(&line).unwrap(), m);
        }
        let line = ChildMessage::Collect { run: 1, runs: 2 }.line().unwrap();
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

    /// Methods are dealt to the groups in turn, each with every seed; with
    /// fewer methods than workers, seeds are, each with every method; each
    /// child is told its group, its seeds and to report lines.
    #[test]
    fn groups_deal_methods_or_seeds_to_the_children() {
        let methods = [Method::Ours, Method::Dgmc, Method::GcnGm];
        let g = child_groups(&methods, &[7, 8], 2);
        assert_eq!(g[0].methods, [Method::Ours, Method::GcnGm]);
        assert_eq!(
            (g[1].methods.as_slice(), g[1].seeds.as_slice()),
            (&[Method::Dgmc][..], &[7, 8][..])
        );
        let g = child_groups(&methods[..1], &[7, 8, 9], 2);
        assert_eq!(
            (g[0].seeds.as_slice(), g[1].seeds.as_slice()),
            (&[7, 9][..], &[8][..])
        );
        assert!(g.iter().all(|g| g.methods == [Method::Ours]));
        let source = TrainSource {
            config: Path::new("c.toml"),
            dataset: None,
            reid_rank1: None,
            without_descriptor: false,
        };
        let args = child_args(source, Path::new("m"), &g[1]);
        let args: Vec<&str> = args.iter().map(|a| a.to_str().unwrap()).collect();
        assert_eq!(
            args,
            [
                "train",
                "--config",
                "c.toml",
                "--out",
                "m",
                "--methods",
                "ours",
                "--seed",
                "8",
                "--workers",
                "1",
                "--force",
                "--skip-validation",
                "--progress-lines"
            ]
        );
        // The candidate without the descriptor: the children train it.
        let without = TrainSource {
            without_descriptor: true,
            ..source
        };
        let args = child_args(without, Path::new("m"), &g[1]);
        assert!(args.iter().any(|a| a == "--without-descriptor"), "{args:?}");
    }
}
