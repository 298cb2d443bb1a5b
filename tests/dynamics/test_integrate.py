"""Tests for coopsim.dynamics.integrate (explicit RK integrators with output-time landing and projection)."""

import math
import pickle
import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from coopsim.dynamics.integrate import IntegrationError, IntegratorStats, integrate


def oscillator(t, y):
    """y'' = -y as a first-order system; y(0) = [1, 0] gives [cos t, -sin t]."""
    return np.array([y[1], -y[0]])


def oscillator_exact(t):
    t = np.asarray(t)
    return np.stack([np.cos(t), -np.sin(t)], axis=-1)


def pendulum(t, y):
    """Damped pendulum θ'' = -(g/l) sin θ - c θ', large amplitude (strongly nonlinear)."""
    return np.array([y[1], -9.81 * np.sin(y[0]) - 0.1 * y[1]])


T10 = np.linspace(0.0, 10.0, 11)


# --- accuracy on the harmonic oscillator -----------------------------------------------------

def test_dop853_oscillator_accuracy():
    Y, stats = integrate(oscillator, [1.0, 0.0], T10, rtol=1e-12, atol=1e-12, step=np.inf)
    err = np.abs(Y - oscillator_exact(T10)).max()
    assert err <= 5e-12          # observed 1.4e-12 (spec bound 1e-10)
    assert stats.n_rejected == 0 and stats.n_accepted > 0


def test_dopri5_oscillator_accuracy():
    Y, _ = integrate(oscillator, [1.0, 0.0], T10, method="dopri5", rtol=1e-11, atol=1e-11,
                     step=np.inf)
    assert np.abs(Y - oscillator_exact(T10)).max() <= 1e-10   # observed 3.5e-11 (spec 1e-8)


def test_rk4_oscillator_accuracy_and_step_count():
    Y, stats = integrate(oscillator, [1.0, 0.0], T10, method="rk4", step=1e-3)
    # Truncation error ~ h^4 T / 120 ≈ 1e-13; observed 7.3e-14 (spec bound 1e-10).
    assert np.abs(Y - oscillator_exact(T10)).max() <= 2e-13
    assert stats.n_accepted == 10_000            # ceil(1 / 1e-3 - 1e-9) = 1000 per interval
    assert stats.n_rhs == 4 * 10_000
    assert stats.n_rejected == 0 and stats.n_projections == 0


def test_rk4_convergence_order():
    errs = []
    for h in (0.1, 0.05, 0.025):
        Y, _ = integrate(oscillator, [1.0, 0.0], T10, method="rk4", step=h)
        errs.append(np.abs(Y - oscillator_exact(T10)).max())
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    np.testing.assert_allclose(orders, 4.0, atol=0.2)    # observed 4.03, 4.02


@pytest.mark.parametrize("method", ["dop853", "dopri5"])
def test_adaptive_error_tracks_tolerance(method):
    tols = [1e-6, 1e-8, 1e-10, 1e-12]
    errs = []
    for tol in tols:
        Y, _ = integrate(oscillator, [1.0, 0.0], T10, method=method, rtol=tol, atol=tol,
                         step=np.inf)
        errs.append(np.abs(Y - oscillator_exact(T10)).max())
    assert all(e2 < e1 / 10 for e1, e2 in zip(errs, errs[1:]))   # observed factors 35..110
    ratios = np.array(errs) / np.array(tols)
    assert np.all((ratios > 0.1) & (ratios < 10.0))              # observed 0.6..3.8


def test_step_is_maximum_step_size():
    Y, stats = integrate(oscillator, [1.0, 0.0], [0.0, 1.0], rtol=1e-6, atol=1e-6, step=0.01)
    assert stats.n_accepted == 100       # 1 s at h_max = 0.01 s (tolerance alone allows ~1 step)
    assert np.abs(Y[-1] - oscillator_exact(1.0)).max() <= 1e-12


# --- agreement with SciPy's DOP853 ------------------------------------------------------------

