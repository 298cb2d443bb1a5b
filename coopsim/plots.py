"""Comparison plots of a run log (native model vs MuJoCo twin), PNG via matplotlib's Agg canvas.

Every function takes a :class:`coopsim.io.log.LogData` (from :func:`coopsim.io.log.read_mcap`), so a fresh
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
from coopsim.core.labels import arm_label, metadata_arms, metadata_joint_labels, metadata_joint_types
from coopsim.io.log import LogData
from coopsim.render import FigureWorkers, render_figures

if TYPE_CHECKING:
    from matplotlib.figure import Figure

NATIVE, TWIN = "/native", "/mujoco"
FILES = ("joint_angles.png", "joint_rates.png", "object_motion.png", "constraint_violation.png")
_AXES = ("x", "y", "z")
PANEL, OBJECT_PANEL = (4.6, 2.7), (3.6, 2.7)   # inches: a joint panel, an object panel
LEGEND_FONT = 8.0    # pt
LEGEND_GAP = 0.12    # inches between a panel's right edge and its legend


def legend_width(labels: list[str], fontsize: float = LEGEND_FONT) -> float:
    """Width (inches) of a one-column legend of `labels` at `fontsize`: the longest label measured with
    matplotlib's font metrics, plus matplotlib's default handle (2 em), text pad (0.8 em) and border
    pads (0.4 em each side) and the frame."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    prop, measure = FontProperties(size=fontsize), TextToPath()
    text = max((measure.get_text_width_height_descent(s, prop, ismath=False)[0] for s in labels), default=0.0)
    return (text + fontsize * (2.0 + 0.8 + 2 * 0.4) + 2.0) / 72.0


def panel_grid(fig: Figure, rows: int, cols: int, size: tuple[float, float], legend: float = 0.0,
               legend_after=None, suptitle: bool = True) -> np.ndarray:
    """Axes (rows, cols) of panels `size` (width, height) inches on `fig`, with room `legend` inches
    wide for a legend (`legend_beside`) right of each panel column in `legend_after` (default: the
    last column; `legend` 0: none): an empty grid column, so the panels, the legends and the next
    column's labels never meet. Sets the figure size for `coopsim.render.fixed_layout`'s margins and
    gaps (`suptitle`: the figure will have one)."""
    from coopsim.render import MARGIN

    after = set(range(cols)[-1:] if legend_after is None else legend_after) if legend > 0 else set()
    spare = max(legend + LEGEND_GAP - MARGIN["wgap"], 0.05)   # the legend starts inside the gap before its column
    widths, index = [], []
    for j in range(cols):
        index.append(len(widths))
        widths += [size[0]] + ([spare] if j in after else [])
    fig.set_size_inches(MARGIN["left"] + MARGIN["right"] + sum(widths) + MARGIN["wgap"] * (len(widths) - 1),
                        MARGIN["top"] + MARGIN["bottom"] + MARGIN["suptitle"] * suptitle + rows * size[1]
                        + MARGIN["hgap"] * (rows - 1))
    grid = fig.add_gridspec(rows, len(widths), width_ratios=widths)
    return np.array([[fig.add_subplot(grid[i, index[j]]) for j in range(cols)] for i in range(rows)])


def legend_beside(ax, handles: list | None = None, fontsize: float = LEGEND_FONT):
    """The legend of `ax` (or of `handles`) outside it: right of the panel, LEGEND_GAP inches from it,
    top edges aligned (in the room `panel_grid` keeps there)."""
    from matplotlib.transforms import ScaledTranslation

    at = ax.transAxes + ScaledTranslation(LEGEND_GAP, 0.0, ax.get_figure().dpi_scale_trans)
    return ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), bbox_transform=at,
                     borderaxespad=0.0, fontsize=fontsize)


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
    """Labels and a grid at the decades (minor ticks off: over ten decades they are ~80 tick objects
    an axis, a third of the figure's drawing time); a note when nothing was drawn."""
    from matplotlib.ticker import LogLocator, NullLocator

    ax.set_ylabel(ylabel)
    ax.set_xlabel("time (s)")
    if ax.get_yscale() == "log":   # not when nothing was drawn (a zero difference): the axis stays linear
        ax.yaxis.set_major_locator(LogLocator(numticks=8))
        ax.yaxis.set_minor_locator(NullLocator())
    ax.grid(True, alpha=0.3)
    if not drawn:
        ax.text(0.5, 0.5, "difference exactly zero", ha="center", va="center", transform=ax.transAxes)


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
        drawn = [_log_plot(axes[1], t, d[:, j], labels[j] if diff is None else diff_ylabel, color=c)
                 for j, c in enumerate(colors)]
        axes[1].set_title(diff_title)
        _finish_log_axis(axes[1], any(drawn), diff_ylabel)
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
    groups = _arm_groups(log, x.shape[1])
    styles = list(STYLES[:1 + (y is not None)])
    fig = Figure()
    axes = panel_grid(fig, 1 if y is None else 2, len(groups), PANEL,
                      legend=max(legend_width(labels[sl] + styles) for _, sl in groups), legend_after=range(len(groups)))
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

    from coopsim.core.spatial import orientation_error, quat_to_rot, rotation_from

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
    drawn = [_log_plot(ax, nat["t"], nat["residual_pos"], labels[0])]
    if twin is not None:
        drawn.append(_log_plot(ax, twin["t"], np.abs(twin["weld_violation"]), labels[1], ls="--"))
    ax.set_title(run_title(log, "Constraint violation", twin=twin is not None), fontsize=9)
    _finish_log_axis(ax, any(drawn), "violation (m or rad)")
    if any(drawn):
        legend_beside(ax)
    return fig


def comparison_jobs(log: LogData, out_dir: str | Path, joint_names: list[str] | None = None) -> list[tuple]:
    """The figures of `comparison_plots` as `coopsim.render` jobs (builder, args, out_dir/FILE); a closed
    loop's log adds `coopsim.plots_control`'s tracking_error.png and internal_force.png."""
    from coopsim.plots_control import control_jobs

    n = log.topics[NATIVE + "/joint_state"]["angle"].shape[1]
    labels = _joint_labels(log, n, joint_names)
    jobs = [(_joint_figure, (log, "angle", "angle", COORDINATE, labels)), (_joint_figure, (log, "rate", "rate", RATE, labels)),
            (_object_figure, (log,)), (_constraint_figure, (log,))]
    out = Path(out_dir)
    return [(fn, args, out / name) for (fn, args), name in zip(jobs, FILES)] + \
        [(fn, args, out / name) for fn, args, name in control_jobs(log)]


def comparison_plots(log: LogData, out_dir: str | Path, joint_names: list[str] | None = None,
                     workers: FigureWorkers | None = None) -> list[Path]:
    """Write joint_angles.png, joint_rates.png, object_motion.png and constraint_violation.png (and, for
    a closed loop, `coopsim.plots_control`'s tracking_error.png and internal_force.png) into out_dir
    (created if missing; each file replaced atomically) and return their paths. joint_names
    (n,) labels the joints (default: `coopsim.core.labels` of the log's model metadata, else joint 1, joint 2,
    …); workers: where to draw (`coopsim.render`; default: processes started for this call)."""
    jobs = comparison_jobs(log, out_dir, joint_names)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    return render_figures(jobs, workers, first=(FILES.index("object_motion.png"),))   # six panels: twice the others' time
