"""Cached trajectories and inverse-dynamics problems shared by the inverse/capacity/stress tests
(plain functions with lru_cache: one forward run per scenario and test session)."""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from coopsim.inverse import capacity as cap
from coopsim.inverse.problem import inverse_problem
from coopsim.io.scenario import load_scenario
from coopsim.forward.simulate import simulate
from coopsim.core.model import ObjectMotion
from coopsim.core.spatial import axis_angle_to_rot
from coopsim.inverse.trajectory import from_simulation, object_motion_trajectory, object_pose_of
from helpers import SCENARIOS

BUNDLED = sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
PAYLOAD = np.array([0.2, 0.0, 0.0])      # on the paper bar's axis, at arm 2's grasp (object frame, m)


@lru_cache(maxsize=None)
def model(name: str):
    return load_scenario(SCENARIOS / f"{name}.yaml")


@lru_cache(maxsize=None)
def run(name: str, duration: float | None = None):
    """(model, SimResult or None, JointTrajectory) of a bundled scenario's trajectory to invert."""
    m = model(name)
    if m.inverse.trajectory == "object_motion":
        return m, None, object_motion_trajectory(m, m.inverse.object_motion)
    res = simulate(m if duration is None else replace(m, duration=duration))
    return m, res, from_simulation(res)


@lru_cache(maxsize=None)
def problem(name: str, duration: float | None = None, payload: bool = True):
    m, res, traj = run(name, duration)
    return inverse_problem(m, traj, PAYLOAD if payload else None)


def with_motors(model, res, traj):
    """Scenarios without motor data get motors for the test: stall torque 1.5 × the forward run's peak
    |τ| per joint (at least 1 N·m), no-load speed 3 × the peak |θ̇| (at least 1 rad/s)."""
    if np.all(np.isfinite(model.motors.stall_torque)):
        return model
    peak_tau = np.max(np.abs(res.tau), axis=0) if res is not None else np.ones(model.n_total)
    stall = np.maximum(1.5 * peak_tau, 1.0)
    speed = np.maximum(3 * np.max(np.abs(traj.qd), axis=0), 1.0)
    return replace(model, motors=replace(model.motors, stall_torque=stall, no_load_speed=speed))


def short_motion(m, scale: float = 0.25) -> ObjectMotion:
    """0.6 s, three waypoints from the object's initial pose: a few mm along the constrained linear rows
    and a few mrad about the constrained angular ones, 50 ms samples."""
    p, R = object_pose_of(m, m.q0)
    S = m.rows
    lin = scale * (S[:, :3].T @ np.array([0.02, -0.015, 0.01, 0.012, -0.01, 0.008])[:S.shape[0]])
    ang = S[:, 3:].T @ np.ones(S.shape[0])
    ax = ang / np.linalg.norm(ang)
    Rs = [R, R @ axis_angle_to_rot(ax, scale * 0.04), R @ axis_angle_to_rot(ax, -scale * 0.02)]
    return ObjectMotion(np.array([0.0, 0.3, 0.6]), np.array([p, p + lin, p - 0.5 * lin]), np.array(Rs), "quintic", 0.05)


def capacity_lps(name, mode, motors=True):
    """lp_capacity's per-sample LPs (max μ) of a bundled scene; motors from `with_motors` (or the
    scene's own: none on spatial_6r_pair, every row then left out)."""
    m, res, traj = run(name)
    m = with_motors(m, res, traj) if motors else m
    A_ub, b_ub, A_eq, b_eq = cap._lp_rows(problem(name), m.motors, m.motors.passive, mode, None, None, "nonsqueezing")
    c = np.zeros(A_ub.shape[2])
    c[-1] = -1.0
    return c, A_ub, b_ub, A_eq, b_eq, [(None, None)] * (len(c) - 1) + [(0, None)]
