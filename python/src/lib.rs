//! `coid_sim._coid_sim`: coid inside the Python that imports it. The
//! commands run in-process exactly as the `coid` binary runs them (same
//! code, same files, same numbers); datasets are read by coid's own
//! reader and handed over as plain Python values (lists, dicts, floats),
//! which the package (`src_py/coid_sim`) turns into numpy arrays and
//! polars frames. Every failure is a `CoidError` carrying the line `coid`
//! prints; long work runs with the GIL released (SUMO's thread takes it
//! when it needs it).

use std::path::PathBuf;

mod commands;

use commands::interruptible;

use coid_sim::dataset::Dataset;
use coid_sim::dataset::read::{DatasetInstance, DatasetNode, DatasetRun, DatasetSide};
use coid_sim::geometry::Vec2;
use coid_sim::graph::SceneGraph;
use coid_sim::matching::Method;
use coid_sim::matching::deep::{GraphParts, PublishedForward};
use coid_sim::sensor::AppearanceWidth;
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

create_exception!(
    coid_sim,
    CoidError,
    PyException,
    "coid refused its input or failed; the message is the line the `coid` command prints."
);

pub(crate) fn coid_error(e: &anyhow::Error) -> PyErr {
    CoidError::new_err(coid_sim::cli::one_line(e))
}

/// `coid` as a program (`python -m coid_sim`, the `coid` script, a
/// batch's workers): `argv` with the program's name first; prints what
/// the binary prints and returns its exit code. Takes the process's
/// signals as the binary does: call it only as the main program.
#[pyfunction]
fn main(py: Python<'_>, argv: Vec<String>) -> i32 {
    coid_sim::cli::prepare_main_process();
    let cli = match coid_sim::cli::try_parse(argv) {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return e.exit_code();
        }
    };
    match py.detach(|| coid_sim::cli::execute(cli)) {
        Ok(_) => 0,
        Err(e) => {
            eprintln!("error: {}", coid_sim::cli::one_line(&e));
            1
        }
    }
}

/// Runs one `coid` command line in this process (`argv` with the
/// program's name first), leaving the interpreter's signals alone.
/// Returns the command's last line (`run`'s headline), if it has one.
/// The command runs in a thread of its own while this one, the
/// interpreter's, looks for its signals: Ctrl-C stops the command at its
/// next SUMO step and raises `KeyboardInterrupt`.
#[pyfunction]
fn call(py: Python<'_>, argv: Vec<String>) -> PyResult<Option<String>> {
    let cli = match coid_sim::cli::try_parse(argv) {
        Ok(cli) => cli,
        // Help and version: printed as the program prints them.
        Err(e) if e.exit_code() == 0 => {
            let _ = e.print();
            return Ok(None);
        }
        Err(e) => {
            let text = e.to_string();
            let line = text
                .lines()
                .find_map(|l| l.strip_prefix("error: "))
                .unwrap_or("no command given (cli(\"--help\") lists them)");
            return Err(CoidError::new_err(line.to_owned()));
        }
    };
    interruptible(py, || coid_sim::cli::execute(cli))
}

/// A JSON object (a configuration given as a dict) as TOML text.
#[pyfunction]
fn toml_of_json(json: &str) -> PyResult<String> {
    let value: toml::Value = serde_json::from_str(json).map_err(|e| {
        CoidError::new_err(format!(
            "the configuration dict is not TOML-shaped (tables of numbers, text, booleans and \
             lists): {e}"
        ))
    })?;
    toml::to_string(&value)
        .map_err(|e| CoidError::new_err(format!("the configuration is not TOML-shaped: {e}")))
}

/// Every built-in method's label, in the tables' order.
#[pyfunction]
fn methods() -> Vec<&'static str> {
    coid_sim::matching::Method::all()
        .iter()
        .map(|m| m.as_str())
        .collect()
}

/// The Delaunay graph coid's matchers build over these positions (metres,
/// one vehicle's body frame): each undirected edge once, `a < b`.
#[pyfunction]
fn delaunay(positions_m: Vec<[f64; 2]>) -> PyResult<Vec<(usize, usize)>> {
    let points: Vec<Vec2> = positions_m.iter().map(|p| Vec2::new(p[0], p[1])).collect();
    let graph = SceneGraph::delaunay(&points).map_err(|e| CoidError::new_err(e.to_string()))?;
    Ok(graph.edges.iter().map(|e| (e.a, e.b)).collect())
}

/// A dataset folder, checked and opened by coid's reader.
#[pyclass(frozen)]
struct DatasetReader {
    dataset: Dataset,
}

