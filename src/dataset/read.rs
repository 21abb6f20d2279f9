//! A dataset folder read back and checked, run by run: [`Dataset::open`]
//! reads the runs, the instances (one row per instance and level) and where
//! each run's rows are in the other files; [`Dataset::run`] reads one run's
//! nodes, truth and true pairs, so that memory holds one run at a time.
//! Checked: every file's declared columns (optional ones where present),
//! every row's run and instance known, a run's rows together in each file,
//! every instance at every level of the dataset, each vehicle's nodes
//! numbered 0..n as its instance says, an object id at most once per
//! vehicle, true pairs that match each node at most once and pair one
//! object, and a pose for every vehicle (reported, or fitted to its nodes'
//! world positions). A folder that does not fit is refused with one line
//! naming the file and row.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::SCHEMA_VERSION;
use super::assemble::{
    add_true_pair, add_truth, check_node_counts, check_unique_objects, instance_of, node_of,
    set_poses,
};
use super::schema::{Edge, Instance, Node, Run, TruePair, Truth};
use crate::geometry::{Cov2, Pose2, Vec2};
use crate::io::frames::{read_dataset_counts, read_dataset_table};
use crate::sensor::{AppearanceWidth, PoseNoiseLabel, PoseNoiseLevel};
use crate::traffic::ObjectClass;

/// A dataset: its runs and instances, ready to read run by run.
#[derive(Debug)]
pub struct Dataset {
    pub dir: PathBuf,
    pub runs: Vec<RunInfo>,
    /// The pose-noise levels every instance has a row at, in the order
    /// they first appear, each with the accuracy of its first row (the
    /// first vehicle's heading accuracy).
    pub levels: Vec<PoseNoiseLevel>,
    /// The length of every node's appearance vector.
    pub appearance_width: AppearanceWidth,
    /// The optional columns present, as `file: column`.
    pub optional_columns: Vec<String>,
    /// Each run's instance rows (grouped by instance, levels in order).
    instances: Vec<Vec<Instance>>,
    /// Each run's rows in the node, truth and true-pair files.
    rows: Vec<[Range<usize>; 3]>,
}

/// A run as `runs.parquet` names it.
#[derive(Clone, Debug, PartialEq)]
pub struct RunInfo {
    pub run: u64,
    pub split: String,
    pub scenario: String,
    pub seed: u64,
    pub n_instances: u64,
}

/// One run's instances, read.
#[derive(Debug)]
pub struct DatasetRun {
    pub info: RunInfo,
    pub instances: Vec<DatasetInstance>,
}

#[derive(Debug)]
pub struct DatasetInstance {
    pub instance: u64,
    pub step: u64,
    pub time_s: Option<f64>,
    /// The instance at each level of the dataset, in its order.
    pub levels: Vec<InstanceLevel>,
    /// Each vehicle's true pose (world frame), where the source knows it.
    pub true_poses: [Option<Pose2>; 2],
    /// Their headings as the file gives them.
    pub true_heading_rad: [Option<f64>; 2],
    pub sides: [DatasetSide; 2],
    /// Node `a` of the first vehicle is node `b` of the second.
    pub true_pairs: Vec<(usize, usize)>,
}

/// An instance at one pose-noise level: each vehicle's reported pose (as
/// given, or fitted to its nodes' world positions) and claimed accuracy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceLevel {
    pub label: PoseNoiseLabel,
    pub position_sigma_m: f64,
    pub heading_sigma_rad: [f64; 2],
    pub reported: [Pose2; 2],
    /// Each reported heading as the file gives it (a pose keeps its
    /// heading as a rotation, which may read back one ulp off), else the
    /// fitted pose's.
    pub reported_heading_rad: [f64; 2],
}

#[derive(Debug, Default)]
pub struct DatasetSide {
    pub id: String,
    pub nodes: Vec<DatasetNode>,
}

/// One node, as plain values: what the vehicle measured, then the truth.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetNode {
    /// Measured centre, the vehicle's body frame.
    pub position_m: Vec2,
    pub cov_m2: Option<Cov2>,
    pub class: ObjectClass,
    /// RGB in [0, 1].
    pub colour_rgb: Option<[f64; 3]>,
    /// Length, width, height.
    pub size_m: Option<[f64; 3]>,
    /// The box's heading (body frame) and speed, where reported.
    pub motion: Option<(f64, f64)>,
    /// The sender's own node (its self-report), not a camera detection.
    pub sender: bool,
    /// Its world position as the vehicle's GPS pose puts it.
    pub world_m: Option<Vec2>,
    pub appearance: Option<Arc<[f32]>>,
    /// Empty for a false positive (or a node without a truth row).
    pub object_id: String,
    /// The object's true centre, world frame.
    pub true_m: Option<Vec2>,
    pub visible_fraction: Option<f64>,
}

