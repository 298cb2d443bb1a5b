"""Python entry points of the compiled model: packing (cached per model), one evaluation, batches of
states (threads, the kernels release the GIL), the time loop with progress, sampling, inverse terms.

Failures come back as codes from compiled code and are turned here into one-line reasons; the
callers (`coopsim.forward.simulate`) add the time and configuration.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import threading
import time
import weakref
from concurrent.futures import ThreadPoolExecutor, wait
from typing import NamedTuple

import numpy as np

from coopsim.compiled import (capacity, closed_chain, control, dense_lp, distributions, ik, integrate, lp,
                              manifold, object_motion, reachability, sample, stress)
from coopsim.compiled.packing import PROJECTION_MAX_ITER, PackedModel, Workspace, pack, tabulated_torques, workspace
from coopsim.compiled.structs import Struct, to_struct
from coopsim.core.errors import ConstraintError
from coopsim.core.model import Model, ObjectMotion
from coopsim.core.results import Projection

_CACHE: "weakref.WeakKeyDictionary[Model, tuple]" = weakref.WeakKeyDictionary()   # model → `_entry`
_NO_FLAGS = np.zeros(0, dtype=np.int64)   # `sample.evaluate`'s raw: no state to project

REASONS = {
    closed_chain.NOT_PD: "closed-chain mass matrix is not positive definite",
    closed_chain.RANK_DEFICIENT: "constraint matrix Λ𝐈⁻¹Λᵀ is rank-deficient",
    closed_chain.NON_FINITE: "non-finite joint accelerations",
    control.CONTROL_SINGULAR: "controller: singular equations (an arm's S J or the wrench distribution)",
    manifold.NON_FINITE_STATE: "non-finite state",
    integrate.STEP_COLLAPSED: "step size collapsed",
    integrate.MAX_STEPS: "maximum number of steps exceeded",
    manifold.PROJECTION_FAILED: f"projection: loop closure did not converge in {PROJECTION_MAX_ITER} "
                                "Gauss–Newton steps",
}


class Compiled(NamedTuple):
    """A model ready for the kernels: the packed arrays and the workspace, for Python and for compiled code.

    Attributes:
        P: the PackedModel (frozen model arrays), for Python to read.
        W: the Workspace (the kernels' buffers, overwritten by each evaluation), for Python to read.
        Ps: P's StructRef (the same arrays), for compiled code.
        Ws: W's StructRef (the same arrays), for compiled code.
    """

    P: PackedModel
    W: Workspace
    Ps: Struct
    Ws: Struct


def _group_entries(group: str) -> tuple:
    """The entries of a compile group: "base", what every native command uses (the first run compiles it,
    `coopsim.apps.warmup.warm_up`); "extras", inverse kinematics (one arm, and object-motion trajectories), the
    object's states along a motion, the capacity objective, the linear resolutions' pass, the LP vertices, the
    section loads, the retiming's reachability pass and the LP bound's (with its small-LP solver) (`inverse`,
    `capacity`, `optimize`, a trajectory given as object motion: their first use compiles them, a few
    seconds); "control", the controllers (the first closed-loop run)."""
    return {"base": (integrate.run, sample.evaluate, sample.inverse_terms, manifold.consistent),
            "extras": (ik.arm_solve, object_motion.trajectory, object_motion.object_states,
                       capacity.min_energy_mass_interval, distributions.linear_pass, lp.lp_vertices,
                       stress.section_loads, reachability.reachability_pass, dense_lp.dense_lp,
                       dense_lp.lp_reachability_pass),
            "control": (control.commands, control.evaluate)}[group]


def is_cached(fn) -> bool:
    """Whether the compiled function `fn` has code in numba's cache on this machine.

    Looks for its index file; the cache folder is keyed by the compiled sources' digest
    (`coopsim.compiled._cache_dir`), so an index there is never stale.

    Args:
        fn: a compiled entry (a numba dispatcher with an on-disk cache).

    Returns:
        bool: True when its index exists, or when the index cannot be located.
    """
    try:
        return os.path.exists(fn._cache._cache_file._index_path)
    except AttributeError:
        return True


def compile_pending(group: str = "base") -> bool:
    """Whether some entry of the compile group has no compiled code cached on this machine yet.

    The first run after installing or editing the package compiles it (`is_cached`).

    Args:
        group: "base", "extras" or "control" (`_group_entries`).

    Returns:
        bool: True when some entry of the group is not cached.
    """
    return not all(is_cached(e) for e in _group_entries(group))


_notice: dict = {}


def set_compile_notice(**notices) -> None:
    """Register, per compile group, a function called once before the group's missing code is first needed.

    Each is called before this process first needs the group's code while it is missing from the cache
    (`announce_compile`; "base": when it first packs a model): the command line uses them to say that a
    first run compiles, and to compile the group on all cores. `set_compile_notice()` clears them.

    Args:
        **notices: group name ("base", "extras", "control", `_group_entries`) → a callable taking no
            arguments.
    """
    _notice.clear()
    _notice.update(notices)


def announce_compile(group: str) -> None:
    """Call the notice of `set_compile_notice` for the group, if set and the group's code is not cached.

    The notice is dropped either way (after this the group's code is on disk), so repeated calls cost a
    dictionary lookup.

    Args:
        group: "base", "extras" or "control".
    """
    notice = _notice.pop(group, None)
    if notice is not None and compile_pending(group):
        notice()


def compiled(model: Model) -> Compiled:
    """The compiled form of `model`, built once per model object.

    Shared by models that differ only in what packing does not read (duration, output grid, tolerances,
    initial state, MuJoCo and inverse settings: e.g. `dataclasses.replace(model, duration=…)`).

    Args:
        model: the frozen Model.

    Returns:
        Compiled: its PackedModel and Workspace, with their StructRefs (the workspace is shared by every
        caller of this model: copy what you keep).
    """
    return _entry(model)[0]


def _entry(model: Model) -> tuple:
    """The cache entry of `model`: (Compiled, what keeps the content key's objects alive, the spare
    record pairs of `_leased_structs`)."""
    hit = _CACHE.get(model)
    if hit is None:
        key = _content_key(model)
        entry = _BY_CONTENT.pop(key, None)
        announce_compile("base")
        if entry is None:
            P = pack(model)
            W = workspace(P)
            entry = (Compiled(P, W, to_struct(P), to_struct(W)), (model.arms, model.object, model.torques), [])
        _BY_CONTENT[key] = entry               # most recently used last
        while len(_BY_CONTENT) > _BY_CONTENT_SIZE:
            _BY_CONTENT.pop(next(iter(_BY_CONTENT)))
        hit = _CACHE[model] = entry
    return hit


@contextlib.contextmanager
def _leased_structs(model: Model):
    """(Ps, Ws): StructRefs of `model`'s packed model and of a workspace, the share's own while the block
    runs: a spare pair kept from an earlier batch (every kernel writes what it reads, and the zeros a
    workspace starts with outside the arms' blocks stay zeros), else a new one; returned afterwards.

    Ps is a StructRef of its own over the same arrays: each kernel call takes a reference to its
    records, and threads sharing one record would contend for its reference count (two threads on
    one Ps ran a batch 1.7× slower than one thread alone; on one each, at the speed of one).
    """
    spares = _entry(model)[2]
    with _SPARES_LOCK:
        pair = spares.pop() if spares else None
    if pair is None:
        P = compiled(model).P
        pair = (to_struct(P), fresh_workspace(P))
    try:
        yield pair
    finally:
        with _SPARES_LOCK:
            spares.append(pair)


_SPARES_LOCK = threading.Lock()
_BY_CONTENT: dict = {}
_BY_CONTENT_SIZE = 32


def _content_key(model: Model) -> tuple:
    """What `pack` reads: the arm, object and torque objects (by identity: frozen, and kept alive by the
    cache entry), gravity, constraint rows and the integrator settings the kernels use."""
    s = model.integrator
    return (id(model.arms), id(model.object), id(model.torques), model.gravity.tobytes(), model.rows.tobytes(),
            s.rank_tol, s.on_rank_deficiency, s.stabilization, s.baumgarte_alpha, s.baumgarte_beta,
            s.projection_tol)


def fresh_workspace(P: PackedModel) -> Struct:
    """A new workspace StructRef for P (one per thread).

    Args:
        P: the PackedModel.

    Returns:
        Struct: the StructRef of a new Workspace of P's sizes (zeros).
    """
    return to_struct(workspace(P))


@functools.cache
def _tableau(method: str) -> Struct:
    return to_struct(integrate.tableau(method))


def n_rows(P: PackedModel) -> int:
    """The number of loop-closure constraint rows, K = k(r − 1).

    Args:
        P: the PackedModel (k = its rows, r arms).

    Returns:
        int: K.
    """
    return P.rows.shape[0] * (len(P.dof) - 2)


class Evaluation(NamedTuple):
    """One closed-chain evaluation.

    Attributes:
        qdd: (N,) rad/s² (m/s² on a prismatic joint), the joint accelerations θ̈.
        F: (K,) N, N·m, the loop-closure wrenches in the rows S.
        status: 0, or a failure code of REASONS.
        rank: the numerical rank of Λ𝐈⁻¹Λᵀ.
    """

    qdd: np.ndarray
    F: np.ndarray
    status: int
    rank: int


def forward(model: Model, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> Evaluation:
    """θ̈ of the closed chain at (q, qd) with torques tau (Baumgarte term included if selected).

    Afterwards `compiled(model).W` holds every term of that state.

    Args:
        model: the Model.
        q: (N,) rad or m, the stacked joint coordinates θ.
        qd: (N,) rad/s or m/s, the joint rates θ̇.
        tau: (N,) N·m (N on a prismatic joint), the joint torques.

    Returns:
        Evaluation: θ̈, the loop-closure wrenches F (copies), the status and the rank of Λ𝐈⁻¹Λᵀ.
    """
    P, W, Ps, Ws = compiled(model)
    out = sample.new_samples(1, len(q), len(P.dof) - 1)
    out.tau[0] = tau
    sample.evaluate(Ps, Ws, np.concatenate([_f(q), _f(qd)])[None], out, False, _NO_FLAGS)
    return Evaluation(W.qdd.copy(), W.F.copy(), int(out.status[0]), int(W.rank[0]))


def chain_terms(model: Model, q: np.ndarray, qd: np.ndarray) -> Workspace:
    """The workspace after one evaluation at (q, qd) with zero torque: W.Mb, W.h, W.J, W.Lam, … (`Workspace`).

    The arrays are reused by the next call: copy what you keep.

    Args:
        model: the Model.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.

    Returns:
        Workspace: `compiled(model).W` (world axes, SI; not a copy).
    """
    forward(model, q, qd, np.zeros(len(q)))
    return compiled(model).W


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64)


def _pull(motion) -> float:
    """The Motion's pull per unit path parameter: rest_gain × the duration for rest_pull 'path', else 0."""
    return 0.0 if motion.rest_pull == "time" else motion.path_gain


def _w(x, dtype=np.float64) -> np.ndarray:
    """x as a writable C-contiguous array of dtype (a copy only where x is not one already): a read-only
    argument would make numba compile an entry again, for the read-only signature."""
    x = np.ascontiguousarray(x, dtype=dtype)
    return x if x.flags.writeable else x.copy()


MIN_PER_THREAD = 200   # states per thread below which a batch runs on the calling thread (the pool's cost outweighs it)


def threads(S: int | None = None) -> int:
    """Threads for a batch of S states: one per core (at most 8), at least MIN_PER_THREAD states each.

    Args:
        S: the batch's number of states; None: the thread count for a pool of any size.

    Returns:
        int: the number of threads, at least 1.
    """
    n = max(1, min(os.cpu_count() or 1, 8))
    return n if S is None else max(1, min(n, S // MIN_PER_THREAD))


def evaluate_states(model: Model, Y: np.ndarray, TAU: np.ndarray, full: bool = False,
                    n_threads: int | None = None, raw: np.ndarray | None = None) -> sample.Samples:
    """The closed chain at S states with torques TAU, split over threads (one workspace each).

    Args:
        model: the Model.
        Y: (S, 2N) the states [θ; θ̇] (rad or m, rad/s or m/s).
        TAU: (S, N) N·m (N on a prismatic joint), the joint torques.
        full: with it every reported quantity, without it θ̈ and status only.
        n_threads: threads to use (default `threads(S)`).
        raw: (S,) bool, the states to project onto the loop-closure manifold first, as the time loop
            projects an output (`sample.evaluate`): Y must then be C-contiguous float64, and those rows
            are overwritten with their projections. None: none is projected.

    Returns:
        sample.Samples: (S, …) arrays, world axes, SI: θ̈, status (0, or a code of REASONS), and with
        `full` every other field.

    Raises:
        ValueError: raw given with a Y that is not C-contiguous float64 (it could not be projected in
            place).
    """
    P = compiled(model).P
    if raw is None:
        Y, flags = _f(Y), _NO_FLAGS
    elif not (Y.dtype == np.float64 and Y.flags.c_contiguous):
        raise ValueError("evaluate_states: projecting in place needs a C-contiguous float64 Y")
    else:
        flags = np.ascontiguousarray(raw, dtype=np.int64)
    out = sample.new_samples(len(Y), int(P.dof[-1]), len(P.dof) - 1)
    out.tau[:] = TAU

    def run(idx):
        if len(idx):
            s = slice(idx[0], idx[-1] + 1)
            with _leased_structs(model) as (Pt, Wt):
                sample.evaluate(Pt, Wt, Y[s], sample.Samples(*(a[s] for a in out)), full,
                                flags[s] if len(flags) else flags)

    _map(run, np.array_split(np.arange(len(Y)), n_threads or threads(len(Y))))
    return out


def forward_models(models: list[Model], Y: np.ndarray, TAU: np.ndarray,
                   n_threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """θ̈ and status of M models at the same S states, one model per task over threads.

    The models are parameter sets of one scene (same arms and grasps, other masses or geometry), each
    packed afresh.

    Args:
        models: the M Models (the same N joints and r arms).
        Y: (S, 2N) the states [θ; θ̇] (rad or m, rad/s or m/s).
        TAU: (S, N) N·m (N on a prismatic joint), the joint torques.
        n_threads: threads to use (default `threads()`).

    Returns:
        tuple[np.ndarray, np.ndarray]: θ̈ (M, S, N) rad/s² (m/s²) and status (M, S) int (0 or a code of
        REASONS).
    """
    Y, TAU = _f(Y), _f(TAU)
    N = TAU.shape[1]
    QDD = np.empty((len(models), len(Y), N))
    status = np.zeros((len(models), len(Y)), dtype=np.int64)

    def run(i):
        P = pack(models[i])
        out = sample.new_samples(len(Y), N, len(P.dof) - 1)
        out.tau[:] = TAU
        sample.evaluate(to_struct(P), fresh_workspace(P), Y, out, False, _NO_FLAGS)
        QDD[i], status[i] = out.qdd, out.status

    _map(run, range(len(models)), n_threads)
    return QDD, status


def _map(fn, items, n_threads=None):
    """fn over items on n threads (default `threads()`): the items dealt into n shares, the calling thread
    running one and the process's worker pool the others (started once: a pool per call costs about
    as much as a few hundred sampled states)."""
    items = list(items)
    n = min(len(items), n_threads or threads())
    if n <= 1:
        for it in items:
            fn(it)
        return

    def work(share):
        for it in share:
            fn(it)

    shares = [items[k::n] for k in range(n)]
    others = [_pool().submit(work, share) for share in shares[1:]]
    try:
        work(shares[0])
    finally:
        wait(others)
    for f in others:
        f.result()


_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """The process's worker threads for `_map`, started on first use (as many as are busy at once)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(64, thread_name_prefix="coopsim-batch")
        return _POOL


def _forget_pool() -> None:
    """In a forked child: the parent's worker threads are not there, so the pool starts afresh (and the
    locks, which a parent's thread may have held at the fork, are new)."""
    global _POOL, _POOL_LOCK, _SPARES_LOCK
    _POOL, _POOL_LOCK, _SPARES_LOCK = None, threading.Lock(), threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)


class Run(NamedTuple):
    """A compiled integration.

    Attributes:
        Y: (len(t_out), 2N) the states [θ; θ̇] at t_out (rows after a failure left zero).
        counts: (rhs evaluations, accepted steps, rejected steps, projections).
        status: 0, or a failure code of REASONS.
        fail_t: s, where it stopped on a failure.
        fail_y: (2N,) the state where it stopped on a failure.
        rank_warning: None, or (t s, y (2N,), rank, cond) at the first loss of rank of Λ𝐈⁻¹Λᵀ (cond its
            condition number).
        raw: (len(t_out),) bool, the rows of Y left unprojected from dense output (`integrate_chain`'s
            defer); None without defer.
    """

    Y: np.ndarray
    counts: tuple[int, int, int, int]
    status: int
    fail_t: float
    fail_y: np.ndarray
    rank_warning: tuple | None
    raw: np.ndarray | None = None


def integrate_chain(model: Model, y0: np.ndarray, t_out: np.ndarray, method: str, rtol: float = 1e-10,
                    atol: float = 1e-12, h_max: float = math.inf, h_min: float = 1e-12,
                    max_steps: int = 10_000_000, fixed_step: float | None = None, progress=None,
                    chunk_seconds: float = 0.25, controller=None, land: bool = False, defer: bool = False) -> Run:
    """Integrate the closed chain of `model` from y0 at t_out[0], sampled at t_out.

    Adaptive (dop853, dopri5) unless fixed_step is given (rk4 needs it). `progress(fraction)` is called
    between chunks of about chunk_seconds of work; the chunking does not change the result.

    Args:
        model: the Model.
        y0: (2N,) the initial state [θ; θ̇] (rad or m, rad/s or m/s), already consistent.
        t_out: (n,) s, the output times, strictly increasing.
        method: "dop853", "dopri5" or "rk4".
        rtol, atol: the adaptive steps' relative and absolute error tolerances.
        h_max, h_min: s, the largest adaptive step, and the smallest before the run fails (step size
            collapsed).
        max_steps: cap on the steps (accepted ones, and with adaptive steps the rejected ones too).
        fixed_step: s, the largest fixed step (None: adaptive).
        progress: None, or a callable taking the fraction of the time span done (0 to 1).
        chunk_seconds: s of work between progress calls.
        controller: None, or the (Pc, Wc, C) StructRefs of a compiled controller in the loop
            (`coopsim.control.controller.Controller.compiled_loop`), whose command is added to the model's
            tables.
        land: adaptive steps end on every output time (`integrate.run`).
        defer: with projection stabilization, leave the outputs reached by dense output unprojected
            (Run.raw flags them) for `sample_states` to project: the steps and every other output are
            unchanged.

    Returns:
        Run: the states at t_out, the step counts, the status and where it failed, the first rank
        warning, and with defer the flags of the rows left unprojected.
    """
    P, W, Ps, Ws = compiled(model)
    ctl = controller
    tab = _tableau(method)
    t_out = _f(t_out)
    Y = np.zeros((len(t_out), len(y0)))
    L = integrate.new_loop(_f(y0), float(t_out[0]), n_rows(P), len(t_out), defer)
    Ls = to_struct(L)
    n_out = len(t_out)
    k_stop = n_out if progress is None else min(n_out, 2)
    st = 0
    while st == 0 and int(L.k_next[0]) < n_out:
        start = time.perf_counter()
        before = int(L.k_next[0])
        integrate.run(Ps, Ws, Ls, tab, ctl, t_out, Y, rtol, atol, h_max, h_min, max_steps, fixed_step or 0.0, k_stop,
                      land)
        st = int(L.status[0])
        if progress is not None:
            progress(float((t_out[min(int(L.k_next[0]), n_out) - 1] - t_out[0]) / max(t_out[-1] - t_out[0], 1e-300)))
            spent = max(time.perf_counter() - start, 1e-4)
            done = max(int(L.k_next[0]) - before, 1)
            k_stop = min(n_out, int(L.k_next[0]) + max(1, int(done * chunk_seconds / spent)))
    warn = None
    if L.warn[0]:
        warn = (float(L.warn_t[0]), L.warn_y.copy(), int(L.warn[1]), float(L.warn_cond[0]))
    return Run(Y, tuple(int(c) for c in L.count), int(L.status[0]), float(L.fail_t[0]), L.fail_y.copy(), warn,
               L.raw.astype(bool) if defer else None)


def sample_states(model: Model, t: np.ndarray, Y: np.ndarray, TAU: np.ndarray | None = None,
                  raw: np.ndarray | None = None) -> sample.Samples:
    """Every reported quantity at the states Y, times t, torques TAU.

    Args:
        model: the Model.
        t: (S,) s, the sample times.
        Y: (S, 2N) the states [θ; θ̇] (rad or m, rad/s or m/s).
        TAU: (S, N) N·m (N on a prismatic joint); default (None): the model's torque tables at t.
        raw: (S,) bool, the rows to project first, in place (`evaluate_states`); None: none.

    Returns:
        sample.Samples: (S, …) arrays, world axes, SI.

    Raises:
        ValueError: raw given with a Y that is not C-contiguous float64.
    """
    P = compiled(model).P
    return evaluate_states(model, Y, tabulated_torques(P, t) if TAU is None else TAU, full=True, raw=raw)


def inverse_terms(model: Model, Q: np.ndarray, QD: np.ndarray, QDD: np.ndarray,
                  n_threads: int | None = None) -> sample.InverseTerms:
    """Per-sample inverse-dynamics terms (`sample.InverseTerms`) at the states (Q, QD, QDD), over threads.

    Args:
        model: the Model.
        Q: (S, N) rad or m, θ.
        QD: (S, N) rad/s or m/s, θ̇.
        QDD: (S, N) rad/s² or m/s², θ̈.
        n_threads: threads to use (default `threads(S)`).

    Returns:
        sample.InverseTerms: (S, …) arrays, world axes, SI.
    """
    P = compiled(model).P
    Q, QD, QDD = _f(Q), _f(QD), _f(QDD)
    nmax = int(np.max(np.diff(P.dof)))
    out = sample.new_inverse_terms(len(Q), int(P.dof[-1]), len(P.dof) - 1, nmax)
    chunks = np.array_split(np.arange(len(Q)), n_threads or threads(len(Q)))

    def run(idx):
        if len(idx):
            s = slice(idx[0], idx[-1] + 1)
            with _leased_structs(model) as (Pt, Wt):
                sample.inverse_terms(Pt, Wt, Q[s], QD[s], QDD[s], sample.InverseTerms(*(a[s] for a in out)))

    _map(run, chunks)
    return out


class LinearPass(NamedTuple):
    """The linear resolutions over the samples (`distributions.linear_pass`); method axis PAPER,
    NONSQUEEZING, MIN_ENERGY of `coopsim.compiled.distributions`.

    Attributes:
        f: (3, s, N, m) [N; N·m], the grasp wrenches in the rows S of each net wrench, world axes.
        tau: (3, s, N, n) N·m (N on a prismatic joint), the torques.
        internal_paper: (3, N, r, 6) [N; N·m], the paper internal wrenches at C of the net wrench asked for.
        internal_nonsqueezing: (3, N, r, 6) [N; N·m], the non-squeezing ones.
        up: (3, P, N, n) kg, the largest carried mass each motor line allows, per ratio test.
        dn: (3, P, N, n) kg, the smallest.
        unsure: (3, N) bool, the samples left to the NumPy path (the arrays above are not written there).
    """

    f: np.ndarray
    tau: np.ndarray
    internal_paper: np.ndarray
    internal_nonsqueezing: np.ndarray
    up: np.ndarray
    dn: np.ndarray
    unsure: np.ndarray


def linear_pass(JT, A, tau_arms, W, R_o, rows, masses, inertias, passive, weights, ys, which, wrench_of: int, lo, hi,
                pairs, rank_tol: float) -> LinearPass:
    """The linear resolutions of s net wrenches at N samples in one compiled pass (`distributions.linear_pass`).

    Args:
        JT: (N, n, m) Jᵀ, the end-effector Jacobians in the rows S, transposed (m = rk).
        A: (N, k, m) A = [S W_1 Sᵀ … S W_r Sᵀ].
        tau_arms: (N, n) N·m (N on a prismatic joint), τ_arms.
        W: (N, r, 6, 6) the grasp matrices.
        R_o: (N, 3, 3) the object rotation, world ← object frame.
        rows: (k, 6) the constraint rows S.
        masses: (r,) kg, the non-squeezing virtual masses.
        inertias: (r, 3, 3) kg·m², the virtual inertias, object frame.
        passive: (n,) bool, the passive joints.
        weights: (n,) the energy weights (passive joints' entries ignored).
        ys: (s, N, k) [N; N·m], the net object wrenches, rows S, world axes.
        which: (3,) bool, the methods computed.
        wrench_of: the index into ys whose internal wrenches are computed (−1: none).
        lo, hi: (N, n) N·m, the motor lines (ignored without pairs).
        pairs: (P, 2) int, the (y₀, y₀ + y₁) indices into ys of each ratio test (P may be 0).
        rank_tol: the forward model's rank tolerance.

    Returns:
        LinearPass: the grasp wrenches, torques, internal wrenches and ratio tests, with the samples left
        to the NumPy path.
    """
    announce_compile("extras")
    N, n, m = JT.shape
    r, s, P = W.shape[1], len(ys), len(pairs)
    passive = np.asarray(passive, dtype=bool)
    out = LinearPass(np.zeros((3, s, N, m)), np.zeros((3, s, N, n)), np.zeros((3, N, r, 6)), np.zeros((3, N, r, 6)),
                     np.zeros((3, P, N, n)), np.zeros((3, P, N, n)), np.zeros((3, N), dtype=bool))
    distributions.linear_pass(_w(JT), _w(A), _w(tau_arms), _w(W), _w(R_o), _w(rows), _w(masses), _w(inertias),
                              np.flatnonzero(passive).astype(np.int64),
                              np.where(passive, 0.0, _w(weights)), _w(ys), _w(which, bool), int(wrench_of), _w(lo),
                              _w(hi), _w(np.reshape(pairs, (P, 2)), np.int64), float(rank_tol), *out)
    return out


def lp_vertices(G, g_lo, g_hi, norm, bound, c, lo, hi, cap_lo, cap_hi, r: int, idx, held, tols) -> tuple:
    """Vertices of k of a batch's LPs at given bases, certified optimal or unbounded, compiled (`lp.lp_vertices`).

    Args:
        G: (N, r + v, v) the batch's rows: r constraint rows, then the identity of the v columns.
        g_lo, g_hi: (N, r + v) their bounds, the columns' capped (±inf: none).
        norm: (N, r + v) max |G_ij| per row.
        bound: (N,) the largest finite row bound per problem.
        c: (v,) the cost.
        lo, hi: (v,) the columns' uncapped bounds.
        cap_lo, cap_hi: (v,) the columns' capped bounds.
        r: the number of constraint rows.
        idx: (k,) int, the problems.
        held: (k, r + v) int8 HiGHS's basis codes of the rows, then the columns.
        tols: (primal, dual, stationarity) relative tolerances of the certificates.

    Returns:
        tuple: x (k, v), the rows' duals (k, r + v), ok (k,) bool (certified optimal) and unbounded (k,)
        bool (certified at a cap with a descent ray).
    """
    announce_compile("extras")
    k, (R, v) = len(idx), np.shape(G)[1:]
    x, dual = np.empty((k, v)), np.empty((k, R))
    ok, unbounded = np.empty(k, bool), np.empty(k, bool)
    lp.lp_vertices(_w(G), _w(g_lo), _w(g_hi), _w(norm), _w(bound), _w(c), _w(lo), _w(hi), _w(cap_lo), _w(cap_hi),
                   int(r), _w(idx, np.int64), _w(held, np.int8), *(float(t) for t in tols), x, dual, ok, unbounded)
    return x, dual, ok, unbounded


def reachability_pass(G, H, E, off, d, tol, start, end_at, start_at, N: int) -> np.ndarray | None:
    """TOPP-RA's backward and forward passes over ragged stage polygons, compiled
    (`reachability.reachability_pass`).

    Args:
        G, H, E: (R,) the stages' rows G a + H b ≤ E, flat, stage after stage.
        off: (K + 1,) int, the stages' row offsets.
        d: (K,) the intervals' lengths.
        tol: (K,) each stage's feasibility tolerance.
        start: (K,) int, the grid point each stage starts at.
        end_at: (K,) bool, the stage's end point ends a piece.
        start_at: (K,) bool, its start point starts a piece.
        N: the grid points.

    Returns:
        np.ndarray | None: b (N,) 1/s², or None (a stage without a controllable state).
    """
    announce_compile("extras")
    b, lo, hi = np.empty(N), np.empty(N), np.empty(N)
    status = reachability.reachability_pass(_w(G), _w(H), _w(E), _w(off, np.int64), _w(d), _w(tol),
                                            _w(start, np.int64), _w(end_at, np.bool_), _w(start_at, np.bool_),
                                            b, lo, hi)
    return None if status else b


LP_STATUS = {dense_lp.OPTIMAL: "optimal", dense_lp.INFEASIBLE: "infeasible",
             dense_lp.NOT_SOLVED: "not solved (step limit or singular basis)"}


def dense_lp_solve(M, h, c, cap) -> tuple[int, np.ndarray]:
    """max cᵀx subject to M x ≤ h and |x_j| ≤ cap_j, by the compiled dual simplex (`dense_lp.dense_lp`).

    Args:
        M: (m, n) the rows.
        h: (m,) their bounds (+inf: no row).
        c: (n,) the objective.
        cap: (n,) the box (finite, > 0).

    Returns:
        tuple: status (0 optimal, 1 infeasible, 2 not solved: `LP_STATUS`) and x (n,).
    """
    announce_compile("extras")
    x = np.zeros(np.shape(M)[1])
    status = dense_lp.dense_lp(_w(M), _w(h), _w(c), _w(cap), x)
    return int(status), x


def lp_reachability_pass(g, h, e, slot, W, off, nslot, d, tol, caps, cap_max, start, end_at, start_at,
                         N: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """The LP bound's reachability passes over stage polyhedra in (a, b, z), compiled
    (`dense_lp.lp_reachability_pass`).

    Args:
        g, h, e: (R,) the stages' rows g a + h b + W z ≤ e, flat, stage after stage.
        slot: (R,) int, the stage's point whose z each row's W multiplies (−1: none).
        W: (R, nz) those coefficients.
        off: (K + 1,) int, the stages' row offsets.
        nslot: (K,) int, the points carrying z per stage (its two grid points first).
        d: (K,) the intervals' lengths.
        tol: (K,) each stage's feasibility tolerance.
        caps: (K, 3) the first box around a, b and each z per stage (grown where it binds).
        cap_max: (3,) the largest box.
        start: (K,) int, the grid point each stage starts at.
        end_at: (K,) bool, the stage's end point ends a piece.
        start_at: (K,) bool, its start point starts a piece.
        N: the grid points.

    Returns:
        tuple: status (0, 1 no controllable state, 2 a stage LP not solved: `LP_STATUS`), b (N,) 1/s²,
        a (K,) 1/s², z (K, 2, nz) the null-space coordinates at the stages' two grid points, and the counts
        (4,) [stage LPs solved, simplex steps, cold starts, box growths].
    """
    announce_compile("extras")
    K, nz = len(d), np.shape(W)[1]
    b, lo, hi, a, z = np.empty(N), np.empty(N), np.empty(N), np.empty(K), np.empty((K, 2, nz))
    count = np.zeros(4, np.int64)
    status = dense_lp.lp_reachability_pass(_w(g), _w(h), _w(e), _w(slot, np.int64), _w(W), _w(off, np.int64),
                                           _w(nslot, np.int64), _w(d), _w(tol), _w(caps), _w(cap_max),
                                           _w(start, np.int64), _w(end_at, np.bool_), _w(start_at, np.bool_),
                                           b, lo, hi, a, z, count)
    return int(status), b, a, z, count


def section_loads(mass: float, R_o, twist, acc, gravity, F_e, rows, grasp_pos, axis: int, frac, K_diag, c_o, ps_o,
                  on, sides) -> tuple:
    """Section loads of a box object at c cuts of N samples, compiled (`stress.section_loads`).

    Args:
        mass: kg, the object's mass.
        R_o: (N, 3, 3) the object's orientation, world ← object frame.
        twist: (N, 6) [v_C; ω] m/s, rad/s, world axes.
        acc: (N, 6) [a_C; ω̇] m/s², rad/s², world axes.
        gravity: (3,) m/s², world axes.
        F_e: (N, r, 6) [f; n] N, N·m, the grasp wrenches at the grasp points, world axes.
        rows: (k, 6) the row selector S.
        grasp_pos: (r, 3) m, the grasp points, object frame.
        axis: the box axis the cuts are across.
        frac: (c,) the parts' mass fractions.
        K_diag: (c, 3) kg·m², the parts' inertias about their centres, box axes.
        c_o: (c, 3) m, the parts' centres, object frame.
        ps_o: (c, 3) m, the section centres, object frame.
        on: (r, c) 1.0 where a grasp is on the part, else 0.0.
        sides: (d₁, d₂, b, t) m, the section's sides along the other two box axes, the larger and the smaller.

    Returns:
        tuple: axial, shear (N, c) N; torsion, bending (N, c) N·m; peak normal and shear stresses (N,) Pa.
    """
    announce_compile("extras")
    N, C = len(R_o), len(frac)
    out = tuple(np.empty((N, C)) for _ in range(4)) + (np.empty(N), np.empty(N))
    stress.section_loads(float(mass), _w(R_o), _w(twist), _w(acc), _w(gravity), _w(F_e), _w(rows), _w(grasp_pos),
                         int(axis), _w(frac), _w(K_diag), _w(c_o), _w(ps_o), _w(on), _w(sides), *out)
    return out


def consistent_state(model: Model, q: np.ndarray, qd: np.ndarray, tol: float | None = None,
                     max_iter: int = PROJECTION_MAX_ITER) -> Projection:
    """(q, qd) projected onto the loop-closure manifold, compiled.

    As `coopsim.dynamics.manifold.consistent_state` does: Gauss–Newton to max |Φ| ≤ tol, then the rates.

    Args:
        model: the Model.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        tol: m or rad, the tolerance on max |Φ| (default None: the scenario's projection_tol).
        max_iter: cap on the Gauss–Newton steps.

    Returns:
        Projection: the consistent (q, qd), the corrections, max |Φ| before and after, the steps taken.

    Raises:
        ConstraintError: when the positions do not converge in max_iter steps.
    """
    P, W, Ps, Ws = compiled(model)
    q, qd = _f(q), _f(qd)
    y = np.concatenate([q, qd])
    info = np.zeros(3)
    tol = model.integrator.projection_tol if tol is None else tol
    if manifold.consistent(Ps, Ws, y, tol, max_iter, info) != 0:
        raise ConstraintError(f"loop closure did not converge: max |Φ| = {info[1]:.3g} after {max_iter} "
                              f"Gauss–Newton steps at q = {np.array2string(y[:len(q)], precision=6)}")
    n = len(q)
    return Projection(y[:n], y[n:], y[:n] - q, y[n:] - qd, float(info[0]), float(info[1]), int(info[2]))


class ArmSolution(NamedTuple):
    """Inverse kinematics of one arm (`ik.arm_solve`).

    Attributes:
        status: ik.SOLVED, SINGULAR or NOT_CONVERGED.
        q: (N,) rad or m, stacked: the guess with the arm's rows replaced by the last iterate.
        qd, qdd: (N,) stacked θ̇, θ̈, the arm's rows filled when SOLVED (zeros elsewhere).
        ratio: σ_min/σ_max of S J (SINGULAR) or the max |S e| left (NOT_CONVERGED); 0 when SOLVED.
        det: det S J at the solution (SOLVED; 0 otherwise).
        full_error: max |pose error| over all six rows (m or rad) at the solution (SOLVED; 0 otherwise).
    """

    status: int
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    ratio: float
    det: float
    full_error: float


def solve_arm(model: Model, m: int, p, R, twist, acc, guess: np.ndarray, tol: float = 1e-13,
              max_iter: int = 50, sing_tol: float = 1e-7) -> ArmSolution:
    """Arm m's joint angles putting its end-effector frame at (p, R) in the model's rows S, and its rates.

    Newton from the stacked `guess`; then θ̇ and θ̈ for the end-effector twist and acceleration.

    Args:
        model: the Model.
        m: arm index, 0-based.
        p: (3,) m, target position relative to the arm's base position, world axes.
        R: (3, 3) target orientation of the end-effector frame, world axes.
        twist: (6,) the end-effector twist [v; ω], m/s and rad/s, world axes.
        acc: (6,) the end-effector acceleration [a; ω̇], m/s² and rad/s², world axes.
        guess: (N,) rad or m, stacked joint coordinates; the arm's rows start the Newton iteration.
        tol: Newton tolerance on max |S e| (m or rad).
        max_iter: cap on the Newton iterations.
        sing_tol: σ_min/σ_max of S J below which the solve stops as SINGULAR.

    Returns:
        ArmSolution: the status, the stacked q, qd, qdd and the solve's diagnostics.
    """
    P, W, Ps, Ws = compiled(model)
    announce_compile("extras")
    q = _f(guess).copy()
    qd, qdd, info = np.zeros_like(q), np.zeros_like(q), np.zeros(3)
    st = ik.arm_solve(Ps, Ws, m, _f(P.rows), _f(p), _f(R), _f(twist), _f(acc), q, tol, max_iter, sing_tol,
                      qd, qdd, info)
    return ArmSolution(int(st), q, qd, qdd, float(info[0]), float(info[1]), float(info[2]))


class MotionSolution(NamedTuple):
    """Closed-chain inverse kinematics of an object motion (`object_motion.trajectory`).

    Attributes:
        status: object_motion.OK or a failure code.
        q, qd, qdd: (n_s, N) θ (rad or m), θ̇ (rad/s or m/s), θ̈ (rad/s² or m/s²), stacked arm after arm
            (complete when OK).
        arm: the failing arm, 0-based (a failure).
        sample: the failing sample's index (−1: a waypoint between segments).
        t: s, the failure's time.
        p_C: (3,) m, the object's centre of mass there, world.
        values: (2,) the numbers of the failure's reason (`object_motion.trajectory`'s info[4:6]).
        t_prev: s, the previous sample's time (a singularity crossed).
    """

    status: int
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    arm: int
    sample: int
    t: float
    p_C: np.ndarray
    values: np.ndarray
    t_prev: float


def motion_struct(model: Model, motion: ObjectMotion, spline: tuple | None = None) -> object_motion.Motion:
    """The object motion as the kernels take it (`object_motion.Motion`), arrays float64, contiguous, copied.

    Args:
        model: the Model (the rest posture's default: its initial angles).
        motion: the object's waypoints, time law ('quintic', 'cubic', 'sampled' or 'linear'), rest posture,
            gain and pull (rest_pull).
        spline: a B-spline path's (knots, coefficients (n, 6) [p − p₀ m; φ rad], degree)
            (`coopsim.inverse.spline_path.spline_arrays`); None: the waypoint path.

    Returns:
        object_motion.Motion.
    """
    law = object_motion.LAWS[motion.time_law]
    rest = model.q0 if motion.rest_posture is None else motion.rest_posture
    law_t, law_s, law_rate = ((motion.samples.t, motion.samples.s, motion.samples.rate) if law == object_motion.SAMPLED
                              else (motion.times[:2], np.zeros(2), np.zeros(2)))
    knots, ctrl, degree = (np.zeros(0), np.zeros((0, 6)), 0) if spline is None else spline
    return object_motion.Motion(_f(motion.times).copy(), _f(motion.positions).copy(), _f(motion.rotations).copy(),
                                _f(motion.positions[0]).copy(), law, _f(rest).copy(), float(motion.rest_gain),
                                _f(law_t).copy(), _f(law_s).copy(), _f(law_rate).copy(), _pull(motion),
                                _f(knots).copy(), _f(ctrl).copy(), int(degree), _f(motion.rotations[0]).copy())


def object_states(model: Model, motion: ObjectMotion, t: np.ndarray, spline: tuple | None = None):
    """The object's state along a prescribed motion at the times t, compiled (`object_motion.object_states`).

    Args:
        model: the Model.
        motion: the ObjectMotion.
        t: (n_s,) s, the times (clamped to the waypoints' span).
        spline: a B-spline path's arrays (`motion_struct`); None: the waypoint path.

    Returns:
        tuple: p_C (n_s, 3) m relative to the first waypoint's position, R_o (n_s, 3, 3) world ← object,
        twists [v_C; ω] (n_s, 6) and accelerations [a_C; ω̇] (n_s, 6), world axes (as
        `coopsim.inverse.trajectory.object_motion_at`).
    """
    announce_compile("extras")
    mo, t = motion_struct(model, motion, spline), _f(t).copy()
    n_s = len(t)
    pc, R, tw, ac = np.zeros((n_s, 3)), np.zeros((n_s, 3, 3)), np.zeros((n_s, 6)), np.zeros((n_s, 6))
    object_motion.object_states(mo, t, object_motion.buffers(model.n_total, 0, model.r), pc, R, tw, ac)
    return pc, R, tw, ac


def object_motion_ik(model: Model, motion: ObjectMotion, t_out: np.ndarray, guess: np.ndarray,
                     redundant: list[int], first: np.ndarray, reach_lim: np.ndarray, plane_tol: float,
                     tol: float = 1e-13, max_iter: int = 50, sing_tol: float = 1e-7, rtol: float = 1e-12,
                     atol: float = 1e-12, spline: tuple | None = None) -> MotionSolution:
    """Every arm's joint motion along a prescribed object motion, in one compiled pass over the samples.

    Square arms by Newton and the differential kinematics, redundant ones by the least-joint-velocity
    ODE with its null-space pull (DOP853 at rtol, atol) put on the grasps at every sample
    (`coopsim.compiled.object_motion`).

    Args:
        model: the Model.
        motion: the object's waypoints, time law, rest posture (None: the model's initial angles) and gain.
        t_out: (n_s,) s, the sample times, within the waypoints' span.
        guess: (N,) rad or m, stacked joint coordinates starting the inverse kinematics at the first sample.
        redundant: the indices of the arms with more joints than rows.
        first: (r, 3) m, each arm's first joint origin relative to its base point, world axes.
        reach_lim: (r,) m, each arm's reach with its slack (a target farther is out of reach).
        plane_tol: m or rad, how far a grasp may leave the constrained rows.
        tol: Newton tolerance on max |S e| (m or rad).
        max_iter: cap on the Newton iterations.
        sing_tol: σ_min/σ_max of S J below which an arm counts as singular.
        rtol, atol: DOP853's tolerances for the redundant arms' ODE.
        spline: a B-spline path's arrays (`motion_struct`; the motion's two waypoints its ends); None: the
            waypoint path.

    Returns:
        MotionSolution: the status, the joint motion and a failure's record.
    """
    P = compiled(model).P
    announce_compile("extras")
    mo = motion_struct(model, motion, spline)
    red = np.array(redundant, dtype=np.int64)
    square = np.array([m for m in range(len(P.dof) - 1) if m not in redundant], dtype=np.int64)
    idx = np.array([j for m in redundant for j in range(P.dof[m], P.dof[m + 1])], dtype=np.int64)
    t_out = _f(t_out).copy()
    n_s, n = len(t_out), int(P.dof[-1])
    Q, QD, QDD = np.zeros((n_s, n)), np.zeros((n_s, n)), np.zeros((n_s, n))
    info, where = np.zeros(7), np.zeros(2, dtype=np.int64)
    L = to_struct(integrate.new_loop(np.zeros(len(idx)), float(t_out[0]), 0, 0))
    B = object_motion.buffers(n, len(idx), len(P.dof) - 1)
    with _leased_structs(model) as (Ps, Ws):
        st = object_motion.trajectory(Ps, Ws, L, _tableau("dop853"), _f(P.rows).copy(), mo, red, idx, square,
                                      _f(first).copy(), _f(reach_lim).copy(), t_out, _f(guess).copy(), tol, max_iter,
                                      sing_tol, plane_tol, rtol, atol, Q, QD, QDD, info, where, B)
    return MotionSolution(int(st), Q, QD, QDD, int(where[0]), int(where[1]), float(info[0]),
                          mo.origin + info[1:4], info[4:6].copy(), float(info[6]))
