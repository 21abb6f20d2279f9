//! The library's commands as typed calls, what both front ends run: the
//! `coid` command line (`cli`: parse, call, print) and the Python package
//! (`python/`: call, convert). A command takes a configuration source,
//! paths and options as values and returns what it wrote as values (the
//! folder, its headline); its progress comes as events for the caller to
//! show or not. Errors are `anyhow` chains whose one line
//! (`cli::one_line`) is what `coid` prints.
//!
//! Every command is typed: `run`, `export`, `score`, `eval` (and its
//! `mc_sweep` and `reid_sweep`), `train`, `track`, `batch` and `merge`,
//! `write_dataset`, `convert_pyg` and `check_dataset`; `cli` keeps the
//! scenario tools, the detector report and the pictures.

use std::path::{Path, PathBuf};

use crate::config::{ConfigError, Overrides, Settings};
use crate::pipeline::Progress;
use crate::sensor::reid::ReidSettings;
use crate::{render, tables};

pub mod batch;
pub mod convert;
pub mod dataset;
pub mod eval;
pub mod export;
pub mod mc_sweep;
pub mod reid_sweep;
pub mod run;
pub mod score;
pub mod track;
pub mod train;

pub use crate::batch::Shard;
pub use crate::export::Split;
pub use batch::{BatchReport, BatchRequest, MergeRequest, batch, batch_run, merge};
pub use convert::{
    ConvertPygRequest, ConvertReport, DatasetSummary, SplitCounts, check_dataset, convert_pyg,
};
pub use dataset::{DatasetFrames, WriteDatasetReport, WriteDatasetRequest, write_dataset};
pub use eval::{EvalReport, EvalRequest, eval};
pub use export::{ExportReport, ExportRequest, MatchesRequest, export, matches};
pub use mc_sweep::{McSweepReport, mc_sweep};
pub use reid_sweep::{ReidSweepReport, ReidSweepRequest, reid_sweep};
pub use run::{RunReport, RunRequest, run};
pub use score::{Matches, ScoreReport, ScoreRequest, score};
pub use track::{TrackReport, TrackRequest, track, track_sweep};
pub use train::{TrainReport, TrainRequest, TrainView, train};

/// What a command tells while it works.
pub enum Event<'a> {
    /// The re-identification descriptor is being calibrated on the
    /// validation runs (`[appearance] descriptor = "reid"`): `done` of
    /// `total` runs.
    Calibrating { done: usize, total: usize },
    /// It was calibrated on `runs` validation runs.
    Calibrated { reid: &'a ReidSettings, runs: usize },
    /// A run's simulation advanced.
    Simulating(Progress),
    /// Something the caller should say now (one line: a scenario without
    /// instances, a training seed without weights).
    Warning(&'a str),
    /// `done` of a batch's `total` runs (of this shard) are through,
    /// `failed` of them failed.
    Batch {
        done: usize,
        total: usize,
        failed: usize,
    },
    /// `done` of `total` pairs are converted.
    Pairs { done: usize, total: usize },
    /// `done` of `total` runs are through; `current` names the next.
    Runs {
        done: usize,
        total: usize,
        current: &'a str,
    },
}

/// What every command that writes a results folder takes: its
/// configuration, the folder, whether it may replace one, and threads.
#[derive(Clone, Debug, PartialEq)]
pub struct Common {
    pub config: ConfigSource,
    /// The results folder [default: `results/<config stem><suffix>`, or
    /// `results/<dataset folder><suffix>` on a dataset].
    pub out: Option<PathBuf>,
    /// Replace a folder that coid wrote for the same command and that did
    /// not change since (the old one removed only once the new one is
    /// complete).
    pub force: bool,
    /// Threads that evaluate a run's steps while SUMO advances [default:
    /// every core]; the results do not depend on it.
    pub threads: Option<usize>,
}

impl Common {
    /// `config` with everything else at its default.
    pub fn of(config: ConfigSource) -> Self {
        Self {
            config,
            out: None,
            force: false,
            threads: None,
        }
    }

    /// The results folder, claimed for a folder of `kind`: refused when
    /// something is there that `force` does not allow to replace.
    fn claim(
        &self,
        suffix: &str,
        dataset: Option<&Path>,
        kind: crate::io::ResultKind,
    ) -> anyhow::Result<crate::io::Claim> {
        let out = match dataset {
            Some(dir) => dataset_out_dir(self.out.clone(), dir, suffix),
            None => out_dir(self.out.clone(), &self.config, suffix),
        };
        let existing = crate::io::Existing::when(self.force);
        Ok(crate::io::Claim::new(&out, kind, existing)?)
    }
}

/// The settings a command runs with: `config` with `overrides` set over
/// it and the descriptor calibrated when it asks for one; or, with a
/// dataset folder, `config` reading that dataset (its splits make the
/// runs, its pose-noise levels the config's).
///
/// # Errors
/// The configuration or the dataset is refused, or calibration fails.
pub fn prepare(
    config: &ConfigSource,
    overrides: &Overrides,
    dataset: Option<&Path>,
    on: &mut impl FnMut(Event),
) -> anyhow::Result<Settings> {
    crate::io::assets::install()?;
    if let Some(dir) = dataset {
        let settings = config.load(overrides)?;
        return Ok(crate::experiments::with_dataset(&settings, dir)?);
    }
    calibrated(&config.load(overrides)?, on)
}

/// `settings` with the re-identification descriptor calibrated on the
/// validation runs when they ask for one (`[appearance] descriptor =
/// "reid"`), saying so in events; as they are otherwise.
///
/// # Errors
/// A validation run or the calibration fails.
pub fn calibrated(settings: &Settings, on: &mut impl FnMut(Event)) -> anyhow::Result<Settings> {
    if !settings.appearance.uncalibrated() || settings.dataset.is_some() {
        return Ok(settings.clone());
    }
    let mut runs = 0;
    let settings = crate::experiments::calibrated(settings, |done, total| {
        runs = total;
        on(Event::Calibrating { done, total });
    })?;
    if let Some(reid) = &settings.appearance.reid {
        on(Event::Calibrated { reid, runs });
    }
    Ok(settings)
}

/// Where a command's configuration comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum ConfigSource {
    /// The defaults alone: the default intersection with the shipped
    /// weights (`configs/default.toml`, compiled in).
    Defaults,
    /// A TOML file: only what differs from the defaults; relative paths
    /// in it resolve against its folder.
    File(PathBuf),
    /// TOML text that is in no file (a Python dict): `shown` names it in
    /// messages and results; relative paths in it resolve against the
    /// current folder.
    Text { text: String, shown: String },
}

