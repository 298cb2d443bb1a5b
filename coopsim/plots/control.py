"""Plots of a closed-loop run log (`coopsim.control.controller`): tracking error of both models and the native
internal force, from the /native/control, /mujoco/control and /native/internal_wrench topics
(`coopsim.io.log.control_series`). Drawn by `coopsim.plots.run.comparison_plots` when the log has a
controller."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from coopsim.io.mcap_codec import LogData
from coopsim.plots.figure import NATIVE, TWIN, arm_groups, finish_log_axis, log_plot, run_title

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FILES = ("tracking_error.png", "internal_force.png")


def _errors(ch: dict, groups) -> list[tuple[str, str, np.ndarray]]:
    """(label, unit, error (N,)) curves of one model's control channel: per arm the largest joint-angle
    error (joint_pd), or the object's position and orientation error (computed_torque)."""
    if "angle_error" in ch:
        return [(name, "rad", np.max(np.abs(ch["angle_error"][:, sl]), axis=1)) for name, sl in groups]
    return [("object position", "m", np.linalg.norm(ch["pose_error"][:, :3], axis=1)),
            ("object orientation", "rad", np.linalg.norm(ch["pose_error"][:, 3:], axis=1))]


def tracking_error_figure(log: LogData) -> Figure:
    """|reference − actual| of both closed loops on a log axis (native solid, MuJoCo twin dashed).

    Per arm the largest joint-angle error (joint_pd, rad), or the object's position (m) and orientation
    (rad) error (computed_torque).

    Args:
        log: a closed-loop run log (its /native/joint_state and /native/control series; /mujoco/control
            where the twin ran).

    Returns:
        Figure: the matplotlib figure.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    n = log.topics[NATIVE + "/joint_state"]["angle"].shape[1]
    groups = arm_groups(log, n)
    drawn = []
    for prefix, who, ls in ((NATIVE, "native", "-"), (TWIN, "MuJoCo", "--")):
        ch = log.topics.get(prefix + "/control")
        if ch is not None:
            drawn += [log_plot(ax, ch["t"], e, f"{who}: {label} ({unit})", ls=ls)
                      for label, unit, e in _errors(ch, groups)]
    ax.set_title(run_title(log, "Tracking error", twin=TWIN + "/control" in log.topics), fontsize=9)
    finish_log_axis(ax, any(drawn), "tracking error (rad or m)")
    return fig


def internal_force_figure(log: LogData) -> Figure:
    """|f_I^m| (N) of every grasp's internal force (the paper's eq. 7) along the native closed loop.

    Args:
        log: a closed-loop run log (its /native/internal_wrench series, wrench (N, r, 6) [f; n]).

    Returns:
        Figure: the matplotlib figure, one curve per grasp.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    d = log.topics[NATIVE + "/internal_wrench"]
    for m in range(d["wrench"].shape[1]):
        ax.plot(d["t"], np.linalg.norm(d["wrench"][:, m, :3], axis=1), label=f"grasp {m + 1}")
    ax.set_title(run_title(log, "Internal force |f_I| (native)"), fontsize=9)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force (N)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return fig


def control_jobs(log: LogData) -> list[tuple]:
    """The figure jobs of the closed-loop figures; none for a log without a controller.

    Args:
        log: a run log.

    Returns:
        list[tuple]: (figure function, args, file name) per figure (FILES), [] without /native/control.
    """
    if NATIVE + "/control" not in log.topics:
        return []
    return [(tracking_error_figure, (log,), FILES[0]), (internal_force_figure, (log,), FILES[1])]
