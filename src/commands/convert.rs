//! `convert_pyg`: PyTorch Geometric pairs recorded elsewhere (DMGM's
//! layout) into a dataset; `check_dataset`: a dataset read run by run,
//! checked and summarised.

use std::ops::RangeInclusive;
use std::path::PathBuf;

use anyhow::{Context, bail};

use super::Event;
use crate::dataset::{self, SCHEMA, SCHEMA_VERSION, convert};
use crate::io;

/// PyG pairs to convert (`coid convert pyg`).
#[derive(Clone, Debug, PartialEq)]
pub struct ConvertPygRequest {
    /// The folder holding the views' folders (DMGM: `data/testdata`).
    pub source: PathBuf,
    /// The views' folder names: the first and the second vehicle.
    pub views: [String; 2],
    /// Each split's pair indices (train, validation or test).
    pub splits: Vec<(String, RangeInclusive<u64>)>,
    /// The source's name: runs are `<name>/<recording>`.
    pub name: String,
    /// The position noise (per axis, m) of the GPS poses the source's
    /// world positions went through.
    pub gps_sigma_m: f64,
    /// Their heading noise, degrees.
    pub gps_heading_sigma_deg: f64,
    /// The dataset folder to write.
    pub out: PathBuf,
    /// Replace a dataset folder coid wrote that did not change since.
    pub force: bool,
}

/// What a conversion wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvertReport {
    pub folder: PathBuf,
    /// Pairs converted (each an instance).
    pub instances: u64,
    pub runs: usize,
    /// Pairs left out because a vehicle saw nothing: (index, view).
    pub skipped: Vec<(u64, String)>,
    /// Recordings the splits cut, with the splits they fall in.
    pub split_recordings: Vec<(String, Vec<String>)>,
}

impl ConvertReport {
    /// One warning per recording the splits cut.
    pub fn warnings(&self) -> Vec<String> {
        self.split_recordings
            .iter()
            .map(|(recording, splits)| {
                format!(
                    "warning: --splits cuts recording {recording} between {}: its frames are \
                     alike, so what is chosen on one split is seen again on the other",
                    splits.join(" and ")
                )
            })
            .collect()
    }

    /// The conversion in one line: pairs, runs, pairs left out.
    pub fn line(&self) -> String {
        let skipped = match self.skipped.as_slice() {
            [] => String::new(),
            s => format!(
                " ({} {} left out: a vehicle saw nothing, e.g. pair {} in {})",
                s.len(),
                plural(s.len(), "pair", "pairs"),
                s[0].0,
                s[0].1
            ),
        };
        format!(
            "converted {} {} into {} {}{skipped}: {}",
            self.instances,
            plural(self.instances as usize, "pair", "pairs"),
            self.runs,
            plural(self.runs, "run", "runs"),
            self.folder.display()
        )
    }
}

pub(super) fn plural<'a>(n: usize, one: &'a str, many: &'a str) -> &'a str {
    if n == 1 { one } else { many }
}

/// Converts the pairs of `request` into a dataset, written as `coid
/// export` writes one; `on` hears [`Event::Pairs`] as they go.
///
/// # Errors
/// A bad option (a negative noise, the same view twice, a name that is
/// no plain word, a missing view folder), a pair the reader refuses, no
/// pair with detections in both views, or the folder is taken.
pub fn convert_pyg(
    request: &ConvertPygRequest,
    mut on: impl FnMut(Event),
) -> anyhow::Result<ConvertReport> {
    let source = pyg_source(request)?;
    let pairs = source.pairs().map_err(anyhow::Error::msg)?;
    let claim = io::Claim::new(
        &request.out,
        io::ResultKind::Export,
        io::Existing::when(request.force),
    )?;
    let templates: Vec<(&str, crate::report::Table)> =
        std::iter::once((dataset::schema::Run::FILE, crate::report::Table::default()))
            .chain(convert::PairRows::default().tables())
            .collect();
    let mut folder = io::TablesFolder::create(claim, &templates)?;
    let mut conv = convert::Converter::default();
    let mut write = |conv: &mut convert::Converter| -> anyhow::Result<()> {
        for (file, table) in conv.take().tables() {
            folder.write(file, &table)?;
        }
        Ok(())
    };
    let total = pairs.len();
    on(Event::Pairs { done: 0, total });
    for (done, (k, split)) in pairs.into_iter().enumerate() {
        let views = source.read_pair(k).map_err(anyhow::Error::msg)?;
        conv.add(&source, k, split, views)
            .map_err(anyhow::Error::msg)?;
        if conv.held() >= 16_384 {
            write(&mut conv)?;
        }
        on(Event::Pairs {
            done: done + 1,
            total,
        });
    }
    write(&mut conv)?;
    if conv.runs.is_empty() {
        bail!(
            "no pair of {} has detections in both views: nothing to convert",
            request.source.display()
        );
    }
    folder.write(dataset::schema::Run::FILE, &conv.run_table(SCHEMA_VERSION))?;
    folder.finish(&[("schema.md", SCHEMA.to_owned())])?;
    Ok(ConvertReport {
        folder: request.out.clone(),
        instances: conv.runs.iter().map(|r| r.n_instances).sum(),
        runs: conv.runs.len(),
        skipped: conv.skipped.clone(),
        split_recordings: conv.split_recordings(),
    })
}

