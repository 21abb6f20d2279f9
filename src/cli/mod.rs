//! The `coid` command line (clap): the command tree, the argument groups
//! commands share, and one file per command. Commands turn arguments into
//! settings, drive the library with progress bars, and print a one-line
//! summary; `main` maps errors to one line and an exit code.

mod batch;
mod dataset;
mod detector;
mod eval;
mod export;
mod progress;
mod render;
mod run;
mod scenarios;
mod track;
mod train;

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use crate::label::{self, Label};

pub use export::{print_export, print_score};
pub use progress::Bars;
pub use run::print_report;
pub use train::TrainBars;

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
    /// Run one scenario headless. Writes into --out: summary.csv (P/R/F1
    /// and displacement errors per method, pose noise and fusion),
    /// objects.parquet (every (ego, object) estimate), summary.md.
    Run(run::Args),
    /// Run a Monte Carlo batch: N runs with seeds derived from one master
    /// seed, on W worker processes, resumable (run the same command again to
    /// finish a killed batch), aggregated with 95% confidence intervals.
    /// Writes into --out: batch.toml (what the batch is), runs/run-NNNNNN/
    /// (each run's folder, as `coid run` writes it), summary.csv,
    /// summary.md, f1_per_method.png and .svg.
    Batch(batch::Args),
    /// Combine batch shard folders into one aggregate, identical to the
    /// unsharded batch's. Writes into --out what `coid batch` writes.
    Merge(batch::MergeArgs),
    /// One run of a batch, from the batch's record (what `coid batch`
    /// starts in each worker process).
    #[command(hide = true)]
    BatchRun(batch::RunArgs),
    /// Draw chosen instances top-down: roads, buildings, road users, camera
    /// frustums, detections and the correspondences of one method (green
    /// right, red wrong, thicker = more uncertain). Writes into --out:
    /// instance-NNNN.png and .svg per instance.
    Render(render::Args),
    /// Evaluate the configured methods ([matching] methods) on the test
    /// runs ([eval] traffic_seeds) and
    /// write the paper's tables, means with 95% confidence intervals over
    /// runs. Writes into --out: table1.csv (P/R/F1 per method and pose
    /// noise, the methods that see the paper's inputs only), table1b.csv
    /// (the methods that see the reported poses too), paired.csv (each
    /// method minus the strongest baseline seeing the same inputs, run by
    /// run), table2.csv (F1 before/after uncertainty thresholding),
    /// table3.csv (uncertainty types), lambda_sweep.csv, case_study.csv
    /// (displacement errors), errors.csv (every method's displacement
    /// errors), calibration.csv, precision_recall.csv (average precision
    /// of every method), pr_curve.csv, consistency.csv, views.csv,
    /// summary.md, and pictures (f1_per_method, lambda_sweep, error_cdf,
    /// pr_curve, reliability_<method>; PNG and SVG). With [eval] scenarios or
    /// --suite: one such folder per scenario, and pooled/.
    Eval(eval::Args),
    /// Write every instance of the configuration as Parquet for a matcher
    /// written elsewhere (Python, PyTorch Geometric): both vehicles' nodes
    /// (ego-frame positions, covariances, appearance, sender flag), the
    /// reported poses per pose-noise level, Delaunay edges, the truth and
    /// the true pairs, and the split of each run. Writes into --out:
    /// runs.parquet, instances.parquet, nodes.parquet, edges.parquet,
    /// truth.parquet, true_pairs.parquet, matches-<method>.parquet (with
    /// --with-matches), schema.md (the columns, versioned).
    Export(export::ExportArgs),
    /// Evaluate correspondences made elsewhere (`--matches FILE`, for the
    /// runs of `coid export`) beside the configured built-in methods, as
    /// method `external`, on the test (or validation) runs. Writes into
    /// --out what `coid eval` writes: table1.csv, table1b.csv, errors.csv (displacement
    /// errors of every method, both fusion variants, common object set),
    /// calibration.csv, precision_recall.csv, pr_curve.csv,
    /// consistency.csv, views.csv, the deep methods' tables, summary.md and
    /// pictures.
    Score(export::ScoreArgs),
    /// Convert correspondence data recorded elsewhere into a coid dataset
    /// (PyTorch Geometric pairs as DMGM distributes them: `convert pyg`).
    Convert(dataset::ConvertArgs),
    /// Check a dataset folder (coid export or convert) and say what it
    /// holds: runs and instances per split, nodes, true pairs, appearance.
    Dataset(dataset::DatasetArgs),
    /// Track over one run, as V2X delivers it ([v2x]): every connected
    /// vehicle near the junction tracks its own detections at every SUMO
    /// step ([v2x] step_length_s; constant-velocity Kalman filter) and
    /// generates Collective Perception Messages from its confirmed tracks
    /// ([v2x.cpm], ETSI TS 103 324's rules), sent to its linked peers over
    /// a channel with latency and loss ([v2x.channel]). The trackers are
    /// scored against what their cameras could see (CLEAR-MOT). Each
    /// receiver extrapolates what arrives to its own time, matches it
    /// against its own tracks ([v2x] matcher) and carries the association
    /// across messages ([v2x.association]). Writes into --out:
    /// tracking.csv (per vehicle and all: misses, false tracks, id
    /// switches, MOTA, MOTP, messages, objects sent, deliveries, losses,
    /// mean latency), association.csv (per message and over time: pair
    /// P/R/F1, share of time right, time to first right, switches,
    /// displacement errors single, fused, fused by covariance
    /// intersection).
    Track(track::Args),
    /// Measure the configured detector profile ([detector]) on the
    /// validation runs ([train] validation_seeds and validation_scenarios):
    /// per range bin, the recall of every visible and of every fully
    /// visible object, the mean translation error, the NEES of the
    /// covariance each detection reports (2 if it were the truth) and the
    /// share beyond chi2's 99.9 %, and false positives per sensor frame,
    /// beside the figures the profile was configured with. Writes into
    /// --out: detector.csv; prints it as a table.
    Detector(detector::Args),
    /// Train the deep matchers on instances from the training runs
    /// ([train] traffic_seeds, and [train] scenarios), then choose each
    /// one's calibration temperature, decision rule and lambda on the
    /// validation runs. Writes into --out: <method>.bpk (weights),
    /// <method>.toml (its record), <method>_loss.csv (loss per epoch).
    Train(train::Args),
    /// Generate a seeded family of junctions with SUMO's netconvert
    /// (crossings of 3-5 legs, arterials with turn pockets, joined junction
    /// clusters, roundabouts, motorway merges; building blocks or none;
    /// light to saturated demand, pedestrians); the same seed gives the
    /// same bytes. Writes into --out: one folder per scenario (net, its
    /// plain sources, buildings, demand, .sumocfg, a coid.toml that runs
    /// as it is, README.md) and README.md (the family).
    Scenarios(scenarios::Args),
    /// Print a shell completion script for coid to stdout (e.g. `coid
    /// completions bash > ~/.local/share/bash-completion/completions/coid`).
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
}