/// Why a dataset was refused: one line naming the file (and row).
#[derive(Debug, thiserror::Error)]
#[error("{file}: {why}")]
pub struct DatasetError {
    pub file: String,
    pub why: String,
}

pub(super) fn refuse(file: &str, why: impl Into<String>) -> DatasetError {
    DatasetError {
        file: file.to_owned(),
        why: why.into(),
    }
}

pub(super) const SIDES: [&str; 2] = ["first", "second"];

/// Reads `file` of `dir` (the `rows` of it, or all) as rows of `R`.
fn rows<R>(
    dir: &Path,
    file: &'static str,
    columns: &[(&str, &str)],
    range: Option<Range<usize>>,
    parse: impl FnOnce(crate::report::Table) -> Result<Vec<R>, String>,
) -> Result<Vec<R>, DatasetError> {
    let path = dir.join(file);
    if !path.exists() {
        return Err(refuse(file, "missing (not a coid dataset folder?)"));
    }
    let slice = range.map(|r| (r.start, r.len()));
    read_dataset_table(&path, columns, slice)
        .and_then(parse)
        .map_err(|why| refuse(file, why))
}

impl Dataset {
    /// Opens the dataset in `dir`: reads and checks its runs and instances,
    /// and finds each run's rows in the other files.
    pub fn open(dir: &Path) -> Result<Dataset, DatasetError> {
        let runs = read_runs(dir)?;
        let run_at: BTreeMap<u64, usize> =
            runs.iter().enumerate().map(|(k, r)| (r.run, k)).collect();
        let all = rows(dir, Instance::FILE, Instance::COLUMNS, None, Instance::rows)?;
        let (instances, levels) = group_instances(all, &run_at)?;
        for (k, (r, rows)) in runs.iter().zip(&instances).enumerate() {
            let n = rows.chunk_by(|a, b| a.instance == b.instance).count() as u64;
            if n != r.n_instances {
                return Err(refuse(
                    Run::FILE,
                    format!(
                        "row {}, column 'n_instances': {}, but instances.parquet holds {n} \
                         instances of run {}",
                        k + 1,
                        r.n_instances,
                        r.run
                    ),
                ));
            }
        }
        let mut optional_columns = Vec::new();
        let mut appearance_width = AppearanceWidth::NONE;
        for (file, columns) in [
            (Instance::FILE, Instance::COLUMNS),
            (Node::FILE, Node::COLUMNS),
            (Edge::FILE, Edge::COLUMNS),
            (Truth::FILE, Truth::COLUMNS),
            (TruePair::FILE, TruePair::COLUMNS),
        ] {
            // The first row (or none): which columns there are.
            let first = rows(dir, file, columns, Some(0..1), |t| Ok(vec![t]))?;
            for (name, ty) in columns {
                if ty.starts_with("Option") && first[0].column(name).is_some() {
                    optional_columns.push(format!("{file}: {name}"));
                }
            }
            if let Some(crate::report::TableColumn::Vectors(v)) = first[0].column("appearance") {
                appearance_width = AppearanceWidth::new(v.first().map_or(0, Vec::len));
            }
        }
        let ranges = [Node::FILE, Truth::FILE, TruePair::FILE]
            .map(|file| run_ranges(dir, file, &run_at))
            .into_iter()
            .collect::<Result<Vec<_>, _>>()?;
        let rows = (0..runs.len())
            .map(|k| std::array::from_fn(|f| ranges[f][k].clone()))
            .collect();
        Ok(Dataset {
            dir: dir.to_owned(),
            runs,
            levels,
            appearance_width,
            optional_columns,
            instances,
            rows,
        })
    }

