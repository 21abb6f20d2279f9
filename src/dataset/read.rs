//! A dataset folder read back and checked: every file's declared columns
//! (optional ones where present), every row's instance known, each
//! vehicle's nodes numbered 0..n as its instance says, one truth per node
//! with an object id at most once per vehicle, and true pairs that match
//! each node at most once and agree with the object ids. A folder that
//! does not fit is refused with one line naming the file and row.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::SCHEMA_VERSION;
use super::schema::{Edge, Instance, Node, Run, TruePair, Truth};
use crate::geometry::Vec2;
use crate::io::frames::read_dataset_table;
use crate::report::{Table, TableColumn};

/// A dataset, read and checked.
#[derive(Debug)]
#[allow(
    dead_code,
    reason = "the evaluation of datasets reads every field; `coid dataset` some"
)]
pub struct Dataset {
    pub dir: PathBuf,
    pub runs: Vec<DatasetRun>,
    /// The length of every node's appearance vector, if the nodes have one.
    pub appearance_width: Option<usize>,
    /// The optional columns present, as `file: column`.
    pub optional_columns: Vec<String>,
}

#[derive(Debug)]
#[allow(
    dead_code,
    reason = "the evaluation of datasets reads every field; `coid dataset` some"
)]
pub struct DatasetRun {
    pub run: u64,
    pub split: String,
    pub scenario: String,
    pub instances: Vec<DatasetInstance>,
}

#[derive(Debug)]
#[allow(
    dead_code,
    reason = "the evaluation of datasets reads every field; `coid dataset` some"
)]
pub struct DatasetInstance {
    pub instance: u64,
    pub step: u64,
    /// The pose-noise levels it has a row at.
    pub levels: Vec<String>,
    pub sides: [DatasetSide; 2],
    /// Node `a` of the first vehicle is node `b` of the second.
    pub true_pairs: Vec<(usize, usize)>,
}

#[derive(Debug, Default)]
#[allow(
    dead_code,
    reason = "the evaluation of datasets reads every field; `coid dataset` some"
)]
pub struct DatasetSide {
    pub id: String,
    pub nodes: Vec<DatasetNode>,
}

#[derive(Debug, Clone)]
#[allow(
    dead_code,
    reason = "the evaluation of datasets reads every field; `coid dataset` some"
)]
pub struct DatasetNode {
    /// Measured centre, the vehicle's body frame.
    pub position_m: Vec2,
    pub class: String,
    /// Empty for a false positive.
    pub object_id: String,
    /// Its world position as the vehicle's GPS pose puts it.
    pub world_m: Option<Vec2>,
    pub appearance: Option<Vec<f32>>,
}

/// Why a dataset was refused: one line naming the file (and row).
#[derive(Debug, thiserror::Error)]
#[error("{file}: {why}")]
pub struct DatasetError {
    pub file: String,
    pub why: String,
}

fn refuse(file: &str, why: impl Into<String>) -> DatasetError {
    DatasetError {
        file: file.to_owned(),
        why: why.into(),
    }
}

/// A table's columns by name, read as their declared types.
struct Columns<'t> {
    file: &'static str,
    table: &'t Table,
}

impl<'t> Columns<'t> {
    fn count(&self, name: &str) -> &'t [u64] {
        match self.table.column(name) {
            Some(TableColumn::Count(v)) => v,
            _ => &[],
        }
    }

    fn number(&self, name: &str) -> Option<&'t [f64]> {
        match self.table.column(name) {
            Some(TableColumn::Number(v)) => Some(v),
            _ => None,
        }
    }

    fn text(&self, name: &str) -> &'t [String] {
        match self.table.column(name) {
            Some(TableColumn::Text(v)) => v,
            _ => &[],
        }
    }

    fn vectors(&self, name: &str) -> Option<&'t [Vec<f32>]> {
        match self.table.column(name) {
            Some(TableColumn::Vectors(v)) => Some(v),
            _ => None,
        }
    }
}

