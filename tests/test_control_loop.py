"""Controllers inside the compiled time loop (`coopsim.compiled.control`), joint-space feedback on each
arm's grasp error, and the 'bounded' distribution's fallback (issue #12, what the first stop left open).

Independent references: the Python controller (`coopsim.control.Controller.command`, NumPy over the
compiled inverse-dynamics terms) in the reference time loop — the 'stages' engine: the same algorithm,
so the two agree to round-off; finite differences of the grasp error; MuJoCo's own integration of the
twin with soft welds."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.control import Controller, ControlError
from coopsim.model import ControlSettings, TorqueTable
from coopsim.scenario import load_scenario
from coopsim.simulate import simulate
from conftest import SCENARIOS

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
    variant, within the motor lines, and is counted."""
    for name, model in _variants(hold, carry):
        a, b = simulate(model), simulate(model, engine="stages")
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


# ------------------------------------------------------------------------------------------------
# Joint-space feedback on each arm's grasp error
# ------------------------------------------------------------------------------------------------

def test_the_grasp_error_is_the_loop_closure_residual_and_its_rate_its_derivative(carry):
    """e_m (`coopsim.control.grasp_errors`) in the scene's rows is minus the plain-NumPy loop-closure
    residual Φ_m (`coopsim.closed_chain.position_residual`) at a state off the manifold (≤ 1e-12; the
    carrier's is zero), and ė_m = [v_C + ω × R_o g_m; ω] − J_m θ̇_m is the derivative of e_m along θ̇ by
    central differences (h = 1e-6) at a consistent state (≤ 1e-8 m/s, rad/s, with rates of 1 rad/s;
    measured 3e-10). Off the manifold the rotation rows of ė are the twist difference, not d/dt log:
    they differ by O(|e| |ω|)."""
    from coopsim.closed_chain import position_residual
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
