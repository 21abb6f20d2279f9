"""Datasets from any source: :class:`DatasetWriter` builds a dataset's
frames instance by instance from per-vehicle arrays (the same
:class:`~coid_sim.Side` and :class:`~coid_sim.Level` a dataset reads
back), and :func:`coid_sim.write_dataset` has coid check and write them."""

from __future__ import annotations

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import polars as pl

from ._coid_sim import CoidError
from .dataset import Dataset, Level, Side

Pose = Tuple[float, float, float]

#: The pose each vehicle reports when its detections are already in a
#: shared frame (docs/data-from-elsewhere.md): the frame's origin.
IDENTITY: Pose = (0.0, 0.0, 0.0)


class DatasetWriter:
    """A dataset built run by run and instance by instance, written by
    :meth:`write`. Instances added one after another with the same
    ``step`` form one frame, as coid's exports order them.

        w = DatasetWriter()
        run = w.add_run("test", "my-recording")
        w.add_instance(run, step=0, first=side_a, second=side_b,
                       levels=[Level("gps", 1.2, (0.0035, 0.0035), (pose_a, pose_b))])
        ds = w.write("results/my-dataset")
    """

    def __init__(self) -> None:
        self._runs: List[Dict[str, Any]] = []
        self._instances: List[List[Dict[str, Any]]] = []

    def add_run(self, split: str, scenario: str, *, seed: Optional[int] = None, index: Optional[int] = None, config_digest: str = "") -> int:
        """A run of ``split`` (``train``, ``validation``, ``test``) named
        ``scenario``, numbered ``index`` in the files [default: runs
        counted from 0]; ``seed`` keys the streams coid draws for it (the
        deep methods' dropout masks) [default: its number]. Returns the
        handle ``add_instance`` takes."""
        k = len(self._runs)
        number = k if index is None else index
        self._runs.append({"run": number, "split": split, "scenario": scenario, "seed": number if seed is None else seed, "config_digest": config_digest})
        self._instances.append([])
        return k

    def add_instance(
        self,
        run: int,
        *,
        step: int,
        first: Side,
        second: Side,
        levels: Sequence[Level],
        time_s: Optional[float] = None,
        true_poses: Tuple[Optional[Pose], Optional[Pose]] = (None, None),
        true_pairs: Optional[np.ndarray] = None,
    ) -> int:
        """An instance of ``run``: two vehicles' nodes in their body frames
        (x forward, y left, metres), each vehicle's reported pose at every
        level, and the true correspondences (``[k, 2]``; by default the
        nodes of equal, non-empty ``object_id``). Returns its index in the
        run."""
        if not 0 <= run < len(self._runs):
            raise CoidError(f"no run {run} (add_run first: {len(self._runs)} runs)")
        if not levels:
            raise CoidError("an instance needs at least one pose-noise level")
        if true_pairs is None:
            true_pairs = _pairs_of(first.object_id, second.object_id)
        k = len(self._instances[run])
        self._instances[run].append(
            {"step": step, "time_s": time_s, "first": first, "second": second, "levels": tuple(levels), "true_poses": true_poses, "true_pairs": np.asarray(true_pairs, dtype=np.int64).reshape(-1, 2)}
        )
        return k

    def frames(self) -> Dict[str, pl.DataFrame]:
        """The dataset's files as frames (``write_dataset``'s arguments)."""
        instances: List[Dict[str, Any]] = []
        nodes: Dict[str, list] = {}
        truth: Dict[str, list] = {}
        pairs: Dict[str, list] = {"run": [], "instance": [], "a": [], "b": []}
        for handle, added in enumerate(self._instances):
            run = self._runs[handle]["run"]
            k = 0
            while k < len(added):
                frame = k
                while frame < len(added) and added[frame]["step"] == added[k]["step"]:
                    frame += 1
                group = list(enumerate(added[k:frame], start=k))
                labels = [tuple(lv.label for lv in inst["levels"]) for _, inst in group]
                if len(set(labels)) > 1:
                    raise CoidError(f"the instances of run {run} at step {added[k]['step']} have different pose-noise levels ({', '.join('/'.join(l) for l in dict.fromkeys(labels))}): give every instance of a step the same levels")
                for i, inst in group:
                    for s, side in enumerate((inst["first"], inst["second"])):
                        _add_side(nodes, truth, run, i, s, side)
                    for a, b in inst["true_pairs"].tolist():
                        for col, v in zip(("run", "instance", "a", "b"), (run, i, a, b)):
                            pairs[col].append(v)
                for li in range(len(group[0][1]["levels"])):
                    for i, inst in group:
                        instances.append(_instance_row(run, i, inst, li))
                k = frame
        runs = pl.DataFrame(
            [{**r, "n_instances": len(added)} for r, added in zip(self._runs, self._instances)],
            schema={"run": pl.UInt64, "split": pl.String, "scenario": pl.String, "seed": pl.UInt64, "config_digest": pl.String, "n_instances": pl.UInt64},
        )
        return {
            "runs": runs,
            "instances": _frame(_columns(instances), "instances"),
            "nodes": _frame(nodes, "nodes"),
            "truth": _frame(truth, "truth"),
            "true_pairs": pl.DataFrame(pairs, schema={c: pl.UInt64 for c in pairs}),
        }

    def write(self, out: Union[str, "os.PathLike[str]"], *, force: bool = False, config: Any = None) -> Dataset:
        """Writes the dataset to ``out`` through :func:`coid_sim.write_dataset`
        (checked by coid's reader first); returns it opened."""
        from . import write_dataset

        return write_dataset(out, force=force, config=config, **self.frames())


