"""Compile the entries of the native model on all cores at once (the first run on a machine).

numba compiles on one thread and caches per function and signature; a function cached by one process
is loaded by another instead of compiled, if it is on disk when that process needs it (a kernel is
cached as LLVM IR, `linking`). The closed-chain kernel `chain_forward` is the largest piece, and the
time loop (open and closed loop) and the evaluation entry all call it, so the work is split to type
and lower it once:
  this process:    `chain_forward`, then the open-loop time loop (`integrate.run`, which loads the
                   manifold kernels a child has cached by then);
  child "chain_free": the chain-free entries every command uses (projection, inverse-dynamics terms),
                   then the evaluation entry once `chain_forward` is on disk (or after WAIT_S);
  child "control" (with `control`): the extras (inverse kinematics, the capacity objective), the
                   controller entries, then the time loop with a controller in it (its second
                   compilation) once `chain_forward` is on disk.
Then this process loads what the children wrote. Without `control` the extras compile on their first
use (`inverse`, `capacity`), the controllers on the first closed-loop run (`warm_up_group`).
`python -m coopsim.compiled.warmup` compiles everything.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from dataclasses import replace

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
    """The time loop, through a short integration of the model."""
    from . import api

    api.integrate_chain(model, _state(model), np.array([0.0, 0.01]), "dop853")


def compile_chain_free(model) -> None:
    """The entries every command uses that do not call `chain_forward`: the consistent projection and
    the inverse-dynamics terms."""
    from . import api

    y = _state(model)[None]
    n = model.n_total
    api.consistent_state(model, model.q0, model.qd0)
    api.inverse_terms(model, y[:, :n], y[:, n:], np.zeros((1, n)), n_threads=1)


def compile_extras(model) -> None:
    """The entries some commands use: inverse kinematics and the capacity objective."""
    from . import api
    from .capacity import min_energy_mass_interval

    api.solve_arm(model, 0, np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), model.q0, max_iter=1)
    z = np.zeros((1, 1, 1))
    min_energy_mass_interval(z, np.zeros((1, 2, 1)), np.ones(1), np.zeros((1, 1)), np.zeros((1, 1)),
                             np.ones(1, bool), np.ones(1, bool), 1e-12)


def compile_evaluations(model) -> None:
    """The evaluation entry (every reported quantity)."""
    from . import api

    api.evaluate_states(model, _state(model)[None], np.zeros((1, model.n_total)), full=True, n_threads=1)


def compile_control(model) -> None:
    """The controller entries and the time loop with a controller in it."""
    from ..control import Controller
    from ..model import ControlSettings
    from . import api

    n = model.n_total
    y = _state(model)
    pd = Controller(replace(model, control=ControlSettings("joint_pd", np.zeros(n), np.zeros(n))))
    pd.compiled_commands(np.zeros(1), y[None, :n], y[None, n:])
    pd.compiled_call(0.0, y[:n], y[n:])
    _wait_for_chain()
    api.integrate_chain(pd.model, y, np.array([0.0, 0.01]), "dop853", controller=pd.compiled_loop, land=True)


def _chain_cached() -> bool:
    """Whether `chain_forward` is in numba's cache (whose folder is keyed by the compiled sources'
    digest, `coopsim.compiled._cache_dir`: an index there is never stale)."""
    from .chain import chain_forward

    try:
        return os.path.exists(chain_forward._cache._cache_file._index_path)
    except AttributeError:
        return True


def _wait_for_chain() -> None:
    deadline = time.monotonic() + WAIT_S
    while not _chain_cached() and time.monotonic() < deadline:
        time.sleep(0.2)


def chain_free_child(model) -> None:
    """The "chain_free" child's share (module docstring)."""
    compile_chain_free(model)
    _wait_for_chain()
    compile_evaluations(model)


def control_child(model) -> None:
    """The "control" child's share (module docstring)."""
    compile_extras(model)
    compile_control(model)


CHILDREN = {"chain_free": chain_free_child, "control": control_child}


def warm_up(control: bool = False) -> None:
    """Compile what every command uses, on two processes, and with `control` the extras and the
    controllers too, on a third (a no-op for what is cached already). Needs the source checkout's
    scenarios/ folder; does nothing without it."""
    from .api import compile_pending

    if not SCENARIO.exists():
        return
    if not compile_pending():
        if control:
            warm_up_group("extras")
            warm_up_group("control")
        return
    names = [name for name in CHILDREN if control or name != "control"]
    children = [subprocess.Popen([sys.executable, "-m", "coopsim.compiled.warmup", name],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for name in names]
    model = _model()
    try:
        compile_chain(model)
        compile_loop(model)
    finally:
        for child in children:
            child.wait()
    compile_chain_free(model)    # loads what the children cached (or compiles it, if a child failed)
    compile_evaluations(model)
    if control:
        control_child(model)


GROUPS = {"extras": compile_extras, "control": compile_control}


def warm_up_group(group: str) -> None:
    """Compile a compile group (`api._group_entries`): "base" by `warm_up`; "extras" or "control" in
    this process (a no-op when cached), what every command uses first if needed."""
    from .api import compile_pending

    if group == "base":
        warm_up()
    elif SCENARIO.exists() and compile_pending(group):
        warm_up()
        GROUPS[group](_model())


if __name__ == "__main__":
    if sys.argv[1:2] and sys.argv[1] in CHILDREN:
        CHILDREN[sys.argv[1]](_model())
    else:
        warm_up(control=True)
