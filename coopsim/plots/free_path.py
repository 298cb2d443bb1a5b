"""The object's path before and after `coopsim optimize --path` (PNG, Agg).

Drawn from the /optimize/path/{own, straight, free, free_retimed} series of the optimize log (p_C and the
rotation vector from the first waypoint's orientation, world axes), so a fresh study and a stored log are
drawn by the same code.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coopsim.io.mcap_codec import LogData
from coopsim.plots.figure import legend_beside, legend_width, panel_grid, run_title

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PATHS = {"own": (dict(color="black", ls="--", lw=1.2), "scenario's path (waypoints)"),
         "straight": (dict(color="tab:gray", ls=":", lw=1.5), "straight path"),
         "free": (dict(color="tab:blue"), "free path, scenario's time law"),
         "free_retimed": (dict(color="tab:red"), "free path, retimed")}


def path_figure(log: LogData) -> Figure:
    """The centre of mass in the world x–y plane, and the rotation about world z, of each path in the log.

    Args:
        log: an optimize log with /optimize/path/<name> series (p_C m, rotation_vector rad).

    Returns:
        Figure: two panels, x–y (equal axes) and the rotation against the normalised time t/T.
    """
    from matplotlib.figure import Figure

    names = [k for k in PATHS if f"/optimize/path/{k}" in log.topics]
    fig = Figure()
    axes = panel_grid(fig, 1, 2, (4.2, 3.4), legend=legend_width([PATHS[k][1] for k in names]))[0]
    for k in names:
        d = log.topics[f"/optimize/path/{k}"]
        style, label = PATHS[k]
        p, t = d["p_C"], d["t"]
        axes[0].plot(p[:, 0], p[:, 1], label=label, **style)
        axes[1].plot(t / max(float(t[-1]), 1e-300), np.degrees(d["rotation_vector"][:, 2]), label=label, **style)
    if names:
        p = log.topics[f"/optimize/path/{names[0]}"]["p_C"]
        axes[0].plot(p[[0, -1], 0], p[[0, -1], 1], "ko", ms=4)
    axes[0].set_aspect("equal", adjustable="datalim")
    axes[0].set_xlabel("x (m)")
    axes[0].set_ylabel("y (m)")
    axes[1].set_xlabel("t / T")
    axes[1].set_ylabel("rotation about z from the start (deg)")
    for ax in axes:
        ax.grid(alpha=0.3)
    legend_beside(axes[1])
    fig.suptitle(run_title(log, "Object path before and after"))
    return fig


def path_jobs(log: LogData, out_dir: str | Path) -> list[tuple]:
    """The path figure as a `coopsim.plots.render` job, when the log holds paths.

    Args:
        log: an optimize log.
        out_dir: the folder the figure goes to.

    Returns:
        list[tuple]: [(builder, args, out_dir/optimize_path.png)] or [].
    """
    if not any(k.startswith("/optimize/path/") for k in log.topics):
        return []
    return [(path_figure, (log,), Path(out_dir) / "optimize_path.png")]