impl ConfigSource {
    /// The configuration as messages name it: its file, "the default
    /// configuration", or the name text is shown by.
    pub fn shown(&self) -> String {
        match self {
            ConfigSource::Defaults => "the default configuration".to_owned(),
            ConfigSource::File(path) => path.display().to_string(),
            ConfigSource::Text { shown, .. } => shown.clone(),
        }
    }

    /// The path that names it: its file, the defaults' file, or for text
    /// the name it is shown by.
    pub fn path(&self) -> PathBuf {
        match self {
            ConfigSource::Defaults => crate::config::defaults_dir().join("default.toml"),
            ConfigSource::File(path) => path.clone(),
            ConfigSource::Text { shown, .. } => PathBuf::from(shown),
        }
    }

    /// The settings it gives, `overrides` set over it before validation.
    ///
    /// # Errors
    /// The file cannot be read, or the TOML is not a valid configuration.
    pub fn load(&self, overrides: &Overrides) -> Result<Settings, ConfigError> {
        match self {
            ConfigSource::Defaults => Settings::load_with(
                &crate::config::defaults_dir().join("default.toml"),
                overrides,
            ),
            ConfigSource::File(path) => Settings::load_with(path, overrides),
            ConfigSource::Text { text, shown } => {
                Settings::from_toml_with(text, Path::new(shown), overrides)
            }
        }
    }

    /// The stem of a command's default results folder: the file's stem,
    /// `default` for the defaults, `config` for text.
    pub fn stem(&self) -> String {
        match self {
            ConfigSource::Defaults => "default".to_owned(),
            ConfigSource::File(path) => path
                .file_stem()
                .map_or_else(|| "run".to_owned(), |s| s.to_string_lossy().into_owned()),
            ConfigSource::Text { .. } => "config".to_owned(),
        }
    }
}

/// A command's results folder: `out`, else `results/<config stem><suffix>`
/// (the one rule for default output folders).
pub fn out_dir(out: Option<PathBuf>, config: &ConfigSource, suffix: &str) -> PathBuf {
    out.unwrap_or_else(|| PathBuf::from("results").join(format!("{}{suffix}", config.stem())))
}

/// The results folder of a command on a dataset: `out`, else
/// `results/<dataset folder name><suffix>`.
pub fn dataset_out_dir(out: Option<PathBuf>, dataset: &Path, suffix: &str) -> PathBuf {
    out.unwrap_or_else(|| {
        let name = dataset
            .canonicalize()
            .ok()
            .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "dataset".to_owned());
        PathBuf::from("results").join(format!("{name}{suffix}"))
    })
}

/// `name` as a label of kind `what` ("split", "method"); an unknown one
/// is refused with the labels that exist.
///
/// # Errors
/// A name that is no label of `T`.
pub fn label<T: crate::label::Label>(what: &str, name: &str) -> Result<T, String> {
    crate::label::parse(what, name)
}

