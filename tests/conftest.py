"""The test session's set-up (the native model compiled once, before the workers start) and the shared
fixtures; the shared helpers are in helpers.py."""

from __future__ import annotations

import shutil

import pytest

from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS


def pytest_sessionstart(session):
    """Compile the native model once, before any test (and before xdist starts its workers, whose
    processes and the CLI subprocesses then load it from numba's cache instead of compiling it each)."""
    if not hasattr(session.config, "workerinput"):
        from coopsim.apps.warmup import warm_up

        warm_up(control=True)


@pytest.fixture
def workdir(tmp_path):
    """A temporary folder holding a copy of scenarios/."""
    shutil.copytree(SCENARIOS, tmp_path / "scenarios")
    return tmp_path


@pytest.fixture(scope="session")
def paper():
    return load_scenario(SCENARIOS / "paper_planar_2x3.yaml")


@pytest.fixture(scope="session")
def spatial():
    return load_scenario(SCENARIOS / "spatial_6r_pair.yaml")


@pytest.fixture(scope="session")
def three_arms():
    return load_scenario(SCENARIOS / "planar_3arm_vertical.yaml")
