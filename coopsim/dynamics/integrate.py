"""Explicit Runge–Kutta time integration for the multibody state y = [q, q̇] (pure NumPy).

The caller supplies the ODE right-hand side ``rhs(t, y) -> ẏ`` and, optionally, a projection
``project(t, y) -> y`` onto the constraint manifold (position/velocity-level constraints of the
closed chain). :func:`integrate` returns the state at a strictly increasing set of output times;
every output time is hit exactly by a step (no dense-output interpolation), so each returned row
is an integrator value (and, with ``project``, a projected one).

Methods
-------
``'dop853'``  Dormand–Prince 8(5,3), 12 stages per step, adaptive; Hairer's combined 5th/3rd-order
              error estimator (Hairer, Nørsett & Wanner, *Solving ODEs I*, 2nd ed., Sec. II.5 and
              the DOP853 code; Prince & Dormand 1981).
``'dopri5'``  Dormand–Prince 5(4) (Dormand & Prince 1980), 6 + 1 stages, FSAL, adaptive.
``'rk4'``     classical 4th-order Runge–Kutta, fixed step.

Step-size control (Hairer et al., Sec. II.4): with sc_i = atol + rtol·max(|y_i|, |y_new,i|),

    err = sqrt( (1/n) Σ_i (e_i / sc_i)² ),    h_new = h · min(10, max(0.2, 0.9 · err^(-1/(p̂+1))))

where e = h Σ_j E_j k_j is the embedded error estimate; p̂ = 4 for dopri5 (order of the embedded
formula) and p̂ = 7 for dop853 (exponent 1/8, as in Hairer's code). A step is accepted when
err < 1; right after a rejection the step may not grow (factor ≤ 1). For dop853 the norm is
Hairer's

    err = |h| ‖e5‖² / sqrt(n (‖e5‖² + 0.01 ‖e3‖²)),  e5 = Σ_j E5_j k_j / sc,  e3 = Σ_j E3_j k_j / sc

(2-norms), which is what SciPy's ``DOP853._estimate_error_norm`` implements.
The initial step is Hairer's algorithm (Sec. II.4, "Starting step size"), capped by ``step``.

References
----------
E. Hairer, S. P. Nørsett, G. Wanner, *Solving Ordinary Differential Equations I: Nonstiff
Problems*, 2nd ed., Springer 1993, Sec. II.1, II.4–II.5.
J. R. Dormand, P. J. Prince, "A family of embedded Runge–Kutta formulae", J. Comput. Appl. Math.
6(1):19–26, 1980.
P. J. Prince, J. R. Dormand, "High order embedded Runge–Kutta formulae", J. Comput. Appl. Math.
7(1):67–75, 1981.
E. Hairer, DOP853 Fortran code, http://www.unige.ch/~hairer/software.html
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from coopsim.core import tableaux

__all__ = ["IntegrationError", "IntegratorStats", "integrate"]

SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0
RK4_SUBSTEP_SLACK = 1e-9   # ceil(Δt/step − slack): Δt = 3·step must give 3 substeps, not 4
STRETCH = 1.01             # a step within 1 % of the next output time is stretched onto it


# --------------------------------------------------------------------------------------------
# Butcher tableaux
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Tableau:
    """Explicit RK tableau. ``e`` (len n_stages + fsal) gives the error e = h Σ e_j k_j;
    ``e3`` is set only for DOP853 (second, 3rd-order estimator); ``err_order`` is p̂."""
    c: np.ndarray
    a: np.ndarray
    b: np.ndarray
    e: np.ndarray | None
    e3: np.ndarray | None
    fsal: bool
    err_order: int

    @property
    def n_stages(self) -> int:
        return len(self.b)


# The tableaux of coopsim.core.tableaux (the compiled time loop reads the same arrays): RK4; Dormand &
# Prince (1980) 5(4), whose 7th stage is f(t + h, y_{n+1}) (FSAL; E = b − b̂ includes that stage's
# weight); DOP853's 12-stage step (its dense-output stages 13–16 are not used here; E3/E5 drop the
# trailing zero weight of f(t + h, y_{n+1})).
_RK4 = _Tableau(c=tableaux.RK4_C, a=tableaux.RK4_A, b=tableaux.RK4_B, e=None, e3=None, fsal=False, err_order=0)
_DOPRI5 = _Tableau(c=tableaux.DOPRI5_C, a=np.hstack([tableaux.DOPRI5_A, np.zeros((6, 1))]), b=tableaux.DOPRI5_B,
                   e=tableaux.DOPRI5_E, e3=None, fsal=True, err_order=4)
_DOP853 = _Tableau(c=tableaux.DOP853_C[:12], a=tableaux.DOP853_A[:12, :12], b=tableaux.DOP853_B,
                   e=tableaux.DOP853_E5[:12], e3=tableaux.DOP853_E3[:12], fsal=False, err_order=7)
_METHODS = {"dop853": _DOP853, "dopri5": _DOPRI5, "rk4": _RK4}


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------

class IntegrationError(RuntimeError):
    """Integration could not continue.

    ``str(e)`` is one line: ``'integration failed at t=<t> s: <reason>'``.

    Args:
        t: s, the time where the failure was detected.
        y: (n,) the state there (copied).
        reason: what failed.

    Attributes:
        t: float, s, the time where the failure was detected.
        y: (n,) ndarray, the state there, y = [q, q̇] (rad, rad/s; m, m/s on a prismatic joint).
        reason: str, what failed.
    """

    def __init__(self, t: float, y: np.ndarray, reason: str):
        self.t = float(t)
        self.y = np.array(y, dtype=float, copy=True)
        self.reason = str(reason)
        super().__init__(f"integration failed at t={self.t:.15g} s: {self.reason}")

    def __reduce__(self):  # keep picklable (e.g. across multiprocessing) despite custom __init__
        return (type(self), (self.t, self.y, self.reason))


@dataclass(frozen=True)
class IntegratorStats:
    """Work counters of one :func:`integrate` call.

    Attributes:
        n_rhs: every rhs evaluation (including the two of the initial-step heuristic).
        n_accepted: accepted steps.
        n_rejected: rejected step attempts (adaptive methods).
        n_projections: calls of ``project`` (y0 included).
    """
    n_rhs: int
    n_accepted: int
    n_rejected: int
    n_projections: int


def integrate(rhs: Callable[[float, np.ndarray], np.ndarray], y0, t_out, *, method: str = "dop853",
              rtol: float = 1e-10, atol: float = 1e-12, step: float = 1e-3, h_min: float = 1e-12,
              max_steps: int = 10_000_000,
              project: Callable[[float, np.ndarray], np.ndarray] | None = None):
    """Integrate dy/dt = rhs(t, y), y(t_out[0]) = y0, and return ``(Y, stats)``.

    Steps are clipped (or stretched by ≤ 1 % within ``step``) so they end exactly on every
    t_out[k]; after a step shortened for an output time, the controller's previous proposal is
    kept. ``rhs`` and ``project`` must not modify their ``y`` argument in place. Exceptions raised
    by ``rhs`` or ``project`` propagate unchanged.

    Args:
        rhs: ``rhs(t, y) -> ẏ``, t in s, y and ẏ (n,) (the multibody state y = [q, q̇]).
        y0: (n,) the initial state (copied; must be finite).
        t_out: (K,) s, the output times, strictly increasing and finite; t_out[0] is the initial time.
        method: 'dop853' (Dormand–Prince 8(5,3), adaptive, Hairer's error estimator), 'dopri5'
            (Dormand–Prince 5(4), adaptive, FSAL) or 'rk4' (classical, fixed step ``step``).
        rtol, atol: adaptive methods: a step is accepted when the RMS of e_i / (atol + rtol·max(|y_i|,
            |y_new_i|)) is < 1 (dop853: Hairer's 5th/3rd-order combination, see module docstring);
            step controller h_new = h·min(10, max(0.2, 0.9·err^(−1/(p̂+1)))), no growth right after a
            rejection. ``atol`` (units of y) may be a scalar or an array of shape (n,).
        step: s. Adaptive methods: MAXIMUM step size (may be ``np.inf``); the initial step is
            min(step, Hairer's starting-step estimate). rk4: nominal step; each interval
            [t_k, t_{k+1}] is split into ceil((t_{k+1} − t_k)/step − 1e-9) equal substeps.
        h_min: s. Adaptive methods: an IntegrationError is raised when the controller's step size
            falls below max(h_min, 10 ulp(t)). Steps shortened only to land on an output time are
            exempt.
        max_steps: maximum number of step attempts (accepted + rejected) over the whole call.
        project: ``project(t, y) -> y`` onto the constraint manifold, or None: applied to y0 and after
            every accepted step (never inside RK stages). The derivative at the projected state is
            re-evaluated (for dopri5 the FSAL stage is discarded).

    Returns:
        tuple[np.ndarray, IntegratorStats]: ``(Y, stats)``: Y (K, n) with Y[k] = y(t_out[k]);
            Y[0] = y0 (projected if ``project`` is given); stats the call's work counters.

    Raises:
        ValueError: t_out not 1-D, empty, non-finite or not strictly increasing; bad y0/options; an
            unknown method; rhs or project returning an array of the wrong shape.
        IntegrationError: 'step size collapsed to … s' (h < h_min), 'non-finite derivative in
            component i' (rhs output; .t/.y are the arguments of that rhs call), 'non-finite state in
            component i' (step result) or 'non-finite projected state in component i' (projection),
            'maximum number of steps (N) exceeded'.
    """
    tab = _METHODS.get(method)
    if tab is None:
        raise ValueError(f"unknown method {method!r}; expected one of {sorted(_METHODS)}")
    y0, t_out = _validate(y0, t_out, rtol, atol, step, h_min, max_steps, tab)
    counts = {"rhs": 0, "acc": 0, "rej": 0, "proj": 0}
    f = _checked_rhs(rhs, y0.size, counts)
    proj = None if project is None else _checked_projection(project, y0.size, counts)

    Y = np.empty((t_out.size, y0.size))
    Y[0] = y0 if proj is None else proj(t_out[0], y0)
    if t_out.size > 1:
        if tab.e is None:
            _run_fixed(f, proj, Y, t_out, tab, step, max_steps, counts)
        else:
            _run_adaptive(f, proj, Y, t_out, tab, rtol, np.asarray(atol, dtype=float), step,
                          h_min, max_steps, counts)
    stats = IntegratorStats(n_rhs=counts["rhs"], n_accepted=counts["acc"],
                            n_rejected=counts["rej"], n_projections=counts["proj"])
    return Y, stats


# --------------------------------------------------------------------------------------------
# Input checking and wrapped callbacks
# --------------------------------------------------------------------------------------------

def _validate(y0, t_out, rtol, atol, step, h_min, max_steps, tab):
    y0 = np.array(y0, dtype=float, copy=True)
    t_out = np.array(t_out, dtype=float, copy=True)
    if y0.ndim != 1 or y0.size == 0:
        raise ValueError(f"y0 must be a non-empty 1-D array, got shape {y0.shape}")
    if not np.all(np.isfinite(y0)):
        raise ValueError("y0 contains non-finite values")
    if t_out.ndim != 1 or t_out.size == 0:
        raise ValueError(f"t_out must be a non-empty 1-D array, got shape {t_out.shape}")
    if not np.all(np.isfinite(t_out)):
        raise ValueError("t_out contains non-finite values")
    if np.any(np.diff(t_out) <= 0.0):
        raise ValueError("t_out must be strictly increasing")
    if not step > 0.0 or (tab.e is None and not math.isfinite(step)):
        raise ValueError(f"step must be positive (and finite for rk4), got {step}")
    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    if tab.e is not None:
        atol_arr = np.asarray(atol, dtype=float)
        positive = rtol > 0.0 or np.all(atol_arr > 0.0)
        if not (rtol >= 0.0 and np.all(atol_arr >= 0.0) and positive):
            raise ValueError("need rtol >= 0, atol >= 0, and not both zero")
        if atol_arr.shape not in ((), y0.shape):
            raise ValueError(f"atol must be a scalar or have shape {y0.shape}")
        if not 0.0 <= h_min < step:
            raise ValueError(f"need 0 <= h_min < step, got h_min={h_min}, step={step}")
    return y0, t_out


def _checked_rhs(rhs, n, counts):
    """Wrap rhs: count calls, coerce to float array of shape (n,), reject non-finite output."""
    def f(t, y):
        counts["rhs"] += 1
        dy = np.asarray(rhs(t, y), dtype=float)
        if dy.shape != (n,):
            raise ValueError(f"rhs returned shape {dy.shape}, expected ({n},)")
        if not np.isfinite(dy).all():
            i = int(np.flatnonzero(~np.isfinite(dy))[0])
            raise IntegrationError(t, y, f"non-finite derivative in component {i}")
        return dy
    return f


def _checked_projection(project, n, counts):
    """Wrap project: count calls, coerce to float array of shape (n,), reject non-finite output."""
    def p(t, y):
        counts["proj"] += 1
        yp = np.asarray(project(t, y), dtype=float)
        if yp.shape != (n,):
            raise ValueError(f"project returned shape {yp.shape}, expected ({n},)")
        _require_finite_state(t, yp, "projected state")
        return yp
    return p


def _require_finite_state(t, y, what="state"):
    if not np.isfinite(y).all():
        i = int(np.flatnonzero(~np.isfinite(y))[0])
        raise IntegrationError(t, y, f"non-finite {what} in component {i}")


# --------------------------------------------------------------------------------------------
# Runge–Kutta step and error norms
# --------------------------------------------------------------------------------------------

def _rk_step(f, t, y, fy, h, tab, K):
    """One explicit RK step (Hairer et al., Eq. II.1.8): k_1 = fy,
    k_i = f(t + c_i h, y + h Σ_{j<i} a_ij k_j); returns y + h Σ b_i k_i. Stages are stored in K."""
    K[0] = fy
    a, c = tab.a, tab.c
    for s in range(1, tab.n_stages):
        K[s] = f(t + c[s] * h, y + h * (a[s, :s] @ K[:s]))
    return y + h * (tab.b @ K[:tab.n_stages])


def _rms_error_norm(tab, K, h, scale):
    """‖h Σ E_j k_j / sc‖_RMS (Hairer et al., Eq. II.4.11)."""
    return abs(h) * math.sqrt(np.mean(np.square((tab.e @ K) / scale)))


def _dop853_error_norm(tab, K, h, scale):
    """Hairer's DOP853 estimate |h| ‖e5‖² / sqrt(n (‖e5‖² + 0.01 ‖e3‖²)) (as SciPy's
    DOP853._estimate_error_norm): the 5th-order estimate, damped where the 3rd-order one is
    large."""
    err5 = np.square((tab.e @ K) / scale).sum()
    err3 = np.square((tab.e3 @ K) / scale).sum()
    if err5 == 0.0 and err3 == 0.0:
        return 0.0
    return abs(h) * err5 / math.sqrt((err5 + 0.01 * err3) * scale.size)


def _initial_step(f, t0, y0, f0, span, h_max, rtol, atol, err_order):
    """Hairer's starting step (Hairer et al., Sec. II.4): explicit Euler probe of size
    h0 = 0.01 ‖y0‖/‖f0‖, then h1 = (0.01 / max(‖f0‖, ‖f1 − f0‖/h0))^(1/(p̂+1));
    h = min(100 h0, h1, span, h_max). Norms are RMS, weighted by atol + rtol |y0|."""
    scale = atol + rtol * np.abs(y0)
    d0 = _rms(y0 / scale)
    d1 = _rms(f0 / scale)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, span)
    f1 = f(t0 + h0, y0 + h0 * f0)
    d2 = _rms((f1 - f0) / scale) / h0
    if max(d1, d2) <= 1e-15:
        h1 = max(1e-6, 1e-3 * h0)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (err_order + 1))
    return min(100.0 * h0, h1, span, h_max)


def _rms(x):
    return math.sqrt(np.mean(np.square(x)))


# --------------------------------------------------------------------------------------------
# Drivers
# --------------------------------------------------------------------------------------------

def _run_fixed(f, proj, Y, t_out, tab, step, max_steps, counts):
    """Fixed-step driver: ceil(Δt/step − 1e-9) equal substeps per output interval."""
    K = np.empty((tab.n_stages, Y.shape[1]))
    y = Y[0].copy()
    for k in range(1, t_out.size):
        t0, t1 = t_out[k - 1], t_out[k]
        m = max(1, math.ceil((t1 - t0) / step - RK4_SUBSTEP_SLACK))
        h = (t1 - t0) / m
        for j in range(m):
            t = t0 + j * h
            t_new = t1 if j == m - 1 else t0 + (j + 1) * h
            if counts["acc"] >= max_steps:
                raise IntegrationError(t, y, f"maximum number of steps ({max_steps}) exceeded")
            y = _rk_step(f, t, y, f(t, y), h, tab, K)
            _require_finite_state(t_new, y)
            counts["acc"] += 1
            if proj is not None:
                y = proj(t_new, y)
        Y[k] = y


def _run_adaptive(f, proj, Y, t_out, tab, rtol, atol, h_max, h_min, max_steps, counts):
    """Adaptive driver: integrate from output time to output time, landing exactly on each."""
    K = np.empty((tab.n_stages + tab.fsal, Y.shape[1]))
    t, y = t_out[0], Y[0].copy()
    fy = f(t, y)
    h_abs = _initial_step(f, t, y, fy, t_out[-1] - t, h_max, rtol, atol, tab.err_order)
    for k in range(1, t_out.size):
        while t < t_out[k]:
            t, y, fy, h_abs = _accepted_step(f, t, y, fy, h_abs, t_out[k], tab, K, rtol, atol,
                                             h_max, h_min, max_steps, counts)
            if proj is not None:
                y = proj(t, y)
                fy = None
        Y[k] = y


def _clip(t, h_abs, t_end, h_max):
    """Step to try from t: h_abs, shortened to end on t_end, or stretched onto t_end when that
    is within 1 % and within h_max. Returns (h, t_new, clipped)."""
    remaining = t_end - t
    if remaining <= h_abs or (remaining <= STRETCH * h_abs and remaining <= h_max):
        return remaining, t_end, remaining < h_abs
    t_new = t + h_abs
    if t_new >= t_end:          # rounding guard
        return remaining, t_end, True
    return h_abs, t_new, False


def _accepted_step(f, t, y, fy, h_abs, t_end, tab, K, rtol, atol, h_max, h_min, max_steps,
                   counts):
    """Attempt steps from (t, y) until one is accepted (Hairer et al., Sec. II.4).
    Returns (t_new, y_new, f(t_new, y_new) or None, next step-size proposal)."""
    if fy is None:
        fy = f(t, y)
    exponent = -1.0 / (tab.err_order + 1)
    error_norm = _dop853_error_norm if tab.e3 is not None else _rms_error_norm
    rejected = False
    while True:
        if h_abs < max(h_min, 10.0 * np.spacing(abs(t))):
            raise IntegrationError(t, y, f"step size collapsed to {h_abs:.3e} s")
        if counts["acc"] + counts["rej"] >= max_steps:
            raise IntegrationError(t, y, f"maximum number of steps ({max_steps}) exceeded")
        h, t_new, clipped = _clip(t, min(h_abs, h_max), t_end, h_max)
        y_new = _rk_step(f, t, y, fy, h, tab, K)
        _require_finite_state(t_new, y_new)
        if tab.fsal:
            K[tab.n_stages] = f(t_new, y_new)
        err = error_norm(tab, K, h, atol + rtol * np.maximum(np.abs(y), np.abs(y_new)))
        if err < 1.0:
            factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, SAFETY * err ** exponent)
            if rejected:
                factor = min(1.0, factor)
            h_next = min(h * factor, h_max)
            if clipped:
                h_next = max(h_next, min(h_abs, h_max))
            counts["acc"] += 1
            f_new = K[tab.n_stages].copy() if tab.fsal else None
            return t_new, y_new, f_new, h_next
        counts["rej"] += 1
        rejected = True
        h_abs = h * max(MIN_FACTOR, SAFETY * err ** exponent)
