"""Comparison plots of a run log (native model vs MuJoCo twin), PNG via matplotlib's Agg canvas.

Every function takes a :class:`coopsim.io.mcap_codec.LogData` (from :func:`coopsim.io.mcap_codec.read_mcap`), so a fresh
run and a stored log are plotted by the same code. Topics used: /native/joint_state, /native/object,
/native/constraint and, when present, their /mujoco counterparts (without them only the native model
is drawn). Arms and joint names come from the log's "model" metadata record when it is there.
Differences |native − mujoco| are drawn on log axes (exact zeros are left out: a log axis cannot show
them); when the twin is sampled at other times it is interpolated linearly onto the native times.
Revolute joints' angles are drawn unwrapped (continuous in time; a prismatic joint's coordinate, m, as
it is), the object's orientation as the rotation vector from its initial orientation. Legends stand
outside the panels, right of them (`panel_grid`, `legend_beside`), so no legend covers a curve whatever
the number of joints.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coopsim.core.joints import COORDINATE, RATE, units_of
from coopsim.core.labels import metadata_joint_labels, metadata_joint_types
from coopsim.core.spatial import orientation_error, quat_to_rot, rotation_from
from coopsim.io.mcap_codec import LogData
from coopsim.plots.control import control_jobs
from coopsim.plots.figure import (
    NATIVE,
    TWIN,
    arm_groups,
    finish_log_axis,
    legend_beside,
    legend_width,
    log_plot,
    panel_grid,
    run_title,
)
from coopsim.plots.render import FigureWorkers, render_figures

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FILES = ("joint_angles.png", "joint_rates.png", "object_motion.png", "constraint_violation.png")
_AXES = ("x", "y", "z")
PANEL, OBJECT_PANEL = (4.6, 2.7), (3.6, 2.7)   # inches: a joint panel, an object panel


def _joint_labels(log: LogData, n: int, joint_names: list[str] | None) -> list[str]:
    if joint_names is not None:
        if len(joint_names) != n:
            raise ValueError(f"joint_names: expected {n} names, got {len(joint_names)}")
        return list(joint_names)
    return metadata_joint_labels(log.metadata, n)


def _aligned(t: np.ndarray, t_other: np.ndarray, x_other: np.ndarray) -> np.ndarray:
    """x_other (M, ...) sampled at t_other, at the times t (N,) (exact when the times agree)."""
    if np.array_equal(t, t_other):
        return x_other
    flat = x_other.reshape(len(t_other), -1)
    cols = [np.interp(t, t_other, c) for c in flat.T]
    return np.stack(cols, axis=-1).reshape((len(t),) + x_other.shape[1:])


def _twin(log: LogData, topic: str, key: str, t: np.ndarray) -> np.ndarray | None:
    """The twin's field on the native times, or None when the log has no twin topic."""
    d = log.topics.get(TWIN + topic)
    return None if d is None else _aligned(t, d["t"], d[key])


STYLES = ("native model", "MuJoCo twin")   # the legend entries of the line styles (solid, dashed)


def _style_handles(twin: bool) -> list:
    """Legend handles of the line styles: native solid, twin dashed (`twin`: the twin is drawn)."""
    from matplotlib.lines import Line2D

    return [Line2D([], [], color="0.3", ls=ls, label=label) for ls, label in zip(("-", "--"), STYLES[:1 + twin])]


def _compare_columns(axes, t: np.ndarray, x: np.ndarray, y: np.ndarray | None, labels: list[str], ylabel: str,
                     title: str, diff_ylabel: str, diff_title: str, diff: np.ndarray | None = None) -> list:
    """The columns of x (N, k) (native, solid) and y (twin, dashed; None: no twin) on axes[0], coloured
    C0, C1, … in the order of `labels` (k,); with the twin, `diff` (N, k') on a log axis on axes[1]
    (default |x − y|, in the same colours; a single column in black). Returns the legend handles: one
    line per label, then the line styles."""
    ax = axes[0]
    handles = []
    for j, label in enumerate(labels):
        handles += ax.plot(t, x[:, j], color=f"C{j % 10}", label=label)
        if y is not None:
            ax.plot(t, y[:, j], "--", color=f"C{j % 10}", label=f"{label} (MuJoCo)")
    ax.set(title=title, xlabel="time (s)", ylabel=ylabel)
    ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 4))   # short tick labels (an offset 1e-4 above)
    ax.grid(True, alpha=0.3)
    if y is not None:
        d = np.abs(x - y) if diff is None else diff
        colors = [f"C{j % 10}" for j in range(d.shape[1])] if d.shape[1] > 1 else ["black"]
        drawn = [log_plot(axes[1], t, d[:, j], labels[j] if diff is None else diff_ylabel, color=c)
                 for j, c in enumerate(colors)]
        axes[1].set_title(diff_title)
        finish_log_axis(axes[1], any(drawn), diff_ylabel)
    return handles + _style_handles(y is not None)


