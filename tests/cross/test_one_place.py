"""One place per idea: the registry of redundancy resolutions that the CLI, the plots and the
capacity read; the one joint-label helper (1-based); the one rigid-point acceleration, box
inertia and reach check — each checked against numbers derived here, and each reader shown to use it."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

from coopsim.inverse import capacity as cap
from coopsim.inverse.solve import default_bounds, distribute, resolution_for
from coopsim.inverse import resolutions
from coopsim.io import scenario
from coopsim.inverse import trajectory
from coopsim.dynamics import kinematics, scene
from coopsim.cli import build_parser
from coopsim.twin.compare import compare
from coopsim.report.inverse_report import _capacity_entry, capacity_study, inverse_study
from coopsim.core.labels import joint_labels, metadata_joint_labels
from coopsim.io.log import run_metadata
from coopsim.io.mcap_codec import LogData
from coopsim.inverse.resolutions import LINEAR_METHODS, METHODS, RESOLUTIONS, resolution_method
from coopsim.core.spatial import axis_angle_to_rot, box_inertia, rigid_acceleration
from inverse_cases import model, problem

PAPER = "paper_planar_2x3"


# ------------------------------------------------------------------------------------------------
# The registry of redundancy resolutions
# ------------------------------------------------------------------------------------------------

def test_registry_lists_every_resolution_once_with_its_function_label_and_linearity():
    assert METHODS == ("paper", "nonsqueezing", "min_energy", "bounded")
    assert LINEAR_METHODS == ("paper", "nonsqueezing", "min_energy")
    assert resolutions.METHODS is METHODS and resolutions.LINEAR_METHODS is LINEAR_METHODS
    assert len({m.label for m in RESOLUTIONS.values()}) == len(METHODS)
    assert len({m.color for m in RESOLUTIONS.values()}) == len(METHODS)
    for k, m in RESOLUTIONS.items():
        assert m.name == k and callable(m.distribute) and m.help
        assert m.linear == (m.nonlinear_why == "")
    with pytest.raises(ValueError, match="unknown method 'nope'; expected one of paper, nonsqueezing, "
                                         "min_energy, bounded"):
        resolution_method("nope")
    # the studies read the registry: every resolution inverted, every linear one's capacity computed
    assert inspect.signature(inverse_study).parameters["methods"].default is METHODS
    assert inspect.signature(capacity_study).parameters["methods"].default is LINEAR_METHODS


def test_every_registered_method_is_accepted_by_the_cli():
    parser = build_parser()
    for k in METHODS + ("all",):
        assert parser.parse_args(["inverse", "s.yaml", "--method", k]).method == k
    with pytest.raises(SystemExit):
        parser.parse_args(["inverse", "s.yaml", "--method", "nope"])
    sub = next(a for a in parser._actions if a.dest == "command").choices["inverse"]
    method = next(a for a in sub._actions if a.dest == "method")
    assert tuple(method.choices) == ("all",) + METHODS
    for m in RESOLUTIONS.values():
        assert f"{m.name}: {m.help}" in method.help


def test_every_registered_method_is_distributed_and_handled_or_refused_by_capacity():
    """Each registered function balances the object (A f = y to 1e-12) at 26 samples of the paper run, and
is what `distribute` runs (the reference engine; the compiled pass within 1e-12 relative);
    method_capacity gives the linear ones a capacity (the pinned 21.71, 24.55, 101.43 kg of the README)
    and refuses the others with the registry's reason."""
    m = model(PAPER)
    P = problem(PAPER)
    fb, mb = default_bounds(P, resolution_for(m, "min_energy"))
    for k, meth in RESOLUTIONS.items():
        res = resolution_for(m, k, force_bound=fb, moment_bound=mb)
        f, failures = meth.distribute(P, P.y, res)
        assert failures == ()
        assert np.max(np.abs(np.einsum("nij,nj->ni", P.A, f) - P.y)) <= 1e-12, k
        assert np.array_equal(distribute(P, P.y, res, engine="reference"), f)
        assert np.max(np.abs(distribute(P, P.y, res) - f)) <= 1e-12 * np.max(np.abs(f)), k   # the compiled pass
        if meth.linear:
            c = cap.method_capacity(P, res, m.motors)
            assert c.feasible and c.mass == pytest.approx({"paper": 21.71, "nonsqueezing": 24.55,
                                                            "min_energy": 101.43}[k], abs=0.005)
        else:
            with pytest.raises(ValueError, match=f"resolution '{k}' has no closed-form capacity: "
                                                 f"{meth.nonlinear_why}"):
                cap.method_capacity(P, res, m.motors)


