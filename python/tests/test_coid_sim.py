"""The installed wheel: runs, datasets, built-in matchers and the scorer
from Python, against the ``coid`` program's own outputs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import polars as pl
import pytest

import coid_sim
from conftest import SHORT

REPO = Path(__file__).resolve().parents[2]


def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _coid_bin() -> str:
    exe = os.environ.get("COID_BIN")
    if not exe:
        pytest.skip("COID_BIN (the coid binary to compare with) is not set")
    return exe


def test_a_run_from_python_writes_the_coid_programs_bytes(in_tmp: Path) -> None:
    """`coid_sim.run` and the `coid` binary, same configuration and seeds:
    the same headline numbers and byte-identical files."""
    config = in_tmp / "short.toml"
    config.write_text(coid_sim._coid_sim.toml_of_json(__import__("json").dumps(SHORT)))
    result = coid_sim.run(config, out=in_tmp / "py", quiet=True)
    assert result.out == in_tmp / "py"
    done = subprocess.run(
        [_coid_bin(), "run", "-q", "-c", str(config), "--out", str(in_tmp / "bin")],
        capture_output=True,
        text=True,
        env={**os.environ, "COID_VENV": os.environ.get("COID_VENV", "")},
    )
    assert done.returncode == 0, done.stderr
    said = done.stderr.strip().splitlines()[-1]
    # The line's numbers but the wall time and speeds (which differ run to run).
    numbers = lambda line: [p for p in line.split("; ") if "F1" in p]  # noqa: E731
    assert numbers(result.headline) == numbers(said) and numbers(said)
    ours, theirs = _files(in_tmp / "py"), _files(in_tmp / "bin")
    assert sorted(ours) == sorted(theirs)
    for name in ours:
        assert ours[name] == theirs[name], name


def test_run_returns_frames_and_a_dict_config_names_its_folder(in_tmp: Path) -> None:
    result = coid_sim.run({**SHORT, "matching": {"methods": ["gps-hungarian", "oracle"]}}, name="short", quiet=True)
    assert result.out == Path("results/short")
    assert result.headline.startswith("coid: ") and "oracle @gps/aligned F1 1.000" in result.headline
    summary = result.frame("summary")
    assert isinstance(summary, pl.DataFrame)
    assert set(summary["method"].unique().to_list()) == {"gps-hungarian", "oracle"}
    assert "summary" in result.frames()
    pytest.importorskip("pyarrow")
    pandas = pytest.importorskip("pandas")
    as_pandas = result.frame("summary", backend="pandas")
    assert isinstance(as_pandas, pandas.DataFrame) and len(as_pandas) == summary.height
    # The config file was removed; a second run into the same folder is refused.
    assert not list(in_tmp.glob(".coid-*.toml"))
    with pytest.raises(coid_sim.CoidError, match="results/short"):
        coid_sim.run(SHORT, name="short", quiet=True)


def test_bad_input_raises_the_coid_programs_line(in_tmp: Path) -> None:
    """A bad configuration is a CoidError with the line `coid` prints, and
    the interpreter goes on."""
    bad = in_tmp / "bad.toml"
    bad.write_text("[scenario]\nend_s = -5\n")
    with pytest.raises(coid_sim.CoidError) as err:
        coid_sim.run(bad, quiet=True)
    message = str(err.value)
    assert "\n" not in message and "end_s" in message
    done = subprocess.run([sys.executable, "-m", "coid_sim", "run", "-q", "-c", str(bad)], capture_output=True, text=True)
    assert done.returncode == 1
    assert done.stderr.strip() == f"error: {message}"
    with pytest.raises(coid_sim.CoidError, match="is not a usable dataset"):
        coid_sim.Dataset(in_tmp)
    with pytest.raises(coid_sim.CoidError, match="unexpected argument"):
        coid_sim.cli("run", "--no-such-flag")
    with pytest.raises(coid_sim.CoidError, match="no command given"):
        coid_sim.cli()
    assert coid_sim.cli("--version") is None  # printed, as the program prints it
    with pytest.raises(coid_sim.CoidError, match="not a TOML value"):
        coid_sim.run({"scenario": {"end_s": object()}}, quiet=True)


def test_a_dataset_iterates_as_arrays_with_the_truth(short_export: coid_sim.Dataset) -> None:
    ds = short_export
    assert ds.runs["split"].to_list() == ["test", "test"]
    instances = list(ds.instances("test"))
    assert len(instances) == len(ds) > 0
    assert [lv[0] for lv in ds.levels] == ["none", "rtk", "gps"]
    truth = pl.read_parquet(ds.path / "true_pairs.parquet")
    assert sum(len(i.true_pairs) for i in instances) == truth.height
    for inst in instances[:20]:
        n_s, n_t = len(inst.first), len(inst.second)
        a = inst.arrays("gps")
        assert a["x_s"].shape == (n_s, 13) and a["x_t"].shape == (n_t, 13)
        assert a["edge_index_s"].shape[0] == 2 and a["edge_index_s"].max(initial=-1) < n_s
        assert a["edge_attr_s"].shape == (a["edge_index_s"].shape[1], 2)
        assert ((a["edge_attr_s"] >= 0) & (a["edge_attr_s"] <= 1)).all()
        y = a["y"]
        assert y.shape == (n_s,)
        for s, t in inst.true_pairs:
            assert y[s] == t and inst.first.object_id[s] == inst.second.object_id[t] != ""
        assert (y >= -1).all() and (y < n_t).all()
        # True partners are one object: one true centre.
        if len(inst.true_pairs):
            s_true, t_true = inst.first.true_m[inst.true_pairs[:, 0]], inst.second.true_m[inst.true_pairs[:, 1]]
            assert np.array_equal(s_true, t_true)
        g = inst.to_pygmtools("gps")
        assert g["X_gt"].sum() == len(inst.true_pairs) and g["ne1"] == a["edge_index_s"].shape[1]
    with pytest.raises(coid_sim.CoidError, match="no run 2"):
        ds.run(2)
    with pytest.raises(coid_sim.CoidError, match="no pose-noise level 'gsp'"):
        instances[0].match("gps-hungarian", "gsp")


def test_the_oracle_read_from_y_scores_as_the_oracle(short_export: coid_sim.Dataset) -> None:
    """Matches made from each instance's `y` (the oracle's) score exactly
    as coid's oracle in every table `coid score` writes."""
    rows = []
    for inst in short_export.instances("test"):
        for s, t in enumerate(inst.y):
            if t >= 0:
                rows.append((inst.run, inst.instance, s, int(t)))
    matches = pl.DataFrame(rows, schema={"run": pl.UInt64, "instance": pl.UInt64, "a": pl.UInt64, "b": pl.UInt64}, orient="row")
    scored = coid_sim.score(matches, dataset=short_export, config=SHORT, quiet=True, out=short_export.path.parent / "s-oracle")
    # Against the export instead (its configuration's digest checked): the
    # results folder is named after the dict configuration.
    here = os.getcwd()
    os.chdir(short_export.path.parent)
    try:
        by_export = coid_sim.score(matches, export=short_export.path, config=SHORT, quiet=True, name="short")
    finally:
        os.chdir(here)
    assert by_export.out == Path("results/short-score")
    for name in ["table1b", "errors", "calibration", "consistency", "views"]:
        frame = scored.frame(name).drop("inputs", strict=False)
        external = frame.filter(pl.col("method") == "external").drop("method")
        oracle = frame.filter(pl.col("method") == "oracle").drop("method")
        assert external.height > 0, name
        assert external.equals(oracle), name


