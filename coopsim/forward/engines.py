"""The forward pipeline's engines behind one interface: each projects a state onto the loop-closure
manifold, runs the time loop over the output grid, and samples every reported quantity there.

    ReferenceEngine  the plain-NumPy stages (`coopsim.dynamics`) in `coopsim.dynamics.integrate`,
                     landing on every output time; the readable reference
    CompiledEngine   the whole time loop compiled (`coopsim.compiled.api.integrate_chain`, dense
                     output), an in-the-loop controller evaluated inside it at every stage
    StagesEngine     the reference time loop over the compiled stage kernels, the torques evaluated in
                     Python at every stage

The third stays because the compiled time loop cannot call Python: a torque source that is Python
code at every stage (the 'bounded' distribution's QP, a notebook's callable) runs on the reference
loop, and the compiled stages make that loop fast. `coopsim.forward.simulate` chooses the engine and
enters it once; each engine's failures are worded alike (the time, the configuration, the reason).
"""

from __future__ import annotations

import warnings
from typing import NamedTuple, Protocol

import numpy as np

from coopsim.core.errors import ConstraintError, ConstraintRankWarning, SimulationError
from coopsim.core.model import Model, applied_torque, loop_controller, torque_at
from coopsim.core.results import Projection
from coopsim.core.spatial import rot_to_quat
from coopsim.dynamics.closed_chain import (ChainAcceleration, ChainTerms, chain_terms, forward_dynamics,
                                           position_residual)
from coopsim.dynamics.grasp import grasp_matrix, internal_wrench
from coopsim.dynamics.integrate import IntegrationError, IntegratorStats, integrate
from coopsim.dynamics.manifold import baumgarte_term, consistent_state, project_positions, project_velocities
from coopsim.forward.diagnostics import RunWarning, describe_state, run_warning


class Run(NamedTuple):
    """What an engine's time loop gives back.

    Attributes:
        Y: (N, 2n) the states [θ; θ̇] at the output times.
        stats: the integrator's counts.
        events: RunWarnings raised while integrating (a rank-deficient constraint matrix).
        tau: (N, n) N·m, the torques at the samples when the loop computed them (a controller in the
            compiled loop); None: the sampler evaluates the model's torques there.
        control_counts: the compiled controller's evaluation counters, or None.
        raw: (N,) bool, the rows of Y the loop left as its dense output interpolated them, off the
            loop-closure manifold, for `Engine.sample` to project in place (the compiled engine's samples
            then reuse the projection's kinematics); None: every row is a state of the loop.
    """

    Y: np.ndarray
    stats: IntegratorStats
    events: tuple
    tau: np.ndarray | None = None
    control_counts: tuple | None = None
    raw: np.ndarray | None = None


# What an engine's `sample` gives: every reported quantity at the N samples, keyed by its SimResult field
# (`coopsim.forward.simulate.SimResult` documents shapes and units).
SAMPLED = ("qdd", "tau", "object_pos", "object_quat", "object_twist", "object_acc", "grasp_wrench",
           "internal_wrench", "residual_pos", "residual_vel", "cond")


class Engine(Protocol):
    """The interface every engine implements (module docstring).

    Attributes:
        name: the engine's name: 'compiled', 'reference' or 'stages' (the key of ENGINES).
    """

    name: str

    def project(self, model: Model, q: np.ndarray, qd: np.ndarray) -> Projection:
        """(q, qd) projected onto the loop-closure manifold.

        Args:
            model: the Model.
            q: (n,) rad (m on a prismatic joint), the stacked joint coordinates.
            qd: (n,) rad/s (m/s), the joint rates.

        Returns:
            Projection: the consistent (q, qd), the corrections, max |Φ| before and after, the steps taken.

        Raises:
            ConstraintError: the positions do not converge onto the manifold.
        """

    def run(self, model: Model, init: Projection, t_out: np.ndarray, progress, fixed_step: float | None) -> Run:
        """The time loop from `init` over the output times t_out.

        Args:
            model: the Model (its torques, integrator settings, duration).
            init: the consistent initial state (Projection: q, qd (n,)).
            t_out: (N,) s, the output times, from 0.
            progress: called with the fraction done (0..1) as the run advances; None: no reports.
            fixed_step: s, the compiled engine only: the method at fixed steps of at most this size (None:
                as the integrator settings say).

        Returns:
            Run: the states Y (N, 2n) at t_out, the integrator's counts, the events, and with a controller in
            the compiled loop its torques and counters.

        Raises:
            SimulationError: the run failed; the message gives the time, the configuration and the reason.
        """

    def sample(self, model: Model, t_out: np.ndarray, run: Run) -> dict:
        """Every reported quantity (SAMPLED) at the run's states.

        Args:
            model: the Model.
            t_out: (N,) s, the sample times.
            run: the engine's Run: its states Y (N, 2n) [θ; θ̇] (rad or m, rad/s or m/s) at t_out, the rows
                run.raw flags projected here first, in place; run.tau (N, n) N·m (N on a prismatic joint),
                the torques at the samples, or None: the model's torques there.

        Returns:
            dict: every name of SAMPLED → its (N, …) array, shapes and units as the SimResult field of that
            name (`coopsim.forward.simulate.SimResult`), world axes.

        Raises:
            SimulationError: a flagged row's projection failed (the time, the configuration, the reason).
        """


