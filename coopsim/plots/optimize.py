"""Plots of a `coopsim optimize --retime` log (PNG, Agg): the phase plane ṡ(s) with the maximum-velocity
curve, each motor's torque against its eq. 36 lines before and after the retiming, and the payload–time
curve.

Topics: /optimize/<method>/law (s, ṡ, s̈, the maximum-velocity curve), /optimize/<method>/torque and
/optimize/<method>/before (τ and the motor lines), and the optimize.<method> metadata records (the
payload–time curve, capacities before and after), as `coopsim.report.optimize_report` writes them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coopsim.core.labels import metadata_joint_labels
from coopsim.io.mcap_codec import LogData
from coopsim.plots.figure import legend_beside, legend_width, panel_grid, run_title
from coopsim.plots.inverse import LABEL, STYLE, _methods, _torque_grid
from coopsim.plots.render import FigureWorkers, render_figures

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _record(log: LogData, name: str, key: str):
    """A value of a metadata record, JSON-decoded (strings as they are; None when absent)."""
    text = log.metadata.get(name, {}).get(key, "null")
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def phase_plane_figure(log: LogData) -> Figure:
    """ṡ(s) of each method's optimal law and its maximum-velocity curve (the fastest ṡ a point alone allows),
    on a log axis (ṡ = 0 at every waypoint).

    Args:
        log: a `coopsim optimize --retime` log.

    Returns:
        Figure: the matplotlib figure.
    """
    from matplotlib.figure import Figure

    methods = _methods(log, "/optimize/", "/law")
    fig = Figure()
    labels = [f"{LABEL.get(k, k)} ({_record(log, f'optimize.{k}', 'after_mass_kg'):.4g} kg)" for k in methods]
    ax = panel_grid(fig, 1, 1, (6.4, 3.2), legend=legend_width(labels + ["maximum-velocity curve"]))[0, 0]
    top = 0.0
    for k, label in zip(methods, labels):
        d = log.topics[f"/optimize/{k}/law"]
        ax.plot(d["s"], d["sdot"], label=label, **STYLE.get(k, {}))
        top = max(top, float(np.max(d["sdot"])))
        mvc = np.where(np.isfinite(d["max_sdot"]), d["max_sdot"], np.nan)
        if np.any(np.isfinite(mvc)):
            ax.plot(d["s"], mvc, lw=0.8, ls="--", color=STYLE.get(k, {}).get("color", "0.5"))
    ax.plot([], [], lw=0.8, ls="--", color="0.4", label="maximum-velocity curve")
    ax.set_yscale("log")
    ax.set_ylim(1e-2 * top if top > 0 else 1e-3, None)
    ax.set_xlabel("s (path parameter)")
    ax.set_ylabel("ṡ (1/s)")
    ax.grid(alpha=0.3)
    legend_beside(ax)
    fig.suptitle(run_title(log, "Phase plane: the heaviest load's time-optimal ṡ(s)"))
    return fig


def motors_figure(log: LogData) -> Figure:
    """Each motor's torque relative to its stall torque against its eq. 36 lines, before and after.

    Before: the scenario's own time law at its capacity; after: the retimed law at the heaviest load
    (the method the optimised scenario carries). Time normalised by each law's duration.

    Args:
        log: a `coopsim optimize --retime` log.

    Returns:
        Figure: the matplotlib figure.
    """
    from matplotlib.figure import Figure

    k = _record(log, "optimize", "method")
    after = log.topics[f"/optimize/{k}/torque"]
    before = log.topics.get(f"/optimize/{k}/before")
    n = after["tau"].shape[1]
    names = metadata_joint_labels(log.metadata, n)
    grid = _torque_grid(log, n)
    cols = max(len(r) for r in grid)
    labels = ["after: τ", "after: τ_max, τ_min", "before: τ", "before: τ_max, τ_min"]
    fig = Figure()
    axes = panel_grid(fig, len(grid), cols, (3.2, 2.2), legend=legend_width(labels))
    for row, joints in zip(axes, grid):
        for ax in row[len(joints):]:
            ax.remove()
        for ax, j in zip(row, joints):
            for d, tag, style in ((after, "after", dict(color="tab:red")),
                                  (before, "before", dict(color="tab:blue", alpha=0.6))):
                if d is None:
                    continue
                u = (d["t"] - d["t"][0]) / max(d["t"][-1] - d["t"][0], 1e-300)
                ax.plot(u, d["tau"][:, j], label=f"{tag}: τ", **style)
                ax.plot(u, d["tau_max"][:, j], lw=0.8, ls="--", label=f"{tag}: τ_max, τ_min", **style)
                ax.plot(u, d["tau_min"][:, j], lw=0.8, ls="--", **style)
            ax.set_title(names[j], fontsize=9)
            ax.set_xlabel("t / duration")
            ax.set_ylabel("τ (N·m)")
            ax.grid(alpha=0.3)
    legend_beside(axes[0, len(grid[0]) - 1])
    fig.suptitle(run_title(log, f"Motor torques against their lines, {LABEL.get(k, k)}: before and after retiming"))
    return fig


def payload_time_figure(log: LogData) -> Figure:
    """The minimum time of each method against the carried mass, with the duration bound and the
    scenario's own capacity (at its own duration).

    Args:
        log: a `coopsim optimize --retime` log.

    Returns:
        Figure: the matplotlib figure.
    """
    from matplotlib.figure import Figure

    methods = [name[len("optimize."):] for name in log.metadata if name.startswith("optimize.")]
    fig = Figure()
    labels = [LABEL.get(k, k) for k in methods] + ["T_max", "scenario's law"]
    ax = panel_grid(fig, 1, 1, (6.4, 3.2), legend=legend_width(labels))[0, 0]
    T = _record(log, "optimize", "duration_bound_s")
    for k in methods:
        mass, dur = _record(log, f"optimize.{k}", "curve_mass_kg"), _record(log, f"optimize.{k}", "curve_duration_s")
        ax.plot(mass, dur, marker="o", ms=3, label=LABEL.get(k, k), **STYLE.get(k, {}))
        b = _record(log, f"optimize.{k}", "before_mass_kg")
        if b is not None and np.isfinite(b):
            ax.plot([b], [T], "s", mfc="none", color=STYLE.get(k, {}).get("color", "0.3"))
    ax.axhline(T, color="0.3", lw=0.8, ls=":", label="T_max")
    ax.plot([], [], "s", mfc="none", color="0.3", label="scenario's law")
    ax.set_xlabel("carried mass (kg)")
    ax.set_ylabel("minimum time (s)")
    ax.grid(alpha=0.3)
    legend_beside(ax)
    fig.suptitle(run_title(log, "Payload–time curve of the fixed path"))
    return fig


def optimize_jobs(log: LogData, out_dir: str | Path) -> list[tuple]:
    """The figures of `optimize_plots` as `coopsim.plots.render` jobs.

    Args:
        log: a `coopsim optimize --retime` log.
        out_dir: the folder the figures go to.

    Returns:
        list[tuple]: (builder, args, out_dir/FILE) per figure.
    """
    out = Path(out_dir)
    return [(phase_plane_figure, (log,), out / "optimize_phase_plane.png"),
            (motors_figure, (log,), out / "optimize_motors.png"),
            (payload_time_figure, (log,), out / "optimize_payload_time.png")]


def optimize_plots(log: LogData, out_dir: str | Path, workers: FigureWorkers | None = None) -> list[Path]:
    """Write optimize_phase_plane.png, optimize_motors.png and optimize_payload_time.png in out_dir.

    Args:
        log: a `coopsim optimize --retime` log.
        out_dir: the folder the figures go to.
        workers: the figure workers to draw on; None: workers started for this call only.

    Returns:
        list[Path]: the figures written.
    """
    return render_figures(optimize_jobs(log, out_dir), workers)
