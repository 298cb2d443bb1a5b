"""The compiled model (coopsim.compiled) against the plain-NumPy reference stages and integrator.

Tolerances: stage terms ≤ 1e-12 relative (max |a − b| / max(1, max |b|)) at random consistent states
of every bundled scenario, and accelerations within that plus eps·cond(Λ M⁻¹ Λᵀ) (the two engines
solve the constraint system by different factorizations, whose forward errors scale with its
condition number); trajectories of the two engines (different step
sequences, both at rtol 1e-11) ≤ 1e-9 rad; dense output against the landing-on-output reference at
the same tolerance ≤ 1e-9 rad.
"""

import os
import signal
import time
from dataclasses import replace

import numpy as np
import pytest

from coopsim.dynamics.closed_chain import chain_terms, forward_dynamics
from coopsim.compiled import api, integrate as cint
from coopsim.core import tableaux
from coopsim.compiled.packing import tabulated_torques
from coopsim.compiled.structs import PACKED_FIELDS, LOOP_FIELDS, TABLEAU_FIELDS, WORKSPACE_FIELDS
from coopsim.compiled.packing import PackedModel, Workspace
from coopsim.dynamics import integrate as ref_integrate
from coopsim.core.model import TorqueTable, torque_at
from coopsim.core.results import output_times
from coopsim.forward.engines import ENGINES, Run
from coopsim.dynamics.integrate import IntegratorStats
from coopsim.forward.simulate import simulate
from coopsim.core.errors import CoopsimError, SimulationError
from helpers import (SCENARIOS, assert_compiled_terms_match_the_reference, consistent_states, constraint_condition,
                     rel_err)
from coopsim.io.scenario import load_scenario

TOL = 1e-12
ALL = sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
# every bundled scene: the top level, the hard cases, the controlled ones and the real robots (skipped
# without the robots extra)
BUNDLED = sorted(str(p.relative_to(SCENARIOS).with_suffix("")) for d in ("", "hard", "control", "robots")
                 for p in (SCENARIOS / d).glob("*.yaml"))


@pytest.fixture(scope="module", params=ALL)
def scene(request):
    return load_scenario(SCENARIOS / f"{request.param}.yaml")


def test_struct_fields_follow_the_named_tuples():
    assert [f for f, _ in PACKED_FIELDS] == list(PackedModel._fields)
    assert [f for f, _ in WORKSPACE_FIELDS] == list(Workspace._fields)
    assert [f for f, _ in LOOP_FIELDS] == list(cint.Loop._fields)
    assert [f for f, _ in TABLEAU_FIELDS] == list(cint.Tableau._fields)


def test_both_integrators_read_the_one_copy_of_the_tableaux():
    """The reference integrator's step tableaux are views of coopsim.core.tableaux, the arrays the
    compiled time loop is built from (tests/dynamics/test_integrate.py checks them against SciPy's)."""
    for ref, core in ((ref_integrate._DOP853.a, tableaux.DOP853_A), (ref_integrate._DOP853.e3, tableaux.DOP853_E3),
                      (ref_integrate._DOPRI5.e, tableaux.DOPRI5_E), (ref_integrate._RK4.b, tableaux.RK4_B)):
        assert np.shares_memory(ref, core) or ref.base is core, "a second copy of a tableau"
    assert np.array_equal(cint.tableau("rk4").B[:4], tableaux.RK4_B)


def test_stage_terms_and_accelerations_match_the_reference(scene):
    assert_compiled_terms_match_the_reference(scene, 10)


def _loadable(name: str):
    try:
        return load_scenario(SCENARIOS / f"{name}.yaml")
    except CoopsimError as exc:
        if name.startswith("robots/"):
            pytest.skip(f"{name}: {exc}")
        raise