def _synthetic_logs(n_t: int = 5):
    """An inverse log and a capacity log with every registered method (random series), the "model"
    record of the paper scene (arms arm1, arm2, 3 joints each)."""
    rng = np.random.default_rng(1)
    t = np.linspace(0.0, 1.0, n_t)
    meta = {"model": {"arms": json.dumps(["arm1", "arm2"]), "dofs": json.dumps([3, 3])}}
    inv_topics = {"/inverse/trajectory": {"t": t, "q": rng.normal(size=(n_t, 6)), "tau_min": -np.ones((n_t, 6)),
                                          "tau_max": np.ones((n_t, 6))}}
    for k in ("forward",) + METHODS:
        inv_topics[f"/inverse/{k}/torque"] = {"t": t, "tau": rng.normal(size=(n_t, 6)), "torque_norm": rng.random(n_t),
                                             "cost": rng.random(n_t)}
        inv_topics[f"/inverse/{k}/internal"] = {"t": t, "nonsqueezing": rng.normal(size=(n_t, 2, 6))}
    cap_topics = {"/capacity/limits": {"t": t, "qd": rng.normal(size=(n_t, 6)), "tau_min": -np.ones((n_t, 6)),
                                       "tau_max": np.ones((n_t, 6))}}
    cap_meta = dict(meta)
    for j, k in enumerate(LINEAR_METHODS + ("lp",)):
        cap_topics[f"/capacity/{k}/scaled"] = {"t": t, "tau": rng.normal(size=(n_t, 6)),
                                               "per_sample_mass": 1.0 + rng.random(n_t)}
        cap_meta[f"capacity.{k}.scaled"] = {"stacked_joint": json.dumps(j + 2), "mass_kg": "2.5", "time_s": "0.5"}
    return LogData(meta, inv_topics, {}), LogData(cap_meta, cap_topics, {})


def test_every_registered_method_is_drawn_by_the_plots_with_its_label_and_colour():
    from matplotlib.colors import to_rgba

    from coopsim.plots.inverse import (capacity_along_path_figure, capacity_motor_figure, inverse_internal_figure,
                                       inverse_norms_figure, inverse_torques_figure)

    ilog, clog = _synthetic_logs()
    for fig in (inverse_torques_figure(ilog), inverse_norms_figure(ilog), inverse_internal_figure(ilog)):
        lines = {ln.get_label(): ln for ln in fig.axes[0].lines}
        assert "forward-dynamics input" in lines
        for m in RESOLUTIONS.values():
            assert to_rgba(lines[m.label].get_color()) == to_rgba(m.color), m.name
    drawn = [ln.get_label() for ln in capacity_along_path_figure(clog).axes[0].lines]
    assert drawn == [RESOLUTIONS[k].label for k in LINEAR_METHODS] + ["LP bound (any distribution)"]
    titles = [ax.get_title() for ax in capacity_motor_figure(clog).axes]
    # the saturating motor's panel: the registry's label and the 1-based joint label (stacked joints 2, 3, 4)
    assert titles == ["zero internal (paper W⁺)\narm 1 joint 3", "zero internal (non-squeezing)\narm 2 joint 1",
                      "minimum energy\narm 2 joint 2"]
    assert [ax.get_title() for ax in inverse_torques_figure(ilog).axes] == [
        f"arm {a} joint {j}" for a in (1, 2) for j in (1, 2, 3)]


# ------------------------------------------------------------------------------------------------
# Joint labels: one helper, 1-based everywhere
# ------------------------------------------------------------------------------------------------

def test_joint_labels_are_one_based_and_name_custom_arms():
    assert joint_labels(model(PAPER)) == [f"arm {a} joint {j}" for a in (1, 2) for j in (1, 2, 3)]
    assert joint_labels(model("planar_3arm_vertical")) == [
        f"arm {a} ({name}) joint {j}" for a, name in ((1, "left"), (2, "right"), (3, "top")) for j in (1, 2, 3)]
    # what a log records, and what is read back from it (an old log's own "joint_names" are not used)
    m = model(PAPER)
    meta = run_metadata(m)
    assert json.loads(meta["model"]["joint_names"]) == joint_labels(m)
    assert metadata_joint_labels(meta, 6) == joint_labels(m)
    assert metadata_joint_labels({"model": {**meta["model"], "joint_names": '["arm1/q0"]'}}, 6) == joint_labels(m)
    assert metadata_joint_labels({}, 3) == ["joint 1", "joint 2", "joint 3"]
    assert metadata_joint_labels(meta, 5) == [f"joint {j}" for j in range(1, 6)]
    assert metadata_joint_labels({"model": {"arms": "not json", "dofs": "[3]"}}, 2) == ["joint 1", "joint 2"]


