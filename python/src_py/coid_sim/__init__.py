"""coid-sim from Python: the simulator, datasets, the built-in matchers and
the scorer of the ``coid`` command, in this interpreter.

    import coid_sim
    result = coid_sim.run()            # the default scenario, as `coid run`
    print(result.headline)

Every command runs in-process with the same code, files and numbers as
the ``coid`` program (``coid_sim.cli("eval", "-c", "my.toml")`` runs any
of them); results come back as polars (or pandas) frames, datasets as
numpy arrays, PyTorch Geometric ``PairData`` and pygmtools' inputs.
Failures raise :class:`CoidError` with the line ``coid`` prints.
"""

from __future__ import annotations

import io
import json
import math
import os
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import polars as pl

from . import _coid_sim
from ._coid_sim import CoidError
from .dataset import Dataset, Instance, Level, Match, Side
from .results import Results
from .writer import DatasetWriter

__version__: str = _coid_sim.__version__

__all__ = [
    "CoidError",
    "Dataset",
    "DatasetWriter",
    "Instance",
    "Level",
    "Match",
    "Results",
    "Side",
    "batch",
    "check_dataset",
    "cli",
    "convert_pyg",
    "eval",
    "export",
    "run",
    "score",
    "track",
    "train",
    "write_dataset",
]

PathLike = Union[str, "os.PathLike[str]"]
Config = Union[None, PathLike, Mapping[str, Any]]


def cli(*args: Any) -> Optional[str]:
    """Runs one ``coid`` command line in this process, as the program runs
    it (``cli("eval", "-c", "configs/family.toml")``): the same output,
    files and progress bars. Returns the command's last line where it has
    one (``run``'s headline). Raises :class:`CoidError` with coid's
    message on bad input or failure."""
    return _coid_sim.call(["coid", *(os.fspath(a) if isinstance(a, os.PathLike) else str(a) for a in args)])


def _config_source(config: Config) -> "tuple[Optional[str], Optional[str]]":
    """A configuration as the typed commands take it: a file's path, or a
    dict's TOML text (checked first: finite numbers, TOML values), or
    neither for the defaults."""
    if config is None:
        return None, None
    if isinstance(config, Mapping):
        _finite(config, "")
        return None, _coid_sim.toml_of_json(json.dumps(config, default=_plain))
    return os.fspath(config), None


def _finite(value: Any, at: str) -> None:
    """Refuses a number that is not finite anywhere in a dict configuration
    (TOML could carry it; no setting of coid takes it)."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            _finite(v, f"{at}.{k}" if at else str(k))
    elif isinstance(value, (list, tuple)):
        for k, v in enumerate(value):
            _finite(v, f"{at}[{k}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise CoidError(f"the configuration dict holds {value} at {at}: no setting of coid takes a number that is not finite")


def _seed(name: str, value: Optional[int]) -> None:
    """Refuses a seed that is not an integer >= 0 (by its name)."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**64:
        raise CoidError(f"{name} must be an integer >= 0, not {value!r}")


def _request(config: Config, out: Optional[PathLike], name: str, suffix: str, force: bool, threads: Optional[int], dataset: Any = None) -> dict:
    """What every typed command that writes a folder takes: the
    configuration (a file's path, or a dict as TOML text named "the
    configuration dict"), the results folder (``_out``), force and threads."""
    _threads(threads)
    path, text = _config_source(config)
    folder = _out(out, config, name, suffix, dataset)
    return {
        "config": path,
        "config_text": text,
        "shown": "the configuration dict",
        "out": None if folder is None else os.fspath(folder),
        "force": force,
        "threads": threads,
    }


def _threads(threads: Optional[int]) -> None:
    """Refuses a thread count that is not an integer (coid checks its range)."""
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 0):
        raise CoidError(f"threads must be an integer from 1 to 1024, not {threads!r}")


def _plain(value: Any) -> Any:
    """A value of a dict configuration that JSON does not know: numpy
    arrays and scalars as lists and numbers, paths as text."""
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if hasattr(value, "tolist"):
        return value.tolist()
    raise CoidError(f"the configuration holds {value!r} ({type(value).__name__}), which is not a TOML value")


def _out(out: Optional[PathLike], config: Config, name: str, suffix: str, dataset: Any = None) -> Optional[PathLike]:
    """The results folder to ask for: ``out`` when given; for a dict
    configuration ``results/<name><suffix>``; else None, coid's default
    (``results/<file stem><suffix>``, or named after ``dataset``)."""
    if out is not None:
        return out
    return f"results/{name}{suffix}" if isinstance(config, Mapping) and dataset is None else None


