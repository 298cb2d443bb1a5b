"""The hard-case scenarios (scenarios/hard/, README "Hard cases"): each runs, and says what is hard about
it — as a warning naming time, configuration and reason, an error where the scenario asks for one, or
numbers checked against an independent computation (MuJoCo's own energy and Jacobians, the planar 3R
Jacobian's determinant l₁l₂ sin θ₂, the MuJoCo twin, a tight-tolerance run). Also what a run leaves on
disk: the whole set of outputs or nothing, when it fails or is killed."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from coopsim import cli
from coopsim.core.errors import ConstraintError, ScenarioError, SimulationError
from coopsim.twin.harness import cross_validate
from coopsim.io.log import write_run_log
from coopsim.io.mcap_codec import read_mcap
from coopsim.twin.mjcf import build_spec, dof_address, qpos_address
from coopsim.io.scenario import load_scenario, model_from_dict
from coopsim.io.yaml_rules import load_yaml
from coopsim.forward.simulate import simulate
from coopsim.report.summary import simulation_summary
from helpers import SCENARIOS

HARD = SCENARIOS / "hard"


def hard(name: str, **changes):
    """The model of scenarios/hard/NAME.yaml; `changes` {"integrator.key": value} edit the file's data."""
    data = load_yaml(HARD / f"{name}.yaml")
    for key, value in changes.items():
        *path, last = key.split(".")
        node = data
        for k in path:
            node = node.setdefault(k, {})
        node[last] = value
    return model_from_dict(data, where=f"{name}.yaml", base_dir=HARD)


def kinds(res) -> list[str]:
    return [w.kind for w in res.warnings]


def mujoco_at(model):
    """The MuJoCo twin's model and data, and a function setting its state to the native (q, qd)."""
    m = build_spec(model).compile()
    m.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    d = mujoco.MjData(m)
    qa, da = qpos_address(m, model), dof_address(m, model)

    def put(q, qd):
        d.qpos[qa], d.qvel[da] = q, qd
        mujoco.mj_forward(m, d)
        return d

    return m, d, put, da


def test_near_singular_chain_warns_and_can_stop():
    """1e-3 rad from a singular chain: cond 2.6e9 and a 5 kN internal force from <= 0.5 N·m torques,
    named in one warning; integrator.on_ill_conditioning: error stops at the first such sample."""
    res = simulate(hard("near_singular_chain"))
    (w,) = [w for w in res.warnings if w.kind == "ill_conditioned"]
    assert w.values["condition_number"] == pytest.approx(np.max(res.cond)) and w.values["condition_number"] > 1e9
    assert w.values["internal_force_N"] > 1e3 and np.max(np.abs(res.tau)) <= 0.5
    assert w.t == res.t[np.argmax(res.cond)] and np.array_equal(w.q, res.q[np.argmax(res.cond)])
    text = w.message()
    assert text.startswith(f"at t={w.t:.6g} s, q=[") and "condition number 2.57e+09" in text and "internal force" in text
    assert np.max(res.residual_pos) <= 1e-10
    with pytest.raises(SimulationError, match=r"simulation stopped at t=0 s, q=.*condition number 7.62e\+08 > "
                                              r"integrator.condition_limit = 1e\+08.*on_ill_conditioning: error"):
        simulate(hard("near_singular_chain", **{"integrator.on_ill_conditioning": "error"}))
    assert "ill_conditioned" not in kinds(simulate(hard("near_singular_chain", **{"integrator.condition_limit": 1e9 - 1,
                                                                                   "duration": 0.01})))


