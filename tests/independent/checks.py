"""coopsim's quantities against the Pinocchio build of the same scenario file (`pinocchio_scene`),
quantity by quantity: link and end-effector poses, arm mass matrices and bias forces, closed-chain
accelerations and grasp wrenches, a trajectory. Used by tests/cross/test_independent.py (every bundled
scene) and tests/io/test_robots.py (robot files).
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from pathlib import Path

import numpy as np
from helpers import SCENARIOS

from coopsim.compiled import api
from coopsim.core.model import torque_at
from coopsim.dynamics.closed_chain import chain_terms
from coopsim.dynamics.kinematics import arm_pose
from coopsim.forward.simulate import forward, simulate
from coopsim.io.scenario import load_scenario
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