def test_matches_scipy_dop853_step_for_step():
    """Same tableau, error norm, controller and initial step: with a single output interval the
    trajectories coincide up to rounding (observed difference 4e-14)."""
    y0 = [2.5, 0.0]
    sol = solve_ivp(pendulum, (0.0, 10.0), y0, method="DOP853", rtol=1e-10, atol=1e-10)
    Y, stats = integrate(pendulum, y0, [0.0, 10.0], rtol=1e-10, atol=1e-10, step=np.inf)
    assert np.abs(Y[-1] - sol.y[:, -1]).max() <= 1e-12
    assert abs(stats.n_accepted - (sol.t.size - 1)) <= 1    # observed equal (127)


def test_matches_scipy_dop853_at_output_times():
    y0 = [2.5, 0.0]
    T = np.linspace(0.0, 10.0, 41)
    sol = solve_ivp(pendulum, (0.0, 10.0), y0, method="DOP853", rtol=1e-10, atol=1e-10, t_eval=T)
    ref = solve_ivp(pendulum, (0.0, 10.0), y0, method="DOP853", rtol=1e-13, atol=1e-13, t_eval=T)
    Y, _ = integrate(pendulum, y0, T, rtol=1e-10, atol=1e-10, step=np.inf)
    assert np.abs(Y - sol.y.T).max() <= 5e-9     # observed 1.2e-9 (both carry ~1e-9 error)
    assert np.abs(Y - ref.y.T).max() <= 2e-9     # observed 3.0e-10


# --- the tableaux against SciPy's coefficients (scipy.integrate._ivp: RK45, dop853_coefficients) ---
# SciPy's arrays are an independent transcription of Dormand & Prince / Hairer's DOP853 Fortran code
# (private modules: a SciPy release that moves them fails these tests loudly, it does not skip them).

from scipy.integrate._ivp import dop853_coefficients as _d853  # noqa: E402
from scipy.integrate._ivp.rk import DOP853 as _SciDOP853, RK45 as _SciRK45  # noqa: E402

from coopsim.dynamics import integrate as _ref# noqa: E402
from coopsim.compiled import integrate as _cint
from coopsim.core import tableaux as _ctab# noqa: E402

TABLEAU_TOL = 1e-15  # absolute; every coefficient is O(1..500), measured differences are exactly 0


def _same(name, ours, scipy_value, tol=TABLEAU_TOL):
    ours, scipy_value = np.asarray(ours, dtype=float), np.asarray(scipy_value, dtype=float)
    assert ours.shape == scipy_value.shape, f"{name}: shape {ours.shape} vs SciPy's {scipy_value.shape}"
    diff = float(np.max(np.abs(ours - scipy_value))) if ours.size else 0.0
    assert diff <= tol, f"{name}: max |coopsim − SciPy| = {diff:.3g} > {tol:g}"


def test_reference_dopri5_tableau_is_scipys_rk45():
    """coopsim.dynamics.integrate's Dormand–Prince 5(4): A, B, C, E (FSAL stage included) and the error order
    equal SciPy's RK45 (A is stored 6x6 here, 6x5 in SciPy: the last column is the zero diagonal)."""
    t = _ref._DOPRI5
    _same("DOPRI5 A", t.a[:, :5], _SciRK45.A)
    assert np.all(t.a[:, 5] == 0.0), "DOPRI5 A: stage 6 feeds no stage"
    _same("DOPRI5 B", t.b, _SciRK45.B)
    _same("DOPRI5 C", t.c, _SciRK45.C)
    _same("DOPRI5 E", t.e, _SciRK45.E)
    assert (t.n_stages, t.err_order, t.fsal) == (_SciRK45.n_stages, _SciRK45.error_estimator_order, True), \
        f"DOPRI5 stages/error order {t.n_stages}/{t.err_order} vs SciPy {_SciRK45.n_stages}/{_SciRK45.error_estimator_order}"


