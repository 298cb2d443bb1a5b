"""Stage 7 against MuJoCo: every resolution's torques and grasp wrenches, applied to MuJoCo's own model
of the arms, produce the prescribed motion, and the grasp wrenches move the object as prescribed.

Per bundled scenario, the panda carry (robots/) and a spatial three-arm scene (hard/) (the trajectory
each one inverts: its forward run, or for the carries the IK of their `inverse.object_motion`), per
resolution (paper, nonsqueezing, min_energy, bounded at half the minimum-energy peak), per engine (the
compiled passes and the NumPy reference) and at six samples:

* arms: MuJoCo's open arms (no object, no welds). `mj_inverse` at the sample's (q, q̇, q̈) gives
  M q̈ + c; the end-effector of arm m receives the reaction −F_e^m of the wrench it applies to the
  object (README: F_e^m = [f; n] at the EE point, world axes), mapped to joint space with MuJoCo's
  `mj_jacSite` at the EE site. So τ_m = (M q̈ + c)_m + J_mᵀ F_e^m must hold — equivalently, the
  torques τ with the reactions applied make MuJoCo's forward dynamics (`qfrc_applied`, `mj_forward`)
  return the prescribed q̈.
* object: MuJoCo's twin with the object on its carrier (the same joint angles) gives the object's
  centre of mass, orientation, mass, inertia, velocity and acceleration (`mj_jac`/`mj_jacDot` at its
  centre of mass, with the carrier's q̈); the grasp wrenches moved there plus gravity must equal
  [m a_C; I α + ω × I ω].

Planar scenes model only the in-plane rows (the bearings carry the rest): the object check is made in
the scene's rows S, the arm check needs nothing (their joints see only in-plane loads)."""

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from coopsim.inverse.problem import ENGINES, inverse_problem
from coopsim.inverse.resolutions import METHODS
from coopsim.inverse.solve import default_bounds, resolution_for, resolve
from coopsim.twin.mjcf import build_spec, dof_address, qpos_address, static_settings
from coopsim.inverse.trajectory import JointTrajectory
from inverse_cases import BUNDLED, run

SAMPLES = 6
TOL = 1e-9


class OpenArms:
    """MuJoCo's open arms (with_object=False: no object, no welds), or the arms with the object on its
    carrier and no welds (with_object=True), in coopsim's stacked joint order."""

    def __init__(self, model, with_object: bool):
        spec = build_spec(model, replace(static_settings(model), object_mass_scale=1.0), with_object=with_object)
        for eq in list(spec.equalities):
            spec.delete(eq)
        self.m = spec.compile()
        self.d = mujoco.MjData(self.m)
        self.qadr, self.dadr = qpos_address(self.m, model), dof_address(self.m, model)

    def set_motion(self, q, qd, qdd):
        """State and acceleration: kinematics and velocities by mj_forward, then q̈ set."""
        self.d.qpos[self.qadr], self.d.qvel[self.dadr] = q, qd
        mujoco.mj_forward(self.m, self.d)
        self.d.qacc[:] = 0.0
        self.d.qacc[self.dadr] = qdd

    def inverse(self) -> np.ndarray:
        """mj_inverse: M q̈ + c (coopsim's order); no constraint is active."""
        mujoco.mj_inverse(self.m, self.d)
        assert self.d.nefc == 0
        return self.d.qfrc_inverse[self.dadr].copy()

    def site_jacobian(self, name: str) -> np.ndarray:
        """J (6, n) = [J_p; J_r] of the site's point, coopsim's joint order."""
        jp, jr = np.zeros((3, self.m.nv)), np.zeros((3, self.m.nv))
        mujoco.mj_jacSite(self.m, self.d, jp, jr, self.m.site(name).id)
        return np.vstack([jp, jr])[:, self.dadr]

    def body_com_motion(self, name: str, qd, qdd):
        """(p_C, R_inertial, mass, principal inertia, v_C, ω, a_C, α) of a body at the set motion:
        J q̈ + J̇ q̇ at its centre of mass (mj_jac, mj_jacDot)."""
        b = self.m.body(name).id
        p = self.d.xipos[b].copy()
        jp, jr, dp, dr = (np.zeros((3, self.m.nv)) for _ in range(4))
        mujoco.mj_jac(self.m, self.d, jp, jr, p, b)
        mujoco.mj_jacDot(self.m, self.d, dp, dr, p, b)
        J, Jd = np.vstack([jp, jr])[:, self.dadr], np.vstack([dp, dr])[:, self.dadr]
        vel, acc = J @ qd, J @ qdd + Jd @ qd
        return (p, self.d.ximat[b].reshape(3, 3).copy(), float(self.m.body_mass[b]), self.m.body_inertia[b].copy(),
                vel[:3], vel[3:], acc[:3], acc[3:])


