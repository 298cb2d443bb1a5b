"""What every figure shares: the panel grid with room for legends beside the panels, the legends,
log axes of differences, run titles, and the log's topic prefixes.

A legend stands outside its panel, right of it (`panel_grid` keeps the room, `legend_beside` places
it), so no legend covers a curve whatever the number of joints.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from coopsim.core.labels import arm_label, metadata_arms
from coopsim.io.mcap_codec import LogData
from coopsim.plots.render import MARGIN

if TYPE_CHECKING:
    from matplotlib.figure import Figure

NATIVE, TWIN = "/native", "/mujoco"   # the log's topic prefixes: native model, MuJoCo twin
LEGEND_FONT = 8.0    # pt
LEGEND_GAP = 0.12    # inches between a panel's right edge and its legend


def legend_width(labels: list[str], fontsize: float = LEGEND_FONT) -> float:
    """Width (inches) of a one-column legend of `labels` at `fontsize`.

    The longest label measured with matplotlib's font metrics, plus matplotlib's default handle (2 em),
    text pad (0.8 em) and border pads (0.4 em each side) and the frame.

    Args:
        labels: the legend's labels (none: only the handle, pads and frame).
        fontsize: pt.

    Returns:
        float: the width, inches.
    """
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    prop, measure = FontProperties(size=fontsize), TextToPath()
    text = max((measure.get_text_width_height_descent(s, prop, ismath=False)[0] for s in labels), default=0.0)
    return (text + fontsize * (2.0 + 0.8 + 2 * 0.4) + 2.0) / 72.0


def panel_grid(fig: Figure, rows: int, cols: int, size: tuple[float, float], legend: float = 0.0,
               legend_after=None, suptitle: bool = True) -> np.ndarray:
    """A grid of panels on `fig`, with room for a legend right of chosen panel columns.

    The room is an empty grid column, so the panels, the legends and the next column's labels never meet.
    Sets the figure size for `coopsim.plots.render.fixed_layout`'s margins and gaps.

    Args:
        fig: the figure, resized.
        rows, cols: the number of panel rows and columns.
        size: (width, height) inches of each panel.
        legend: inches, the width kept for a legend (`legend_beside`); 0: none.
        legend_after: the panel columns (0-based) a legend follows; None: the last column.
        suptitle: the figure will have a suptitle (room is kept for it).

    Returns:
        np.ndarray: (rows, cols) of matplotlib Axes, the panels.
    """
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
    """The legend of `ax` (or of `handles`) outside it, right of the panel.

    It stands LEGEND_GAP inches from the panel, top edges aligned, in the room `panel_grid` keeps there.

    Args:
        ax: the panel.
        handles: the artists to list; None: the labelled artists of `ax`.
        fontsize: pt.

    Returns:
        Legend: the matplotlib legend.
    """
    from matplotlib.transforms import ScaledTranslation

    at = ax.transAxes + ScaledTranslation(LEGEND_GAP, 0.0, ax.get_figure().dpi_scale_trans)
    return ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), bbox_transform=at,
                     borderaxespad=0.0, fontsize=fontsize)


def arm_groups(log: LogData, n: int) -> list[tuple[str, slice]]:
    """The stacked joints grouped by arm, from the log's "model" metadata record.

    Args:
        log: the log read back.
        n: the number of joints of all arms (the width of the joint arrays).

    Returns:
        list[tuple[str, slice]]: (arm label, slice of its joints in the stacked order) per arm; one group
            ("joints", all n) when the record is missing or its joint counts do not add up to n.
    """
    arms = metadata_arms(log.metadata)
    if arms is None or sum(arms[1]) != n:
        return [("joints", slice(0, n))]
    names, dofs = arms
    ends = np.cumsum([0] + dofs)
    return [(arm_label(a, m), slice(int(s), int(e))) for m, (a, s, e) in enumerate(zip(names, ends[:-1], ends[1:]))]


def run_title(log: LogData, what: str, twin: bool = False) -> str:
    """A figure title naming the scenario and its settings, as the log's metadata records them.

    E.g. 'paper_planar_2x3 — Joint angle (native dop853 rtol 1e-12; MuJoCo RK4 0.001 s)'.

    Args:
        log: the log read back.
        what: what the figure shows ('Joint angle').
        twin: name the MuJoCo settings too.

    Returns:
        str: the title.
    """
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


def log_plot(ax, t: np.ndarray, y: np.ndarray, label: str, **kw) -> bool:
    """Plot the positive values of y against t on a log axis (the others left out).

    Args:
        ax: the panel; it becomes a log axis when something is drawn.
        t: (N,) s, the sample times.
        y: (N,) the values (any unit), e.g. a difference's magnitude.
        label: the curve's legend label.
        kw: passed on to `ax.semilogy`.

    Returns:
        bool: whether anything was drawn.
    """
    y = np.where(y > 0, y, np.nan)
    if not np.any(np.isfinite(y)):
        return False
    ax.semilogy(t, y, label=label, **kw)
    return True


def finish_log_axis(ax, drawn: bool, ylabel: str) -> None:
    """Labels and a grid at the decades on a panel of `log_plot` curves; a note when nothing was drawn.

    Minor ticks are off: over ten decades they are ~80 tick objects an axis, a third of the figure's
    drawing time.

    Args:
        ax: the panel.
        drawn: whether any `log_plot` on it drew something (False: "difference exactly zero" is written).
        ylabel: the y-axis label; the x-axis is time (s).
    """
    from matplotlib.ticker import LogLocator, NullLocator

    ax.set_ylabel(ylabel)
    ax.set_xlabel("time (s)")
    if ax.get_yscale() == "log":   # not when nothing was drawn (a zero difference): the axis stays linear
        ax.yaxis.set_major_locator(LogLocator(numticks=8))
        ax.yaxis.set_minor_locator(NullLocator())
    ax.grid(True, alpha=0.3)
    if not drawn:
        ax.text(0.5, 0.5, "difference exactly zero", ha="center", va="center", transform=ax.transAxes)
