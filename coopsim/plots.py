"""Comparison plots of a run log (native model vs MuJoCo twin), PNG via matplotlib's Agg canvas.

Every function takes a :class:`coopsim.log.LogData` (from :func:`coopsim.log.read_mcap`), so a fresh
run and a stored log are plotted by the same code. Topics used: /native/joint_state, /native/object,
/native/constraint and, when present, their /mujoco counterparts (without them only the native model
is drawn). Arms and joint names come from the log's "model" metadata record when it is there.
Differences |native − mujoco| are drawn on log axes (exact zeros are left out: a log axis cannot show
them); when the twin is sampled at other times it is interpolated linearly onto the native times.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .labels import arm_label, metadata_arms, metadata_joint_labels
from .log import LogData
from .render import FigureWorkers, render_figures

if TYPE_CHECKING:
    from matplotlib.figure import Figure

NATIVE, TWIN = "/native", "/mujoco"
FILES = ("joint_angles.png", "joint_rates.png", "object_motion.png", "constraint_violation.png")
_AXES = ("x", "y", "z")


def _arm_groups(log: LogData, n: int) -> list[tuple[str, slice]]:
    """(arm label, joint slice) per arm from the "model" metadata record; one group without it."""
    arms = metadata_arms(log.metadata)
    if arms is None or sum(arms[1]) != n:
        return [("joints", slice(0, n))]
    names, dofs = arms
    ends = np.cumsum([0] + dofs)
    return [(arm_label(a, m), slice(int(s), int(e))) for m, (a, s, e) in enumerate(zip(names, ends[:-1], ends[1:]))]


def _joint_labels(log: LogData, n: int, joint_names: list[str] | None) -> list[str]:
    if joint_names is not None:
        if len(joint_names) != n:
            raise ValueError(f"joint_names: expected {n} names, got {len(joint_names)}")
        return list(joint_names)
    return metadata_joint_labels(log.metadata, n)


def run_title(log: LogData, what: str, twin: bool = False) -> str:
    """A figure title naming the scenario and its settings, as the log's metadata records them:
    'paper_planar_2x3 — Joint angle (native dop853 rtol 1e-12; MuJoCo RK4 0.001 s)'. `twin`: name the
    MuJoCo settings too."""
    meta = log.metadata
    name = meta.get("scenario", {}).get("name")
    nat, mj = meta.get("native.integrator", {}), meta.get("mujoco", {})
    settings = []
    if "method" in nat:
        settings.append(f"native {nat['method']}" + (f" rtol {nat['rtol']}" if nat["method"] != "rk4" else
                                                     f" step {nat.get('step')} s"))
    if twin and "integrator" in mj:
        settings.append(f"MuJoCo {mj['integrator']} {mj.get('timestep')} s")
    text = what if name is None else f"{name} — {what}"
    return text + (f" ({'; '.join(settings)})" if settings else "")


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


def _log_plot(ax, t: np.ndarray, y: np.ndarray, label: str, **kw) -> bool:
    """Plot positive values of y on a log axis; return whether anything was drawn."""
    y = np.where(y > 0, y, np.nan)
    if not np.any(np.isfinite(y)):
        return False
    ax.semilogy(t, y, label=label, **kw)
    return True


def _finish_log_axis(ax, drawn: bool, ylabel: str) -> None:
    """Labels, a grid at the decades (minor ticks off: over ten decades they are ~80 tick objects an
    axis, a third of the figure's drawing time) and the legend."""
    from matplotlib.ticker import LogLocator, NullLocator

    ax.set_ylabel(ylabel)
    ax.set_xlabel("time (s)")
    if ax.get_yscale() == "log":   # not when nothing was drawn (a zero difference): the axis stays linear
        ax.yaxis.set_major_locator(LogLocator(numticks=8))
        ax.yaxis.set_minor_locator(NullLocator())
    ax.grid(True, alpha=0.3)
    if drawn:
        ax.legend(fontsize="small", ncol=2)
    else:
        ax.text(0.5, 0.5, "difference exactly zero", ha="center", va="center", transform=ax.transAxes)


def _compare_columns(axes, t, x, y, cols, labels, quantity: str, unit: str, title: str, diff_title: str) -> None:
    """Columns `cols` of x (native, solid) and y (twin, dashed; None: none) on axes[0], and their
    absolute difference on a log axis on axes[1] when the twin is there."""
    ax = axes[0]
    for j, label in zip(cols, labels):
        line, = ax.plot(t, x[:, j], label=f"{label} native")
        if y is not None:
            ax.plot(t, y[:, j], "--", color=line.get_color(), label=f"{label} mujoco")
    ax.set(title=title, xlabel="time (s)", ylabel=f"{quantity} ({unit})")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small", ncol=2)
    if y is not None:
        drawn = [_log_plot(axes[1], t, np.abs(x[:, j] - y[:, j]), label) for j, label in zip(cols, labels)]
        axes[1].set_title(diff_title)
        _finish_log_axis(axes[1], any(drawn), f"|Δ {quantity}| ({unit})")


def _joint_figure(log: LogData, key: str, quantity: str, unit: str, labels: list[str]) -> Figure:
    from matplotlib.figure import Figure

    nat = log.topics[NATIVE + "/joint_state"]
    t, x = nat["t"], nat[key]
    y = _twin(log, "/joint_state", key, t)
    groups = _arm_groups(log, x.shape[1])
    rows = 1 if y is None else 2
    fig = Figure(figsize=(5.5 * len(groups), 3.6 * rows))
    axes = fig.subplots(rows, len(groups), squeeze=False)
    for col, (arm, sl) in enumerate(groups):
        cols = range(sl.start, sl.stop)
        _compare_columns(axes[:, col], t, x, y, cols, [labels[j] for j in cols], quantity, unit,
                         f"{arm}: joint {quantity}", f"{arm}: |native − mujoco|")
    fig.suptitle(run_title(log, f"Joint {quantity}" + ("" if y is None else ": native model vs MuJoCo twin"),
                           twin=y is not None))
    return fig


def _object_figure(log: LogData) -> Figure:
    from matplotlib.figure import Figure

    nat = log.topics[NATIVE + "/object"]
    t = nat["t"]
    pos, twist = _twin(log, "/object", "position", t), _twin(log, "/object", "twist", t)
    parts = [("position", "", "m", nat["position"], pos),
             ("velocity", "v", "m/s", nat["twist"][:, :3], None if twist is None else twist[:, :3])]
    rows = 1 if pos is None else 2
    fig = Figure(figsize=(11, 3.8 * rows))
    axes = fig.subplots(rows, 2, squeeze=False)
    for col, (name, sym, unit, x, y) in enumerate(parts):
        _compare_columns(axes[:, col], t, x, y, range(3), [f"{sym}{c}" for c in _AXES], name, unit,
                         f"Object centre-of-mass {name}", f"Object {name}: |native − mujoco|")
    fig.suptitle(run_title(log, "Object motion" + ("" if rows == 1 else ": native model vs MuJoCo twin"),
                           twin=rows > 1))
    return fig


def _constraint_figure(log: LogData) -> Figure:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4))
    ax = fig.subplots()
    nat = log.topics[NATIVE + "/constraint"]
    drawn = [_log_plot(ax, nat["t"], nat["residual_pos"], "native loop-closure residual max |Φ|")]
    twin = log.topics.get(TWIN + "/constraint")
    if twin is not None:
        drawn.append(_log_plot(ax, twin["t"], np.abs(twin["weld_violation"]), "MuJoCo weld violation", ls="--"))
    ax.set_title(run_title(log, "Constraint violation", twin=twin is not None), fontsize=9)
    _finish_log_axis(ax, any(drawn), "violation (m or rad)")
    return fig


def comparison_plots(log: LogData, out_dir: str | Path, joint_names: list[str] | None = None,
                     workers: FigureWorkers | None = None) -> list[Path]:
    """Write joint_angles.png, joint_rates.png, object_motion.png and constraint_violation.png (and, for
    a closed loop, `coopsim.plots_control`'s tracking_error.png and internal_force.png) into out_dir (created if missing; each file replaced atomically) and return their paths. joint_names
    (n,) labels the joints (default: `coopsim.labels` of the log's model metadata, else joint 1, joint 2,
    …); workers: where to draw (`coopsim.render`; default: processes started for this call)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    n = log.topics[NATIVE + "/joint_state"]["angle"].shape[1]
    labels = _joint_labels(log, n, joint_names)
    jobs = [(_joint_figure, (log, "angle", "angle", "rad", labels)), (_joint_figure, (log, "rate", "rate", "rad/s", labels)),
            (_object_figure, (log,)), (_constraint_figure, (log,))]
    from .plots_control import control_jobs   # a closed loop adds tracking_error.png, internal_force.png

    figures = [(fn, args, out / name) for (fn, args), name in zip(jobs, FILES)]
    return render_figures(figures + [(fn, args, out / name) for fn, args, name in control_jobs(log)], workers)
