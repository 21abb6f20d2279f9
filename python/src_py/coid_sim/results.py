"""A results folder that a coid command wrote, read as frames."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Optional

import polars as pl


class Results:
    """The folder a command wrote (``out``) and the line it printed last
    (``headline``). Its tables (``*.csv``, ``*.parquet``) are read on
    demand: ``frame("summary")`` is ``summary.csv`` as a polars frame
    (``backend="pandas"`` for pandas)."""

    def __init__(self, out: Path, headline: Optional[str]) -> None:
        self.out = Path(out)
        self.headline = headline

    def __repr__(self) -> str:
        return f"Results({str(self.out)!r}, tables={self.tables()})"

    def tables(self) -> List[str]:
        """The names of the folder's tables (file stems), sorted."""
        return sorted(p.stem for p in self.out.iterdir() if p.suffix in (".csv", ".parquet"))

    def frame(self, name: str, *, backend: str = "polars") -> Any:
        """One table by name (``"summary"`` or ``"summary.csv"``)."""
        path = self._path(name)
        frame = pl.read_parquet(path) if path.suffix == ".parquet" else pl.read_csv(path, infer_schema_length=None)
        if backend == "polars":
            return frame
        if backend == "pandas":
            try:
                import pandas  # noqa: F401
                import pyarrow  # noqa: F401
            except ImportError as e:
                raise ImportError(f"pandas frames need pandas and pyarrow ({e}): pip install 'coid-sim[pandas]'") from e
            return frame.to_pandas()
        raise ValueError(f"backend must be 'polars' or 'pandas', not {backend!r}")

    def frames(self, *, backend: str = "polars") -> Dict[str, Any]:
        """Every table of the folder, by name."""
        return {name: self.frame(name, backend=backend) for name in self.tables()}

    def _path(self, name: str) -> Path:
        direct = self.out / name
        if direct.suffix in (".csv", ".parquet") and direct.is_file():
            return direct
        for suffix in (".csv", ".parquet"):
            candidate = self.out / f"{name}{suffix}"
            if candidate.is_file():
                return candidate
        raise KeyError(f"{self.out} has no table {name!r} (it has {', '.join(self.tables())})")