def _unwrap_revolute(x: np.ndarray | None, types: list[str]) -> np.ndarray | None:
    """x (N, n) joint coordinates with the columns of the revolute joints unwrapped along time (no 2π
    jump where an angle passes ±π); a prismatic joint's coordinate (m) is left as it is. None → None."""
    if x is None:
        return None
    rev = np.array([ty == "revolute" for ty in types], dtype=bool)
    out = np.array(x, dtype=np.float64)
    out[:, rev] = np.unwrap(out[:, rev], axis=0)
    return out


def _joint_figure(log: LogData, key: str, quantity: str, kind: int, labels: list[str]) -> Figure:
    """One column per arm: its joints' `key` series (native and twin) and, with the twin, their
    difference; the legend of each arm beside its column. kind (`joints.COORDINATE`, `RATE`) picks each
    column's unit from its joints' types (rad, m, or rad or m). Revolute joints' angles are drawn
    unwrapped (continuous in time: no 2π jump where a joint passes ±π), as the axis label says;
    prismatic joints' coordinates (m) are drawn as they are."""
    from matplotlib.figure import Figure

    nat = log.topics[NATIVE + "/joint_state"]
    t, x = nat["t"], nat[key]
    y = _twin(log, "/joint_state", key, t)
    types = metadata_joint_types(log.metadata, x.shape[1])
    if key == "angle":
        x, y = _unwrap_revolute(x, types), _unwrap_revolute(y, types)
    groups = arm_groups(log, x.shape[1])
    styles = list(STYLES[:1 + (y is not None)])
    fig = Figure()
    axes = panel_grid(fig, 1 if y is None else 2, len(groups), PANEL,
                      legend=max(legend_width(labels[sl] + styles) for _, sl in groups),
                      legend_after=range(len(groups)))
    for col, (arm, sl) in enumerate(groups):
        unit = units_of(types[sl], kind)
        unwrapped = ", unwrapped" if key == "angle" and "revolute" in types[sl] else ""
        handles = _compare_columns(axes[:, col], t, x[:, sl], None if y is None else y[:, sl], labels[sl],
                                   f"{quantity} ({unit}{unwrapped})", f"{arm}: joint {quantity}",
                                   f"|Δ {quantity}| ({unit})", f"{arm}: |native − MuJoCo|")
        legend_beside(axes[0, col], handles)
    fig.suptitle(run_title(log, f"Joint {quantity}" + ("" if y is None else ": native model vs MuJoCo twin"),
                           twin=y is not None))
    return fig


def _object_figure(log: LogData) -> Figure:
    """Columns: the object's centre-of-mass position, its orientation (the rotation vector from its
    initial orientation, world axes; with the twin, the angle between the two models' orientations)
    and its centre-of-mass velocity; one legend beside the last column."""
    from matplotlib.figure import Figure


    nat = log.topics[NATIVE + "/object"]
    t = nat["t"]
    pos, twist, quat = (_twin(log, "/object", k, t) for k in ("position", "twist", "quaternion"))
    R0 = quat_to_rot(nat["quaternion"][0])
    if quat is not None:   # a twin sampled at other times is interpolated componentwise: back to unit length
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    parts = [(nat["position"], pos, "position (m)", "Object centre-of-mass position", "|Δ position| (m)", None),
             (rotation_from(nat["quaternion"], R0), None if quat is None else rotation_from(quat, R0),
              "rotation from t = 0, φ (rad)", "Object orientation (rotation vector)",
              "angle between the orientations (rad)",
              None if quat is None else orientation_error(nat["quaternion"], quat)[:, None]),
             (nat["twist"][:, :3], None if twist is None else twist[:, :3], "velocity (m/s)",
              "Object centre-of-mass velocity", "|Δ velocity| (m/s)", None)]
    labels = [f"{c} component (world)" for c in _AXES]
    fig = Figure()
    axes = panel_grid(fig, 1 if pos is None else 2, len(parts), OBJECT_PANEL,
                      legend=legend_width(labels + list(STYLES[:1 + (pos is not None)])))
    for col, (x, y, ylabel, title, diff_ylabel, diff) in enumerate(parts):
        handles = _compare_columns(axes[:, col], t, x, y, labels, ylabel, title, diff_ylabel,
                                   title.replace("Object ", "") + ": native − MuJoCo", diff)
    legend_beside(axes[0, -1], handles)
    fig.suptitle(run_title(log, "Object motion" + ("" if pos is None else ": native model vs MuJoCo twin"),
                           twin=pos is not None))
    return fig


