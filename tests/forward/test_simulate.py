"""Forward simulation: energy balance, constraint drift, stabilization variants, failure reports."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import simpson

from coopsim.dynamics.closed_chain import chain_terms, forward_dynamics
from coopsim.core.model import TorqueTable
from coopsim.forward.simulate import simulate
from coopsim.core.errors import ConstraintRankWarning, SimulationError
from helpers import SCENARIOS, MujocoReference


def _free(model, duration=10.0, seed=0, **integrator):
    """The model without gravity or torques, started with random joint rates (made consistent)."""
    rng = np.random.default_rng(seed)
    zero = tuple(TorqueTable(np.zeros(1), np.zeros((1, a.n))) for a in model.arms)
    return replace(model, gravity=np.zeros(3), torques=zero, qd0=rng.normal(scale=0.5, size=model.n_total),
                   duration=duration, integrator=replace(model.integrator, **integrator))


def _kinetic_energy(model, res):
    """½ θ̇ᵀ M θ̇ with MuJoCo's mass matrix of the open chain carrying the object (independent)."""
    ref = MujocoReference(model, with_object=True)
    ke = []
    for q, qd in zip(res.q, res.qd):
        ref.set_state(q, qd)
        ke.append(0.5 * qd @ ref.mass_matrix() @ qd)
    return np.array(ke)


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_free_motion_conserves_energy_and_closure_over_10s(scenario, request):
    model = _free(request.getfixturevalue(scenario), output_dt=0.05, step=0.05)
    res = simulate(model)
    ke = _kinetic_energy(model, res)
    drift = np.max(np.abs(ke - ke[0])) / ke[0]
    assert res.t[-1] == pytest.approx(10.0)
    assert drift <= 1e-8, f"kinetic energy drifted by {drift:.3g} (relative) over 10 s"
    assert np.max(res.residual_pos) <= 1e-10, f"loop-closure residual reached {np.max(res.residual_pos):.3g}"


def test_torque_work_equals_kinetic_energy_gain(paper):
    """∫ τ·θ̇ dt = ΔT for the paper run (gravity normal to the plane does no work), Simpson's rule
    on a 2 ms grid over 1 s."""
    model = replace(paper, duration=1.0, integrator=replace(paper.integrator, output_dt=0.002))
    res = simulate(model)
    power = np.einsum("ij,ij->i", res.tau, res.qd)
    work = simpson(power, x=res.t)
    ke = _kinetic_energy(model, res)
    assert abs(work - (ke[-1] - ke[0])) <= 1e-9 * max(abs(work), 1e-3), (work, ke[-1] - ke[0])


@pytest.mark.parametrize("method,stabilization,bound", [
    ("rk4", "projection", 1e-10), ("dopri5", "projection", 1e-10), ("dop853", "baumgarte", 1e-8)])
def test_integrator_and_stabilization_variants_agree(paper, method, stabilization, bound):
    """Every integrator/stabilization pair reproduces the reference run (dop853 + projection) over
    1 s to a bound set by its own accuracy, and keeps the loop closed."""
    ref = simulate(replace(paper, duration=1.0))
    settings = replace(paper.integrator, method=method, stabilization=stabilization, step=1e-3,
                       rtol=1e-12, atol=1e-13)
    res = simulate(replace(paper, duration=1.0), settings=settings)
    assert np.max(np.abs(res.q - ref.q)) <= bound
    assert np.max(res.residual_pos) <= bound


def test_rank_deficient_constraints_are_handled_with_a_warning(paper):
    """Forcing 6 constraint rows on the planar scene makes Λ𝐈⁻¹Λᵀ singular (3 rows vanish); the
    minimum-norm solve gives the planar θ̈ and a warning naming time and configuration."""
    forced = replace(paper, rows=np.eye(6), integrator=replace(paper.integrator, constraint_rows="spatial"))
    tau = np.array([0.5, -0.02, 0.0, -0.1, 0.0, 0.0])
    q = simulate(replace(paper, duration=0.0)).q[0]
    acc_planar = forward_dynamics(paper, chain_terms(paper, q, np.zeros(6)), tau)
    acc_forced = forward_dynamics(forced, chain_terms(forced, q, np.zeros(6)), tau)
    assert acc_forced.rank == 3
    assert np.max(np.abs(acc_forced.qdd - acc_planar.qdd)) <= 1e-12
    with pytest.warns(ConstraintRankWarning, match=r"t=0 s, q=\[.*rank-deficient"):
        simulate(replace(forced, duration=0.05))


def test_rank_deficiency_can_be_an_error_with_time_and_configuration(paper):
    forced = replace(paper, rows=np.eye(6), duration=0.05, integrator=replace(
        paper.integrator, constraint_rows="spatial", on_rank_deficiency="error"))
    with pytest.raises(SimulationError, match=r"failed at t=0 s, q=\[1\.5707.*rank-deficient \(rank 3"):
        simulate(forced)


def test_results_are_deterministic(paper):
    a = simulate(replace(paper, duration=0.5))
    b = simulate(replace(paper, duration=0.5))
    for field in ("q", "qd", "qdd", "object_pos", "grasp_wrench", "internal_wrench"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_non_finite_dynamics_stop_with_time_configuration_and_reason(paper):
    huge = tuple(TorqueTable(np.zeros(1), np.full((1, a.n), 1e308)) for a in paper.arms)
    with pytest.raises(SimulationError, match=r"failed at t=.* s, q=\[.*\] rad: non-finite"):
        simulate(replace(paper, torques=huge, duration=0.1))


def test_a_control_section_runs_only_once_its_loop_is_closed():
    """simulate takes a torque source and knows no controller: a scenario's control: section is put in
    the loop by the caller (coopsim.control.closed_loop); left open, simulate says so instead of
    running the torque tables alone."""
    from coopsim.control.controller import closed_loop
    from coopsim.core.errors import CoopsimError
    from coopsim.core.model import loop_controller
    from coopsim.io.scenario import load_scenario

    model = load_scenario(SCENARIOS / "control" / "control_spatial_hold.yaml", duration=0.02)
    with pytest.raises(CoopsimError, match=r"control: section is not in the loop: close it first"):
        simulate(model)
    closed = closed_loop(model)
    assert loop_controller(closed) is closed.torques.fn and loop_controller(model) is None
    res = simulate(closed)
    assert res.engine == "compiled" and res.control_counts is not None and np.all(np.isfinite(res.q))
