"""Both engines are translation-invariant: a scene moved 100 km from the world origin gives the same
mass matrices, bias forces, Jacobians, constraint terms, accelerations and grasp/internal wrenches (all
expressed at points that move with the scene) as the scene at home, and integrates to the same
trajectory (issue #8: lever arms from positions relative to the arm bases, not world positions).

The two scenes must be the *same* scene in floating point: a base at 0.55 m becomes 99999.45 m, which
is rounded by up to 7e-12 m, and that change of the scene alone moves the accelerations of the spatial
pair by ~1e-10 relative. So every position the YAML gives (bases, object pose) is first put on the grid
of the far scene — x_home = fl(x + D) − D, exact — and the far scene is x_far = fl(x + D) = x_home + D
exactly. Measured after the fix: every quantity identical to the last bit (0.0) in both engines. Before
(lever arms from world positions), as `rel_err` here: loop-closure wrenches F 6.7e-10 (compiled),
grasp / internal wrenches 4.7e-10 / 5.7e-10, θ̈ 2.6e-10, object acceleration 2.5e-10, bias forces
8.7e-11, Λ 4.1e-11, mass matrices 2.2e-11; and the far 3-arm and spatial scenes could not be simulated
(the loop-closure residual, a difference of world positions, carried ~1e-11 m of rounding noise against
the 1e-12 projection tolerance).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from coopsim.closed_chain import chain_terms, forward_dynamics, position_residual
from coopsim.compiled import api
from coopsim.grasp import grasp_matrix, internal_wrench
from coopsim.scenario import model_from_dict
from coopsim.simulate import initial_state, simulate
from conftest import SCENARIOS, consistent_states, rel_err

D = np.array([1e5, -7e4, 3e4])
ALL = sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
TOL = 1e-12


def _moved(data: dict, shift) -> dict:
    """Scenario data with every world position (arm bases, object pose, object-motion waypoints)
    replaced by shift(position)."""
    data = copy.deepcopy(data)
    for arm in data["arms"]:
        base = arm.setdefault("base", {})
        base["position"] = shift(base.get("position", [0.0, 0.0, 0.0]))
    pose = data["object"].get("pose")
    if pose is not None:
        pose["position"] = shift(pose["position"])
    motion = (data.get("inverse") or {}).get("object_motion")
    for wp in (motion or {}).get("waypoints", []):
        wp["position"] = shift(wp["position"])
    return data


def home_and_far(name: str):
    """(home, far): the scenario on the far grid at home, and the same scene moved by D (exactly)."""
    data = yaml.safe_load((SCENARIOS / f"{name}.yaml").read_text())
    home = _moved(data, lambda p: ((np.asarray(p, float) + D) - D).tolist())
    far = _moved(data, lambda p: (np.asarray(p, float) + D).tolist())
    models = [model_from_dict(d, name, SCENARIOS, name) for d in (home, far)]
    bases = [np.array([a.base_pos for a in m.arms]) for m in models]
    assert np.array_equal(bases[1] - D, bases[0]), "the two scenes are not exact translates"
    return models


def _reference(model, q, qd, tau, q_off):
    T = chain_terms(model, q, qd)
    acc = forward_dynamics(model, T, tau)
    return {"M": T.M, "h": T.h, "J": np.hstack(T.J), "Jd_qd": T.Jd_qd, "J_o": T.J_o, "Jd_o_qd": T.Jd_o_qd,
            "Lam": T.Lam, "Lam_dot_qd": T.Lam_dot_qd, "s": T.s, "qdd": acc.qdd, "F_e": acc.F_e,
            "vd_o": acc.vd_o, "F_I": internal_wrench([grasp_matrix(s) for s in T.s], acc.F_e),
            "phi": position_residual(model, q_off)}


def _compiled(model, q, qd, tau, q_off):
    ev = api.forward(model, q, qd, tau)
    W = api.compiled(model).W
    out = {"qdd": ev.qdd, "F": ev.F, "Mb": W.Mb.copy(), "h": W.h.copy(), "J": W.J.copy(), "Jd_qd": W.Jd_qd.copy(),
           "J_o": W.J_o.copy(), "Lam": W.Lam.copy(), "Lam_dot_qd": W.Lam_dot_qd.copy()}
    S = api.evaluate_states(model, np.concatenate([q_off, qd])[None], tau[None], full=True)
    S0 = api.evaluate_states(model, np.concatenate([q, qd])[None], tau[None], full=True)
    out.update(grasp_wrench=S0.grasp_wrench[0], internal_wrench=S0.internal_wrench[0],
               object_acc=S0.object_acc[0], object_twist=S0.object_twist[0], residual_pos=S.residual_pos)
    return out, S0.object_pos[0]


@pytest.mark.parametrize("name", ALL)
def test_terms_accelerations_and_wrenches_do_not_move_with_the_scene(name):
    home, far = home_and_far(name)
    rng = np.random.default_rng(5)
    worst = {}
    for q, qd in consistent_states(home, 4, seed=6):
        tau = rng.normal(scale=2.0, size=home.n_total)
        q_off = q + rng.normal(scale=1e-3, size=home.n_total)       # off the loop: Φ ≠ 0
        for engine, fn in (("reference", _reference), ("compiled", lambda *a: _compiled(*a)[0])):
            a, b = fn(far, q, qd, tau, q_off), fn(home, q, qd, tau, q_off)
            for k in b:
                worst[engine, k] = max(worst.get((engine, k), 0.0), rel_err(a[k], b[k]))
        # the object's world position does move, by D (to the rounding of a world position at 100 km)
        p_far, p_home = _compiled(far, q, qd, tau, q_off)[1], _compiled(home, q, qd, tau, q_off)[1]
        assert np.max(np.abs(p_far - D - p_home)) <= 3e-11
    bad = {f"{e}.{k}": f"{v:.2g}" for (e, k), v in worst.items() if not v <= TOL}
    assert not bad, f"{name}: moved by {D.tolist()} m, relative changes above {TOL}: {bad}"


@pytest.mark.parametrize("name", ["planar_3arm_vertical", "spatial_6r_pair"])
def test_a_far_scene_projects_and_integrates_as_at_home(name):
    """Before the fix the far scenes failed here: the loop-closure projection (tolerance 1e-12) saw
    ~1e-11 m of rounding noise in Φ and did not converge (3-arm at t = 1.4 ms, spatial at 9.8 ms)."""
    home, far = home_and_far(name)
    for engine in ("compiled", "reference"):
        a, b = initial_state(home, engine), initial_state(far, engine)
        assert np.max(np.abs(b.q - a.q)) <= 1e-15 and b.residual_after <= 1e-12, engine
    ra, rb = simulate(home, 0.05), simulate(far, 0.05)
    assert np.max(np.abs(rb.q - ra.q)) <= 1e-13, f"{name}: trajectories differ by {np.max(np.abs(rb.q - ra.q)):.3g} rad"
    assert np.max(np.abs(rb.qd - ra.qd)) <= 1e-12