fn table(dir: &Path, file: &'static str, columns: &[(&str, &str)]) -> Result<Table, DatasetError> {
    let path = dir.join(file);
    if !path.exists() {
        return Err(refuse(file, "missing (not a coid dataset folder?)"));
    }
    read_dataset_table(&path, columns).map_err(|why| refuse(file, why))
}

/// Reads and checks the dataset in `dir`.
pub fn read(dir: &Path) -> Result<Dataset, DatasetError> {
    let runs_t = table(dir, Run::FILE, Run::COLUMNS)?;
    let runs = Columns {
        file: Run::FILE,
        table: &runs_t,
    };
    let mut out = Dataset {
        dir: dir.to_owned(),
        runs: Vec::new(),
        appearance_width: None,
        optional_columns: Vec::new(),
    };
    let mut run_at: BTreeMap<u64, usize> = BTreeMap::new();
    for (k, &run) in runs.count("run").iter().enumerate() {
        let version = runs.count("schema_version")[k];
        if !(3..=SCHEMA_VERSION).contains(&version) {
            return Err(refuse(
                runs.file,
                format!(
                    "row {}: schema version {version}; this coid reads versions 3 to {SCHEMA_VERSION}",
                    k + 1
                ),
            ));
        }
        let split = runs.text("split")[k].clone();
        if !["train", "validation", "test"].contains(&split.as_str()) {
            return Err(refuse(
                runs.file,
                format!(
                    "row {}, column 'split': '{split}' is not train, validation or test",
                    k + 1
                ),
            ));
        }
        if run_at.insert(run, out.runs.len()).is_some() {
            return Err(refuse(runs.file, format!("row {}: run {run} twice", k + 1)));
        }
        out.runs.push(DatasetRun {
            run,
            split,
            scenario: runs.text("scenario")[k].clone(),
            instances: Vec::new(),
        });
    }
    let instances_t = table(dir, Instance::FILE, Instance::COLUMNS)?;
    let nodes_t = table(dir, Node::FILE, Node::COLUMNS)?;
    let truth_t = table(dir, Truth::FILE, Truth::COLUMNS)?;
    let pairs_t = table(dir, TruePair::FILE, TruePair::COLUMNS)?;
    table(dir, Edge::FILE, Edge::COLUMNS)?;
    for (file, t, columns) in [
        (Instance::FILE, &instances_t, Instance::COLUMNS),
        (Node::FILE, &nodes_t, Node::COLUMNS),
        (Truth::FILE, &truth_t, Truth::COLUMNS),
    ] {
        for (name, ty) in columns {
            if ty.starts_with("Option") && t.column(name).is_some() {
                out.optional_columns.push(format!("{file}: {name}"));
            }
        }
    }
    let mut index: BTreeMap<(u64, u64), (usize, usize)> = BTreeMap::new();
    let declared = read_instances(&instances_t, &run_at, &mut out, &mut index)?;
    read_nodes(&nodes_t, &index, declared, &mut out)?;
    read_truth(&truth_t, &index, &mut out)?;
    read_true_pairs(&pairs_t, &index, &mut out)?;
    Ok(out)
}

/// Where `(run, instance)` is in `out`, or the reason in one line.
fn locate(
    file: &str,
    row: usize,
    index: &BTreeMap<(u64, u64), (usize, usize)>,
    run: u64,
    instance: u64,
) -> Result<(usize, usize), DatasetError> {
    index.get(&(run, instance)).copied().ok_or_else(|| {
        refuse(
            file,
            format!(
                "row {}: run {run}, instance {instance} is not in instances.parquet",
                row + 1
            ),
        )
    })
}