/// Prepares a process that runs coid as its main program (the binary,
/// `python -m coid_sim`), first thing, while it has one thread: its
/// signals, and the embedded interpreter's home.
pub fn prepare_main_process() {
    crate::bridge::prepare_process();
}

/// Runs the parsed command; returns the line it printed last on stderr
/// for `run` (instances, speed and the headline methods), `export` and
/// `score` (ending with the folder written).
pub fn execute(cli: Cli) -> anyhow::Result<Option<String>> {
    report_panics_in_one_line();
    // The default scenario and the shipped weights, where the defaults
    // point (written out once per build).
    if !matches!(cli.command, Command::Completions { .. }) {
        crate::io::assets::install()?;
    }
    match cli.command {
        Command::Run(a) => return run::run(a).map(Some),
        Command::Batch(a) => batch::batch(a),
        Command::Merge(a) => batch::merge(a),
        Command::BatchRun(a) => batch::run_one(a),
        Command::Render(a) => render::render(a),
        Command::Eval(a) => eval::eval(a),
        Command::Export(a) => return export::export(a).map(Some),
        Command::Score(a) => return export::score(a).map(Some),
        Command::Convert(a) => dataset::convert(a),
        Command::Dataset(a) => dataset::dataset(a),
        Command::Track(a) => track::track(a),
        Command::Detector(a) => detector::detector(a),
        Command::Train(a) => train::train(a),
        Command::Scenarios(a) => scenarios::scenarios(a),
        Command::Completions { shell } => {
            use clap::CommandFactory;
            let mut cmd = Cli::command();
            clap_complete::generate(shell, &mut cmd, "coid", &mut std::io::stdout());
            Ok(())
        }
    }
    .map(|()| None)
}