/// The source of `request`, its options checked.
fn pyg_source(request: &ConvertPygRequest) -> anyhow::Result<convert::PygSource> {
    for (name, v) in [
        ("--gps-sigma-m", request.gps_sigma_m),
        ("--gps-heading-sigma-deg", request.gps_heading_sigma_deg),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{name} must be a number >= 0, not {v}");
        }
    }
    let [first, second] = &request.views;
    if first == second {
        bail!("--views names {first} twice: the two vehicles' folders differ");
    }
    check_source_name(&request.name)?;
    for v in &request.views {
        if !request.source.join(v).is_dir() {
            bail!(
                "{} has no folder {v} (the views' folders, --views)",
                request.source.display()
            );
        }
    }
    Ok(convert::PygSource {
        dir: request.source.clone(),
        views: request.views.clone(),
        splits: request.splits.clone(),
        name: request.name.clone(),
        position_sigma_m: request.gps_sigma_m,
        heading_sigma_rad: request.gps_heading_sigma_deg.to_radians(),
    })
}

/// A source's name becomes the first part of each run's scenario: one
/// plain word (letters, digits, `.`, `_`, `-`).
fn check_source_name(name: &str) -> anyhow::Result<()> {
    let plain = name
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
    if name.is_empty() || !plain || name.chars().all(|c| c == '.') {
        bail!(
            "--name {name:?} is not a plain word (letters, digits, '.', '_', '-'): runs are \
             named <name>/<recording>"
        );
    }
    Ok(())
}

/// One split of a dataset, counted.
#[derive(Clone, Debug, PartialEq)]
pub struct SplitCounts {
    /// `train`, `validation` or `test` (a split of another name counts as
    /// test).
    pub split: &'static str,
    pub runs: usize,
    pub instances: usize,
    /// Nodes of both vehicles.
    pub nodes: usize,
    pub true_pairs: usize,
}

/// What a dataset holds, checked run by run (`coid dataset`).
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    pub dir: PathBuf,
    pub runs: usize,
    /// Each split that has runs, in train, validation, test order.
    pub splits: Vec<SplitCounts>,
    /// Runs without instances: `run <k> (<split>, <scenario>)`.
    pub empty_runs: Vec<String>,
    /// Each pose-noise level and its position sigma (m).
    pub levels: Vec<(String, f64)>,
    /// Values per node's appearance vector (`None`: no vectors).
    pub appearance_width: Option<usize>,
    pub optional_columns: Vec<String>,
}

impl DatasetSummary {
    /// The summary as `coid dataset` prints it, a line each.
    pub fn lines(&self) -> Vec<String> {
        let mut out = vec![format!(
            "dataset {}: {} {}",
            self.dir.display(),
            self.runs,
            plural(self.runs, "run", "runs")
        )];
        for c in &self.splits {
            let n = c.instances.max(1) as f64;
            out.push(format!(
                "  {}: {} {}, {} instances, {:.1} nodes per vehicle, {:.1} true pairs per \
                 instance",
                c.split,
                c.runs,
                plural(c.runs, "run", "runs"),
                c.instances,
                c.nodes as f64 / (2.0 * n),
                c.true_pairs as f64 / n
            ));
        }
        if !self.empty_runs.is_empty() {
            out.push(format!(
                "  runs without instances: {} (tables average over the runs that have some): {}",
                self.empty_runs.len(),
                self.empty_runs.join(", ")
            ));
        }
        let levels: Vec<String> = self
            .levels
            .iter()
            .map(|(label, sigma)| format!("{label} ({sigma} m)"))
            .collect();
        out.push(format!("  pose-noise levels: {}", levels.join(", ")));
        out.push(match self.appearance_width {
            Some(w) => format!("  appearance vectors: {w} values per node"),
            None => "  appearance vectors: none".to_owned(),
        });
        out.push(format!(
            "  optional columns: {}",
            if self.optional_columns.is_empty() {
                "none".to_owned()
            } else {
                self.optional_columns.join(", ")
            }
        ));
        out
    }
}

/// Reads the dataset in `dir` one run at a time, checking every run, and
/// counts what it holds.
///
/// # Errors
/// The dataset or one of its runs is refused ("<dir> is not a usable
/// dataset: ...").
pub fn check_dataset(dir: &std::path::Path) -> anyhow::Result<DatasetSummary> {
    let unusable = || format!("{} is not a usable dataset", dir.display());
    let d = dataset::Dataset::open(dir).with_context(unusable)?;
    const SPLITS: [&str; 3] = ["train", "validation", "test"];
    let mut counts: Vec<SplitCounts> = SPLITS
        .iter()
        .map(|&split| SplitCounts {
            split,
            runs: 0,
            instances: 0,
            nodes: 0,
            true_pairs: 0,
        })
        .collect();
    for k in 0..d.runs.len() {
        let run = d.run(k).with_context(unusable)?;
        let at = SPLITS
            .iter()
            .position(|s| *s == run.info.split)
            .unwrap_or(2);
        let c = &mut counts[at];
        c.runs += 1;
        for i in &run.instances {
            c.instances += 1;
            c.nodes += i.sides[0].nodes.len() + i.sides[1].nodes.len();
            c.true_pairs += i.true_pairs.len();
        }
    }
    Ok(DatasetSummary {
        dir: dir.to_owned(),
        runs: d.runs.len(),
        splits: counts.into_iter().filter(|c| c.runs > 0).collect(),
        empty_runs: d
            .runs
            .iter()
            .filter(|r| r.n_instances == 0)
            .map(|r| format!("run {} ({}, {})", r.run, r.split, r.scenario))
            .collect(),
        levels: d
            .levels
            .iter()
            .map(|l| (l.label.as_str().to_owned(), l.position_sigma_m))
            .collect(),
        appearance_width: d.appearance_width.width(),
        optional_columns: d.optional_columns.clone(),
    })
}