fn read_instances(
    t: &Table,
    run_at: &BTreeMap<u64, usize>,
    out: &mut Dataset,
    index: &mut BTreeMap<(u64, u64), (usize, usize)>,
) -> Result<Declared, DatasetError> {
    let mut declared = Declared::new();
    let c = Columns {
        file: Instance::FILE,
        table: t,
    };
    let (runs, instances) = (c.count("run"), c.count("instance"));
    for k in 0..runs.len() {
        let (run, instance) = (runs[k], instances[k]);
        let &r = run_at.get(&run).ok_or_else(|| {
            refuse(
                c.file,
                format!("row {}: run {run} is not in runs.parquet", k + 1),
            )
        })?;
        let level = c.text("pose_noise")[k].clone();
        if let Some(&(r, i)) = index.get(&(run, instance)) {
            let inst = &mut out.runs[r].instances[i];
            if inst.levels.contains(&level) {
                return Err(refuse(
                    c.file,
                    format!(
                        "row {}: run {run}, instance {instance} at level '{level}' twice",
                        k + 1
                    ),
                ));
            }
            inst.levels.push(level);
            continue;
        }
        let n = [c.count("n_first")[k], c.count("n_second")[k]];
        let ids = [
            c.text("first_id")[k].clone(),
            c.text("second_id")[k].clone(),
        ];
        let sides = [0, 1].map(|s| DatasetSide {
            id: ids[s].clone(),
            nodes: Vec::with_capacity(n[s] as usize),
        });
        let run_rows = &mut out.runs[r].instances;
        index.insert((run, instance), (r, run_rows.len()));
        run_rows.push(DatasetInstance {
            instance,
            step: c.count("step")[k],
            levels: vec![level],
            sides,
            true_pairs: Vec::new(),
        });
        declared.insert((run, instance), n);
    }
    Ok(declared)
}

/// Each instance's node counts as `instances.parquet` declares them.
type Declared = BTreeMap<(u64, u64), [u64; 2]>;

fn read_nodes(
    t: &Table,
    index: &BTreeMap<(u64, u64), (usize, usize)>,
    declared: Declared,
    out: &mut Dataset,
) -> Result<(), DatasetError> {
    let c = Columns {
        file: Node::FILE,
        table: t,
    };
    let (runs, instances, sides, nodes) = (
        c.count("run"),
        c.count("instance"),
        c.count("side"),
        c.count("node"),
    );
    let (x, y) = (
        c.number("x_m").unwrap_or(&[]),
        c.number("y_m").unwrap_or(&[]),
    );
    let world = c.number("world_x_m").zip(c.number("world_y_m"));
    let appearance = c.vectors("appearance");
    for k in 0..runs.len() {
        let (r, i) = locate(c.file, k, index, runs[k], instances[k])?;
        let side = sides[k];
        if side > 1 {
            return Err(refuse(
                c.file,
                format!("row {}, column 'side': {side}, not 0 or 1", k + 1),
            ));
        }
        let list = &mut out.runs[r].instances[i].sides[side as usize].nodes;
        if nodes[k] != list.len() as u64 {
            return Err(refuse(
                c.file,
                format!(
                    "row {}, column 'node': node {} where node {} comes next (each vehicle's nodes are numbered 0, 1, ... in order)",
                    k + 1,
                    nodes[k],
                    list.len()
                ),
            ));
        }
        let a = appearance.map(|a| a[k].clone());
        if let Some(a) = &a {
            match out.appearance_width {
                Some(w) if w != a.len() => {
                    return Err(refuse(
                        c.file,
                        format!(
                            "row {}, column 'appearance': {} values, earlier rows {w}",
                            k + 1,
                            a.len()
                        ),
                    ));
                }
                _ => out.appearance_width = Some(a.len()),
            }
        }
        list.push(DatasetNode {
            position_m: Vec2::new(x[k], y[k]),
            class: c.text("class")[k].clone(),
            object_id: String::new(),
            world_m: world.map(|(wx, wy)| Vec2::new(wx[k], wy[k])),
            appearance: a,
        });
    }
    for ((run, instance), n) in declared {
        let (r, i) = index[&(run, instance)];
        for (s, side) in out.runs[r].instances[i].sides.iter().enumerate() {
            if side.nodes.len() as u64 != n[s] {
                return Err(refuse(
                    c.file,
                    format!(
                        "run {run}, instance {instance}: {} nodes of the {} vehicle, instances.parquet says {}",
                        side.nodes.len(),
                        ["first", "second"][s],
                        n[s]
                    ),
                ));
            }
        }
    }
    Ok(())
}

