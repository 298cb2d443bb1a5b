"""Both engines are translation-invariant: a scene moved 100 km from the world origin gives the same
mass matrices, bias forces, Jacobians, constraint terms, accelerations and grasp/internal wrenches (all
expressed at points that move with the scene) as the scene at home, and integrates to the same
trajectory (lever arms from positions relative to the arm bases, not world positions). The
inverse side too: the closed-chain IK of a prescribed object motion, the inverse torques, grasp and
internal wrenches, grasp-line frames and the load capacities of every resolution.

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
from dataclasses import replace

import numpy as np
import pytest
import yaml

from coopsim.dynamics.closed_chain import chain_terms, forward_dynamics, position_residual
from coopsim.compiled import api
from coopsim.dynamics.grasp import grasp_matrix, internal_wrench
from coopsim.dynamics.kinematics import arm_pose
from coopsim.io.scenario import model_from_dict
from coopsim.forward.simulate import initial_state, simulate
from helpers import SCENARIOS, consistent_states, rel_err

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


# ------------------------------------------------------------------------------------------------
# The inverse side: closed-chain IK of a prescribed object motion, inverse dynamics, capacities
# ------------------------------------------------------------------------------------------------

def _trajectory(model):
    """The scenario's trajectory to invert: the IK of its object motion, else a 0.1 s forward run."""
    from coopsim.inverse.trajectory import from_simulation, object_motion_trajectory

    if model.inverse.trajectory == "object_motion":
        return object_motion_trajectory(model, model.inverse.object_motion)
    return from_simulation(simulate(replace(model, duration=0.1)))


def _inverse_numbers(model, traj, every: int):
    """Every number the inverse side reports that must not move with the scene: per resolution τ,
    grasp wrenches, both internal wrenches and their grasp-line components, the grasp-line frames; the
    closed-form capacities (scaled and payload) of the linear resolutions and the LP bound."""
    from coopsim.inverse import capacity as cap
    from coopsim.inverse.distributions import grasp_line_frames
    from coopsim.inverse.problem import inverse_problem
    from coopsim.inverse.resolutions import LINEAR_METHODS, METHODS
    from coopsim.inverse.solve import resolution_for, resolve
    from coopsim.inverse import solve
    from coopsim.inverse.stress import decompose_internal
    from coopsim.inverse.trajectory import JointTrajectory

    sub = JointTrajectory(traj.t[::every], traj.q[::every], traj.qd[::every], traj.qdd[::every], traj.source)
    P = inverse_problem(model, sub, np.array([0.1, 0.0, 0.0]))
    frames = grasp_line_frames(P)
    out = {"frames": frames, "grasp_offset": P.grasp_offset}
    base = resolution_for(model, "min_energy")
    bounds = solve.default_bounds(P, base)
    out["default_bounds"] = np.array(bounds)
    for k in METHODS:
        R = replace(base, method=k, force_bound=bounds[0], moment_bound=bounds[1])
        r = resolve(P, R)
        out.update({f"{k}.tau": r.tau, f"{k}.grasp_wrench": r.grasp_wrench, f"{k}.internal_paper": r.internal_paper,
                    f"{k}.internal_nonsqueezing": r.internal_nonsqueezing})
        for part, v in decompose_internal(r.internal_nonsqueezing, frames[:, :, 0]).items():
            out[f"{k}.{part}"] = v
        if k in LINEAR_METHODS:
            for mode in cap.MODES:
                c = cap.method_capacity(P, R, model.motors, mode)
                out[f"{k}.capacity.{mode}"] = np.array([c.mass, c.lower])
                out[f"{k}.capacity.{mode}.per_sample"] = c.per_sample
    out["lp.capacity"] = np.array([cap.lp_capacity(P, model.motors, model.motors.passive).mass])
    return out


def _finite_rel_err(a, b) -> float:
    """rel_err where both are finite; non-finite entries must agree exactly (an infinite capacity)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    fin = np.isfinite(a) & np.isfinite(b)
    if not np.array_equal(np.isfinite(a), np.isfinite(b)) or not np.array_equal(a[~fin], b[~fin]):
        return np.inf
    return rel_err(a[fin], b[fin]) if np.any(fin) else 0.0


def test_object_motion_ik_does_not_move_with_the_scene():
    """The closed-chain IK of the carry scenario's object motion (13 s, 651 samples) gives the same joint
    angles, rates and accelerations (<= 1e-12 relative; measured: identical, 0.0) when the whole scene,
    waypoints included, is moved by D: the pose error is formed from the end-effector and the target
    relative to the arm base (compiled `ik.pose_error`, `trajectory.pose_error`), the targets from the
    waypoints relative to the first one. Before (p_EE − p in world positions) they moved: θ 1.2e-11,
    θ̇ 3.5e-12, θ̈ 2.8e-12 (rel_err, measured with the previous code on this test)."""
    from coopsim.inverse.trajectory import object_motion_trajectory, pose_error

    home, far = home_and_far("paper_planar_2x3_carry")
    a, b = (object_motion_trajectory(m, m.inverse.object_motion) for m in (far, home))
    errs = {k: rel_err(getattr(a, k), getattr(b, k)) for k in ("q", "qd", "qdd")}
    assert all(v <= TOL for v in errs.values()), errs
    # the NumPy reference's pose error: the same for the same relative target, in either scene
    q = b.q[100, :3]
    for model in (home, far):
        arm = model.arms[0]
        assert np.max(np.abs(pose_error(arm, q, arm_pose(arm, q).p_ee_rel, np.eye(3))[:3])) == 0.0


@pytest.mark.parametrize("name,every", [("paper_planar_2x3_carry", 13), ("planar_3arm_vertical", 1),
                                        ("spatial_6r_pair", 1)])
def test_inverse_dynamics_and_capacities_do_not_move_with_the_scene(name, every):
    """Inverse torques, grasp and internal wrenches (both definitions, grasp-line components), the
    grasp-line frames, the default internal bounds, every resolution ('bounded' included) and the
    closed-form (scaled, payload) and LP capacities are the same (<= 1e-12 relative; measured: identical)
    for the scene moved by D. Before, the grasp-line frames came from world grasp points minus the world
    centre (p_grasp − p_C) and moved by 3.8e-11 (carry), 4.3e-11 (3-arm), 3.7e-11 (spatial), and the
    carry scene's IK trajectory moved its minimum-energy torques by 3.4e-12 (measured with the previous
    code)."""
    home, far = home_and_far(name)
    ta, tb = _trajectory(far), _trajectory(home)
    assert rel_err(ta.q, tb.q) <= TOL
    a, b = _inverse_numbers(far, ta, every), _inverse_numbers(home, tb, every)
    errs = {k: _finite_rel_err(a[k], b[k]) for k in b}
    bad = {k: f"{v:.2g}" for k, v in errs.items() if not v <= TOL}
    assert not bad, f"{name}: moved by {D.tolist()} m, relative changes above {TOL}: {bad}"
