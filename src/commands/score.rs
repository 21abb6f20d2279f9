//! `score`: correspondences made elsewhere, for the runs of an export or
//! of a dataset, evaluated beside the built-in methods into the tables
//! `eval` writes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{Common, ConfigSource, Event};
use crate::config::{Overrides, Settings};
use crate::export::{self, ExportRun, Split};
use crate::io;
use crate::matching::{self, MultiVehicle};
use crate::report::MatchRow;
use crate::tables::RunEval;

/// Where the matches to score are.
#[derive(Clone, Debug, PartialEq)]
pub enum Matches {
    /// A file: Parquet, or CSV by its `.csv` ending.
    File(PathBuf),
    /// A Parquet file's bytes, handed over in memory (no file anywhere),
    /// named `shown` in messages ("the matches frame").
    Parquet { bytes: Vec<u8>, shown: String },
}

impl Matches {
    /// What messages call them: the file's path, or `shown`.
    pub fn shown(&self) -> String {
        match self {
            Matches::File(path) => path.display().to_string(),
            Matches::Parquet { shown, .. } => shown.clone(),
        }
    }

    /// The file they are in, if any.
    fn path(&self) -> Option<&Path> {
        match self {
            Matches::File(path) => Some(path),
            Matches::Parquet { .. } => None,
        }
    }

    fn read(&self) -> anyhow::Result<Vec<MatchRow>> {
        match self {
            Matches::File(path) => io::frames::read_matches(path),
            Matches::Parquet { bytes, .. } => io::frames::read_matches_parquet(bytes),
        }
        .map_err(|why| anyhow::anyhow!("cannot read {}: {why}", self.shown()))
    }
}

/// What to score, against which runs.
#[derive(Clone, Debug, PartialEq)]
pub struct ScoreRequest {
    /// The folder's default: `results/<config stem>-score`, or
    /// `results/<dataset folder>-score`.
    pub common: Common,
    /// Columns run, instance, a, b and optionally pose_noise, probability,
    /// uncertainty (the export's schema.md).
    pub matches: Matches,
    /// The export they were made from [default: the folder holding the
    /// matches file].
    pub export: Option<PathBuf>,
    /// Instead, the dataset they were made from: its runs scored as they
    /// are.
    pub dataset: Option<PathBuf>,
    /// Test, or validation (a threshold chosen there first).
    pub split: Split,
}

impl ScoreRequest {
    /// The test runs of `config`'s export in the folder holding `matches`.
    pub fn of(config: ConfigSource, matches: Matches) -> Self {
        Self {
            common: Common::of(config),
            matches,
            export: None,
            dataset: None,
            split: Split::Test,
        }
    }
}

/// What scoring wrote and noticed.
#[derive(Clone, Debug, PartialEq)]
pub struct ScoreReport {
    pub folder: PathBuf,
    /// What the matches were (a file's path, or the name they were given).
    pub shown: String,
    pub methods: usize,
    pub split: Split,
    pub runs: usize,
    pub instances: usize,
    /// What the caller should tell the user: runs the matches name no
    /// instance of, rows of other splits left out.
    pub notes: Vec<String>,
}

impl ScoreReport {
    /// The scoring in one line, as `coid score` prints it.
    pub fn line(&self) -> String {
        format!(
            "coid: scored {} with {} on {} ({}); wrote {}",
            self.shown,
            crate::label::counted(self.methods as u64, "built-in method"),
            crate::label::counted(self.runs as u64, &format!("{} run", self.split.as_str())),
            crate::label::counted(self.instances as u64, "instance"),
            self.folder.display()
        )
    }
}