def test_arm_singularity_is_named_and_manipulability_is_exact():
    """Arm 2's elbow folds through straight: a warning names the two samples around the crossing; the
    manipulability is |det S J| = l₁l₂|sin θ₂| (planar 3R, analytic) and MuJoCo's Jacobian gives the same."""
    model = hard("arm_singularity")
    res = simulate(model)
    (w,) = res.warnings
    theta2 = res.q[:, 4]
    i = int(np.flatnonzero(np.sign(theta2[:-1]) != np.sign(theta2[1:]))[0])
    assert w.kind == "arm_singularity" and w.values["arm"] == 2 and w.t in (res.t[i], res.t[i + 1])
    assert f"between t={res.t[i]:.6g} s and t={res.t[i + 1]:.6g} s" in w.reason and "arm 2 passes" in w.reason
    assert np.max(res.cond) < 1e5, "the chain itself stays regular"
    np.testing.assert_allclose(res.manipulability[:, 1], 0.36 * np.abs(np.sin(theta2)), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res.manipulability[:, 0], 0.36 * np.abs(np.sin(res.q[:, 1])), rtol=1e-12)
    m, d, put, da = mujoco_at(model)
    for k in (0, i, len(res.t) - 1):
        put(res.q[k], res.qd[k])
        for a in range(model.r):
            jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jp, jr, m.site(f"a{a}_ee").id)
            A = (model.rows @ np.vstack([jp, jr]))[:, da[model.dof_slices[a]]]
            assert abs(np.linalg.det(A)) == pytest.approx(res.manipulability[k, a], rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("name", ["heavy_object", "light_object", "tiny_last_link", "planar_4arm_mixed"])
def test_extreme_scenes_keep_closure_and_energy(name):
    """Object 1e4x heavier / 1e-4x lighter than the lightest link, 1 mm last links, four planar arms of
    3-5 joints: the loop stays closed (<= 1e-10) and the kinetic energy ½θ̇ᵀ𝐈θ̇ is MuJoCo's
    (mj_energyVel on the twin at the same state) to 1e-11 relative."""
    model = hard(name, duration=0.3)
    res = simulate(model)
    assert np.max(res.residual_pos) <= 1e-10 and res.warnings == ()
    _, d, put, _ = mujoco_at(model)
    for k in (0, len(res.t) // 2, len(res.t) - 1):
        put(res.q[k], res.qd[k])
        assert res.kinetic_energy[k] == pytest.approx(d.energy[1], rel=1e-11, abs=1e-15)
    assert res.kinetic_energy[-1] > 0


@pytest.mark.parametrize("name", ["light_object", "spatial_3arm_mixed"])
def test_hard_scenes_agree_with_their_twin(name):
    """Through the cross-validation harness (what `coopsim validate` runs), 0.2 s: within the file's
    thresholds (three spatial arms of 6, 7 and 6 joints; an object 1e-4 of the lightest link)."""
    cv = cross_validate(hard(name), duration=0.2)
    assert cv.comparison.passed, cv.comparison.failures()
    assert [a.n for a in cv.native.model.arms] == ([3, 3] if name == "light_object" else [6, 7, 6])


def test_validate_runs_the_hard_cases_with_a_twin(monkeypatch):
    monkeypatch.chdir(SCENARIOS.parent)
    paths = cli._scenario_paths([], hard=True)
    assert [Path(p).stem for p in paths if "hard" in p] == [
        "arm_singularity", "far_from_closure", "heavy_object", "light_object", "passive_joints", "planar_4arm_mixed",
        "spatial_3arm_mixed", "tiny_last_link"]
    assert cli._scenario_paths([]) == sorted(str(p.relative_to(SCENARIOS.parent)) for p in SCENARIOS.glob("*.yaml"))


def test_fast_motion_adaptive_keeps_accuracy_and_rk4_says_when_it_cannot():
    """Up to 88 rad/s: DOP853 at rtol 1e-9 stays within 1e-7 rad of an rtol 1e-13 run; rk4 warns at
    steps whose (step-doubling) local error exceeds the tolerance — and those runs are off by more than
    1e-5 rad — and not at 0.1 ms, whose run is within 1e-8 rad."""
    model = hard("fast_motion")
    res = simulate(model)
    ref = simulate(model, settings=replace(model.integrator, rtol=1e-13, atol=1e-14))
    assert np.max(np.abs(res.qd)) > 50
    assert np.max(np.abs(res.q - ref.q)) <= 1e-7 and "step_too_large" not in kinds(res)
    coarse = simulate(model, settings=replace(model.integrator, method="rk4", step=1e-3))
    (w,) = [w for w in coarse.warnings if w.kind == "step_too_large"]
    assert w.values["error_ratio"] > 100 and 1e-4 < w.values["suggested_step_s"] < 1e-3
    assert "integrator.step = 0.001 s is too large for integrator.rtol = 1e-09" in w.reason
    assert np.max(np.abs(coarse.q - ref.q)) > 1e-5
    fine = simulate(model, settings=replace(model.integrator, method="rk4", step=1e-4))
    assert "step_too_large" not in kinds(fine) and np.max(np.abs(fine.q - ref.q)) <= 1e-8


def test_passive_joints_forward_and_inverse():
    """Passive joints get no torque forward (a torque on one is refused); the minimum-energy inverse
    keeps them at zero and its replay gives the forward motion back; `paper` loads them."""
    from coopsim.report.inverse_report import inverse_study

    model = hard("passive_joints", duration=0.3)
    P = model.motors.passive
    assert P.tolist() == [False, True, False, False, False, True]
    study = inverse_study(model, methods=("min_energy", "paper"), with_replay=True, curve=False)
    assert np.all(study.sim.tau[:, P] == 0)
    assert np.max(np.abs(study.results["min_energy"].tau[:, P])) <= 1e-12
    assert np.max(np.abs(study.results["paper"].tau[:, P])) > 1e-2
    assert study.replays["min_energy"].max_angle_error <= 1e-10
    data = load_yaml(HARD / "passive_joints.yaml")
    data["arms"][1]["torque"]["constant"] = [-0.1, 0.05, 0.3]
    with pytest.raises(ScenarioError, match=r"arms\[1\]\.torque: joint 3 is passive \(arms\[1\]\.passive\) but its "
                                            r"torque is not zero \(up to 0.3 N·m\)"):
        model_from_dict(data, where="p.yaml")


def test_initial_state_far_from_closure_warns_then_stops():
    res = simulate(hard("far_from_closure", duration=0.05))
    (w,) = res.warnings
    assert w.kind == "initial_correction" and w.t == 0 and np.array_equal(w.q, res.model.q0)
    assert w.values["max_correction_rad"] == pytest.approx(np.max(np.abs(res.initial.dq)))
    assert w.values["max_correction_rad"] > 5e-3
    assert "closing it moved arm 2 joint 1 by -0.006059 rad (> integrator.initial_correction_warning = 0.001" in w.reason
    with pytest.raises(ConstraintError, match=r"needs a joint correction of 0.006059 rad \(> "
                                              r"integrator.max_initial_correction = 0.005 rad\)"):
        simulate(hard("far_from_closure", **{"integrator.max_initial_correction": 0.005}))


def test_hundred_seconds_of_free_motion(capsys):
    """No torque, no gravity, 100 s: `simulate --json` reports the kinetic-energy drift; projection and
    Baumgarte keep the loop closed to 1e-10 and the energy to 1e-9 relative; without stabilization the
    residual grows past both (pinned: 1.6e-10 and 1.9e-10 J measured)."""
    path = HARD / "free_drift_100s.yaml"
    assert cli.main(["simulate", str(path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["kinetic_energy"]["conserved"] and report["duration_s"] == 100
    drift = {"projection": (report["kinetic_energy"]["max_relative_change"], report["max_constraint_residual"])}
    model = load_scenario(path)
    for method in ("baumgarte", "none"):
        s = simulation_summary(simulate(model, settings=replace(model.integrator, stabilization=method)))
        drift[method] = (s["kinetic_energy"]["max_relative_change"], s["max_constraint_residual"])
    for method in ("projection", "baumgarte"):
        assert drift[method][0] <= 1e-9 and drift[method][1] <= 1e-10, (method, drift)
    assert drift["none"][1] > 10 * max(drift["projection"][1], drift["baumgarte"][1]), drift
    assert drift["none"][0] > drift["baumgarte"][0], drift


def test_log_and_summary_carry_manipulability_and_warnings(tmp_path):
    res = simulate(hard("near_singular_chain", duration=0.2))
    path = write_run_log(tmp_path / "n.mcap", res.model, res)
    log = read_mcap(path)
    np.testing.assert_array_equal(log.topics["/native/constraint"]["manipulability"], res.manipulability)
    assert log.topics["/native/constraint"]["manipulability"].shape == (len(res.t), 2)
    meta = log.metadata["native.warnings"]
    assert int(meta["count"]) == len(res.warnings) >= 2
    assert [json.loads(meta[str(i + 1)]) for i in range(len(res.warnings))] == [w.as_dict() for w in res.warnings]
    assert simulation_summary(res)["warnings"] == [w.as_dict() for w in res.warnings]


def test_bad_option_value_is_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "--duration", "abc", "s.yaml"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1
    assert err.startswith("coopsim: error: argument --duration: invalid float value: 'abc'"), err


# ------------------------------------------------------------------------------------------------
# outputs: a complete set or nothing
# ------------------------------------------------------------------------------------------------

class _NoWorkers:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _quick_plots(fail: bool = False):
    """comparison_plots stand-in: four small files (or a failure after two), no drawing."""
    def plots(log, out, workers=None):
        paths = []
        for name in ("joint_angles", "joint_rates", "object_motion", "constraint_violation"):
            if fail and len(paths) == 2:
                raise OSError(28, "No space left on device")
            (Path(out) / f"{name}.png").write_bytes(name.encode())
            paths.append(Path(out) / f"{name}.png")
        return paths
    return plots


def _run(monkeypatch, scenario: Path, out: Path, fail: bool = False) -> int:
    monkeypatch.setattr("coopsim.plots.render.FigureWorkers", _NoWorkers)
    monkeypatch.setattr("coopsim.plots.run.comparison_plots", _quick_plots(fail))
    return cli.main(["run", str(scenario), "--duration", "0.05", "--out", str(out), "--json"])


def _tree(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_a_failed_run_leaves_the_previous_set_and_a_new_one_replaces_it(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    assert _run(monkeypatch, SCENARIOS / "paper_planar_2x3.yaml", out) == 0
    (out / "notes.txt").write_text("mine")           # another command's (or the user's) file stays
    before = _tree(out)
    assert set(before) == {"paper_planar_2x3.mcap", "summary.json", "joint_angles.png", "joint_rates.png",
                           "object_motion.png", "constraint_violation.png", "notes.txt"}
    assert _run(monkeypatch, HARD / "passive_joints.yaml", out, fail=True) == 2     # disk full while plotting
    assert "No space left on device" in capsys.readouterr().err
    assert _tree(out) == before and sorted(os.listdir(tmp_path)) == ["out"]
    assert _run(monkeypatch, HARD / "passive_joints.yaml", out) == 0
    after = _tree(out)
    assert set(after) == set(before) - {"paper_planar_2x3.mcap"} | {"passive_joints.mcap"}, "no mixed sets"
    assert json.loads(after["summary.json"])["files"]["log"] == str(out / "passive_joints.mcap")
    assert after["notes.txt"] == b"mine" and sorted(os.listdir(tmp_path)) == ["out"]


def test_inverse_writes_its_set_beside_a_run(tmp_path, monkeypatch, capsys):
    """`coopsim inverse` (and capacity: the same `cli._write_set`) writes its log, figures and JSON
    summary as one set too: a failure while drawing leaves the folder as it was (the run's set and the
    previous inverse set)."""
    out = tmp_path / "out"
    assert _run(monkeypatch, SCENARIOS / "paper_planar_2x3.yaml", out) == 0
    draw = {"fail": False}

    def plots(log, folder, workers=None):
        assert "/inverse/min_energy/torque" in log.topics     # the in-memory log of this study
        if draw["fail"]:
            raise OSError(28, "No space left on device")
        (Path(folder) / "inverse_torques.png").write_bytes(b"png")
        return [Path(folder) / "inverse_torques.png"]

    monkeypatch.setattr("coopsim.plots.inverse.inverse_plots", plots)
    args = ["inverse", str(SCENARIOS / "paper_planar_2x3.yaml"), "--duration", "0.05", "--method", "min_energy",
            "--no-curve", "--out", str(out), "--json"]
    assert cli.main(args) == 0
    before = _tree(out)
    assert {"inverse.mcap", "inverse.json", "inverse_torques.png", "summary.json"} <= set(before)
    draw["fail"] = True
    assert cli.main(args) == 2 and "No space left on device" in capsys.readouterr().err
    assert _tree(out) == before and sorted(os.listdir(tmp_path)) == ["out"]


_KILLED_WRITER = """
import sys, time
from pathlib import Path
from coopsim.io.atomic import staged_folder
with staged_folder(Path(sys.argv[1])) as stage:      # as `coopsim run` writes its outputs
    (stage / "half.mcap").write_bytes(b"x" * 1000)
    print("writing", flush=True)
    time.sleep(60)
"""


def test_a_killed_run_leaves_nothing_and_the_next_run_cleans_up(tmp_path, monkeypatch, capsys):
    """A process SIGKILLed while it writes a run's outputs (coopsim.io.atomic.staged_folder, as `coopsim run`
    does; the real command under SIGINT and SIGTERM: test_cli_stop) leaves no `out`, only a hidden temporary,
    which the next `coopsim run` removes."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(out)], cwd=tmp_path, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline() == "writing\n"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    left = sorted(os.listdir(tmp_path))
    assert not out.exists() and len(left) == 1 and left[0].startswith(".out.") and left[0].endswith(".tmp"), left
    assert _run(monkeypatch, SCENARIOS / "paper_planar_2x3.yaml", out) == 0
    assert sorted(os.listdir(tmp_path)) == ["out"] and not [p for p in os.listdir(out) if p.startswith(".")]
    assert "half.mcap" not in os.listdir(out)
