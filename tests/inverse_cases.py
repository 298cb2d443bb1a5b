"""Cached trajectories and inverse-dynamics problems shared by the inverse/capacity/stress tests
(plain functions with lru_cache: one forward run per scenario and test session)."""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from coopsim.inverse.problem import inverse_problem
from coopsim.io.scenario import load_scenario
from coopsim.forward.simulate import simulate
from coopsim.inverse.trajectory import from_simulation, object_motion_trajectory
from helpers import SCENARIOS

BUNDLED = sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
PAYLOAD = np.array([0.2, 0.0, 0.0])      # on the paper bar's axis, at arm 2's grasp (object frame, m)


@lru_cache(maxsize=None)
def model(name: str):
    return load_scenario(SCENARIOS / f"{name}.yaml")


@lru_cache(maxsize=None)
def run(name: str, duration: float | None = None):
    """(model, SimResult or None, JointTrajectory) of a bundled scenario's trajectory to invert."""
    m = model(name)
    if m.inverse.trajectory == "object_motion":
        return m, None, object_motion_trajectory(m, m.inverse.object_motion)
    res = simulate(m if duration is None else replace(m, duration=duration))
    return m, res, from_simulation(res)


@lru_cache(maxsize=None)
def problem(name: str, duration: float | None = None, payload: bool = True):
    m, res, traj = run(name, duration)
    return inverse_problem(m, traj, PAYLOAD if payload else None)
