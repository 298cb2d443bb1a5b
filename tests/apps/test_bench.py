"""The work-precision benchmark (coopsim.apps.bench and its report, coopsim.plots.bench, `coopsim bench`):
its pieces on tiny ladders and short runs. Correctness only: no timing is asserted."""

from __future__ import annotations

import csv
import io
import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from coopsim.apps import bench
from coopsim.apps.bench import inverse, measure, runs, scaling, startup, study
from coopsim.apps.bench import Ladders, RunRow
from coopsim.apps.bench import report as bench_report
from coopsim.apps.bench.report import CSV_FIELDS, csv_text, json_text, markdown_report, write_outputs
from coopsim.cli import build_parser, main
from coopsim.core.errors import CoopsimError
from coopsim.io.overrides import parse_assignment
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS

# Tiny ladders: enough to exercise every family and table, a second or two per scenario.
TINY = Ladders(rtols=(1e-4, 1e-8), rk4_steps=(0.05, 0.025), mujoco=(("RK4", (5e-3, 2.5e-3)), ("Euler", (5e-3,))),
               pin_rtols=(1e-6,), max_duration=0.2, repeats=1, repeat_budget_s=0.0, max_repeats=1,
               eval_states=300, scaling_r=(2, 3), scaling_n=(3, 6), startup=False, inverse_dts=(0.04, 0.02),
               inverse_arms=(2, 3))


@pytest.fixture(scope="module")
def peers():
    return measure.load_peers()


@pytest.fixture(scope="module")
def spatial_short(spatial):
    """The spatial scene over 0.5 s and its reference (SimResult on the 0.05 s grid)."""
    model = replace(spatial, duration=0.5)
    return model, runs.reference(model)


@pytest.fixture(scope="module")
def report(peers):
    """A whole (tiny) report: the paper scenario and a 2 x 2 scaling grid."""
    return bench.run_bench([SCENARIOS / "paper_planar_2x3.yaml"], TINY, peers)


def _row(family, err, wall, loop=None, method="m"):
    return RunRow(family, method, "s", 0.0, "l", wall, err, 0.0, 1, loop_s=loop)


# ------------------------------------------------------------------------------------------------ pieces


def test_pareto_front_keeps_exactly_the_undominated_points():
    err = [1e-3, 1e-6, 1e-6, 1e-9, 1e-3, math.nan, 1e-12]
    wall = [1.0, 2.0, 3.0, 5.0, 0.5, 0.1, math.inf]
    # 0 is dominated by 4 (same error, faster); 2 by 1 (same error, faster); NaN/inf never on it
    assert measure.pareto_front(err, wall).tolist() == [False, True, False, True, True, False, False]
    assert measure.pareto_front([1.0, 1.0], [2.0, 2.0]).tolist() == [True, True]  # ties dominate neither


def test_power_fit_recovers_an_exact_power_law():
    x = np.array([6.0, 12.0, 14.0, 21.0])
    fit = measure.power_fit(x, 0.3 * x ** 1.7)
    assert fit["exponent"] == pytest.approx(1.7) and fit["coefficient"] == pytest.approx(0.3)
    assert fit["rms_log10"] < 1e-12


def test_best_time_repeats_and_returns_the_minimum():
    calls = []
    out, wall = measure.best_time(lambda: calls.append(1) or len(calls), repeats=4)
    assert out == 4 and len(calls) == 4 and 0 <= wall < 1


def test_max_joint_error_is_nan_for_a_diverged_run():
    ref = np.zeros((3, 2))
    assert measure.max_joint_error(np.array([[0, 1e-3], [0, -2e-3], [0, 0]]), ref) == pytest.approx(2e-3)
    assert math.isnan(measure.max_joint_error(np.array([[0, 0], [np.nan, 0], [0, 0]]), ref))


def test_headline_picks_the_fastest_run_reaching_each_target():
    rows = [_row("native", 1e-4, 0.010, 0.002), _row("native", 1e-9, 0.020, 0.004),
            _row("native", 1e-7, 0.030, 0.001), _row("native", math.nan, 0.001, 0.0001),
            _row("mujoco", 1e-4, 0.050), _row("mujoco", 5e-7, 0.300), _row("mujoco", math.nan, 0.001)]
    h = {e["target_rad"]: e for e in study.headline("paper_planar_2x3", rows)}
    assert h[1e-3]["ratio_wall"] == pytest.approx(5.0)            # 0.050 / 0.010
    assert h[1e-3]["ratio_loop"] == pytest.approx(50.0)           # 0.050 / 0.001 (fastest loop: the 1e-7 run)
    assert h[1e-6]["native"]["wall_s"] == 0.020 and h[1e-6]["ratio_wall"] == pytest.approx(15.0)
    assert h[1e-6]["met_wall"] is True and h[1e-3]["met_wall"] is True   # issue: ≥ 10x, ≥ 1x
    assert h[1e-8]["mujoco"] is None and h[1e-8]["ratio_wall"] is None and h[1e-8]["met_wall"] is None
    assert h[1e-8]["note"] == "no MuJoCo run reaches this error" and h[1e-6]["note"] == ""
    other = study.headline("some_scene", rows)
    assert all(e["required_ratio"] is None and e["met_wall"] is None for e in other)


