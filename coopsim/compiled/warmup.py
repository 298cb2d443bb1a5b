"""Compile every entry of the native model on two cores at once (the first run on a machine).

numba compiles on one thread and caches per function and signature; a function cached by one process
is loaded by another instead of compiled, if it is on disk when that process needs it. The closed-chain
kernel `chain_forward` is the largest piece, and both the time loop and the evaluation entry call it,
so the work is split to compile it once:
  this process:   `chain_forward`, then the time loop (`integrate.run`, which loads the manifold
                  kernels the child has cached by then) and the capacity kernel;
  a child process: the chain-free entries (projection, inverse kinematics, inverse-dynamics terms),
                  then the evaluation entry once `chain_forward` is on disk (or after WAIT_S).
Then this process loads what the child wrote. `python -m coopsim.compiled.warmup` compiles everything.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "paper_planar_2x3.yaml"
WAIT_S = 120.0      # the child's longest wait for the parent's `chain_forward` before compiling it itself


def _model():
    from ..scenario import load_scenario

    return load_scenario(SCENARIO)


def _state(model):
    return np.concatenate([model.q0, model.qd0])


def compile_chain(model) -> None:
    """`chain.chain_forward` for the packed model's types and contiguous float64 vectors (the
    signature both callers use)."""
    from numba import typeof, types

    from . import api
    from .chain import chain_forward

    c = api.compiled(model)
    vec = types.float64[::1]
    chain_forward.compile((typeof(c.Ps), typeof(c.Ws), vec, vec, vec, vec))


def compile_loop(model) -> None:
    """The time loop, through a short integration of the model, and the capacity objective."""
    from . import api
    from .capacity import min_energy_mass_interval

    api.integrate_chain(model, _state(model), np.array([0.0, 0.01]), "dop853")
    z = np.zeros((1, 1, 1))
    min_energy_mass_interval(z, np.zeros((1, 2, 1)), np.ones(1), np.zeros((1, 1)), np.zeros((1, 1)),
                             np.ones(1, bool), np.ones(1, bool), 1e-12)


def compile_chain_free(model) -> None:
    """The entries that do not call `chain_forward`: the consistent projection, inverse kinematics and
    the inverse-dynamics terms."""
    from . import api

    y = _state(model)[None]
    n = model.n_total
    api.consistent_state(model, model.q0, model.qd0)
    api.inverse_terms(model, y[:, :n], y[:, n:], np.zeros((1, n)), n_threads=1)
    api.solve_arm(model, 0, np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), model.q0, max_iter=1)


def compile_evaluations(model) -> None:
    """The evaluation entry (every reported quantity)."""
    from . import api

    api.evaluate_states(model, _state(model)[None], np.zeros((1, model.n_total)), full=True, n_threads=1)


def _chain_cached() -> bool:
    """Whether `chain_forward`'s cache index was written after its source last changed."""
    from . import chain

    try:
        index = chain.chain_forward._cache._cache_file._index_path
        return os.path.exists(index) and os.path.getmtime(index) >= os.path.getmtime(chain.__file__)
    except (AttributeError, OSError):
        return True


def child() -> None:
    """The child's share (module docstring)."""
    model = _model()
    compile_chain_free(model)
    deadline = time.monotonic() + WAIT_S
    while not _chain_cached() and time.monotonic() < deadline:
        time.sleep(0.2)
    compile_evaluations(model)


def warm_up() -> None:
    """Compile everything, on two processes (a no-op when the cache is complete). Needs the source
    checkout's scenarios/ folder; does nothing without it."""
    from .api import compile_pending

    if not compile_pending() or not SCENARIO.exists():
        return
    proc = subprocess.Popen([sys.executable, "-m", "coopsim.compiled.warmup", "child"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    model = _model()
    try:
        compile_chain(model)
        compile_loop(model)
    finally:
        proc.wait()
    compile_chain_free(model)    # loads what the child cached (or compiles it, if the child failed)
    compile_evaluations(model)


if __name__ == "__main__":
    if sys.argv[1:] == ["child"]:
        child()
    else:
        warm_up()
