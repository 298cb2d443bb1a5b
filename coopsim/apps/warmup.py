"""Compile the entries of the native model on all cores at once (the first run on a machine).

numba compiles on one thread and caches per function and signature; a function cached by one process
is loaded by another instead of compiled, if it is on disk when that process needs it (a kernel is
cached as LLVM IR, `linking`). The closed-chain kernel `chain_forward` is the largest piece: the time
loop (open and closed loop) and the evaluation entry call it, the projection and the inverse-dynamics
terms call its kinematic kernels. The work is split so that no kernel is compiled twice, each process
waiting for what the other one compiles:
  this process:      the records' constructors and most of `chain_forward`'s kinematic kernels
                     (`KINEMATICS`, by signature); once the child's share is on disk,
                     `chain_forward`; then the open-loop time loop (`integrate.run`, which compiles
                     the projection kernels);
  child "chain_free": `chain_solve` and the other kinematic kernels (`CHILD_KERNELS`, by signature);
                     once the constructors are on disk, the inverse-dynamics terms; once
                     `chain_forward` is, the evaluation entry; once the projection kernels are, the
                     consistent projection;
  child "control" (with `control`): once `chain_forward` is on disk, the extras (inverse
                     kinematics, the capacity objective, the linear resolutions' pass, the LP vertices, the
                     section loads), the controller entries and the time loop with a controller in it.
Then this process loads what the children wrote. A wait ends when the kernel is on disk, when the
child compiling it has ended (this process's waits), or after WAIT_S; the process then compiles what
it needs itself. Without `control` the extras compile on their first use (`inverse`, `capacity`,
object-motion trajectories), the controllers on the first closed-loop run (`warm_up_group`). The children end with
this process however it ends (`coopsim.io.processes`), and are stopped when it is interrupted.
`python -m coopsim.apps.warmup` compiles everything.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
from numba import types

from coopsim.compiled import api, closed_chain, gibbs_appell, grasp, kinematics
from coopsim.compiled.api import compile_pending, compiled, is_cached
from coopsim.compiled.capacity import min_energy_mass_interval
from coopsim.compiled.closed_chain import chain_forward
from coopsim.compiled.manifold import project_state
from coopsim.compiled.structs import PACKED_T, WORKSPACE_T, _new_workspace
from coopsim.control.controller import Controller
from coopsim.core.model import ControlSettings, ObjectMotion
from coopsim.io.processes import end_with_parent
from coopsim.io.scenario import model_from_dict


def _box(length: float) -> dict:
    return {"joint": {"axis": [0, 0, 1]}, "box": {"length": length, "cross_section": [0.04, 0.04], "density": 7850}}


def _arm(name: str, x: float, angles_deg: list, torque: list) -> dict:
    return {"name": name, "base": {"position": [x, 0.0, 0.0]}, "links": [_box(0.6), _box(0.6), _box(0.05)],
            "initial": {"angles_deg": angles_deg}, "torque": {"constant": torque},
            "motors": {"stall_torque": [0.55, 0.96, 0.96], "no_load_speed": [5.85, 3.0, 3.0]}}


# The scene the warm-up compiles on, built here so that an installed package warms up too: the paper's
# two planar 3R arms and steel bar (scenarios/paper_planar_2x3.yaml). Kernels are compiled for the
# types of their arguments, which any scene shares.
SCENE = {"name": "warm_up", "gravity": [0.0, 0.0, -9.81], "duration": 0.05,
         "arms": [_arm("arm1", 0.0, [90.0, 303.56, 326.44], [0.5, -0.02, 0.0]),
                  _arm("arm2", 1.5, [90.0, 56.44, 33.56], [-0.1, 0.0, 0.0])],
         "object": {"box": {"size": [0.4, 0.06, 0.1], "density": 7850},
                    "grasps": [{"arm": "arm1", "position": [-0.2, 0.0, 0.0]},
                               {"arm": "arm2", "position": [0.2, 0.0, 0.0], "rpy_deg": [0, 0, 180]}]},
         "integrator": {"method": "dop853", "rtol": 1e-12, "atol": 1e-13, "output_dt": 0.01}}
WAIT_S = 120.0      # the longest wait for a kernel another process compiles


def _model():
    return model_from_dict(SCENE, where="warm-up scene")


def _state(model):
    return np.concatenate([model.q0, model.qd0])


def _signatures() -> dict:
    """The kernels compiled by signature, as `chain_forward` calls them: the records' types, int64 arm
    indices and contiguous float64 vectors (a test checks that no caller compiles another one)."""
    vec, i = types.float64[::1], types.int64
    return {kinematics.arm_kinematics: (i, vec), kinematics.arm_jacobian: (i,), gibbs_appell.arm_bias: (i, vec),
            gibbs_appell.arm_mass_matrix: (i,), grasp.object_pose: (), grasp.object_dynamics: (vec,),
            closed_chain.constraint_jacobian: (), closed_chain.constraint_bias: (),
            closed_chain.baumgarte_rhs: (vec, vec), closed_chain.chain_solve: (vec, vec),
            closed_chain.chain_forward: (vec, vec, vec, vec)}


def _named(names) -> dict:
    """The kernels of `_signatures` named in `names`, with their signatures after P, W."""
    return {kernel: rest for kernel, rest in _signatures().items() if kernel.__name__ in names}


def compile_kernels(names) -> None:
    """Compile the named kernels of `_signatures` (P, W first), from their types alone: no record needed.

    Args:
        names: the kernels' function names (e.g. `KINEMATICS`, `CHILD_KERNELS`).
    """
    for kernel, rest in _named(names).items():
        kernel.compile((PACKED_T, WORKSPACE_T, *rest))


# `chain_forward`'s callees, by process: each share takes about as long with what else the process
# compiles first (this one the records' constructors, the child nothing)
KINEMATICS = ("arm_kinematics", "arm_jacobian", "arm_bias", "object_pose", "object_dynamics",
              "constraint_jacobian", "baumgarte_rhs")
CHILD_KERNELS = ("chain_solve", "arm_mass_matrix", "constraint_bias")


def compile_loop(model) -> None:
    """Compile the time loop, through a short integration of the model (0.01 s, dop853).

    Args:
        model: the warm-up scene's Model (any model: kernels are compiled for argument types).
    """
    api.integrate_chain(model, _state(model), np.array([0.0, 0.01]), "dop853")


def compile_consistent(model) -> None:
    """Compile the consistent projection, on the model's initial state.

    Args:
        model: the warm-up scene's Model.
    """
    api.consistent_state(model, model.q0, model.qd0)


def compile_inverse_terms(model) -> None:
    """Compile the inverse-dynamics terms, on one sample (the initial state, zero accelerations).

    Args:
        model: the warm-up scene's Model.
    """
    y = _state(model)[None]
    n = model.n_total
    api.inverse_terms(model, y[:, :n], y[:, n:], np.zeros((1, n)), n_threads=1)


def compile_extras(model) -> None:
    """Compile the entries some commands use: inverse kinematics (one arm's, and an object motion's in one pass), the
    object's states along a motion, the capacity objective, the linear resolutions' pass, the LP vertices, the
    section loads, the retiming's reachability pass and the LP bound's (with its small-LP solver).

    Args:
        model: the warm-up scene's Model.
    """
    api.solve_arm(model, 0, np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), model.q0, max_iter=1)
    still = ObjectMotion(np.array([0.0, 1.0]), np.zeros((2, 3)), np.stack([np.eye(3)] * 2))
    api.object_motion_ik(model, still, np.array([0.0, 1.0]), model.q0, [], np.zeros((model.r, 3)),
                         np.full(model.r, np.inf), 1e-9, max_iter=1)
    api.object_states(model, still, np.array([0.0, 1.0]))
    z = np.zeros((1, 1, 1))
    min_energy_mass_interval(z, np.zeros((1, 2, 1)), np.ones(1), np.zeros((1, 1)), np.zeros((1, 1)),
                             np.ones(1, bool), np.ones(1, bool), 1e-12)
    n, k, r = model.n_total, model.rows.shape[0], model.r
    lim = np.zeros((1, n))
    api.linear_pass(np.zeros((1, n, r * k)), np.zeros((1, k, r * k)), lim, np.zeros((1, r, 6, 6)), np.eye(3)[None],
                    model.rows, np.ones(r), np.zeros((r, 3, 3)), model.motors.passive, np.ones(n), np.zeros((1, 1, k)),
                    np.ones(3, bool), 0, lim, lim, [(0, 0)], 1e-12)
    api.lp_vertices(np.eye(2)[None], np.zeros((1, 2)), np.ones((1, 2)), np.ones((1, 2)), np.ones(1), np.ones(1),
                    np.zeros(1), np.ones(1), np.zeros(1), np.ones(1), 1, np.zeros(1, np.int64),
                    np.zeros((1, 2), np.int8), (1e-12, 1e-10, 1e-9))
    api.reachability_pass(np.ones(3), np.ones(3), np.ones(3), np.array([0, 3]), np.ones(1), np.ones(1),
                          np.zeros(1, np.int64), np.ones(1, bool), np.ones(1, bool), 2)
    api.dense_lp_solve(np.ones((1, 1)), np.ones(1), np.ones(1), np.ones(1))
    api.lp_reachability_pass(np.ones(3), np.ones(3), np.ones(3), np.full(3, -1), np.ones((3, 1)), np.array([0, 3]),
                             np.full(1, 2), np.ones(1), np.ones(1), np.ones((1, 3)), np.ones(3), np.zeros(1, np.int64),
                             np.ones(1, bool), np.ones(1, bool), 2)
    one = np.ones((1, 3))
    api.section_loads(1.0, np.eye(3)[None], np.zeros((1, 6)), np.zeros((1, 6)), model.gravity, np.zeros((1, r, 6)),
                      model.rows, model.object.grasp_pos, 0, np.ones(1), one, one, one, np.ones((r, 1)), np.ones(4))


def compile_evaluations(model) -> None:
    """Compile the evaluation entry (every reported quantity), on one sample.

    Args:
        model: the warm-up scene's Model.
    """
    api.evaluate_states(model, _state(model)[None], np.zeros((1, model.n_total)), full=True, n_threads=1)


def compile_control(model) -> None:
    """Compile the controller entries and the time loop with a controller in it (a zero-gain joint PD).

    Args:
        model: the warm-up scene's Model.
    """
    n = model.n_total
    y = _state(model)
    pd = Controller(replace(model, control=ControlSettings("joint_pd", np.zeros(n), np.zeros(n))))
    pd.compiled_commands(np.zeros(1), y[None, :n], y[None, n:])
    pd.compiled_call(0.0, y[:n], y[n:])
    api.integrate_chain(pd.model, y, np.array([0.0, 0.01]), "dop853", controller=pd.compiled_loop, land=True)


def wait_for(kernel, child: subprocess.Popen | None = None) -> None:
    """Wait until `kernel` is cached (`api.is_cached`), at most WAIT_S, and only while `child` runs.

    Args:
        kernel: the compiled function waited for.
        child: the process compiling it; None: wait for the cache or WAIT_S alone.
    """
    deadline = time.monotonic() + WAIT_S
    while not is_cached(kernel) and time.monotonic() < deadline and (child is None or child.poll() is None):
        time.sleep(0.05)


def chain_free_child(model) -> None:
    """The "chain_free" child's share (module docstring).

    Args:
        model: the warm-up scene's Model.
    """
    compile_kernels(CHILD_KERNELS)
    wait_for(_new_workspace)
    compile_inverse_terms(model)
    wait_for(chain_forward)
    compile_evaluations(model)
    wait_for(project_state)
    compile_consistent(model)


def control_child(model) -> None:
    """The "control" child's share (module docstring).

    Args:
        model: the warm-up scene's Model.
    """
    wait_for(chain_forward)
    compile_extras(model)
    compile_control(model)


CHILDREN = {"chain_free": chain_free_child, "control": control_child}


def warm_up(control: bool = False) -> None:
    """Compile what every command uses, on two processes (a no-op for what is cached already).

    Args:
        control: also compile the extras and the controllers, on a third process.
    """
    if not compile_pending():
        if control:
            warm_up_group("extras")
            warm_up_group("control")
        return
    names = [name for name in CHILDREN if control or name != "control"]
    children = [subprocess.Popen([sys.executable, "-m", "coopsim.apps.warmup", name, str(os.getpid())],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for name in names]
    model = _model()
    try:
        compiled(model)           # the records' constructors
        compile_kernels(KINEMATICS)
        for kernel in _named(CHILD_KERNELS):
            wait_for(kernel, children[0])
        compile_kernels(("chain_forward",))
        compile_loop(model)
    except BaseException:         # e.g. the command interrupted: its compile processes stop with it
        for child in children:
            child.kill()
        raise
    finally:
        for child in children:
            child.wait()
    compile_inverse_terms(model)    # loads what the children cached (or compiles it, if a child failed)
    compile_evaluations(model)
    compile_consistent(model)
    if control:
        control_child(model)


GROUPS = {"extras": compile_extras, "control": compile_control}


def warm_up_group(group: str) -> None:
    """Compile one compile group (`api._group_entries`), what every command uses first if needed.

    Args:
        group: "base" (by :func:`warm_up`), or "extras" or "control" (in this process, a no-op when
            cached).
    """
    if group == "base":
        warm_up()
    elif compile_pending(group):
        warm_up()
        GROUPS[group](_model())


if __name__ == "__main__":
    if sys.argv[1:2] and sys.argv[1] in CHILDREN:     # a child of `warm_up`: NAME PARENT_PID
        end_with_parent(int(sys.argv[2]))            # `warm_up` waits for it on the thread that started it
        CHILDREN[sys.argv[1]](_model())
    else:
        warm_up(control=True)