def test_reference_dop853_tableau_is_scipys():
    """coopsim.dynamics.integrate's DOP853 step: A, B, C (12 stages), E3 and E5 (SciPy's 13th weight, that of
    f(t + h, y_new), is 0 and dropped here) equal SciPy's, and the error order is 7."""
    t = _ref._DOP853
    _same("DOP853 A", t.a, _SciDOP853.A)
    _same("DOP853 A (extended table)", t.a, _d853.A[:12, :12])
    _same("DOP853 B", t.b, _SciDOP853.B)
    _same("DOP853 C", t.c, _SciDOP853.C)
    _same("DOP853 E3", t.e3, _SciDOP853.E3[:12])
    _same("DOP853 E5", t.e, _SciDOP853.E5[:12])
    assert _SciDOP853.E3[12] == 0.0 and _SciDOP853.E5[12] == 0.0, "SciPy's FSAL-stage error weights are no longer 0"
    assert (t.n_stages, t.err_order) == (_SciDOP853.n_stages, _SciDOP853.error_estimator_order), \
        f"DOP853 stages/error order {t.n_stages}/{t.err_order}"


def test_compiled_tableau_arrays_are_scipys_including_dense_output():
    """coopsim.core.tableaux, as printed there: DOP853's full 16-stage A and C (stages 13–16 are
    the dense-output stages), B, E3, E5 and the dense-output matrix D (4, 16); DOPRI5's A, B, C, E and
    Shampine's dense-output polynomial P (7, 4)."""
    _same("compiled DOP853_A (16x16)", _ctab.DOP853_A, _d853.A)
    _same("compiled DOP853_C (16)", _ctab.DOP853_C, _d853.C)
    _same("compiled DOP853_B", _ctab.DOP853_B, _d853.B)
    _same("compiled DOP853_E3", _ctab.DOP853_E3, _d853.E3)
    _same("compiled DOP853_E5", _ctab.DOP853_E5, _d853.E5)
    _same("compiled DOP853_D (dense output)", _ctab.DOP853_D, _d853.D)
    _same("compiled DOPRI5_A", _ctab.DOPRI5_A, _SciRK45.A)
    _same("compiled DOPRI5_B", _ctab.DOPRI5_B, _SciRK45.B)
    _same("compiled DOPRI5_C", _ctab.DOPRI5_C, _SciRK45.C)
    _same("compiled DOPRI5_E", _ctab.DOPRI5_E, _SciRK45.E)
    _same("compiled DOPRI5_P (dense output)", _ctab.DOPRI5_P, _SciRK45.P)


@pytest.mark.parametrize("method", ["dop853", "dopri5"])
def test_compiled_kernel_tableau_is_scipys(method):
    """The padded arrays the compiled time loop actually runs with (compiled.integrate.tableau): every
    used slot equals SciPy's, every unused slot is 0."""
    tab = _cint.tableau(method)
    if method == "dop853":
        s, (A, B, C, E3, E5) = 12, (_d853.A, _d853.B, _d853.C, _d853.E3, _d853.E5)
        _same("kernel DOP853 D", tab.D, _d853.D)
        assert not np.any(tab.Pd), "kernel DOP853: Dormand–Prince dense output set"
    else:
        s, (A, B, C, E3, E5) = 6, (_SciRK45.A, _SciRK45.B, _SciRK45.C, np.zeros(0), _SciRK45.E)
        _same("kernel DOPRI5 P", tab.Pd, _SciRK45.P)
        assert not np.any(tab.D), "kernel DOPRI5: DOP853 dense output set"
    assert tab.stages == s, f"kernel {method}: {tab.stages} stages, SciPy {s}"
    for name, ours, ref in (("A", tab.A, A), ("B", tab.B, B), ("C", tab.C, C), ("E3", tab.E3, E3), ("E5", tab.E5, E5)):
        if ours.ndim == 2:
            _same(f"kernel {method} {name}", ours[:ref.shape[0], :ref.shape[1]], ref)
            rest = ours.copy()
            rest[:ref.shape[0], :ref.shape[1]] = 0.0
        else:
            _same(f"kernel {method} {name}", ours[:len(ref)], ref)
            rest = ours[len(ref):]
        assert not np.any(rest), f"kernel {method} {name}: nonzero entry outside SciPy's table"
    order = {"dop853": _SciDOP853, "dopri5": _SciRK45}[method].error_estimator_order
    assert tab.err_order == order, f"kernel {method}: error order {tab.err_order} vs SciPy {order}"


