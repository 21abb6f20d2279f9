//! The typed commands of the library (`coid_sim::commands`) as Python
//! calls: values in, the folder written and the line `coid` prints out;
//! no argv, no printed line parsed. Each runs in a thread of its own that
//! Ctrl-C stops ([`interruptible`]).

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{CoidError, coid_error};

/// Runs `work` (a command) in a thread of its own, the GIL released,
/// while this thread, the interpreter's, looks for its signals: Ctrl-C
/// stops the command at its next SUMO step and raises
/// `KeyboardInterrupt`. Errors as `CoidError` with `coid`'s line.
pub(crate) fn interruptible<T: Send>(
    py: Python<'_>,
    work: impl FnOnce() -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    coid_sim::cli::clear_stop();
    let (outcome, interrupted) = py.detach(|| {
        std::thread::scope(|scope| {
            let worker = std::thread::Builder::new()
                .name("coid".into())
                .stack_size(COMMAND_STACK_BYTES)
                .spawn_scoped(scope, work);
            let worker = match worker {
                Ok(w) => w,
                Err(e) => return (Err(anyhow::anyhow!("cannot start a thread: {e}")), None),
            };
            let mut interrupted: Option<PyErr> = None;
            while !worker.is_finished() {
                std::thread::sleep(SIGNAL_POLL);
                if interrupted.is_none()
                    && let Err(e) = Python::attach(|py| py.check_signals())
                {
                    coid_sim::cli::request_stop();
                    interrupted = Some(e);
                }
            }
            let outcome = worker
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (outcome, interrupted)
        })
    });
    coid_sim::cli::clear_stop();
    if let Some(e) = interrupted {
        return Err(e);
    }
    outcome.map_err(|e| coid_error(&e))
}

/// `coid run` as a typed call: the configuration as a file (`config`),
/// as TOML text in no file (`config_text`, named `shown` in messages and
/// results) or the defaults (neither); the results folder and the
/// headline back, nothing parsed from printed lines. Progress bars as
/// the program shows them unless `quiet`.
#[pyfunction]
#[pyo3(signature = (config=None, config_text=None, shown=None, out=None, force=false, threads=None, traffic_seed=None, sensor_seed=None, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn run(
    py: Python<'_>,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    force: bool,
    threads: Option<usize>,
    traffic_seed: Option<u64>,
    sensor_seed: Option<u64>,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    let request = coid_sim::commands::RunRequest {
        common: common(config, config_text, shown, out, force, threads)?,
        traffic_seed,
        sensor_seed,
    };
    let report = with_bars(py, quiet, "running", |on| {
        coid_sim::commands::run(&request, on)
    })?;
    let line = coid_sim::cli::print_report(&report);
    Ok((report.folder, line))
}

/// Runs a typed command in its own thread ([`interruptible`]), its
/// events shown as `coid` shows them (`cli::Bars`: "`doing`: run 3/10")
/// unless `quiet`; a panic reported in one line.
fn with_bars<T: Send>(
    py: Python<'_>,
    quiet: bool,
    doing: &'static str,
    work: impl FnOnce(&mut dyn FnMut(coid_sim::commands::Event)) -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    coid_sim::cli::report_panics_in_one_line();
    interruptible(py, || {
        let mut bars = coid_sim::cli::Bars::new(quiet, doing);
        let done = work(&mut |e| bars.show(e));
        bars.clear();
        done
    })
}

/// A configuration as the typed commands take it: a file, TOML text in
/// no file (named `shown`), or the defaults (neither).
fn config_source(
    config: Option<PathBuf>,
    text: Option<String>,
    shown: Option<String>,
) -> PyResult<coid_sim::commands::ConfigSource> {
    use coid_sim::commands::ConfigSource;
    match (config, text) {
        (Some(path), None) => Ok(ConfigSource::File(path)),
        (None, Some(text)) => Ok(ConfigSource::Text {
            text,
            shown: shown.unwrap_or_else(|| "the configuration".to_owned()),
        }),
        (None, None) => Ok(ConfigSource::Defaults),
        (Some(_), Some(_)) => Err(CoidError::new_err(
            "a configuration is a file or a text, not both",
        )),
    }
}

/// What every typed command that writes a folder takes: the
/// configuration as [`config_source`] reads it, the folder, force and
/// threads.
fn common(
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    force: bool,
    threads: Option<usize>,
) -> PyResult<coid_sim::commands::Common> {
    Ok(coid_sim::commands::Common {
        config: config_source(config, config_text, shown)?,
        out,
        force,
        threads,
    })
}

