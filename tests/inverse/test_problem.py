"""The inverse problem along a trajectory (coopsim.inverse.problem): its per-sample terms shared."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from coopsim.inverse import problem as problem_module
from coopsim.inverse.problem import inverse_problem, shared_inverse_problem
from coopsim.inverse.trajectory import shared_object_motion_trajectory
from inverse_cases import model


def test_shared_terms_give_the_problem_bit_for_bit_and_a_heavier_object_its_own(monkeypatch):
    """Two payload positions and other motors share one set of terms, each problem equal to one built
    afresh to the last bit (and its own arrays); a heavier object (its net wrench changes) gets its own."""
    monkeypatch.setattr(problem_module, "_shared_terms", type(problem_module._shared_terms)())
    m = model("paper_planar_2x3_carry")
    traj = shared_object_motion_trajectory(m, m.inverse.object_motion)
    other = replace(m, motors=replace(m.motors, stall_torque=3 * m.motors.stall_torque))
    a = shared_inverse_problem(m, traj, np.array([0.1, 0.0, 0.0]))
    b = shared_inverse_problem(other, traj, np.array([-0.2, 0.0, 0.0]))
    fresh = inverse_problem(other, traj, np.array([-0.2, 0.0, 0.0]))
    assert len(problem_module._shared_terms) == 1 and a.R_o is not b.R_o
    for f in fields(fresh):
        x, y = getattr(b, f.name), getattr(fresh, f.name)
        assert np.array_equal(x, y) if isinstance(y, np.ndarray) else x == y, f.name
    heavy = replace(m, object=replace(m.object, mass=2 * m.object.mass, inertia=2 * m.object.inertia))
    c = shared_inverse_problem(heavy, traj)
    assert len(problem_module._shared_terms) == 2 and not np.allclose(c.y, a.y)
