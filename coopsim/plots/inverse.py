"""Plots of inverse-dynamics and capacity logs, in the spirit of the paper's Figs. 6–8 (PNG, Agg).

Every function takes a :class:`coopsim.io.log.LogData` read back from the MCAP file the CLI wrote, so a
fresh study and a stored log are drawn by the same code. Topics: /inverse/trajectory,
/inverse/<method>/{torque,internal,stress} (`coopsim inverse`), /capacity/limits,
/capacity/<method>/<mode>, /capacity/lp/<mode> and the capacity.<method>.<mode> metadata records
(`coopsim capacity`). Joint labels come from the log's "model" metadata record (`coopsim.core.labels`); the
resolutions' labels, colours and order from the registry `coopsim.inverse.resolutions.RESOLUTIONS`.
"""

from __future__ import annotations

import json
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np

from coopsim.core.joints import EFFORT, units_of
from coopsim.core.labels import metadata_arms, metadata_joint_labels, metadata_joint_types
from coopsim.io.mcap_codec import LogData
from coopsim.plots.figure import legend_beside, legend_width, panel_grid, run_title
from coopsim.plots.render import FigureWorkers, render_figures
from coopsim.inverse.resolutions import RESOLUTIONS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# the series that are not resolutions: the forward run's input torques (first), the capacity study's
# optimised weights and LP bound (last); between them every registered resolution, in registry order
_OTHERS_FIRST = {"forward": (dict(color="black", ls="--", lw=1.2), "forward-dynamics input")}
_OTHERS_LAST = {"optimised": (dict(color="tab:orange"), "minimum energy, optimised Q"),
                "lp": (dict(color="tab:gray", ls=":", lw=1.5), "LP bound (any distribution)")}
_SERIES = (_OTHERS_FIRST | {k: (dict(color=m.color), m.label) for k, m in RESOLUTIONS.items()} | _OTHERS_LAST)
STYLE = {k: style for k, (style, _) in _SERIES.items()}
LABEL = {k: label for k, (_, label) in _SERIES.items()}


def _joints(log: LogData, n: int) -> list[str]:
    return metadata_joint_labels(log.metadata, n)


def _methods(log: LogData, prefix: str, suffix: str) -> list[str]:
    order = list(STYLE)
    found = [k[len(prefix):-len(suffix)] for k in log.topics if k.startswith(prefix) and k.endswith(suffix)]
    return sorted(found, key=lambda k: order.index(k) if k in order else len(order))


MOTOR_LINES = "motor lines τ_max, τ_min (eq. 36)"


def _torque_grid(log: LogData, n: int) -> list[list[int]]:
    """Joint indices (stacked) per row of the torque figure: each arm starts a row, at most 4 panels a
    row (one row of all n when the log names no arms)."""
    arms = metadata_arms(log.metadata)
    dofs = arms[1] if arms is not None and sum(arms[1]) == n else [n]
    cols = min(max(dofs), 4)
    rows, start = [], 0
    for d in dofs:
        rows += [list(range(start + i, start + min(i + cols, d))) for i in range(0, d, cols)]
        start += d
    return rows