/// `coid export` as a typed call: the configuration as for [`run`];
/// `splits` and `with_matches` as labels; the folder written and the
/// line `coid export` prints back.
#[pyfunction]
#[pyo3(signature = (config=None, config_text=None, shown=None, out=None, force=false, threads=None, splits=Vec::new(), with_matches=Vec::new(), dataset=None, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn export(
    py: Python<'_>,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    force: bool,
    threads: Option<usize>,
    splits: Vec<String>,
    with_matches: Vec<String>,
    dataset: Option<PathBuf>,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    use coid_sim::commands::labels;
    let request = coid_sim::commands::ExportRequest {
        common: common(config, config_text, shown, out, force, threads)?,
        splits: labels("split", &splits).map_err(CoidError::new_err)?,
        with_matches: labels("method", &with_matches).map_err(CoidError::new_err)?,
        dataset,
    };
    let report = with_bars(py, quiet, "exporting", |on| {
        coid_sim::commands::export(&request, on)
    })?;
    let line = coid_sim::cli::print_export(&report);
    Ok((report.folder, line))
}

/// `coid score` as a typed call: the configuration as for [`run`]; the
/// matches a file (`matches`) or a Parquet file's bytes in memory
/// (`matches_parquet`, named "the matches frame"); the folder written and
/// the line `coid score` prints back.
#[pyfunction]
#[pyo3(signature = (config=None, config_text=None, shown=None, out=None, force=false, threads=None, matches=None, matches_parquet=None, export=None, dataset=None, split="test", quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn score(
    py: Python<'_>,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    force: bool,
    threads: Option<usize>,
    matches: Option<PathBuf>,
    matches_parquet: Option<&[u8]>,
    export: Option<PathBuf>,
    dataset: Option<PathBuf>,
    split: &str,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    use coid_sim::commands::Matches;
    let matches = match (matches, matches_parquet) {
        (Some(path), None) => Matches::File(path),
        (None, Some(bytes)) => Matches::Parquet {
            bytes: bytes.to_vec(),
            shown: "the matches frame".to_owned(),
        },
        _ => {
            return Err(CoidError::new_err(
                "matches are a file or a frame's Parquet bytes, one of them",
            ));
        }
    };
    let request = coid_sim::commands::ScoreRequest {
        common: common(config, config_text, shown, out, force, threads)?,
        matches,
        export,
        dataset,
        split: coid_sim::commands::label("split", split).map_err(CoidError::new_err)?,
    };
    let report = with_bars(py, quiet, "scoring", |on| {
        coid_sim::commands::score(&request, on)
    })?;
    let line = coid_sim::cli::print_score(&report);
    Ok((report.folder, line))
}

/// The stack of the thread a command runs in: the main thread's.
const COMMAND_STACK_BYTES: usize = 8 << 20;
/// How often the interpreter's signals are looked at while a command runs.
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// A built-in method's matches on every run of a dataset, as columns
/// (run, instance, pose_noise, a, b, probability, uncertainty): what
/// `coid export --dataset --with-matches` writes, held in memory.
#[pyfunction]
#[pyo3(signature = (dataset, method, config=None, config_text=None, shown=None, threads=None, quiet=true))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn dataset_matches<'py>(
    py: Python<'py>,
    dataset: PathBuf,
    method: &str,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    threads: Option<usize>,
    quiet: bool,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let request = coid_sim::commands::MatchesRequest {
        config: config_source(config, config_text, shown)?,
        dataset,
        method: coid_sim::commands::label("method", method).map_err(CoidError::new_err)?,
        threads,
    };
    let rows = with_bars(py, quiet, "matching", |on| {
        coid_sim::commands::matches(&request, on)
    })?;
    let columns = pyo3::types::PyDict::new(py);
    columns.set_item("run", rows.iter().map(|r| r.run).collect::<Vec<_>>())?;
    columns.set_item(
        "instance",
        rows.iter().map(|r| r.instance).collect::<Vec<_>>(),
    )?;
    columns.set_item(
        "pose_noise",
        rows.iter()
            .map(|r| r.pose_noise.clone())
            .collect::<Vec<_>>(),
    )?;
    columns.set_item("a", rows.iter().map(|r| r.a).collect::<Vec<_>>())?;
    columns.set_item("b", rows.iter().map(|r| r.b).collect::<Vec<_>>())?;
    columns.set_item(
        "probability",
        rows.iter().map(|r| r.probability).collect::<Vec<_>>(),
    )?;
    columns.set_item(
        "uncertainty",
        rows.iter().map(|r| r.uncertainty).collect::<Vec<_>>(),
    )?;
    Ok(columns)
}

