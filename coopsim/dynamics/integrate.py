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


# Classical RK4 (Hairer et al., Sec. II.1, Table 1.2 right).
_RK4 = _Tableau(
    c=np.array([0.0, 0.5, 0.5, 1.0]),
    a=np.array([[0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.0], [0.0, 0.5, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0]]),
    b=np.array([1.0, 2.0, 2.0, 1.0]) / 6.0,
    e=None, e3=None, fsal=False, err_order=0,
)

# Dormand & Prince (1980) 5(4), Hairer et al. Table II.5.2. The 7th stage is f(t + h, y_{n+1})
# (FSAL); E = b − b̂ (5th minus embedded 4th order) includes the weight of that stage.
_DOPRI5 = _Tableau(
    c=np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0]),
    a=np.array([
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [1 / 5, 0.0, 0.0, 0.0, 0.0, 0.0],
        [3 / 40, 9 / 40, 0.0, 0.0, 0.0, 0.0],
        [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0, 0.0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0, 0.0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0.0],
    ]),
    b=np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]),
    e=np.array([-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40]),
    e3=None, fsal=True, err_order=4,
)

# DOP853 (Prince & Dormand 1981; Hairer's DOP853): the 12 stages of the 8th-order step.
# Coefficients copied from Hairer's DOP853 Fortran code via SciPy's
# scipy/integrate/_ivp/dop853_coefficients.py (BSD-3-Clause, Copyright (c) SciPy Developers);
# dense-output stages 13–16 are not needed here and omitted. E3/E5 drop SciPy's trailing zero
# (weight of f(t + h, y_{n+1}), unused by the error estimate).
_DOP853_C = np.array([
    0.0, 0.526001519587677318785587544488e-01, 0.789002279381515978178381316732e-01,
    0.118350341907227396726757197510, 0.281649658092772603273242802490,
    0.333333333333333333333333333333, 0.25, 0.307692307692307692307692307692,
    0.651282051282051282051282051282, 0.6, 0.857142857142857142857142857142, 1.0,
])
_DOP853_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [5.26001519587677318785587544488e-2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1.97250569845378994544595329183e-2, 5.91751709536136983633785987549e-2, 0.0, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [2.95875854768068491816892993775e-2, 0.0, 8.87627564304205475450678981324e-2, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [2.41365134159266685502369798665e-1, 0.0, -8.84549479328286085344864962717e-1,
     9.24834003261792003115737966543e-1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.7037037037037037037037037037e-2, 0.0, 0.0, 1.70828608729473871279604482173e-1,
     1.25467687566822425016691814123e-1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.7109375e-2, 0.0, 0.0, 1.70252211019544039314978060272e-1, 6.02165389804559606850219397283e-2,
     -1.7578125e-2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.70920001185047927108779319836e-2, 0.0, 0.0, 1.70383925712239993810214054705e-1,
     1.07262030446373284651809199168e-1, -1.53194377486244017527936158236e-2,
     8.27378916381402288758473766002e-3, 0.0, 0.0, 0.0, 0.0, 0.0],
    [6.24110958716075717114429577812e-1, 0.0, 0.0, -3.36089262944694129406857109825,
     -8.68219346841726006818189891453e-1, 2.75920996994467083049415600797e1,
     2.01540675504778934086186788979e1, -4.34898841810699588477366255144e1, 0.0, 0.0, 0.0, 0.0],
    [4.77662536438264365890433908527e-1, 0.0, 0.0, -2.48811461997166764192642586468,
     -5.90290826836842996371446475743e-1, 2.12300514481811942347288949897e1,
     1.52792336328824235832596922938e1, -3.32882109689848629194453265587e1,
     -2.03312017085086261358222928593e-2, 0.0, 0.0, 0.0],
    [-9.3714243008598732571704021658e-1, 0.0, 0.0, 5.18637242884406370830023853209,
     1.09143734899672957818500254654, -8.14978701074692612513997267357,
     -1.85200656599969598641566180701e1, 2.27394870993505042818970056734e1,
     2.49360555267965238987089396762, -3.0467644718982195003823669022, 0.0, 0.0],
    [2.27331014751653820792359768449, 0.0, 0.0, -1.05344954667372501984066689879e1,
     -2.00087205822486249909675718444, -1.79589318631187989172765950534e1,
     2.79488845294199600508499808837e1, -2.85899827713502369474065508674,
     -8.87285693353062954433549289258, 1.23605671757943030647266201528e1,
     6.43392746015763530355970484046e-1, 0.0],
])
_DOP853_B = np.array([
    5.42937341165687622380535766363e-2, 0.0, 0.0, 0.0, 0.0, 4.45031289275240888144113950566,
    1.89151789931450038304281599044, -5.8012039600105847814672114227,
    3.1116436695781989440891606237e-1, -1.52160949662516078556178806805e-1,
    2.01365400804030348374776537501e-1, 4.47106157277725905176885569043e-2,
])
# E3 = B - BHH (Hairer's bhh1..bhh3): embedded 3rd-order error weights.
_DOP853_E3 = _DOP853_B - np.array([
    0.244094488188976377952755905512, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.733846688281611857341361741547, 0.0, 0.0, 0.220588235294117647058823529412e-1,
])
_DOP853_E5 = np.array([
    0.1312004499419488073250102996e-1, 0.0, 0.0, 0.0, 0.0, -0.1225156446376204440720569753e+1,
    -0.4957589496572501915214079952, 0.1664377182454986536961530415e+1,
    -0.3503288487499736816886487290, 0.3341791187130174790297318841,
    0.8192320648511571246570742613e-1, -0.2235530786388629525884427845e-1,
])