def test_dopri5_dense_output_ends_on_the_step():
    """Independent of SciPy: Shampine's dense output y(t + θh) = y + h Σ_j k_j Σ_m P[j, m] θ^(m+1) at
    θ = 1 is the step itself, Σ_m P[j, m] = b_j (b_7 = 0, the FSAL stage)."""
    P = _ctab.DOPRI5_P
    _same("DOPRI5 P row sums vs b", P.sum(axis=1), np.append(_ref._DOPRI5.b, 0.0), tol=4e-15)


@pytest.mark.parametrize("name", ["_DOP853", "_DOPRI5", "_RK4"])
def test_tableau_consistency(name):
    from coopsim.dynamics import integrate as m
    tab = getattr(m, name)
    assert abs(tab.b.sum() - 1.0) <= 1e-14                        # order-1 condition
    np.testing.assert_allclose(tab.a.sum(axis=1), tab.c, rtol=0, atol=1e-14)   # row sums = c
    assert np.all(np.triu(tab.a) == 0.0)                            # explicit


# --- exact landing on output times -------------------------------------------------------------

@pytest.mark.parametrize("method,kw,tol", [
    ("dop853", dict(rtol=1e-12, atol=1e-12, step=np.inf), 5e-12),
    ("dopri5", dict(rtol=1e-11, atol=1e-11, step=np.inf), 1e-10),
    ("rk4", dict(step=1e-3), 2e-13),     # observed 7.1e-14
])
def test_lands_exactly_on_irregular_output_times(method, kw, tol):
    T = np.array([0.0, 0.013, 0.1, 0.77, 0.7700001, 2.5, math.pi, 6.0001, 9.99])
    calls = []

    def rhs(t, y):
        calls.append(t)
        return oscillator(t, y)

    Y, _ = integrate(rhs, [1.0, 0.0], T, method=method, **kw)
    assert Y.shape == (T.size, 2)
    assert np.abs(Y - oscillator_exact(T)).max() <= tol
    assert max(calls) <= T[-1]                       # never steps past the last output
    assert set(T[:-1]) <= set(calls)                 # each step starts exactly on an output time


def test_single_output_time_returns_y0():
    y0 = np.array([1.0, 2.0])
    Y, stats = integrate(oscillator, y0, [3.0])
    np.testing.assert_array_equal(Y, [[1.0, 2.0]])
    assert stats == IntegratorStats(n_rhs=0, n_accepted=0, n_rejected=0, n_projections=0)


def test_y0_not_modified_and_returned_exactly():
    y0 = np.array([1.0, 0.0])
    Y, _ = integrate(oscillator, y0, [0.0, 1.0])
    np.testing.assert_array_equal(y0, [1.0, 0.0])
    np.testing.assert_array_equal(Y[0], y0)


# --- projection ---------------------------------------------------------------------------------

def drifting_rotation(t, y):
    """Rotation about the origin plus a radial drift off the unit circle."""
    return np.array([-y[1], y[0]]) + 0.05 * y


@pytest.mark.parametrize("method,kw,tol", [
    ("dop853", dict(rtol=1e-12, atol=1e-12, step=0.05), 1e-13),   # observed 1.5e-14
    ("dopri5", dict(rtol=1e-11, atol=1e-11, step=0.05), 5e-11),   # observed 8.8e-12
    ("rk4", dict(step=1e-2), 1e-9),                               # observed 5.1e-10
])
def test_projection_after_every_accepted_step(method, kw, tol):
    projected = []
    rhs_args = []

    def rhs(t, y):
        rhs_args.append((t, y.copy()))
        return drifting_rotation(t, y)

    def project(t, y):
        yp = y / np.linalg.norm(y)
        projected.append((t, yp.copy()))
        return yp

    T = np.array([0.0, 0.3, 1.7, 4.0, 2 * math.pi])
    Y, stats = integrate(rhs, [2.0, 0.0], T, method=method, project=project, **kw)
    np.testing.assert_array_equal(Y[0], [1.0, 0.0])                 # y0 projected
    assert stats.n_projections == stats.n_accepted + 1 == len(projected)
    times = np.array([t for t, _ in projected])
    assert np.all(np.diff(times) > 0) and times[-1] == T[-1]       # only accepted step ends
    assert np.abs(np.hypot(Y[:, 0], Y[:, 1]) - 1.0).max() <= 1e-14
    # Projected dynamics = pure rotation: y = [cos t, sin t].
    exact = np.stack([np.cos(T), np.sin(T)], axis=-1)
    assert np.abs(Y - exact).max() <= tol
    # Each new step starts from the projected state (FSAL derivative recomputed for dopri5).
    rhs_states = {(t, tuple(y)) for t, y in rhs_args}
    assert all((t, tuple(y)) in rhs_states for t, y in projected[:-1])