def run(
    config: Config = None,
    *,
    out: Optional[PathLike] = None,
    force: bool = False,
    traffic_seed: Optional[int] = None,
    sensor_seed: Optional[int] = None,
    threads: Optional[int] = None,
    quiet: bool = False,
    name: str = "config",
) -> Results:
    """Runs one scenario headless, as ``coid run`` does, and returns its
    results folder.

    config: a TOML file, or a dict of the same tables (only what differs
        from the defaults); None runs the default intersection.
    out: the results folder [default: results/<config file stem>, or
        results/<name> for a dict].
    force: replace a results folder that is there.
    traffic_seed, sensor_seed: override ``[seeds]``.
    threads: worker threads [default: every core].
    quiet: no progress bar.
    """
    _seed("traffic_seed", traffic_seed)
    _seed("sensor_seed", sensor_seed)
    folder, headline = _coid_sim.run(
        **_request(config, out, name, "", force, threads),
        traffic_seed=traffic_seed,
        sensor_seed=sensor_seed,
        quiet=quiet,
    )
    return Results(Path(folder), headline)


def eval(
    config: Config = None,
    *,
    out: Optional[PathLike] = None,
    validation: bool = False,
    suite: Sequence[PathLike] = (),
    dataset: Optional[Union[Dataset, PathLike]] = None,
    force: bool = False,
    threads: Optional[int] = None,
    quiet: bool = False,
    name: str = "config",
) -> Results:
    """Evaluates every configured method, as ``coid eval`` does: the
    paper's tables and plots of the test runs, per scenario and pooled.

    config: a TOML file, or a dict of the same tables; None evaluates the
        default intersection.
    out: the results folder [default: results/<config file stem>-eval,
        results/<name>-eval for a dict, results/<dataset folder>-eval].
    validation: the validation runs instead of the test runs.
    suite: more scenario configs, each on its own runs.
    dataset: a dataset's runs (a :class:`Dataset` or its folder) instead
        of simulated ones.
    """
    if isinstance(dataset, Dataset):
        if config is None:
            config = dataset.config
        dataset = dataset.path
    suffix = "-validation" if validation else "-eval"
    folder, line = _coid_sim.eval(
        **_request(config, out, name, suffix, force, threads, dataset),
        validation=validation,
        suite=[os.fspath(p) for p in suite],
        dataset=None if dataset is None else os.fspath(dataset),
        quiet=quiet,
    )
    return Results(Path(folder), line)


def export(
    config: Config = None,
    *,
    out: Optional[PathLike] = None,
    splits: Sequence[str] = (),
    with_matches: Sequence[str] = (),
    dataset: Optional[PathLike] = None,
    force: bool = False,
    threads: Optional[int] = None,
    quiet: bool = False,
    name: str = "config",
) -> Dataset:
    """Writes every instance of a configuration as a dataset, as ``coid
    export`` does, and opens it.

    splits: any of "train", "validation", "test" [default: all three].
    with_matches: built-in methods whose matches are written beside
        (``matches-<method>.parquet``), e.g. ["ours", "gps-app-hungarian"].
    dataset: instead of simulating, the runs of this dataset (any dataset
        folder, one converted from elsewhere too): the built-in methods'
        matches on it.
    """
    folder, _line = _coid_sim.export(
        **_request(config, out, name, "-export", force, threads, dataset),
        splits=list(splits),
        with_matches=list(with_matches),
        dataset=None if dataset is None else os.fspath(dataset),
        quiet=quiet,
    )
    return Dataset(folder, config=config)


def score(
    matches: Union[pl.DataFrame, "Any", PathLike],
    *,
    dataset: Optional[Union[Dataset, PathLike]] = None,
    export: Optional[PathLike] = None,
    config: Config = None,
    split: str = "test",
    out: Optional[PathLike] = None,
    force: bool = False,
    threads: Optional[int] = None,
    quiet: bool = False,
    name: str = "config",
) -> Results:
    """Scores matches made elsewhere beside the built-in methods, as
    ``coid score`` does: the same tables.

    matches: a polars (or pandas) frame, or a Parquet/CSV file, with
        columns run, instance, a, b and optionally pose_noise, probability,
        uncertainty (docs/export-schema.md).
    dataset: the dataset they were made from (a :class:`Dataset` or its
        folder): its runs are scored as they are.
    export: instead, the ``coid export`` folder of this configuration.
    split: "test", or "validation" to choose a threshold there first.
    """
    if isinstance(dataset, Dataset):
        if config is None:
            config = dataset.config
        dataset = dataset.path
    if not isinstance(matches, (str, os.PathLike, pl.DataFrame)) and type(matches).__module__.split(".")[0] != "pandas":
        raise CoidError(f"matches must be a polars or pandas frame, or a Parquet or CSV file, not {type(matches).__name__}")
    if isinstance(matches, (str, os.PathLike)):
        file, parquet = os.fspath(matches), None
    else:
        file, parquet = None, _parquet(matches, "matches")
    folder, line = _coid_sim.score(
        **_request(config, out, name, "-score", force, threads, dataset),
        matches=file,
        matches_parquet=parquet,
        export=None if export is None else os.fspath(export),
        dataset=None if dataset is None else os.fspath(dataset),
        split=split,
        quiet=quiet,
    )
    return Results(Path(folder), line)