def forward(model: Model, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> tuple[ChainTerms, ChainAcceleration]:
    """One evaluation of the reference closed-chain forward dynamics (eqs. 25–27).

    Baumgarte stabilization is included when integrator.stabilization selects it.

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), the stacked joint coordinates.
        qd: (n,) rad/s (m/s), the joint rates.
        tau: (n,) N·m (N on a prismatic joint), the joint torques.

    Returns:
        tuple[ChainTerms, ChainAcceleration]: the terms of the state and its accelerations (θ̈, grasp
        wrenches, object acceleration, cond and rank of Λ𝐈⁻¹Λᵀ).

    Raises:
        ConstraintError: the closed-chain mass matrix 𝐈 is not positive definite.
    """
    terms = chain_terms(model, q, qd)
    stab = baumgarte_term(model, q, terms.Lam_qd) if model.integrator.stabilization == "baumgarte" else None
    return terms, forward_dynamics(model, terms, tau, stab)


def rank_reason(rank: int, cond: float) -> str:
    """The one-line reason of a rank-deficient constraint matrix.

    Args:
        rank: the numerical rank of Λ𝐈⁻¹Λᵀ.
        cond: its condition number.

    Returns:
        str: 'constraint matrix Λ𝐈⁻¹Λᵀ is rank-deficient (rank …, cond …)'.
    """
    return f"constraint matrix Λ𝐈⁻¹Λᵀ is rank-deficient (rank {rank}, cond {cond:.3g})"


def rank_event(t: float, q: np.ndarray, rank: int, cond: float, stacklevel: int) -> RunWarning:
    """The rank-deficiency warning: a ConstraintRankWarning now, a RunWarning on the result.

    Args:
        t: s, the time of the rank loss.
        q: (n,) rad (m on a prismatic joint), the stacked joint coordinates there.
        rank: the numerical rank of Λ𝐈⁻¹Λᵀ.
        cond: its condition number.
        stacklevel: the stack level of the Python warning, counted from the caller (the caller's own
            frame is 1).

    Returns:
        RunWarning: a 'rank_deficient' warning (values: rank, condition_number).
    """
    reason = rank_reason(rank, cond) + "; using minimum-norm grasp wrenches"
    warnings.warn(f"at {describe_state(t, q)}: {reason}", ConstraintRankWarning, stacklevel=stacklevel + 1)
    return run_warning("rank_deficient", t, q, reason, rank=rank, condition_number=cond)


def _report(progress, model: Model, t: float) -> None:
    if progress is not None:
        progress(min(1.0, t / model.duration) if model.duration > 0 else 1.0)


def _step_bound(model: Model) -> float:
    s = model.integrator
    return s.step if s.method == "rk4" else (np.inf if s.max_step is None else s.max_step)


def _reference_loop(model: Model, init: Projection, t_out: np.ndarray, rhs,
                    project) -> tuple[np.ndarray, IntegratorStats]:
    """`coopsim.dynamics.integrate` over rhs and project (the latter with projection stabilization
    only); an IntegrationError becomes a SimulationError naming the time and configuration."""
    s, n = model.integrator, model.n_total
    try:
        return integrate(rhs, np.concatenate([init.q, init.qd]), t_out, method=s.method, rtol=s.rtol, atol=s.atol,
                         step=_step_bound(model), project=project if s.stabilization == "projection" else None)
    except IntegrationError as exc:
        raise SimulationError(f"simulation failed at {describe_state(exc.t, exc.y[:n])}: {exc.reason}") from None


def _projection_step(n: int, onto_manifold):
    """The reference loop's projection after each step, y = [θ; θ̇] (2n,) → its projection by
    onto_manifold(q, qd) -> (q, qd); a ConstraintError becomes a SimulationError naming the time and
    configuration."""
    def project(t, y):
        try:
            q, qd = onto_manifold(y[:n], y[n:])
        except ConstraintError as exc:
            raise SimulationError(f"simulation failed at {describe_state(t, y[:n])}: projection: {exc}") from None
        return np.concatenate([q, qd])

    return project


def _torques_at(model: Model, t_out: np.ndarray, Y: np.ndarray) -> np.ndarray:
    n = model.n_total
    return np.array([applied_torque(model.torques, ti, y[:n], y[n:]) for ti, y in zip(t_out, Y)])


class ReferenceEngine(Engine):
    """The plain-NumPy stages in the reference time loop (module docstring).

    Attributes:
        name: 'reference'.
    """

    name = "reference"

    def project(self, model: Model, q: np.ndarray, qd: np.ndarray) -> Projection:
        """(q, qd) projected onto the loop-closure manifold (`coopsim.dynamics.manifold.consistent_state`).

        Args, Returns, Raises: as `Engine.project`.
        """
        return consistent_state(model, q, qd)

    def run(self, model: Model, init: Projection, t_out: np.ndarray, progress, fixed_step: float | None) -> Run:
        """The reference time loop (`coopsim.dynamics.integrate`) over `forward`, landing on every output time.

        Projection stabilization projects after each step; a rank-deficient Λ𝐈⁻¹Λᵀ warns once (a
        ConstraintRankWarning and a 'rank_deficient' event) or, with integrator.on_rank_deficiency: error,
        stops the run.

        fixed_step is not used (the step is the integrator settings'); the Run's tau is None.

        Args, Returns, Raises: as `Engine.run`.
        """
        n, events = model.n_total, []

        def rhs(t, y):
            q, qd = y[:n], y[n:]
            _report(progress, model, t)
            tau = applied_torque(model.torques, t, q, qd)
            try:
                with np.errstate(invalid="ignore", over="ignore"):
                    _, acc = forward(model, q, qd, tau)
            except ConstraintError as exc:
                raise SimulationError(f"simulation failed at {describe_state(t, q)}: {exc}") from None
            if not np.all(np.isfinite(acc.qdd)):
                raise SimulationError(f"simulation failed at {describe_state(t, q)}: non-finite joint accelerations "
                                      f"(torques up to {np.max(np.abs(tau)):.3g} N·m, rates up to "
                                      f"{np.max(np.abs(qd)):.3g} rad/s)")
            if acc.rank < model.rows.shape[0] * (model.r - 1):
                if model.integrator.on_rank_deficiency == "error":
                    raise SimulationError(f"simulation failed at {describe_state(t, q)}: "
                                          f"{rank_reason(acc.rank, acc.cond)}")
                if not events:
                    events.append(rank_event(t, q, acc.rank, acc.cond, stacklevel=2))
            return np.concatenate([qd, acc.qdd])

        def onto_manifold(q, qd):
            q, _ = project_positions(model, q, model.integrator.projection_tol)
            return q, project_velocities(model, q, qd)

        Y, stats = _reference_loop(model, init, t_out, rhs, _projection_step(n, onto_manifold))
        return Run(Y, stats, tuple(events))

    def sample(self, model: Model, t_out: np.ndarray, run: Run) -> dict:
        """Every reported quantity (SAMPLED) at the run's states, one reference evaluation per sample.

        The reference loop lands on every output (run.raw is None); run.tau None: the model's torques at
        (t, q, qd).

        Args, Returns, Raises: as `Engine.sample`.
        """
        Y, tau = run.Y, run.tau
        n, N, r = model.n_total, len(t_out), model.r
        out = {k: np.zeros((N,) + shape) for k, shape in [
            ("qdd", (n,)), ("tau", (n,)), ("object_pos", (3,)), ("object_quat", (4,)), ("object_twist", (6,)),
            ("object_acc", (6,)), ("grasp_wrench", (r, 6)), ("internal_wrench", (r, 6)), ("residual_pos", ()),
            ("residual_vel", ()), ("cond", ())]}
        for i, (ti, y) in enumerate(zip(t_out, Y)):
            q, qd = y[:n], y[n:]
            tau_i = applied_torque(model.torques, ti, q, qd) if tau is None else tau[i]
            terms, acc = forward(model, q, qd, tau_i)
            W = [grasp_matrix(s) for s in terms.s]
            out["qdd"][i], out["tau"][i] = acc.qdd, tau_i
            out["object_pos"][i], out["object_quat"][i] = terms.obj.p_C, rot_to_quat(terms.obj.R_o)
            out["object_twist"][i], out["object_acc"][i] = terms.v_o, acc.vd_o
            out["grasp_wrench"][i], out["internal_wrench"][i] = acc.F_e, internal_wrench(W, acc.F_e)
            out["residual_pos"][i] = np.max(np.abs(position_residual(model, q)))
            out["residual_vel"][i] = np.max(np.abs(terms.Lam_qd))
            out["cond"][i] = acc.cond
        return out


def _compiled_samples(model: Model, t_out: np.ndarray, Y: np.ndarray, tau: np.ndarray | None,
                      raw: np.ndarray | None = None) -> dict:
    """`coopsim.compiled.api.sample_states` as the SAMPLED dict; the rows raw flags projected in Y first,
    and a failed projection raised as the time loop words it (SimulationError)."""
    from coopsim.compiled import api

    smp = api.sample_states(model, t_out, Y, tau, raw=raw)
    if raw is not None:
        st = smp.status
        bad = np.flatnonzero(raw & ((st == api.manifold.NON_FINITE_STATE) | (st == api.manifold.PROJECTION_FAILED)))
        if len(bad):
            i, n = int(bad[0]), model.n_total
            raise SimulationError(f"simulation failed at {describe_state(t_out[i], Y[i, :n])}: "
                                  f"{api.REASONS[int(smp.status[i])]}")
    return {k: getattr(smp, k) for k in SAMPLED}


def _compiled_projection(model: Model, q: np.ndarray, qd: np.ndarray) -> Projection:
    from coopsim.compiled import api

    return api.consistent_state(model, q, qd)


class CompiledEngine(Engine):
    """The whole time loop compiled (module docstring).

    With an in-the-loop controller the loop runs on the controller's model (its torque tables, the
    command added at every stage), lands on every output time, and the samples' torques are the
    controller's.

    Attributes:
        name: 'compiled'.
    """

    name = "compiled"

    def project(self, model: Model, q: np.ndarray, qd: np.ndarray) -> Projection:
        """(q, qd) projected onto the loop-closure manifold, compiled (`coopsim.compiled.api.consistent_state`).

        Args, Returns, Raises: as `Engine.project`.
        """
        return _compiled_projection(model, q, qd)

    @staticmethod
    def _kernel_model(model: Model) -> Model:
        ctrl = loop_controller(model)
        return model if ctrl is None else ctrl.model

    def run(self, model: Model, init: Projection, t_out: np.ndarray, progress, fixed_step: float | None) -> Run:
        """The compiled time loop (`coopsim.compiled.api.integrate_chain`, dense output).

        rk4 runs at integrator.step; with a controller in the loop the controller is evaluated at every
        stage, the steps land on every output time, and the run returns the controller's torques at the
        samples and its evaluation counters.

        fixed_step: the method (DOP853 or DOPRI5 too) at fixed steps of at most this size; None: rk4 at
        integrator.step, the others adaptive. With a controller in the loop the Run carries its torques
        (N, n) N·m at t_out and its evaluation counters. Without one, the outputs reached by dense output
        are left to `sample` to project (Run.raw; with projection stabilization), which evaluates each on
        its projection's kinematics.

        Args, Returns, Raises: as `Engine.run`.
        """
        from coopsim.compiled import api

        s, n = model.integrator, model.n_total
        ctrl = loop_controller(model)
        kernel = self._kernel_model(model)
        fixed = fixed_step if fixed_step is not None else (s.step if s.method == "rk4" else None)
        loop = None if ctrl is None else ctrl.loop_record()
        run = api.integrate_chain(kernel, np.concatenate([init.q, init.qd]), t_out, s.method, rtol=s.rtol,
                                  atol=s.atol, h_max=np.inf if s.max_step is None else s.max_step, fixed_step=fixed,
                                  progress=progress, controller=loop, land=loop is not None, defer=loop is None)
        events = ()
        if run.rank_warning is not None:
            t, y, rank, cond = run.rank_warning
            events = (rank_event(t, y[:n], rank, cond, stacklevel=3),)   # the warning names simulate's caller
        if run.status:
            raise SimulationError(f"simulation failed at {describe_state(run.fail_t, run.fail_y[:n])}: "
                                  f"{self._reason(kernel, run)}")
        deferred = 0 if run.raw is None else int(np.count_nonzero(run.raw))   # projected by `sample`
        stats = IntegratorStats(n_rhs=run.counts[0], n_accepted=run.counts[1], n_rejected=run.counts[2],
                                n_projections=run.counts[3] + deferred)
        if ctrl is None:
            return Run(run.Y, stats, events, raw=run.raw)
        counts = ctrl.loop_counts()        # the loop's own evaluations, before the samples' torques add theirs
        return Run(run.Y, stats, events, ctrl.loop_torques(t_out, run.Y[:, :n], run.Y[:, n:]), counts)

    def sample(self, model: Model, t_out: np.ndarray, run: Run) -> dict:
        """Every reported quantity (SAMPLED) at the run's states, compiled, on the model the loop ran on.

        The rows the loop left unprojected (run.raw) are projected here, each evaluated on its
        projection's kinematics; run.tau None: the torque tables of the model the loop ran on, at t_out.

        Args, Returns, Raises: as `Engine.sample`.
        """
        return _compiled_samples(self._kernel_model(model), t_out, run.Y, run.tau, run.raw)

    @staticmethod
    def _reason(model: Model, run) -> str:
        """The one-line reason of a compiled run's failure (as the reference engine words it)."""
        from coopsim.compiled import api

        reason = api.REASONS.get(run.status, f"failure code {run.status}")
        n = model.n_total
        if run.status == api.closed_chain.RANK_DEFICIENT:
            W = api.compiled(model).W
            reason += f" (rank {int(W.rank[0])}, cond {float(W.cond[0]):.3g})"
        if run.status == api.closed_chain.NON_FINITE:
            tau = torque_at(model.torques, run.fail_t)
            reason += (f" (torques up to {np.max(np.abs(tau)):.3g} N·m, rates up to "
                       f"{np.max(np.abs(run.fail_y[n:])):.3g} rad/s)")
        return reason


class StagesEngine(Engine):
    """The reference time loop over the compiled stage kernels (module docstring).

    The compiled closed-chain evaluation and projection at every stage, the torques evaluated in
    Python there.

    Attributes:
        name: 'stages'.
    """

    name = "stages"

    def project(self, model: Model, q: np.ndarray, qd: np.ndarray) -> Projection:
        """(q, qd) projected onto the loop-closure manifold, compiled (`coopsim.compiled.api.consistent_state`).

        Args, Returns, Raises: as `Engine.project`.
        """
        return _compiled_projection(model, q, qd)

    def run(self, model: Model, init: Projection, t_out: np.ndarray, progress, fixed_step: float | None) -> Run:
        """The reference time loop over the compiled evaluation, the torques evaluated in Python.

        `coopsim.dynamics.integrate` over `coopsim.compiled.api.forward`. Projection stabilization
        projects after each step (compiled); a rank-deficient Λ𝐈⁻¹Λᵀ warns once unless
        integrator.on_rank_deficiency is error, and any other failure code stops the run.

        fixed_step is not used (the step is the integrator settings'); the Run's tau is None.

        Args, Returns, Raises: as `Engine.run`.
        """
        from coopsim.compiled import api

        n, events = model.n_total, []

        def rhs(t, y):
            q, qd = y[:n], y[n:]
            _report(progress, model, t)
            ev = api.forward(model, q, qd, applied_torque(model.torques, t, q, qd))
            if ev.status == api.closed_chain.RANK_DEFICIENT and model.integrator.on_rank_deficiency != "error":
                if not events:
                    events.append(rank_event(t, q, ev.rank, float(api.compiled(model).W.cond[0]), stacklevel=2))
            elif ev.status:
                raise SimulationError(f"simulation failed at {describe_state(t, q)}: {api.REASONS[ev.status]}")
            return np.concatenate([qd, ev.qdd])

        def onto_manifold(q, qd):
            p = api.consistent_state(model, q, qd)
            return p.q, p.qd

        Y, stats = _reference_loop(model, init, t_out, rhs, _projection_step(n, onto_manifold))
        return Run(Y, stats, tuple(events))

    def sample(self, model: Model, t_out: np.ndarray, run: Run) -> dict:
        """Every reported quantity (SAMPLED) at the run's states, compiled.

        The reference loop lands on every output (run.raw is None); run.tau None: the model's torques at
        (t, q, qd), evaluated in Python.

        Args, Returns, Raises: as `Engine.sample`.
        """
        Y, tau = run.Y, run.tau
        return _compiled_samples(model, t_out, Y, _torques_at(model, t_out, Y) if tau is None else tau)


ENGINES: dict[str, Engine] = {e.name: e for e in (CompiledEngine(), ReferenceEngine(), StagesEngine())}