/// A dataset folder from its files' frames, each as a Parquet file's
/// bytes (`edges.parquet` coid computes), checked by coid's reader before
/// the folder appears; the folder and the line it printed back.
#[pyfunction]
#[pyo3(signature = (out, runs, instances, nodes, truth, true_pairs, force=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_dataset(
    py: Python<'_>,
    out: PathBuf,
    runs: &[u8],
    instances: &[u8],
    nodes: &[u8],
    truth: &[u8],
    true_pairs: &[u8],
    force: bool,
) -> PyResult<(PathBuf, String)> {
    let request = coid_sim::commands::WriteDatasetRequest {
        out,
        force,
        frames: coid_sim::commands::DatasetFrames {
            runs: runs.to_vec(),
            instances: instances.to_vec(),
            nodes: nodes.to_vec(),
            truth: truth.to_vec(),
            true_pairs: true_pairs.to_vec(),
        },
    };
    coid_sim::cli::report_panics_in_one_line();
    let report = interruptible(py, || coid_sim::commands::write_dataset(&request))?;
    let line = report.line();
    eprintln!("{line}");
    Ok((report.folder, line))
}

/// `coid dataset` as a call: the dataset in `dir` read run by run and
/// checked; what it holds as a dict (the counts per split, the runs
/// without instances, the levels, the appearance width, the optional
/// columns) and the lines `coid dataset` prints.
#[pyfunction]
pub(crate) fn check_dataset(py: Python<'_>, dir: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    coid_sim::cli::report_panics_in_one_line();
    let s = interruptible(py, || coid_sim::commands::check_dataset(&dir))?;
    let out = PyDict::new(py);
    out.set_item("dir", &s.dir)?;
    out.set_item("runs", s.runs)?;
    let splits = PyDict::new(py);
    for c in &s.splits {
        let d = PyDict::new(py);
        d.set_item("runs", c.runs)?;
        d.set_item("instances", c.instances)?;
        d.set_item("nodes", c.nodes)?;
        d.set_item("true_pairs", c.true_pairs)?;
        splits.set_item(c.split, d)?;
    }
    out.set_item("splits", splits)?;
    out.set_item("empty_runs", &s.empty_runs)?;
    out.set_item("levels", s.levels.clone())?;
    out.set_item("appearance_width", s.appearance_width)?;
    out.set_item("optional_columns", &s.optional_columns)?;
    out.set_item("lines", s.lines())?;
    Ok(out)
}

/// `coid convert pyg` as a call: DMGM-layout PyG pairs in `source` into
/// the dataset `out`; the folder and the line it printed (after a warning
/// for each recording the splits cut).
#[pyfunction]
#[pyo3(signature = (source, out, splits, views=("proc_s".to_owned(), "proc_t".to_owned()), name="dmgm".to_owned(), gps_sigma_m=1.2, gps_heading_sigma_deg=0.2, force=false, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn convert_pyg(
    py: Python<'_>,
    source: PathBuf,
    out: PathBuf,
    splits: Vec<(String, u64, u64)>,
    views: (String, String),
    name: String,
    gps_sigma_m: f64,
    gps_heading_sigma_deg: f64,
    force: bool,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    let mut ranges = Vec::with_capacity(splits.len());
    for (split, first, last) in splits {
        if first > last {
            return Err(CoidError::new_err(format!(
                "the range {first}..{last} of {split} is empty"
            )));
        }
        ranges.push((split, first..=last));
    }
    let request = coid_sim::commands::ConvertPygRequest {
        source,
        views: [views.0, views.1],
        splits: ranges,
        name,
        gps_sigma_m,
        gps_heading_sigma_deg,
        out,
        force,
    };
    let report = with_bars(py, quiet, "converting", |on| {
        coid_sim::commands::convert_pyg(&request, on)
    })?;
    for w in report.warnings() {
        eprintln!("{w}");
    }
    let line = report.line();
    eprintln!("{line}");
    Ok((report.folder, line))
}

