"""The minimum energy's weights optimised with its time law (coopsim/inverse/retime_weights.py): the payload
never drops, the optimum is feasible by the inverse dynamics rerun from scratch with those weights, and the
problem along the law is the one the retiming constrains."""

import numpy as np
import pytest

from coopsim.core.model import torque_limits
from coopsim.inverse import capacity as cap
from coopsim.inverse import retime as rt
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.retime_weights import law_problem, weights_with_law, with_weights
from coopsim.inverse.solve import resolution_for, resolve
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS

INTERVALS = 12


@pytest.fixture(scope="module")
def carry():
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    path = WaypointPath.of(model.inverse.object_motion)
    s, piece = path_grid(path.knots, INTERVALS)
    jp = joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)
    return model, jp, weights_with_law(model, jp, 13.0, "payload", rounds=2)


def test_the_weights_carry_more_and_no_round_loses(carry):
    """The first round is the scenario's weights' retiming; each kept round carries more than the last;
    the weights are normalised (geometric mean 1) and positive; the minimum energy with them carries at
    least 10 % more than with equal weights (206 → 256 kg at 50 intervals; a regression pin, loose)."""
    model, jp, wl = carry
    plain, _, _ = rt.max_payload(rt.path_dynamics(model, jp, "min_energy", "payload"), 13.0)
    assert wl.rounds[0][1] == pytest.approx(plain, rel=1e-12)
    masses = [m for _, m in wl.rounds]
    assert all(b > a for a, b in zip(masses, masses[1:])) and wl.mass == masses[-1]
    assert wl.mass > 1.1 * plain
    assert np.all(wl.weights > 0) and np.exp(np.mean(np.log(wl.weights))) == pytest.approx(1.0, rel=1e-12)
    assert np.array_equal(wl.model.motors.energy_weight, wl.weights)


def test_the_optimum_meets_eq_36_by_the_inverse_dynamics_rerun_with_its_weights(carry):
    """At every grid point and both sides of it, the minimum-energy torques recomputed from scratch (a model
    carrying the payload, the resolution built with the optimised weights, the joint motion θ̇ = θ′√b,
    θ̈ = θ′a + θ″b) stay within eq. 36 up to 1e-9 τ_s, and some motor is on its line within 1e-6 τ_s (a
    heavier load would not fit)."""
    model, jp, wl = carry
    heavy = cap.payload_model(model, model.inverse.payload_position, wl.mass)
    prob = law_problem(heavy, jp, wl.retiming.law)
    tau = resolve(prob, resolution_for(model, "min_energy", weights=wl.weights)).tau
    lo, hi = torque_limits(model.motors, prob.qd)
    excess = np.maximum(tau - hi, lo - tau) / model.motors.stall_torque
    assert np.max(excess) <= 1e-9
    assert np.max(excess) >= -1e-6


def test_the_law_problem_is_the_joint_motion_at_both_sides_of_each_point(carry):
    """law_problem's samples: each point twice, the 'before' side with the previous interval's s̈, the 'after'
    side with its own; equal to the inverse problem of `JointPath.states` side by side (bit for bit: the same
    arithmetic)."""
    model, jp, wl = carry
    law = wl.retiming.law
    prob = law_problem(model, jp, law)
    after = inverse_problem(model, jp.states(law.a, law.b))
    before = inverse_problem(model, jp.states(np.append(0.0, law.a[:-1]), law.b))
    assert np.array_equal(prob.qdd[1::2], after.qdd) and np.array_equal(prob.qdd[0::2], before.qdd)
    assert np.array_equal(prob.qd[0::2], after.qd) and np.array_equal(prob.t[0::2], law.t)


def test_with_weights_changes_only_the_weights(carry):
    model, _, _ = carry
    w = np.arange(1.0, 7.0)
    m = with_weights(model, w)
    assert np.array_equal(m.motors.energy_weight, w)
    assert np.array_equal(m.motors.stall_torque, model.motors.stall_torque) and m.arms is model.arms
