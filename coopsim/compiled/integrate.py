"""Compiled stage 6: the whole time loop of the closed chain, with no Python per step.

Methods and step control are those of the reference `coopsim.dynamics.integrate` (Hairer, Nørsett & Wanner,
*Solving ODEs I*, 2nd ed., Sec. II.4–II.5): DOP853 (Hairer's 5th/3rd-order error estimate, exponent
1/8), Dormand–Prince 5(4) (FSAL, exponent 1/5), classical RK4 at a fixed step; Hairer's starting step;
h_new = h·min(10, max(0.2, 0.9·err^(−1/(p̂+1)))), no growth right after a rejection. Unlike the
reference, outputs come from the methods' dense output — DOP853's 7th-order interpolant (3 extra
stages, only in steps that hold an output time) and Dormand–Prince's 4th-order one (free) — so the
output grid does not limit the step, and the adaptive step is unbounded unless `h_max` is given
(`land`: the steps end on every output time instead, as the reference's do — with a controller in the
loop, so that both loops take the same steps).
With projection stabilization, every accepted step and every output sample is projected onto the
loop-closure manifold (`manifold.project_state`) and the derivative is re-evaluated there; an output
from dense output can instead be left to the sampler to project (Loop.defer: `sample.evaluate` then
evaluates it on the projection's own kinematics), which changes nothing in the steps.

A fixed-step mode (any of the three tableaux) splits each output interval into
ceil(Δt/step − 1e-9) equal steps, as the reference's RK4; its stage times t + c_i h are computed as
`stage_times` computes them, so torques tabulated at exactly those times are met exactly (replays).

Torques are the packed per-joint tables (linear between knots, held outside), evaluated at every
stage time, plus a controller's command where one is in the loop (`control.feedback`). The loop can
stop after the step that fills output `k_stop` and resume exactly where it stopped (the step sequence
is unchanged), which is how progress is reported. `run` is compiled twice: without a controller (ctl
None) and with one.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from coopsim.compiled.closed_chain import OK, RANK_DEFICIENT, chain_forward
from coopsim.compiled.control import feedback
from coopsim.compiled.linalg import bisect, copy1, finite
from coopsim.compiled.manifold import NON_FINITE_STATE, project_state
from coopsim.compiled.packing import STAB_PROJECTION
from coopsim.compiled.toolchain.jit import entry, kernel
from coopsim.core import tableaux

DOP853, DOPRI5, RK4 = 0, 1, 2
STEP_COLLAPSED, MAX_STEPS = 5, 6      # failure codes after NON_FINITE_STATE (manifold's, 4)
SAFETY, MIN_FACTOR, MAX_FACTOR, STRETCH, SUBSTEP_SLACK = 0.9, 0.2, 10.0, 1.01, 1e-9


class Tableau(NamedTuple):
    """An explicit Runge–Kutta method as arrays (16 stage slots, unused ones zero).

    Compiled code takes it as the StructRef of `structs.to_struct` (the kernels' argument tab).

    Attributes:
        code: DOP853, DOPRI5 or RK4.
        stages: the number of stages of one step (s below).
        A: (16, 16) the stage coefficients a_ij.
        C: (16,) the nodes c_i (stage i is evaluated at t + c_i h).
        B: (16,) step weights over stages 0…s−1.
        E5, E3: (16,) error weights over stages 0…s (stage s = f(t + h, y_new)); E3 is DOP853's only.
        D: (4, 16) DOP853's dense-output rows (stages 0…15).
        Pd: (7, 4) Dormand–Prince's dense-output polynomial.
        err_order: p̂ (controller exponent 1/(p̂+1)); 0 for RK4, which has no error estimate.
    """

    code: int
    stages: int
    A: np.ndarray
    C: np.ndarray
    B: np.ndarray
    E5: np.ndarray
    E3: np.ndarray
    D: np.ndarray
    Pd: np.ndarray
    err_order: int


def tableau(method: str) -> Tableau:
    """The tableau of 'dop853', 'dopri5' or 'rk4'.

    Args:
        method: 'dop853', 'dopri5' or 'rk4'.

    Returns:
        Tableau: the method's coefficients (`coopsim.core.tableaux`) in the 16-slot arrays.

    Raises:
        ValueError: for any other method.
    """
    A, C, B, E5, E3 = np.zeros((16, 16)), np.zeros(16), np.zeros(16), np.zeros(16), np.zeros(16)
    D, Pd = np.zeros((4, 16)), np.zeros((7, 4))
    if method == "dop853":
        A[:] = tableaux.DOP853_A
        C[:] = tableaux.DOP853_C
        B[:12] = tableaux.DOP853_B
        E5[:13], E3[:13], D[:] = tableaux.DOP853_E5, tableaux.DOP853_E3, tableaux.DOP853_D
        return Tableau(DOP853, 12, A, C, B, E5, E3, D, Pd, 7)
    if method == "dopri5":
        A[:6, :5] = tableaux.DOPRI5_A
        C[:6] = tableaux.DOPRI5_C
        B[:6] = tableaux.DOPRI5_B
        E5[:7], Pd[:] = tableaux.DOPRI5_E, tableaux.DOPRI5_P
        return Tableau(DOPRI5, 6, A, C, B, E5, E3, D, Pd, 4)
    if method == "rk4":
        A[:4, :4] = tableaux.RK4_A
        C[:4] = tableaux.RK4_C
        B[:4] = tableaux.RK4_B
        return Tableau(RK4, 4, A, C, B, E5, E3, D, Pd, 0)
    raise ValueError(f"unknown method {method!r}; expected dop853, dopri5 or rk4")


class Loop(NamedTuple):
    """State and buffers of one integration (n = 2N state size, N joints, K constraint rows).

    Compiled code takes it as the StructRef of `structs.to_struct` (the kernels' argument L); `run`
    advances it in place, and Python reads the counters and records after each call.

    Attributes:
        t: (1,) s, the time of the state y.
        h: (1,) s, the step proposal (0 before the first step).
        y: (n,) the state [θ; θ̇] (rad or m, rad/s or m/s).
        fy: (n,) its derivative [θ̇; θ̈].
        has_fy: (1,) int: 1 once fy holds the derivative at (t, y).
        k_next: (1,) int: next output to fill (0: the initial state is not yet projected).
        count: (4,) int: rhs evaluations, accepted and rejected steps, projections.
        status: (1,) int: 0 or a failure code.
        fail_t, fail_y: (1,) s and (n,): where it failed.
        warn: (2,) int: [Λ𝐈⁻¹Λᵀ rank lost?, its rank].
        warn_t, warn_cond, warn_y: (1,) s, (1,), (n,): the first such state, its time and the condition
            number of Λ𝐈⁻¹Λᵀ there.
        K: (16, n) the stage derivatives.
        y_new, ytmp: (n,) the step's new state, and the stage input (scratch).
        Fd: (7, n) dense-output coefficients.
        stab: (K,) Baumgarte term.
        step: (N,) projection step.
        defer: (1,) int: 1: with projection stabilization, an output filled from dense output is left
            as interpolated (flagged in raw) for the sampler to project (`sample.evaluate`), which then
            reuses the projection's kinematics; 0: it is projected here.
        raw: (len(t_out),) int: 1 for an output left unprojected (with defer), else 0.
    """

    t: np.ndarray
    h: np.ndarray
    y: np.ndarray
    fy: np.ndarray
    has_fy: np.ndarray
    k_next: np.ndarray
    count: np.ndarray
    status: np.ndarray
    fail_t: np.ndarray
    fail_y: np.ndarray
    warn: np.ndarray
    warn_t: np.ndarray
    warn_cond: np.ndarray
    warn_y: np.ndarray
    K: np.ndarray
    y_new: np.ndarray
    ytmp: np.ndarray
    Fd: np.ndarray
    stab: np.ndarray
    step: np.ndarray
    defer: np.ndarray
    raw: np.ndarray


def new_loop(y0: np.ndarray, t0: float, n_rows: int, n_out: int, defer: bool = False) -> Loop:
    """Fresh loop state at (t0, y0) for a model with n_rows constraint rows and n_out output times.

    Args:
        y0: (2N,) the initial state [θ; θ̇] (rad or m, rad/s or m/s), copied.
        t0: s, its time.
        n_rows: K = k(r−1), the model's constraint rows.
        n_out: the number of output times.
        defer: leave the outputs filled from dense output unprojected, for the sampler (Loop.defer).

    Returns:
        Loop: counters and buffers zeroed; h = 0 (`run` chooses the first step), k_next = 0.
    """
    n = len(y0)
    z, iz = np.zeros, lambda k: np.zeros(k, dtype=np.int64)  # noqa: E731
    return Loop(np.array([t0]), z(1), np.array(y0, dtype=float), z(n), iz(1), iz(1),
                iz(4), iz(1), z(1), z(n), iz(2), z(1), z(1), z(n), z((16, n)), z(n), z(n), z((7, n)),
                z(n_rows), z(n // 2), np.array([int(defer)], dtype=np.int64), iz(n_out))


def stage_times(t0: float, t1: float, step: float, C: np.ndarray, stages: int) -> np.ndarray:
    """Every stage time of the fixed-step mode over [t0, t1], sorted and unique.

    Computed exactly as the loop computes them, so that torques tabulated there are met exactly.

    Args:
        t0, t1: s, the ends of one output interval.
        step: s, the largest fixed step: [t0, t1] is split into ceil((t1 − t0)/step − 1e-9) equal steps.
        C: (16,) the tableau's nodes c_i.
        stages: the number of stages of one step.

    Returns:
        np.ndarray: (T,) s, the stage times t + c_i h of every step, and t1.
    """
    m = max(1, math.ceil((t1 - t0) / step - SUBSTEP_SLACK))
    h = (t1 - t0) / m
    out = [t0 + j * h + C[i] * h for j in range(m) for i in range(stages)] + [t1]
    return np.unique(np.array(out))


# ------------------------------------------------------------------------------------------------
# Right-hand side
# ------------------------------------------------------------------------------------------------

@kernel
def torque_at(P, t, tau):
    """τ(t) (N,) from the packed per-joint tables: linear between knots, held outside.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        t: s, the time.
        tau: (N,) written: τ(t), N·m (N for a prismatic joint).
    """
    off, tt, tv = P.tq_off, P.tq_t, P.tq_v
    for j in range(P.dof[-1]):
        lo, hi = off[j], off[j + 1] - 1
        if hi == lo or t <= tt[lo]:
            tau[j] = tv[lo]
        elif t >= tt[hi]:
            tau[j] = tv[hi]
        else:
            lo = bisect(tt, lo, hi, t)
            t0 = tt[lo]
            tau[j] = tv[lo] + (t - t0) / (tt[lo + 1] - t0) * (tv[lo + 1] - tv[lo])


@kernel
def fail(L, code, t, y):
    """Record a failure (code, time, state); returns the code.

    Args:
        L: the loop (Loop StructRef): L.status, L.fail_t and L.fail_y written.
        code: the failure code (chain_forward's, the controller's or the integrator's).
        t: s, the time of the failure.
        y: (n,) the state there.

    Returns:
        int: code.
    """
    L.status[0] = code
    L.fail_t[0] = t
    for i in range(len(y)):
        L.fail_y[i] = y[i]
    return code


@kernel
def rhs(P, W, L, ctl, t, y, dy):
    """dy ← [θ̇; θ̈(t, θ, θ̇)]: closed-chain forward dynamics with the tabulated torques.

    A controller's command is added to the torques: ctl = (Pc, Wc, C), `control.feedback`; None: no
    controller — numba prunes the branch, so the open loop's compiled code is what it was without
    controllers. A lost rank of Λ𝐈⁻¹Λᵀ stops the loop (P.rank_error) or is recorded once (minimum-norm
    wrenches).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.tau ← the torques applied, and every term of the
            evaluation (`closed_chain.chain_forward`) written.
        L: the loop (Loop StructRef): L.count[0] counted, L.stab scratch for the Baumgarte term, the rank
            warning (L.warn, warn_t, warn_cond, warn_y) or a failure recorded.
        ctl: None, or (Pc, Wc, C): the controller's compiled model, a workspace of its own and its record
            (`control.control_struct`), StructRefs.
        t: s, the time.
        y: (2N,) the state [θ; θ̇] (rad or m, rad/s or m/s).
        dy: (2N,) written: [θ̇; θ̈].

    Returns:
        int: 0 (OK) or a failure code (the controller's, or chain_forward's: RANK_DEFICIENT only with
            P.rank_error).
    """
    N = P.dof[-1]
    L.count[0] += 1
    torque_at(P, t, W.tau)
    if ctl is not None:
        st = feedback(ctl[0], ctl[1], ctl[2], t, y[:N], y[N:], W.tau)
        if st != OK:
            return fail(L, st, t, y)
    st = chain_forward(P, W, y[:N], y[N:], W.tau, L.stab)
    if st == RANK_DEFICIENT:
        if P.rank_error:
            return fail(L, st, t, y)
        if L.warn[0] == 0:
            L.warn[0], L.warn[1] = 1, W.rank[0]
            L.warn_t[0], L.warn_cond[0] = t, W.cond[0]
            for i in range(len(y)):
                L.warn_y[i] = y[i]
        st = OK
    if st != OK:
        return fail(L, st, t, y)
    for i in range(N):
        dy[i] = y[N + i]
        dy[N + i] = W.qdd[i]
    return OK


# ------------------------------------------------------------------------------------------------
# One Runge–Kutta step, error norms, dense output
# ------------------------------------------------------------------------------------------------

@kernel
def stage_input(tab, L, y, h, i):
    """L.ytmp ← y + h Σ_{j<i} a_ij K_j, the state at which stage i is evaluated.

    Args:
        tab: the tableau (Tableau StructRef).
        L: the loop (Loop StructRef): stage derivatives L.K[0:i] read, L.ytmp written.
        y: (n,) the state at the start of the step.
        h: s, the step.
        i: the stage index, 1 ≤ i < 16.
    """
    A, Ks, out = tab.A, L.K, L.ytmp
    for x in range(len(y)):
        acc = 0.0
        for j in range(i):
            acc += A[i, j] * Ks[j, x]
        out[x] = y[x] + h * acc


@kernel
def rk_combine(tab, L, y, h, out):
    """out ← y + h Σ_i b_i K_i, the state at the end of the step.

    Args:
        tab: the tableau (Tableau StructRef).
        L: the loop (Loop StructRef): stage derivatives L.K[0:s] read.
        y: (n,) the state at the start of the step.
        h: s, the step.
        out: (n,) written.
    """
    B, Ks, s = tab.B, L.K, tab.stages
    for x in range(len(y)):
        acc = 0.0
        for i in range(s):
            acc += B[i] * Ks[i, x]
        out[x] = y[x] + h * acc


@kernel
def error_norm(tab, L, y, y_new, h, rtol, atol):
    """Scaled error of the step.

    DOP853 |h| ‖e5‖² / sqrt(n (‖e5‖² + 0.01 ‖e3‖²)) (Hairer's code), else |h| ‖e‖_RMS, with
    e = Σ_j E_j K_j / (atol + rtol max(|y|, |y_new|)).

    Args:
        tab: the tableau (Tableau StructRef).
        L: the loop (Loop StructRef): stage derivatives L.K[0:s+1] read (stage s = f(t + h, y_new)).
        y, y_new: (n,) the states at the start and end of the step.
        h: s, the step.
        rtol, atol: relative and absolute tolerances (atol in the units of the state's components).

    Returns:
        float: the scaled error (the step is accepted below 1).
    """
    n = len(y)
    E5, E3, Ks, s = tab.E5, tab.E3, L.K, tab.stages
    e5 = 0.0
    e3 = 0.0
    for x in range(n):
        sc = atol + rtol * max(abs(y[x]), abs(y_new[x]))
        a5 = 0.0
        a3 = 0.0
        for j in range(s + 1):
            a5 += E5[j] * Ks[j, x]
            a3 += E3[j] * Ks[j, x]
        e5 += (a5 / sc) ** 2
        e3 += (a3 / sc) ** 2
    if tab.code == DOP853:
        if e5 == 0.0 and e3 == 0.0:
            return 0.0
        return abs(h) * e5 / np.sqrt((e5 + 0.01 * e3) * n)
    return abs(h) * np.sqrt(e5 / n)


@kernel
def dense_coefficients(tab, L, y, y_new, h):
    """Dense-output coefficients of the accepted step (t, y) → (t + h, y_new) into L.Fd.

    DOP853 (its extra stages 13–15 in L.K): F_0 = Δy, F_1 = h f_0 − Δy, F_2 = 2Δy − h (f_0 + f_new),
    F_3…6 = h D K. Dormand–Prince: Q = Kᵀ Pd (rows 0…3 of Fd).

    Args:
        tab: the tableau (Tableau StructRef).
        L: the loop (Loop StructRef): stage derivatives L.K read, L.Fd written.
        y, y_new: (n,) the states at the start and end of the step.
        h: s, the step.
    """
    n = len(y)
    Ks, Fd = L.K, L.Fd
    if tab.code == DOPRI5:
        Pd = tab.Pd
        for k in range(4):
            for x in range(n):
                acc = 0.0
                for j in range(7):
                    acc += Ks[j, x] * Pd[j, k]
                Fd[k, x] = acc
        return
    D = tab.D
    for x in range(n):
        dy = y_new[x] - y[x]
        Fd[0, x] = dy
        Fd[1, x] = h * Ks[0, x] - dy
        Fd[2, x] = 2.0 * dy - h * (Ks[12, x] + Ks[0, x])
        for k in range(4):
            acc = 0.0
            for j in range(16):
                acc += D[k, j] * Ks[j, x]
            Fd[3 + k, x] = h * acc


@kernel
def dense_eval(tab, L, y, h, u, out):
    """out ← the dense output at t + u h (0 ≤ u ≤ 1) of the prepared step from y.

    Args:
        tab: the tableau (Tableau StructRef).
        L: the loop (Loop StructRef): L.Fd of `dense_coefficients` read.
        y: (n,) the state at the start of the step.
        h: s, the step.
        u: the fraction of the step, 0 ≤ u ≤ 1.
        out: (n,) written: the interpolated state.
    """
    n = len(y)
    Fd = L.Fd
    if tab.code == DOPRI5:
        for x in range(n):
            acc = 0.0
            p = u
            for k in range(4):
                acc += Fd[k, x] * p
                p *= u
            out[x] = y[x] + h * acc
        return
    for x in range(n):
        acc = 0.0
        for i in range(7):
            acc += Fd[6 - i, x]
            acc *= u if i % 2 == 0 else 1.0 - u
        out[x] = y[x] + acc


# ------------------------------------------------------------------------------------------------
# Drivers
# ------------------------------------------------------------------------------------------------

@kernel
def project(P, W, L, t, y):
    """Project y in place (projection stabilization only; otherwise y is left as it is).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): the kinematics, Λ and Φ of the projection written.
        L: the loop (Loop StructRef): L.count[3] counted, L.step scratch, a failure recorded.
        t: s, the time of y (for the failure record).
        y: (2N,) the state [θ; θ̇], overwritten with its projection onto Φ(θ) = 0, Λ(θ)θ̇ = 0.

    Returns:
        int: 0 (OK) or a failure code (PROJECTION_FAILED, NON_FINITE_STATE).
    """
    if P.stabilization != STAB_PROJECTION:
        return OK
    L.count[3] += 1
    st = project_state(P, W, y, P.projection_tol, P.projection_max_iter, L.step)
    if st != OK:
        return fail(L, st, t, y)
    return OK


@kernel
def rms_scaled(x, y, rtol, atol):
    """sqrt(mean((x_i / (atol + rtol |y_i|))²)).

    Args:
        x: (n,) the vector measured.
        y: (n,) the state setting the weights.
        rtol, atol: relative and absolute tolerances.

    Returns:
        float: the weighted RMS norm of x.
    """
    acc = 0.0
    for i in range(len(x)):
        acc += (x[i] / (atol + rtol * abs(y[i]))) ** 2
    return np.sqrt(acc / len(x))


@kernel
def probe_step(L, span, rtol, atol):
    """Hairer's starting step (Sec. II.4), first half: the Euler probe h0 = 0.01 ‖y0‖/‖f0‖.

    Weighted RMS norms (`rms_scaled`); h0 = 1e-6 when either is tiny, at most span; L.ytmp ← y0 + h0 f0.

    Args:
        L: the loop (Loop StructRef): y0 = L.y and f0 = L.fy read, L.ytmp written.
        span: s, the time to the end of the run.
        rtol, atol: relative and absolute tolerances.

    Returns:
        float: h0, s.
    """
    d0 = rms_scaled(L.y, L.y, rtol, atol)
    d1 = rms_scaled(L.fy, L.y, rtol, atol)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, span)
    for x in range(len(L.y)):
        L.ytmp[x] = L.y[x] + h0 * L.fy[x]
    return h0


@kernel
def first_step(tab, L, h0, span, h_max, rtol, atol):
    """Hairer's starting step, second half, with f1 = f(t0 + h0, ytmp) in L.K[1].

    h1 = (0.01 / max(‖f0‖, ‖f1 − f0‖/h0))^(1/(p̂+1)), h = min(100 h0, h1, span, h_max).

    Args:
        tab: the tableau (Tableau StructRef; its err_order p̂).
        L: the loop (Loop StructRef): L.y, L.fy = f0 and L.K[1] = f1 read, L.ytmp scratch.
        h0: s, the probe step of `probe_step`.
        span: s, the time to the end of the run.
        h_max: s, the largest step.
        rtol, atol: relative and absolute tolerances.

    Returns:
        float: h, s, the first step to try.
    """
    d1 = rms_scaled(L.fy, L.y, rtol, atol)
    for x in range(len(L.y)):
        L.ytmp[x] = L.K[1, x] - L.fy[x]
    d2 = rms_scaled(L.ytmp, L.y, rtol, atol) / h0
    if max(d1, d2) <= 1e-15:
        h1 = max(1e-6, 1e-3 * h0)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (tab.err_order + 1))
    return min(100.0 * h0, h1, span, h_max)


@kernel
def clip_step(t, h_abs, t_end, h_max):
    """Step to try from t: h_abs (at most h_max), or one that ends on t_end.

    Shortened to end on t_end, or stretched onto t_end when that is within 1 % and within h_max.

    Args:
        t: s, the time at the start of the step.
        h_abs: s, the step proposed (positive).
        t_end: s, the time the step must not pass (the end of the run, or the next output with `land`).
        h_max: s, the largest step.

    Returns:
        tuple[float, float, bool]: (h, t_new, clipped): the step, s; its end time, s (t_end exactly when it
            ends there); whether h is shorter than min(h_abs, h_max).
    """
    hc = min(h_abs, h_max)
    remaining = t_end - t
    if remaining <= hc or (remaining <= STRETCH * hc and remaining <= h_max):
        return remaining, t_end, remaining < hc
    t_new = t + hc
    if t_new >= t_end:          # rounding guard
        return remaining, t_end, True
    return hc, t_new, False


@kernel
def next_step_size(err, expo, h, h_abs, h_max, rejected, clipped):
    """The step controller after an accepted step: the next step proposal.

    h·min(10, 0.9·err^expo) (no growth right after a rejection), at most h_max; after a step shortened
    onto the end, the earlier proposal is kept.

    Args:
        err: the accepted step's scaled error (`error_norm`, < 1).
        expo: the controller exponent −1/(p̂+1).
        h: s, the step taken.
        h_abs: s, the proposal it was clipped from (`clip_step`).
        h_max: s, the largest step.
        rejected: whether a rejection preceded the step.
        clipped: whether `clip_step` shortened the step.

    Returns:
        float: s, the next step proposal.
    """
    factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, SAFETY * err ** expo)
    if rejected:
        factor = min(1.0, factor)
    h_next = min(h * factor, h_max)
    if clipped:
        h_next = max(h_next, min(h_abs, h_max))
    return h_next


@kernel
def step_too_small(t, h_abs, h_min):
    """Whether the step proposal has collapsed: below h_min, or below 10 units in the last place of t.

    Args:
        t: s, the current time.
        h_abs: s, the step proposal.
        h_min: s, the smallest step allowed.

    Returns:
        bool: True when the loop must stop (STEP_COLLAPSED).
    """
    return h_abs < max(h_min, 10.0 * (np.nextafter(abs(t), np.inf) - abs(t)))


@entry
def run(P, W, L, tab, ctl, t_out, Y, rtol, atol, h_max, h_min, max_steps, fixed_step, k_stop, land):
    """Integrate from L's state until outputs up to k_stop − 1 are in Y (len(t_out), 2N).

    First the projection of the initial state (output 0), then adaptive steps, or fixed steps of at
    most fixed_step s when fixed_step > 0. Stops early on a failure (L.status). ctl = (Pc, Wc, C): the
    controller in the loop (`rhs`). land: adaptive steps end on every output time (as the reference
    `coopsim.dynamics.integrate` does) instead of reaching them by dense output.

    This is the only function that evaluates the right-hand side (every stage, probe and dense-output
    stage is evaluated here): each compiled function that calls the closed-chain kernel compiles it
    again, so the helpers above only prepare stage inputs and combine stage values.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef; scratch, overwritten).
        L: the loop (Loop StructRef of `new_loop`): state, step proposal, counters, failure and rank
            warning records, advanced in place; a later call resumes exactly where this one stopped.
        tab: the tableau (Tableau StructRef of `tableau`).
        ctl: None, or (Pc, Wc, C): the controller in the loop (`rhs`).
        t_out: (S,) s, the output times, strictly increasing; t_out[0] is the initial time.
        Y: (S, 2N) written: the states [θ; θ̇] at t_out, each row once the loop reaches its time (rows
            L.k_next … k_stop − 1 at least, L.k_next as on entry); with L.defer, a row from dense output
            as interpolated (L.raw).
        rtol, atol: relative and absolute tolerances of the adaptive steps.
        h_max: s, the largest adaptive step (inf: unbounded).
        h_min: s, the smallest adaptive step (STEP_COLLAPSED below it).
        max_steps: the most steps (accepted, and for adaptive steps rejected too) before MAX_STEPS.
        fixed_step: s, the largest fixed step; 0: adaptive steps.
        k_stop: outputs 0 … k_stop − 1 are filled before the call returns (unless it fails).
        land: adaptive steps end on every output time.
    """
    if L.k_next[0] == 0:
        if project(P, W, L, t_out[0], L.y) != OK:
            return
        copy1(L.y, Y[0])
        L.k_next[0] = 1
    if fixed_step > 0.0:
        while L.k_next[0] < k_stop:
            k = L.k_next[0]
            t0, t1 = t_out[k - 1], t_out[k]
            m = max(1, math.ceil((t1 - t0) / fixed_step - SUBSTEP_SLACK))
            h = (t1 - t0) / m
            for j in range(m):
                t = t0 + j * h
                t_new = t1 if j == m - 1 else t0 + (j + 1) * h
                if L.count[1] >= max_steps:
                    fail(L, MAX_STEPS, t, L.y)
                    return
                if rhs(P, W, L, ctl, t, L.y, L.K[0]) != OK:
                    return
                for i in range(1, tab.stages):
                    stage_input(tab, L, L.y, h, i)
                    if rhs(P, W, L, ctl, t + tab.C[i] * h, L.ytmp, L.K[i]) != OK:
                        return
                rk_combine(tab, L, L.y, h, L.y_new)
                if not finite(L.y_new):
                    fail(L, NON_FINITE_STATE, t_new, L.y_new)
                    return
                L.count[1] += 1
                copy1(L.y_new, L.y)
                if project(P, W, L, t_new, L.y) != OK:
                    return
            copy1(L.y, Y[k])
            L.k_next[0] = k + 1
            L.t[0] = t1
        return
    t_end = t_out[-1]
    s = tab.stages
    expo = -1.0 / (tab.err_order + 1)
    if L.has_fy[0] == 0:
        if rhs(P, W, L, ctl, L.t[0], L.y, L.fy) != OK:
            return
        L.has_fy[0] = 1
    if L.h[0] <= 0.0:
        span = t_end - L.t[0]
        h0 = probe_step(L, span, rtol, atol)
        if rhs(P, W, L, ctl, L.t[0] + h0, L.ytmp, L.K[1]) != OK:
            return
        L.h[0] = first_step(tab, L, h0, span, h_max, rtol, atol)
    while L.k_next[0] < k_stop:
        t, h_abs = L.t[0], L.h[0]
        rejected = False
        while True:
            if step_too_small(t, h_abs, h_min):
                fail(L, STEP_COLLAPSED, t, L.y)
                return
            if L.count[1] + L.count[2] >= max_steps:
                fail(L, MAX_STEPS, t, L.y)
                return
            h, t_new, clipped = clip_step(t, h_abs, t_out[L.k_next[0]] if land else t_end, h_max)
            copy1(L.fy, L.K[0])
            for i in range(1, s):
                stage_input(tab, L, L.y, h, i)
                if rhs(P, W, L, ctl, t + tab.C[i] * h, L.ytmp, L.K[i]) != OK:
                    return
            rk_combine(tab, L, L.y, h, L.y_new)
            if not finite(L.y_new):
                fail(L, NON_FINITE_STATE, t_new, L.y_new)
                return
            if rhs(P, W, L, ctl, t_new, L.y_new, L.K[s]) != OK:
                return
            err = error_norm(tab, L, L.y, L.y_new, h, rtol, atol)
            if err < 1.0:
                break
            L.count[2] += 1
            rejected = True
            h_abs = h * max(MIN_FACTOR, SAFETY * err ** expo)
        h_next = next_step_size(err, expo, h, h_abs, h_max, rejected, clipped)
        L.count[1] += 1
        k = L.k_next[0]
        if k < len(t_out) and t_out[k] < t_new:
            if tab.code == DOP853:
                for i in range(13, 16):
                    stage_input(tab, L, L.y, h, i)
                    if rhs(P, W, L, ctl, t + tab.C[i] * h, L.ytmp, L.K[i]) != OK:
                        return
            dense_coefficients(tab, L, L.y, L.y_new, h)
            while k < len(t_out) and t_out[k] < t_new:
                dense_eval(tab, L, L.y, h, (t_out[k] - t) / h, Y[k])
                if L.defer[0] and P.stabilization == STAB_PROJECTION:
                    L.raw[k] = 1
                elif project(P, W, L, t_out[k], Y[k]) != OK:
                    return
                k += 1
        copy1(L.y_new, L.y)
        copy1(L.K[s], L.fy)
        if P.stabilization == STAB_PROJECTION:
            if project(P, W, L, t_new, L.y) != OK:
                return
            if rhs(P, W, L, ctl, t_new, L.y, L.fy) != OK:
                return
        while k < len(t_out) and t_out[k] <= t_new:
            copy1(L.y, Y[k])
            k += 1
        L.k_next[0] = k
        L.t[0], L.h[0] = t_new, h_next
