"""coid's Rust core (the extension module); the package wraps it."""

from typing import Any, Dict, List, Optional, Sequence, Tuple

__version__: str
SCHEMA_VERSION: int

class CoidError(Exception):
    """coid refused its input or failed; the message is the line the
    ``coid`` command prints."""

def main(argv: List[str]) -> int:
    """``coid`` as the process's main program (``python -m coid_sim``):
    prints what the binary prints, returns its exit code, takes the
    process's signals."""

def call(argv: List[str]) -> Optional[str]:
    """One ``coid`` command line in this process (program name first);
    the command's last line (``run``, ``export``, ``score``) or None.
    Raises CoidError."""

def run(config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, out: Optional[str] = None, force: bool = False, threads: Optional[int] = None, traffic_seed: Optional[int] = None, sensor_seed: Optional[int] = None, quiet: bool = False) -> Tuple[str, str]:
    """``coid run`` as a typed call: the results folder and the headline.
    Raises CoidError."""

def export(config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, out: Optional[str] = None, force: bool = False, threads: Optional[int] = None, splits: Sequence[str] = (), with_matches: Sequence[str] = (), dataset: Optional[str] = None, quiet: bool = False) -> Tuple[str, str]:
    """``coid export`` as a typed call: the folder and the line ``coid
    export`` prints. Raises CoidError."""

def score(config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, out: Optional[str] = None, force: bool = False, threads: Optional[int] = None, matches: Optional[str] = None, matches_parquet: Optional[bytes] = None, export: Optional[str] = None, dataset: Optional[str] = None, split: str = "test", quiet: bool = False) -> Tuple[str, str]:
    """``coid score`` as a typed call: matches as a file, or a frame's
    Parquet bytes ("the matches frame" in messages); the folder and the
    line ``coid score`` prints. Raises CoidError."""

def dataset_matches(dataset: str, method: str, config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, threads: Optional[int] = None, quiet: bool = True) -> Dict[str, List[Any]]:
    """A built-in method's matches on every run of a dataset as columns
    (run, instance, pose_noise, a, b, probability, uncertainty), held in
    memory. Raises CoidError."""

def write_dataset(out: str, runs: bytes, instances: bytes, nodes: bytes, truth: bytes, true_pairs: bytes, force: bool = False) -> Tuple[str, str]:
    """A dataset folder from its files' frames as Parquet bytes, checked
    by coid's reader before it appears. Raises CoidError."""

def eval(config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, out: Optional[str] = None, force: bool = False, threads: Optional[int] = None, validation: bool = False, suite: List[str] = [], dataset: Optional[str] = None, quiet: bool = False) -> Tuple[str, str]:
    """``coid eval`` as a typed call: the folder and the line it prints.
    Raises CoidError."""

def track(config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, out: Optional[str] = None, force: bool = False, sweep: bool = False, validation: bool = False, quiet: bool = False) -> Tuple[str, str]:
    """``coid track`` (``sweep``: ``--sweep``) as a typed call: the folder
    and the line it prints last. Raises CoidError."""

def batch(runs: int, config: Optional[str] = None, config_text: Optional[str] = None, shown: Optional[str] = None, out: Optional[str] = None, seed: int = 1, shard: Optional[str] = None, workers: Optional[int] = None, threads: Optional[int] = None, quiet: bool = False) -> Tuple[str, str]:
    """``coid batch`` as a typed call: the folder and the line it prints.
    Raises CoidError."""

def train(config: Optional[str] = None, out: Optional[str] = None, force: bool = False, methods: List[str] = [], workers: Optional[int] = None, skip_validation: bool = False, validate_only: bool = False, seeds: List[int] = [], dataset: Optional[str] = None, reid_rank1: Optional[float] = None, without_descriptor: bool = False, quiet: bool = False) -> Tuple[str, Optional[str]]:
    """``coid train`` as a typed call: the models folder and the line it
    prints last (None with validate_only). Raises CoidError."""

def check_dataset(dir: str) -> Dict[str, Any]:
    """``coid dataset`` as a call: the dataset read run by run, checked,
    and what it holds. Raises CoidError."""

def convert_pyg(source: str, out: str, splits: List[Tuple[str, int, int]], views: Tuple[str, str] = ("proc_s", "proc_t"), name: str = "dmgm", gps_sigma_m: float = 1.2, gps_heading_sigma_deg: float = 0.2, force: bool = False, quiet: bool = False) -> Tuple[str, str]:
    """``coid convert pyg`` as a call: the folder and the line it
    printed. Raises CoidError."""

def toml_of_json(json: str) -> str:
    """A JSON object as TOML text. Raises CoidError."""

def methods() -> List[str]:
    """Every built-in method's label, in the tables' order."""

def delaunay(positions_m: Sequence[Sequence[float]]) -> List[Tuple[int, int]]:
    """coid's Delaunay graph over body-frame positions: each undirected
    edge once, ``a < b``. Raises CoidError."""

class DatasetReader:
    """A dataset folder checked and opened by coid's reader."""

    def __init__(self, dir: str) -> None: ...
    def info(self) -> Dict[str, Any]:
        """runs (run, split, scenario, seed, n_instances), levels (label,
        position sigma), appearance_width, optional_columns."""
    def run(self, k: int) -> List[Dict[str, Any]]:
        """The k-th run's instances as plain values."""

class PublishedNetwork:
    """A published network (gcn-gm, dgmc, coid, ...) with its weights, its
    forward pass run with the dropout masks and consensus indicators the
    caller gives (tools/dgmc_reference). Raises CoidError."""

    def __init__(self, weights: str, method: str, appearance_width: int = 0, samples: int = 1) -> None: ...
    def config(self) -> Dict[str, Any]:
        """kind, node_features, hidden, out, dropout_conv, consensus_dim,
        consensus_steps, sinkhorn_iters, edge_scale_m."""
    def parameters(self) -> Dict[str, Tuple[List[int], List[float]]]:
        """Every parameter by name: shape and row-major values."""
    @staticmethod
    def weights_of(method: str, parameters: Dict[str, Tuple[List[int], List[float]]], appearance_width: int = 0) -> bytes:
        """A .bpk weights file's bytes for these parameters."""
    def forward(
        self,
        first: Tuple[List[float], List[Tuple[int, int]], List[float]],
        second: Tuple[List[float], List[Tuple[int, int]], List[float]],
        masks: Tuple[List[float], List[float]],
        indicators: List[List[float]],
    ) -> List[List[float]]:
        """Each sample's (n1 + 1) x (n2 + 1) assignment, dustbins last."""