#[pymethods]
impl DatasetReader {
    #[new]
    fn new(py: Python<'_>, dir: PathBuf) -> PyResult<Self> {
        let dataset = py.detach(|| Dataset::open(&dir)).map_err(|e| {
            CoidError::new_err(format!("{} is not a usable dataset: {e}", dir.display()))
        })?;
        Ok(DatasetReader { dataset })
    }

    /// Runs, levels, appearance width and optional columns.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = &self.dataset;
        let out = PyDict::new(py);
        let runs = PyList::empty(py);
        for r in &d.runs {
            let run = PyDict::new(py);
            run.set_item("run", r.run)?;
            run.set_item("split", &r.split)?;
            run.set_item("scenario", &r.scenario)?;
            run.set_item("seed", r.seed)?;
            run.set_item("n_instances", r.n_instances)?;
            runs.append(run)?;
        }
        out.set_item("runs", runs)?;
        let levels: Vec<(String, f64)> = d
            .levels
            .iter()
            .map(|l| (l.label.as_str().to_owned(), l.position_sigma_m))
            .collect();
        out.set_item("levels", levels)?;
        out.set_item("appearance_width", d.appearance_width.width())?;
        out.set_item("optional_columns", d.optional_columns.clone())?;
        Ok(out)
    }

    /// The `k`-th run (in `runs.parquet`'s order), every instance as
    /// plain values.
    fn run<'py>(&self, py: Python<'py>, k: usize) -> PyResult<Bound<'py, PyList>> {
        if k >= self.dataset.runs.len() {
            return Err(CoidError::new_err(format!(
                "{} has {} runs, not {}",
                self.dataset.dir.display(),
                self.dataset.runs.len(),
                k + 1
            )));
        }
        let run: DatasetRun = py.detach(|| self.dataset.run(k)).map_err(|e| {
            CoidError::new_err(format!(
                "{} is not a usable dataset: {e}",
                self.dataset.dir.display()
            ))
        })?;
        let out = PyList::empty(py);
        for inst in &run.instances {
            out.append(instance(py, &self.dataset, inst)?)?;
        }
        Ok(out)
    }
}

fn instance<'py>(
    py: Python<'py>,
    dataset: &Dataset,
    inst: &DatasetInstance,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("instance", inst.instance)?;
    d.set_item("step", inst.step)?;
    d.set_item("time_s", inst.time_s)?;
    let levels = PyList::empty(py);
    for l in &inst.levels {
        let level = PyDict::new(py);
        level.set_item("label", l.label.as_str())?;
        level.set_item("position_sigma_m", l.position_sigma_m)?;
        level.set_item("heading_sigma_rad", l.heading_sigma_rad.to_vec())?;
        let poses: Vec<[f64; 3]> = (0..2)
            .map(|s| pose(&l.reported[s], l.reported_heading_rad[s]))
            .collect();
        level.set_item("reported", poses)?;
        levels.append(level)?;
    }
    d.set_item("levels", levels)?;
    let true_poses: Vec<Option<[f64; 3]>> = (0..2)
        .map(|s| {
            Some(pose(
                inst.true_poses[s].as_ref()?,
                inst.true_heading_rad[s]?,
            ))
        })
        .collect();
    d.set_item("true_poses", true_poses)?;
    let sides = PyList::empty(py);
    for s in &inst.sides {
        sides.append(side(py, dataset, s)?)?;
    }
    d.set_item("sides", sides)?;
    d.set_item("true_pairs", inst.true_pairs.clone())?;
    Ok(d)
}

/// A pose as (x, y, heading), the heading as the dataset gives it.
fn pose(p: &coid_sim::geometry::Pose2, heading_rad: f64) -> [f64; 3] {
    let t = p.position_m();
    [t.x, t.y, heading_rad]
}

