"""Figures of a sweep (PNG, Agg), chosen by its number of axes: one figure per plotted column.

- one axis: the column against the axis value (a line through the points, in axis order);
- two axes: a heat map over the two axes (a grid design: cells; a quasi-random one: the points
  coloured by value);
- more: the distribution of the column over the points (a histogram).

Where the column has a sibling `…saturating_motor` (a capacity: `capacity.payload.min_energy.mass_kg`
→ `capacity.payload.min_energy.saturating_motor`), each point is marked by the motor that saturates
first there (one marker per motor, named in the legend beside the panel). Failed points are left out
(a heat map's cell stays blank).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .plots import legend_beside, legend_width, panel_grid
from .render import save_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PANEL = (5.2, 3.8)        # inches
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">")


def motor_column(column: str, columns) -> str | None:
    """The saturating-motor column that belongs to `column` (…mass_kg), if the rows have it."""
    if not column.endswith("mass_kg"):
        return None
    sibling = column[: -len("mass_kg")] + "saturating_motor"
    return sibling if sibling in columns else None


def _values(rows: list[dict], column: str) -> np.ndarray:
    return np.array([float(r[column]) if isinstance(r.get(column), (int, float)) and not isinstance(r.get(column), bool)
                     else np.nan for r in rows])


def _mark_motors(ax, x: np.ndarray, y: np.ndarray, motors: list) -> list:
    """One marker per saturating motor at the points (x, y); returns the legend handles."""
    handles = []
    labels = sorted({m for m in motors if m}, key=str)
    for k, label in enumerate(labels):
        at = np.array([m == label for m in motors])
        handles.append(ax.scatter(x[at], y[at], marker=MARKERS[k % len(MARKERS)], s=28, facecolor="white",
                                  edgecolor="black", linewidth=0.8, label=f"first saturates: {label}", zorder=3))
    return handles


def column_figure(title: str, axis_names: list[str], axis_values: np.ndarray, grid: bool, values: np.ndarray,
                  column: str, motors: list | None) -> Figure:
    """One column of a sweep over its points: axis_values (P, a), values (P,) (nan: a failed point),
    motors (P,) the saturating motor's label per point or None; `grid`: the points form a grid."""
    from matplotlib.figure import Figure

    labels = [f"first saturates: {m}" for m in sorted({m for m in motors or () if m}, key=str)]
    fig = Figure()
    ax = panel_grid(fig, 1, 1, PANEL, legend=legend_width(labels) if labels else 0.0)[0, 0]
    a = axis_values.shape[1]
    handles = []
    if a == 1:
        order = np.argsort(axis_values[:, 0], kind="stable")
        x, y = axis_values[order, 0], values[order]
        ax.plot(x, y, "-", color="tab:blue", lw=1.2, marker="." if motors is None else None)
        ax.set(xlabel=axis_names[0], ylabel=column)
        if motors is not None:
            handles = _mark_motors(ax, x, y, [motors[i] for i in order])
    elif a == 2:
        x, y = axis_values[:, 0], axis_values[:, 1]
        if grid:
            xs, ys = np.unique(x), np.unique(y)
            z = np.full((len(ys), len(xs)), np.nan)
            z[np.searchsorted(ys, y), np.searchsorted(xs, x)] = values
            mesh = ax.pcolormesh(_edges(xs), _edges(ys), np.ma.masked_invalid(z), cmap="viridis", shading="flat")
        else:
            mesh = ax.scatter(x, y, c=values, cmap="viridis", s=60)
        fig.colorbar(mesh, ax=ax, label=column, pad=0.02)
        ax.set(xlabel=axis_names[0], ylabel=axis_names[1])
        if motors is not None:
            handles = _mark_motors(ax, x, y, motors)
    else:
        ax.hist(values[np.isfinite(values)], bins=min(30, max(5, len(values) // 4)), color="tab:blue")
        ax.set(xlabel=column, ylabel="points")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, fontsize=10)
    if handles:
        legend_beside(ax, handles)
    return fig


def _edges(centres: np.ndarray) -> np.ndarray:
    """Cell edges around sorted grid values (a single value: ±0.5, or ±half its size)."""
    if len(centres) == 1:
        h = 0.5 * abs(centres[0]) or 0.5
        return np.array([centres[0] - h, centres[0] + h])
    mid = 0.5 * (centres[1:] + centres[:-1])
    return np.concatenate([[2 * centres[0] - mid[0]], mid, [2 * centres[-1] - mid[-1]]])


def figure_name(column: str, axes: int) -> str:
    from .sweep_run import field_name

    return f"{'line' if axes == 1 else 'map' if axes == 2 else 'hist'}_{field_name(column)}.png"


def sweep_figures(sweep, rows: list[dict], columns: list[str], folder: Path) -> list[Path]:
    """Draw each of `columns` of the sweep's rows into `folder` (names by `figure_name`); their paths."""
    names = [a.name for a in sweep.axes]
    axis_values = np.array([[r[n] for n in names] for r in rows], dtype=float).reshape(len(rows), len(names))
    present = set().union(*(r.keys() for r in rows)) if rows else set()
    paths = []
    for c in columns:
        mc = motor_column(c, present)
        motors = None if mc is None else [r.get(mc) for r in rows]
        title = f"{sweep.name} — {sweep.study.kind}: {c}"
        fig = column_figure(title, names, axis_values, sweep.design == "grid", _values(rows, c), c, motors)
        paths.append(save_figure(fig, Path(folder) / figure_name(c, len(names))))
    return paths