def test_a_built_in_matcher_on_an_instance_is_the_exports(short_export: coid_sim.Dataset) -> None:
    """`Instance.match` on the dataset gives what the simulation's export
    wrote for the same method (probabilities and uncertainties too)."""
    written = pl.read_parquet(short_export.path / "matches-gps-hungarian.parquet")
    checked = 0
    for inst in list(short_export.instances("test"))[:30]:
        for label in ["gps", "none"]:
            got = inst.match("gps-hungarian", label)
            want = written.filter((pl.col("run") == inst.run) & (pl.col("instance") == inst.instance) & (pl.col("pose_noise") == label))
            assert sorted((m.a, m.b) for m in got) == sorted(zip(want["a"].to_list(), want["b"].to_list()))
            for m in got:
                assert 0.0 <= m.probability <= 1.0 and 0.0 <= m.uncertainty <= 1.0
            checked += len(got)
    assert checked > 0
    with pytest.raises(coid_sim.CoidError, match="no-such-method"):
        short_export.matches("no-such-method")


def test_to_pyg_gives_dgmc_pair_data(short_export: coid_sim.Dataset) -> None:
    torch = pytest.importorskip("torch")
    pytest.importorskip("torch_geometric")
    from torch_geometric.loader import DataLoader

    from torch_geometric.data import Data
    from torch_geometric.transforms import Cartesian

    pairs = short_export.to_pyg("test")
    batch = next(iter(DataLoader(pairs[:4], batch_size=4, follow_batch=["x_s", "x_t"])))
    assert batch.edge_index_s.max() < batch.x_s.size(0)
    assert batch.y.dtype == torch.long and batch.y.size(0) == batch.x_s.size(0)
    # The edge attributes are PyG's own Cartesian pseudo-coordinates.
    for p in pairs[:10]:
        theirs = Cartesian()(Data(pos=p.pos_s.double(), edge_index=p.edge_index_s)).edge_attr
        assert torch.allclose(p.edge_attr_s.double(), theirs, atol=1e-6)


