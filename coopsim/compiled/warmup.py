"""Compile every entry of the native model on all cores at once (the first run on a machine).

numba compiles on one thread and caches per function, so the entries are split in three groups, each
compiled by its own process: this one compiles the time loop (`integrate.run`), a child process the
evaluation, inverse-dynamics and inverse-kinematics entries, another the controller entries and the
time loop with a controller in it. All write numba's on-disk cache; what one has written the others
load. `python -m coopsim.compiled.warmup` compiles everything.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "paper_planar_2x3.yaml"


def _model():
    from ..scenario import load_scenario

    return load_scenario(SCENARIO)


def compile_loop() -> None:
    """The time loop, through a short simulation of the paper scenario, and the capacity objective."""
    from ..simulate import simulate
    from .capacity import min_energy_mass_interval

    simulate(_model(), duration=0.02)
    z = np.zeros((1, 1, 1))
    min_energy_mass_interval(z, np.zeros((1, 2, 1)), np.ones(1), np.zeros((1, 1)), np.zeros((1, 1)),
                             np.ones(1, bool), np.ones(1, bool), 1e-12)


def compile_evaluations() -> None:
    """The evaluation, inverse-dynamics-terms and inverse-kinematics entries."""
    from . import api

    model = _model()
    y = np.concatenate([model.q0, model.qd0])[None]
    api.evaluate_states(model, y, np.zeros((1, model.n_total)), full=True, n_threads=1)
    api.inverse_terms(model, y[:, :model.n_total], y[:, model.n_total:], np.zeros((1, model.n_total)), n_threads=1)
    api.solve_arm(model, 0, np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), model.q0, max_iter=1)


def compile_control() -> None:
    """The controller entries and the time loop with a controller in it (its second compilation)."""
    from ..control import Controller
    from ..model import ControlSettings
    from ..simulate import simulate

    model = _model()
    n = model.n_total
    y = np.concatenate([model.q0, model.qd0])[None]
    pd = Controller(replace(model, control=ControlSettings("joint_pd", np.zeros(n), np.zeros(n))))
    pd.compiled_commands(np.zeros(1), y[:, :n], y[:, n:])
    pd.compiled_call(0.0, y[0, :n], y[0, n:])
    simulate(pd.model, duration=0.01)


GROUPS = {"evaluations": compile_evaluations, "control": compile_control}


def warm_up() -> None:
    """Compile everything, the three groups at once (a no-op when the cache is complete). Needs the
    source checkout's scenarios/ folder; does nothing without it."""
    from .api import compile_pending

    if not compile_pending() or not SCENARIO.exists():
        return
    children = [subprocess.Popen([sys.executable, "-m", "coopsim.compiled.warmup", name],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for name in GROUPS]
    try:
        compile_loop()
    finally:
        for child in children:
            child.wait()
    for group in GROUPS.values():   # loads what the children cached (or compiles it, if a child failed)
        group()


if __name__ == "__main__":
    if sys.argv[1:2] and sys.argv[1] in GROUPS:
        GROUPS[sys.argv[1]]()
    else:
        warm_up()
