"""Forward simulation of the closed chain: the pipeline in the order it runs.

    state (θ, θ̇), torque τ(t)
      → chain_terms        kinematics (stage 1), Gibbs–Appell arm dynamics (2), object/grasp (3),
                           loop-closure Jacobians (4)
      → stabilization      Baumgarte right-hand side, if selected (5)
      → forward_dynamics   θ̈ and grasp wrenches (eqs. 25–27)
      → integrate          adaptive DOP853/DOPRI5 (dense output) or fixed-step RK4, projection after
                           each step (5)
      → sample             every reported quantity at the output times

Three engines run it behind one interface (`coopsim.forward.engines`: project, run, sample):
'compiled' (the default: the whole time loop in compiled code, an in-the-loop controller evaluated
inside it at every stage, the adaptive steps then ending on every output time as the reference loop's
do), 'reference' (the plain-NumPy stages in `coopsim.dynamics.integrate`, landing on every output time:
torques given as a Python function, and the readable reference the compiled engine is tested against),
and 'stages' (the reference time loop over the compiled stage kernels: a torque source that is Python
at every stage, such as the 'bounded' distribution or a notebook's callable). `simulate` chooses the
engine and enters it once; `SimResult.engine` says which ran.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from coopsim.core.errors import ConstraintError, CoopsimError, SimulationError
from coopsim.core.model import IntegratorSettings, Model, TorqueFeedback, TorqueFunction, loop_controller
from coopsim.core.results import Projection, SampledMotion, output_times
from coopsim.dynamics.integrate import IntegratorStats
from coopsim.forward import diagnostics
from coopsim.forward.diagnostics import RunWarning, describe_state
from coopsim.forward.engines import ENGINES, Engine, Run, forward  # noqa: F401 (forward: the reference evaluation)


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
        arm_terms: the per-sample end-effector Jacobians, 𝐈_m θ̇_m and object rotations
            (`coopsim.forward.diagnostics.ArmTerms`), computed on first use.
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
        """Per-sample Jacobians, 𝐈_m θ̇_m and object rotations (`diagnostics.arm_terms`), on first use."""
        return diagnostics.arm_terms(self.model, self.q, self.qd)

    @cached_property
    def manipulability(self) -> np.ndarray:
        """(N, r) each arm's manipulability in the scene's rows (`diagnostics.manipulability`), on first use."""
        return diagnostics.manipulability(self.model, self.arm_terms.J)

    @cached_property
    def kinetic_energy(self) -> np.ndarray:
        """(N,) J, the kinetic energy of arms and object (`diagnostics.kinetic_energy`), on first use."""
        return diagnostics.kinetic_energy(self.model, self.qd, self.arm_terms, self.object_twist)

    @cached_property
    def warnings(self) -> tuple[RunWarning, ...]:
        """Every RunWarning of the run, events first (`diagnostics.collect`), on first use."""
        return diagnostics.collect(self, self.arm_terms)


def initial_state(model: Model, engine: str = "compiled") -> Projection:
    """The consistent initial state: the scenario's (q0, qd0) projected onto the loop-closure manifold.

    Args:
        model: the Model.
        engine: the engine that projects ('compiled' or 'stages': the compiled projection;
            'reference': the plain-NumPy one).

    Returns:
        The Projection (q, qd, the corrections applied, the residual before and after).

    Raises:
        ConstraintError: naming the fields when the grasps cannot be reached from the initial angles,
            or the correction exceeds integrator.max_initial_correction.
    """
    try:
        proj = ENGINES[engine].project(model, model.q0, model.qd0)
    except ConstraintError as exc:
        raise ConstraintError(f"object.grasps: the arms cannot close the loop from arms[].initial: {exc}") from None
    worst = float(np.max(np.abs(proj.dq)))
    limit = model.integrator.max_initial_correction
    if worst > limit:
        raise ConstraintError(
            f"object.grasps: closing the loop from arms[].initial needs a joint correction of {worst:.4g} rad "
            f"(> integrator.max_initial_correction = {limit:g} rad); check the grasps and initial angles")
    return proj


def choose_engine(model: Model, engine: str) -> str:
    """The engine that runs `model` when `engine` is asked for.

    An in-the-loop controller runs on 'compiled' unless it needs Python (then 'stages'); other Python
    torque functions run on 'reference' ('stages' when asked).

    Args:
        model: the Model (its torque source).
        engine: the engine asked for: 'compiled', 'reference' or 'stages'.

    Returns:
        str: the engine that runs: 'compiled', 'reference' or 'stages'.

    Raises:
        ValueError: an unknown engine.
    """
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}")
    if isinstance(model.torques, TorqueFeedback) and engine == "compiled":
        ctrl = loop_controller(model)
        return "compiled" if ctrl is not None and ctrl.compiled_reason is None else "stages"
    if isinstance(model.torques, TorqueFunction) and engine != "stages":
        return "reference"
    return engine


def simulate(model: Model, duration: float | None = None, settings: IntegratorSettings | None = None,
             progress=None, engine: str = "compiled", fixed_step: float | None = None) -> SimResult:
    """Integrate the closed chain (eqs. 14–27) from its consistent initial state, driven by the model's
    torque source, and sample every reported quantity on the output grid.

    Args:
        model: the Model; its `torques` are the source (tables, a TorqueFunction, or a TorqueFeedback
            such as a closed loop, `coopsim.control.controller.closed_loop`).
        duration: s, in place of the model's.
        settings: integrator settings in place of the model's.
        progress: called with the fraction done (0..1) as the run advances; None: no reports.
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
        ValueError: an unknown engine, or fixed_step with an engine other than 'compiled'.
        SimulationError: the run failed; the message gives the time, the configuration and the reason.
    """
    if settings is not None:
        model = replace(model, integrator=settings)
    if duration is not None:
        model = replace(model, duration=duration)
    start = time.perf_counter()
    if model.control is not None and not isinstance(model.torques, TorqueFeedback):
        raise CoopsimError(f"{model.name}: the scenario's control: section is not in the loop: close it first "
                           f"(coopsim.closed_loop(model))")
    eng = ENGINES[choose_engine(model, engine)]
    if fixed_step is not None and eng.name != "compiled":
        raise ValueError("fixed_step needs the compiled engine and tabulated torques")
    init = initial_state(model, eng.name)
    t_out = output_times(model.duration, model.integrator.output_dt)
    run = eng.run(model, init, t_out, progress, fixed_step)
    res = _result(model, eng, t_out, run, eng.sample(model, t_out, run), init, start)
    _check_conditioning(res)
    return res


def _result(model: Model, eng: Engine, t_out: np.ndarray, run: Run, smp: dict, init: Projection,
            start: float) -> SimResult:
    """The SimResult of an engine's run and samples; the in-the-loop controller's warnings added."""
    n, ctrl = model.n_total, loop_controller(model)
    events = run.events + (() if ctrl is None else tuple(ctrl.run_warnings()))
    return SimResult(model=model, t=t_out, q=run.Y[:, :n], qd=run.Y[:, n:], initial=init, stats=run.stats,
                     wall_time=time.perf_counter() - start, events=events, engine=eng.name,
                     control_counts=run.control_counts, **smp)


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