def inverse_torques_figure(log: LogData) -> Figure:
    """Fig. 6: joint torques of every resolution against the forward-dynamics input, one panel per joint.

    A row per arm, at most 4 panels a row, with the motor lines of eq. 36 (grey; on a panel where they are
    finite and τ_max comes below three times the largest |τ| drawn); one legend beside the first row.
    Torques in N·m (N on a prismatic joint).

    Args:
        log: a `coopsim inverse` log (/inverse/trajectory and /inverse/<method>/torque series).

    Returns:
        Figure: the matplotlib figure.
    """
    from matplotlib.figure import Figure

    traj = log.topics["/inverse/trajectory"]
    t, n = traj["t"], traj["q"].shape[1]
    names, types = _joints(log, n), metadata_joint_types(log.metadata, n)
    methods = _methods(log, "/inverse/", "/torque")
    grid = _torque_grid(log, n)
    cols = max(len(r) for r in grid)
    fig = Figure()
    axes = panel_grid(fig, len(grid), cols, (3.4, 2.3),
                      legend=legend_width([LABEL.get(k, k) for k in methods] + [MOTOR_LINES]))
    for row, joints in zip(axes, grid):
        for ax in row[len(joints):]:
            ax.remove()
        for ax, j in zip(row, joints):
            for k in methods:
                ax.plot(t, log.topics[f"/inverse/{k}/torque"]["tau"][:, j], label=LABEL.get(k, k), **STYLE.get(k, {}))
            lo, hi = traj["tau_min"][:, j], traj["tau_max"][:, j]
            if np.all(np.isfinite(hi)):
                span = max(np.max(np.abs([ln.get_ydata() for ln in ax.lines])), 1e-9)
                if np.min(hi) < 3 * span:
                    ax.plot(t, hi, color="0.6", lw=0.8, label=MOTOR_LINES)
                    ax.plot(t, lo, color="0.6", lw=0.8)
            ax.set_title(names[j], fontsize=9)
            ax.set_xlabel("t (s)")
            ax.set_ylabel(f"τ ({units_of(types[j:j + 1], EFFORT)})")
            ax.grid(alpha=0.3)
    legend = {}   # label → handle over every panel: the motor lines may be drawn on other panels only
    for ax in fig.axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    legend_beside(axes[0, len(grid[0]) - 1], list(legend.values()))
    fig.suptitle(run_title(log, "Joint torques of each resolution (Fig. 6)"))
    return fig


def inverse_norms_figure(log: LogData) -> Figure:
    """Fig. 7: the torque norm |τ| and the cost ½τᵀQτ of every resolution over time.

    Args:
        log: a `coopsim inverse` log (/inverse/trajectory and /inverse/<method>/torque series).

    Returns:
        Figure: the matplotlib figure, two panels.
    """
    from matplotlib.figure import Figure

    methods = _methods(log, "/inverse/", "/torque")
    fig = Figure()
    ax1, ax2 = panel_grid(fig, 2, 1, (6.4, 2.4), legend=legend_width([LABEL.get(k, k) for k in methods]))[:, 0]
    for k in methods:
        d = log.topics[f"/inverse/{k}/torque"]
        ax1.plot(d["t"], d["torque_norm"], label=LABEL.get(k, k), **STYLE.get(k, {}))
        ax2.plot(d["t"], d["cost"], label=LABEL.get(k, k), **STYLE.get(k, {}))
    units = units_of(metadata_joint_types(log.metadata, log.topics["/inverse/trajectory"]["q"].shape[1]), EFFORT,
                     sep=", ")
    squared = {"N·m": "N²·m²", "N": "N²"}
    ax1.set_ylabel(f"|τ| ({units})")
    ax2.set_ylabel(f"½ τᵀQτ ({', '.join(squared[u] for u in units.split(', '))})")
    for ax in (ax1, ax2):
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    legend_beside(ax1)
    fig.suptitle(run_title(log, "Torque norm and cost (Fig. 7)"))
    return fig