def _parquet(frame: Any, name: str) -> bytes:
    """A polars or pandas frame as a Parquet file's bytes (no file)."""
    if not isinstance(frame, pl.DataFrame):
        if type(frame).__module__.split(".")[0] != "pandas":
            raise CoidError(f"{name} must be a polars or pandas frame, not {type(frame).__name__}")
        frame = pl.from_pandas(frame)
    buffer = io.BytesIO()
    frame.write_parquet(buffer)
    return buffer.getvalue()


def write_dataset(
    out: PathLike,
    *,
    runs: Any,
    instances: Any,
    nodes: Any,
    truth: Any,
    true_pairs: Any,
    force: bool = False,
    config: Config = None,
) -> Dataset:
    """Writes a dataset folder from its files' frames (polars or pandas),
    whatever the data's source: the columns of docs/export-schema.md,
    ``edges.parquet`` computed by coid. ``runs`` may leave out
    ``schema_version`` and ``config_digest`` (this coid's version, and
    empty). Nothing is written unless coid's own reader accepts every run
    (:class:`CoidError` says why); the same instances written by ``coid
    export`` give the same bytes. Returns the dataset, opened (with
    ``config`` for its matchers' settings).
    :class:`DatasetWriter` builds the frames from per-vehicle arrays."""
    if isinstance(runs, pl.DataFrame) or type(runs).__module__.split(".")[0] == "pandas":
        frame = runs if isinstance(runs, pl.DataFrame) else pl.from_pandas(runs)
        if "schema_version" not in frame.columns:
            frame = frame.with_columns(pl.lit(_coid_sim.SCHEMA_VERSION, pl.UInt64).alias("schema_version"))
        if "config_digest" not in frame.columns:
            frame = frame.with_columns(pl.lit("", pl.String).alias("config_digest"))
        runs = frame
    folder, _line = _coid_sim.write_dataset(
        os.fspath(out),
        _parquet(runs, "runs"),
        _parquet(instances, "instances"),
        _parquet(nodes, "nodes"),
        _parquet(truth, "truth"),
        _parquet(true_pairs, "true_pairs"),
        force=force,
    )
    return Dataset(Path(folder), config=config)


def check_dataset(path: PathLike) -> dict:
    """Reads the dataset folder ``path`` run by run and checks it, as
    ``coid dataset`` does; returns what it holds: ``runs``, ``splits``
    (per split: ``runs``, ``instances``, ``nodes`` of both vehicles,
    ``true_pairs``), ``empty_runs``, ``levels`` (name and position sigma
    in m), ``appearance_width`` (None without vectors),
    ``optional_columns``, and ``lines`` (what ``coid dataset`` prints).
    Raises :class:`CoidError` with coid's message when the dataset is
    refused."""
    return _coid_sim.check_dataset(os.fspath(path))


def convert_pyg(
    source: PathLike,
    out: PathLike,
    *,
    splits: Mapping[str, tuple],
    views: Sequence[str] = ("proc_s", "proc_t"),
    name: str = "dmgm",
    gps_sigma_m: float = 1.2,
    gps_heading_sigma_deg: float = 0.2,
    force: bool = False,
    quiet: bool = False,
    config: Config = None,
) -> Dataset:
    """Converts PyTorch Geometric pairs as DMGM distributes them (one
    folder per view, ``<view>/<k>/data.pt``; read without torch, nothing
    in them run) into the dataset folder ``out``, as ``coid convert pyg``
    does. ``splits`` gives each split's first and last pair index:
    ``{"validation": (60260, 64006), "test": (64007, 69468)}``. Returns
    the dataset, opened (with ``config`` for its matchers' settings)."""
    if len(views) != 2:
        raise CoidError(f"views names the two vehicles' folders, not {len(views)}")
    ranges = [(split, int(first), int(last)) for split, (first, last) in splits.items()]
    folder, _line = _coid_sim.convert_pyg(
        os.fspath(source),
        os.fspath(out),
        ranges,
        views=(str(views[0]), str(views[1])),
        name=name,
        gps_sigma_m=float(gps_sigma_m),
        gps_heading_sigma_deg=float(gps_heading_sigma_deg),
        force=force,
        quiet=quiet,
    )
    return Dataset(Path(folder), config=config)