@pytest.mark.parametrize("name", BUNDLED)
@pytest.mark.parametrize("rank_tol", [None, 0.5], ids=["solve path", "eigen path"])
def test_reported_condition_number_is_numpys(name, rank_tol):
    """The sampled cond (`closed_chain.constraint_condition`: singular values of the pivoted Cholesky
    factor, or the eigen path's own) against numpy.linalg.cond of the reference Λ𝐈⁻¹Λᵀ at random
    consistent states: relative 1e-13 + 8·K·eps·cond. Both sides form the matrix in floating point,
    which moves λ_min by about eps·λ_max: the ratio is determined only to about eps·cond. rank_tol 0.5
    sends every solve down the eigen path (no Cholesky certificate reaches it)."""
    model = _loadable(name)
    if rank_tol is not None:
        model = replace(model, integrator=replace(model.integrator, rank_tol=rank_tol, on_rank_deficiency="warn"))
    states = consistent_states(model, 6, seed=21)
    Y = np.array([np.concatenate(s) for s in states])
    TAU = np.random.default_rng(22).normal(size=(len(Y), model.n_total))
    out = api.evaluate_states(model, Y, TAU, full=True, n_threads=1)
    K = model.rows.shape[0] * (model.r - 1)
    for (q, qd), cond in zip(states, out.cond):
        ref = constraint_condition(chain_terms(model, q, qd))
        tol = 1e-13 + 8 * K * np.finfo(float).eps * ref
        assert abs(cond / ref - 1.0) <= tol, f"{name}: cond {cond:.17g} against numpy's {ref:.17g}"


def test_batch_on_threads_equals_single_evaluations(paper):
    """Batches on the worker pool, their workspaces kept for the next batch: each state as alone."""
    states = consistent_states(paper, 6, seed=3)
    Y = np.array([np.concatenate(s) for s in states])
    TAU = np.random.default_rng(4).normal(size=(len(Y), paper.n_total))
    first, again = api.evaluate_states(paper, Y, TAU, n_threads=2), api.evaluate_states(paper, Y, TAU, n_threads=2)
    for y, tau, qdd in zip(Y, TAU, first.qdd):
        assert np.array_equal(qdd, api.forward(paper, y[:6], y[6:], tau).qdd)
    assert np.array_equal(again.qdd, first.qdd)


def test_a_forked_child_runs_batches_on_a_pool_of_its_own(paper):
    """The worker pool's threads are not inherited by a fork: a child's batch on threads completes."""
    Y = np.array([np.concatenate(s) for s in consistent_states(paper, 4, seed=3)])
    TAU = np.zeros((len(Y), paper.n_total))
    want = api.evaluate_states(paper, Y, TAU, n_threads=2).qdd      # the parent's pool is running
    pid = os.fork()
    if pid == 0:                                                     # the child: exit 0 only if it agrees
        ok = np.array_equal(api.evaluate_states(paper, Y, TAU, n_threads=2).qdd, want)
        os._exit(0 if ok else 1)
    for _ in range(600):
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        time.sleep(0.05)
    else:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's batch did not complete (the parent's pool inherited)")
    assert os.waitstatus_to_exitcode(status) == 0


def test_parameter_sets_in_one_call(paper):
    """forward_models: the object's mass changed per model equals one model at a time."""
    models = [replace(paper, object=replace(paper.object, mass=m)) for m in (5.0, 18.0, 40.0)]
    q, qd = consistent_states(paper, 1, seed=5)[0]
    Y = np.concatenate([q, qd])[None]
    TAU = np.ones((1, paper.n_total))
    QDD, status = api.forward_models(models, Y, TAU)
    for m, qdd in zip(models, QDD):
        assert rel_err(qdd[0], forward_dynamics(m, chain_terms(m, q, qd), TAU[0]).qdd) <= TOL
    assert not status.any()


def test_torque_tables_match_the_model(paper):
    tabs = (TorqueTable(np.array([0.0, 1.0, 2.5]), np.array([[1.0, 0, -1], [2, 1, 0], [0, 0, 3]])),
            TorqueTable(np.zeros(1), np.array([[0.5, 0.25, 0.125]])))
    model = replace(paper, torques=tabs)
    t = np.array([-1.0, 0.0, 0.3, 1.0, 2.0, 2.5, 7.0])
    ref = np.array([torque_at(tabs, ti) for ti in t])
    assert np.allclose(tabulated_torques(api.compiled(model).P, t), ref, rtol=0, atol=1e-15)