def test_a_batch_from_python_starts_its_workers_through_the_package(in_tmp: Path) -> None:
    """`coid batch` inside the package starts `python -m coid_sim` workers
    (two at once); its aggregate is the binary's, byte for byte."""
    config = in_tmp / "short.toml"
    config.write_text(coid_sim._coid_sim.toml_of_json(__import__("json").dumps(SHORT)))
    coid_sim.cli("batch", "-q", "-c", config, "--runs", "2", "--workers", "2", "--out", in_tmp / "py")
    done = subprocess.run(
        [_coid_bin(), "batch", "-q", "-c", str(config), "--runs", "2", "--workers", "2", "--out", str(in_tmp / "bin")],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    summary = (in_tmp / "py" / "summary.csv").read_bytes()
    assert summary and summary == (in_tmp / "bin" / "summary.csv").read_bytes()
    # The typed call: the same aggregate; a dict configuration is refused.
    typed = coid_sim.batch(config, runs=2, workers=2, out=in_tmp / "typed", quiet=True)
    assert typed.headline.startswith("coid: 2 runs done in ") and typed.out == in_tmp / "typed"
    assert (in_tmp / "typed" / "summary.csv").read_bytes() == summary
    with pytest.raises(coid_sim.CoidError, match=r"a batch reads its configuration from a file"):
        coid_sim.batch(SHORT, runs=1)


def test_scenarios_from_python_use_the_sumo_wheels_netconvert(in_tmp: Path) -> None:
    """`coid scenarios` inside the package runs netconvert from the
    eclipse-sumo wheel of this interpreter; the family is the binary's,
    byte for byte (the nets too)."""
    coid_sim.cli("scenarios", "--count", "1", "--seed", "5", "--out", in_tmp / "py")
    done = subprocess.run([_coid_bin(), "scenarios", "--count", "1", "--seed", "5", "--out", str(in_tmp / "bin")], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    ours, theirs = _files(in_tmp / "py"), _files(in_tmp / "bin")
    assert any(name.endswith(".net.xml") for name in ours)
    assert sorted(ours) == sorted(theirs)
    for name in ours:
        assert ours[name] == theirs[name], name


def test_ctrl_c_stops_a_command_from_python_and_leaves_no_folder(in_tmp: Path) -> None:
    """Ctrl-C while `coid_sim.cli` runs a long command: KeyboardInterrupt
    at the command's next SUMO step (not when it ends), the interpreter
    goes on, and neither the results folder nor its temporary one is left."""
    script = in_tmp / "long.py"
    script.write_text(
        "import sys, time, coid_sim\n"
        "config = {'scenario': {'end_s': 3600.0}, 'eval': {'traffic_seeds': list(range(1, 41))}}\n"
        "print('started', flush=True)\n"
        "t = time.time()\n"
        "try:\n"
        "    coid_sim.run(config, name='long', quiet=True)\n"
        "    print('finished')\n"
        "except KeyboardInterrupt:\n"
        "    print(f'interrupted after {time.time() - t:.1f} s')\n"
        "print('still here')\n"
    )
    child = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=in_tmp)
    assert child.stdout is not None
    assert child.stdout.readline().strip() == "started"
    time.sleep(2.0)
    child.send_signal(signal.SIGINT)
    out, _ = child.communicate(timeout=60)
    assert "interrupted after" in out and "still here" in out, out
    left = sorted(p.name for p in (in_tmp / "results").iterdir()) if (in_tmp / "results").exists() else []
    assert left == [], left


def test_python_m_coid_sim_is_the_coid_program(in_tmp: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "coid_sim", "--version"], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.startswith("coid")


def test_the_nearest_match_example_scores_what_its_rule_implies(short_export: coid_sim.Dataset) -> None:
    """examples/nearest_match.py, through the package: the precision,
    recall and F1 it prints for its rule are the ones `coid score` finds."""
    example = REPO / "examples" / "nearest_match.py"
    if not example.is_file():
        pytest.skip("the examples are in the source tree, not in the wheel")
    out = short_export.path.parent / "nm-score"
    done = subprocess.run(
        [sys.executable, str(example), str(short_export.path), "--score-out", str(out)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    table = pl.read_csv(out / "table1b.csv")
    checked = 0
    for line in done.stdout.splitlines():
        words = line.split()
        if not words or words[0].rstrip(":") not in ("none", "rtk", "gps") or " f1 " not in line:
            continue
        level = words[0].rstrip(":")
        row = table.filter((pl.col("method") == "external") & (pl.col("pose_noise") == level)).row(0, named=True)
        for name, at in [("precision", 2), ("recall", 4), ("f1", 6)]:
            assert abs(float(words[at]) - row[name]) < 1e-6, (name, level)
        checked += 1
    assert checked == 3, done.stdout


def test_the_pyg_example_trains_on_a_dataset_and_coid_scores_it(tmp_path: Path) -> None:
    """examples/train_pyg.py on the short configuration's train,
    validation and test runs (one epoch): coid scores its matches."""
    pytest.importorskip("torch")
    pytest.importorskip("torch_geometric")
    example = REPO / "examples" / "train_pyg.py"
    ds = coid_sim.export({**SHORT, "train": {"traffic_seeds": [11, 12], "validation_seeds": [13, 14]}}, out=tmp_path / "all", quiet=True)
    assert set(ds.runs["split"].to_list()) == {"train", "validation", "test"}
    done = subprocess.run(
        [sys.executable, str(example), str(ds.path), "--epochs", "1", "--score-out", str(tmp_path / "s")],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    table = pl.read_csv(tmp_path / "s" / "table1b.csv").filter(pl.col("method") == "external")
    assert table.filter(pl.col("pose_noise") == "gps")["f1"][0] > 0.0


# Issue 63: bad input from Python is a CoidError naming what the user gave.


def test_an_unknown_split_lists_the_datasets_splits(short_export: coid_sim.Dataset) -> None:
    with pytest.raises(coid_sim.CoidError, match=r"'Test' is not a split .*this dataset's runs are test"):
        list(short_export.instances("Test"))
    assert list(short_export.instances("train")) == []


def test_an_unknown_method_lists_coids_methods(short_export: coid_sim.Dataset) -> None:
    inst = next(iter(short_export))
    with pytest.raises(coid_sim.CoidError, match=r"unknown method 'nope' \(coid's methods: coid, .*oracle"):
        inst.match("nope")


def test_a_dict_configs_errors_name_the_dict_not_a_temporary_file(in_tmp: Path) -> None:
    with pytest.raises(coid_sim.CoidError) as e:
        coid_sim.run({"scenario": {"end_s": -5.0}}, quiet=True)
    assert "the configuration dict" in str(e.value) and ".coid-" not in str(e.value), e.value
    with pytest.raises(coid_sim.CoidError, match=r"holds nan at scenario.end_s: no setting of coid takes a number that is not finite"):
        coid_sim.run({"scenario": {"end_s": float("nan")}}, quiet=True)


def test_a_negative_seed_is_refused_by_name(in_tmp: Path) -> None:
    with pytest.raises(coid_sim.CoidError, match=r"traffic_seed must be an integer >= 0, not -1"):
        coid_sim.run(traffic_seed=-1, quiet=True)


def test_score_names_what_it_was_given(short_export: coid_sim.Dataset, in_tmp: Path) -> None:
    with pytest.raises(coid_sim.CoidError, match=r"matches must be a polars or pandas frame, or a Parquet or CSV file, not list"):
        coid_sim.score([1, 2, 3], export=short_export.path)
    bad = pl.DataFrame({"run": [0], "instance": [0], "a": [0], "b": [0], "probability": [2.0]})
    with pytest.raises(coid_sim.CoidError) as e:
        coid_sim.score(bad, export=short_export.path, config=SHORT, quiet=True)
    assert "coid-score-" not in str(e.value) and "the matches frame" in str(e.value), e.value


def test_to_pyg_without_torch_says_what_to_install(short_export: coid_sim.Dataset) -> None:
    try:
        import torch_geometric  # noqa: F401

        pytest.skip("torch_geometric is installed here")
    except ModuleNotFoundError:
        pass
    inst = next(iter(short_export))
    with pytest.raises(ModuleNotFoundError, match=r"pip install torch torch_geometric"):
        inst.to_pyg()


def test_a_dataset_with_a_nan_is_refused_by_name(short_export: coid_sim.Dataset, in_tmp: Path) -> None:
    import shutil

    bad = in_tmp / "nan"
    shutil.copytree(short_export.path, bad)
    nodes = pl.read_parquet(bad / "nodes.parquet")
    nodes = nodes.with_columns(pl.when(pl.int_range(pl.len()) == 0).then(float("nan")).otherwise(pl.col("x_m")).alias("x_m"))
    nodes.write_parquet(bad / "nodes.parquet")
    with pytest.raises(coid_sim.CoidError, match=r"nodes.parquet: row 1, column 'x_m': NaN is not a number coid can use"):
        list(coid_sim.Dataset(bad))


# Issue 65: the published networks' forward pass, opened to the reference check.


def _published_pair(inst: "coid_sim.Instance", width: int = 13) -> tuple:
    def graph(side: "coid_sim.Side") -> tuple:
        edges = side.edges()
        lengths = np.linalg.norm(side.xy_m[edges[:, 0]] - side.xy_m[edges[:, 1]], axis=1) if len(edges) else np.zeros(0)
        x = side.network_features()[:, :width].astype(np.float32)
        return (x.reshape(-1).tolist(), [tuple(map(int, e)) for e in edges], lengths.tolist())

    return graph(inst.first), graph(inst.second)


def test_a_published_forward_with_given_draws_is_a_dustbin_assignment_per_sample(short_export: coid_sim.Dataset) -> None:
    """`PublishedNetwork` runs the shipped networks on an exported pair with
    the masks and indicators given: one `(n1 + 1) x (n2 + 1)` assignment per
    sample whose real columns sum to 1 (Sinkhorn's last step normalises
    the columns; 20 steps leave the rows near 1), the same numbers for the
    same draws, other numbers for other indicators (DGMC) and none asked of
    GCN-GM."""
    from coid_sim import _coid_sim

    inst = next(i for i in short_export.instances("test") if len(i.first) > 2 and len(i.second) > 2)
    n1, n2 = len(inst.first), len(inst.second)
    first, second = _published_pair(inst)
    rng = np.random.default_rng(5)
    net = _coid_sim.PublishedNetwork(str(REPO / "models" / "coid.bpk"), "coid", samples=2)
    c = net.config()
    assert (c["kind"], c["node_features"], c["hidden"], c["consensus_steps"]) == ("dgmc", 13, 256, 10)
    assert net.parameters()["psi1.conv1.weight"][0] == [13, 5 * 256]
    masks = tuple(((rng.random(2 * n * 256) >= 0.4) / 0.6).astype(np.float32).tolist() for n in (n1, n2))
    draw = lambda: [rng.standard_normal(2 * n1 * 32).astype(np.float32).tolist() for _ in range(10)]
    indicators = draw()
    out = net.forward(first, second, masks, indicators)
    assert len(out) == 2 and all(len(s) == (n1 + 1) * (n2 + 1) for s in out)
    for s in out:
        p = np.asarray(s).reshape(n1 + 1, n2 + 1)
        assert np.allclose(p[:, :n2].sum(axis=0), 1.0, atol=1e-4) and (p >= 0).all()
    assert out[0] != out[1]
    assert net.forward(first, second, masks, indicators) == out
    assert net.forward(first, second, masks, draw()) != out
    gcn = _coid_sim.PublishedNetwork(str(REPO / "models" / "gcn-gm.bpk"), "gcn-gm", samples=2)
    assert len(gcn.forward(first, second, masks, [])) == 2
    # Parameters by name make the same weights file again.
    assert _coid_sim.PublishedNetwork.weights_of("coid", net.parameters()) == (REPO / "models" / "coid.bpk").read_bytes()


def test_a_published_forward_refuses_what_does_not_fit(short_export: coid_sim.Dataset, tmp_path: Path) -> None:
    from coid_sim import _coid_sim

    inst = next(i for i in short_export.instances("test") if len(i.first) > 2 and len(i.second) > 2)
    n1, n2 = len(inst.first), len(inst.second)
    first, second = _published_pair(inst)
    weights = str(REPO / "models" / "gcn-gm.bpk")
    net = _coid_sim.PublishedNetwork(weights, "gcn-gm")
    masks = ([1.0] * n1 * 256, [1.0] * n2 * 256)
    with pytest.raises(coid_sim.CoidError, match="a mask of 3 values"):
        net.forward(first, second, ([1.0] * 3, masks[1]), [])
    with pytest.raises(coid_sim.CoidError, match="0 consensus steps need 0 indicator draws"):
        net.forward(first, second, masks, [[0.0]])
    with pytest.raises(coid_sim.CoidError, match=rf"edge \(0, {n1}\) in a graph of {n1} nodes"):
        net.forward((first[0], [(0, n1)], [1.0]), second, masks, [])
    with pytest.raises(coid_sim.CoidError, match="an edge NaN m long"):
        net.forward((first[0], [(0, 1)], [float("nan")]), second, masks, [])
    with pytest.raises(coid_sim.CoidError, match="are not rows of 13"):
        net.forward((first[0][:-1], [], []), second, masks, [])
    with pytest.raises(coid_sim.CoidError, match="ours is not a network on the paper's inputs"):
        _coid_sim.PublishedNetwork(str(REPO / "models" / "ours.bpk"), "ours")
    with pytest.raises(coid_sim.CoidError, match="does not fit dgmc"):
        _coid_sim.PublishedNetwork(weights, "dgmc")
    with pytest.raises(coid_sim.CoidError, match="no method"):
        _coid_sim.PublishedNetwork(weights, "spectral-magic")
    with pytest.raises(coid_sim.CoidError, match="cannot read"):
        _coid_sim.PublishedNetwork(str(tmp_path / "none.bpk"), "dgmc")
    params = net.parameters()
    shape, values = params["dustbin"]
    with pytest.raises(coid_sim.CoidError, match="dustbin holds a value that is not a finite number"):
        _coid_sim.PublishedNetwork.weights_of("gcn-gm", {**params, "dustbin": (shape, [float("nan")])})
    with pytest.raises(coid_sim.CoidError, match="the weights have no dustbin"):
        _coid_sim.PublishedNetwork.weights_of("gcn-gm", {k: v for k, v in params.items() if k != "dustbin"})
    with pytest.raises(coid_sim.CoidError, match="ours is not a network on the paper's inputs"):
        _coid_sim.PublishedNetwork.weights_of("ours", params)


def _dgmc_reference() -> str:
    """The DGMC checkout for tools/dgmc_reference, whose scripts become
    importable; skips without torch, PyTorch Geometric or COID_DGMC_SRC."""
    pytest.importorskip("torch")
    pytest.importorskip("torch_geometric")
    dgmc = os.environ.get("COID_DGMC_SRC")
    if not dgmc:
        pytest.skip("COID_DGMC_SRC (a checkout of rusty1s/deep-graph-matching-consensus) is not set")
    sys.path.insert(0, str(REPO / "tools" / "dgmc_reference"))
    return dgmc


def test_coids_published_forward_is_dgmcs_reference(short_export: coid_sim.Dataset) -> None:
    """tools/dgmc_reference/check.py: the shipped `coid` weights through
    DGMC's own forward (PyG's SplineConv) give coid's assignments to 1e-4 on
    the exported pairs; with the reference's "no match" score moved by 0.5
    they do not. Needs torch, PyTorch Geometric and a DGMC checkout
    (COID_DGMC_SRC)."""
    dgmc = _dgmc_reference()
    import check

    args = ["--dgmc", dgmc, "--dataset", str(short_export.path), "--split", "test", "--pairs", "20", "--weights", str(REPO / "models" / "coid.bpk")]
    assert check.main(args) == 0
    original = check.dustbin_sinkhorn
    try:
        check.dustbin_sinkhorn = lambda scores, bin_score, iters: original(scores, bin_score + 0.5, iters)
        assert check.main(args) == 1
    finally:
        check.dustbin_sinkhorn = original


def test_network_features_are_the_attributes_coids_networks_read(short_export: coid_sim.Dataset) -> None:
    """A network trained elsewhere on `Side.features()` (sizes in metres)
    and run in coid (sizes over 10, 3 and 4 m) read other inputs: the
    reference trained that way lost 0.2 F1 in coid. `network_features()`
    are coid's own: the class and colour of `features()`, its sizes as the
    networks scale them, then the appearance vector."""
    inst = next(iter(short_export.instances("test")))
    for side in (inst.first, inst.second):
        plain, network = side.features(), side.network_features()
        assert network.dtype == np.float32 and network.shape == plain.shape
        assert np.allclose(network[:, :10], plain[:, :10])
        assert np.allclose(network[:, 10:13], plain[:, 10:13] / np.array([10.0, 3.0, 4.0]), atol=1e-6)
        assert not np.allclose(network[:, 10:13], plain[:, 10:13])


def test_the_reference_trains_on_a_dataset_and_coid_runs_its_weights(tmp_path: Path) -> None:
    """tools/dgmc_reference/train.py (one epoch of GCN-GM with DGMC's code)
    on a dataset with train and validation runs, its record copied from
    the port's: coid validates the weights and evaluates them, as
    docs/faithfulness.md's commands do. Needs torch, PyTorch Geometric and
    a DGMC checkout (COID_DGMC_SRC)."""
    dgmc = _dgmc_reference()
    import train

    ds = coid_sim.export({**SHORT, "train": {"traffic_seeds": [11, 12], "validation_seeds": [13, 14]}}, out=tmp_path / "all", quiet=True)
    port, ref = tmp_path / "port", tmp_path / "reference"
    config = tmp_path / "c.toml"
    config.write_text(f'[matching]\nmethods = ["gcn-gm", "oracle"]\nmodels_dir = "{port}"\n[train]\nepochs = 1\n[eval]\ntraining_seeds = [7]\n')
    coid_sim.cli("train", "-c", config, "--dataset", ds.path, "--methods", "gcn-gm", "--seed", "7", "--out", port, "-q")
    args = ["--dgmc", dgmc, "--dataset", str(ds.path), "--method", "gcn-gm", "--epochs", "1", "--shape-of", str(REPO / "models"), "--record", str(port / "gcn-gm.toml"), "--out", str(ref)]
    assert train.main(args) == 0
    assert (ref / "gcn-gm.bpk").read_bytes() != (port / "gcn-gm.bpk").read_bytes()
    config.write_text(config.read_text().replace(str(port), str(ref)))
    with pytest.raises(coid_sim.CoidError, match="no validated_lambda"):
        coid_sim.cli("eval", "-c", config, "--dataset", ds.path, "-o", tmp_path / "e0", "-q")
    coid_sim.cli("train", "-c", config, "--dataset", ds.path, "--validate-only", "--methods", "gcn-gm", "--out", ref, "-q")
    coid_sim.cli("eval", "-c", config, "--dataset", ds.path, "-o", tmp_path / "e", "-q")
    table = pl.read_csv(tmp_path / "e" / "table1.csv").filter(pl.col("method") == "gcn-gm")
    assert table.height > 0 and 0.0 <= table["f1"][0] <= 1.0


def test_a_published_network_takes_its_shape_from_the_record_beside_it(tmp_path: Path) -> None:
    """Weights trained with another edge scale run at that scale (their
    record beside them says it); weights trained on every pair of
    detections are refused, since this forward pass takes a dataset's
    Delaunay edges; without a record, the default shape."""
    from coid_sim import _coid_sim

    (tmp_path / "coid.bpk").write_bytes((REPO / "models" / "coid.bpk").read_bytes())
    weights = str(tmp_path / "coid.bpk")
    assert _coid_sim.PublishedNetwork(weights, "coid").config()["edge_scale_m"] == 60.0
    record = (REPO / "models" / "coid.toml").read_text()
    assert "edge_scale_m = 60.0" in record
    (tmp_path / "coid.toml").write_text(record.replace("edge_scale_m = 60.0", "edge_scale_m = 30.0"))
    assert _coid_sim.PublishedNetwork(weights, "coid").config()["edge_scale_m"] == 30.0
    (tmp_path / "coid.toml").write_text(record.replace("[architecture]\n", '[architecture]\ngraph = "complete"\n'))
    with pytest.raises(coid_sim.CoidError, match="every pair of detections"):
        _coid_sim.PublishedNetwork(weights, "coid")


def test_a_dict_config_run_writes_nothing_but_its_results_folder(in_tmp: Path) -> None:
    """A dict configuration is handed to coid as text: no file appears in
    the current folder, and the results name the dict, not a file."""
    result = coid_sim.run({**SHORT, "matching": {"methods": ["oracle"]}}, name="dict", quiet=True)
    assert sorted(p.name for p in in_tmp.iterdir()) == ["results"], list(in_tmp.iterdir())
    assert result.out == Path("results/dict")
    assert "- config: `the configuration dict`" in (result.out / "summary.md").read_text()
    with pytest.raises(coid_sim.CoidError, match=r"threads must be 1 to 1024, got 0"):
        coid_sim.run(SHORT, out="elsewhere", threads=0, quiet=True)
    assert not Path("elsewhere").exists()


def test_export_takes_typed_lists_and_names_a_bad_label(in_tmp: Path) -> None:
    with pytest.raises(coid_sim.CoidError, match=r"unknown split 'nope' \(expected one of: train, validation, test\)"):
        coid_sim.export(SHORT, splits=["nope"], quiet=True)
    with pytest.raises(coid_sim.CoidError, match=r"splits names 'test' twice"):
        coid_sim.export(SHORT, splits=["test", "test"], quiet=True)
    ds = coid_sim.export({**SHORT, "eval": {"traffic_seeds": [1]}}, splits=["test"], name="one", quiet=True)
    assert ds.path == Path("results/one-export") and len(ds.runs) == 1
    assert sorted(p.name for p in in_tmp.iterdir()) == ["results"]


def test_matches_and_scores_of_frames_write_no_file_of_their_own(short_export: coid_sim.Dataset, in_tmp: Path, tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """A dataset's matches come from coid in memory, equal to what `coid
    export --dataset --with-matches` writes; a frame of matches is scored
    from memory: no file appears in the temporary folder or the current
    one but the results folder asked for."""
    replayed = tmp_path_factory.mktemp("replayed") / "ex"
    coid_sim.export(short_export.config, dataset=short_export.path, with_matches=["gps-hungarian"], out=replayed, quiet=True)
    exported = pl.read_parquet(replayed / "matches-gps-hungarian.parquet")
    scratch = tmp_path_factory.mktemp("scratch")
    monkeypatch.setenv("TMPDIR", str(scratch))
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    fresh = coid_sim.Dataset(short_export.path, config=short_export.config)
    made = fresh.matches("gps-hungarian")
    assert made.height > 0
    assert made.equals(exported), (made, exported)
    scored = coid_sim.score(made, dataset=fresh, quiet=True, out="scored")
    assert scored.headline is not None and "scored the matches frame" in scored.headline, scored.headline
    assert sorted(p.name for p in in_tmp.iterdir()) == ["scored"], list(in_tmp.iterdir())
    assert list(scratch.iterdir()) == []


EXPORT_FILES = ("runs", "instances", "nodes", "edges", "truth", "true_pairs")


def test_a_dataset_written_from_arrays_is_the_export_byte_for_byte(short_export: coid_sim.Dataset, tmp_path: Path) -> None:
    """Every instance of an export, read back as numpy arrays and written
    again through DatasetWriter, gives the export's files byte for byte
    (edges computed by coid); the frames alone through write_dataset too."""
    runs = short_export.runs
    digests = pl.read_parquet(short_export.path / "runs.parquet")["config_digest"].to_list()
    w = coid_sim.DatasetWriter()
    for k in range(runs.height):
        meta = runs.row(k, named=True)
        run = w.add_run(meta["split"], meta["scenario"], seed=meta["seed"], index=meta["run"], config_digest=digests[k])
        for inst in short_export.run(k):
            w.add_instance(run, step=inst.step, time_s=inst.time_s, first=inst.first, second=inst.second, levels=inst.levels, true_poses=inst.true_poses, true_pairs=inst.true_pairs)
    written = w.write(tmp_path / "from-arrays")
    assert len(list(written.instances())) == len(list(short_export.instances()))
    for name in EXPORT_FILES:
        assert (written.path / f"{name}.parquet").read_bytes() == (short_export.path / f"{name}.parquet").read_bytes(), name
    assert (written.path / "schema.md").read_text() == (short_export.path / "schema.md").read_text()
    read = {name: pl.read_parquet(short_export.path / f"{name}.parquet") for name in EXPORT_FILES if name != "edges"}
    again = coid_sim.write_dataset(tmp_path / "from-frames", **read)
    for name in EXPORT_FILES:
        assert (again.path / f"{name}.parquet").read_bytes() == (short_export.path / f"{name}.parquet").read_bytes(), name


def test_write_dataset_refuses_what_coids_reader_refuses_and_writes_nothing(short_export: coid_sim.Dataset, tmp_path: Path) -> None:
    read = {name: pl.read_parquet(short_export.path / f"{name}.parquet") for name in EXPORT_FILES if name != "edges"}
    out = tmp_path / "bad"
    nan = read["nodes"].with_columns(pl.when(pl.col("node") == 1).then(float("nan")).otherwise(pl.col("x_m")).alias("x_m"))
    with pytest.raises(coid_sim.CoidError, match=r"nodes\.parquet.*x_m"):
        coid_sim.write_dataset(out, **{**read, "nodes": nan})
    assert not out.exists() and list(tmp_path.iterdir()) == []
    with pytest.raises(coid_sim.CoidError, match=r"the nodes frame is refused: it has no column 'class'"):
        coid_sim.write_dataset(out, **{**read, "nodes": read["nodes"].drop("class")})
    stray = read["truth"].with_columns(pl.lit(999, pl.UInt64).alias("run"))
    with pytest.raises(coid_sim.CoidError, match=r"truth\.parquet.*row 1: run 999 is not in runs\.parquet"):
        coid_sim.write_dataset(out, **{**read, "truth": stray})
    short = read["nodes"].head(read["nodes"].height - 1)
    with pytest.raises(coid_sim.CoidError, match=r"coid's reader refuses the dataset"):
        coid_sim.write_dataset(out, **{**read, "nodes": short})
    assert list(tmp_path.iterdir()) == []


def _kitti_files(ds: coid_sim.Dataset, folder: Path, shared: bool) -> tuple:
    """The first run of an export as two vehicles' KITTI-tracking label
    files (and GNSS pose files): one track id per object, shared by both
    vehicles; a false positive an id of its own. With ``shared``, each
    vehicle's detections where its GPS pose puts them in the world."""
    ids: dict = {}
    lines: dict = {}
    poses: dict = {}
    count = {"instances": 0, "pairs": 0}
    fresh = iter(range(10**6, 10**7))
    for inst in ds.run(0):
        gps = inst.level("gps")
        world = inst.world_xy("gps")
        count["instances"] += 1
        count["pairs"] += len(inst.true_pairs)
        for k, side in enumerate((inst.first, inst.second)):
            xy = world[k] if shared else side.xy_m
            for n in range(len(side)):
                obj = side.object_id[n]
                track = ids.setdefault(obj, len(ids)) if obj else next(fresh)
                length, width, height = side.size_m[n]
                x, z = -xy[n, 1], xy[n, 0]
                cls = {"car": "Car", "van": "Van", "truck": "Truck", "bus": "Tram", "pedestrian": "Pedestrian", "bicycle": "Cyclist", "motorcycle": "Cyclist"}[side.classes[n]]
                lines.setdefault(side.id, []).append(f"{inst.step} {track} {cls} 0 0 0 0 0 0 0 {height:.6f} {width:.6f} {length:.6f} {x:.6f} 1.5 {z:.6f} 0")
            pose = gps.reported[k]
            poses.setdefault(side.id, []).append(f"{inst.step} {pose[0]!r} {pose[1]!r} {pose[2]!r}")
            lines[side.id].append(f"{inst.step} -1 DontCare -1 -1 -10 0 0 1 1 -1 -1 -1 -1000 -1000 -1000 -10")
    labels, pose_files = [], []
    for vehicle in sorted(lines):
        (folder / f"{vehicle}.txt").write_text("\n".join(lines[vehicle]) + "\n")
        (folder / f"{vehicle}.poses").write_text("\n".join(poses[vehicle]) + "\n")
        labels.append(str(folder / f"{vehicle}.txt"))
        pose_files.append(str(folder / f"{vehicle}.poses"))
    return labels, pose_files, count


def test_the_kitti_tracking_example_writes_a_dataset_coid_accepts(short_export: coid_sim.Dataset, tmp_path: Path) -> None:
    """examples/kitti_tracking.py: two vehicles' KITTI-tracking label files
    (here the short export's first test run written in that format) become a
    dataset that `coid dataset` accepts, with every instance, node and true
    pair of the source; with --shared, detections already in a shared
    frame become body frames with identity poses."""
    example = REPO / "examples" / "kitti_tracking.py"
    if not example.is_file():
        pytest.skip("the examples are in the source tree, not in the wheel")
    pairs = {(i.first.id, i.second.id) for i in short_export.instances("test")}
    assert len(pairs) == 1, pairs
    for shared in (False, True):
        folder = tmp_path / ("shared" if shared else "gnss")
        folder.mkdir()
        labels, poses, count = _kitti_files(short_export, folder, shared)
        out = folder / "dataset"
        args = ["--labels", *labels, "--out", str(out)] + (["--shared"] if shared else ["--poses", *poses])
        done = subprocess.run([sys.executable, str(example), *args], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        checked = subprocess.run([_coid_bin(), "dataset", str(out)], capture_output=True, text=True)
        assert checked.returncode == 0, checked.stderr
        ds = coid_sim.Dataset(out)
        got = list(ds.instances("test"))
        assert len(got) == count["instances"]
        assert sum(len(i.true_pairs) for i in got) == count["pairs"]
        for mine, theirs in zip(got, short_export.run(0)):
            assert mine.step == theirs.step and len(mine.first) == len(theirs.first)
            lv = mine.level("gps")
            if shared:
                assert lv.reported == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
                expected = theirs.world_xy("gps")[0]
            else:
                assert lv.reported == theirs.level("gps").reported
                expected = theirs.first.xy_m
            assert np.abs(mine.first.xy_m - expected).max() < 1e-5


def test_the_dataset_writer_refuses_a_step_whose_instances_differ_in_levels(short_export: coid_sim.Dataset, tmp_path: Path) -> None:
    inst = next(iter(short_export.instances("test")))
    w = coid_sim.DatasetWriter()
    run = w.add_run("test", "mine")
    w.add_instance(run, step=3, first=inst.first, second=inst.second, levels=inst.levels)
    w.add_instance(run, step=3, first=inst.first, second=inst.second, levels=inst.levels[:1])
    with pytest.raises(coid_sim.CoidError, match=r"the instances of run 0 at step 3 have different pose-noise levels"):
        w.write(tmp_path / "mine")
    assert not (tmp_path / "mine").exists()
    with pytest.raises(coid_sim.CoidError, match=r"no run 1 \(add_run first: 1 runs\)"):
        w.add_instance(1, step=0, first=inst.first, second=inst.second, levels=inst.levels)


def test_check_dataset_says_what_coid_dataset_says(short_export: coid_sim.Dataset, capfd: pytest.CaptureFixture) -> None:
    """coid_sim.check_dataset is ``coid dataset`` as a call: its lines are
    what the program prints, its counts the dataset's own."""
    summary = coid_sim.check_dataset(short_export.path)
    capfd.readouterr()
    coid_sim.cli("dataset", short_export.path)
    assert capfd.readouterr().out.splitlines() == summary["lines"]
    assert summary["runs"] == 2 and list(summary["splits"]) == ["test"]
    instances = list(short_export)
    test = summary["splits"]["test"]
    assert test["runs"] == 2 and test["instances"] == len(instances) > 0
    assert test["nodes"] == sum(len(i.first.xy_m) + len(i.second.xy_m) for i in instances)
    assert [name for name, _ in summary["levels"]] == ["none", "rtk", "gps"]
    assert summary["appearance_width"] is None


def test_check_dataset_and_convert_pyg_refuse_by_name_and_write_nothing(tmp_path: Path) -> None:
    with pytest.raises(coid_sim.CoidError, match=r"is not a usable dataset"):
        coid_sim.check_dataset(tmp_path)
    source = tmp_path / "pyg"
    (source / "proc_s").mkdir(parents=True)
    out = tmp_path / "converted"
    with pytest.raises(coid_sim.CoidError, match=r"has no folder proc_t \(the views' folders, --views\)"):
        coid_sim.convert_pyg(source, out, splits={"test": (0, 3)}, quiet=True)
    with pytest.raises(coid_sim.CoidError, match=r"the range 5\.\.3 of test is empty"):
        coid_sim.convert_pyg(source, out, splits={"test": (5, 3)}, quiet=True)
    with pytest.raises(coid_sim.CoidError, match=r"--views names proc_s twice"):
        coid_sim.convert_pyg(source, out, splits={"test": (0, 3)}, views=("proc_s", "proc_s"), quiet=True)
    assert not out.exists()


def test_eval_from_python_writes_the_coid_programs_bytes(in_tmp: Path) -> None:
    """`coid_sim.eval` is `coid eval` as a call: the same tables byte for
    byte, the same last line but the folder; a dataset evaluates as
    `coid eval --dataset` does."""
    config = in_tmp / "short.toml"
    config.write_text(coid_sim._coid_sim.toml_of_json(__import__("json").dumps(SHORT)))
    result = coid_sim.eval(config, out=in_tmp / "py", quiet=True)
    assert result.out == in_tmp / "py"
    assert result.headline.startswith("coid: evaluated 3 methods on 2 test runs of 1 scenario (")
    coid_sim.cli("eval", "-q", "-c", config, "--out", in_tmp / "bin")
    ours, theirs = _files(in_tmp / "py"), _files(in_tmp / "bin")
    assert sorted(ours) == sorted(theirs) and "table1b.csv" in ours
    for name in ours:
        assert ours[name] == theirs[name], name
    with pytest.raises(coid_sim.CoidError, match=r"dataset .*nothing: "):
        coid_sim.eval(config, dataset=in_tmp / "nothing", out=in_tmp / "none", quiet=True)
    assert not (in_tmp / "none").exists()


def test_track_from_python_writes_the_coid_programs_bytes(in_tmp: Path) -> None:
    """`coid_sim.track` is `coid track` as a call: the same tables byte for
    byte; validation without a sweep is refused by name."""
    config = in_tmp / "cpm.toml"
    config.write_text('[scenario]\nend_s = 70.0\n[v2x]\nmode = "cpm"\n')
    result = coid_sim.track(config, out=in_tmp / "py", quiet=True)
    assert result.headline.startswith("coid: ") and "tracked, MOTA" in result.headline
    coid_sim.cli("track", "-q", "-c", config, "--out", in_tmp / "bin")
    ours, theirs = _files(in_tmp / "py"), _files(in_tmp / "bin")
    assert sorted(ours) == sorted(theirs) and "tracking.csv" in ours
    for name in ours:
        assert ours[name] == theirs[name], name
    with pytest.raises(coid_sim.CoidError, match=r"validation chooses the runs of a sweep"):
        coid_sim.track(config, validation=True)


def test_train_from_python_writes_the_coid_programs_bytes(in_tmp: Path) -> None:
    """`coid_sim.train` is `coid train` as a call: real burn training on one
    short SUMO run, the same weights byte for byte as the program's and the
    same record but its wall time; a dict configuration is refused (child
    processes read the file)."""
    config = in_tmp / "t.toml"
    config.write_text(
        '[scenario]\nend_s = 80.0\n[train]\ntraffic_seeds = [201]\nepochs = 1\nmethods = ["gcn-gm"]\n'
        '[matching]\nmethods = ["gcn-gm", "oracle"]\n[pose_noise]\nlevels = ["gps"]\n'
    )
    result = coid_sim.train(config, out=in_tmp / "py", skip_validation=True, workers=1, quiet=True)
    assert result.out == in_tmp / "py" and result.headline.startswith("coid: training took ")
    coid_sim.cli("train", "-q", "-c", config, "--out", in_tmp / "bin", "--skip-validation", "--workers", "1")
    ours, theirs = _files(in_tmp / "py"), _files(in_tmp / "bin")
    assert sorted(ours) == sorted(theirs) and "gcn-gm.bpk" in ours
    assert ours["gcn-gm.bpk"] == theirs["gcn-gm.bpk"]
    assert ours["gcn-gm_loss.csv"] == theirs["gcn-gm_loss.csv"]
    # The record says how long training took; everything else is equal.
    timeless = lambda b: [l for l in b.decode().splitlines() if not l.startswith("seconds = ")]  # noqa: E731
    assert timeless(ours["gcn-gm.toml"]) == timeless(theirs["gcn-gm.toml"])
    with pytest.raises(coid_sim.CoidError, match=r"training reads its configuration from a file"):
        coid_sim.train({"train": {"epochs": 1}})
    with pytest.raises(coid_sim.CoidError, match=r"'ours-t1' runs the weights of 'ours'"):
        coid_sim.train(config, methods=["ours-t1"], out=in_tmp / "none", quiet=True)
