//! `export`: every instance of a configuration (or of a dataset's runs)
//! as Parquet tables in the dataset schema, for matchers written
//! elsewhere, with built-in methods' matches beside when asked.

use std::path::PathBuf;

use anyhow::Context;

use super::{Common, ConfigSource, Event};
use crate::config::Overrides;
use crate::export::{self, ExportRun, Split};
use crate::io;
use crate::matching::Method;

/// What to export and where.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportRequest {
    /// The folder's default: `results/<config stem>-export`, or
    /// `results/<dataset folder>-export`.
    pub common: Common,
    /// The splits to export [default (empty): all three].
    pub splits: Vec<Split>,
    /// Built-in methods whose matches are written beside, each as
    /// `matches-<method>.parquet`.
    pub with_matches: Vec<Method>,
    /// Instead of simulating the configuration's runs, this dataset's.
    pub dataset: Option<PathBuf>,
}

impl ExportRequest {
    /// An export of every split of `config`, nothing else asked.
    pub fn of(config: ConfigSource) -> Self {
        Self {
            common: Common::of(config),
            splits: Vec::new(),
            with_matches: Vec::new(),
            dataset: None,
        }
    }
}

/// What an export wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportReport {
    pub folder: PathBuf,
    pub runs: usize,
    pub instances: usize,
    /// The splits asked for that have runs (a dataset's own), in order.
    pub splits: Vec<Split>,
}

impl ExportReport {
    /// The export in one line, as `coid export` prints it (without the
    /// folder).
    pub fn summary(&self) -> String {
        format!(
            "coid: exported {} ({}) of {}",
            crate::label::counted(self.runs as u64, "run"),
            crate::label::counted(self.instances as u64, "instance"),
            self.splits
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        )
    }
}

/// Writes the export of `request`.
///
/// # Errors
/// A list names something twice, the configuration or the dataset is
/// refused, the folder is taken, or a run fails; the folder is then not
/// left half-written.
pub fn export(request: &ExportRequest, mut on: impl FnMut(Event)) -> anyhow::Result<ExportReport> {
    super::no_repeats("splits", &request.splits)?;
    super::no_repeats("with_matches", &request.with_matches)?;
    let common = &request.common;
    let threads = super::threads(common.threads)?;
    let dataset = request.dataset.as_deref();
    let settings = super::prepare(&common.config, &Overrides::default(), dataset, &mut on)?;
    let claim = common.claim("-export", dataset, io::ResultKind::Export)?;
    let out = claim.out().to_owned();
    let splits = if request.splits.is_empty() {
        vec![Split::Train, Split::Validation, Split::Test]
    } else {
        request.splits.clone()
    };
    let digest = settings.instances_digest()?;
    let runs: Vec<ExportRun> = export::runs(&settings)?
        .into_iter()
        .filter(|r| splits.contains(&r.split))
        .collect();
    let mut files: Vec<(String, crate::report::Table)> = export::files()
        .into_iter()
        .map(|(n, t)| (n.to_owned(), t))
        .collect();
    files.extend(
        request
            .with_matches
            .iter()
            .map(|&m| (export::matches_file(m), export::matches_template())),
    );
    let named: Vec<(&str, crate::report::Table)> =
        files.iter().map(|(n, t)| (n.as_str(), t.clone())).collect();
    let mut folder = io::TablesFolder::create(claim, &named)?;
    let mut counts = Vec::new();
    let warnings = crate::pipeline::Warnings::default();
    for (k, r) in runs.iter().enumerate() {
        let current = format!("{} {} seed {}", r.split.as_str(), r.scenario, r.seed);
        on(Event::Runs {
            done: k,
            total: runs.len(),
            current: &current,
        });
        let n = export::export_run(
            r,
            &request.with_matches,
            threads,
            &warnings,
            |_| {},
            &mut folder,
        )
        .with_context(|| format!("run {} ({} seed {}) failed", r.index, r.scenario, r.seed))?;
        counts.push((r, n));
    }
    on(Event::Runs {
        done: runs.len(),
        total: runs.len(),
        current: "",
    });
    folder.write(export::RUNS_FILE, &export::run_table(&counts, &digest))?;
    folder.finish(&[("schema.md", export::SCHEMA.to_owned())])?;
    Ok(ExportReport {
        folder: out,
        runs: runs.len(),
        instances: counts.iter().map(|c| c.1).sum(),
        splits: splits
            .into_iter()
            .filter(|s| runs.iter().any(|r| r.split == *s))
            .collect(),
    })
}

/// A built-in method's matches on every run of a dataset, held in memory:
/// what `export` with `with_matches` writes in `matches-<method>.parquet`,
/// without a folder.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchesRequest {
    /// The settings of the method (the dataset gives the runs).
    pub config: ConfigSource,
    pub dataset: PathBuf,
    pub method: Method,
    pub threads: Option<usize>,
}

/// The matches of `request`, run by run, in the export's order.
///
/// # Errors
/// The configuration or the dataset is refused, or a run fails.
pub fn matches(
    request: &MatchesRequest,
    mut on: impl FnMut(Event),
) -> anyhow::Result<Vec<crate::report::MatchRow>> {
    let threads = super::threads(request.threads)?;
    let dataset = Some(request.dataset.as_path());
    let settings = super::prepare(&request.config, &Overrides::default(), dataset, &mut on)?;
    let runs = export::runs(&settings)?;
    let warnings = crate::pipeline::Warnings::default();
    let mut rows = Vec::new();
    for (k, r) in runs.iter().enumerate() {
        let current = format!("{} {} seed {}", r.split.as_str(), r.scenario, r.seed);
        on(Event::Runs {
            done: k,
            total: runs.len(),
            current: &current,
        });
        rows.extend(
            export::run_matches(r, request.method, threads, &warnings).with_context(|| {
                format!("run {} ({} seed {}) failed", r.index, r.scenario, r.seed)
            })?,
        );
    }
    on(Event::Runs {
        done: runs.len(),
        total: runs.len(),
        current: "",
    });
    Ok(rows)
}
