//! The `coid` command line (clap): the command tree, the argument groups
//! commands share, and one file per command. Commands turn arguments into
//! settings, drive the library with progress bars, and print a one-line
//! summary; `main` maps errors to one line and an exit code.

mod batch;
mod eval;
mod render;
mod run;
mod scenarios;
mod train;

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use crate::label::{self, Label};

#[derive(Parser)]
#[command(
    name = "coid",
    version,
    about = "Correspondence identification and fusion for connected vehicles at a SUMO intersection",
    long_about = "coid-sim runs a SUMO intersection headless, derives each connected vehicle's camera \
detections (occlusion, noise, misses, false positives, GPS pose error), matches the detections of \
every pair of connected vehicles, fuses the matched measurements and reports precision, recall, F1 \
and displacement error, single-vehicle vs fused, per method, pose-noise level and fusion variant."
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run one scenario headless and write summary.csv, objects.parquet and summary.md.
    Run(run::Args),
    /// Run a Monte Carlo batch: N runs with seeds derived from one master
    /// seed, on W worker processes, resumable (run the same command again to
    /// finish a killed batch), aggregated into <out>/summary.csv with 95%
    /// confidence intervals. Each run keeps its own folder in <out>/runs/.
    Batch(batch::Args),
    /// Combine batch shard folders into one aggregate, identical to the
    /// unsharded batch's.
    Merge(batch::MergeArgs),
    /// Draw chosen instances top-down (PNG and SVG): roads, buildings, road
    /// users, camera frustums, detections and the correspondences of one
    /// method (green right, red wrong, thicker = more uncertain).
    Render(render::Args),
    /// Evaluate every method on the test runs ([eval] traffic_seeds) and write
    /// the paper's tables: table1.csv (P/R/F1 per method and pose noise),
    /// table2.csv (F1 before/after uncertainty thresholding), table3.csv
    /// (uncertainty types), lambda_sweep.csv, case_study.csv,
    /// calibration.csv; means with 95% confidence intervals over runs. With
    /// [eval] scenarios or --suite: per scenario and pooled.
    Eval(eval::Args),
    /// Train the deep matchers on instances from the training runs
    /// ([train] traffic_seeds, and [train] scenarios) and save their weights,
    /// config and loss curve; then choose each one's calibration
    /// temperature, decision rule and lambda on the validation runs.
    Train(train::Args),
    /// Generate a seeded family of junctions with SUMO's netconvert
    /// (crossings of 3-5 legs, arterials with turn pockets, joined junction
    /// clusters, roundabouts, motorway merges; building blocks or none;
    /// light to saturated demand, pedestrians), one folder each with a
    /// coid.toml that runs as it is; the same seed gives the same bytes.
    Scenarios(scenarios::Args),
}

/// Runs the parsed command.
pub fn execute(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Run(a) => run::run(a),
        Command::Batch(a) => batch::batch(a),
        Command::Merge(a) => batch::merge(a),
        Command::Render(a) => render::render(a),
        Command::Eval(a) => eval::eval(a),
        Command::Train(a) => train::train(a),
        Command::Scenarios(a) => scenarios::scenarios(a),
    }
}

/// The configuration file, for every command that reads one.
#[derive(clap::Args)]
struct ConfigArg {
    /// Configuration file (TOML): only what differs from
    /// configs/default.toml; relative paths inside it resolve against its
    /// folder.
    #[arg(long, short, default_value = "configs/default.toml")]
    config: PathBuf,
}

/// Threads inside one run.
#[derive(clap::Args)]
struct ThreadsArg {
    /// Threads that evaluate a run's steps while SUMO advances; the
    /// results do not depend on it [default: the number of cores].
    #[arg(long)]
    threads: Option<std::num::NonZeroUsize>,
}

impl ThreadsArg {
    fn get(&self) -> usize {
        self.threads.map_or_else(cores, std::num::NonZeroUsize::get)
    }
}

/// The cores this process may use.
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
}

/// What `run`, `eval` and `render` share: a config, a results folder, a
/// progress bar.
#[derive(clap::Args)]
struct CommonArgs {
    #[command(flatten)]
    config: ConfigArg,
    /// Output folder [default: results/<config file stem>, plus -eval or
    /// -render for those commands].
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Replace the output folder if it exists (the old one is removed only
    /// after the new one is complete).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    quiet: QuietArg,
}

impl CommonArgs {
    /// The settings, and the results folder (`results/<stem><suffix>` by
    /// default), refused when it exists and `--force` was not given.
    fn prepare(&self, suffix: &str) -> anyhow::Result<(crate::config::Settings, PathBuf)> {
        let config = &self.config.config;
        let settings = crate::config::Settings::load(config)?;
        let out = out_dir(self.out.clone(), config, suffix);
        if out.exists() && !self.force {
            return Err(crate::io::OutputError::Exists(out).into());
        }
        Ok((settings, out))
    }

    /// A progress bar over the simulated time of one run.
    fn sim_bar(&self, end_s: f64) -> ProgressBar {
        progress_bar(
            self.quiet.quiet,
            (end_s * 10.0).round() as u64,
            "{spinner} SUMO t = {msg} [{bar:30}] {percent:>3}% elapsed {elapsed} eta {eta}",
        )
    }
}

/// Shows a simulation's progress on a bar made by [`CommonArgs::sim_bar`].
fn show_sim_progress(bar: &ProgressBar, p: crate::pipeline::Progress) {
    bar.set_position((p.time_s * 10.0).round() as u64);
    bar.set_message(format!("{:6.1} s, {} instances", p.time_s, p.instances));
}

/// No progress bar.
#[derive(clap::Args)]
struct QuietArg {
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

/// The results folder of a command: `--out`, else
/// `results/<config file stem><suffix>`.
fn out_dir(out: Option<PathBuf>, config: &Path, suffix: &str) -> PathBuf {
    out.unwrap_or_else(|| {
        let stem = config
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "run".into());
        PathBuf::from("results").join(format!("{stem}{suffix}"))
    })
}

/// A progress bar with `template`, hidden when `quiet`.
fn progress_bar(quiet: bool, len: u64, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

/// A clap parser for a labelled enum: the labels are its possible values
/// (listed in `--help`).
fn label_arg<T: Label + Clone + Send + Sync>(
    what: &'static str,
) -> impl clap::builder::TypedValueParser<Value = T> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(T::VARIANTS)
        .try_map(move |s: String| label::parse::<T>(what, &s))
}