def test_bench_duration_is_whole_output_intervals(paper):
    assert measure.bench_duration(paper, bench.FULL) == pytest.approx(5.0)
    assert measure.bench_duration(replace(paper, duration=1.23), bench.FULL) == pytest.approx(1.2)
    assert measure.bench_duration(paper, bench.QUICK) == pytest.approx(0.5)


# ------------------------------------------------------------------------------------------------ runs


def test_reference_converges_far_below_the_targets(spatial_short):
    _, ref = spatial_short
    assert ref.result.t[1] - ref.result.t[0] == pytest.approx(measure.OUTPUT_DT)
    assert 0 < ref.self_convergence < 1e-11  # measured 9e-14 rad


def test_native_errors_decrease_along_the_ladders(spatial_short):
    model, ref = spatial_short
    one = replace(TINY, repeats=1)
    dop = [runs.native_run(model, measure.adaptive_settings(model, "dop853", r), ref.result, one)
           for r in (1e-3, 1e-6, 1e-9)]
    rk4 = [runs.native_run(model, measure.rk4_settings(model, h), ref.result, one) for h in (0.05, 0.025, 0.0125)]
    for rows in (dop, rk4):
        errs = [r.max_error for r in rows]
        assert errs == sorted(errs, reverse=True) and errs[-1] < 1e-6, errs
        assert all(r.loop_s > 0 and r.wall_s > 0 and r.final_violation < 1e-10 for r in rows)
    # RK4 is fourth order: halving the step divides the error by about 16
    assert 8 < rk4[1].max_error / rk4[2].max_error < 32
    assert dop[0].setting == "rtol 1e-03, atol 1e-04" and dop[0].evals > 0