fn read_truth(
    t: &Table,
    index: &BTreeMap<(u64, u64), (usize, usize)>,
    out: &mut Dataset,
) -> Result<(), DatasetError> {
    let c = Columns {
        file: Truth::FILE,
        table: t,
    };
    let (runs, instances, sides, nodes) = (
        c.count("run"),
        c.count("instance"),
        c.count("side"),
        c.count("node"),
    );
    let ids = c.text("object_id");
    let mut seen = vec![];
    for k in 0..runs.len() {
        let (r, i) = locate(c.file, k, index, runs[k], instances[k])?;
        let side = sides[k].min(2) as usize;
        let Some(list) = out.runs[r].instances[i].sides.get_mut(side) else {
            return Err(refuse(
                c.file,
                format!("row {}, column 'side': not 0 or 1", k + 1),
            ));
        };
        let Some(node) = list.nodes.get_mut(nodes[k] as usize) else {
            return Err(refuse(
                c.file,
                format!(
                    "row {}, column 'node': node {} is not in nodes.parquet",
                    k + 1,
                    nodes[k]
                ),
            ));
        };
        let id = &ids[k];
        if !id.is_empty() {
            let key = (runs[k], instances[k], side, id.clone());
            seen.push((key, k));
        }
        node.object_id.clone_from(id);
    }
    seen.sort();
    if let Some(w) = seen.windows(2).find(|w| w[0].0 == w[1].0) {
        let (run, instance, side, id) = &w[1].0;
        return Err(refuse(
            c.file,
            format!(
                "row {}: object '{id}' behind two nodes of the {} vehicle of run {run}, instance {instance}",
                w[1].1 + 1,
                ["first", "second"][*side]
            ),
        ));
    }
    Ok(())
}

fn read_true_pairs(
    t: &Table,
    index: &BTreeMap<(u64, u64), (usize, usize)>,
    out: &mut Dataset,
) -> Result<(), DatasetError> {
    let c = Columns {
        file: TruePair::FILE,
        table: t,
    };
    let (runs, instances, a, b) = (
        c.count("run"),
        c.count("instance"),
        c.count("a"),
        c.count("b"),
    );
    for k in 0..runs.len() {
        let (r, i) = locate(c.file, k, index, runs[k], instances[k])?;
        let inst = &mut out.runs[r].instances[i];
        let (a, b) = (a[k] as usize, b[k] as usize);
        for (s, node) in [(0, a), (1, b)] {
            if node >= inst.sides[s].nodes.len() {
                return Err(refuse(
                    c.file,
                    format!(
                        "row {}: node {node} of the {} vehicle is not in nodes.parquet",
                        k + 1,
                        ["first", "second"][s]
                    ),
                ));
            }
            let again = inst
                .true_pairs
                .iter()
                .any(|&(x, y)| if s == 0 { x == node } else { y == node });
            if again {
                return Err(refuse(
                    c.file,
                    format!(
                        "row {}: node {node} of the {} vehicle of run {}, instance {} is matched a second time",
                        k + 1,
                        ["first", "second"][s],
                        runs[k],
                        instances[k]
                    ),
                ));
            }
        }
        let (ia, ib) = (
            &inst.sides[0].nodes[a].object_id,
            &inst.sides[1].nodes[b].object_id,
        );
        if ia.is_empty() || ia != ib {
            return Err(refuse(
                c.file,
                format!(
                    "row {}: pairs node {a} (object '{ia}') with node {b} (object '{ib}'), not one object",
                    k + 1
                ),
            ));
        }
        inst.true_pairs.push((a, b));
    }
    Ok(())
}