/// One vehicle's nodes, column by column: a column the dataset lacks is
/// `None`; where a node lacks a value of a column the dataset has (a
/// false positive's true centre), its value is NaN, its appearance
/// vector zeros (coid's "none").
fn side<'py>(py: Python<'py>, d: &Dataset, s: &DatasetSide) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    let n = &s.nodes;
    let has = |column: &str| {
        d.optional_columns
            .iter()
            .any(|c| c.ends_with(&format!(": {column}")))
    };
    out.set_item("id", &s.id)?;
    let col = |column: &str, width: usize, f: &dyn Fn(&DatasetNode) -> Option<Vec<f64>>| {
        has(column).then(|| {
            n.iter()
                .map(|v| f(v).unwrap_or_else(|| vec![f64::NAN; width]))
                .collect::<Vec<_>>()
        })
    };
    let xy: Vec<[f64; 2]> = n.iter().map(|v| [v.position_m.x, v.position_m.y]).collect();
    out.set_item("xy_m", xy)?;
    out.set_item(
        "network_features",
        coid_sim::pipeline::network_node_attributes(s),
    )?;
    out.set_item(
        "cov_m2",
        col("cov_xx_m2", 3, &|v| {
            v.cov_m2.map(|c| vec![c[(0, 0)], c[(0, 1)], c[(1, 1)]])
        }),
    )?;
    let classes: Vec<&str> = n.iter().map(|v| v.class.as_str()).collect();
    out.set_item("class", classes)?;
    out.set_item(
        "colour_rgb",
        col("colour_r", 3, &|v| v.colour_rgb.map(|c| c.to_vec())),
    )?;
    out.set_item(
        "size_m",
        col("length_m", 3, &|v| v.size_m.map(|c| c.to_vec())),
    )?;
    out.set_item(
        "heading_speed",
        col("heading_rad", 2, &|v| v.motion.map(|(h, s)| vec![h, s])),
    )?;
    let senders: Vec<bool> = n.iter().map(|v| v.sender).collect();
    out.set_item("sender", senders)?;
    out.set_item(
        "world_m",
        col("world_x_m", 2, &|v| v.world_m.map(|w| vec![w.x, w.y])),
    )?;
    let appearance: Option<Vec<Vec<f32>>> = d.appearance_width.width().map(|width| {
        n.iter()
            .map(|v| {
                v.appearance
                    .as_ref()
                    .map_or_else(|| vec![0.0; width], |a| a.to_vec())
            })
            .collect()
    });
    out.set_item("appearance", appearance)?;
    let ids: Vec<&str> = n.iter().map(|v| v.object_id.as_str()).collect();
    out.set_item("object_id", ids)?;
    out.set_item(
        "true_m",
        col("true_x_m", 2, &|v| v.true_m.map(|t| vec![t.x, t.y])),
    )?;
    out.set_item(
        "visible_fraction",
        col("visible_fraction", 1, &|v| {
            v.visible_fraction.map(|f| vec![f])
        }),
    )?;
    Ok(out)
}

/// A published network (`gcn-gm`, `dgmc`, `coid`, ...) with its weights,
/// its forward pass run with the dropout masks and consensus indicators
/// the caller gives: what `tools/dgmc_reference` holds DGMC's PyTorch
/// code to. Not used by any command.
/// The shape (graph, edge scale, indicator width) the record beside
/// `weights` (`<method>.toml` in its folder) gives its network; the
/// default one when there is no record.
fn record_shape(
    weights: &std::path::Path,
    method: Method,
) -> PyResult<coid_sim::matching::deep::arch::NetworkShape> {
    use coid_sim::matching::deep::arch::{Backbone, NetworkShape};
    let path = weights.with_file_name(format!("{}.toml", method.weights_owner().as_str()));
    if !path.is_file() {
        return Ok(NetworkShape::default());
    }
    let bad = |why: String| CoidError::new_err(format!("{}: {why}", path.display()));
    let text = std::fs::read_to_string(&path).map_err(|e| bad(e.to_string()))?;
    let table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| bad(e.to_string()))?;
    let architecture = table
        .get("architecture")
        .cloned()
        .ok_or_else(|| bad("no [architecture] table".into()))?;
    let backbone: Backbone = architecture
        .try_into()
        .map_err(|e: toml::de::Error| bad(e.to_string()))?;
    Ok(backbone.shape())
}

#[pyclass(frozen)]
struct PublishedNetwork {
    net: PublishedForward,
}

#[pymethods]
impl PublishedNetwork {
    /// `method`'s network with the weights of the `.bpk` file `weights`,
    /// reading appearance vectors `appearance_width` wide (0: none),
    /// computing `samples` samples per pair; of the shape (edge scale,
    /// indicator width) its record beside it (`<method>.toml`) gives,
    /// or the default one without a record.
    #[new]
    #[pyo3(signature = (weights, method, appearance_width = 0, samples = 1))]
    fn new(
        weights: PathBuf,
        method: &str,
        appearance_width: usize,
        samples: usize,
    ) -> PyResult<Self> {
        let method: Method = method
            .parse()
            .map_err(|_| CoidError::new_err(format!("no method {method:?}")))?;
        let bytes = std::fs::read(&weights)
            .map_err(|e| CoidError::new_err(format!("cannot read {}: {e}", weights.display())))?;
        let width = AppearanceWidth::new(appearance_width);
        let shape = record_shape(&weights, method)?;
        let net = PublishedForward::new(method, width, shape, &bytes, samples).map_err(|e| {
            CoidError::new_err(format!(
                "{} does not fit {}: {e}",
                weights.display(),
                method.as_str()
            ))
        })?;
        Ok(Self { net })
    }

