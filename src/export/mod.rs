//! `coid export` and `coid score`: every instance of a configuration as
//! Parquet tables for matchers written elsewhere (schema:
//! `docs/export-schema.md`, [`SCHEMA_VERSION`]), and correspondences made
//! elsewhere read back as one more method, checked against the instances
//! they name.
//!
//! Runs are numbered once for a configuration ([`runs`]: training, then
//! validation, then test runs), whatever is exported, so that a matches
//! file names the same run in every export of the same configuration.
//!
//! One job per file: `rows` (an instance's rows, in the dataset schema of
//! `crate::dataset::schema`), `score` (a matches file's rows checked and
//! turned into each run's external matches); this file numbers the runs
//! and exports one.

use std::collections::BTreeMap;

use crate::config::Settings;
use crate::evaluate::{FrameEval, PairAtLevel};
use crate::experiments;
use crate::io::TablesFolder;
use crate::matching::Method;
use crate::pipeline::{self, Instance, Progress, RunError, Warnings};
use crate::report::Table;

mod rows;
mod score;

use crate::dataset::schema;
pub use crate::dataset::{SCHEMA, SCHEMA_VERSION};

pub use score::external_matches;

/// The oldest export `coid score` scores: its instances are this coid's
/// (versions 4 and 5 changed the instances' columns, not the instances).
pub const SCORED_SINCE: u64 = 3;

/// The file of the runs (`runs.parquet`), written last.
pub const RUNS_FILE: &str = schema::Run::FILE;

crate::label_enum! { "split";
    /// What a run may be used for.
    pub enum Split {
        #[strum(serialize = "train")]
        Train,
        #[strum(serialize = "validation")]
        Validation,
        #[strum(serialize = "test")]
        Test,
    }
}

/// One run of a configuration, numbered for export and scoring.
pub struct ExportRun {
    pub index: usize,
    pub split: Split,
    /// The SUMO configuration, as `<folder>/<file stem>`.
    pub scenario: String,
    pub seed: u64,
    pub settings: Settings,
}

/// Every run of `settings`: the training runs (instances sampled as
/// training samples them), the validation runs, the test runs (as `coid
/// eval` runs them), numbered in that order; with a dataset, its runs,
/// numbered as it numbers them.
pub fn runs(settings: &Settings) -> Result<Vec<ExportRun>, RunError> {
    if let Some(runs) = experiments::dataset_runs(settings)? {
        // A dataset's runs, numbered as it numbers them.
        return Ok(runs
            .into_iter()
            .map(|(r, s)| ExportRun {
                index: r.run as usize,
                split: crate::label::parse("split", &r.split).unwrap_or(Split::Test),
                scenario: r.scenario,
                seed: r.seed,
                settings: s,
            })
            .collect());
    }
    let splits = [
        (Split::Train, experiments::training_runs(settings)?),
        (Split::Validation, experiments::validation_runs(settings)?),
        (Split::Test, experiments::test_runs(settings)?),
    ];
    let mut out = Vec::new();
    for (split, runs) in splits {
        for s in runs {
            let cfg = &s.scenario.sumocfg;
            let name = |p: Option<&std::ffi::OsStr>| p.map(|n| n.to_string_lossy().into_owned());
            let folder = name(cfg.parent().and_then(|p| p.file_name())).unwrap_or_default();
            let stem = name(cfg.file_stem()).unwrap_or_default();
            out.push(ExportRun {
                index: out.len(),
                split,
                scenario: format!("{folder}/{stem}"),
                seed: s.seeds.traffic,
                settings: s,
            });
        }
    }
    Ok(out)
}

/// The export's Parquet files of instances, each with its (empty) columns.
pub fn files() -> Vec<(&'static str, Table)> {
    let mut f = vec![(RUNS_FILE, run_table(&[], ""))];
    f.extend(rows::Rows::default().take());
    f
}

/// The file of a method's matches (`--with-matches`).
pub fn matches_file(method: Method) -> String {
    format!("matches-{}.parquet", method.as_str())
}

