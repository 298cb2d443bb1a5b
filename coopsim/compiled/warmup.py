"""Compile every entry of the native model on two cores at once (the first run on a machine).

numba compiles on one thread and caches per function, so the entries are split in two groups, each
compiled by its own process: this one compiles the time loop (`integrate.run`), a child process the
evaluation, inverse-dynamics, inverse-kinematics and controller entries and the time loop with a
controller in it. Both write numba's on-disk cache; what
one has written the other loads. `python -m coopsim.compiled.warmup` compiles everything.
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
    """The evaluation, inverse-dynamics-terms, inverse-kinematics and controller entries, and the time
    loop with a controller."""
    from ..simulate import simulate
    from . import api

    model = _model()
    y = np.concatenate([model.q0, model.qd0])[None]
    api.evaluate_states(model, y, np.zeros((1, model.n_total)), full=True, n_threads=1)
    api.inverse_terms(model, y[:, :model.n_total], y[:, model.n_total:], np.zeros((1, model.n_total)), n_threads=1)
    api.solve_arm(model, 0, np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), model.q0, max_iter=1)
    from ..control import Controller
    from ..model import ControlSettings

    n = model.n_total
    pd = Controller(replace(model, control=ControlSettings("joint_pd", np.zeros(n), np.zeros(n))))
    pd.compiled_commands(np.zeros(1), y[:, :n], y[:, n:])
    pd.compiled_call(0.0, y[0, :n], y[0, n:])
    simulate(pd.model, duration=0.01)          # the time loop with a controller (its second compilation)


def warm_up() -> None:
    """Compile everything, the two groups in parallel (a no-op when the cache is complete). Needs the
    source checkout's scenarios/ folder; does nothing without it."""
    from .api import compile_pending

    if not compile_pending() or not SCENARIO.exists():
        return
    child = subprocess.Popen([sys.executable, "-m", "coopsim.compiled.warmup", "evaluations"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        compile_loop()
    finally:
        child.wait()
    compile_evaluations()   # loads what the child cached (or compiles it, if the child failed)


if __name__ == "__main__":
    if sys.argv[1:] == ["evaluations"]:
        compile_evaluations()
    else:
        warm_up()
