"""The benchmark's peer models (validation/peers.py): Pinocchio's closed-chain accelerations against
coopsim's, and the MuJoCo twin through `mujoco.rollout` against coopsim and against `run_twin`."""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace

import numpy as np
import pytest

from coopsim.dynamics.manifold import consistent_state
from coopsim.core.model import torque_at
from coopsim.twin.mujoco_run import run_twin
from coopsim.io.scenario import load_scenario
from coopsim.forward.simulate import forward, simulate
from helpers import ROOT, SCENARIOS

SCENARIO_FILES = sorted(SCENARIOS.glob("*.yaml"))

# Pinocchio's θ̈ against coopsim's, max |Δθ̈| / max |θ̈|. Measured at these states: spatial 8e-15,
# planar 4e-13 to 9e-13 (proximal μ = 1e-12, 3 iterations). Both models sit within ~1e-10 of MuJoCo's
# own KKT solve even at the worst-conditioned states seen (spatial scene at its initial angles).
ACC_RTOL = 1e-9


def _load_peers():
    """validation/peers.py as a module (validation/ is a folder of scripts, not a package)."""
    spec = importlib.util.spec_from_file_location("validation_peers", ROOT / "validation" / "peers.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


peers = _load_peers()


@pytest.fixture
def pin():
    return pytest.importorskip("pinocchio")


@pytest.fixture(scope="module")
def paper_run():
    """The paper scenario and coopsim's reference over 0.2 s (output every 0.01 s)."""
    model = load_scenario(SCENARIOS / "paper_planar_2x3.yaml")
    return model, simulate(model, duration=0.2)


def _states(model, count: int, seed: int, spread: float = 0.1):
    """`count` consistent (q, qd, tau): q0 + N(0, spread²) rad and N(0, 1) rad/s rates projected
    onto the loop-closure manifold; the scenario's torque at a random time plus N(0, 1) N·m."""
    rng = np.random.default_rng(seed)
    n = model.n_total
    out = []
    for _ in range(count):
        st = consistent_state(model, model.q0 + rng.normal(scale=spread, size=n), rng.normal(size=n))
        tau = torque_at(model.torques, rng.uniform(0.0, model.duration)) + rng.normal(size=n)
        out.append((st.q, st.qd, tau))
    return out


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=[p.stem for p in SCENARIO_FILES])
def test_pinocchio_accelerations_match_coopsim(pin, path):
    model = load_scenario(path)
    system = peers.pinocchio_system(model)
    for q, qd, tau in _states(model, 6, seed=7):
        assert peers.closure_residual(system, q) < 1e-11
        ref = forward(model, q, qd, tau)[1].qdd
        err = np.max(np.abs(system.qdd(q, qd, tau) - ref)) / np.max(np.abs(ref))
        assert err <= ACC_RTOL, (model.name, err)


def test_planar_6d_constraint_is_redundant_and_needs_the_proximal_solver(pin):
    """The planar scene's 6D weld has 3 zero directions: a plain Cholesky solve (μ = 0) of the
    singular Delassus matrix gives NaN; μ = 1e-12 with a few proximal iterations gives θ̈ exactly."""
    model = load_scenario(SCENARIOS / "paper_planar_2x3.yaml")
    (q, qd, tau), = _states(model, 1, seed=3)
    ref = forward(model, q, qd, tau)[1].qdd
    with np.errstate(invalid="ignore"):
        plain = peers.pinocchio_system(model, proximal=(1e-14, 0.0, 1)).qdd(q, qd, tau)
    assert not np.all(np.isfinite(plain))
    prox = peers.pinocchio_system(model)
    assert np.max(np.abs(prox.qdd(q, qd, tau) - ref)) / np.max(np.abs(ref)) <= ACC_RTOL
    assert 1 < prox.settings.iter < 10


def test_pinocchio_trajectory_and_timing(pin, paper_run):
    model, ref = paper_run
    system = peers.pinocchio_system(model)
    traj = peers.pinocchio_trajectory(system, ref.initial.q, ref.initial.qd, ref.t, None, 1e-10, 1e-11)
    assert np.max(np.abs(traj.q - ref.q)) <= 1e-8  # rad; measured 2e-11
    assert traj.nfev > 10 and traj.wall_time > 0 and np.max(traj.residual) < 1e-9
    assert 0 < peers.pinocchio_eval_us(system, ref.q[-1], ref.qd[-1], ref.tau[-1], calls=200, repeats=2) < 1e4


def test_pinocchio_missing_says_how_to_install(monkeypatch, paper_run):
    monkeypatch.setitem(sys.modules, "pinocchio", None)
    with pytest.raises(ImportError, match=r"pip install -e '\.\[bench\]'"):
        peers.pinocchio_system(paper_run[0])


def test_mujoco_rollout_matches_coopsim_and_run_twin(paper_run):
    """RK4 at 0.1 ms, weld time constant one step: measured 2.2e-11 rad from coopsim; bit-identical
    to run_twin (constant torques: the midpoint hold is exact)."""
    model, ref = paper_run
    q0, qd0 = ref.initial.q, ref.initial.qd
    roll = peers.mujoco_rollout(model, q0, qd0, ref.t, "RK4", 1e-4)
    assert roll.diverged_at is None and roll.nstep == 2000 and roll.wall_time > 0
    assert np.max(np.abs(roll.q - ref.q)) <= 1e-6
    assert np.max(roll.weld_violation) <= 1e-9
    twin = run_twin(replace(model, mujoco=replace(model.mujoco, timestep=1e-4, integrator="RK4", weld_solref=None)),
                    q0, qd0, ref.t)
    assert np.max(np.abs(roll.q - twin.q)) <= 1e-12
    assert np.max(np.abs(roll.qd - twin.qd)) <= 1e-10
    assert np.max(np.abs(roll.weld_violation - twin.weld_violation)) <= 1e-12


def test_mujoco_rollout_midpoint_hold_and_instability(paper_run, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its instability warning to ./MUJOCO_LOG.TXT
    model, ref = paper_run
    q0, qd0 = ref.initial.q, ref.initial.qd
    twin = peers.mujoco_twin(model, "Euler", 1e-3)
    assert twin.weld_timeconst == pytest.approx(2e-3)
    ctrl = peers.midpoint_controls(twin, 0.0, 3)
    assert ctrl.shape == (3, twin.mj_model.nu)
    np.testing.assert_allclose(ctrl[:, twin.ctrl_adr], np.tile(torque_at(model.torques, 0.0), (3, 1)))
    euler = peers.twin_rollout(twin, q0, qd0, ref.t)
    assert euler.diverged_at is None and np.max(np.abs(euler.q - ref.q)) < 1e-3  # first order: 2e-5 rad
    # a one-step weld time constant is too stiff for Euler: MuJoCo resets, the samples turn NaN
    unstable = peers.mujoco_rollout(model, q0, qd0, ref.t, "Euler", 1e-3, weld_timeconst=1e-3)
    assert unstable.diverged_at is not None and np.isnan(unstable.q[-1]).all()
    with pytest.raises(ValueError, match="whole multiples"):
        peers.twin_rollout(twin, q0, qd0, np.array([0.0, 1.5e-3]))
    assert 0 < peers.mujoco_forward_us(twin, q0, qd0, ref.tau[0], calls=200, repeats=2) < 1e4
