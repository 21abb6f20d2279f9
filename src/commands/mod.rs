//! The library's commands as typed calls, what both front ends run: the
//! `coid` command line (`cli`: parse, call, print) and the Python package
//! (`python/`: call, convert). A command takes a configuration source,
//! paths and options as values and returns what it wrote as values (the
//! folder, its headline); its progress comes as events for the caller to
//! show or not. Errors are `anyhow` chains whose one line
//! (`cli::one_line`) is what `coid` prints.
//!
//! `run` is typed so far; the other commands are still reached through
//! `cli`.

use std::path::{Path, PathBuf};

use crate::config::{ConfigError, Overrides, Settings};

pub mod run;

pub use run::{RunEvent, RunReport, RunRequest, run};

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

/// The most threads or worker processes a command starts: more would only
/// exhaust the machine (each thread a stack, each worker a SUMO).
pub const MAX_PARALLEL: usize = 1024;

/// `threads`, else every core this process may use; refused beyond
/// [`MAX_PARALLEL`] or at 0.
///
/// # Errors
/// `threads` is 0 or above [`MAX_PARALLEL`].
pub fn threads(threads: Option<usize>) -> anyhow::Result<usize> {
    match threads {
        None => Ok(cores()),
        Some(n) if (1..=MAX_PARALLEL).contains(&n) => Ok(n),
        Some(n) => anyhow::bail!("threads must be 1 to {MAX_PARALLEL}, got {n}"),
    }
}

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
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
