"""Datasets (coid's exports, or data converted from elsewhere) as numpy
arrays, PyTorch Geometric ``PairData`` and pygmtools' inputs.

A dataset folder is checked and read by coid's own reader (the one ``coid
eval --dataset`` and ``coid score`` use), so an instance here is exactly
what coid's matchers see: each vehicle's nodes in its body frame (x
forward, y left, metres), its GPS-reported pose at each pose-noise level,
and the truth beside them.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np
import polars as pl

from . import _coid_sim
from ._coid_sim import CoidError

#: coid's detected classes, in the order of the one-hot node features.
CLASSES: Tuple[str, ...] = ("car", "van", "truck", "bus", "motorcycle", "bicycle", "pedestrian")
#: What stands in for a column a dataset lacks (as coid's matchers fill
#: it: one grey, one size, so that they tell no two nodes apart).
UNKNOWN_COLOUR = (0.5, 0.5, 0.5)
UNKNOWN_SIZE_M = (4.6, 1.8, 1.5)

#: The columns of a matches frame, as ``matches-<method>.parquet`` holds them.
MATCH_SCHEMA = {
    "run": pl.UInt64,
    "instance": pl.UInt64,
    "pose_noise": pl.String,
    "a": pl.UInt64,
    "b": pl.UInt64,
    "probability": pl.Float64,
    "uncertainty": pl.Float64,
}


class Match(NamedTuple):
    """Node ``a`` of the first vehicle is node ``b`` of the second, with
    the matcher's probability and its uncertainty (bits, in [0, 1])."""

    a: int
    b: int
    probability: float
    uncertainty: float


@dataclass(frozen=True)
class Level:
    """An instance at one pose-noise level: each vehicle's reported pose
    (world x, y in metres, heading in radians) and the accuracy its GPS
    claims."""

    label: str
    position_sigma_m: float
    heading_sigma_rad: Tuple[float, float]
    reported: Tuple[Tuple[float, float, float], Tuple[float, float, float]]


def _array(values: Optional[list], width: int, dtype: Any = np.float64) -> Optional[np.ndarray]:
    if values is None:
        return None
    return np.asarray(values, dtype=dtype).reshape(-1, width)


@dataclass(frozen=True)
class Side:
    """One vehicle's nodes, one row each (``n`` rows); a column the dataset
    lacks is None, a value a node lacks NaN (an appearance vector: zeros)."""

    id: str
    xy_m: np.ndarray
    classes: np.ndarray
    sender: np.ndarray
    object_id: np.ndarray
    cov_m2: Optional[np.ndarray] = None
    colour_rgb: Optional[np.ndarray] = None
    size_m: Optional[np.ndarray] = None
    heading_speed: Optional[np.ndarray] = None
    world_m: Optional[np.ndarray] = None
    appearance: Optional[np.ndarray] = None
    true_m: Optional[np.ndarray] = None
    visible_fraction: Optional[np.ndarray] = None
    _network: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    @staticmethod
    def _of(raw: Mapping[str, Any], appearance_width: Optional[int]) -> "Side":
        cov = _array(raw["cov_m2"], 3)
        if cov is not None:
            cov = np.stack([cov[:, [0, 1]], cov[:, [1, 2]]], axis=1)
        appearance = raw["appearance"]
        vf = _array(raw["visible_fraction"], 1)
        return Side(
            id=raw["id"],
            xy_m=np.asarray(raw["xy_m"], dtype=np.float64).reshape(-1, 2),
            classes=np.asarray(raw["class"], dtype=object),
            sender=np.asarray(raw["sender"], dtype=bool),
            object_id=np.asarray(raw["object_id"], dtype=object),
            cov_m2=cov,
            colour_rgb=_array(raw["colour_rgb"], 3),
            size_m=_array(raw["size_m"], 3),
            heading_speed=_array(raw["heading_speed"], 2),
            world_m=_array(raw["world_m"], 2),
            appearance=None if appearance is None else np.asarray(appearance, dtype=np.float32).reshape(len(raw["xy_m"]), appearance_width or 0),
            true_m=_array(raw["true_m"], 2),
            visible_fraction=None if vf is None else vf[:, 0],
            _network=np.asarray(raw["network_features"], dtype=np.float32).reshape(len(raw["xy_m"]), 13),
        )

    def __len__(self) -> int:
        return int(self.xy_m.shape[0])

    def edges(self) -> np.ndarray:
        """The Delaunay graph coid's matchers build over the nodes: each
        undirected edge once, ``[e, 2]`` with ``a < b``."""
        pairs = _coid_sim.delaunay(self.xy_m.tolist())
        return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)

    def features(self) -> np.ndarray:
        """Node features ``[n, 13 (+ d)]``: the class one-hot (``CLASSES``),
        colour (RGB in [0, 1]), size (length, width, height in metres), then
        the appearance vector where the dataset has one. A colour or size
        missing (for the dataset, or for a node) is the same for every node
        (``UNKNOWN_*``), as coid fills it."""
        n = len(self)
        onehot = np.zeros((n, len(CLASSES)))
        for i, c in enumerate(self.classes):
            if c in CLASSES:
                onehot[i, CLASSES.index(c)] = 1.0

        def filled(values: Optional[np.ndarray], unknown: Tuple[float, ...]) -> np.ndarray:
            known = np.tile(unknown, (n, 1))
            if values is None:
                return known
            return np.where(np.isnan(values).any(axis=1, keepdims=True), known, values)

        colour = filled(self.colour_rgb, UNKNOWN_COLOUR)
        size = filled(self.size_m, UNKNOWN_SIZE_M)
        parts = [onehot, colour, size]
        if self.appearance is not None:
            parts.append(self.appearance.astype(np.float64))
        return np.concatenate(parts, axis=1).reshape(n, -1)


    def network_features(self) -> np.ndarray:
        """The node attributes coid's networks read, ``[n, 13 (+ d)]``
        float32, computed by coid itself: the class one-hot, colour, and
        size as the networks scale it (length / 10 m, width / 3 m, height /
        4 m), what the dataset lacks filled as :meth:`features` fills it,
        then the appearance vector where the dataset has one. What a
        network trained elsewhere must read to run in coid
        (``tools/dgmc_reference``)."""
        parts = [self._network]
        if self.appearance is not None:
            parts.append(self.appearance.astype(np.float32))
        return np.concatenate(parts, axis=1).reshape(len(self), -1)