    /// Reads and checks run `k` (of [`Dataset::runs`]).
    pub fn run(&self, k: usize) -> Result<DatasetRun, DatasetError> {
        let info = self.runs[k].clone();
        let [nodes, truth, pairs] = self.rows[k].clone();
        let mut instances = Vec::new();
        let mut index: BTreeMap<u64, usize> = BTreeMap::new();
        let rows = &self.instances[k];
        for group in rows.chunk_by(|a, b| a.instance == b.instance) {
            index.insert(group[0].instance, instances.len());
            instances.push(instance_of(group));
        }
        let locate = |file: &str, row: usize, instance: u64| {
            index.get(&instance).copied().ok_or_else(|| {
                refuse(
                    file,
                    format!(
                        "row {}: run {}, instance {instance} is not in instances.parquet",
                        row + 1,
                        info.run
                    ),
                )
            })
        };
        let first = nodes.start;
        let node_rows = rows_in(&self.dir, Node::FILE, Node::COLUMNS, nodes, Node::rows)?;
        for (k, n) in node_rows.into_iter().enumerate() {
            super::check::node(&n, first + k)?;
            let i = locate(Node::FILE, first + k, n.instance)?;
            self.add_node(&mut instances[i], n, first + k)?;
        }
        for (inst, group) in instances
            .iter()
            .zip(rows.chunk_by(|a, b| a.instance == b.instance))
        {
            check_node_counts(inst, &group[0], info.run)?;
        }
        let first = truth.start;
        let truth_rows = rows_in(&self.dir, Truth::FILE, Truth::COLUMNS, truth, Truth::rows)?;
        for (k, t) in truth_rows.into_iter().enumerate() {
            super::check::truth(&t, first + k)?;
            let i = locate(Truth::FILE, first + k, t.instance)?;
            add_truth(&mut instances[i], t, first + k)?;
        }
        for inst in &instances {
            check_unique_objects(inst, info.run)?;
        }
        let first = pairs.start;
        let pair_rows = rows_in(&self.dir, TruePair::FILE, TruePair::COLUMNS, pairs, |t| {
            TruePair::rows(t)
        })?;
        for (k, p) in pair_rows.into_iter().enumerate() {
            let i = locate(TruePair::FILE, first + k, p.instance)?;
            add_true_pair(&mut instances[i], &p, first + k)?;
        }
        for (inst, group) in instances
            .iter_mut()
            .zip(rows.chunk_by(|a, b| a.instance == b.instance))
        {
            set_poses(inst, group, info.run)?;
        }
        Ok(DatasetRun { info, instances })
    }

    fn add_node(
        &self,
        inst: &mut DatasetInstance,
        n: Node,
        row: usize,
    ) -> Result<(), DatasetError> {
        let Some(side) = inst.sides.get_mut(n.side as usize) else {
            return Err(refuse(
                Node::FILE,
                format!("row {}, column 'side': {}, not 0 or 1", row + 1, n.side),
            ));
        };
        if n.node != side.nodes.len() as u64 {
            return Err(refuse(
                Node::FILE,
                format!(
                    "row {}, column 'node': node {} where node {} comes next (each vehicle's \
                     nodes are numbered 0, 1, ... in order)",
                    row + 1,
                    n.node,
                    side.nodes.len()
                ),
            ));
        }
        if let (Some(a), Some(w)) = (&n.appearance, self.appearance_width.width())
            && a.len() != w
        {
            return Err(refuse(
                Node::FILE,
                format!(
                    "row {}, column 'appearance': {} values, the first row {w}",
                    row + 1,
                    a.len()
                ),
            ));
        }
        side.nodes.push(node_of(n));
        Ok(())
    }
}

/// Reads the `range` rows of `file` (none when the run has none there).
fn rows_in<R>(
    dir: &Path,
    file: &'static str,
    columns: &[(&str, &str)],
    range: Range<usize>,
    parse: impl FnOnce(crate::report::Table) -> Result<Vec<R>, String>,
) -> Result<Vec<R>, DatasetError> {
    if range.is_empty() {
        return Ok(Vec::new());
    }
    rows(dir, file, columns, Some(range), parse)
}

fn read_runs(dir: &Path) -> Result<Vec<RunInfo>, DatasetError> {
    let runs = rows(dir, Run::FILE, Run::COLUMNS, None, Run::rows)?;
    let mut out: Vec<RunInfo> = Vec::new();
    for (k, r) in runs.into_iter().enumerate() {
        let at = |why: String| refuse(Run::FILE, format!("row {}{why}", k + 1));
        if !(3..=SCHEMA_VERSION).contains(&r.schema_version) {
            return Err(at(format!(
                ": schema version {}; this coid reads versions 3 to {SCHEMA_VERSION}",
                r.schema_version
            )));
        }
        if !["train", "validation", "test"].contains(&r.split.as_str()) {
            return Err(at(format!(
                ", column 'split': '{}' is not train, validation or test",
                r.split
            )));
        }
        if out.iter().any(|o| o.run == r.run) {
            return Err(at(format!(": run {} twice", r.run)));
        }
        out.push(RunInfo {
            run: r.run,
            split: r.split,
            scenario: r.scenario,
            seed: r.seed,
            n_instances: r.n_instances,
        });
    }
    Ok(out)
}

