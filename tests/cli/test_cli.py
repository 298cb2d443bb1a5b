"""End-to-end: the real `coopsim` command in a temporary folder, checking numbers."""

import json
import shutil

import pytest
import yaml

from helpers import SCENARIOS, run_cli




def test_simulate_paper_reports_the_projection(workdir):
    out = run_cli("simulate", "scenarios/paper_planar_2x3.yaml", "--json", cwd=workdir)
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    assert s["duration_s"] == pytest.approx(5.0)
    ic = s["initial_correction"]
    # regression pin (number produced by coopsim itself); checked by hand in test_manifold.py /
    # test_scenario.py (conftest.paper_residual_by_hand: 3.114654e-5 m)
    assert ic["residual_before"] == pytest.approx(3.1147e-5, rel=1e-3), f"residual before projection {ic['residual_before']}"
    assert ic["residual_after"] <= 1e-12
    assert 1e-6 < ic["max_abs_dq_rad"] < 1e-4
    assert s["max_constraint_residual"] <= 1e-10
    text = run_cli("simulate", "scenarios/paper_planar_2x3.yaml", "--duration", "0.1", cwd=workdir)
    assert "loop-closure residual 3.11e-05 -> " in text.stdout


def test_validate_fails_on_a_wrong_twin_naming_the_quantity(workdir):
    data = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())
    data["mujoco"]["object_mass_scale"] = 1.01
    (workdir / "wrong.yaml").write_text(yaml.safe_dump(data))
    out = run_cli("validate", "wrong.yaml", "--duration", "1", cwd=workdir)
    assert out.returncode == 1
    assert "FAIL: joint angle error" in out.stdout
    assert ": not the twin's weld yield (predicted " in out.stdout and "the models disagree" in out.stdout
    assert "cross-validation: 0/1 scenarios agree" in out.stdout


def test_validate_json_passes_on_the_paper_scenario(workdir):
    out = run_cli("validate", "scenarios/paper_planar_2x3.yaml", "--duration", "1", "--json", cwd=workdir)
    assert out.returncode == 0, out.stdout + out.stderr
    table = json.loads(out.stdout)
    metric = table["scenarios"][0]["metrics"]["joint angle error"]
    assert table["passed"] and metric["max"] <= 1e-7


def test_bad_scenario_is_one_line_and_exit_2(workdir):
    data = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())
    data["arms"][0]["links"][0]["box"]["density"] = -1
    (workdir / "bad.yaml").write_text(yaml.safe_dump(data))
    out = run_cli("simulate", "bad.yaml", cwd=workdir)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0
    assert "arms[0].links[0].box.density: must be positive" in out.stderr
    missing = run_cli("simulate", "nope.yaml", cwd=workdir)
    assert missing.returncode == 2 and "scenario file not found" in missing.stderr


def test_run_writes_log_plots_and_summary(workdir):
    out = run_cli("run", "scenarios/paper_planar_2x3.yaml", "--duration", "0.5", "--out", "res", cwd=workdir)
    assert out.returncode == 0, out.stdout + out.stderr
    res = workdir / "res"
    summary = json.loads((res / "summary.json").read_text())
    assert summary["agreement"]["passed"]
    assert summary["agreement"]["metrics"]["joint angle error"]["max"] <= 1e-7
    assert summary["wall_time_s"]["native"] > 0 and summary["wall_time_s"]["mujoco"] > 0
    # regression pin (number produced by coopsim itself); checked by hand: conftest.paper_residual_by_hand
    assert summary["native"]["initial_correction"]["residual_before"] == pytest.approx(3.1147e-5, rel=1e-3), \
        "residual before projection in summary.json"
    pngs = sorted(p.name for p in res.glob("*.png"))
    assert pngs == ["constraint_violation.png", "joint_angles.png", "joint_rates.png", "object_motion.png"]
    log = res / "paper_planar_2x3.mcap"
    elsewhere = workdir / "elsewhere"
    shutil.copytree(workdir / "scenarios", elsewhere / "scenarios")
    again = run_cli("run", "scenarios/paper_planar_2x3.yaml", "--duration", "0.5", "--out", "res", cwd=elsewhere,
                    process=True)   # another process too: another hash seed
    assert again.returncode == 0
    assert (elsewhere / "res" / log.name).read_bytes() == log.read_bytes(), \
        "re-running in another working folder must give a byte-identical log"
    assert not list(res.glob(".*.tmp")), "no temporary files left behind"
    replot = run_cli("plot", str(log), "--out", "replot", cwd=workdir)
    assert replot.returncode == 0, replot.stderr
    assert len(list((workdir / "replot").glob("*.png"))) == 4


def test_every_command_has_help(workdir):
    for cmd in ("simulate", "run", "validate", "plot", "mjcf"):
        out = run_cli(cmd, "--help", cwd=workdir)
        assert out.returncode == 0 and "usage: coopsim" in out.stdout