def _constraint_figure(log: LogData) -> Figure:
    from matplotlib.figure import Figure

    nat = log.topics[NATIVE + "/constraint"]
    twin = log.topics.get(TWIN + "/constraint")
    labels = ["native loop-closure residual max |Φ|"] + (["MuJoCo weld violation"] if twin is not None else [])
    fig = Figure()
    ax = panel_grid(fig, 1, 1, (6.0, 3.0), legend=legend_width(labels), suptitle=False)[0, 0]
    drawn = [log_plot(ax, nat["t"], nat["residual_pos"], labels[0])]
    if twin is not None:
        drawn.append(log_plot(ax, twin["t"], np.abs(twin["weld_violation"]), labels[1], ls="--"))
    ax.set_title(run_title(log, "Constraint violation", twin=twin is not None), fontsize=9)
    finish_log_axis(ax, any(drawn), "violation (m or rad)")
    if any(drawn):
        legend_beside(ax)
    return fig


def comparison_jobs(log: LogData, out_dir: str | Path, joint_names: list[str] | None = None) -> list[tuple]:
    """The figures of `comparison_plots` as `coopsim.plots.render` jobs.

    A closed loop's log adds `coopsim.plots.control`'s tracking_error.png and internal_force.png.

    Args:
        log: the run log (`LogData`).
        out_dir: the folder the figures are to be written into.
        joint_names: (n,) labels of the stacked joints (default: `coopsim.core.labels` of the log's model
            metadata, else joint 1, joint 2, …).

    Returns:
        list[tuple]: (builder, args, out_dir/FILE) per figure, FILES first.

    Raises:
        ValueError: joint_names does not hold one name per joint.
    """
    n = log.topics[NATIVE + "/joint_state"]["angle"].shape[1]
    labels = _joint_labels(log, n, joint_names)
    jobs = [(_joint_figure, (log, "angle", "angle", COORDINATE, labels)),
            (_joint_figure, (log, "rate", "rate", RATE, labels)),
            (_object_figure, (log,)), (_constraint_figure, (log,))]
    out = Path(out_dir)
    return [(fn, args, out / name) for (fn, args), name in zip(jobs, FILES)] + \
        [(fn, args, out / name) for fn, args, name in control_jobs(log)]


def comparison_plots(log: LogData, out_dir: str | Path, joint_names: list[str] | None = None,
                     workers: FigureWorkers | None = None) -> list[Path]:
    """Write the comparison figures of a run log into out_dir and return their paths.

    The files: joint_angles.png, joint_rates.png, object_motion.png and constraint_violation.png (and, for a
    closed loop, `coopsim.plots.control`'s tracking_error.png and internal_force.png); out_dir is created if
    missing, each file replaced atomically.

    Args:
        log: the run log (`LogData`).
        out_dir: the folder written.
        joint_names: (n,) labels of the stacked joints (default: `coopsim.core.labels` of the log's model
            metadata, else joint 1, joint 2, …).
        workers: where to draw (`coopsim.plots.render`; default: processes started for this call).

    Returns:
        list[Path]: the PNG files written, in job order.

    Raises:
        ValueError: joint_names does not hold one name per joint.
    """
    jobs = comparison_jobs(log, out_dir, joint_names)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    return render_figures(jobs, workers,
                          first=(FILES.index("object_motion.png"),))   # six panels: twice the others' time