# Simulated time per scenario in the engine comparison (default 0.25 s: the plain-NumPy reference engine
# at rtol 1e-11 costs seconds per scenario and method, the suite's largest share; a quarter second still
# spans dozens of adaptive steps with dense output between them). gantry_prismatic: 0.1 s — its
# reference-engine run costs ~9 s serial over 0.5 s against ~2 s over 0.1 s, and its prismatic dynamics
# are checked term by term against MuJoCo in test_joints.py; 0.1 s (11 outputs, 66 and 197 evaluations)
# still runs the whole compiled loop with dense output over its slides.
ENGINE_DURATION = {"gantry_prismatic": 0.1}
ENGINE_DEFAULT_DURATION = 0.25


@pytest.mark.parametrize("method", ["dop853", "dopri5"])
def test_engines_agree_on_every_scenario(scene, method):
    """Compiled (dense output, unbounded step) against reference (landing on outputs), same
    tolerance: every reported quantity."""
    s = replace(scene.integrator, method=method, rtol=1e-11, atol=1e-12)
    model = replace(scene, duration=min(scene.duration, ENGINE_DURATION.get(scene.name, ENGINE_DEFAULT_DURATION)),
                    integrator=s)
    a, b = simulate(model), simulate(model, engine="reference")
    assert a.stats.n_rhs < b.stats.n_rhs
    for name in ("q", "object_pos", "object_quat"):
        err = float(np.max(np.abs(getattr(a, name) - getattr(b, name))))
        assert err <= 1e-9, f"{method} {scene.name}: {name} differs by {err:.3g}"
    for name in ("qd", "qdd", "object_twist", "object_acc", "grasp_wrench", "internal_wrench"):
        err = rel_err(getattr(a, name), getattr(b, name))
        assert err <= 1e-7, f"{method} {scene.name}: {name} differs by {err:.3g}"
    assert np.max(a.residual_pos) <= model.integrator.projection_tol


@pytest.mark.parametrize("name", ["paper_planar_2x3", "planar_3arm_vertical"])
def test_outputs_left_to_the_sampler_equal_the_loops_projection(name):
    """The outputs the time loop leaves unprojected (defer) come out of the sampler as the loop projects
    them, and every sampled quantity as when they are evaluated from scratch, to the bit: the sampler
    projects with the loop's kernel and evaluates on that projection's own kinematics (two and three
    arms: the dense and the O(r) solves)."""
    scene = load_scenario(SCENARIOS / f"{name}.yaml")
    s = replace(scene.integrator, rtol=1e-9, atol=1e-10)
    model = replace(scene, duration=0.5, integrator=s)
    y0 = np.concatenate(consistent_states(model, 1, seed=31)[0])
    t = output_times(model.duration, s.output_dt)
    ref = api.integrate_chain(model, y0, t, "dop853", rtol=s.rtol, atol=s.atol)
    run = api.integrate_chain(model, y0, t, "dop853", rtol=s.rtol, atol=s.atol, defer=True)
    assert ref.raw is None and run.raw[1:-1].all() and not run.raw[[0, -1]].any()
    assert run.counts[:3] == ref.counts[:3] and run.counts[3] == ref.counts[3] - np.count_nonzero(run.raw)
    assert np.array_equal(run.Y[~run.raw], ref.Y[~run.raw])
    assert np.max(np.abs(run.Y[run.raw] - ref.Y[run.raw])) > 0, "the dense outputs were projected after all"
    Y = run.Y.copy()
    got, want = api.sample_states(model, t, Y, raw=run.raw), api.sample_states(model, t, ref.Y)
    assert np.array_equal(Y, ref.Y)
    for field in got._fields:
        assert np.array_equal(getattr(got, field), getattr(want, field)), field


def test_a_failed_projection_at_a_sample_names_time_and_configuration(paper):
    """A row the sampler cannot project (here non-finite) stops the run as the time loop's own
    projection failure does: SimulationError with the time, the configuration and the reason."""
    t = np.array([0.0, 0.01])
    y = np.concatenate([paper.q0, paper.qd0])
    Y = np.array([y, np.full_like(y, np.nan)])
    run = Run(Y, IntegratorStats(0, 0, 0, 0), (), raw=np.array([False, True]))
    with pytest.raises(SimulationError, match=r"simulation failed at t=0.01 s, q=\[.*\] rad: projection: loop "
                                              r"closure did not converge"):
        ENGINES["compiled"].sample(paper, t, run)


