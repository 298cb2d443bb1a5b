"""Forward simulation of the closed chain: the pipeline in the order it runs.

    state (θ, θ̇), torque τ(t)
      → chain_terms        kinematics (stage 1), Gibbs–Appell arm dynamics (2), object/grasp (3),
                           loop-closure Jacobians (4)
      → stabilization      Baumgarte right-hand side, if selected (5)
      → forward_dynamics   θ̈ and grasp wrenches (eqs. 25–27)
      → integrate          adaptive DOP853/DOPRI5 (dense output) or fixed-step RK4, projection after
                           each step (5)
      → sample             every reported quantity at the output times

Two engines run this pipeline: 'compiled' (`coopsim.compiled`, the default: the whole time loop in
compiled code) and 'reference' (the plain-NumPy stage modules and `coopsim.dynamics.integrate`, which lands on
every output time; used for torques given as a Python function, and as the readable reference the
compiled engine is tested against). A controller in the loop (`coopsim.control.controller`, torques that read the
state) runs in the compiled time loop (`coopsim.compiled.control`, evaluated at every stage; the
adaptive steps then end on every output time, as the reference loop's do), except a 'bounded'
distribution or a Python callable: those run on a third engine, 'stages' — the reference time loop over
the compiled stage kernels, the controller evaluated in Python. `SimResult.engine` says which ran.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from coopsim.forward import diagnostics
from coopsim.core.errors import ConstraintError, ConstraintRankWarning, CoopsimError, SimulationError
from coopsim.dynamics.closed_chain import ChainAcceleration, ChainTerms, chain_terms, forward_dynamics, position_residual
from coopsim.forward.diagnostics import RunWarning, describe_state, run_warning
from coopsim.dynamics.grasp import grasp_matrix, internal_wrench
from coopsim.dynamics.integrate import IntegrationError, IntegratorStats, integrate
from coopsim.dynamics.manifold import baumgarte_term, consistent_state, project_positions, project_velocities
from coopsim.core.model import (IntegratorSettings, Model, TorqueFeedback, TorqueFunction, applied_torque, loop_controller,
                                torque_at)
from coopsim.core.results import Projection, SampledMotion, output_times
from coopsim.core.spatial import rot_to_quat


@dataclass(frozen=True, eq=False)
class SimResult(SampledMotion):
    """A forward run sampled on its output grid: N samples, n joints stacked arm by arm, r arms, SI
    units, world axes.

    Attributes:
        t: (N,) s.
        q, qd, qdd: (N, n) rad, rad/s, rad/s² (m, m/s, m/s² on a prismatic joint).
        tau: (N, n) N·m (N), the torques applied.
        object_pos: (N, 3) m, the object's centre of mass C.
        object_quat: (N, 4) the object's orientation [w, x, y, z].
        object_twist: (N, 6) [v_C; ω] m/s, rad/s.
        object_acc: (N, 6) [v̇_C; ω̇] m/s², rad/s².
        grasp_wrench: (N, r, 6) [f; n] N, N·m, the wrench each end-effector applies to the object at
            its end-effector point.
        internal_wrench: (N, r, 6) at C (eq. 7, the paper's W⁺); rows sum to zero.
        residual_pos: (N,) max |Φ|, m or rad (loop closure).
        residual_vel: (N,) max |Λθ̇|.
        cond: (N,) the condition number of Λ𝐈⁻¹Λᵀ.
        model: the Model that ran.
        initial: the Projection applied to the scenario's initial state.
        stats: the integrator's counts (IntegratorStats).
        wall_time: s; not deterministic, so never logged as data.
        events: RunWarnings raised while integrating (a rank-deficient constraint matrix).
        engine: the engine that ran: 'compiled', 'reference' or 'stages'.
        control_counts: with a controller in the compiled loop, (stage evaluations, evaluations in
            which the motor lines clipped a joint, clipped (evaluation, joint) pairs); else None.
        manipulability: (N, r) of each arm, computed on first use (`coopsim.forward.diagnostics`).
        kinetic_energy: (N,) J, computed on first use.
        warnings: every RunWarning of the run, events included, computed on first use.
    """

    model: Model
    object_acc: np.ndarray
    grasp_wrench: np.ndarray
    internal_wrench: np.ndarray
    residual_pos: np.ndarray
    residual_vel: np.ndarray
    cond: np.ndarray
    initial: Projection
    stats: IntegratorStats
    wall_time: float
    events: tuple[RunWarning, ...] = ()
    engine: str = "compiled"
    control_counts: tuple[int, int, int] | None = None

    @cached_property
    def arm_terms(self) -> diagnostics.ArmTerms:
        return diagnostics.arm_terms(self.model, self.q, self.qd)

    @cached_property
    def manipulability(self) -> np.ndarray:
        return diagnostics.manipulability(self.model, self.arm_terms.J)

    @cached_property
    def kinetic_energy(self) -> np.ndarray:
        return diagnostics.kinetic_energy(self.model, self.qd, self.arm_terms, self.object_twist)

    @cached_property
    def warnings(self) -> tuple[RunWarning, ...]:
        return diagnostics.collect(self, self.arm_terms)


def forward(model: Model, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> tuple[ChainTerms, ChainAcceleration]:
    """One evaluation of the closed-chain forward dynamics at (q, qd) with torques tau (n,)."""
    terms = chain_terms(model, q, qd)
    stab = baumgarte_term(model, q, terms.Lam_qd) if model.integrator.stabilization == "baumgarte" else None
    return terms, forward_dynamics(model, terms, tau, stab)


def initial_state(model: Model, engine: str = "compiled") -> Projection:
    """Consistent initial state: the scenario's (q0, qd0) projected onto the loop-closure manifold, on
    the compiled engine or the NumPy reference (`engine`). Raises ConstraintError naming the fields
    when the grasps cannot be reached from there."""
    if engine == "compiled":
        from coopsim.compiled.api import consistent_state as project
    else:
        project = consistent_state
    try:
        proj = project(model, model.q0, model.qd0)
    except ConstraintError as exc:
        raise ConstraintError(f"object.grasps: the arms cannot close the loop from arms[].initial: {exc}") from None
    worst = float(np.max(np.abs(proj.dq)))
    limit = model.integrator.max_initial_correction
    if worst > limit:
        raise ConstraintError(
            f"object.grasps: closing the loop from arms[].initial needs a joint correction of {worst:.4g} rad "
            f"(> integrator.max_initial_correction = {limit:g} rad); check the grasps and initial angles")
    return proj


def _rank_reason(rank: int, cond: float) -> str:
    return f"constraint matrix Λ𝐈⁻¹Λᵀ is rank-deficient (rank {rank}, cond {cond:.3g})"


def _rank_event(t: float, q: np.ndarray, rank: int, cond: float, stacklevel: int) -> RunWarning:
    """The rank-deficiency warning (a ConstraintRankWarning now, a RunWarning on the result)."""
    reason = _rank_reason(rank, cond) + "; using minimum-norm grasp wrenches"
    warnings.warn(f"at {describe_state(t, q)}: {reason}", ConstraintRankWarning, stacklevel=stacklevel + 1)
    return run_warning("rank_deficient", t, q, reason, rank=rank, condition_number=cond)


def _rhs(model: Model, progress=None, warned: list | None = None):
    """dy/dt for y = [θ; θ̇]; wraps failures with the time and configuration; reports the fraction
    of the run done to `progress` (called with t / duration); the first loss of rank is appended to
    `warned` (a RunWarning)."""
    n = model.n_total
    warned = [] if warned is None else warned

    def rhs(t, y):
        q, qd = y[:n], y[n:]
        if progress is not None:
            progress(min(1.0, t / model.duration) if model.duration > 0 else 1.0)
        tau = applied_torque(model.torques, t, q, qd)
        try:
            with np.errstate(invalid="ignore", over="ignore"):
                _, acc = forward(model, q, qd, tau)
        except ConstraintError as exc:
            raise SimulationError(f"simulation failed at {describe_state(t, q)}: {exc}") from None
        if not np.all(np.isfinite(acc.qdd)):
            raise SimulationError(f"simulation failed at {describe_state(t, q)}: non-finite joint accelerations "
                                  f"(torques up to {np.max(np.abs(tau)):.3g} N·m, rates up to {np.max(np.abs(qd)):.3g} rad/s)")
        if acc.rank < model.rows.shape[0] * (model.r - 1):
            if model.integrator.on_rank_deficiency == "error":
                raise SimulationError(f"simulation failed at {describe_state(t, q)}: {_rank_reason(acc.rank, acc.cond)}")
            if not warned:
                warned.append(_rank_event(t, q, acc.rank, acc.cond, stacklevel=2))
        return np.concatenate([qd, acc.qdd])

    return rhs


def _projector(model: Model):
    n, tol = model.n_total, model.integrator.projection_tol

    def project(t, y):
        try:
            q, _ = project_positions(model, y[:n], tol)
        except ConstraintError as exc:
            raise SimulationError(f"simulation failed at {describe_state(t, y[:n])}: projection: {exc}") from None
        return np.concatenate([q, project_velocities(model, q, y[n:])])

    return project


ENGINES = ("compiled", "reference", "stages")


def simulate(model: Model, duration: float | None = None, settings: IntegratorSettings | None = None,
             progress=None, engine: str = "compiled", fixed_step: float | None = None) -> SimResult:
    """Integrate the closed chain (eqs. 14–27) from its consistent initial state, driven by the model's
    torque source, and sample every reported quantity on the output grid.

    Args:
        model: the Model; its `torques` are the source (tables, a TorqueFunction, or a TorqueFeedback
            such as a closed loop, `coopsim.control.controller.closed_loop`).
        duration: s, in place of the model's.
        settings: integrator settings in place of the model's.
        progress: called with the fraction done (0..1) as the run advances.
        engine: 'compiled', 'reference' or 'stages' (module docstring). An in-the-loop controller runs
            on the compiled engine unless it needs Python (then 'stages'); other Python torque
            functions run on 'reference' ('stages' for feedback).
        fixed_step: s, compiled engine: the method (DOP853 or DOPRI5 too) at fixed steps of at most
            this size, landing on every output time, for torques tabulated at exactly those steps'
            stage times (`coopsim.compiled.integrate.stage_times`).

    Returns:
        SimResult: N output samples (t (N,) s, q, qd, qdd (N, n), torques, object motion, grasp and
        internal wrenches, constraint residuals, condition numbers, warnings), world axes, SI units.

    Raises:
        CoopsimError: the model has a `control:` section that is not in the loop.
        SimulationError: the run failed; the message gives the time, the configuration and the reason.
    """
    if settings is not None:
        model = replace(model, integrator=settings)
    if duration is not None:
        model = replace(model, duration=duration)
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}")
    start = time.perf_counter()
    if model.control is not None and not isinstance(model.torques, TorqueFeedback):
        raise CoopsimError(f"{model.name}: the scenario's control: section is not in the loop: close it first "
                           f"(coopsim.closed_loop(model))")
    ctrl = loop_controller(model)
    if isinstance(model.torques, TorqueFeedback) and engine == "compiled":
        engine = "compiled" if ctrl is not None and ctrl.compiled_reason is None else "stages"
    elif isinstance(model.torques, TorqueFunction) and engine != "stages":
        engine = "reference"
    init = initial_state(model, engine)
    t_out = output_times(model.duration, model.integrator.output_dt)
    if engine != "compiled":
        if fixed_step is not None:
            raise ValueError("fixed_step needs the compiled engine and tabulated torques")
        res = _simulate_reference(model, init, t_out, progress, start, stages=engine == "stages")
    else:
        res = _simulate_compiled(model, init, t_out, progress, start, fixed_step,
                                 ctrl if isinstance(model.torques, TorqueFeedback) else None)
    res = replace(res, engine=engine)
    _check_conditioning(res)
    return res


def _check_conditioning(res: SimResult) -> None:
    """With integrator.on_ill_conditioning: error, stop at the first sample whose constraint matrix is
    ill-conditioned (`coopsim.forward.diagnostics`); a warning on the result otherwise."""
    m = res.model
    i = diagnostics.first_ill_conditioned(m, res.cond) if m.integrator.on_ill_conditioning == "error" else None
    if i is not None:
        force = float(np.max(np.linalg.norm(res.internal_wrench[i, :, :3], axis=1)))
        raise SimulationError(f"simulation stopped at {describe_state(res.t[i], res.q[i])}: "
                              f"{diagnostics.ill_conditioning_reason(m, res.cond[i], force)} "
                              f"(integrator.on_ill_conditioning: error)")


def _simulate_compiled(model: Model, init: Projection, t_out: np.ndarray, progress, start: float,
                       fixed_step: float | None = None, controller=None) -> SimResult:
    """The compiled engine: one compiled time loop (`coopsim.compiled.api.integrate_chain`), then the
    compiled sampling of every reported quantity. With a `coopsim.control.controller.Controller` (model being its
    closed loop) the loop evaluates it at every stage over its scenario's torque tables, lands on every
    output time, and the samples' torques are the controller's there."""
    from coopsim.compiled import api

    s = model.integrator
    kernel_model = model if controller is None else controller.model
    y0 = np.concatenate([init.q, init.qd])
    fixed = fixed_step if fixed_step is not None else (s.step if s.method == "rk4" else None)
    h_max = np.inf if s.max_step is None else s.max_step
    loop = None if controller is None else controller.loop_record()
    run = api.integrate_chain(kernel_model, y0, t_out, s.method, rtol=s.rtol, atol=s.atol, h_max=h_max,
                              fixed_step=fixed, progress=progress, controller=loop, land=loop is not None)
    n = model.n_total
    events = ()
    if run.rank_warning is not None:
        t, y, rank, cond = run.rank_warning
        events = (_rank_event(t, y[:n], rank, cond, stacklevel=3),)
    if run.status:
        raise SimulationError(f"simulation failed at {describe_state(run.fail_t, run.fail_y[:n])}: "
                              f"{_compiled_reason(kernel_model, run)}")
    counts, tau = None, None
    if controller is not None:
        counts = controller.loop_counts()
        tau = controller.loop_torques(t_out, run.Y[:, :n], run.Y[:, n:])
    smp = api.sample_states(kernel_model, t_out, run.Y, tau)
    stats = IntegratorStats(n_rhs=run.counts[0], n_accepted=run.counts[1], n_rejected=run.counts[2],
                            n_projections=run.counts[3])
    return replace(_sampled_result(model, t_out, run.Y, smp, init, stats, start, events), control_counts=counts)


def _sampled_result(model: Model, t_out, Y, smp, init: Projection, stats, start: float, events) -> SimResult:
    """The SimResult of states Y (N, 2n) at t_out sampled by the compiled sampler (`smp`)."""
    n = model.n_total
    return SimResult(model=model, t=t_out, q=Y[:, :n], qd=Y[:, n:], qdd=smp.qdd, tau=smp.tau,
                     object_pos=smp.object_pos, object_quat=smp.object_quat, object_twist=smp.object_twist,
                     object_acc=smp.object_acc, grasp_wrench=smp.grasp_wrench, internal_wrench=smp.internal_wrench,
                     residual_pos=smp.residual_pos, residual_vel=smp.residual_vel, cond=smp.cond, initial=init,
                     stats=stats, wall_time=time.perf_counter() - start, events=tuple(events))


def _compiled_reason(model: Model, run) -> str:
    """The one-line reason of a compiled run's failure (as the reference engine words it)."""
    from coopsim.compiled import api

    reason = api.REASONS.get(run.status, f"failure code {run.status}")
    n = model.n_total
    if run.status == api.chain.RANK_DEFICIENT:
        W = api.compiled(model).W
        reason += f" (rank {int(W.rank[0])}, cond {float(W.cond[0]):.3g})"
    if run.status == api.chain.NON_FINITE:
        tau = torque_at(model.torques, run.fail_t)
        reason += (f" (torques up to {np.max(np.abs(tau)):.3g} N·m, rates up to "
                   f"{np.max(np.abs(run.fail_y[n:])):.3g} rad/s)")
    return reason


def _simulate_reference(model: Model, init: Projection, t_out: np.ndarray, progress, start: float,
                        stages: bool = False) -> SimResult:
    """The reference engine: `coopsim.dynamics.integrate` over the plain-NumPy stages, landing on every output
    (stages: over the compiled stage kernels, sampled by the compiled sampler — the 'stages' engine)."""
    s = model.integrator
    if stages:
        return _simulate_stages(model, init, t_out, progress, start)
    project = _projector(model) if s.stabilization == "projection" else None
    step = s.step if s.method == "rk4" else (np.inf if s.max_step is None else s.max_step)
    events: list = []
    try:
        Y, stats = integrate(_rhs(model, progress, events), np.concatenate([init.q, init.qd]), t_out,
                             method=s.method, rtol=s.rtol, atol=s.atol, step=step, project=project)
    except IntegrationError as exc:
        n = model.n_total
        raise SimulationError(f"simulation failed at {describe_state(exc.t, exc.y[:n])}: {exc.reason}") from None
    events += _controller_warnings(model)
    return replace(_sample(model, t_out, Y, init, stats, time.perf_counter() - start), events=tuple(events))


def _simulate_stages(model: Model, init: Projection, t_out: np.ndarray, progress, start: float) -> SimResult:
    """The 'stages' engine: the reference time loop (`coopsim.dynamics.integrate`, landing on every output) with
    the compiled closed-chain evaluation (`coopsim.compiled.api.forward`) and projection at each stage,
    the torques evaluated in Python there (a controller in the loop); the compiled sampler reports."""
    from coopsim.compiled import api

    s, n = model.integrator, model.n_total
    events: list = []

    def rhs(t, y):
        q, qd = y[:n], y[n:]
        if progress is not None:
            progress(min(1.0, t / model.duration) if model.duration > 0 else 1.0)
        ev = api.forward(model, q, qd, applied_torque(model.torques, t, q, qd))
        if ev.status == api.chain.RANK_DEFICIENT and model.integrator.on_rank_deficiency != "error":
            if not events:
                events.append(_rank_event(t, q, ev.rank, float(api.compiled(model).W.cond[0]), stacklevel=2))
        elif ev.status:
            raise SimulationError(f"simulation failed at {describe_state(t, q)}: {api.REASONS[ev.status]}")
        return np.concatenate([qd, ev.qdd])

    def project(t, y):
        try:
            p = api.consistent_state(model, y[:n], y[n:])
        except ConstraintError as exc:
            raise SimulationError(f"simulation failed at {describe_state(t, y[:n])}: projection: {exc}") from None
        return np.concatenate([p.q, p.qd])

    step = s.step if s.method == "rk4" else (np.inf if s.max_step is None else s.max_step)
    try:
        Y, stats = integrate(rhs, np.concatenate([init.q, init.qd]), t_out, method=s.method, rtol=s.rtol,
                             atol=s.atol, step=step, project=project if s.stabilization == "projection" else None)
    except IntegrationError as exc:
        raise SimulationError(f"simulation failed at {describe_state(exc.t, exc.y[:n])}: {exc.reason}") from None
    events += _controller_warnings(model)
    tau = np.array([applied_torque(model.torques, ti, y[:n], y[n:]) for ti, y in zip(t_out, Y)])
    return _sampled_result(model, t_out, Y, api.sample_states(model, t_out, Y, tau), init, stats, start, events)


def _controller_warnings(model: Model) -> list[RunWarning]:
    """The run warnings of the model's in-the-loop controller (none without one)."""
    ctrl = loop_controller(model)
    return [] if ctrl is None else list(ctrl.run_warnings())


def _sample(model: Model, t: np.ndarray, Y: np.ndarray, init: Projection, stats, wall: float) -> SimResult:
    """Evaluate every reported quantity at the output samples."""
    n, N, r = model.n_total, len(t), model.r
    out = {k: np.zeros((N,) + shape) for k, shape in [
        ("qdd", (n,)), ("tau", (n,)), ("object_pos", (3,)), ("object_quat", (4,)), ("object_twist", (6,)),
        ("object_acc", (6,)), ("grasp_wrench", (r, 6)), ("internal_wrench", (r, 6)), ("residual_pos", ()),
        ("residual_vel", ()), ("cond", ())]}
    for i, (ti, y) in enumerate(zip(t, Y)):
        q, qd = y[:n], y[n:]
        tau = applied_torque(model.torques, ti, q, qd)
        terms, acc = forward(model, q, qd, tau)
        W = [grasp_matrix(s) for s in terms.s]
        out["qdd"][i], out["tau"][i] = acc.qdd, tau
        out["object_pos"][i], out["object_quat"][i] = terms.obj.p_C, rot_to_quat(terms.obj.R_o)
        out["object_twist"][i], out["object_acc"][i] = terms.v_o, acc.vd_o
        out["grasp_wrench"][i], out["internal_wrench"][i] = acc.F_e, internal_wrench(W, acc.F_e)
        out["residual_pos"][i] = np.max(np.abs(position_residual(model, q)))
        out["residual_vel"][i] = np.max(np.abs(terms.Lam_qd))
        out["cond"][i] = acc.cond
    return SimResult(model=model, t=t, q=Y[:, :n], qd=Y[:, n:], initial=init, stats=stats, wall_time=wall, **out)
