"""Independent scenario check: every bundled scenario read by coopsim and, separately, by
`independent.pinocchio_scene` (PyYAML and the README's conventions only, built in Pinocchio, never
importing coopsim), compared quantity by quantity.

Tolerances: link and end-effector poses ≤ 1e-10 (m, and rotation-matrix entries); each arm's mass
matrix and bias forces (arms alone, and the carrier with the object) ≤ 1e-10 relative
(max |Δ| / max(1, max |reference|)); closed-chain accelerations and grasp wrenches at 10 random
consistent states (closed by Pinocchio-side Newton steps) ≤ 1e-9 relative (max |Δ| / max |reference|
over the state); 1 s of joint angles against scipy's DOP853 (rtol = atol = 1e-12) on
pinocchio.constraintDynamics ≤ 1e-9 rad. Both coopsim engines are compared where they expose the
quantity (reference stage modules; compiled workspace and samples).

Each check collects every violation with the quantity, scenario, arm and state it concerns; the
wrong-convention tests run the same checks against a builder switched to a wrong reading (rpy
composed Rx·Ry·Rz, quaternion read [x, y, z, w], box cross-section axes swapped, joint position
default at the frame origin) and require them to fail by a wide margin.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
import yaml

from coopsim.dynamics.closed_chain import chain_terms
from coopsim.compiled import api
from coopsim.dynamics.kinematics import arm_pose
from coopsim.core.model import torque_at
from coopsim.io.scenario import load_scenario
from coopsim.forward.simulate import forward, simulate
from helpers import SCENARIOS
from independent.pinocchio_scene import README, Conventions, PinocchioScene

FILES = sorted(SCENARIOS.glob("*.yaml"))
TOL_POSE = 1e-10           # m / rotation-matrix entries
TOL_DYN = 1e-10            # relative, max(1, |ref|)
TOL_CHAIN = 1e-9           # relative to the state's largest reference value
TOL_TRAJ = 1e-9            # rad
TOL_CLOSED = 1e-12         # loop-closure residual of a state called consistent (m, rad)
WIDE = 1e3                 # a wrong convention must miss its tolerance by at least this factor


class Report:
    """Largest error per quantity, and every violation as one line naming quantity, scenario, arm
    and state."""

    def __init__(self, scenario: str):
        self.scenario, self.worst, self.failures = scenario, {}, []

    def add(self, quantity: str, arm: str, state: str, err: float, tol: float):
        if err > self.worst.get(quantity, (-1.0,))[0]:
            self.worst[quantity] = (err, arm, state)
        if not err <= tol:
            self.failures.append(f"{quantity}: scenario {self.scenario}, arm {arm}, state {state}: "
                                 f"error {err:.3g} > {tol:g}")

    def max(self, quantity: str) -> float:
        return self.worst[quantity][0]

    def check(self):
        assert not self.failures, f"{len(self.failures)} violations:\n" + "\n".join(self.failures[:20])


def _abs(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def _rel1(a, b) -> float:
    return _abs(a, b) / max(1.0, float(np.max(np.abs(b))))


@lru_cache(maxsize=None)
def coopsim_model(path: Path):
    return load_scenario(path)


@lru_cache(maxsize=None)
def scene(path: Path, conventions: Conventions = README) -> PinocchioScene:
    return PinocchioScene(path, conventions)


def random_states(n: int, count: int, seed: int):
    rng = np.random.default_rng(seed)
    return [(f"random {k}", rng.uniform(-np.pi, np.pi, n), rng.normal(size=n)) for k in range(count)]


def consistent_states(S: PinocchioScene, count: int, seed: int, spread: float = 0.3):
    """`count` (label, q, qd, tau): the scenario's initial angles plus N(0, spread²) closed by the
    Pinocchio-side projection (residual ≤ TOL_CLOSED checked), N(0, 1) rates projected onto the
    velocity constraint, N(0, 1) torques."""
    rng = np.random.default_rng(seed)
    states = []
    for _ in range(20 * count):
        st = S.project(S.q0 + rng.normal(scale=spread, size=S.n), rng.normal(size=S.n))
        tau = rng.normal(size=S.n)
        if st is None:
            continue
        q, qd = st
        assert np.max(np.abs(S.closure_error(q))) <= TOL_CLOSED
        assert np.max(np.abs(S.closure_jacobian(q) @ qd)) <= TOL_CLOSED
        states.append((f"consistent {len(states)}", q, qd, tau))
        if len(states) == count:
            return states
    raise RuntimeError(f"{S.name}: could not draw {count} consistent states")


# ------------------------------------------------------------------------------------------ checks
def check_poses(model, S: PinocchioScene, states, report: Report):
    """Link frames (origin at the joint, orientation) and end-effector frames, both engines."""
    for label, q, qd in states:
        links, ees = S.link_poses(q), S.ee_poses(q)
        api.chain_terms(model, q, qd)
        W = api.compiled(model).W
        for m, (arm, sl) in enumerate(zip(model.arms, model.dof_slices)):
            P = arm_pose(arm, q[sl])
            p_ref = np.array([X.translation for X in links[m]])
            R_ref = np.array([X.rotation for X in links[m]])
            for engine, p, R, p_ee, R_ee in (("reference", P.p, P.R, P.p_ee, P.R_ee),
                                             ("compiled", W.p[sl], W.R[sl], W.p_ee[m], W.R_ee[m])):
                report.add(f"link position ({engine})", arm.name, label, _abs(p, p_ref), TOL_POSE)
                report.add(f"link rotation ({engine})", arm.name, label, _abs(R, R_ref), TOL_POSE)
                report.add(f"end-effector position ({engine})", arm.name, label, _abs(p_ee, ees[m].translation),
                           TOL_POSE)
                report.add(f"end-effector rotation ({engine})", arm.name, label, _abs(R_ee, ees[m].rotation),
                           TOL_POSE)


def check_arm_dynamics(model, S: PinocchioScene, states, report: Report):
    """Each arm's mass matrix and bias forces h (M θ̈ + h = τ): the arm alone, and in the closed chain's
    𝐈 and h (the object's inertia on the carrier), both engines."""
    for label, q, qd in states:
        M_open, h_open = S.arm_dynamics(q, qd)
        M_obj, h_obj = S.arm_dynamics(q, qd, with_object=True)
        T = chain_terms(model, q, qd)
        api.chain_terms(model, q, qd)
        W = api.compiled(model).W
        for m, (arm, sl) in enumerate(zip(model.arms, model.dof_slices)):
            n = arm.n
            for quantity, value, ref in (
                    ("mass matrix, arm alone (reference)", T.M_arms[m], M_open[m]),
                    ("bias forces, arm alone (reference)", T.h_arms[m], h_open[m]),
                    ("bias forces, arm alone (compiled)", W.h_arm[sl], h_open[m]),
                    ("mass matrix with object (reference)", T.M[sl, sl], M_obj[m]),
                    ("bias forces with object (reference)", T.h[sl], h_obj[m]),
                    ("mass matrix with object (compiled)", W.Mb[sl, :n], M_obj[m]),
                    ("bias forces with object (compiled)", W.h[sl], h_obj[m])):
                report.add(quantity, arm.name, label, _rel1(value, ref), TOL_DYN)


def reported_components(S: PinocchioScene, F: np.ndarray) -> np.ndarray:
    """The grasp-wrench components coopsim reports: all six in a spatial scene; in a planar one
    (normal n) the in-plane force and the moment about n, the rest zero (README: out-of-plane loads
    are carried by the bearings and not reported)."""
    if S.normal is None:
        return F
    n = S.normal
    f = F[:, :3] - np.outer(F[:, :3] @ n, n)
    return np.hstack([f, np.outer(F[:, 3:] @ n, n)])


def check_chain(model, S: PinocchioScene, states, report: Report):
    """Closed-chain accelerations and grasp wrenches at consistent states, both engines."""
    for label, q, qd, tau in states:
        qdd_ref, F_full = S.forward(q, qd, tau)
        F_ref = reported_components(S, F_full)
        acc_err, kkt_err = S.kkt_residual(q, qd, tau, qdd_ref)
        report.add("pinocchio solve (closure acceleration)", "all", label, acc_err / np.max(np.abs(qdd_ref)), TOL_CHAIN)
        report.add("pinocchio solve (equations of motion)", "all", label, kkt_err / max(1.0, np.max(np.abs(tau))),
                   TOL_CHAIN)
        if S.normal is not None:       # planar: every revolute axis stays along the normal, prismatic across it
            off = [abs(X.rotation @ link.axis @ S.normal) if link.prismatic else
                   np.linalg.norm(np.cross(X.rotation @ link.axis, S.normal))
                   for arm, Xs in zip(S.arms, S.link_poses(q)) for link, X in zip(arm.links, Xs)]
            report.add("planar scene: joint axes along the normal (prismatic: in the plane)", "all", label,
                       max(off), 1e-12)
        _, acc = forward(model, q, qd, tau)
        smp = api.evaluate_states(model, np.concatenate([q, qd])[None], tau[None], full=True, n_threads=1)
        qdd_scale, F_scale = np.max(np.abs(qdd_ref)), np.max(np.abs(F_ref))
        for m, (arm, sl) in enumerate(zip(model.arms, model.dof_slices)):
            for engine, qdd, F in (("reference", acc.qdd, acc.F_e), ("compiled", smp.qdd[0], smp.grasp_wrench[0])):
                report.add(f"closed-chain accelerations ({engine})", arm.name, label,
                           _abs(qdd[sl], qdd_ref[sl]) / qdd_scale, TOL_CHAIN)
                report.add(f"grasp wrench ({engine})", arm.name, label, _abs(F[m], F_ref[m]) / F_scale, TOL_CHAIN)


@lru_cache(maxsize=None)
def coopsim_run(path: Path, duration: float = 1.0):
    return simulate(replace(coopsim_model(path), duration=duration))


def check_trajectory(path: Path, S: PinocchioScene, report: Report, duration: float = 1.0):
    """coopsim's simulate (compiled engine, the scenario's integrator) against DOP853 on Pinocchio
    from coopsim's consistent initial state (its closure checked by Pinocchio first)."""
    res = coopsim_run(path, duration)
    q0, qd0 = res.initial.q, res.initial.qd
    report.add("initial state: loop closure (pinocchio)", "all", "t=0", float(np.max(np.abs(S.closure_error(q0)))),
               TOL_CLOSED)
    report.add("initial state: velocity constraint (pinocchio)", "all", "t=0",
               float(np.max(np.abs(S.closure_jacobian(q0) @ qd0))), TOL_CLOSED)
    mine = S.project(S.q0, S.qd0)
    for m, (arm, sl) in enumerate(zip(S.arms, S.slices)):
        # the scenario's initial state closed by either side's minimum-norm projection (the two
        # differ only by their error metric: second order in the correction, ≤ 3e-5 rad here)
        report.add("initial state: projected angles", arm.name, "t=0", _abs(q0[sl], mine[0][sl]), 1e-8)
        report.add("initial state: projected rates", arm.name, "t=0", _abs(qd0[sl], mine[1][sl]), 1e-8)
    Q, _ = S.trajectory(q0, qd0, res.t, rtol=1e-12, atol=1e-12)
    for m, (arm, sl) in enumerate(zip(S.arms, S.slices)):
        k = int(np.argmax(np.max(np.abs(res.q[:, sl] - Q[:, sl]), axis=1)))
        report.add("joint angles over 1 s", arm.name, f"t={res.t[k]:.2f} s", _abs(res.q[k, sl], Q[k, sl]), TOL_TRAJ)
    return res


def check_as_read(model, S: PinocchioScene, report: Report):
    """What both sides read directly: gravity, initial angles and rates, torques over the run."""
    report.add("gravity", "all", "-", _abs(model.gravity, S.gravity), 0.0)
    t = np.linspace(0.0, S.duration, 37)
    for m, (arm, sl) in enumerate(zip(model.arms, model.dof_slices)):
        report.add("initial angles", arm.name, "t=0", _abs(model.q0[sl], S.q0[sl]), 0.0)
        report.add("initial rates", arm.name, "t=0", _abs(model.qd0[sl], S.qd0[sl]), 0.0)
        report.add("torque table", arm.name, "t in [0, duration]",
                   max(_abs(torque_at(model.torques, ti)[sl], S.torque(ti)[sl]) for ti in t), 1e-14)


def full_report(path: Path, conventions: Conventions = README, states_from: PinocchioScene | None = None,
                trajectory: bool = True) -> Report:
    """Every check of one scenario file against the builder read with `conventions`; consistent
    states come from `states_from` (default: that builder)."""
    model, S = coopsim_model(path), scene(path, conventions)
    report = Report(model.name)
    check_as_read(model, S, report)
    open_states = [("initial", model.q0, model.qd0)] + random_states(S.n, 10, seed=8)
    check_poses(model, S, open_states, report)
    check_arm_dynamics(model, S, open_states, report)
    check_chain(model, S, consistent_states(states_from or S, 10, seed=9), report)
    if trajectory:
        check_trajectory(path, S, report)
    return report


# ------------------------------------------------------------------------------------------ tests
@pytest.fixture(scope="module", params=FILES, ids=lambda p: p.stem)
def scenario(request) -> Path:
    return request.param


def test_builder_reads_the_scene(scenario):
    """The builder's own sanity: joint order, the carrier the README names, the scene's plane."""
    model, S = coopsim_model(scenario), scene(scenario)
    assert S.n == model.n_total and S.r == model.r
    assert [a.name for a in S.arms] == [a.name for a in model.arms]
    data = yaml.safe_load(scenario.read_text())
    grasps = data["object"]["grasps"]
    first = 0 if grasps == "derive" else [a["name"] for a in data["arms"]].index(grasps[0]["arm"])
    assert S.carrier == first == model.object.carrier, f"carrier, scenario {model.name}"
    assert (S.normal is None) == (model.plane is None), f"planar or not, scenario {model.name}"
    if S.normal is not None:
        assert np.allclose(np.abs(S.normal @ model.plane[2]), 1.0, rtol=0, atol=1e-14)


def test_scenario_as_read(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_as_read(model, S, report)
    report.check()


def test_link_and_end_effector_poses(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_poses(model, S, [("initial", model.q0, model.qd0)] + random_states(S.n, 10, seed=8), report)
    report.check()


def test_arm_mass_matrices_and_bias_forces(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_arm_dynamics(model, S, [("initial", model.q0, model.qd0)] + random_states(S.n, 10, seed=8), report)
    report.check()


def test_closed_chain_accelerations_and_grasp_wrenches(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_chain(model, S, consistent_states(S, 10, seed=9), report)
    report.check()


def test_one_second_trajectory(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_trajectory(scenario, S, report)
    report.check()


# ------------------------------------------------------------------------- wrong conventions
SPATIAL = SCENARIOS / "spatial_6r_pair.yaml"
PAPER = SCENARIOS / "paper_planar_2x3.yaml"


def _fails_widely(report: Report, quantity: str, tol: float):
    assert report.failures, f"a wrong convention went unnoticed in {report.scenario}"
    assert report.max(quantity) > WIDE * tol, (
        f"{quantity}: a wrong convention misses by only {report.max(quantity):.3g} (tolerance {tol:g})")


def test_rpy_read_as_rx_ry_rz_is_caught():
    """spatial_6r_pair's object pose rpy [0.5708, 0, 0.0997] (grasps derived from it): composed as
    Rx·Ry·Rz it turns the bar's inertia, which the accelerations, wrenches and trajectory notice."""
    report = full_report(SPATIAL, Conventions(rpy_order="xyz"), states_from=scene(SPATIAL))
    _fails_widely(report, "closed-chain accelerations (compiled)", TOL_CHAIN)
    _fails_widely(report, "grasp wrench (compiled)", TOL_CHAIN)
    _fails_widely(report, "joint angles over 1 s", TOL_TRAJ)


def test_cross_section_axes_swapped_is_caught():
    report = Report("spatial_6r_pair")
    check_arm_dynamics(coopsim_model(SPATIAL), scene(SPATIAL, Conventions(cross_section="zy")),
                       random_states(12, 10, seed=8), report)
    _fails_widely(report, "mass matrix, arm alone (reference)", TOL_DYN)


def test_joint_position_default_at_the_origin_is_caught():
    report = Report("paper_planar_2x3")
    check_poses(coopsim_model(PAPER), scene(PAPER, Conventions(joint_default="origin")),
                random_states(6, 10, seed=8), report)
    _fails_widely(report, "link position (reference)", TOL_POSE)
    _fails_widely(report, "end-effector position (compiled)", TOL_POSE)


def _variant(tmp_path: Path, base: Path, edit) -> Path:
    data = yaml.safe_load(base.read_text())
    edit(data)
    out = tmp_path / f"{base.stem}_variant.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def _with_quaternions(data):
    """spatial_6r_pair with its bases and one joint frame given as quaternions [w, x, y, z]."""
    left, right = data["arms"]
    left["base"] = {"position": left["base"]["position"], "quat": [0.0, 1.0, 0.0, 0.0]}     # π about x
    right["base"] = {"position": right["base"]["position"], "quat": [0.0, 0.0, 1.0, 0.0]}   # π about y
    c, s = np.cos(0.2), np.sin(0.2)
    left["links"][3]["joint"]["quat"] = [float(c), 0.0, float(0.6 * s), float(0.8 * s)]


def test_quaternions_are_read_wxyz(tmp_path):
    """A variant of spatial_6r_pair using `quat`: every check passes read as [w, x, y, z] and the
    poses fail read as [x, y, z, w]."""
    path = _variant(tmp_path, SPATIAL, _with_quaternions)
    full_report(path, trajectory=False).check()
    wrong = Report("spatial_6r_pair with quaternions")
    check_poses(coopsim_model(path), scene(path, Conventions(quat_order="xyzw")),
                random_states(12, 10, seed=8), wrong)
    _fails_widely(wrong, "link rotation (reference)", TOL_POSE)


def _other_keys(tmp_path: Path):
    """The paper scene rewritten with keys no bundled scenario uses: an `inertial` link (inertia as
    [Ixx, Iyy, Izz, Ixy, Ixz, Iyz], com off the axis), a box `size`, explicit `end_effector` frames
    (one turned), an explicit joint `position`, rates in deg/s, a csv torque, grasps listed
    carrier-last (so arm2 carries the object)."""
    def edit(data):
        a1, a2 = data["arms"]
        a1["links"][2] = {"joint": {"axis": [0, 0, 1], "position": [0.6, 0.0, 0.0]},
                          "inertial": {"mass": 0.7, "com": [0.03, 0.004, 0.0],
                                       "inertia": [2.0e-4, 6.0e-4, 7.0e-4, 1.0e-5, 0.0, 0.0]}}
        a1["end_effector"] = {"position": [0.05, 0.0, 0.0]}
        a1["initial"] = {"angles_deg": a1["initial"]["angles_deg"], "rates_deg": [6.0, -3.0, 2.0]}
        a1["torque"] = {"csv": "torque_arm1.csv"}
        a2["links"][1]["box"] = {"size": [0.6, 0.04, 0.05], "density": 7850}
        a2["end_effector"] = {"position": [0.05, 0.0, 0.0], "rpy_deg": [0, 0, 10]}
        data["object"]["grasps"] = [{"arm": "arm2", "position": [0.2, 0.0, 0.0], "rpy_deg": [0, 0, 190]},
                                    {"arm": "arm1", "position": [-0.2, 0.0, 0.0], "rpy_deg": [0, 0, 0]}]
    (tmp_path / "torque_arm1.csv").write_text("time,tau1,tau2,tau3\n0.0,0.5,-0.02,0.0\n0.4,0.3,0.05,-0.01\n"
                                              "1.0,0.6,0.0,0.01\n")
    return _variant(tmp_path, PAPER, edit)


def test_keys_the_bundled_scenarios_do_not_use(tmp_path):
    path = _other_keys(tmp_path)
    S = scene(path)
    assert S.carrier == 1 == coopsim_model(path).object.carrier
    full_report(path).check()