# --- failures ----------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["dop853", "dopri5"])
def test_blow_up_raises_step_size_collapse_near_singularity(method):
    # y' = y^2, y(0) = 1: y = 1/(1 - t) blows up at t = 1.
    with pytest.raises(IntegrationError) as info:
        integrate(lambda t, y: y * y, [1.0], [0.0, 2.0], method=method)
    e = info.value
    assert abs(e.t - 1.0) <= 1e-6                   # observed 1 - t ≈ 1e-11
    assert "step size collapsed" in e.reason
    # Last accepted state still follows y = 1/(1 - t); this close to the pole a time error of
    # 1e-13 s is already a 1 % relative error (observed 1.0 % dop853, 2.1 % dopri5).
    assert abs(e.y[0] * (1.0 - e.t) - 1.0) <= 0.05
    msg = str(e)
    assert "\n" not in msg
    assert re.fullmatch(r"integration failed at t=0\.9999\d* s: step size collapsed to \S+ s", msg)


def test_blow_up_rk4_raises_non_finite():
    with np.errstate(over="ignore"), pytest.raises(IntegrationError) as info:
        integrate(lambda t, y: y * y, [1.0], [0.0, 2.0], method="rk4", step=1e-2)
    assert "non-finite" in info.value.reason
    assert abs(info.value.t - 1.0) <= 0.05           # observed 1.02 (a stage time)


@pytest.mark.parametrize("method", ["dop853", "dopri5", "rk4"])
def test_nan_rhs_raises(method):
    def rhs(t, y):
        return np.array([y[1], np.nan if t > 0.5 else -y[0]])

    with pytest.raises(IntegrationError) as info:
        integrate(rhs, [1.0, 0.0], [0.0, 1.0], method=method, step=1e-2)
    e = info.value
    assert e.reason == "non-finite derivative in component 1"
    assert 0.5 < e.t <= 0.5 + 1e-2                  # the rhs call that returned NaN
    assert str(e).startswith(f"integration failed at t={e.t:.15g} s: non-finite derivative")


def test_max_steps_exceeded():
    with pytest.raises(IntegrationError, match=r"maximum number of steps \(5\) exceeded"):
        integrate(oscillator, [1.0, 0.0], [0.0, 1.0], step=0.01, max_steps=5)


def test_rhs_exception_propagates_unchanged():
    class Boom(Exception):
        pass

    def rhs(t, y):
        raise Boom("from rhs")

    with pytest.raises(Boom, match="from rhs"):
        integrate(rhs, [1.0], [0.0, 1.0])


def test_project_exception_propagates_unchanged():
    def project(t, y):
        raise KeyError("from project")

    with pytest.raises(KeyError):
        integrate(oscillator, [1.0, 0.0], [0.0, 1.0], project=project)


@pytest.mark.parametrize("t_out", [[0.0, 1.0, 1.0], [0.0, 2.0, 1.0], [1.0, 0.0]])
def test_non_increasing_t_out_rejected(t_out):
    with pytest.raises(ValueError, match="strictly increasing"):
        integrate(oscillator, [1.0, 0.0], t_out)


def test_unknown_method_rejected():
    with pytest.raises(ValueError, match="unknown method"):
        integrate(oscillator, [1.0, 0.0], [0.0, 1.0], method="euler")


def test_integration_error_attributes_and_pickle():
    e = IntegrationError(0.25, np.array([1.0, 2.0]), "something")
    assert str(e) == "integration failed at t=0.25 s: something"
    e2 = pickle.loads(pickle.dumps(e))
    assert (e2.t, e2.reason, str(e2)) == (e.t, e.reason, str(e))
    np.testing.assert_array_equal(e2.y, e.y)
    assert isinstance(e2, RuntimeError)