def _pairs_of(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The nodes of equal, non-empty object ids, ``[k, 2]``."""
    at = {o: b for b, o in enumerate(second.tolist()) if o}
    return np.asarray([(a, at[o]) for a, o in enumerate(first.tolist()) if o and o in at], dtype=np.int64).reshape(-1, 2)


def _instance_row(run: int, i: int, inst: Dict[str, Any], li: int) -> Dict[str, Any]:
    """An instance's row at its ``li``-th level."""
    first, second = inst["first"], inst["second"]
    lv: Level = inst["levels"][li]
    row: Dict[str, Any] = {
        "run": run,
        "instance": i,
        "pose_noise": lv.label,
        "step": inst["step"],
        "first_id": first.id,
        "second_id": second.id,
        "n_first": len(first),
        "n_second": len(second),
        "position_sigma_m": float(lv.position_sigma_m),
        "first_heading_sigma_rad": float(lv.heading_sigma_rad[0]),
        "second_heading_sigma_rad": float(lv.heading_sigma_rad[1]),
    }
    if inst["time_s"] is not None:
        row["time_s"] = float(inst["time_s"])
    for who, pose in zip(("first", "second"), lv.reported):
        row[f"{who}_x_m"], row[f"{who}_y_m"], row[f"{who}_heading_rad"] = (float(v) for v in pose)
    for who, pose in zip(("first", "second"), inst["true_poses"]):
        if pose is not None:
            row[f"{who}_true_x_m"], row[f"{who}_true_y_m"], row[f"{who}_true_heading_rad"] = (float(v) for v in pose)
    return row


def _add_side(nodes: Dict[str, list], truth: Dict[str, list], run: int, i: int, s: int, side: Side) -> None:
    """One vehicle's node and truth rows (an optional column only where
    the side has it; ``_frame`` refuses one that some sides lack)."""
    n = len(side)
    base = {"run": [run] * n, "instance": [i] * n, "side": [s] * n, "node": list(range(n))}
    columns: Dict[str, Any] = {**base, "x_m": side.xy_m[:, 0].tolist(), "y_m": side.xy_m[:, 1].tolist(), "class": [str(c) for c in side.classes.tolist()], "sender": [bool(v) for v in side.sender.tolist()]}
    if side.cov_m2 is not None:
        columns.update(cov_xx_m2=side.cov_m2[:, 0, 0].tolist(), cov_xy_m2=side.cov_m2[:, 0, 1].tolist(), cov_yy_m2=side.cov_m2[:, 1, 1].tolist())
    for names, values in (
        (("colour_r", "colour_g", "colour_b"), side.colour_rgb),
        (("length_m", "width_m", "height_m"), side.size_m),
        (("heading_rad", "speed_mps"), side.heading_speed),
        (("world_x_m", "world_y_m"), side.world_m),
    ):
        if values is not None:
            for c, name in enumerate(names):
                columns[name] = values[:, c].tolist()
    if side.appearance is not None:
        columns["appearance"] = [list(map(float, v)) for v in side.appearance.tolist()]
    _extend(nodes, columns, n)
    t: Dict[str, Any] = {**base, "object_id": [str(o) for o in side.object_id.tolist()]}
    if side.true_m is not None:
        t.update(true_x_m=side.true_m[:, 0].tolist(), true_y_m=side.true_m[:, 1].tolist())
    if side.visible_fraction is not None:
        t["visible_fraction"] = side.visible_fraction.tolist()
    _extend(truth, t, n)


def _extend(into: Dict[str, list], columns: Dict[str, Any], n: int) -> None:
    """Appends a side's columns; a column it lacks (or has alone) is
    padded with None, for ``_frame`` to refuse by name."""
    rows = len(next(iter(into.values()))) if into else 0
    for name in columns.keys() - into.keys():
        into[name] = [None] * rows
    for name, values in into.items():
        values.extend(columns.get(name, [None] * n))


def _columns(rows: List[Dict[str, Any]]) -> Dict[str, list]:
    """Rows as columns (a column some rows lack padded with None)."""
    out: Dict[str, list] = {}
    for row in rows:
        _extend(out, {k: [v] for k, v in row.items()}, 1)
    return out


def _frame(columns: Dict[str, list], name: str) -> pl.DataFrame:
    """Columns as a frame; an optional column is all or nothing."""
    for col, values in columns.items():
        if any(v is None for v in values) and not all(v is None for v in values):
            raise CoidError(f"the {name} column '{col}' is given for some vehicles or instances and not for others: give it for all or none")
    return pl.DataFrame({c: v for c, v in columns.items() if not all(x is None for x in v)} if columns else {})
