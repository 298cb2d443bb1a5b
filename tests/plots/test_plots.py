"""Comparison plots from a run log: four PNGs, with and without the MuJoCo twin."""

from __future__ import annotations

import dataclasses
import signal
import time
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from coopsim.io.log import write_run_log
from coopsim.io.mcap_codec import read_mcap
from coopsim.twin.mujoco_run import run_twin
from coopsim.plots.run import FILES, comparison_plots
from coopsim.forward.simulate import simulate

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


def test_comparison_plots_of_both_models_and_of_the_native_one_alone(logs, tmp_path):
    both, native = logs
    assert "/mujoco/joint_state" not in native.topics
    paths = comparison_plots(native, tmp_path)
    _check_pngs(paths, tmp_path)
    full = comparison_plots(both, tmp_path / "both")
    _check_pngs(full, tmp_path / "both")
    # without the difference rows the joint figure is shorter than the comparison one
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
    """Titles carry the scenario's name and the integrator settings the log records."""
    from coopsim.plots import run as plots
    from coopsim.core.joints import COORDINATE

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
    from coopsim.report.inverse_report import inverse_series, solve_study
    from coopsim.io.log import run_metadata
    from coopsim.io.mcap_codec import log_data
    from coopsim.plots.inverse import MOTOR_LINES, inverse_torques_figure
    from coopsim.io.scenario import load_scenario
    from helpers import SCENARIOS

    model = load_scenario(SCENARIOS / "paper_planar_2x3.yaml")
    study = solve_study(model, duration=0.3)                   # what `coopsim inverse` logs, in memory
    fig = inverse_torques_figure(log_data(inverse_series(study), run_metadata(model, study.sim)))
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert len(legends) == 1, "one legend for every panel"
    texts = [t.get_text() for t in legends[0].get_texts()]
    assert texts.count(MOTOR_LINES) == 1 and len(texts) == 6, texts


def _panel(fig, title):
    return next(ax for ax in fig.axes if ax.get_title() == title)


def test_object_orientation_panel_against_the_heading_by_hand(logs):
    """The orientation column of the object figure: the paper's bar turns about z only, so the
    rotation vector from t = 0 is [0, 0, ψ(t) − ψ(0)] with ψ = 2 atan2(q_z, q_w) of the logged
    quaternion [w, x, y, z]; the difference panel is the angle between the two models' orientations,
    here |ψ_native − ψ_mujoco|."""
    from coopsim.plots import run as plots

    both, _ = logs
    fig = plots._object_figure(both)
    heading = {}
    for prefix in ("/native", "/mujoco"):
        q = both.topics[prefix + "/object"]["quaternion"]
        heading[prefix] = 2 * np.arctan2(q[:, 3], q[:, 0])
    top = _panel(fig, "Object orientation (rotation vector)")
    assert "rad" in top.get_ylabel()
    native = [ln.get_ydata() for ln in top.lines if not ln.get_label().endswith("(MuJoCo)")]
    twin = [ln.get_ydata() for ln in top.lines if ln.get_label().endswith("(MuJoCo)")]
    turn = heading["/native"] - heading["/native"][0]
    assert np.ptp(turn) > 1e-3, "the bar turns"
    np.testing.assert_allclose(native[2], turn, rtol=0, atol=1e-13)
    np.testing.assert_allclose(twin[2], heading["/mujoco"] - heading["/native"][0], rtol=0, atol=1e-13)
    assert max(np.max(np.abs(native[0])), np.max(np.abs(native[1]))) < 1e-13
    diff = _panel(fig, "orientation (rotation vector): native − MuJoCo").lines[0].get_ydata()
    want = np.abs(heading["/native"] - heading["/mujoco"])
    drawn = np.isfinite(diff)
    assert drawn.sum() >= len(diff) - 1 and np.max(want) > 1e-12
    np.testing.assert_allclose(diff[drawn], want[drawn], rtol=1e-6, atol=1e-15)


def _wrapped_log(both):
    """`both` with its angles wrapped into (−π, π], joint 1 passing π between two samples mid-run."""
    q = both.topics["/native/joint_state"]["angle"]
    mid = len(q) // 2
    shift = np.pi - 0.5 * (q[mid, 0] + q[mid + 1, 0])     # joint 1 crosses π between two samples mid-run
    assert np.ptp(q[:, 0]) > 1e-3 and np.all(np.diff(q[:, 0]) > 0)

    def wrapped(a):
        return np.mod(a + shift + np.pi, 2 * np.pi) - np.pi

    topics = dict(both.topics)
    for prefix in ("/native", "/mujoco"):
        topics[prefix + "/joint_state"] = dict(topics[prefix + "/joint_state"],
                                               angle=wrapped(topics[prefix + "/joint_state"]["angle"]))
    assert np.max(np.abs(np.diff(topics["/native/joint_state"]["angle"][:, 0]))) > 6, "the log jumps by 2π"
    return dataclasses.replace(both, topics=topics)


