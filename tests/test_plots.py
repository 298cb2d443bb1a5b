"""Comparison plots from a run log: four PNGs, with and without the MuJoCo twin."""

from __future__ import annotations

import dataclasses

import matplotlib.image as mpimg
import pytest

from coopsim.log import read_mcap, write_run_log
from coopsim.mujoco_run import run_twin
from coopsim.plots import FILES, comparison_plots
from coopsim.simulate import simulate

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def logs(paper, tmp_path_factory):
    model = dataclasses.replace(paper, duration=0.2)
    res = simulate(model)
    tw = run_twin(model, res.initial.q, res.initial.qd, res.t)
    folder = tmp_path_factory.mktemp("logs")
    both = read_mcap(write_run_log(folder / "both.mcap", model, res, tw))
    native = read_mcap(write_run_log(folder / "native.mcap", model, res, None))
    return both, native


def _check_pngs(paths, folder):
    assert [p.name for p in paths] == list(FILES)
    assert sorted(p.name for p in folder.iterdir()) == sorted(FILES)  # no temporary files left
    for p in paths:
        assert p.read_bytes()[:8] == PNG_SIGNATURE
        img = mpimg.imread(p)
        assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 400


def test_comparison_plots_of_both_models(logs, tmp_path):
    both, _ = logs
    out = tmp_path / "plots"
    _check_pngs(comparison_plots(both, out), out)


def test_native_only_log_is_plotted(logs, tmp_path):
    both, native = logs
    assert "/mujoco/joint_state" not in native.topics
    paths = comparison_plots(native, tmp_path)
    _check_pngs(paths, tmp_path)
    # without the difference rows the joint figure is shorter than the comparison one
    full = comparison_plots(both, tmp_path / "both")
    assert mpimg.imread(paths[0]).shape[0] < mpimg.imread(full[0]).shape[0]


def test_plots_replace_existing_files_and_check_joint_names(logs, tmp_path):
    both, _ = logs
    (tmp_path / "joint_angles.png").write_bytes(b"stale")
    paths = comparison_plots(both, tmp_path, joint_names=[f"j{i}" for i in range(6)])
    assert paths[0].read_bytes()[:8] == PNG_SIGNATURE
    with pytest.raises(ValueError, match="joint_names: expected 6 names, got 2"):
        comparison_plots(both, tmp_path, joint_names=["a", "b"])


def test_a_twin_identical_to_the_native_model_is_plotted(logs, tmp_path):
    """Differences exactly zero (a scene at rest): the difference panels stay linear and say so
    (a log locator on them raised 'Data cannot be log-scaled')."""
    both, _ = logs
    topics = dict(both.topics)
    for key in list(topics):
        if key.startswith("/mujoco/") and ("/native/" + key[len("/mujoco/"):]) in topics:
            native = topics["/native/" + key[len("/mujoco/"):]]
            topics[key] = {k: (native[k] if k in native else v) for k, v in topics[key].items()}
    same = dataclasses.replace(both, topics=topics)
    out = tmp_path / "same"
    _check_pngs(comparison_plots(same, out), out)


def test_every_figure_names_its_scenario_and_settings(logs):
    """Titles carry the scenario's name and the integrator settings the log records (issue 10)."""
    from coopsim import plots
    from coopsim.joints import COORDINATE

    both, native = logs
    labels = [f"j{i}" for i in range(6)]
    figs = [plots._joint_figure(both, "angle", "angle", COORDINATE, labels), plots._object_figure(both)]
    titles = [f.get_suptitle() for f in figs] + [plots._constraint_figure(both).axes[0].get_title()]
    for title in titles:
        assert title.startswith("paper_planar_2x3 — ") and "native dop853 rtol 1e-12" in title, title
        assert "MuJoCo RK4 0.001 s" in title, title
    alone = plots._joint_figure(native, "angle", "angle", COORDINATE, labels).get_suptitle()
    assert alone == "paper_planar_2x3 — Joint angle (native dop853 rtol 1e-12)", alone


def test_inverse_torque_figure_names_the_motor_lines_in_its_legend(tmp_path):
    """The grey motor lines of Fig. 6 are in the legend (once), with every resolution."""
    from coopsim.cli import main
    from coopsim.plots_inverse import MOTOR_LINES, inverse_torques_figure
    from conftest import SCENARIOS

    assert main(["inverse", str(SCENARIOS / "paper_planar_2x3.yaml"), "--duration", "0.3", "--no-curve",
                 "--out", str(tmp_path), "--json"]) == 0
    fig = inverse_torques_figure(read_mcap(tmp_path / "inverse.mcap"))
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts.count(MOTOR_LINES) == 1 and len(texts) == 6, texts
