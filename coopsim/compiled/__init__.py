"""Compiled native model (numba): the same algorithms as the plain-NumPy stages, over flat arrays.

The plain-NumPy stages (`coopsim.dynamics`: kinematics, gibbs_appell, grasp, closed_chain, manifold,
integrate) are the readable reference; this package runs the same equations compiled, with no
Python and no allocation per evaluation, and is what the commands use. Stages, in the order they run:

    toolchain/      how numba compiles the package, fenced off from the stages:
      jit.py         the two compilation modes: internal kernels and entries called from Python
      linking.py     kernels compiled to LLVM IR only, made machine code inside the entries that call them
      resolution.py  numba's call-type resolution, remembered (each operation's signature found once)
      loading.py     compiled code loaded from numba's cache without numba's compiler registries
      numba_range.py the numba versions those three follow (they act on coopsim's functions only)
      scope.py       the per-thread scope that keeps them to coopsim's compiles
    packing.py      Model → PackedModel (frozen arrays) and a Workspace of preallocated buffers
    structs.py      both as numba StructRefs (passed by reference, fields read without reference
                    counting), built by cached constructors
    linalg.py       small in-place factorizations (pivoted Cholesky with a certified rank test, eigen
                    fallback)
    spatial.py      3-vector / 3×3 helpers, rotation log, quaternion
    kinematics.py   stage 1: joint frames, link and end-effector poses, the Jacobian
    gibbs_appell.py stage 2: each arm's bias forces and mass matrix
    grasp.py        stage 3: the object's pose and its terms joined to the carrier arm
    closed_chain.py stage 4: the constraint Jacobian and bias, the closed-chain solve
    schur.py        the constraint solve in O(r) (block diagonal plus the carrier's coupling), for
                    three arms or more
    manifold.py     loop-closure residual Φ, projection of positions and rates
    object_state.py a prescribed object motion's pose, twist and acceleration at a time (waypoints under a
                    time law, or a B-spline path): the object-motion IK's and the computed-torque reference's
    control/        controllers in the loop: the record, references, the distributions of the inverse
                    dynamics and squeeze, the laws (joint PD, object-space computed torque, grasp
                    feedback, saturation)
    integrate.py    the DOP853 / DOPRI5 (dense output) / RK4 time loop (tableaux: coopsim.core.tableaux),
                    torque tables, stabilization
    sample.py       many states at once (θ̈, every reported quantity), inverse-dynamics terms
    ik.py           one arm's inverse kinematics and rates
    object_motion.py closed-chain inverse kinematics of a prescribed object motion, every sample in one pass
                    (square arms by Newton, redundant ones by their least-velocity ODE, DOP853)
    capacity.py     the minimum-energy load capacity of one weight vector (the weight optimiser's objective)
    distributions.py the linear redundancy resolutions over all samples in one pass: grasp wrenches,
                    torques, internal wrenches and the load-capacity ratio test
    lp.py           LP vertices at given bases, certified optimal or unbounded (the LP bound's batches)
    reachability.py TOPP-RA's reachability pass of the retiming (backward controllable sets, greedy forward pass)
    dense_lp.py     small dense LPs (a dual simplex) and the LP bound's reachability pass on them
    stress.py       section loads of a box object at every sample and cut
    api.py          the Python entry points (batches on threads, parameter sets) and error reporting

The first compile, on two cores with no kernel compiled twice, is `coopsim.apps.warmup`'s.
Tested against the reference stages at random states of every bundled scenario (stage terms ≤ 1e-12
relative; accelerations within that plus eps·cond of the constraint system).
"""

import hashlib as _hashlib
from pathlib import Path as _Path

from numba.core import config as _numba_config


def _cache_dir() -> str:
    """numba's cache for this package, keyed by the package's sources: numba re-validates a cached
    entry against its own file only, though it holds the kernels of the other files compiled into it,
    so an edited kernel would otherwise run stale from another entry's cache. Under NUMBA_CACHE_DIR
    if that is set, else in this folder's __pycache__."""
    here = _Path(__file__).resolve().parent
    digest = _hashlib.sha256()
    for path in sorted(here.rglob("*.py")):
        digest.update(path.relative_to(here).as_posix().encode() + b"\0" + path.read_bytes())
    base = _numba_config.CACHE_DIR or str(here / "__pycache__")
    return str(_Path(base) / f"coopsim-{digest.hexdigest()[:16]}")


def _import_kernels() -> None:
    """Import every compiled module with numba's cache directory set to `_cache_dir()` (restored after:
    the choice is made once per function, when it is decorated)."""
    previous = _numba_config.CACHE_DIR
    _numba_config.CACHE_DIR = _cache_dir()
    try:
        from coopsim.compiled import (api, closed_chain, control, gibbs_appell, grasp, ik, integrate,  # noqa: F401
                                      kinematics, linalg, manifold, sample, spatial, structs)
    finally:
        _numba_config.CACHE_DIR = previous


_import_kernels()