def test_reports_name_joints_with_the_helper():
    """The capacity entry's saturating motor (stacked joint 3 of the paper scene: arm 2's first joint,
    the README's 'arm 2 joint 1'), the comparison's worst joint and the plots' legends."""
    from coopsim.inverse.capacity import Capacity
    from coopsim.forward.simulate import simulate

    m = model(PAPER)
    entry = _capacity_entry(m, Capacity(21.71, 0.0, True, 3, 10, 1.77, "upper"))
    assert entry["saturating_motor"] == "arm 2 joint 1" and entry["stacked_joint"] == 3
    res = simulate(m, duration=0.05)

    class Twin:                     # the native run as its own twin, joint 5 (arm 2 joint 3) off by 1e-3 rad
        t, q, qd, object_twist = res.t, res.q.copy(), res.qd, res.object_twist
        object_pos, object_quat, weld_violation = res.object_pos, res.object_quat, np.zeros(len(res.t))
    Twin.q[:, 5] += 1e-3
    metric = next(x for x in compare(res, Twin).metrics if x.name == "joint angle error")
    assert metric.where == "arm 2 joint 3" and metric.max == pytest.approx(1e-3, rel=1e-9)


# ------------------------------------------------------------------------------------------------
# One rigid-point acceleration, one box inertia, one reach check
# ------------------------------------------------------------------------------------------------

def test_rigid_acceleration_is_the_second_derivative_of_a_body_point():
    """A body turning about a fixed axis with θ(t) = 0.3 + 0.7 t + 0.45 t² (so ω = θ̇ a, ω̇ = θ̈ a) and
    its point O moving as p_O(t) = [t², −t³, 2t]: p_P = p_O + R(t) r₀; the helper's a_P equals the second
    central difference of p_P (h = 1e-4 s) to 1e-7 m/s², and broadcasts over leading axes."""
    a = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    r0 = np.array([0.3, -0.1, 0.25])

    def p_P(t):
        return np.array([t * t, -t ** 3, 2 * t]) + axis_angle_to_rot(a, 0.3 + 0.7 * t + 0.45 * t * t) @ r0

    t, h = 0.8, 1e-4
    fd = (p_P(t + h) - 2 * p_P(t) + p_P(t - h)) / h ** 2
    r = axis_angle_to_rot(a, 0.3 + 0.7 * t + 0.45 * t * t) @ r0
    got = rigid_acceleration(np.array([2.0, -6 * t, 0.0]), (0.7 + 0.9 * t) * a, 0.9 * a, r)
    assert np.max(np.abs(got - fd)) <= 1e-7
    batch = rigid_acceleration(np.zeros((4, 3)), np.tile(a, (4, 1)), np.zeros((4, 3)), np.tile(r, (4, 1)))
    assert np.allclose(batch, np.cross(a, np.cross(a, r)), rtol=0, atol=1e-16)


def test_box_inertia_by_integration_and_its_users():
    """m/12 (b² + c²), … against the midpoint-rule integral of ∫ρ(|x|²I − xxᵀ)dV over 40³ cells (1e-3
    relative); a box link of a scenario and the stress module's pieces use the same function."""
    size, mass = np.array([0.4, 0.1, 0.06]), 2.5
    n = 40
    g = [(np.arange(n) + 0.5) / n * s - s / 2 for s in size]
    X = np.stack(np.meshgrid(*g, indexing="ij"), axis=-1).reshape(-1, 3)
    dm = mass / len(X)
    K = dm * (np.sum(X * X) * np.eye(3) - X.T @ X)
    assert np.max(np.abs(box_inertia(mass, size) - K)) <= 1e-3 * np.max(K)
    assert box_inertia(12.0, [1.0, 2.0, 3.0]) == pytest.approx(np.diag([13.0, 10.0, 5.0]), abs=1e-15)
    import coopsim.inverse.stress as stress
    assert stress.box_inertia is box_inertia and scenario.box_inertia is box_inertia
    assert not hasattr(stress, "piece_inertia") and not hasattr(scenario, "_box_inertia")


def test_one_reach_check_with_one_slack():
    """A point at reach (1 + 0.9e-9) from the first joint passes, at reach (1 + 1.1e-9) fails, for the
    paper's arm (reach 1.25 m: links 0.6 + 0.6 + 0.05): the scenario's grasp check and the object-motion
    pre-check are the same function (they had slacks 1e-9 and 1e-12)."""
    arm = model(PAPER).arms[0]
    first = arm.base_rot @ arm.joint_pos[0]
    u = np.array([0.6, 0.8, 0.0])
    inside = kinematics.reach_check(arm, first + 1.25 * (1 + 0.9e-9) * u)
    outside = kinematics.reach_check(arm, first + 1.25 * (1 + 1.1e-9) * u)
    assert inside.ok and not outside.ok
    assert inside.reach == pytest.approx(1.25, rel=1e-15)
    assert outside.dist == pytest.approx(1.25 * (1 + 1.1e-9), rel=1e-15)
    assert kinematics.REACH_SLACK == 1e-9
    assert scene.reach_check is kinematics.reach_check and trajectory.reach_check is kinematics.reach_check