/// Asks the command running in this process to stop (the embedding
/// interpreter was interrupted): it ends at its next SUMO step with an
/// error, its temporary folders removed.
pub fn request_stop() {
    crate::interrupt::request_stop();
}

/// Lets the next command run (after [`request_stop`]).
pub fn clear_stop() {
    crate::interrupt::clear_stop();
}

/// `argv` (the program's name first) parsed as the `coid` binary parses
/// its command line; clap's error (usage, help and version too) if not.
pub fn try_parse<I, T>(argv: I) -> Result<Cli, clap::Error>
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    use clap::Parser;
    Cli::try_parse_from(argv)
}

/// An error as the one line `coid` prints: the cause chain joined by
/// ": ", a cause that an outer message already quotes left out.
pub fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain().map(|c| c.to_string()) {
        if !line.contains(&cause) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&cause);
        }
    }
    line
}

/// A panic (a bug in coid) is reported as one line, like any other
/// error, saying where and asking for a report; the process still ends
/// as a panic does (exit code 101), with its temporary folders removed.
pub fn report_panics_in_one_line() {
    std::panic::set_hook(Box::new(|info| {
        let what = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown cause".into());
        let at = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        let what = what.split_whitespace().collect::<Vec<_>>().join(" ");
        eprintln!("error: internal error (a bug in coid, please report it): {what}{at}");
    }));
}

/// The configuration file, for every command that reads one.
#[derive(clap::Args)]
struct ConfigArg {
    /// Configuration file (TOML): only what differs from the defaults
    /// (configs/default.toml, compiled in); relative paths inside it
    /// resolve against its folder [default: the defaults alone: the
    /// default intersection with the shipped weights].
    #[arg(long, short)]
    config: Option<PathBuf>,
}

impl ConfigArg {
    /// The file to read: `--config`, else the defaults as this build
    /// wrote them out (named `default.toml`).
    fn path(&self) -> PathBuf {
        self.source().path()
    }

    /// The configuration as the library's commands take it.
    fn source(&self) -> crate::commands::ConfigSource {
        crate::commands::ConfigSource::from(self.config.clone())
    }
}

/// The output folder, for every command whose folder has a default.
#[derive(clap::Args)]
struct OutArg {
    /// Output folder [default: results/<config file stem> plus the
    /// command's suffix: -eval, -render, -batch, -models, -export, ...].
    #[arg(long, short)]
    out: Option<PathBuf>,
}

/// `--force`, for every command that writes a folder.
#[derive(clap::Args)]
struct ForceArg {
    /// Replace the output folder (or, for train and scenarios, write into
    /// it) if coid wrote it for this command and it did not change; the
    /// old folder is removed only after the new one is complete.
    #[arg(long)]
    force: bool,
}

/// Worker processes, for `batch` and `train`.
#[derive(clap::Args)]
struct WorkersArg {
    /// Worker processes, 1 to 1024: runs (batch) or groups of methods
    /// (train) at once, each in its own process; the results do not
    /// depend on it [default: the number of cores].
    #[arg(long, short, value_parser = in_range(1, MAX_PARALLEL))]
    workers: Option<usize>,
}

/// Threads inside one run.
#[derive(clap::Args, Default)]
struct ThreadsArg {
    /// Threads that evaluate a run's steps while SUMO advances (1 to
    /// 1024); the results do not depend on it [default: the number of
    /// cores; in a batch, shared among its workers].
    #[arg(long, value_parser = in_range(1, MAX_PARALLEL))]
    threads: Option<usize>,
}

impl ThreadsArg {
    fn get(&self) -> usize {
        self.threads.unwrap_or_else(cores)
    }
}

use crate::commands::{MAX_PARALLEL, cores};

/// A clap parser for a count in `min..=max`.
fn in_range(min: usize, max: usize) -> impl Fn(&str) -> Result<usize, String> + Clone {
    move |s: &str| match s.parse::<usize>() {
        Ok(n) if (min..=max).contains(&n) => Ok(n),
        Ok(n) => Err(format!("{n} is not in {min}..={max}")),
        Err(e) => Err(e.to_string()),
    }
}

/// What `run`, `eval` and `render` share: a config, a results folder, a
/// progress bar.
#[derive(clap::Args)]
struct CommonArgs {
    #[command(flatten)]
    config: ConfigArg,
    #[command(flatten)]
    out: OutArg,
    #[command(flatten)]
    force: ForceArg,
    #[command(flatten)]
    quiet: QuietArg,
}