/// Scores the matches of `request` and writes the tables.
///
/// # Errors
/// The configuration, the matches or the runs they were made from are
/// refused, the folder is taken, or a run fails; the folder is then not
/// left half-written.
pub fn score(request: &ScoreRequest, mut on: impl FnMut(Event)) -> anyhow::Result<ScoreReport> {
    let common = &request.common;
    let threads = super::threads(common.threads)?;
    let dataset = request.dataset.as_deref();
    let settings = super::prepare(&common.config, &Overrides::default(), dataset, &mut on)?;
    let claim = common.claim("-score", dataset, io::ResultKind::Eval)?;
    let out = claim.out().to_owned();
    if settings.matching.multi_vehicle != MultiVehicle::Pairwise {
        anyhow::bail!(
            "coid score compares pairwise correspondences: set [matching] multi_vehicle = \"pairwise\""
        );
    }
    if request.split == Split::Train {
        anyhow::bail!("coid score scores the test or validation runs (--split), not training runs");
    }
    let shown = request.matches.shown();
    let exported = made_from(request, &settings)?;
    let rows = request.matches.read()?;
    let runs = export::runs(&settings)?;
    let export_dir = export_dir(request, request.export.as_deref().or(dataset));
    check_split_exported(&export_dir, &runs, request.split, &exported)?;
    let levels: Vec<_> = settings.pose_noise.iter().map(|l| l.label).collect();
    let (mut external, other_splits) =
        export::external_matches(&rows, &runs, request.split, &levels)
            .map_err(|why| anyhow::anyhow!("{shown} does not fit this configuration: {why}"))?;
    let unnamed = unnamed_runs(&external, &exported);
    let methods = settings.matching.methods.clone();
    let choices = crate::pipeline::choices(&settings, &methods)?;
    let lambdas = matching::method_lambdas(&choices);
    let scored: Vec<&ExportRun> = runs.iter().filter(|r| r.split == request.split).collect();
    let mut evals: Vec<RunEval> = Vec::new();
    for (k, r) in scored.iter().enumerate() {
        let current = format!("{} seed {}", r.scenario, r.seed);
        on(Event::Runs {
            done: k,
            total: scored.len(),
            current: &current,
        });
        let matches = external.remove(&r.index).unwrap_or_default();
        evals.push(eval_scored(
            r, &methods, matches, &lambdas, threads, &shown,
        )?);
    }
    on(Event::Runs {
        done: scored.len(),
        total: scored.len(),
        current: "",
    });
    let header = report_header(&settings, request.split);
    claim.fill(|dir| super::write_eval(dir, &header, &evals, &choices, None))?;
    let notes = notes(&shown, &unnamed, other_splits, rows.len(), request.split);
    Ok(ScoreReport {
        folder: out,
        shown,
        methods: methods.len(),
        split: request.split,
        runs: evals.len(),
        instances: evals.iter().map(|r| r.instances).sum(),
        notes,
    })
}

/// One scored run evaluated with `matches` beside the built-in `methods`.
fn eval_scored(
    r: &ExportRun,
    methods: &[crate::matching::Method],
    matches: crate::evaluate::ExternalMatches,
    lambdas: &crate::matching::MethodLambdas,
    threads: usize,
    shown: &str,
) -> anyhow::Result<RunEval> {
    let warnings = crate::pipeline::Warnings::default();
    crate::experiments::eval_run_with(
        &r.settings,
        methods,
        Some(matches),
        lambdas,
        threads,
        &warnings,
        |_| {},
    )
    .map_err(|e| match e {
        crate::pipeline::RunError::Matches(why) => anyhow::anyhow!(
            "{shown} does not fit run {} ({} seed {}): {why}",
            r.index,
            r.scenario,
            r.seed
        ),
        other => anyhow::Error::new(other).context(format!(
            "run {} ({} seed {}) failed",
            r.index, r.scenario, r.seed
        )),
    })
}

/// What scoring tells beside its line: runs the matches name no instance
/// of although they have some (every pair there counts as unmatched),
/// rows of runs of other splits (left out).
fn notes(
    shown: &str,
    unnamed: &[String],
    other_splits: usize,
    rows: usize,
    split: Split,
) -> Vec<String> {
    let mut notes = Vec::new();
    if !unnamed.is_empty() {
        notes.push(format!(
            "coid: warning: {shown} names no instance of run(s) {} (they have instances): all \
             their pairs count as unmatched",
            unnamed.join(", ")
        ));
    }
    if other_splits > 0 {
        notes.push(format!(
            "coid: {other_splits} of {shown}'s {rows} rows name runs of other splits than {}: left \
             out (--split chooses the runs scored)",
            split.as_str()
        ));
    }
    notes
}

