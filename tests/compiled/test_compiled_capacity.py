"""Compiled minimum-energy capacity objective (`coopsim.compiled.capacity`) against the NumPy path it
replaces in `coopsim.inverse.capacity.optimise_weights`: `min_energy_solve` → `torques_of` → `mass_limits` →
`mass_interval`, at random weights on every bundled scenario that has motor lines."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from coopsim.core.model import torque_limits
from coopsim.inverse import capacity as cap
from coopsim.inverse.distributions import min_energy_setup
from coopsim.inverse.problem import InverseRankWarning, torques_of
from coopsim.inverse import distributions
from coopsim.compiled.capacity import min_energy_mass_interval
from inverse_cases import BUNDLED, model, problem

WITH_MOTORS = [n for n in BUNDLED if np.any(np.isfinite(model(n).motors.stall_torque))]


def _setup(name: str, mode: str = "scaled", duration: float | None = None):
    m, P = model(name), problem(name, duration)
    y0, y1 = cap.mass_line(P, mode)
    setup = min_energy_setup(P, np.stack([y0, y0 + y1]), m.motors.passive)
    lo, hi = torque_limits(m.motors, P.qd)
    return m, P, setup, lo, hi


def _numpy_interval(P, setup, w, lo, hi, act):
    f0, f1 = distributions.min_energy_solve(P, setup, w)
    a = torques_of(P, f0)
    b = torques_of(P, f1) - a
    return cap.mass_interval(*cap.mass_limits(a[:, act], b[:, act], lo[:, act], hi[:, act]))


@pytest.mark.parametrize("mode", cap.MODES)
@pytest.mark.parametrize("name", WITH_MOTORS)
def test_compiled_interval_equals_the_numpy_path(name, mode):
    """Mass and lower limit agree to 1e-11 relative at 6 random weight vectors (log-uniform over four
    decades) wherever the kernel certifies every sample; feasibility is the same."""
    m, P, setup, lo, hi = _setup(name, mode)
    act = ~m.motors.passive
    rng = np.random.default_rng(7)
    for _ in range(6):
        w = np.where(act, 10.0 ** rng.uniform(-2, 2, len(act)), 0.0)
        mass, lower, certain = min_energy_mass_interval(setup.D, setup.u, w, lo, hi, act, setup.regular,
                                                        P.rank_tol)
        assert certain, name
        ref_mass, ref_lower, ref_ok = _numpy_interval(P, setup, w, lo, hi, act)
        assert mass == pytest.approx(ref_mass, rel=1e-11, abs=1e-12), (name, mode, w)
        assert lower == pytest.approx(ref_lower, rel=1e-11, abs=1e-12), (name, mode, w)
        assert ((lower <= mass) if np.isfinite(mass) else mass > 0) == ref_ok


def test_uncertified_samples_take_the_numpy_path():
    """With rank_tol 0.5 no energy Hessian passes the kernel's certificate: it says uncertain, and
    `capacity.min_energy_interval` gives the NumPy path's interval (there the minimum-norm solution at
    every sample; 0.2 s of the paper run). With the scenario's rank_tol both give the same interval."""
    m, P, setup, lo, hi = _setup("paper_planar_2x3", duration=0.2)
    act = ~m.motors.passive
    w = np.linspace(0.5, 2.0, len(act))
    assert min_energy_mass_interval(setup.D, setup.u, w, lo, hi, act, setup.regular, P.rank_tol)[2]
    assert cap.min_energy_interval(P, setup, w, lo, hi, act) == pytest.approx(
        _numpy_interval(P, setup, w, lo, hi, act), rel=1e-11)
    strict = replace(P, rank_tol=0.5)
    assert not min_energy_mass_interval(setup.D, setup.u, w, lo, hi, act, setup.regular, 0.5)[2]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InverseRankWarning)
        got = cap.min_energy_interval(strict, setup, w, lo, hi, act)
        ref = _numpy_interval(strict, setup, w, lo, hi, act)
    assert got == ref and got[0] != pytest.approx(_numpy_interval(P, setup, w, lo, hi, act)[0], rel=1e-6)
