//! `coid train`: its arguments parsed, `commands::train` called, its
//! progress shown ([`TrainBars`]). Several methods train at once in child
//! `coid train` processes, which report their progress to this one as
//! messages on stdout ([`ChildMessage`]: one JSON object a line).

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{ConfigArg, ForceArg, OutArg, QuietArg, WorkersArg, label_arg, progress_bar};
use crate::commands::{self, TrainView};
use crate::matching::Method;
use crate::training::{self, ChildMessage, Trained};

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

pub fn train(a: Args) -> anyhow::Result<()> {
    let request = commands::TrainRequest {
        config: a.config.config.clone(),
        out: a.out.out.clone(),
        force: a.force.force,
        methods: a.methods.clone(),
        workers: a.workers.workers,
        skip_validation: a.skip_validation,
        validate_only: a.validate_only,
        seeds: a.seed.clone(),
        dataset: a.dataset.clone(),
        reid_rank1: a.reid_rank1,
        without_descriptor: a.without_descriptor,
    };
    let show = match (a.progress_lines, a.quiet.quiet) {
        (true, _) => Show::Lines,
        (false, true) => Show::Quiet,
        (false, false) => Show::Bars,
    };
    let mut view = TrainBars::new(show);
    let report = commands::train(&request, &mut view);
    view.clear();
    if let Some(line) = report?.line.filter(|_| show != Show::Lines) {
        eprintln!("{line}");
    }
    Ok(())
}

/// How `coid train` shows a training: progress bars and lines on stderr
/// (only the lines when quiet), or, in a child process, messages on
/// stdout for its parent.
pub struct TrainBars {
    show: Show,
    shown: Shown,
    children: Option<ChildBars>,
    /// The bar over a validation or tuning pass, and which.
    pass: Option<(bool, ProgressBar)>,
}

impl TrainBars {
    fn new(show: Show) -> Self {
        Self {
            show,
            shown: Shown::new(show),
            children: None,
            pass: None,
        }
    }

    /// Bars and lines on stderr; only the lines when `quiet`.
    pub fn on_stderr(quiet: bool) -> Self {
        Self::new(if quiet { Show::Quiet } else { Show::Bars })
    }

    /// Clears every bar (the training ended, well or not).
    pub fn clear(&mut self) {
        self.shown.pb.finish_and_clear();
        if let Some((_, pb)) = self.pass.take() {
            pb.finish_and_clear();
        }
        if let Some(c) = self.children.take() {
            for k in 0..c.child.len() {
                c.finish(k);
            }
        }
    }

    /// The pass bar, made for validation (`validating`) or tuning.
    fn pass_bar(&mut self, validating: bool, total: usize) -> &ProgressBar {
        if self.pass.as_ref().is_none_or(|(v, _)| *v != validating) {
            let template = if validating {
                "{spinner} choosing temperature, decision and lambda on the validation runs: run {pos}/{len} [{bar:30}] eta {eta}"
            } else {
                "{spinner} choosing the baselines' thresholds on the validation runs: value {pos}/{len} [{bar:30}] eta {eta}"
            };
            let pb = progress_bar(self.show != Show::Bars, total as u64, template);
            self.pass = Some((validating, pb));
        }
        let (_, pb) = self.pass.as_ref().expect("made above");
        pb.set_length(total as u64);
        pb
    }
}

impl training::Report for TrainBars {
    fn collecting(&mut self, what: &str, runs: usize) {
        self.shown.collecting(what, runs);
    }
    fn collected(&mut self, run: usize, runs: usize, examples: usize) {
        self.shown.collected(run, runs, examples);
    }
    fn collected_all(&mut self) {
        self.shown.collected_all();
    }
    fn training_data(&mut self, examples: usize, runs: usize) {
        self.shown.training_data(examples, runs);
    }
    fn training(&mut self, method: Method) {
        self.shown.training(method);
    }
    fn step(&mut self, step: usize, total: usize, loss: f32) {
        self.shown.step(step, total, loss);
    }
    fn epoch(&mut self, epoch: usize, train_loss: f64, validation_loss: Option<f64>) {
        self.shown.epoch(epoch, train_loss, validation_loss);
    }
    fn trained(&mut self, model: &Trained) {
        self.shown.trained(model);
    }
}

impl TrainView for TrainBars {
    fn note(&mut self, text: &str) {
        match &self.children {
            Some(c) => c.note(text),
            None => self.show.note(text),
        }
    }

    fn validating(&mut self, done: usize, total: usize) {
        self.pass_bar(true, total).set_position(done as u64);
    }

    fn tuning(&mut self, done: usize, total: usize) {
        self.pass_bar(false, total).set_position(done as u64);
    }

    fn passed(&mut self) {
        if let Some((_, pb)) = self.pass.take() {
            pb.finish_and_clear();
        }
    }

    fn children(&mut self, n: usize) {
        self.children = Some(ChildBars::new(n, self.show != Show::Bars));
    }

    fn child_line(&mut self, k: usize, line: &str) {
        if let Some(c) = &self.children {
            c.show(k, line);
        }
    }

    fn child_done(&mut self, k: usize) {
        if let Some(c) = &self.children {
            c.finish(k);
        }
    }
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
