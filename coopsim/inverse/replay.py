"""The torques of a resolved inverse study fed back through the forward model: the replay that checks
the inverse dynamics (the trajectory must come back), and the torques as a Python torque function.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from coopsim.core.model import Model, TorqueFunction, TorqueTable
from coopsim.core.results import output_times
from coopsim.forward.simulate import simulate
from coopsim.inverse.problem import InverseError, Resolution, SampleFailure, inverse_problem, torques_of
from coopsim.inverse.solve import distribute
from coopsim.inverse.trajectory import JointTrajectory, trajectory_at_times


@dataclass(frozen=True, eq=False)
class Replay:
    """Forward simulation driven by a resolution's torques, against the trajectory.

    When the resolution has no torques at some stage times (SampleFailure) nothing is simulated: sim
    None, errors nan, `failures` says where.

    Attributes:
        sim: the `coopsim.forward.simulate.SimResult` on the trajectory's sample times (relative to
            traj.t[0]), or None.
        max_angle_error: rad (m on a prismatic joint), max |θ_sim − θ_traj| over samples and joints; nan
            without a simulation.
        max_rate_error: rad/s (m/s), max |θ̇_sim − θ̇_traj| over samples and joints; nan without a
            simulation.
        failures: the SampleFailures of the stage times the resolution could not solve (indices into the
            stage times, times relative to traj.t[0]); empty when simulated.
    """

    sim: object
    max_angle_error: float
    max_rate_error: float
    failures: tuple = ()


def stage_torques(model: Model, traj: JointTrajectory, res: Resolution, t: np.ndarray,
                  failures: list | None = None, wrenches: Callable | None = None) -> np.ndarray:
    """τ of resolution `res` along `traj` at times t (relative to traj.t[0]).

    The trajectory's quintic Hermite interpolant at each t (`coopsim.inverse.trajectory.trajectory_at_times`,
    clamped to the sampled span), then the inverse dynamics of those states; nan where `res` has no
    solution.

    Args:
        model: the Model.
        traj: the JointTrajectory (N samples).
        res: the Resolution.
        t: (M,) s, the times, relative to traj.t[0].
        failures: a list the SampleFailures of the unsolved times are appended to (written; indices into
            t); None: not reported.
        wrenches: InverseProblem (M samples, t relative to traj.t[0]) ↦ its grasp wrenches (M, rk) in place of
            the distribution of `res` (the LP bound's, `coopsim.inverse.lp_replay.lp_distribution`); None: res's.

    Returns:
        np.ndarray: (M, n) N·m (N on a prismatic joint), the joint torques, stacked arm by arm.
    """
    q, qd, qdd = trajectory_at_times(traj, traj.t[0] + np.asarray(t, dtype=float))
    prob = inverse_problem(model, JointTrajectory(np.asarray(t, dtype=float), q, qd, qdd, traj.source))
    return torques_of(prob, distribute(prob, prob.y, res, failures) if wrenches is None else wrenches(prob))


def torque_function(model: Model, traj: JointTrajectory, res: Resolution) -> TorqueFunction:
    """τ(t) of resolution `res` along `traj` at any time t (relative to traj.t[0]), as a Python function.

    For the reference engine; `replay` tabulates it at the integrator's stage times instead.

    Args:
        model: the Model.
        traj: the JointTrajectory.
        res: the Resolution.

    Returns:
        TorqueFunction: t (s, relative to traj.t[0]) → τ (n,) N·m (N on a prismatic joint), by
        `stage_torques` at that one time (nan where `res` has no solution).
    """
    return TorqueFunction(lambda t: stage_torques(model, traj, res, np.array([t]))[0])


REPLAY_METHOD = "dop853"


def replay(model: Model, traj: JointTrajectory, res: Resolution, wrenches: Callable | None = None) -> Replay:
    """Simulate the closed chain from the trajectory's first state with the torques of `res`.

    Sampled at the trajectory's (uniform) sample times: DOP853 at fixed steps of one sample interval, the
    torques evaluated beforehand (in one batch) at exactly its stage times and tabulated there, so the
    compiled time loop meets every stage on a knot of the table. Nothing is simulated when `res` has no
    solution at some stage time.

    Args:
        model: the Model (its torques, controller and integrator method are replaced).
        traj: the JointTrajectory, at evenly spaced times.
        res: the Resolution.
        wrenches: the grasp wrenches in place of res's distribution (`stage_torques`); None: res's.

    Returns:
        Replay: the SimResult and its largest angle and rate errors against the trajectory, or the stage
        times that failed.

    Raises:
        InverseError: the trajectory's samples are not evenly spaced.
    """
    from coopsim.compiled.integrate import stage_times, tableau
    tr = traj.t - traj.t[0]
    dt = float(tr[1])
    t_out = output_times(float(tr[-1]), dt)
    if len(t_out) != len(tr) or not np.allclose(t_out, tr, rtol=0, atol=1e-9 * dt):
        raise InverseError("replay: the trajectory's samples are not evenly spaced")
    tab = tableau(REPLAY_METHOD)
    t_stage = np.unique(np.concatenate([stage_times(a, b, dt, tab.C, tab.stages)
                                        for a, b in zip(t_out[:-1], t_out[1:])]))
    failures: list[SampleFailure] = []
    tau = stage_torques(model, traj, res, t_stage, failures, wrenches)
    if failures:
        return Replay(None, np.nan, np.nan, tuple(failures))
    tables = tuple(TorqueTable(t_stage, tau[:, sl]) for sl in model.dof_slices)
    replay_model = replace(model, torques=tables, control=None, q0=traj.q[0], qd0=traj.qd[0], duration=float(tr[-1]),
                           integrator=replace(model.integrator, method=REPLAY_METHOD, output_dt=dt))
    sim = simulate(replay_model, fixed_step=dt)
    return Replay(sim, float(np.max(np.abs(sim.q - traj.q))), float(np.max(np.abs(sim.qd - traj.qd))))
