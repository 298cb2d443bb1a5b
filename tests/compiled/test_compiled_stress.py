"""The compiled section loads (`coopsim.compiled.stress`, `coopsim.inverse.stress.section_loads`) against the
NumPy reference (engine 'reference') at every bundled scenario with a box object, the robot carry and two
hard scenes, with each linear resolution's grasp wrenches: every resultant and peak stress within 1e-13 of
its largest magnitude (the same products and sums, in another order and with fused multiply-adds; a few
terms each, measured ≤ 7e-16). The analytic cases of tests/inverse/test_stress.py run through the compiled
path."""

import numpy as np
import pytest

from coopsim.inverse.resolutions import LINEAR_METHODS
from coopsim.inverse.solve import resolution_for, resolve
from coopsim.inverse.stress import section_loads
from inverse_cases import BUNDLED, model, problem

CASES = [n for n in BUNDLED + ["robots/panda_ceiling_carry", "hard/passive_joints", "hard/spatial_3arm_mixed"]
         if np.any(model(n).object.box > 0)]
FIELDS = ("axial", "shear", "torsion", "bending", "peak_normal", "peak_shear")


def _loads(name, F, engine, cuts=81):
    m, P = model(name), problem(name)
    return section_loads(m.object.mass, m.object.box, m.object.grasp_pos, P.R_o, P.twist, P.acc, m.gravity, F,
                         m.rows, cuts, engine=engine)


@pytest.mark.parametrize("name", CASES)
def test_section_loads_equal_the_reference(name):
    m, P = model(name), problem(name)
    for method in LINEAR_METHODS:
        F = resolve(P, resolution_for(m, method)).grasp_wrench
        got, ref = _loads(name, F, "compiled"), _loads(name, F, "reference")
        assert got.axis == ref.axis and np.array_equal(got.xi, ref.xi)
        for f in FIELDS:
            a, b = getattr(got, f), getattr(ref, f)
            assert np.max(np.abs(a - b)) <= 1e-13 * max(np.max(np.abs(b)), 1e-300), (name, method, f)


def test_an_unsolved_sample_stays_nan():
    """A sample whose grasp wrenches are nan (a resolution could not solve it) has nan loads and peaks,
    as in the reference; the other samples are unaffected."""
    name = "paper_planar_2x3_carry"
    m, P = model(name), problem(name)
    F = resolve(P, resolution_for(m, "paper")).grasp_wrench.copy()
    F[5] = np.nan
    got, ref = _loads(name, F, "compiled", 9), _loads(name, F, "reference", 9)
    for f in FIELDS:
        a, b = getattr(got, f), getattr(ref, f)
        assert np.all(np.isnan(a[5])) and np.all(np.isnan(b[5]))
        a, b = np.delete(a, 5, axis=0), np.delete(b, 5, axis=0)
        assert np.max(np.abs(a - b)) <= 1e-13 * max(np.max(np.abs(b)), 1e-300), f