def track(
    config: Config = None,
    *,
    out: Optional[PathLike] = None,
    sweep: bool = False,
    validation: bool = False,
    force: bool = False,
    quiet: bool = False,
    name: str = "config",
) -> Results:
    """Tracks over one run, as ``coid track`` does: every connected
    vehicle's tracker, its CPMs over the channel and what the receivers
    make of them (``tracking.csv``, ``association.csv``). With ``sweep``,
    as ``coid track --sweep``: latency, loss and rate one at a time over
    the test runs (``validation``: the validation runs), ``sweep.csv``."""
    suffix = ("-sweep-validation" if validation else "-sweep") if sweep else "-track"
    request = _request(config, out, name, suffix, force, None)
    request.pop("threads")
    folder, line = _coid_sim.track(**request, sweep=sweep, validation=validation, quiet=quiet)
    return Results(Path(folder), line)


def batch(
    config: Optional[PathLike] = None,
    *,
    runs: int,
    seed: int = 1,
    out: Optional[PathLike] = None,
    shard: Optional[str] = None,
    workers: Optional[int] = None,
    threads: Optional[int] = None,
    quiet: bool = False,
) -> Results:
    """Runs a Monte Carlo batch, as ``coid batch`` does: ``runs`` runs with
    seeds derived from ``seed`` on worker processes (this package's
    program), resumable (the same call finishes a stopped batch), the
    aggregate with 95 % intervals in ``summary.csv``. ``config`` is a TOML
    file (the batch records its text) or None for the defaults; ``shard``
    ``"k/n"`` runs one slice."""
    if isinstance(config, Mapping):
        raise CoidError("a batch reads its configuration from a file (it records the file's text and folder): write the configuration to a TOML file")
    _seed("seed", seed)
    _threads(threads)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise CoidError(f"workers must be an integer from 1 to 1024, not {workers!r}")
    folder, line = _coid_sim.batch(
        int(runs),
        config=None if config is None else os.fspath(config),
        out=None if out is None else os.fspath(out),
        seed=seed,
        shard=shard,
        workers=workers,
        threads=threads,
        quiet=quiet,
    )
    return Results(Path(folder), line)


def train(
    config: Optional[PathLike] = None,
    *,
    out: Optional[PathLike] = None,
    methods: Sequence[str] = (),
    seeds: Sequence[int] = (),
    dataset: Optional[Union[Dataset, PathLike]] = None,
    skip_validation: bool = False,
    validate_only: bool = False,
    reid_rank1: Optional[float] = None,
    without_descriptor: bool = False,
    workers: Optional[int] = None,
    force: bool = False,
    quiet: bool = False,
) -> Results:
    """Trains the deep matchers, as ``coid train`` does: weights, record
    and loss curve of each method into the models folder, then each one's
    temperature, decision rule and lambda (and the baselines' thresholds)
    chosen on the validation runs. ``config`` is a TOML file (several
    methods train in child processes, which read it) or None for the
    defaults. ``headline`` is the line ``coid train`` ends with (None with
    ``validate_only``)."""
    if isinstance(config, Mapping):
        raise CoidError("training reads its configuration from a file (its child processes read it): write the configuration to a TOML file")
    if isinstance(dataset, Dataset):
        dataset = dataset.path
    for s in seeds:
        _seed("seeds", s)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise CoidError(f"workers must be an integer from 1 to 1024, not {workers!r}")
    folder, line = _coid_sim.train(
        config=None if config is None else os.fspath(config),
        out=None if out is None else os.fspath(out),
        force=force,
        methods=[str(m) for m in methods],
        workers=workers,
        skip_validation=skip_validation,
        validate_only=validate_only,
        seeds=[int(s) for s in seeds],
        dataset=None if dataset is None else os.fspath(dataset),
        reid_rank1=None if reid_rank1 is None else float(reid_rank1),
        without_descriptor=without_descriptor,
        quiet=quiet,
    )
    return Results(Path(folder), line)