/// `coid eval` as a typed call: every configured method on the test (or
/// validation) runs of the configuration, its `suite` and a `dataset`;
/// the folder and the line `coid eval` prints.
#[pyfunction]
#[pyo3(signature = (config=None, config_text=None, shown=None, out=None, force=false, threads=None, validation=false, suite=Vec::new(), dataset=None, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn eval(
    py: Python<'_>,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    force: bool,
    threads: Option<usize>,
    validation: bool,
    suite: Vec<PathBuf>,
    dataset: Option<PathBuf>,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    let request = coid_sim::commands::EvalRequest {
        common: common(config, config_text, shown, out, force, threads)?,
        validation,
        suite,
        dataset,
    };
    let report = with_bars(py, quiet, "evaluating", |on| {
        coid_sim::commands::eval(&request, on)
    })?;
    let line = report.line();
    eprintln!("{line}");
    Ok((report.folder, line))
}

/// `coid track` as a typed call (with `sweep`, `coid track --sweep`): the
/// folder and the line `coid track` prints last.
#[pyfunction]
#[pyo3(signature = (config=None, config_text=None, shown=None, out=None, force=false, sweep=false, validation=false, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn track(
    py: Python<'_>,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    force: bool,
    sweep: bool,
    validation: bool,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    if validation && !sweep {
        return Err(CoidError::new_err(
            "validation chooses the runs of a sweep: it needs sweep=True",
        ));
    }
    let request = coid_sim::commands::TrackRequest {
        common: common(config, config_text, shown, out, force, None)?,
        validation,
    };
    let doing = if sweep { "sweeping" } else { "tracking" };
    let report = with_bars(py, quiet, doing, |on| {
        if sweep {
            coid_sim::commands::track_sweep(&request, on)
        } else {
            coid_sim::commands::track(&request, on)
        }
    })?;
    if let Some(why) = &report.no_vehicle {
        eprintln!("{why}");
    }
    eprintln!("{}", report.line);
    Ok((report.folder, report.line))
}

/// `coid batch` as a typed call: `runs` runs seeded from `seed` on worker
/// processes (this package's program), resumable; the folder and the line
/// `coid batch` prints.
#[pyfunction]
#[pyo3(signature = (runs, config=None, config_text=None, shown=None, out=None, seed=1, shard=None, workers=None, threads=None, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn batch(
    py: Python<'_>,
    runs: usize,
    config: Option<PathBuf>,
    config_text: Option<String>,
    shown: Option<String>,
    out: Option<PathBuf>,
    seed: u64,
    shard: Option<String>,
    workers: Option<usize>,
    threads: Option<usize>,
    quiet: bool,
) -> PyResult<(PathBuf, String)> {
    let shard = shard
        .map(|s| s.parse::<coid_sim::commands::Shard>())
        .transpose()
        .map_err(CoidError::new_err)?;
    let request = coid_sim::commands::BatchRequest {
        config: config_source(config, config_text, shown)?,
        runs,
        seed,
        out,
        shard,
        workers,
        threads,
    };
    let report = with_bars(py, quiet, "running", |on| {
        coid_sim::commands::batch(&request, on)
    })?;
    eprintln!("{}", report.line);
    Ok((report.folder, report.line))
}

/// `coid train` as a typed call: the deep methods trained (in child
/// processes of this package's program when several train at once), then
/// validated; the models folder and the line `coid train` prints last
/// (none for `validate_only`).
#[pyfunction]
#[pyo3(signature = (config=None, out=None, force=false, methods=Vec::new(), workers=None, skip_validation=false, validate_only=false, seeds=Vec::new(), dataset=None, reid_rank1=None, without_descriptor=false, quiet=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn train(
    py: Python<'_>,
    config: Option<PathBuf>,
    out: Option<PathBuf>,
    force: bool,
    methods: Vec<String>,
    workers: Option<usize>,
    skip_validation: bool,
    validate_only: bool,
    seeds: Vec<u64>,
    dataset: Option<PathBuf>,
    reid_rank1: Option<f64>,
    without_descriptor: bool,
    quiet: bool,
) -> PyResult<(PathBuf, Option<String>)> {
    let request = coid_sim::commands::TrainRequest {
        config,
        out,
        force,
        methods: coid_sim::commands::labels("method", &methods).map_err(CoidError::new_err)?,
        workers,
        skip_validation,
        validate_only,
        seeds,
        dataset,
        reid_rank1,
        without_descriptor,
    };
    coid_sim::cli::report_panics_in_one_line();
    let report = interruptible(py, || {
        let mut view = coid_sim::cli::TrainBars::on_stderr(quiet);
        let done = coid_sim::commands::train(&request, &mut view);
        view.clear();
        done
    })?;
    if let Some(line) = &report.line {
        eprintln!("{line}");
    }
    Ok((report.folder, report.line))
}