def _to_world(xy: np.ndarray, pose: Sequence[float]) -> np.ndarray:
    x, y, h = pose
    c, s = math.cos(h), math.sin(h)
    return np.stack([x + c * xy[:, 0] - s * xy[:, 1], y + s * xy[:, 0] + c * xy[:, 1]], axis=1).reshape(-1, 2)


def _both_ways(edges: np.ndarray) -> np.ndarray:
    """``[2, 2e]``: every undirected edge in both directions (PyG's)."""
    return np.concatenate([edges, edges[:, ::-1]], axis=0).T.copy()


def _cartesian(xy: np.ndarray, index: np.ndarray) -> np.ndarray:
    """DGMC's edge attributes (PyG's ``Cartesian`` transform): each edge's
    offset, source minus target, scaled into [0, 1] by the largest one."""
    if index.shape[1] == 0:
        return np.zeros((0, 2))
    offset = xy[index[0]] - xy[index[1]]
    largest = np.abs(offset).max()
    return offset / (2.0 * largest) + 0.5 if largest > 0 else np.full_like(offset, 0.5)


@dataclass(frozen=True)
class Instance:
    """A step and a pair of connected vehicles: ``first`` and ``second``
    (the vehicle with the smaller id first), their reported poses at each
    pose-noise level (``levels``), and the true correspondences
    (``true_pairs``, ``[k, 2]``: node ``a`` of the first is node ``b`` of
    the second)."""

    run: int
    split: str
    scenario: str
    instance: int
    step: int
    time_s: Optional[float]
    levels: Tuple[Level, ...]
    first: Side
    second: Side
    true_pairs: np.ndarray
    true_poses: Tuple[Optional[Tuple[float, float, float]], Optional[Tuple[float, float, float]]]
    _dataset: "Dataset" = field(repr=False, compare=False, default=None)  # type: ignore[assignment]

    @property
    def y(self) -> np.ndarray:
        """``[n_first]``: the index of each first-vehicle node's partner
        among the second's nodes, or -1 where it has none."""
        y = np.full(len(self.first), -1, dtype=np.int64)
        if len(self.true_pairs):
            y[self.true_pairs[:, 0]] = self.true_pairs[:, 1]
        return y

    def level(self, label: str = "gps") -> Level:
        """The instance at one pose-noise level (``none``, ``rtk``, ``gps``
        by default)."""
        for lv in self.levels:
            if lv.label == label:
                return lv
        raise _coid_sim.CoidError(f"the dataset has no pose-noise level {label!r} (it has {', '.join(l.label for l in self.levels)})")

    def world_xy(self, label: str = "gps") -> Tuple[np.ndarray, np.ndarray]:
        """Both vehicles' nodes in the world frame, as their reported poses
        at ``label`` put them."""
        lv = self.level(label)
        return _to_world(self.first.xy_m, lv.reported[0]), _to_world(self.second.xy_m, lv.reported[1])

    def arrays(self, label: str = "gps") -> Dict[str, np.ndarray]:
        """The instance in DGMC's names, as numpy arrays: ``x_s`` (node
        features, :meth:`Side.features`), ``edge_index_s`` (``[2, 2e]``,
        the Delaunay graph both ways), ``edge_attr_s`` (DGMC's Cartesian
        pseudo-coordinates), ``pos_s`` (body frame, metres), ``pos_world_s``
        (world, through the reported pose at ``label``), ``pose_s`` (that
        pose), the same with ``_t`` for the second vehicle, and ``y``."""
        out: Dict[str, np.ndarray] = {}
        world = self.world_xy(label)
        lv = self.level(label)
        for suffix, side, w, pose in (("s", self.first, world[0], lv.reported[0]), ("t", self.second, world[1], lv.reported[1])):
            index = _both_ways(side.edges())
            out[f"x_{suffix}"] = side.features().astype(np.float32)
            out[f"edge_index_{suffix}"] = index
            out[f"edge_attr_{suffix}"] = _cartesian(side.xy_m, index).astype(np.float32)
            out[f"pos_{suffix}"] = side.xy_m.astype(np.float32)
            out[f"pos_world_{suffix}"] = w.astype(np.float32)
            out[f"pose_{suffix}"] = np.asarray(pose, dtype=np.float32)
        out["y"] = self.y
        return out

    def to_pyg(self, label: str = "gps") -> Any:
        """A PyTorch Geometric ``PairData`` in DGMC's convention (the fields
        of :meth:`arrays` as tensors; ``edge_index_s`` batches by
        ``x_s``'s rows, ``y`` stays local: the partner's index in its own
        instance, -1 for none). Needs torch_geometric."""
        torch = _needs("torch", "to_pyg")
        data = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in self.arrays(label).items()}
        return pair_data_class()(**data, run=self.run, instance=self.instance, num_nodes=len(self.first))

    def to_pygmtools(self, label: str = "gps") -> Dict[str, Any]:
        """pygmtools' inputs to ``build_aff_mat``: ``node_feat1`` and ``2``
        (``[n, f]``), ``edge_feat1`` and ``2`` (each edge's length in metres,
        ``[ne, 1]``), ``connectivity1`` and ``2`` (``[ne, 2]``, both
        directions), ``n1``, ``n2``, ``ne1``, ``ne2``, and ``X_gt``
        (``[n1, n2]``, 1 where two nodes are the same object)."""
        out: Dict[str, Any] = {}
        for k, side in (("1", self.first), ("2", self.second)):
            conn = _both_ways(side.edges()).T.copy()
            length = np.linalg.norm(side.xy_m[conn[:, 1]] - side.xy_m[conn[:, 0]], axis=1) if len(conn) else np.zeros(0)
            out[f"node_feat{k}"] = side.features()
            out[f"edge_feat{k}"] = length.reshape(-1, 1)
            out[f"connectivity{k}"] = conn
            out[f"n{k}"] = len(side)
            out[f"ne{k}"] = int(conn.shape[0])
        gt = np.zeros((len(self.first), len(self.second)))
        if len(self.true_pairs):
            gt[self.true_pairs[:, 0], self.true_pairs[:, 1]] = 1.0
        out["X_gt"] = gt
        return out

    def match(self, method: str, label: str = "gps") -> List[Match]:
        """A built-in matcher's correspondences on this instance at
        ``label``: ``method`` is one of coid's (``"ours"``, ``"coid"``,
        ``"gps-app-hungarian"``, ``"mogm"``, ...), with the settings of the
        dataset's configuration (the defaults unless it was opened with
        one). The method runs once over the whole dataset
        (:meth:`Dataset.matches`), kept for the next call."""
        self.level(label)
        frame = self._dataset.matches(method)

        rows = frame.filter(
            (pl.col("run") == self.run) & (pl.col("instance") == self.instance) & (pl.col("pose_noise") == label)
        )
        return [Match(int(r["a"]), int(r["b"]), float(r["probability"]), float(r["uncertainty"])) for r in rows.iter_rows(named=True)]


