"""The compiled reachability pass (`coopsim.compiled.reachability`, `coopsim.inverse.retime.reachability`)
against its NumPy reference (`coopsim.inverse.retime.reachability_reference`) on the paper carry: the rows
linearised at a minimum-time law, without and with check points' rows between the grid points (ragged
stages), and a load the motors cannot carry (both infeasible). Both compute the same vertices, chords and
clipped steps by the same formulas; the kernel contracts a·b + c into fused multiply-adds and takes minima in
another order, and the forward pass sums its steps b_{i+1} = b_i + 2Δa over the stages, so ṡ² agrees to
1e-12 of its peak (measured ≤ 2e-16)."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.inverse import retime as rt
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS

REL = 1e-12


@pytest.fixture(scope="module")
def carry():
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    path = WaypointPath.of(model.inverse.object_motion)
    s, piece = path_grid(path.knots, 8)
    return model, joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)


@pytest.mark.parametrize("method, mass", [("paper", 30.0), ("min_energy", 180.0)])
def test_the_compiled_pass_is_the_reference_with_and_without_check_points(carry, method, mass):
    model, jp = carry
    dyn = rt.path_dynamics(model, jp, method, "payload")
    r = rt.retime(dyn, mass, "grid_lp")
    b = r.law.b
    lam = rt._tangent(b, b.max())
    fp = dyn.fine_points()
    sub = fp.subset(np.arange(0, len(fp.sigma), 4))              # check points on most intervals, ragged stages
    k = rt._stages(jp.s, jp.points.piece)[sub.stage]
    extra = (sub, rt._tangent((1 - sub.sigma) * b[k] + sub.sigma * b[k + 1], b.max()))
    for more in (None, extra):
        got, ref = rt.reachability(dyn, mass, lam, more), rt.reachability_reference(dyn, mass, lam, more)
        assert got is not None and ref is not None
        assert np.max(np.abs(got - ref)) <= REL * np.max(ref)


def test_a_load_the_motors_cannot_carry_is_infeasible_in_both(carry):
    """A constant load of twice the stall torques on every motor (the plane's gravity costs none)."""
    model, jp = carry
    dyn = rt.path_dynamics(model, jp, "min_energy", "payload", fine=None)
    weak = replace(dyn, tau=dyn.tau.copy())
    weak.tau[0, 0] += 2.0 * dyn.stall
    lam = (np.zeros(len(jp.s)), np.zeros(len(jp.s)))
    assert rt.reachability(weak, 0.0, lam) is None and rt.reachability_reference(weak, 0.0, lam) is None