_DOP853 = _Tableau(c=_DOP853_C, a=_DOP853_A, b=_DOP853_B, e=_DOP853_E5, e3=_DOP853_E3,
                   fsal=False, err_order=7)

_METHODS = {"dop853": _DOP853, "dopri5": _DOPRI5, "rk4": _RK4}


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------

class IntegrationError(RuntimeError):
    """Integration could not continue. Attributes: ``t`` (float, s) and ``y`` (ndarray) where the
    failure was detected, ``reason`` (str). ``str(e)`` is one line:
    ``'integration failed at t=<t> s: <reason>'``."""

    def __init__(self, t: float, y: np.ndarray, reason: str):
        self.t = float(t)
        self.y = np.array(y, dtype=float, copy=True)
        self.reason = str(reason)
        super().__init__(f"integration failed at t={self.t:.15g} s: {self.reason}")

    def __reduce__(self):  # keep picklable (e.g. across multiprocessing) despite custom __init__
        return (type(self), (self.t, self.y, self.reason))


@dataclass(frozen=True)
class IntegratorStats:
    """Work counters of one :func:`integrate` call. ``n_rhs`` counts every rhs evaluation
    (including the two of the initial-step heuristic); ``n_projections`` includes y0."""
    n_rhs: int
    n_accepted: int
    n_rejected: int
    n_projections: int


def integrate(rhs: Callable[[float, np.ndarray], np.ndarray], y0, t_out, *, method: str = "dop853",
              rtol: float = 1e-10, atol: float = 1e-12, step: float = 1e-3, h_min: float = 1e-12,
              max_steps: int = 10_000_000,
              project: Callable[[float, np.ndarray], np.ndarray] | None = None):
    """Integrate dy/dt = rhs(t, y), y(t_out[0]) = y0, and return ``(Y, stats)``.

    ``Y`` has shape (len(t_out), len(y0)) with Y[k] = y(t_out[k]); Y[0] = y0 (projected if
    ``project`` is given). ``stats`` is an :class:`IntegratorStats`.

    method
        'dop853' (Dormand–Prince 8(5,3), adaptive, Hairer's error estimator), 'dopri5'
        (Dormand–Prince 5(4), adaptive, FSAL) or 'rk4' (classical, fixed step ``step``).
    rtol, atol
        Adaptive methods: a step is accepted when the RMS of e_i / (atol + rtol·max(|y_i|,
        |y_new_i|)) is < 1 (dop853: Hairer's 5th/3rd-order combination, see module docstring);
        step controller h_new = h·min(10, max(0.2, 0.9·err^(−1/(p̂+1)))), no growth right after a
        rejection. ``atol`` may be a scalar or an array of shape (n,).
    step
        Adaptive methods: MAXIMUM step size (may be ``np.inf``); the initial step is
        min(step, Hairer's starting-step estimate). rk4: nominal step; each interval
        [t_k, t_{k+1}] is split into ceil((t_{k+1} − t_k)/step − 1e-9) equal substeps.
    h_min
        Adaptive methods: an IntegrationError is raised when the controller's step size falls
        below max(h_min, 10 ulp(t)). Steps shortened only to land on an output time are exempt.
    max_steps
        Maximum number of step attempts (accepted + rejected) over the whole call.
    project
        ``project(t, y) -> y`` onto the constraint manifold: applied to y0 and after every
        accepted step (never inside RK stages). The derivative at the projected state is
        re-evaluated (for dopri5 the FSAL stage is discarded).

    Steps are clipped (or stretched by ≤ 1 % within ``step``) so they end exactly on every
    t_out[k]; after a step shortened for an output time, the controller's previous proposal is
    kept. ``rhs`` and ``project`` must not modify their ``y`` argument in place.

    Raises
    ------
    ValueError
        t_out not 1-D, empty, non-finite or not strictly increasing; bad y0/options; rhs or
        project returning an array of the wrong shape.
    IntegrationError
        'step size collapsed to … s' (h < h_min), 'non-finite derivative in component i'
        (rhs output; .t/.y are the arguments of that rhs call), 'non-finite state in component
        i' (step result or projection), 'maximum number of steps (N) exceeded'.
    Exceptions raised by ``rhs`` or ``project`` propagate unchanged.
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