_PAIR_DATA: Any = None


def _needs(module: str, what: str) -> Any:
    """``module``, imported; a missing one named with what to install."""
    import importlib

    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        raise ModuleNotFoundError(
            f"{what} needs torch and torch_geometric, which are not installed here "
            f"(pip install torch torch_geometric)",
            name=e.name,
        ) from None


def pair_data_class() -> Any:
    """DGMC's ``PairData``: a ``torch_geometric.data.Data`` whose
    ``edge_index_s``/``_t`` are offset by ``x_s``/``x_t``'s rows when
    batched (everything else, ``y`` too, is not)."""
    global _PAIR_DATA
    if _PAIR_DATA is None:
        Data = _needs("torch_geometric.data", "to_pyg").Data

        class PairData(Data):  # type: ignore[misc, valid-type]
            def __inc__(self, key: str, value: Any, *args: Any, **kwargs: Any) -> Any:
                if key.startswith("edge_index_s"):
                    return self.x_s.size(0)
                if key.startswith("edge_index_t"):
                    return self.x_t.size(0)
                return 0

        _PAIR_DATA = PairData
    return _PAIR_DATA


class Dataset:
    """A dataset folder (``coid export``'s, ``coid convert``'s, or any that
    fits the schema of docs/export-schema.md), checked by coid's reader.

    Iterating it gives every :class:`Instance` of every run in the
    folder's order; ``instances(split="test")`` those of one split.
    ``config`` gives the built-in methods' settings for :meth:`matches`
    (a TOML file or a dict; the defaults when None)."""

    def __init__(self, path: Union[str, "os.PathLike[str]"], *, config: Any = None) -> None:
        self.path = Path(path)
        self.config = config
        self._reader = _coid_sim.DatasetReader(str(self.path))
        info = self._reader.info()
        self.runs: pl.DataFrame = pl.DataFrame(
            info["runs"],
            schema={"run": pl.UInt64, "split": pl.String, "scenario": pl.String, "seed": pl.UInt64, "n_instances": pl.UInt64},
        )
        #: The pose-noise levels, each with its position accuracy (m).
        self.levels: List[Tuple[str, float]] = [tuple(l) for l in info["levels"]]
        self.appearance_width: Optional[int] = info["appearance_width"]
        self.optional_columns: List[str] = list(info["optional_columns"])
        self._matches: Dict[str, pl.DataFrame] = {}

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r}, runs={self.runs.height}, instances={int(self.runs['n_instances'].sum())})"

    def __len__(self) -> int:
        """Instances in the dataset."""
        return int(self.runs["n_instances"].sum())

    def __iter__(self) -> Iterator[Instance]:
        return self.instances()

    def run(self, k: int) -> List[Instance]:
        """The instances of the ``k``-th run (``runs``' row ``k``)."""
        if not 0 <= k < self.runs.height:
            raise _coid_sim.CoidError(f"{self.path} has {self.runs.height} runs: no run {k}")
        meta = self.runs.row(k, named=True)
        out = []
        for raw in self._reader.run(k):
            levels = tuple(
                Level(l["label"], l["position_sigma_m"], tuple(l["heading_sigma_rad"]), tuple(tuple(p) for p in l["reported"]))
                for l in raw["levels"]
            )
            pairs = np.asarray(raw["true_pairs"], dtype=np.int64).reshape(-1, 2)
            poses = tuple(None if p is None else tuple(p) for p in raw["true_poses"])
            out.append(
                Instance(
                    run=meta["run"],
                    split=meta["split"],
                    scenario=meta["scenario"],
                    instance=raw["instance"],
                    step=raw["step"],
                    time_s=raw["time_s"],
                    levels=levels,
                    first=Side._of(raw["sides"][0], self.appearance_width),
                    second=Side._of(raw["sides"][1], self.appearance_width),
                    true_pairs=pairs,
                    true_poses=poses,  # type: ignore[arg-type]
                    _dataset=self,
                )
            )
        return out

    def instances(self, split: Optional[str] = None) -> Iterator[Instance]:
        """Every instance, run by run (only ``split``'s runs when given:
        ``"train"``, ``"validation"`` or ``"test"``)."""
        if split is not None and split not in ("train", "validation", "test"):
            have = ", ".join(dict.fromkeys(self.runs["split"].to_list())) or "none"
            raise CoidError(f"{split!r} is not a split (train, validation or test; this dataset's runs are {have})")
        for k, split_k in enumerate(self.runs["split"].to_list()):
            if split is None or split_k == split:
                yield from self.run(k)

    def to_pyg(self, split: Optional[str] = None, label: str = "gps") -> List[Any]:
        """Every instance (of ``split``) as DGMC's ``PairData``."""
        return [inst.to_pyg(label) for inst in self.instances(split)]

    def matches(self, method: str, *, threads: Optional[int] = None) -> pl.DataFrame:
        """A built-in method's matches on every run of the dataset, as a
        matches frame (run, instance, pose_noise, a, b, probability,
        uncertainty): ``coid export --dataset`` in this process, once per
        method (kept for the next call)."""
        from . import _config_source, _threads

        _threads(threads)

        if method not in _coid_sim.methods():
            raise CoidError(f"unknown method {method!r} (coid's methods: {', '.join(_coid_sim.methods())})")
        if method not in self._matches:
            path, text = _config_source(self.config)
            columns = _coid_sim.dataset_matches(os.fspath(self.path), method, config=path, config_text=text, shown="the configuration dict", threads=threads)
            self._matches[method] = pl.DataFrame(columns, schema=MATCH_SCHEMA)
        return self._matches[method]