def test_mujoco_run_keeps_the_best_weld_time_constant(paper, peers, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    model = replace(paper, duration=0.3)
    ref = runs.reference(model).result
    rk4 = [runs.mujoco_run(model, ref, "RK4", dt, peers, TINY) for dt in (5e-3, 2.5e-3)]
    assert rk4[0].max_error > rk4[1].max_error  # second order in the step (weld yield ∝ timeconst²)
    for row in rk4:
        errs = row.extra["errors_by_weld_factor"]
        assert row.max_error == min(errs.values()) == errs[str(row.extra["weld_factor"])]
        assert row.evals == 4 * row.extra["nstep"]
    euler = runs.mujoco_run(model, ref, "Euler", 5e-3, peers, TINY)
    assert math.isnan(euler.extra["errors_by_weld_factor"]["1"])  # one-step weld: unstable for Euler
    assert euler.extra["weld_factor"] in (2, 4) and np.isfinite(euler.max_error)
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()  # warnings collected, not written


# ------------------------------------------------------------------------------------------------ scaling


def test_synthetic_scenes(peers):
    planar, spatial = scaling.synthetic_model(3, 3), scaling.synthetic_model(3, 7)
    assert planar.plane is not None and planar.rows.shape == (3, 6) and planar.n_total == 9
    assert spatial.plane is None and spatial.rows.shape == (6, 6) and spatial.n_total == 21
    p = scaling.scaling_point(2, 6, 200, peers, repeats=1)
    assert (p["r"], p["n_total"], p["rows"], p["planar"], p["bad_states"]) == (2, 12, 6, False, 0)
    assert all(p[k] > 0 for k in ("native_amortised_us", "native_cholesky_us", "native_python_us", "mujoco_forward_us"))
    with pytest.raises(ValueError, match="n must be 3"):
        scaling.synthetic_scene(2, 2)


def test_scaling_fits_group_by_arms_and_joints():
    pts = [{"r": r, "n": n, "n_total": r * n, "v": 2.0 * (r * n) ** 1.5} for r in (2, 3) for n in (3, 6)]
    fits = scaling.scaling_fits(pts, key="v")
    assert set(fits["in_total_joints"]) == {"2", "3"} and set(fits["in_arms"]) == {"3", "6"}
    assert fits["in_total_joints"]["3"]["exponent"] == pytest.approx(1.5)
    assert fits["all"]["exponent"] == pytest.approx(1.5)


# ------------------------------------------------------------------------------------------------ report


def test_report_shape_tables_and_json(report, paper):
    """The paper scenario on the 0.05 s grid and again on its own 0.01 s grid (Ladders.own_grid): the same
    runs, each compared on its grid; the µs per evaluation once."""
    sc, own = report["scenarios"]
    assert sc["name"] == own["name"] == "paper_planar_2x3"
    assert sc["duration_s"] == own["duration_s"] == pytest.approx(0.2)
    assert sc["output_dt_s"] == measure.OUTPUT_DT and own["output_dt_s"] == paper.integrator.output_dt == 0.01
    for s in (sc, own):
        fams = [r["family"] for r in s["runs"]]
        n_pin = len(TINY.pin_rtols) if measure.have_pinocchio() else 0
        assert fams.count("native") == 2 * len(TINY.rtols) + len(TINY.rk4_steps)
        assert fams.count("mujoco") == sum(len(steps) for _, steps in TINY.mujoco) and fams.count("pinocchio") == n_pin
        assert any(r["pareto"] for r in s["runs"])
        assert [h["target_rad"] for h in s["headline"]] == list(measure.TARGETS)
        assert s["reference"]["far_below_targets"]
    assert sc["eval_us"]["native_amortised_us"] > 0 and own["eval_us"] is None
    assert len(report["scaling"]["points"]) == 4 and report["startup"] is None and report["commands"] is None
    inv = report["inverse"]
    assert [p["samples"] for p in inv["scaling"]["in_samples"]] == [326, 651]      # 13 s every 0.04 s, 0.02 s
    assert [p["arms"] for p in inv["scaling"]["in_arms"]] == [2, 3] and inv["commands"] is None
    assert inv["point"]["samples"] == 651 and inv["point"]["point_ms"] > 0
    assert set(inv["scaling"]["fits"]) == {"point_in_samples", "trajectory_in_samples", "point_in_arms",
                                           "trajectory_in_arms"}
    data = json.loads(json_text(report))  # strict JSON: NaN written as the string "NaN"
    assert data["scenarios"][0]["runs"][0].keys() >= {"family", "wall_s", "loop_s", "max_error", "pareto"}
    rows = list(csv.reader(io.StringIO(csv_text(report))))
    assert tuple(rows[0]) == CSV_FIELDS and len(rows) == 1 + len(sc["runs"]) + len(own["runs"])
    assert {r[1] for r in rows[1:]} == {"0.05", "0.01"}
    text = markdown_report(report)
    for heading in ("## Headline", "## µs per dynamics evaluation", "## Scaling", "## The inverse side",
                    "| arms r × 6 joints | samples | IK ms | capacity point ms |",
                    "## paper_planar_2x3, 0.2 s, 0.05 s grid", "## paper_planar_2x3, 0.2 s, 0.01 s grid",
                    "| paper_planar_2x3, 0.01 s grid | 1e-03 |"):
        assert heading in text


def test_own_grid_is_the_scenarios_where_it_differs(paper, spatial):
    assert study.own_grid(paper, TINY) == 0.01 and study.own_grid(spatial, TINY) is None
    assert study.own_grid(paper, replace(TINY, own_grid=())) is None
    assert study.own_grid(replace(paper, integrator=replace(paper.integrator, output_dt=0.05)), TINY) is None


def test_write_outputs_writes_every_file(report, tmp_path):
    paths = write_outputs(report, tmp_path / "b")
    names = sorted(p.name for p in paths)
    assert names == ["bench.json", "bench.md", "runs.csv", "scaling.csv", "scaling.png",
                     "work_precision_paper_planar_2x3.png", "work_precision_paper_planar_2x3_10ms.png"]
    assert all(p.stat().st_size > 0 for p in paths)
    assert (tmp_path / "b" / "scaling.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in (tmp_path / "b").iterdir() if p.name.startswith(".")]  # no temporary files left


def test_without_pinocchio_the_rows_are_skipped_with_a_note(paper, peers, monkeypatch):
    monkeypatch.setitem(sys.modules, "pinocchio", None)   # as if pin were not installed
    one = replace(TINY, rtols=(1e-6,), rk4_steps=(), mujoco=(("RK4", (5e-3,)),), max_duration=0.1)
    sc = study.bench_scenario(paper, one, peers)
    assert not [r for r in sc["runs"] if r["family"] == "pinocchio"]
    assert "pin" in sc["notes"][0] and sc["eval_us"]["pinocchio_us"] is None


def test_cli_bench_dispatches_and_defaults_to_out_bench(tmp_path, monkeypatch, capsys):
    assert build_parser().parse_args(["bench"]).out == "out/bench"
    one = replace(TINY, rtols=(1e-6,), rk4_steps=(), mujoco=(("RK4", (5e-3,)),), pin_rtols=(),
                  max_duration=0.1, scaling_r=(2,), scaling_n=(3,))
    monkeypatch.setattr(bench, "QUICK", one)
    monkeypatch.chdir(tmp_path)
    assert main(["bench", str(SCENARIOS / "paper_planar_2x3.yaml"), "--quick", "--json", "--out", "res"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["scenarios"][0]["name"] == "paper_planar_2x3"
    assert (tmp_path / "res" / "bench.json").is_file() and not (tmp_path / "out").exists()


def test_startup_is_measured_again_when_sources_change_in_between(monkeypatch):
    stamps = iter([{"a": 1}, {"a": 2}, {"a": 2}, {"a": 2}])
    runs = []
    monkeypatch.setattr(startup, "_source_stamps", lambda: next(stamps))
    monkeypatch.setattr(startup, "_startup_once", lambda path: runs.append(path) or {"compile_s": 30.0, "cached_s": 1.0})
    out = startup.startup_times(SCENARIOS / "paper_planar_2x3.yaml")
    assert len(runs) == 2 and out["sources_changed"] is False and runs[0].endswith("paper_planar_2x3.yaml")


def test_startup_script_reports_its_phases_from_a_filled_cache():
    wall, phases = startup.startup_process(str(SCENARIOS / "paper_planar_2x3.yaml"), warm=False)
    assert set(phases) == {"imports", "first", "again"}, f"phases {phases}"
    assert 0 < phases["again"] < phases["first"] < wall, f"wall {wall:.3f} s, phases {phases}"


def test_command_times_take_the_minimum_and_judge_the_targets(monkeypatch):
    """The commands run as a user runs them (`python -m coopsim.cli CMD SCENARIO … --json --out DIR`); the
    minimum over the repeats is compared with the target; exit 1 (a failed check) still counts, exit 2
    is an error naming the command. (Subprocesses replaced here: the real ones run in `coopsim bench`.)"""
    calls, clock = [], iter([0.0, 4.0, 10.0, 12.5, 20.0, 23.0, 30.0, 32.0])
    monkeypatch.setattr(startup.time, "perf_counter", lambda: next(clock))
    monkeypatch.setattr(startup.subprocess, "run", lambda cmd, **kw: calls.append(cmd) or
                        subprocess.CompletedProcess(cmd, 1 if "capacity" in cmd else 0, "", ""))
    times = startup.command_times("s.yaml", repeats=2, commands={"run": (["run"], 3.0), "capacity": (["capacity"], 1.5)})
    assert times == {"run": {"wall_s": 2.5, "target_s": 3.0, "met": True},
                     "capacity": {"wall_s": 2.0, "target_s": 1.5, "met": False}}
    assert calls[0][1:5] == ["-m", "coopsim.cli", "run", "s.yaml"] and calls[0][5:7] == ["--json", "--out"]
    assert "| `coopsim capacity` | 2.00 | 1.5 | NO |" in bench_report.command_lines(times)
    monkeypatch.setattr(startup.subprocess, "run", lambda cmd, **kw: subprocess.CompletedProcess(cmd, 2, "", "bad\n"))
    monkeypatch.setattr(startup.time, "perf_counter", lambda: 0.0)
    with pytest.raises(CoopsimError, match="coopsim run failed"):
        startup.command_times("s.yaml", repeats=1, commands={"run": (["run"], 3.0)})


@pytest.mark.parametrize("r", [2, 3])
def test_the_synthetic_carry_starts_at_the_initial_pose_and_lifts_the_box(r):
    """The carry's first waypoint is the object pose of the scene's initial angles (its IK gives them
    back), the last one 5 cm above it: checked by forward kinematics of the IK's joint angles (1e-9 m and
    rad: the IK converges to 1e-13; angles of a 6R arm are not a unique answer, the pose is)."""
    from coopsim.inverse.trajectory import object_motion_trajectory, object_pose_of
    model = inverse.synthetic_carry(r, 6)
    traj = object_motion_trajectory(model, model.inverse.object_motion)
    p0, R0 = object_pose_of(model, model.q0)
    p_start, R_start = object_pose_of(model, traj.q[0])
    p_end, R_end = object_pose_of(model, traj.q[-1])
    assert np.abs(p_start - p0).max() < 1e-9 and np.abs(R_start - R0).max() < 1e-9
    assert np.abs(p_end - p0 - [0.0, 0.0, 0.05]).max() < 1e-9 and np.abs(R_end - R0).max() < 1e-9
    assert len(traj.t) == 101 and model.motors.stall_torque.tolist() == [100.0] * 6 * r


def test_minimal_overrides_cut_a_study_to_its_fewest_samples(paper):
    """The command's fixed start-up is measured on the same command with these overrides: the carry's
    motion sampled at its two ends only, a forward scene for one 0.01 s step."""
    carry = SCENARIOS / "paper_planar_2x3_carry.yaml"
    words = inverse.minimal_overrides(load_scenario(carry))
    cut = load_scenario(carry, overrides=[parse_assignment(w) for w in words[1::2]])
    om = cut.inverse.object_motion
    assert words[0] == "--set" and (om.times[-1] - om.times[0]) / om.output_dt + 1 == 2
    words = inverse.minimal_overrides(paper)
    cut = load_scenario(SCENARIOS / "paper_planar_2x3.yaml", overrides=[parse_assignment(w) for w in words[1::2]])
    assert cut.duration == 0.01 and cut.integrator.output_dt == 0.01


def test_command_overheads_are_the_difference_of_the_two_walls(monkeypatch):
    """Each command on each scene twice: as given and with `minimal_overrides`; the difference is judged
    against the 1 s margin. (Processes replaced here: the real ones run in `coopsim bench`.)"""
    calls = []
    monkeypatch.setattr(inverse, "command_wall", lambda words, repeats, cwd: calls.append(words) or
                        (1.2 if "--set" in words else (2.5 if words[0] == "capacity" else 2.0)))
    rows = inverse.command_overheads(scenes=("scenarios/paper_planar_2x3_carry.yaml",))
    assert [(r["command"], r["above_s"], r["met"]) for r in rows] == [("capacity", pytest.approx(1.3), False),
                                                                      ("inverse --replay", pytest.approx(0.8), True)]
    assert calls[0][:2] == ["capacity", "scenarios/paper_planar_2x3_carry.yaml"] and "--set" in calls[1]
    assert "| paper_planar_2x3_carry | `coopsim capacity` | 2.50 | 1.20 | 1.30 | NO |" in \
        bench_report.inverse_lines({"point": rows and {"samples": 1, "point_ms": 1.0, "trajectory_ms": 1.0},
                                    "scaling": {"in_samples": [], "in_arms": [], "fits": {}}, "commands": rows})


def test_the_sources_it_stamps_and_digests_are_the_package_s():
    """The start-up stamps cover the compiled kernels' sources and the source digest the whole package
    (paths found from the package, wherever the benchmark's own files sit)."""
    stamps = startup._source_stamps()
    assert any(p.endswith("compiled/api.py") for p in stamps) and all("/compiled/" in p for p in stamps)
    state = bench.source_state()
    assert len(state["sources_sha256"]) == 12 and (state["git_head"] is None or len(state["git_head"]) == 40)
    assert bench.source_state()["sources_sha256"] == state["sources_sha256"]


@pytest.mark.parametrize("diverged_at, note", [
    (None, "no finite error for any weld time constant"),
    (0.25, "no finite error for any weld time constant (at t = 0.25 s)")])
def test_a_twin_with_no_finite_error_is_a_row_with_a_note(paper, diverged_at, note):
    """Every weld time constant leaving NaN angles (a reset by MuJoCo, or NaN without one) is one row
    with max_error NaN and a note, never an exception (peers stubbed: no MuJoCo run here)."""
    from types import SimpleNamespace

    t = np.array([0.0, 0.5])
    ref = SimpleNamespace(initial=SimpleNamespace(q=paper.q0, qd=np.zeros(paper.n_total)), t=t,
                          q=np.zeros((2, paper.n_total)))
    roll = SimpleNamespace(q=np.full((2, paper.n_total), np.nan), wall_time=0.0, diverged_at=diverged_at, nstep=10,
                           weld_violation=np.array([0.0, np.nan]))
    peers = SimpleNamespace(mujoco_twin=lambda *a: None, twin_rollout=lambda *a: roll)
    row = runs.mujoco_run(paper, ref, "RK4", 5e-3, peers, replace(TINY, repeats=1))
    assert math.isnan(row.max_error) and row.note == note and row.family == "mujoco"
