"""Fixtures for the installed package's tests: a short configuration (the
shipped intersection for 60 s, the fast methods, two test runs) and its
test split exported once for the session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import coid_sim

#: What the tests run: the default intersection for 60 s, the methods
#: that run in seconds, two test runs.
SHORT = {
    "scenario": {"end_s": 60.0},
    "matching": {"methods": ["gps-hungarian", "gps-app-hungarian", "oracle"]},
    "eval": {"traffic_seeds": [1, 2]},
}


@pytest.fixture(autouse=True)
def _coid_home(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """coid's data folder (the shipped files it writes out) for the session,
    never the user's."""
    home = tmp_path_factory.getbasetemp() / "coid-home"
    monkeypatch.setenv("COID_HOME", str(home))


@pytest.fixture(scope="session")
def short_export(tmp_path_factory: pytest.TempPathFactory) -> coid_sim.Dataset:
    """The short configuration's test runs, exported with GPS-Hungarian's
    matches."""
    os.environ["COID_HOME"] = str(tmp_path_factory.getbasetemp() / "coid-home")
    out = tmp_path_factory.mktemp("export") / "ex"
    return coid_sim.export(SHORT, splits=["test"], with_matches=["gps-hungarian"], out=out, quiet=True)


@pytest.fixture
def in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The test's own current folder (where default results folders go)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path