/// Each run's instance rows, grouped by instance (levels in the dataset's
/// order), and the dataset's levels; refused when a row names an unknown
/// run or level, a level twice, or an instance lacks a level.
#[allow(clippy::type_complexity, reason = "a private pair of results")]
fn group_instances(
    all: Vec<Instance>,
    run_at: &BTreeMap<u64, usize>,
) -> Result<(Vec<Vec<Instance>>, Vec<PoseNoiseLevel>), DatasetError> {
    let file = Instance::FILE;
    let mut levels: Vec<PoseNoiseLevel> = Vec::new();
    let mut by_run: Vec<BTreeMap<u64, Vec<(usize, Instance)>>> =
        vec![BTreeMap::new(); run_at.len()];
    for (k, row) in all.into_iter().enumerate() {
        super::check::instance(&row, k)?;
        let at = |why: String| refuse(file, format!("row {}{why}", k + 1));
        let &r = run_at
            .get(&row.run)
            .ok_or_else(|| at(format!(": run {} is not in runs.parquet", row.run)))?;
        let label: PoseNoiseLabel = crate::label::parse("pose-noise level", &row.pose_noise)
            .map_err(|why| at(format!(", column 'pose_noise': {why}")))?;
        let level = match levels.iter().position(|l| l.label == label) {
            Some(p) => p,
            None => {
                levels.push(PoseNoiseLevel {
                    label,
                    position_sigma_m: row.position_sigma_m,
                    heading_sigma_rad: row.first_heading_sigma_rad,
                    correlation_s: None,
                });
                levels.len() - 1
            }
        };
        let rows = by_run[r].entry(row.instance).or_default();
        if rows.iter().any(|(l, _)| *l == level) {
            return Err(at(format!(
                ": run {}, instance {} at level '{}' twice",
                row.run, row.instance, row.pose_noise
            )));
        }
        rows.push((level, row));
    }
    let mut out = Vec::with_capacity(by_run.len());
    for run in by_run {
        let mut rows = Vec::new();
        for (_, mut group) in run {
            if group.len() < levels.len() {
                let row = &group[0].1;
                let missing = levels
                    .iter()
                    .enumerate()
                    .find(|(l, _)| !group.iter().any(|(g, _)| g == l))
                    .map(|(_, l)| l.label.as_str())
                    .unwrap_or_default();
                return Err(refuse(
                    file,
                    format!(
                        "run {}, instance {} has no row at level '{missing}' (every instance \
                         has one at every level of the dataset)",
                        row.run, row.instance
                    ),
                ));
            }
            group.sort_by_key(|(l, _)| *l);
            rows.extend(group.into_iter().map(|(_, r)| r));
        }
        out.push(rows);
    }
    Ok((out, levels))
}

/// Where each run's rows are in `file` (by its `run` column): refused when
/// a run's rows are not together or a row names an unknown run.
fn run_ranges(
    dir: &Path,
    file: &'static str,
    run_at: &BTreeMap<u64, usize>,
) -> Result<Vec<Range<usize>>, DatasetError> {
    let path = dir.join(file);
    if !path.exists() {
        return Err(refuse(file, "missing (not a coid dataset folder?)"));
    }
    let runs = read_dataset_counts(&path, "run").map_err(|why| refuse(file, why))?;
    let mut out: Vec<Option<Range<usize>>> = vec![None; run_at.len()];
    let mut start = 0;
    for (k, group) in runs.chunk_by(|a, b| a == b).map(|g| (g[0], g.len())) {
        let end = start + group;
        let &r = run_at.get(&k).ok_or_else(|| {
            refuse(
                file,
                format!("row {}: run {k} is not in runs.parquet", start + 1),
            )
        })?;
        if out[r].is_some() {
            return Err(refuse(
                file,
                format!(
                    "row {}: the rows of run {k} are not together (coid reads a dataset run by \
                     run: write each run's rows one after another)",
                    start + 1
                ),
            ));
        }
        out[r] = Some(start..end);
        start = end;
    }
    Ok(out.into_iter().map(|r| r.unwrap_or(0..0)).collect())
}