def test_rk4_is_the_reference_rk4(paper):
    s = replace(paper.integrator, method="rk4", step=0.005)
    model = replace(paper, duration=0.5, integrator=s)
    a, b = simulate(model), simulate(model, engine="reference")
    assert a.stats.n_rhs == b.stats.n_rhs
    assert float(np.max(np.abs(a.q - b.q))) <= 1e-13


def test_output_grid_no_longer_limits_the_step(paper):
    """A 1 ms output grid does not change the step sequence (dense output)."""
    coarse = simulate(replace(paper, duration=2.0, integrator=replace(paper.integrator, output_dt=0.1)))
    fine = simulate(replace(paper, duration=2.0, integrator=replace(paper.integrator, output_dt=0.001)))
    assert coarse.stats.n_accepted == fine.stats.n_accepted
    assert float(np.max(np.abs(fine.q[::100] - coarse.q))) <= 1e-10


def test_fixed_step_meets_tabulated_stage_times_exactly(paper):
    """The fixed-step loop evaluates torques exactly at `stage_times` (a table zigzagging ±0.1 N·m
    between consecutive knots tells any other time apart): the same steps of the reference DOP853
    stage formula, with the torque looked up by exact time, agree to rounding."""
    tab = cint.tableau("dop853")
    times = cint.stage_times(0.0, 0.05, 0.01, tab.C, tab.stages)
    zig = 0.1 * (-1.0) ** np.arange(len(times))
    lookup = dict(zip(times.tolist(), zig))
    table = TorqueTable(times, np.repeat(zig[:, None], 3, axis=1))
    model = replace(paper, duration=0.05, torques=(table, table),
                    integrator=replace(paper.integrator, stabilization="none"))
    y0 = np.concatenate(consistent_states(paper, 1, seed=8)[0])
    run = api.integrate_chain(model, y0, np.array([0.0, 0.05]), "dop853", fixed_step=0.01)
    assert run.status == 0 and run.counts[1] == 5

    def f(t, y):   # KeyError unless t is a knot
        tau = np.full(model.n_total, lookup[t])
        n = model.n_total
        return np.concatenate([y[n:], forward_dynamics(model, chain_terms(model, y[:n], y[n:]), tau).qdd])

    y, h = y0.copy(), 0.01
    for j in range(5):
        t = 0.0 + j * h
        y = ref_integrate._rk_step(f, t, y, f(t, y), h, ref_integrate._DOP853, np.empty((12, len(y))))
    assert float(np.max(np.abs(run.Y[-1] - y))) <= 1e-12


def test_failure_names_time_and_configuration(paper):
    model = replace(paper, duration=0.2, torques=(TorqueTable(np.zeros(1), np.full((1, 3), np.nan)),
                                                  TorqueTable(np.zeros(1), np.zeros((1, 3)))))
    with pytest.raises(SimulationError, match=r"simulation failed at t=0 s, q=\[.*\] rad: non-finite joint accelerations"):
        simulate(model)


def test_progress_is_reported_and_does_not_change_the_result(paper):
    model = replace(paper, duration=1.0)
    seen = []
    a = simulate(model)
    b = simulate(model, progress=seen.append)
    assert np.array_equal(a.q, b.q)
    assert seen and seen[-1] == pytest.approx(1.0) and all(np.diff(seen) >= 0)


def test_a_groups_compile_notice_fires_once_and_only_when_pending(monkeypatch):
    """The command line's notices (`api.set_compile_notice`): a group's fires on its first use while its
    code is missing, once; never while it is cached, nor for another group."""
    calls = []
    for pending in (False, True):
        monkeypatch.setattr(api, "compile_pending", lambda group="base", p=pending: group != "base" and p)
        api.set_compile_notice(base=lambda: calls.append("base"), extras=lambda: calls.append("extras"),
                               control=lambda: calls.append("control"))
        for group in ("control", "control", "extras", "base"):
            api.announce_compile(group)
    api.set_compile_notice()
    assert calls == ["control", "extras"]
