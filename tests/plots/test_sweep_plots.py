"""Sweep figures (coopsim.plots.sweep): the marks of a heat map on a dense grid."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection, PathCollection

from coopsim.plots import sweep as sweep_plots


def _grid_figure(nx: int, ny: int, split: int):
    """A heat map of an nx × ny grid whose points left of x index `split` saturate motor A, the rest B."""
    xs, ys = np.linspace(-0.3, 0.3, nx), np.linspace(-0.1, 0.1, ny)
    X, Y = np.meshgrid(xs, ys)
    x, y = X.ravel(), Y.ravel()
    labels = ["first saturates: A" if xi < xs[split] else "first saturates: B" for xi in x]
    fig = sweep_plots.column_figure("t", ["x", "y"], np.column_stack([x, y]), True, x + y, "v", labels)
    ax = fig.axes[0]
    marked = sum(len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection))
    borders = [seg for c in ax.collections if isinstance(c, LineCollection) for seg in c.get_segments()]
    return marked, borders, xs


def test_a_dense_grid_is_marked_on_a_sub_lattice_with_borders_between_motors():
    """41 × 3 points: more than MARKED_PER_AXIS along x, so every second x (stride ⌈40/20⌉ = 2: 21 of
    them) in each of the 3 rows is marked; the border between the two motors' regions is one vertical
    cell edge per row, halfway between x indices 19 and 20."""
    marked, borders, xs = _grid_figure(41, 3, 20)
    assert marked == 21 * 3
    assert len(borders) == 3
    assert all(np.allclose(seg[:, 0], 0.5 * (xs[19] + xs[20])) for seg in borders)


def test_a_coarse_grid_marks_every_point_and_draws_no_border():
    marked, borders, _ = _grid_figure(9, 5, 4)
    assert marked == 45 and borders == []
