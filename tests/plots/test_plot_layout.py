"""Every figure of a 7-joint-per-arm scene, drawn as the commands save it, keeps its legends off the
plotted lines — checked with matplotlib's own geometry: each legend's window extent against the display
coordinates of every drawn point of every Line2D. The scene (tests/data/planar_7r_pair.yaml:
two planar 7R arms, 14 joints) runs for 0.2 s in-process; the logs go through MCAP and back as the
commands' do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from coopsim.io.log import run_metadata, write_run_log
from coopsim.io.mcap_codec import read_mcap, write_mcap
from coopsim.twin.mujoco_run import run_twin
from coopsim.io.scenario import load_scenario
from coopsim.forward.simulate import simulate
from helpers import ROOT

SCENE = ROOT / "tests" / "data" / "planar_7r_pair.yaml"
DURATION = 0.2


@pytest.fixture(scope="module")
def model():
    return load_scenario(SCENE, duration=DURATION)


@pytest.fixture(scope="module")
def run_log(model, tmp_path_factory):
    res = simulate(model)
    tw = run_twin(model, res.initial.q, res.initial.qd, res.t)
    return read_mcap(write_run_log(tmp_path_factory.mktemp("run") / "run.mcap", model, res, tw))


@pytest.fixture(scope="module")
def inverse_log(model, tmp_path_factory):
    from coopsim.report.inverse_report import inverse_series, inverse_study

    study = inverse_study(model, curve=False)
    path = tmp_path_factory.mktemp("inverse") / "inverse.mcap"
    return read_mcap(write_mcap(path, inverse_series(study), run_metadata(model, study.sim)))


@pytest.fixture(scope="module")
def capacity_log(model, tmp_path_factory):
    from coopsim.report.inverse_report import capacity_metadata, capacity_series, capacity_study, capacity_summary

    study = capacity_study(model, optimise=False)
    meta = run_metadata(model, None, capacity_metadata(capacity_summary(study)))
    return read_mcap(write_mcap(tmp_path_factory.mktemp("capacity") / "capacity.mcap", capacity_series(study), meta))


def legend_overlaps(fig) -> list[str]:
    """What each legend of `fig` covers: '<legend's first entry> over <line label>: k points' for every
    Line2D with a drawn point (finite, inside its axes) inside the legend's window extent, and
    '<legend> over axes <title>' for a legend that reaches into a panel that has lines, or
    '<legend> outside the figure'. Geometry from the figure as last drawn."""
    renderer = fig.canvas.get_renderer()
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert legends, "the figure has no legend"
    found = []
    for legend in legends:
        box = legend.get_window_extent(renderer)
        name = legend.get_texts()[0].get_text() if legend.get_texts() else "legend"
        if not fig.bbox.contains(box.x0, box.y0) or not fig.bbox.contains(box.x1, box.y1):
            found.append(f"{name!r} outside the figure")
        for ax in fig.axes:
            lines = [ln for ln in ax.lines if ln.get_visible() and len(ln.get_xydata())]
            if lines and box.overlaps(ax.bbox):
                found.append(f"{name!r} over axes {ax.get_title()!r}")
            for line in lines:
                xy = line.get_transform().transform(line.get_xydata())
                xy = xy[np.all(np.isfinite(xy), axis=1)]
                x, y = xy.T
                drawn = (x >= ax.bbox.x0) & (x <= ax.bbox.x1) & (y >= ax.bbox.y0) & (y <= ax.bbox.y1)
                under = drawn & (x >= box.x0) & (x <= box.x1) & (y >= box.y0) & (y <= box.y1)
                if under.any():
                    found.append(f"{name!r} over {line.get_label()!r}: {int(under.sum())} points")
    return found


def _check_jobs(jobs, scene: str = "planar_7r_pair"):
    """Build every (builder, args, path) job's figure, lay it out and draw it as `coopsim.plots.render` saves
    it (Agg canvas, `fixed_layout`; without rasterising and encoding the PNG, half the time); its title
    names the scene; no legend over a line."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from coopsim.plots.render import fixed_layout

    for builder, args, path in jobs:
        fig = builder(*args)
        FigureCanvasAgg(fig)
        fixed_layout(fig)
        fig.draw_without_rendering()
        assert scene in (fig.get_suptitle() or fig.axes[0].get_title()), Path(path).name
        assert legend_overlaps(fig) == [], Path(path).name


def test_run_figures_keep_legends_off_the_lines(run_log, tmp_path):
    from coopsim.plots.run import comparison_jobs

    _check_jobs(comparison_jobs(run_log, tmp_path))


def test_inverse_figures_keep_legends_off_the_lines(inverse_log, tmp_path):
    from coopsim.plots.inverse import inverse_jobs

    _check_jobs(inverse_jobs(inverse_log, tmp_path))


def test_capacity_figures_keep_legends_off_the_lines(capacity_log, tmp_path):
    from coopsim.plots.inverse import capacity_jobs

    jobs = capacity_jobs(capacity_log, tmp_path)   # the payload mode's two figures are these builders again
    assert [Path(p).name for _, _, p in jobs] == ["capacity_motors.png", "capacity_along_path.png"]
    _check_jobs(jobs)


def test_work_precision_points_are_labelled_and_off_the_legend():
    """The committed benchmark's work-precision figure: every drawn run carries its tolerance or step
    as a label at its point, and the legend covers no line."""
    from coopsim.plots.bench import work_precision_plot

    report = json.loads((ROOT / "validation" / "results" / "bench" / "bench.json").read_text())
    scenario = report["scenarios"][0]
    fig = work_precision_plot(scenario)
    _check_jobs([(lambda: fig, (), "work_precision.png")], scenario["name"])
    runs = [r for r in scenario["runs"] if np.isfinite(r["max_error"]) and np.isfinite(r["wall_s"])]
    assert sorted(t.get_text() for t in fig.axes[0].texts) == sorted(r["label"] for r in runs)
    assert {"1e-06", "5ms"} <= {r["label"] for r in runs}, "native tolerances and MuJoCo steps"
