//! A dataset from its files' rows given in memory (the Python package's
//! frames): each file's rows read as the reader reads them, the Delaunay
//! edges of every vehicle's nodes computed as coid's exports have them,
//! and the rows of each run in the files' order, ready for the writer.

use std::collections::BTreeMap;

use super::read::{DatasetError, refuse};
use super::schema::{Edge, Instance, Node, Run, TruePair, Truth};
use crate::geometry::Vec2;
use crate::graph::SceneGraph;
use crate::report::Table;

/// A dataset's files as tables, `edges.parquet` aside (coid computes it).
pub struct DatasetTables {
    pub runs: Table,
    pub instances: Table,
    pub nodes: Table,
    pub truth: Table,
    pub true_pairs: Table,
}

/// The files' columns, as each table is read: (file, columns).
pub fn columns() -> [(&'static str, &'static [(&'static str, &'static str)]); 5] {
    [
        (Run::FILE, Run::COLUMNS),
        (Instance::FILE, Instance::COLUMNS),
        (Node::FILE, Node::COLUMNS),
        (Truth::FILE, Truth::COLUMNS),
        (TruePair::FILE, TruePair::COLUMNS),
    ]
}

/// What is written: `runs.parquet`'s table, and each run's rows of the
/// instance files, in file order (as an export writes them run by run).
pub struct Assembled {
    pub runs: Table,
    pub n_runs: usize,
    pub n_instances: u64,
    pub by_run: Vec<[(&'static str, Table); 5]>,
}

/// The rows of `tables` checked to belong to the runs it names, with each
/// vehicle's Delaunay edges, by run.
///
/// # Errors
/// A table lacks a column or holds a value of another type, a row names a
/// run that `runs.parquet` does not, or a vehicle's nodes cannot be
/// triangulated.
pub fn assemble(tables: DatasetTables) -> Result<Assembled, DatasetError> {
    let parse = |file: &str, why: String| refuse(file, why);
    let runs = Run::rows(tables.runs).map_err(|w| parse(Run::FILE, w))?;
    let instances = Instance::rows(tables.instances).map_err(|w| parse(Instance::FILE, w))?;
    let nodes = Node::rows(tables.nodes).map_err(|w| parse(Node::FILE, w))?;
    let truth = Truth::rows(tables.truth).map_err(|w| parse(Truth::FILE, w))?;
    let pairs = TruePair::rows(tables.true_pairs).map_err(|w| parse(TruePair::FILE, w))?;
    let known: Vec<u64> = runs.iter().map(|r| r.run).collect();
    let named = |file: &str, rows: &mut dyn Iterator<Item = u64>| match rows
        .enumerate()
        .find(|(_, run)| !known.contains(run))
    {
        Some((k, run)) => Err(refuse(
            file,
            format!("row {}: run {run} is not in runs.parquet", k + 1),
        )),
        None => Ok(()),
    };
    named(Instance::FILE, &mut instances.iter().map(|r| r.run))?;
    named(Node::FILE, &mut nodes.iter().map(|r| r.run))?;
    named(Truth::FILE, &mut truth.iter().map(|r| r.run))?;
    named(TruePair::FILE, &mut pairs.iter().map(|r| r.run))?;
    // The reader's own checks of a node (finite positions, covariances,
    // ...) before its graph is built.
    for (row, n) in nodes.iter().enumerate() {
        super::check::node(n, row)?;
    }
    let edges = edges(&nodes)?;
    let n_instances = runs.iter().map(|r| r.n_instances).sum();
    let by_run = runs
        .iter()
        .map(|r| {
            let of = |run: u64| run == r.run;
            [
                (
                    Instance::FILE,
                    Instance::table(kept(&instances, |x| of(x.run))),
                ),
                (Node::FILE, Node::table(kept(&nodes, |x| of(x.run)))),
                (Edge::FILE, Edge::table(kept(&edges, |x| of(x.run)))),
                (Truth::FILE, Truth::table(kept(&truth, |x| of(x.run)))),
                (TruePair::FILE, TruePair::table(kept(&pairs, |x| of(x.run)))),
            ]
        })
        .collect();
    Ok(Assembled {
        n_runs: runs.len(),
        runs: Run::table(runs),
        n_instances,
        by_run,
    })
}

/// The rows `keep` keeps, in order.
fn kept<T: Clone>(rows: &[T], keep: impl Fn(&T) -> bool) -> Vec<T> {
    rows.iter().filter(|r| keep(r)).cloned().collect()
}

/// A vehicle of an instance: (run, instance, side).
type VehicleKey = (u64, u64, u64);
/// A node's index, body-frame position and row in `nodes.parquet`.
type NodeAt = (u64, Vec2, usize);

/// Each vehicle's Delaunay graph over its nodes' body-frame positions (in
/// node order), as edge rows: vehicles in the order their nodes come,
/// each edge once, `source < target`.
fn edges(nodes: &[Node]) -> Result<Vec<Edge>, DatasetError> {
    let mut order: Vec<VehicleKey> = Vec::new();
    let mut of: BTreeMap<VehicleKey, Vec<NodeAt>> = BTreeMap::new();
    for (row, n) in nodes.iter().enumerate() {
        let key = (n.run, n.instance, n.side);
        let side = of.entry(key).or_insert_with(|| {
            order.push(key);
            Vec::new()
        });
        side.push((n.node, Vec2::new(n.x_m, n.y_m), row));
    }
    let mut out = Vec::new();
    for key in order {
        let mut side = of.remove(&key).unwrap_or_default();
        side.sort_by_key(|(node, _, _)| *node);
        let positions: Vec<Vec2> = side.iter().map(|(_, p, _)| *p).collect();
        let graph = SceneGraph::delaunay(&positions).map_err(|e| {
            refuse(
                Node::FILE,
                format!("row {}: {e}", side.get(e.index).map_or(0, |s| s.2) + 1),
            )
        })?;
        let (run, instance, side_k) = key;
        out.extend(graph.edges.iter().map(|e| Edge {
            run,
            instance,
            side: side_k,
            source: side[e.a.min(e.b)].0,
            target: side[e.a.max(e.b)].0,
            length_m: e.length_m,
        }));
    }
    Ok(out)
}