impl CommonArgs {
    /// The settings, and the results folder (`results/<stem><suffix>` by
    /// default) claimed for a folder of `kind`: refused when something is
    /// there that `--force` does not allow to replace.
    fn prepare(
        &self,
        suffix: &str,
        kind: crate::io::ResultKind,
    ) -> anyhow::Result<(crate::config::Settings, crate::io::Claim)> {
        self.prepare_with(suffix, kind, &crate::config::Overrides::default())
    }

    /// [`CommonArgs::prepare`] with command-line `overrides` set over the
    /// config before it is validated.
    fn prepare_with(
        &self,
        suffix: &str,
        kind: crate::io::ResultKind,
        overrides: &crate::config::Overrides,
    ) -> anyhow::Result<(crate::config::Settings, crate::io::Claim)> {
        let config = self.config.path();
        let settings = crate::config::Settings::load_with(&config, overrides)?;
        let settings = calibrated(&settings, self.quiet.quiet)?;
        let out = out_dir(self.out.out.clone(), &config, suffix);
        let claim = crate::io::Claim::new(&out, kind, crate::io::Existing::when(self.force.force))?;
        Ok((settings, claim))
    }

    /// What the library's commands take of these arguments, with
    /// `threads`.
    fn common(&self, threads: &ThreadsArg) -> crate::commands::Common {
        crate::commands::Common {
            config: self.config.source(),
            out: self.out.out.clone(),
            force: self.force.force,
            threads: threads.threads,
        }
    }

    /// A progress bar over the simulated time of one run.
    fn sim_bar(&self, end_s: f64) -> ProgressBar {
        progress_bar(
            self.quiet.quiet,
            (end_s * 10.0).round() as u64,
            SIM_TEMPLATE,
        )
    }
}

/// `settings` with the re-identification descriptor calibrated when the
/// config asks for one (`[appearance] descriptor = "reid"`) on the
/// validation runs, with a progress bar, saying what it measured; as they
/// are otherwise.
pub(crate) fn calibrated(
    settings: &crate::config::Settings,
    quiet: bool,
) -> anyhow::Result<crate::config::Settings> {
    if !settings.appearance.uncalibrated() || settings.dataset.is_some() {
        return Ok(settings.clone());
    }
    let pb = progress_bar(quiet, 0, CALIBRATION_TEMPLATE);
    let mut runs = 0;
    let settings = crate::experiments::calibrated(settings, |done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
        runs = total;
    })?;
    pb.finish_and_clear();
    if let Some(r) = &settings.appearance.reid
        && let Some(line) = calibration_line(r, runs)
        && !quiet
    {
        eprintln!("{line}");
    }
    Ok(settings)
}

/// The bar of a descriptor's calibration over the validation runs.
const CALIBRATION_TEMPLATE: &str = "{spinner} calibrating the re-identification descriptor: \
     validation run {pos}/{len} [{bar:30}] eta {eta}";

/// The bar over a run's simulated time.
const SIM_TEMPLATE: &str =
    "{spinner} SUMO t = {msg} [{bar:30}] {percent:>3}% elapsed {elapsed} eta {eta}";

/// What a descriptor's calibration on `runs` validation runs measured, in
/// one line (none before it is calibrated).
fn calibration_line(r: &crate::sensor::reid::ReidSettings, runs: usize) -> Option<String> {
    let c = r.calibration.as_ref()?;
    let f = &c.figures;
    let auroc = r
        .target
        .auroc
        .map_or("free".to_owned(), |a| format!("{a:.2}"));
    Some(format!(
        "coid: re-identification descriptor ({} values) calibrated on {}: rank-1 {:.3} \
         (target {:.2}), AUROC {:.3} (target {auroc}) over {} queries among {:.1} \
         candidates",
        r.width,
        crate::label::counted(runs as u64, "validation run"),
        f.rank1,
        r.target.rank1,
        f.auroc,
        f.queries,
        f.candidates,
    ))
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
    let source = crate::commands::ConfigSource::File(config.to_owned());
    crate::commands::out_dir(out, &source, suffix)
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

/// Refuses a list argument that names something twice.
fn no_repeats<T: PartialEq + Label>(flag: &str, list: &[T]) -> anyhow::Result<()> {
    crate::commands::no_repeats(flag, list)
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