/// `names` as labels of kind `what` ("split", "method"); an unknown one
/// is refused with the labels that exist.
///
/// # Errors
/// A name that is no label of `T`.
pub fn labels<T: crate::label::Label>(what: &str, names: &[String]) -> Result<Vec<T>, String> {
    names.iter().map(|n| crate::label::parse(what, n)).collect()
}

/// Refuses a list that names something twice (`what`: the list's name
/// as the caller gave it).
pub(crate) fn no_repeats<T: PartialEq + crate::label::Label>(
    what: &str,
    list: &[T],
) -> anyhow::Result<()> {
    match first_repeat(list) {
        Some(x) => anyhow::bail!("{what} names '{}' twice", x.label()),
        None => Ok(()),
    }
}

/// The first entry of `list` that an earlier one repeats.
pub(crate) fn first_repeat<T: PartialEq>(list: &[T]) -> Option<&T> {
    (0..list.len())
        .find(|&k| list[..k].contains(&list[k]))
        .map(|k| &list[k])
}

/// The most threads or worker processes a command starts: more would only
/// exhaust the machine (each thread a stack, each worker a SUMO).
pub const MAX_PARALLEL: usize = 1024;

/// `threads`, else every core this process may use; refused beyond
/// [`MAX_PARALLEL`] or at 0.
///
/// # Errors
/// `threads` is 0 or above [`MAX_PARALLEL`].
pub fn threads(threads: Option<usize>) -> anyhow::Result<usize> {
    parallel("threads", threads)
}

/// A count of `what` (workers or threads): as given (1 to
/// [`MAX_PARALLEL`]), else every core.
pub(crate) fn parallel(what: &str, n: Option<usize>) -> anyhow::Result<usize> {
    match n {
        None => Ok(cores()),
        Some(n) if (1..=MAX_PARALLEL).contains(&n) => Ok(n),
        Some(n) => anyhow::bail!("{what} must be 1 to {MAX_PARALLEL}, got {n}"),
    }
}

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
}

/// The tables and plots of evaluated `runs` into the folder `dir`, as
/// `eval` and `score` write them.
pub(crate) fn write_eval(
    dir: &Path,
    settings: &Settings,
    runs: &[tables::RunEval],
    choices: &std::collections::BTreeMap<crate::matching::Method, crate::matching::DeepChoice>,
    pooled: Option<&str>,
) -> Result<(), crate::io::OutputError> {
    let lambdas = crate::matching::method_lambdas(choices);
    let tables = tables::eval_tables(settings, runs, &lambdas);
    let plots = tables::plot_data(settings, runs, &lambdas);
    crate::io::write_eval(dir, settings, &tables.files(), choices, pooled, |dir| {
        render::eval_plots(dir, &plots).map_err(|e| crate::io::OutputError::picture(dir, e))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A configuration in no file is named as its caller shows it, and
    /// its relative paths resolve against the current folder.
    #[test]
    fn a_configuration_in_no_file_is_named_as_its_caller_shows_it() {
        let text = ConfigSource::Text {
            text: "[scenario]\nend_s = -5\n".to_owned(),
            shown: "the configuration dict".to_owned(),
        };
        let e = text.load(&Overrides::default()).unwrap_err().to_string();
        assert!(
            e.contains("the configuration dict") && e.contains("end_s"),
            "{e}"
        );
        let ok = ConfigSource::Text {
            text: "[matching]\nmodels_dir = \"weights\"\n".to_owned(),
            shown: "the configuration dict".to_owned(),
        };
        let s = ok.load(&Overrides::default()).unwrap();
        assert_eq!(s.matching.models_dir, PathBuf::from("weights"));
        assert_eq!(s.source, PathBuf::from("the configuration dict"));
    }

    #[test]
    fn default_folders_and_thread_counts_follow_one_rule() {
        let file = ConfigSource::File(PathBuf::from("configs/family.toml"));
        assert_eq!(
            out_dir(None, &file, "-eval"),
            PathBuf::from("results/family-eval")
        );
        assert_eq!(
            out_dir(None, &ConfigSource::Defaults, ""),
            PathBuf::from("results/default")
        );
        let text = ConfigSource::Text {
            text: String::new(),
            shown: "x".to_owned(),
        };
        assert_eq!(out_dir(None, &text, ""), PathBuf::from("results/config"));
        assert_eq!(
            out_dir(Some("here".into()), &text, ""),
            PathBuf::from("here")
        );
        assert_eq!(threads(Some(3)).unwrap(), 3);
        assert!(threads(None).unwrap() >= 1);
        for bad in [0, MAX_PARALLEL + 1] {
            let e = threads(Some(bad)).unwrap_err().to_string();
            assert_eq!(e, format!("threads must be 1 to {MAX_PARALLEL}, got {bad}"));
        }
    }
}