    /// The bytes of a `.bpk` weights file of `method`'s network with the
    /// parameters `parameters` (by name: `(shape, values)`, as
    /// `parameters()` gives them), for coid to run weights trained
    /// elsewhere.
    #[staticmethod]
    #[pyo3(signature = (method, parameters, appearance_width = 0))]
    fn weights_of<'py>(
        py: Python<'py>,
        method: &str,
        parameters: std::collections::HashMap<String, (Vec<usize>, Vec<f32>)>,
        appearance_width: usize,
    ) -> PyResult<Bound<'py, pyo3::types::PyBytes>> {
        let method: Method = method
            .parse()
            .map_err(|_| CoidError::new_err(format!("no method {method:?}")))?;
        let named = parameters
            .into_iter()
            .map(|(k, (shape, v))| (k, shape, v))
            .collect();
        let width = AppearanceWidth::new(appearance_width);
        let bytes = py
            .detach(|| coid_sim::matching::deep::train::published_weights(method, width, named))
            .map_err(CoidError::new_err)?;
        Ok(pyo3::types::PyBytes::new(py, &bytes))
    }

    /// The architecture, as its record writes it.
    fn config<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.net.config();
        let d = PyDict::new(py);
        d.set_item(
            "kind",
            if c.consensus_steps() > 0 {
                "dgmc"
            } else {
                "gcn-gm"
            },
        )?;
        d.set_item("node_features", c.node_features())?;
        d.set_item("hidden", c.hidden)?;
        d.set_item("out", c.out)?;
        d.set_item("dropout_conv", c.dropout_conv)?;
        d.set_item("consensus_dim", c.consensus_dim)?;
        d.set_item("consensus_steps", c.consensus_steps())?;
        d.set_item("sinkhorn_iters", c.sinkhorn_iters)?;
        d.set_item("edge_scale_m", c.edge_scale_m)?;
        Ok(d)
    }

    /// Every parameter by its name in the weights file: `(shape, values)`,
    /// values row-major (a linear layer's weight `[in, out]`, a spline
    /// convolution's `[in, knots * out]`).
    fn parameters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, shape, values) in self.net.parameters() {
            d.set_item(name, (shape, values))?;
        }
        Ok(d)
    }

    /// Each sample's `(n1 + 1) x (n2 + 1)` assignment (row-major, dustbins
    /// last) for two graphs given as `(node_features, edges, lengths_m)`:
    /// `n x width` attributes row-major, each undirected edge once;
    /// `masks`: psi_1's hidden-channel dropout masks, `samples x n x
    /// hidden` per graph; `indicators`: one `samples x n1 x consensus_dim`
    /// draw per consensus step.
    fn forward(
        &self,
        py: Python<'_>,
        first: (Vec<f32>, Vec<(usize, usize)>, Vec<f64>),
        second: (Vec<f32>, Vec<(usize, usize)>, Vec<f64>),
        masks: (Vec<f32>, Vec<f32>),
        indicators: Vec<Vec<f32>>,
    ) -> PyResult<Vec<Vec<f32>>> {
        let parts = |(node_features, edges, length_m)| GraphParts {
            node_features,
            edges,
            length_m,
        };
        let (g1, g2) = (parts(first), parts(second));
        py.detach(|| {
            self.net
                .forward([&g1, &g2], [&masks.0, &masks.1], &indicators)
        })
        .map_err(CoidError::new_err)
    }
}

#[pymodule]
fn _coid_sim(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("CoidError", m.py().get_type::<CoidError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("SCHEMA_VERSION", coid_sim::dataset::SCHEMA_VERSION)?;
    m.add_function(wrap_pyfunction!(main, m)?)?;
    m.add_function(wrap_pyfunction!(call, m)?)?;
    m.add_function(wrap_pyfunction!(commands::run, m)?)?;
    m.add_function(wrap_pyfunction!(commands::export, m)?)?;
    m.add_function(wrap_pyfunction!(commands::score, m)?)?;
    m.add_function(wrap_pyfunction!(commands::dataset_matches, m)?)?;
    m.add_function(wrap_pyfunction!(commands::write_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(commands::check_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(commands::eval, m)?)?;
    m.add_function(wrap_pyfunction!(commands::track, m)?)?;
    m.add_function(wrap_pyfunction!(commands::batch, m)?)?;
    m.add_function(wrap_pyfunction!(commands::train, m)?)?;
    m.add_function(wrap_pyfunction!(commands::convert_pyg, m)?)?;
    m.add_function(wrap_pyfunction!(toml_of_json, m)?)?;
    m.add_function(wrap_pyfunction!(delaunay, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_class::<DatasetReader>()?;
    m.add_class::<PublishedNetwork>()?;
    Ok(())
}
