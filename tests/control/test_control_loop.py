"""Controllers inside the compiled time loop (`coopsim.compiled.control`), joint-space feedback on each
arm's grasp error, and the 'bounded' distribution's fallback.

Independent references: the Python controller (`coopsim.control.controller.Controller.command`, NumPy over the
compiled inverse-dynamics terms) in the reference time loop — the 'stages' engine: the same algorithm,
so the two agree to round-off; finite differences of the grasp error; MuJoCo's own integration of the
twin with soft welds."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.control.controller import Controller, ControlError
from coopsim.core.model import ControlSettings, TorqueTable
from coopsim.io.scenario import load_scenario
from coopsim.control.controller import closed_loop
from coopsim.forward.simulate import simulate
from helpers import SCENARIOS

HOLD = SCENARIOS / "control" / "control_spatial_hold.yaml"
CARRY = SCENARIOS / "control" / "control_paper_carry.yaml"


@pytest.fixture(scope="module")
def hold():
    return load_scenario(HOLD)


@pytest.fixture(scope="module")
def carry():
    """The carry with its shoulder pulse moved to the first 20 ms (the tables are added to the command in
    both engines: a disturbance inside the short runs)."""
    model = load_scenario(CARRY)
    pulse = (replace(model.torques[0], times=np.array([0.0, 0.005, 0.01, 0.015, 0.02])),) + model.torques[1:]
    return replace(model, torques=pulse)


def _short(model, duration, step=None, **control):
    """`model` over `duration` s (two samples) with control fields replaced; classical RK4 at `step` s
    when given (both engines then take the same steps: no accept/reject decision that round-off could
    flip at the kinks of a torque table or of saturation)."""
    s = replace(model.integrator, output_dt=duration / 2)
    if step is not None:
        s = replace(s, method="rk4", step=step)
    return replace(model, duration=duration, integrator=s, control=replace(model.control, **control))


def _variants(hold, carry):
    """(name, model) of every bundled control scenario and each controller kind, on short runs."""
    n = hold.n_total
    weak = replace(hold.motors, stall_torque=np.full(n, 5.0), no_load_speed=np.full(n, 4.0))
    om = carry.inverse.object_motion
    first = replace(om, times=om.times[:2], positions=om.positions[:2], rotations=om.rotations[:2], output_dt=0.05)
    pd_carry = replace(carry, inverse=replace(carry.inverse, object_motion=first),
                       control=ControlSettings("joint_pd", np.full(6, 20.0), np.full(6, 2.0), compensation="bias",
                                               distribution="min_energy", reference="object_motion"))
    return [
        ("hold: joint PD + gravity, paper W+ (as bundled: DOP853)", _short(hold, 0.02)),
        ("hold: joint PD + bias, min energy, saturated", replace(_short(hold, 0.02, 0.002, compensation="bias",
                                                                          distribution="min_energy", saturate=True),
                                                                  motors=weak)),
        ("carry: computed torque, min energy, squeeze, mass error", _short(carry, 0.04, 0.005)),
        ("carry: computed torque, non-squeezing, grasp feedback", _short(
            carry, 0.04, 0.005, distribution="nonsqueezing", grasp_kp=np.array([2e3, 50.0]),
            grasp_kd=np.array([40.0, 1.0]))),
        ("carry: computed torque, paper W+", _short(carry, 0.04, 0.005, distribution="paper", squeeze=0.0)),
        ("carry: joint PD + bias on the object motion's joint trajectory", _short(pd_carry, 0.04, 0.005)),
    ]


def test_the_compiled_closed_loop_is_the_stages_engine_to_round_off(hold, carry):
    """Every bundled control scenario and each controller kind (joint PD to a set-point and along a joint
    trajectory with gravity or full-bias compensation; object-space computed torque with the paper,
    non-squeezing and minimum-energy distributions, a squeeze, a mass error, grasp-error feedback; eq. 36
    saturation; the torque tables as a disturbance): the compiled time loop and the 'stages' engine (the
    Python controller at every stage of the reference loop) give the same trajectory and torques to
    ≤ 1e-10 rad and N·m (measured ≤ 1.3e-15 rad, 3.3e-13 N·m on torques up to 69 N·m) while each run
    moves. The bundled DOP853 runs one variant; the others take RK4 steps, so that no accept/reject
    decision at the kinks of the torque table or of saturation can be flipped by round-off (with DOP853
    they then agree to the tolerance instead: measured 4.5e-11 rad). Saturation clips in the saturated
    variant, within the motor lines, and is counted (`summary.json`: `native.controller`); the summary
    names the engine that ran."""
    from coopsim.report.summary import simulation_summary

    for name, model in _variants(hold, carry):
        a, b = simulate(closed_loop(model)), simulate(closed_loop(model), engine="stages")
        assert (a.engine, b.engine) == ("compiled", "stages"), name
        dq, dtau = float(np.max(np.abs(a.q - b.q))), float(np.max(np.abs(a.tau - b.tau)))
        assert dq <= 1e-10 and dtau <= 1e-10, f"{name}: {dq:.3g} rad, {dtau:.3g} N·m"
        assert float(np.max(np.abs(a.q[-1] - a.q[0]))) > 1e-6, f"{name}: the chain did not move"
        assert float(np.max(np.abs(a.tau))) > 1e-3, f"{name}: no torque"
        evaluations, clipped, pairs = a.control_counts
        assert evaluations == a.stats.n_rhs
        assert (clipped > 0) == ("saturated" in name), f"{name}: {clipped} evaluations clipped"
        if "saturated" in name:                      # eq. 36 written out: ∓5 − (5/4) θ̇
            lo, hi = -5.0 - 1.25 * a.qd, 5.0 - 1.25 * a.qd
            assert pairs >= clipped and np.all(a.tau >= lo - 1e-12) and np.all(a.tau <= hi + 1e-12)
            summary = simulation_summary(a)
            assert summary["engine"] == "compiled" and summary["controller"] == {
                "evaluations": evaluations, "saturated_evaluations": clipped, "saturated_joint_evaluations": pairs}
            assert simulation_summary(b)["engine"] == "stages" and "controller" not in simulation_summary(b)


# ------------------------------------------------------------------------------------------------
# Joint-space feedback on each arm's grasp error
# ------------------------------------------------------------------------------------------------

def test_the_grasp_error_is_the_loop_closure_residual_and_its_rate_its_derivative(carry):
    """e_m (`coopsim.control.laws.grasp_errors`) in the scene's rows is minus the plain-NumPy loop-closure
    residual Φ_m (`coopsim.dynamics.closed_chain.position_residual`) at a state off the manifold (≤ 1e-12; the
    carrier's is zero), and ė_m = [v_C + ω × R_o g_m; ω] − J_m θ̇_m is the derivative of e_m along θ̇ by
    central differences (h = 1e-6) at a consistent state (≤ 1e-8 m/s, rad/s, with rates of 1 rad/s;
    measured 3e-10). Off the manifold the rotation rows of ė are the twist difference, not d/dt log:
    they differ by O(|e| |ω|)."""
    from coopsim.dynamics.closed_chain import position_residual
    from coopsim.compiled.api import consistent_state

    ctrl = Controller(carry)
    rng = np.random.default_rng(12)
    off = carry.q0 + rng.normal(0.0, 1e-3, carry.n_total)
    e, _ = ctrl.grasp_errors_at(off, np.zeros(carry.n_total))
    c, S = carry.object.carrier, carry.rows
    others = [m for m in range(carry.r) if m != c]
    np.testing.assert_allclose(np.concatenate([S @ e[m] for m in others]), -position_residual(carry, off),
                               rtol=0, atol=1e-12)
    assert np.all(e[c] == 0) and np.max(np.abs(e)) > 1e-4

    q = consistent_state(carry, carry.q0, np.zeros(carry.n_total)).q
    qd = rng.normal(0.0, 1.0, carry.n_total)
    e0, ed = ctrl.grasp_errors_at(q, qd)
    h = 1e-6
    fd = (ctrl.grasp_errors_at(q + h * qd, qd)[0] - ctrl.grasp_errors_at(q - h * qd, qd)[0]) / (2 * h)
    assert np.max(np.abs(e0)) <= 1e-12
    np.testing.assert_allclose(fd, ed, rtol=0, atol=1e-8)
    assert np.max(np.abs(ed)) > 0.1, "the rates left the grasps closed: nothing was differentiated"


def test_grasp_feedback_closes_soft_grasps_in_the_twin_and_leaves_the_native_model_alone(carry):
    """The carry's twin with soft welds (time constant 0.05 s, impedance 0.5: compliant grasps), started
    with arm 2 turned 1–2 mrad off its grasp (grasp error 1.2e-3 m) under the perfect-model computed
    torque: without grasp feedback the error grows as the welds yield to the controller's forces
    (measured 4.4e-3 m at 0.2 s); with J_mᵀ(Kp e + Kd ė) (2000 N/m, 20 N·m/rad; 100 N·s/m, 1 N·m·s/rad)
    it decays, to at most 5 % by 0.2 s (measured 1.5 %). On the native model, whose grasps are rigid
    (e = 0 to the closure tolerance), the same gains change the trajectory by ≤ 1e-12 rad."""
    from coopsim.twin.mujoco_run import run_twin
    from coopsim.forward.simulate import initial_state
    from coopsim.core.results import output_times

    zero = tuple(TorqueTable(np.zeros(1), np.zeros((1, tab.values.shape[1]))) for tab in carry.torques)
    soft = replace(carry.mujoco, timestep=1e-3, weld_solref=(0.05, 1.0), weld_solimp=(0.5, 0.5, 0.001, 0.5, 2.0))
    base = replace(carry, torques=zero, duration=0.2, control=replace(carry.control, mass_scale=1.0, squeeze=0.0),
                   integrator=replace(carry.integrator, output_dt=0.01), mujoco=soft)
    fed = replace(base, control=replace(base.control, grasp_kp=np.array([2e3, 20.0]), grasp_kd=np.array([100.0, 1.0])))
    init = initial_state(base)
    q0 = init.q + np.r_[0.0, 0.0, 0.0, 2e-3, -2e-3, 1e-3]
    t = output_times(0.2, 0.01)
    ctrl = Controller(base)
    err = {}
    for name, model in (("without", base), ("with", fed)):
        twin = run_twin(model, q0, init.qd, t)
        err[name] = np.array([np.linalg.norm(ctrl.grasp_errors_at(q, qd)[0][1, :3]) for q, qd in zip(twin.q, twin.qd)])
    e0 = err["with"][0]
    assert 1e-3 < e0 == err["without"][0]
    assert err["without"][-1] > e0, f"the soft grasps closed by themselves: {err['without'][-1]:.3g} m"
    assert err["with"][-1] <= 0.05 * e0, f"grasp feedback left {err['with'][-1]:.3g} m of {e0:.3g} m"

    short = dict(duration=0.05, integrator=replace(base.integrator, output_dt=0.025))
    a, b = simulate(closed_loop(replace(base, **short))), simulate(closed_loop(replace(fed, **short)))
    assert float(np.max(np.abs(a.q - b.q))) <= 1e-12


# ------------------------------------------------------------------------------------------------
# 'bounded' distribution without a solution: fallback or a one-line error
# ------------------------------------------------------------------------------------------------

@pytest.fixture
def failing_qp(monkeypatch):
    """`coopsim.inverse.qp.solve_qps` reporting no solution at the calls whose numbers are in the returned
    set (1-based; the real solver runs, its answer is dropped there). With actuated arms the bounded QP
    always has one (zero internal wrench is feasible), so the failure is injected."""
    from coopsim.inverse import distributions

    real, calls, failing = distributions.solve_qps, [0], set()

    def solve(*args):
        out = real(*args)
        calls[0] += 1
        if calls[0] in failing:
            out.ok[:] = False
            out.x[:] = np.nan
            out.messages[:] = ["injected: no verified minimiser"] * len(out.messages)
        return out

    monkeypatch.setattr(distributions, "solve_qps", solve)   # the bounded resolution's QP
    return failing


def _bounded(hold, **control):
    """The hold under 'bounded' (unbounded internal wrench: the minimum-energy torques), two RK4 steps."""
    model = _short(hold, 0.004, 0.002, distribution="bounded", **control)
    return replace(model, integrator=replace(model.integrator, output_dt=0.004))


def test_a_bounded_distribution_without_solution_falls_back_and_says_so(hold, failing_qp):
    """Where the QP has no solution the controller uses control.fallback's distribution (default
    non-squeezing: its torque exactly), the run goes on on the 'stages' engine, and one RunWarning names
    the first such evaluation's time and configuration, the reason and their count (2: the 2nd and 3rd
    stages of the first step, t = 1 ms); the summary carries it. Without failures: no warning."""
    from coopsim.report.summary import simulation_summary

    model = _bounded(hold)
    failing_qp.update({1})
    ctrl = Controller(model)
    ref = Controller(replace(model, control=replace(model.control, distribution="nonsqueezing")))
    q, qd = hold.q0, np.zeros(hold.n_total)
    np.testing.assert_allclose(ctrl(0.0, q, qd), ref(0.0, q, qd), rtol=0, atol=1e-12)
    assert len(ctrl.fallbacks) == 1
    assert not np.allclose(ctrl(0.0, q, qd), ref(0.0, q, qd), rtol=0, atol=1e-6), "bounded is non-squeezing here"

    failing_qp.clear()
    failing_qp.update({4, 5})            # 2 calls above; the run's stages 1, 2, 3 are calls 3, 4, 5
    res = simulate(closed_loop(model))
    assert res.engine == "stages"
    [w] = [w for w in res.warnings if w.kind == "distribution_fallback"]
    assert w.values == {"fallbacks": 2.0} and w.t == pytest.approx(0.001)
    assert "injected: no verified minimiser" in w.reason and "'nonsqueezing'" in w.reason
    assert w.as_dict() in simulation_summary(res)["warnings"]
    failing_qp.clear()
    assert not [w for w in simulate(closed_loop(model)).warnings if w.kind == "distribution_fallback"]


def test_a_bounded_distribution_without_solution_stops_the_run_when_told(hold, failing_qp):
    """control.fallback: error — the run stops at the first evaluation without a solution, with one line
    naming the field, the time, the configuration and the reason; fallback is validated by name."""
    from coopsim.io.scenario import model_from_dict
    from coopsim.core.errors import ScenarioError
    import yaml

    failing_qp.update({2})
    with pytest.raises(ControlError) as err:
        simulate(closed_loop(_bounded(hold, fallback="error")))
    msg = str(err.value)
    assert msg.startswith("control.fallback: error: the 'bounded' distribution has no solution at t=0.001 s, q=[")
    assert msg.endswith("rad: injected: no verified minimiser") and "\n" not in msg
    for extra, expect in (({"fallback": "paper"}, "control.fallback: only with distribution: bounded"),
                          ({"distribution": "bounded", "fallback": "qp"}, "control.fallback: must be one of")):
        data = yaml.safe_load(HOLD.read_text())
        data["control"].update(extra)
        with pytest.raises(ScenarioError, match=expect.replace(".", r"\.")):
            model_from_dict(data, where="s.yaml")