/// The columns of a matches file, for an empty one.
pub fn matches_template() -> Table {
    schema::Match::table(Vec::new())
}

/// The `runs.parquet` rows of `runs` (with their instance counts), of the
/// configuration whose instances digest is `digest`
/// ([`Settings::instances_digest`]).
pub fn run_table(runs: &[(&ExportRun, usize)], digest: &str) -> Table {
    let rows = runs
        .iter()
        .map(|&(run, n_instances)| schema::Run {
            schema_version: SCHEMA_VERSION,
            run: run.index as u64,
            split: run.split.as_str().to_owned(),
            scenario: run.scenario.clone(),
            seed: run.seed,
            n_instances: n_instances as u64,
            config_digest: digest.to_owned(),
        })
        .collect();
    schema::Run::table(rows)
}

/// Exports one run into `out`: its instances, nodes, edges, truth and true
/// pairs, and the matches of each of `methods` (files
/// [`matches_file`]); returns its instance count.
pub fn export_run(
    run: &ExportRun,
    methods: &[Method],
    threads: usize,
    warnings: &Warnings,
    progress: impl FnMut(Progress),
    out: &mut TablesFolder,
) -> Result<usize, RunError> {
    let s = &run.settings;
    // The oracle's pass makes the instance files; its matches, if asked
    // for, come from the same pass.
    let mut runners = vec![crate::evaluate::CorrespondenceSource::Oracle];
    let others: Vec<Method> = methods
        .iter()
        .copied()
        .filter(|&m| m != Method::Oracle)
        .collect();
    runners.extend(pipeline::runners(s, &others)?);
    let oracle_matches = methods.contains(&Method::Oracle);
    let first_level = s.pose_noise.first().map(|l| l.label);
    let mut rows = rows::Rows::default();
    rows.appearance_width = s.appearance.appearance_width();
    let mut matches: BTreeMap<Method, Vec<schema::Match>> = BTreeMap::new();
    let on_eval = |insts: &[Instance], pairs: &[PairAtLevel], level, f: FrameEval| {
        if f.method != Method::Oracle || oracle_matches {
            let made = rows::matches(run.index, pairs, &f);
            matches.entry(f.method).or_default().extend(made);
        }
        if f.method == Method::Oracle {
            rows.add(run.index, insts, pairs, Some(level) == first_level);
            if rows.held() >= ROWS_PER_GROUP {
                rows.write(out)?;
            }
        }
        Ok(())
    };
    let stats = pipeline::evaluate_frames(s, &runners, threads, warnings, progress, on_eval)?;
    rows.write(out)?;
    for (method, m) in matches {
        out.write(&matches_file(method), &schema::Match::table(m))?;
    }
    Ok(stats.n_instances)
}

/// `method`'s matches on every instance of `run`, as `export_run` writes
/// them in `matches-<method>.parquet` (the same passes: the oracle's
/// beside), held in memory and nothing written.
///
/// # Errors
/// The run fails.
pub fn run_matches(
    run: &ExportRun,
    method: Method,
    threads: usize,
    warnings: &Warnings,
) -> Result<Vec<crate::report::MatchRow>, RunError> {
    let s = &run.settings;
    let mut runners = vec![crate::evaluate::CorrespondenceSource::Oracle];
    if method != Method::Oracle {
        runners.extend(pipeline::runners(s, &[method])?);
    }
    let mut made = Vec::new();
    let on_eval = |_: &[Instance], pairs: &[PairAtLevel], _, f: FrameEval| {
        if f.method == method {
            made.extend(
                rows::matches(run.index, pairs, &f).map(|m| crate::report::MatchRow {
                    run: m.run,
                    instance: m.instance,
                    pose_noise: Some(m.pose_noise),
                    a: m.a,
                    b: m.b,
                    probability: Some(m.probability),
                    uncertainty: Some(m.uncertainty),
                }),
            );
        }
        Ok(())
    };
    pipeline::evaluate_frames(s, &runners, threads, warnings, |_| {}, on_eval)?;
    Ok(made)
}

/// Node rows held before they are written as row groups.
const ROWS_PER_GROUP: usize = 65_536;
