"""Figures of a sweep (PNG, Agg), chosen by its number of axes: one figure per plotted column.

- one axis: the column against the axis value (a line through the points, in axis order);
- two axes: a heat map over the two axes (a grid design: cells; a quasi-random one: the points
  coloured by value);
- more: the distribution of the column over the points (a histogram).

Where the column has a sibling `…saturating_motor` (a capacity: `capacity.payload.min_energy.mass_kg`
→ `capacity.payload.min_energy.saturating_motor`), each point is marked by the motor that saturates
first there (one marker per motor, named in the legend beside the panel); where its sibling
`…feasible` is false (no mass the motors can carry) the value is left out and the point marked
"infeasible". Failed points are left out (a heat map's cell stays blank). A grid denser than
MARKED_PER_AXIS points along an axis is marked on an evenly strided sub-lattice of its points, and the
borders between regions of different saturating motors are drawn as lines between the cells.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coopsim.core.labels import field_name
from coopsim.plots.figure import LEGEND_FONT, legend_beside, legend_width, panel_grid
from coopsim.plots.render import save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PANEL = (5.2, 3.8)        # inches
COLORBAR = (0.1, 0.2, 0.85)   # inches: gap from the panel, colorbar width, room for its ticks and label
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">")
MARKED_PER_AXIS = 21      # a denser grid is marked on a sub-lattice of at most this many points per axis


def sibling(column: str, columns, name: str) -> str | None:
    """The column `name` beside a capacity column (…mass_kg → …saturating_motor, …feasible), if the rows have it.

    Args:
        column: the column plotted.
        columns: the column names the rows hold (a set or any container).
        name: the sibling's last part, 'saturating_motor' or 'feasible'.

    Returns:
        str | None: the sibling column's name; None when `column` is not a capacity column (…mass_kg) or
            the sibling is not among `columns`.
    """
    if not column.endswith("mass_kg"):
        return None
    other = column[: -len("mass_kg")] + name
    return other if other in columns else None


def marks(rows: list[dict], column: str, values: np.ndarray) -> list | None:
    """Per point the legend label of its marker, for a capacity column.

    Args:
        rows: the sweep's rows, one dict (column → value) per point.
        column: the column plotted.
        values: (P,) the column's values per point, written: infeasible points' set to nan.

    Returns:
        list | None: (P,) per point "first saturates: arm 2 joint 1", "infeasible" or None (no marker);
            None (no marks at all) when the column has no `…saturating_motor` sibling.
    """
    present = set().union(*(r.keys() for r in rows)) if rows else set()
    motor, feasible = sibling(column, present, "saturating_motor"), sibling(column, present, "feasible")
    if motor is None:
        return None
    out = []
    for k, r in enumerate(rows):
        if feasible is not None and r.get(feasible) is False:
            values[k] = np.nan
            out.append("infeasible")
        else:
            out.append(None if not r.get(motor) else f"first saturates: {r[motor]}")
    return out


def _values(rows: list[dict], column: str) -> np.ndarray:
    return np.array([float(r[column]) if isinstance(r.get(column), (int, float)) and not isinstance(r.get(column), bool)
                     else np.nan for r in rows])


def _mark(ax, x: np.ndarray, y: np.ndarray, labels: list, foot: bool = False) -> list:
    """One marker per label (a saturating motor, or "infeasible": a cross) at the points (x, y); `foot`
    (a line plot, whose infeasible points have no value): the crosses at the foot of the panel. Returns
    the legend handles."""
    handles = []
    for k, label in enumerate(_legend_labels(labels)):
        at = np.array([m == label for m in labels])
        if label == "infeasible":
            where = dict(transform=ax.get_xaxis_transform()) if foot else {}
            yy = np.full(at.sum(), 0.03) if foot else y[at]
            handles.append(ax.scatter(x[at], yy, s=28, linewidth=0.8, label=label, zorder=3, marker="x", color="black",
                                      **where))
        else:
            handles.append(ax.scatter(x[at], y[at], s=28, linewidth=0.8, label=label, zorder=3,
                                      marker=MARKERS[k % len(MARKERS)], facecolor="white", edgecolor="black"))
    return handles


def _mark_grid(ax, x: np.ndarray, y: np.ndarray, labels: list) -> list:
    """The marks of a heat map on a grid: every point's (`_mark`) on a grid of at most MARKED_PER_AXIS
    points per axis; on a denser one the points of an evenly strided sub-lattice (from the first row and
    column) and black borders between cells whose labels differ. Returns the legend
    handles."""
    xs, ys = np.unique(x), np.unique(y)
    i, j = np.searchsorted(xs, x), np.searchsorted(ys, y)
    if max(len(xs), len(ys)) <= MARKED_PER_AXIS:
        return _mark(ax, x, y, labels)
    keep = _lattice(i, len(xs)) & _lattice(j, len(ys))
    cells = np.full((len(ys), len(xs)), None, dtype=object)
    cells[j, i] = labels
    _borders(ax, cells, _edges(xs), _edges(ys))
    return _mark(ax, x[keep], y[keep], [m for m, k in zip(labels, keep) if k])


def _lattice(index: np.ndarray, count: int) -> np.ndarray:
    """Whether each grid index is on the strided sub-lattice of `_mark_grid` (from the first index)."""
    return index % -(-(count - 1) // (MARKED_PER_AXIS - 1)) == 0


def _borders(ax, cells: np.ndarray, xe: np.ndarray, ye: np.ndarray) -> None:
    """Black lines along the cell edges (xe, ye: the edges) between neighbouring cells of a (rows, columns)
    grid whose labels differ."""
    from matplotlib.collections import LineCollection

    segments = [[(xe[c + 1], ye[r]), (xe[c + 1], ye[r + 1])] for r, c in zip(*np.nonzero(cells[:, 1:] != cells[:, :-1]))]
    segments += [[(xe[c], ye[r + 1]), (xe[c + 1], ye[r + 1])] for r, c in zip(*np.nonzero(cells[1:] != cells[:-1]))]
    if segments:
        ax.add_collection(LineCollection(segments, colors="black", linewidths=1.2, zorder=2))


def _legend_labels(labels) -> list[str]:
    return sorted({m for m in labels or () if m}, key=lambda m: (m == "infeasible", m))


def column_figure(title: str, axis_names: list[str], axis_values: np.ndarray, grid: bool, values: np.ndarray,
                  column: str, motors: list | None) -> Figure:
    """The figure of one column of a sweep over its P points (module docstring: line, heat map or histogram).

    Args:
        title: the panel's title.
        axis_names: the a sweep axes' names (the axis labels).
        axis_values: (P, a) each point's axis values, in the axes' own units.
        grid: the points form a grid (a heat map draws cells).
        values: (P,) the column's value per point (nan: left out).
        column: the column's name (its axis or colorbar label).
        motors: (P,) each point's marker label (`marks`), or None: no marks.

    Returns:
        Figure: the matplotlib figure, not yet laid out or saved.
    """
    from matplotlib.figure import Figure

    labels = _legend_labels(motors)
    a = axis_values.shape[1]
    bar = sum(COLORBAR) if a == 2 else 0.0      # a heat map's colorbar stands between the panel and the legend
    fig = Figure()
    ax = panel_grid(fig, 1, 1, PANEL, legend=(legend_width(labels) if labels else 0.0) + bar)[0, 0]
    handles = []
    if a == 1:
        order = np.argsort(axis_values[:, 0], kind="stable")
        x, y = axis_values[order, 0], values[order]
        ax.plot(x, y, "-", color="tab:blue", lw=1.2, marker="." if motors is None else None)
        ax.set(xlabel=axis_names[0], ylabel=column)
        pad = 0.04 * (x[-1] - x[0])
        if pad > 0:
            ax.set_xlim(x[0] - pad, x[-1] + pad)   # every point, those without a value too
        if motors is not None:
            handles = _mark(ax, x, y, [motors[i] for i in order], foot=True)
    elif a == 2:
        x, y = axis_values[:, 0], axis_values[:, 1]
        if grid:
            xs, ys = np.unique(x), np.unique(y)
            z = np.full((len(ys), len(xs)), np.nan)
            z[np.searchsorted(ys, y), np.searchsorted(xs, x)] = values
            mesh = ax.pcolormesh(_edges(xs), _edges(ys), np.ma.masked_invalid(z), cmap="viridis", shading="flat")
        else:
            mesh = ax.scatter(x, y, c=values, cmap="viridis", s=60)
        w, _ = PANEL
        cax = ax.inset_axes([1.0 + COLORBAR[0] / w, 0.0, COLORBAR[1] / w, 1.0])
        fig.colorbar(mesh, cax=cax, label=column)
        ax.set(xlabel=axis_names[0], ylabel=axis_names[1])
        if motors is not None and grid:
            handles = _mark_grid(ax, x, y, motors)
        elif motors is not None:
            handles = _mark(ax, x, y, motors)
    else:
        ax.hist(values[np.isfinite(values)], bins=min(30, max(5, len(values) // 4)), color="tab:blue")
        ax.set(xlabel=column, ylabel="points")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, fontsize=10)
    if handles:
        _legend(ax, handles, bar)
    return fig


def _legend(ax, handles: list, offset: float) -> None:
    """The legend right of the panel (`legend_beside`), `offset` inches further out (past a colorbar)."""
    from matplotlib.transforms import ScaledTranslation

    if offset == 0.0:
        legend_beside(ax, handles)
        return
    at = ax.transAxes + ScaledTranslation(offset, 0.0, ax.get_figure().dpi_scale_trans)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), bbox_transform=at, borderaxespad=0.0,
              fontsize=LEGEND_FONT)


def _edges(centres: np.ndarray) -> np.ndarray:
    """Cell edges around sorted grid values (a single value: ±0.5, or ±half its size)."""
    if len(centres) == 1:
        h = 0.5 * abs(centres[0]) or 0.5
        return np.array([centres[0] - h, centres[0] + h])
    mid = 0.5 * (centres[1:] + centres[:-1])
    return np.concatenate([[2 * centres[0] - mid[0]], mid, [2 * centres[-1] - mid[-1]]])


def figure_name(column: str, axes: int) -> str:
    """The PNG file name of a column's figure: line_…, map_… or hist_… by the number of axes.

    Args:
        column: the column's name (made a field name by `coopsim.core.labels.field_name`).
        axes: the sweep's number of axes.

    Returns:
        str: e.g. 'map_capacity_payload_min_energy_mass_kg.png'.
    """
    return f"{'line' if axes == 1 else 'map' if axes == 2 else 'hist'}_{field_name(column)}.png"


def sweep_figures(sweep, rows: list[dict], columns: list[str], folder: Path) -> list[Path]:
    """Draw each of `columns` of the sweep's rows into `folder`, one PNG each (names by `figure_name`).

    Args:
        sweep: the validated Sweep (`coopsim.apps.sweep`: its name, axes, design and study kind are used).
        rows: one dict per point (column → value), holding each axis's value under the axis's name.
        columns: the columns to plot.
        folder: the output folder.

    Returns:
        list[Path]: the figures written, in the order of `columns`.
    """
    names = [a.name for a in sweep.axes]
    axis_values = np.array([[r[n] for n in names] for r in rows], dtype=float).reshape(len(rows), len(names))
    paths = []
    for c in columns:
        values = _values(rows, c)
        labels = marks(rows, c, values)
        title = f"{sweep.name} — {sweep.study.kind}: {c}"
        fig = column_figure(title, names, axis_values, sweep.design == "grid", values, c, labels)
        paths.append(save_figure(fig, Path(folder) / figure_name(c, len(names))))
    return paths