def inverse_internal_figure(log: LogData) -> Figure:
    """What each resolution puts into the object: its largest internal wrench over the arms and its stress.

    The largest internal force (N) and moment (N·m) over the arms (non-squeezing definition, at C) and, for
    a box, the peak normal stress (kPa) over its cross-sections.

    Args:
        log: a `coopsim inverse` log (/inverse/<method>/internal series, and /inverse/<method>/stress for a
            box).

    Returns:
        Figure: the matplotlib figure, two or three panels.
    """
    from matplotlib.figure import Figure

    methods = _methods(log, "/inverse/", "/internal")
    has_stress = all(f"/inverse/{k}/stress" in log.topics for k in methods)
    fig = Figure()
    axes = panel_grid(fig, 3 if has_stress else 2, 1, (6.4, 2.0),
                      legend=legend_width([LABEL.get(k, k) for k in methods]))[:, 0]
    for k in methods:
        d = log.topics[f"/inverse/{k}/internal"]
        F = d["nonsqueezing"]
        axes[0].plot(d["t"], np.max(np.linalg.norm(F[..., :3], axis=-1), axis=1), label=LABEL.get(k, k),
                     **STYLE.get(k, {}))
        axes[1].plot(d["t"], np.max(np.linalg.norm(F[..., 3:], axis=-1), axis=1), **STYLE.get(k, {}))
        if has_stress:
            s = log.topics[f"/inverse/{k}/stress"]
            axes[2].plot(s["t"], s["peak_normal"] / 1e3, **STYLE.get(k, {}))
    axes[0].set_ylabel("internal force (N)")
    axes[1].set_ylabel("internal moment (N·m)")
    if has_stress:
        axes[2].set_ylabel("peak normal stress (kPa)")
    for ax in axes:
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    legend_beside(axes[0])
    fig.suptitle(run_title(log, "Internal wrench and object stress"))
    return fig


def inverse_jobs(log: LogData, out_dir: str | Path) -> list[tuple]:
    """The figures of `inverse_plots` as `coopsim.plots.render` jobs.

    Args:
        log: a `coopsim inverse` log.
        out_dir: the folder the figures go to.

    Returns:
        list[tuple]: (builder, args, out_dir/FILE) per figure.
    """
    out = Path(out_dir)
    return [(inverse_torques_figure, (log,), out / "inverse_torques.png"),
            (inverse_norms_figure, (log,), out / "inverse_norms.png"),
            (inverse_internal_figure, (log,), out / "inverse_internal.png")]


def inverse_plots(log: LogData, out_dir: str | Path, workers: FigureWorkers | None = None) -> list[Path]:
    """Write inverse_torques.png, inverse_norms.png, inverse_internal.png in out_dir.

    Args:
        log: a `coopsim inverse` log.
        out_dir: the folder the figures go to.
        workers: the figure workers to draw on; None: workers started for this call only.

    Returns:
        list[Path]: the figures written.
    """
    return render_figures(inverse_jobs(log, out_dir), workers)


def capacity_motor_figure(log: LogData, mode: str = "scaled") -> Figure:
    """Fig. 8: per resolution, the torque of the motor that saturates first, at the capacity mass.

    It is drawn against its torque–speed lines τ_max(θ̇), τ_min(θ̇) (eq. 36); the dot marks the saturation.
    Each panel's legend stands beside it. The LP bound has no panel.

    Args:
        log: a `coopsim capacity` log (/capacity/limits, /capacity/<method>/<mode> and the
            capacity.<method>.<mode> metadata records).
        mode: the capacity mode (`coopsim.inverse.capacity.MODES`): 'scaled' (the object scaled at constant
            geometry) or 'payload' (a point payload on the object).

    Returns:
        Figure: the matplotlib figure.
    """
    from matplotlib.figure import Figure

    lim = log.topics["/capacity/limits"]
    t = lim["t"]
    methods = [k for k in _methods(log, "/capacity/", f"/{mode}") if k != "lp"]
    names = _joints(log, lim["qd"].shape[1])
    records = [log.metadata.get(f"capacity.{k}.{mode}", {}) for k in methods]
    masses = [json.loads(rec.get("mass_kg", "NaN")) for rec in records]  # Python's json reads Infinity and NaN
    lines = ["τ_max line (eq. 36)", "τ_min line (eq. 36)", "first saturation"]
    cols = min(2, max(1, len(methods)))
    rows = int(np.ceil(max(1, len(methods)) / cols))
    fig = Figure()
    axes = panel_grid(fig, rows, cols, (4.2, 2.8), legend=legend_width([f"τ at {m:.4g} kg" for m in masses] + lines),
                      legend_after=range(cols)).ravel()
    for ax in axes[len(methods):]:
        ax.remove()
    for ax, k, rec, mass in zip(axes, methods, records, masses):
        j = json.loads(rec.get("stacked_joint", "null"))
        if j is None:
            ax.text(0.5, 0.5, "no saturating motor", ha="center", va="center", transform=ax.transAxes)
            continue
        tau = log.topics[f"/capacity/{k}/{mode}"]["tau"][:, j]
        ax.plot(t, tau, label=f"τ at {mass:.4g} kg", **STYLE.get(k, {}))
        ax.plot(t, lim["tau_max"][:, j], color="0.4", lw=1, label=lines[0])
        ax.plot(t, lim["tau_min"][:, j], color="0.4", lw=1, ls="--", label=lines[1])
        ts = json.loads(rec.get("time_s", "null"))
        if ts is not None:
            ax.plot([ts], [np.interp(ts, t, tau)], "o", color="black", label=lines[2])
        ax.set_title(f"{LABEL.get(k, k)}\n{names[j]}", fontsize=9)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"τ ({units_of(metadata_joint_types(log.metadata, len(names))[j:j + 1], EFFORT)})")
        ax.grid(alpha=0.3)
        legend_beside(ax)
    fig.suptitle(run_title(log, f"Capacity: the motor that saturates first ({mode})"))
    return fig