def test_joint_angles_are_drawn_unwrapped(logs):
    """A log whose angles are wrapped into (−π, π] (joint 1 passing π mid-run) is drawn continuous, for
    both models, with 'unwrapped' in the axis label, and its difference panel stays at the models'
    difference (not 2π)."""
    from coopsim.plots import run as plots
    from coopsim.core.joints import COORDINATE

    both, _ = logs
    fig = plots._joint_figure(_wrapped_log(both), "angle", "angle", COORDINATE, [f"j{i}" for i in range(6)])
    top = fig.axes[0]
    assert top.get_ylabel() == "angle (rad, unwrapped)"
    for line, prefix in zip(top.lines[:2], ("/native", "/mujoco")):   # joint 1, native and MuJoCo
        y, logged = line.get_ydata(), both.topics[prefix + "/joint_state"]["angle"][:, 0]
        np.testing.assert_allclose(y - y[0], logged - logged[0], rtol=0, atol=1e-12)
    diff = fig.axes[2].lines[0].get_ydata()      # arm 1's difference panel, joint 1
    assert np.nanmax(diff) < 1e-6


def test_prismatic_coordinates_are_not_unwrapped(logs):
    """The same wrapped log with joint 1 recorded as prismatic: its coordinate (m) is drawn exactly as
    logged, jump included (unwrapping metres by 2π would invent motion), while arm 2's revolute angles
    are still unwrapped; each arm's axis names its units."""
    import json

    from coopsim.plots import run as plots
    from coopsim.core.joints import COORDINATE

    both, _ = logs
    log = _wrapped_log(both)
    types = ["prismatic"] + ["revolute"] * 5
    log = dataclasses.replace(log, metadata=dict(log.metadata, model=dict(log.metadata["model"],
                                                                         joint_types=json.dumps(types))))
    fig = plots._joint_figure(log, "angle", "angle", COORDINATE, [f"j{i}" for i in range(6)])
    arm1, arm2 = fig.axes[0], fig.axes[1]
    assert arm1.get_ylabel() == "angle (m or rad, unwrapped)" and arm2.get_ylabel() == "angle (rad, unwrapped)"
    for line, prefix in zip(arm1.lines[:2], ("/native", "/mujoco")):
        np.testing.assert_array_equal(line.get_ydata(), log.topics[prefix + "/joint_state"]["angle"][:, 0])
    wrapped_rev = log.topics["/native/joint_state"]["angle"][:, 3]
    np.testing.assert_allclose(arm2.lines[0].get_ydata(), np.unwrap(wrapped_rev), rtol=0, atol=0)


def test_costly_figures_are_handed_out_first_and_paths_keep_job_order():
    """`FigureWorkers.render(jobs, first)`: the jobs in `first` go to the workers before the others (a
    recording pool stands in for the processes); the paths come back in job order."""
    from concurrent.futures import Future

    from coopsim.plots.render import FigureWorkers

    submitted = []

    class Pool:
        def submit(self, fn, job):
            submitted.append(job[2])
            done = Future()
            done.set_result(job[2])
            return done

    workers = FigureWorkers(n=0)
    workers.pool = Pool()
    jobs = [(None, (), f"{name}.png") for name in ("angles", "rates", "object", "constraint")]
    assert [p.name for p in workers.render(jobs, first=(2,))] == ["angles.png", "rates.png", "object.png", "constraint.png"]
    assert submitted == ["object.png", "angles.png", "rates.png", "constraint.png"]
    workers.pool = None


def _ignored_signals(pid: int) -> int:
    """The mask of signals process `pid` ignores (bit n - 1 for signal n), from /proc."""
    status = Path(f"/proc/{pid}/status").read_text()
    return int(next(ln.split()[1] for ln in status.splitlines() if ln.startswith("SigIgn:")), 16)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the workers' signal masks from /proc")
def test_figure_workers_leave_signals_to_the_command_and_stop_at_once():
    """The workers ignore SIGINT and SIGTERM (a terminal's Ctrl-C and a service stop reach the whole process
    group; the command stops its workers itself), and `close(stop=True)` ends them in the middle of a job."""
    from coopsim.plots.render import FigureWorkers

    workers = FigureWorkers(warm=False)
    if workers.pool is None:
        pytest.skip("no fork or a single core: no worker processes")
    both = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))
    try:
        workers.pool.submit(time.sleep, 60)
        pids = list(workers.pool._processes)
        deadline = time.monotonic() + 30
        while not all(_ignored_signals(pid) & both == both for pid in pids):   # each worker's initializer ran
            assert time.monotonic() < deadline, [hex(_ignored_signals(pid)) for pid in pids]
            time.sleep(0.02)
    finally:
        workers.close(stop=True)
    assert len(pids) == 2 and not any(Path(f"/proc/{pid}").exists() for pid in pids)