def _sampled_problem(name: str):
    """(model, InverseProblem at SAMPLES evenly spaced samples of the scenario's trajectory)."""
    m, _, traj = run(name)
    idx = np.linspace(0, len(traj.t) - 1, SAMPLES).round().astype(int)
    sub = JointTrajectory(traj.t[idx], traj.q[idx], traj.qd[idx], traj.qdd[idx], traj.source)
    return m, inverse_problem(m, sub)


def _resolutions(m, P, engine="compiled"):
    base = resolution_for(m, "min_energy")
    fb, mb = default_bounds(P, base, engine=engine)
    return {k: replace(base, method=k, force_bound=fb, moment_bound=mb) for k in METHODS}


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(1.0, np.max(np.abs(b))))


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", BUNDLED + ["robots/panda_ceiling_carry", "hard/spatial_3arm_mixed"])
def test_resolutions_move_mujocos_arms_and_object_as_prescribed(name, engine):
    """Every resolution, every sample: τ = mj_inverse(q, q̇, q̈) + Σ_m J_mᵀ F_e^m (<= 1e-9 relative),
    MuJoCo's forward dynamics of τ with the reactions −F_e^m applied returns q̈ (<= 1e-9 relative),
    and the object's Newton–Euler equations hold with MuJoCo's object motion (<= 1e-9 relative, in
    the scene's rows). Measured: torques 1e-14, q̈ 2e-12, object 1e-13; the same checks with the
    reaction's sign flipped, or the grasp wrenches not moved to C, fail by 0.5–5 and 0.07–0.7. The
    bounded resolution has at least one bound active (it differs from min_energy), so the QP path is
    what is checked. Both engines: the compiled passes and the NumPy reference."""
    m, P = _sampled_problem(name)
    arms, carried = OpenArms(m, with_object=False), OpenArms(m, with_object=True)
    S = m.rows
    worst = {"torque": 0.0, "qdd": 0.0, "object": 0.0}
    results = {k: resolve(P, res, engine) for k, res in _resolutions(m, P, engine).items()}
    assert not results["bounded"].failures
    assert np.max(np.abs(results["bounded"].tau - results["min_energy"].tau)) > 1e-6
    for i in range(len(P.t)):
        q, qd, qdd = P.q[i], P.qd[i], P.qdd[i]
        arms.set_motion(q, qd, qdd)
        Mqdd_c = arms.inverse()
        J = [arms.site_jacobian(f"a{a}_ee") for a in range(m.r)]
        p_ee = [arms.d.site_xpos[arms.m.site(f"a{a}_ee").id].copy() for a in range(m.r)]
        carried.set_motion(q, qd, qdd)
        p_C, R, mass, inertia, _, w, a_C, alpha = carried.body_com_motion("object", qd, qdd)
        I_w = R @ np.diag(inertia) @ R.T
        rhs = np.concatenate([mass * a_C, I_w @ alpha + np.cross(w, I_w @ w)])
        for k, r in results.items():
            F = r.grasp_wrench[i]                                        # (r, 6) applied by EE m to the object
            tau = Mqdd_c + sum(J[a].T @ F[a] for a in range(m.r))        # the reaction −F_e^m on EE m
            worst["torque"] = max(worst["torque"], _rel(r.tau[i], tau))
            # forward: τ and the reactions as applied forces, MuJoCo's own q̈
            d = arms.d
            d.qpos[arms.qadr], d.qvel[arms.dadr] = q, qd
            d.qfrc_applied[:] = 0.0
            d.qfrc_applied[arms.dadr] = r.tau[i] - sum(J[a].T @ F[a] for a in range(m.r))
            mujoco.mj_forward(arms.m, d)
            worst["qdd"] = max(worst["qdd"], _rel(d.qacc[arms.dadr], qdd))
            d.qfrc_applied[:] = 0.0
            # object: the grasp wrenches at C, plus gravity
            net = np.zeros(6)
            for a in range(m.r):
                net[:3] += F[a, :3]
                net[3:] += F[a, 3:] + np.cross(p_ee[a] - p_C, F[a, :3])
            net[:3] += mass * m.gravity
            worst["object"] = max(worst["object"], _rel(S @ net, S @ rhs))
    assert worst["torque"] <= TOL, worst
    assert worst["qdd"] <= TOL, worst
    assert worst["object"] <= TOL, worst