/// Checks that the matches were made for this configuration's instances:
/// the export they come from (`export`, else the folder holding them) was
/// made with the same instances digest. Returns the export's instance
/// count per run.
fn check_export(request: &ScoreRequest, settings: &Settings) -> anyhow::Result<BTreeMap<u64, u64>> {
    let dir = export_dir(request, request.export.as_deref());
    let beside = request.matches.path().is_some() && dir.join(export::RUNS_FILE).is_file();
    if request.export.is_none() && !beside {
        anyhow::bail!(
            "cannot tell which export {} was made from: pass --export DIR (the folder `coid \
             export` wrote; its runs.parquet names the configuration)",
            request.matches.shown()
        );
    }
    let path = dir.join(export::RUNS_FILE);
    let runs = io::frames::read_export_runs(&path)
        .map_err(|why| anyhow::anyhow!("cannot read {}: {why}", path.display()))?;
    let mine = settings.instances_digest()?;
    if let Some(old) = runs
        .first()
        .filter(|r| r.schema_version < export::SCORED_SINCE)
    {
        anyhow::bail!(
            "{} was written by an older coid (export schema {}; this coid scores schemas {} \
             to {}, whose nodes carry the boxes' heading and speed and whose digest covers how \
             unset colours look): export again with this coid",
            path.display(),
            old.schema_version,
            export::SCORED_SINCE,
            export::SCHEMA_VERSION
        );
    }
    if let Some(new) = runs
        .first()
        .filter(|r| r.schema_version > export::SCHEMA_VERSION)
    {
        anyhow::bail!(
            "{} was written by a newer coid (export schema {}; this coid knows schemas up to \
             {}): score with that coid, or export again with this one",
            path.display(),
            new.schema_version,
            export::SCHEMA_VERSION
        );
    }
    match runs.first().map(|r| r.config_digest.clone()) {
        None => anyhow::bail!("{} names no run", path.display()),
        Some(None) => anyhow::bail!(
            "{} was written by an older coid (export schema 1, without config_digest): \
             export again with this coid",
            path.display()
        ),
        Some(Some(d)) if d != mine => anyhow::bail!(
            "the export in {} was made with another configuration (digest {d}; this one's is \
             {mine}): its instances are not this configuration's; score with the config it was \
             exported with",
            dir.display()
        ),
        Some(Some(_)) => {}
    }
    Ok(runs.iter().map(|r| (r.run, r.n_instances)).collect())
}

/// The settings the report's header names the scored runs by.
fn report_header(settings: &Settings, split: Split) -> Settings {
    settings.reporting_split(split.as_str())
}

/// The instance count of every run the matches were made from: the
/// dataset's, else the export's, checked to be this configuration's
/// ([`check_export`]).
fn made_from(request: &ScoreRequest, settings: &Settings) -> anyhow::Result<BTreeMap<u64, u64>> {
    match &request.dataset {
        Some(dir) => Ok(crate::dataset::Dataset::open(dir)
            .map_err(|e| anyhow::anyhow!("{} is not a usable dataset: {e}", dir.display()))?
            .runs
            .iter()
            .map(|r| (r.run, r.n_instances))
            .collect()),
        None => check_export(request, settings),
    }
}

/// Refused unless the export in `export_dir` holds every run of `split`
/// (its runs: `exported`): matches for runs it does not hold were not made
/// from it.
fn check_split_exported(
    export_dir: &Path,
    runs: &[ExportRun],
    split: Split,
    exported: &BTreeMap<u64, u64>,
) -> anyhow::Result<()> {
    let missing = runs
        .iter()
        .filter(|r| r.split == split && !exported.contains_key(&(r.index as u64)))
        .count();
    if missing == 0 {
        return Ok(());
    }
    let mut held: Vec<&str> = runs
        .iter()
        .filter(|r| exported.contains_key(&(r.index as u64)))
        .map(|r| r.split.as_str())
        .collect();
    held.dedup();
    anyhow::bail!(
        "the export in {} does not hold the {} {} runs this configuration scores (it holds {} \
         runs): export them (`coid export --splits {}`) and match them",
        export_dir.display(),
        missing,
        split.as_str(),
        if held.is_empty() {
            "no".to_owned()
        } else {
            held.join(" and ")
        },
        split.as_str()
    )
}

/// The folder of the export the matches came from: `export`, else the
/// folder holding the matches file (the current folder for a bare name
/// or matches in memory).
fn export_dir(request: &ScoreRequest, export: Option<&Path>) -> PathBuf {
    match export {
        Some(d) => d.to_owned(),
        None => match request.matches.path().and_then(Path::parent) {
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        },
    }
}

/// The scored runs with instances that the matches name none of (every
/// pair there counts as unmatched): a matcher that found nothing in a
/// whole run is rare; a file cut short or filtered is not.
fn unnamed_runs(
    external: &BTreeMap<usize, crate::evaluate::ExternalMatches>,
    exported: &BTreeMap<u64, u64>,
) -> Vec<String> {
    external
        .iter()
        .filter(|(run, m)| {
            m.by_instance.is_empty() && exported.get(&(**run as u64)).is_some_and(|&n| n > 0)
        })
        .map(|(run, _)| run.to_string())
        .collect()
}