def capacity_along_path_figure(log: LogData, mode: str = "scaled") -> Figure:
    """The largest mass (kg) each sample alone allows, per resolution and for the LP bound.

    The capacity is the lowest point of each curve.

    Args:
        log: a `coopsim capacity` log (/capacity/<method>/<mode> series).
        mode: the capacity mode (`coopsim.inverse.capacity.MODES`): 'scaled' (the object scaled at constant
            geometry) or 'payload' (a point payload on the object).

    Returns:
        Figure: the matplotlib figure, a log axis.
    """
    from matplotlib.figure import Figure

    methods = _methods(log, "/capacity/", f"/{mode}")
    fig = Figure()
    ax = panel_grid(fig, 1, 1, (6.4, 3.0), legend=legend_width([LABEL.get(k, k) for k in methods]))[0, 0]
    for k in methods:
        d = log.topics[f"/capacity/{k}/{mode}"]
        y = np.where(np.isfinite(d["per_sample_mass"]), d["per_sample_mass"], np.nan)
        ax.plot(d["t"], y, label=LABEL.get(k, k), **STYLE.get(k, {}))
    ax.set_yscale("log")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("largest mass this sample allows (kg)")
    ax.grid(alpha=0.3, which="both")
    legend_beside(ax)
    fig.suptitle(run_title(log, f"Largest mass each sample allows ({mode})"))
    return fig


def capacity_jobs(log: LogData, out_dir: str | Path) -> list[tuple]:
    """The figures of `capacity_plots` as `coopsim.plots.render` jobs, for each mode the log holds.

    Args:
        log: a `coopsim capacity` log.
        out_dir: the folder the figures go to.

    Returns:
        list[tuple]: (builder, args, out_dir/FILE) per figure.
    """
    out = Path(out_dir)
    jobs = []
    for mode in ("scaled", "payload"):
        if not any(k.endswith(f"/{mode}") and k.startswith("/capacity/") for k in log.topics):
            continue
        tag = "" if mode == "scaled" else "_payload"
        jobs += [(capacity_motor_figure, (log, mode), out / f"capacity_motors{tag}.png"),
                 (capacity_along_path_figure, (log, mode), out / f"capacity_along_path{tag}.png")]
    return jobs


def capacity_plots(log: LogData, out_dir: str | Path, workers: FigureWorkers | None = None) -> list[Path]:
    """Write capacity_motors[_payload].png and capacity_along_path[_payload].png in out_dir.

    Args:
        log: a `coopsim capacity` log.
        out_dir: the folder the figures go to.
        workers: the figure workers to draw on; None: workers started for this call only.

    Returns:
        list[Path]: the figures written.
    """
    return render_figures(capacity_jobs(log, out_dir), workers)
