"""Frozen model data: every array the kernels need, built once from a scenario.

Units are SI throughout (m, kg, s, N, N·m, rad). Frames: "world" is Σ; each arm has a base frame and
one frame per link, attached at the link's joint (MuJoCo's body convention: frame i sits at
`joint_pos[i]` in the parent frame, rotated by `joint_rot[i]`, then moved by the joint coordinate θ_i
along `joint_axis[i]`, given in frame i: turned by θ_i rad about it (revolute joint) or slid θ_i m
along it (prismatic joint; `coopsim.core.joints`). The object frame Σ_o sits at the object's centre of mass
C. Joint vectors of all arms are stacked arm after arm (`Model.dof_slices`); a joint's coordinate,
rate and effort are rad, rad/s, N·m (revolute) or m, m/s, N (prismatic).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Callable, Protocol, runtime_checkable

import numpy as np


REVOLUTE, PRISMATIC = 0, 1                        # joint type codes (ArmModel.joint_type)
JOINT_TYPES = {"revolute": REVOLUTE, "prismatic": PRISMATIC}


@dataclass(frozen=True, eq=False)
class ArmModel:
    """One serial arm of n joints, each revolute or prismatic.

    link_box, box_pos and box_rot are for drawing only: the dynamics never reads them.

    Attributes:
        name: the arm's name in the scenario.
        base_pos: (3,) m, the base frame's origin, world axes.
        base_rot: (3, 3) world ← base.
        joint_pos: (n, 3) m, origin of frame i in frame i−1 (the base frame for i = 0).
        joint_rot: (n, 3, 3) frame i−1 ← frame i at θ_i = 0.
        joint_axis: (n, 3) unit joint axes, each in its own frame i.
        link_mass: (n,) kg.
        link_com: (n, 3) m, each link's centre of mass in frame i.
        link_inertia: (n, 3, 3) kg·m², about the link's centre of mass, frame-i axes.
        link_box: (n, 3) m, box size for drawing (zeros: none) along the box's own axes.
        ee_pos: (3,) m, the end-effector frame's origin in frame n−1.
        ee_rot: (3, 3) frame n−1 ← end-effector frame.
        joint_type: (n,) int, REVOLUTE or PRISMATIC per joint (given as None: every joint revolute).
        box_pos: (n, 3) m, the drawing box's centre in frame i (given as None: link_com).
        box_rot: (n, 3, 3) frame i ← box axes (given as None: the link's own axes).
    """

    name: str
    base_pos: np.ndarray
    base_rot: np.ndarray
    joint_pos: np.ndarray
    joint_rot: np.ndarray
    joint_axis: np.ndarray
    link_mass: np.ndarray
    link_com: np.ndarray
    link_inertia: np.ndarray
    link_box: np.ndarray
    ee_pos: np.ndarray
    ee_rot: np.ndarray
    joint_type: np.ndarray | None = None
    box_pos: np.ndarray | None = None
    box_rot: np.ndarray | None = None

    def __post_init__(self):
        types = np.full(len(self.link_mass), REVOLUTE) if self.joint_type is None else self.joint_type
        object.__setattr__(self, "joint_type", np.asarray(types, dtype=np.int64))
        if self.box_pos is None:
            object.__setattr__(self, "box_pos", np.array(self.link_com, dtype=float))
        if self.box_rot is None:
            object.__setattr__(self, "box_rot", np.tile(np.eye(3), (len(self.link_mass), 1, 1)))

    @property
    def n(self) -> int:
        """The number of joints n."""
        return len(self.link_mass)

    @property
    def prismatic(self) -> np.ndarray:
        """(n,) bool: which joints are prismatic."""
        return self.joint_type == PRISMATIC


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """The grasped rigid object.

    Attributes:
        mass: kg.
        inertia: (3, 3) kg·m², about the centre of mass C, object axes.
        box: (3,) m, box size along the object axes (zeros: none), for drawing and for the section loads
            of a box object (`coopsim.inverse.stress`).
        grasp_pos: (r, 3) m, the origin of arm m's end-effector frame in the object frame (row m belongs
            to arm m).
        grasp_rot: (r, 3, 3) object frame ← arm m's end-effector frame (row m belongs to arm m).
        carrier: index (0-based) of the arm whose last link the object is rigidly attached to in the
            reduced model (paper eqs. 17–19, arm "1").
    """

    mass: float
    inertia: np.ndarray
    box: np.ndarray
    grasp_pos: np.ndarray
    grasp_rot: np.ndarray
    carrier: int


@dataclass(frozen=True, eq=False)
class TorqueTable:
    """Piecewise-linear joint torques of one arm, held constant outside [times[0], times[-1]].

    One row is a constant torque.

    Attributes:
        times: (k,) s, strictly increasing.
        values: (k, n) N·m (N for a prismatic joint), the torques at those times.
    """

    times: np.ndarray
    values: np.ndarray


@dataclass(frozen=True, eq=False)
class TorqueFunction:
    """Joint torques given as a function of time, fn(t) -> stacked τ.

    Used in place of the per-arm tables when the torque is itself computed at the integrator's stage
    times (e.g. the inverse-dynamics torques of a trajectory, replayed through the forward dynamics).

    Attributes:
        fn: t (s) -> τ (n_total,) N·m (N on a prismatic joint), joints stacked arm after arm.
    """

    fn: Callable[[float], np.ndarray]


@dataclass(frozen=True, eq=False)
class TorqueFeedback(TorqueFunction):
    """Joint torques of a controller in the loop, fn(t, q, qd) -> stacked τ.

    τ comes from the time and the state the integrator is evaluating (every stage of the native reference
    engine, every RK4 stage of the MuJoCo twin). A notebook passes its own τ = u(t, q, q̇) as
    `replace(model, torques=TorqueFeedback(u))`; a scenario's `control:` section builds one
    (`coopsim.control.controller.closed_loop`).

    Attributes:
        fn: (t s, q (n_total,) rad or m, qd (n_total,) rad/s or m/s) -> τ (n_total,) N·m (N on a
            prismatic joint), joints stacked arm after arm.
    """

    fn: Callable[[float, np.ndarray, np.ndarray], np.ndarray]


@runtime_checkable
class LoopController(Protocol):
    """A controller the forward pipeline runs in the loop, as the `fn` of a TorqueFeedback: the
    reference time loop calls it, τ = fn(t, q, q̇); the compiled time loop evaluates it from its record
    (`coopsim.control.controller.Controller` is one). The forward pipeline knows controllers only
    through this protocol.

    Attributes:
        model: the model whose torque tables the controller's command is added to (the compiled time
            loop runs on it).
        compiled_reason: why the controller cannot run in the compiled time loop; None when it can.
    """

    model: "Model"
    compiled_reason: str | None

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The controller's joint torques at one time and state.

        Args:
            t: s, the time.
            q: (n,) rad (m on a prismatic joint), stacked joint coordinates.
            qd: (n,) rad/s (m/s), stacked joint rates.

        Returns:
            np.ndarray: (n,) N·m (N on a prismatic joint), the stacked torques τ.
        """

    def loop_record(self) -> tuple:
        """The record the compiled time loop evaluates, its evaluation counters reset for a new run.

        Returns:
            tuple: the controller record of `coopsim.compiled.api.integrate_chain`.
        """

    def loop_counts(self) -> tuple:
        """The compiled evaluations' counters since `loop_record`.

        Returns:
            tuple: the counters.
        """

    def loop_torques(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The controller's joint torques at the samples of a run.

        Args:
            t: (N,) s, the sample times.
            q: (N, n) rad (m on a prismatic joint), stacked joint coordinates.
            qd: (N, n) rad/s (m/s), stacked joint rates.

        Returns:
            np.ndarray: (N, n) N·m (N on a prismatic joint), the torques τ.
        """

    def run_warnings(self) -> list:
        """What the controller reports about the run so far.

        Returns:
            list: `coopsim.forward.diagnostics.RunWarning`s.
        """


def loop_controller(model: "Model") -> LoopController | None:
    """The in-the-loop controller a model's torques feed back through; None for any other torque source.

    Args:
        model: a Model, closed loop or not.

    Returns:
        `model.torques.fn` when the torques are a TorqueFeedback whose function is a LoopController.
    """
    fn = getattr(model.torques, "fn", None)
    return fn if is_loop_controller(fn) else None


_LOOP_DATA = tuple(LoopController.__annotations__)
_LOOP_METHODS = tuple(name for name, v in vars(LoopController).items()
                      if callable(v) and (not name.startswith("_") or name == "__call__"))


@lru_cache(maxsize=None)
def _has_loop_methods(cls: type) -> bool:
    return all(callable(getattr(cls, name, None)) for name in _LOOP_METHODS)


def is_loop_controller(fn) -> bool:
    """`isinstance(fn, LoopController)`, without the protocol check's cost on every call: the methods are
    looked up once per class, the data members on the object.

    Args:
        fn: any object (a torque function, a controller, None).

    Returns:
        bool: whether `fn` has every method and attribute of LoopController.
    """
    return fn is not None and _has_loop_methods(type(fn)) and all(hasattr(fn, name) for name in _LOOP_DATA)


# the control vocabulary (ControlSettings' choices), read by the scenario and the controller
LAWS = ("joint_pd", "computed_torque")
COMPILED_DISTRIBUTIONS = ("paper", "nonsqueezing", "min_energy")    # the linear ones: `coopsim.compiled.control`
FALLBACKS = COMPILED_DISTRIBUTIONS + ("error",)                     # where 'bounded' has no solution
COMPENSATIONS = ("none", "gravity", "bias")
REFERENCES = ("setpoint", "object_motion")


@dataclass(frozen=True, eq=False)
class ControlSettings:
    """A controller in the loop (scenario `control:`), added to the scenario's torque tables.

    The tables then act as a disturbance. Two laws:

    joint_pd: τ = τ_comp + Kp (θ_r − θ) + Kd (θ̇_r − θ̇), τ_comp the compensation, the object's share
    distributed by the resolution `distribution`; the reference θ_r is a setpoint or the joint
    trajectory of inverse.object_motion.

    computed_torque: track inverse.object_motion with the object acceleration a = a_r + Kd (v_r − v) + Kp e,
    the closed-chain inverse dynamics of that acceleration distributed by `distribution`, plus a squeeze
    force, plus joint-space feedback on each arm's grasp error e_m (`coopsim.control.laws.grasp_errors`),
    τ_m += J_mᵀSᵀS (Kp e_m + Kd ė_m).

    Joint vectors (n,) are stacked arm after arm (n = n_total).

    Attributes:
        law: 'joint_pd' | 'computed_torque'.
        kp: (n,) N·m/rad, joint_pd's Kp (zeros for computed_torque).
        kd: (n,) N·m·s/rad, joint_pd's Kd (zeros for computed_torque).
        compensation: joint_pd's τ_comp: 'none' | 'gravity' (closed-chain inverse dynamics at (θ, 0, 0)) |
            'bias' (at (θ, θ̇, 0)).
        distribution: the resolution of the redundant inverse dynamics that distributes the object's
            share among the arms (`coopsim.inverse.resolutions`, e.g. 'paper', 'nonsqueezing',
            'min_energy', 'bounded').
        reference: joint_pd's θ_r: 'setpoint' or 'object_motion' (the joint trajectory of
            inverse.object_motion); computed_torque always 'object_motion'.
        setpoint: (n,) rad, joint_pd's setpoint (None: the consistent initial state).
        object_kp: (2,) 1/s², computed_torque's Kp on the object: [linear, angular].
        object_kd: (2,) 1/s, computed_torque's Kd on the object: [linear, angular].
        squeeze: N, the squeeze force along each grasp line towards the centre of mass, in the null space
            of the grasp matrix.
        grasp_kp: (2,) [N/m, N·m/rad], the Kp of the grasp-error feedback (zero: none; e_m is zero on the
            native model up to its loop-closure tolerance).
        grasp_kd: (2,) [N·s/m, N·m·s/rad], the Kd of the grasp-error feedback (zero: none).
        mass_scale: the controller's object mass and inertia relative to the true ones (a model error;
            1 = none).
        saturate: clip τ to the motor lines of eq. 36 (`torque_limits`).
        fallback: distribution 'bounded' only (its bounds inverse.internal_force_bound and
            internal_moment_bound, none: unbounded): where its QP has no solution, the resolution used
            instead ('nonsqueezing', 'paper', 'min_energy': a `distribution_fallback` RunWarning counts
            them) or 'error' (the run stops there with a one-line error).
    """

    law: str
    kp: np.ndarray
    kd: np.ndarray
    compensation: str = "gravity"
    distribution: str = "paper"
    reference: str = "setpoint"
    setpoint: np.ndarray | None = None
    object_kp: np.ndarray = field(default_factory=lambda: np.zeros(2))
    object_kd: np.ndarray = field(default_factory=lambda: np.zeros(2))
    squeeze: float = 0.0
    grasp_kp: np.ndarray = field(default_factory=lambda: np.zeros(2))
    grasp_kd: np.ndarray = field(default_factory=lambda: np.zeros(2))
    mass_scale: float = 1.0
    saturate: bool = False
    fallback: str = "nonsqueezing"


@dataclass(frozen=True, eq=False)
class Motors:
    """The joints' motors, per joint, stacked arm after arm (n = n_total).

    Attributes:
        stall_torque: (n,) N·m (N for a prismatic joint: a force), τ_s of eq. 36 (inf: no limit).
        no_load_speed: (n,) rad/s (m/s for a prismatic joint), ω_s of eq. 36 (inf: no limit).
        energy_weight: (n,) the diagonal of Q (eqs. 33–35).
        passive: (n,) bool, which joints are passive (unactuated).
    """

    stall_torque: np.ndarray
    no_load_speed: np.ndarray
    energy_weight: np.ndarray
    passive: np.ndarray

    @property
    def line_slope(self) -> np.ndarray:
        """τ_s/ω_s (n,) N·m·s/rad (N·s/m on a prismatic joint), the motor lines' slope of eq. 36; 0
        where the line is flat (infinite no-load speed) or there is no limit (infinite stall torque)."""
        ts, ws = self.stall_torque, self.no_load_speed
        return np.where(np.isfinite(ts) & np.isfinite(ws), ts / np.where(np.isfinite(ws), ws, 1.0), 0.0)


def torque_limits(motors: Motors, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The motor lines of eq. 36 at joint rates: τ_min = −τ_s − (τ_s/ω_s) θ̇, τ_max = τ_s − (τ_s/ω_s) θ̇.

    Args:
        motors: the Motors (stall torque τ_s, no-load speed ω_s per joint).
        qd: joint rates (..., n) rad/s (m/s on a prismatic joint).

    Returns:
        (τ_min, τ_max), each shaped like qd, N·m (N): infinite stall torque gives no limit, infinite
        no-load speed a flat line.
    """
    drop = np.nan_to_num(motors.line_slope * qd)
    return -motors.stall_torque - drop, motors.stall_torque - drop


@dataclass(frozen=True)
class IntegratorSettings:
    """The forward run's time integration, constraint stabilization and conditioning checks.

    rtol/atol are also the accuracy a fixed rk4 step is checked against (`coopsim.forward.diagnostics`).

    Attributes:
        method: 'dop853' | 'dopri5' (adaptive, rtol/atol; outputs from their dense output) | 'rk4'
            (fixed `step`).
        rtol: relative tolerance of the adaptive methods.
        atol: absolute tolerance of the adaptive methods (units of the state: rad, rad/s; m, m/s on a
            prismatic joint).
        step: s, the fixed step of 'rk4'.
        max_step: s, largest step of the adaptive methods (None: unbounded).
        output_dt: s, sample interval of the results.
        stabilization: 'projection' | 'baumgarte' | 'none'.
        baumgarte_alpha: 1/s, α in Λθ̈ = −Λ̇θ̇ − 2αΛθ̇ − β²Φ.
        baumgarte_beta: 1/s, β in the same.
        projection_tol: m and rad, the loop-closure tolerance.
        max_initial_correction: rad, largest joint correction accepted when the initial state is made
            consistent.
        constraint_rows: 'auto' (planar rows for planar scenes) or 'spatial'.
        rank_tol: relative eigenvalue below which the constraint matrix counts as rank-deficient.
        on_rank_deficiency: 'warn' (minimum-norm grasp wrenches, warning) or 'error'.
        condition_limit: condition number of Λ𝐈⁻¹Λᵀ above which a sample counts as ill-conditioned (the
            chain is near a singular configuration: grasp wrenches lose about log10(cond) digits).
        on_ill_conditioning: 'warn' (a warning naming the worst sample) or 'error' (the run stops).
        initial_correction_warning: rad, joint correction of the initial state above which a warning
            says so (max_initial_correction stops the run).
        singularity_limit: an arm counts as near a singularity where σ_min/σ_max of its end-effector
            Jacobian in the scene's rows (linear rows divided by the arm's reach) falls below this.
    """

    method: str = "dop853"
    rtol: float = 1e-11
    atol: float = 1e-12
    step: float = 1e-2
    max_step: float | None = None
    output_dt: float = 1e-2
    stabilization: str = "projection"
    baumgarte_alpha: float = 10.0
    baumgarte_beta: float = 10.0
    projection_tol: float = 1e-12
    max_initial_correction: float = 0.05
    constraint_rows: str = "auto"
    rank_tol: float = 1e-10
    on_rank_deficiency: str = "warn"
    condition_limit: float = 1e8
    on_ill_conditioning: str = "warn"
    initial_correction_warning: float = 1e-3
    singularity_limit: float = 1e-3


@dataclass(frozen=True)
class MujocoSettings:
    """The MuJoCo twin's numerics.

    MuJoCo holds a weld row with J q̈ = −J̇q̇ − b J q̇ − k d r − R f (b = 2/timeconst, k = 1/timeconst² at
    critical damping, d the impedance, R = (1 − d)/d · an estimate of J M⁻¹ Jᵀ's diagonal), so a weld
    carrying the force λ yields by R λ / (k d) ∝ timeconst² (`coopsim.twin.weld`). The default
    timeconst is therefore one timestep (None), with MuJoCo's `refsafe` clamp to 2·timestep disabled:
    RK4 stays stable down to about timestep/2.8. The default timestep (None) is chosen for each run from
    the yield predicted along the native run (`coopsim.twin.weld.twin_step`).

    Attributes:
        timestep: s; None: automatic, the largest step whose predicted twin errors stay within a quarter
            of every `validation` threshold.
        integrator: 'RK4' | 'Euler' | 'implicit' | 'implicitfast'.
        weld_solref: [timeconst s, dampratio] of the welds (None: [timestep, 1], `solref`).
        weld_solimp: [d0, d_width, width m, midpoint, power] of the welds.
        tolerance: the Newton solver's tolerance.
        iterations: the Newton solver's iteration cap.
        object_mass_scale: a deliberate error in the twin's object mass and inertia (1 = none), to prove
            the harness detects a wrong twin.
    """

    timestep: float | None = None
    integrator: str = "RK4"
    weld_solref: tuple[float, float] | None = None
    weld_solimp: tuple[float, ...] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    tolerance: float = 1e-12
    iterations: int = 200
    object_mass_scale: float = 1.0

    def solref(self) -> tuple[float, float]:
        """The welds' solref: weld_solref, or one timestep at critical damping when it is None.

        Returns:
            tuple[float, float]: (timeconst s, dampratio).

        Raises:
            ValueError: both are left to follow an automatic step that is not chosen yet.
        """
        if self.weld_solref is not None:
            return self.weld_solref
        if self.timestep is None:
            raise ValueError("mujoco.timestep is automatic: the welds' time constant follows the step, "
                             "chosen from the native run (coopsim.twin.weld.twin_step)")
        return (self.timestep, 1.0)


@dataclass(frozen=True)
class ValidationThresholds:
    """Agreement the native model and the MuJoCo twin must reach over the run (max over samples and joints).

    Attributes:
        max_angle_error: rad, joint angle.
        max_rate_error: rad/s, joint rate.
        max_object_position_error: m, object position.
        max_object_orientation_error: rad, object orientation.
        max_weld_violation: m or rad, the MuJoCo weld violation (max |efc_pos| of the welds).
        max_native_residual: m or rad, the native loop-closure residual.
    """

    max_angle_error: float = 1e-6
    max_rate_error: float = 1e-5
    max_object_position_error: float = 1e-6
    max_object_orientation_error: float = 1e-6
    max_weld_violation: float = 1e-6
    max_native_residual: float = 1e-10


@dataclass(frozen=True, eq=False)
class SampledTimeLaw:
    """A time law s(t) given by samples, s̈ constant between them (the output of `coopsim optimize`).

    s is the path parameter of the waypoint path: waypoint k of w at s = k/(w − 1), the straight line
    and single-axis rotation uniform in s between waypoints. Between samples k and k + 1,
    s = s_k + ṡ_k τ + ½ s̈_k τ², s̈_k = (ṡ_{k+1} − ṡ_k)/(t_{k+1} − t_k), τ = t − t_k (so
    s_{k+1} − s_k = (ṡ_k + ṡ_{k+1})(t_{k+1} − t_k)/2).

    Attributes:
        t: (K,) s, the sample times, strictly increasing (the first and last waypoints' times at the
            ends; each waypoint's time among them, with ṡ = 0 there).
        s: (K,) the path parameter at the samples, non-decreasing from 0 to 1.
        rate: (K,) 1/s, ṡ at the samples (≥ 0).
    """

    t: np.ndarray
    s: np.ndarray
    rate: np.ndarray


@dataclass(frozen=True, eq=False)
class PathSpline:
    """A free-form object path between an object motion's two waypoints (scenario
    `inverse.object_motion.path`).

    The centre of mass follows a clamped B-spline p(s), s ∈ [0, 1], through the control points
    [p_first; positions; p_last]; the orientation is R(s) = Exp(φ(s)) R_first, φ(s) the clamped B-spline
    of rotation vectors [0; rotation_vectors; log(R_last R_firstᵀ)] (world axes); degree
    min(3, K + 1) with K interior control points, uniform knots (`coopsim.inverse.spline_path`).

    Attributes:
        kind: 'bspline' (the only kind).
        positions: (K, 3) m, the interior control points of the centre of mass, world axes.
        rotation_vectors: (K, 3) rad, the interior control points of φ, world axes, relative to the
            first waypoint's orientation.
    """

    kind: str
    positions: np.ndarray
    rotation_vectors: np.ndarray


@dataclass(frozen=True, eq=False)
class ObjectMotion:
    """A prescribed object motion (scenario `inverse.object_motion`) through w waypoints.

    The object rests at every waypoint and moves between them along a straight line and a single-axis
    rotation with the time law `time_law`. Arms with more joints than constraint rows (redundant) move by
    least joint-velocity norm plus a null-space pull toward rest_posture
    (`coopsim.inverse.trajectory.redundant_rates`).

    Attributes:
        times: (w,) s, waypoint times, strictly increasing.
        positions: (w, 3) m, the centre of mass C at the waypoints, world axes.
        rotations: (w, 3, 3) world ← object, at the waypoints.
        time_law: 'quintic' (s = 10u³ − 15u⁴ + 6u⁵, zero rate and acceleration at both ends), 'cubic'
            (s = 3u² − 2u³, zero rate only), 'sampled' (`samples`, over the whole path) or 'linear' (s = u,
            not at rest; not a scenario's law: `coopsim.inverse.free_path.spline_joint_path`'s path in s).
        output_dt: s, the sample interval.
        initial_guess: (n_total,) rad, joint angles that pick the inverse-kinematics branch at the first
            waypoint (None: the scenario's initial angles).
        rest_posture: (n_total,) rad, the redundant arms' null-space target (None: the scenario's initial
            angles).
        rest_gain: 1/s, the gain of the null-space pull toward rest_posture.
        rest_pull: 'time': the pull z = rest_gain (θ_rest − θ) per second; 'path': per unit of the path
            parameter σ ∈ [0, 1], z = rest_gain · T · σ̇ (θ_rest − θ) (T the motion's duration; the same
            pull at a uniform σ̇ = 1/T), so the redundant arms' joint path θ(σ) does not depend on the time
            law (the joint path `coopsim optimize` retimes).
        samples: the SampledTimeLaw of time_law 'sampled' (None otherwise).
        path: the free-form path between the two waypoints (then there are exactly two, and the time law
            runs once over their span); None: straight segments between the waypoints.
    """

    times: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    time_law: str = "quintic"
    output_dt: float = 1e-2
    initial_guess: np.ndarray | None = None
    rest_posture: np.ndarray | None = None
    rest_gain: float = 1.0
    samples: SampledTimeLaw | None = None
    path: PathSpline | None = None
    rest_pull: str = "time"

    @property
    def path_gain(self) -> float:
        """The redundant arms' null-space pull per unit of the path parameter σ ∈ [0, 1]: rest_gain × the
        motion's duration (what rest_pull 'path' applies as rest_gain·T·σ̇, and the gain of the joint path
        in σ, `coopsim.inverse.path.joint_path`)."""
        return self.rest_gain * float(self.times[-1] - self.times[0])


@dataclass(frozen=True)
class OptimizeSettings:
    """Payload-optimal motion settings (scenario `inverse.optimize`, `coopsim optimize`).

    Attributes:
        control_points: K, the interior control points of the free path's B-spline.
        starts: how many starts the free-path optimiser runs (the straight path, then random ones).
        seed: the seed of the random starts.
        manipulability_margin: each arm's manipulability along a free path must stay at least this
            fraction of its manipulability at the first waypoint (0: only no singularity crossed).
        sample_dt: s, the sample interval of the free-path optimiser's grid (the result is checked on
            the object motion's output_dt).
        max_iterations: the most iterations of each optimiser run.
    """

    control_points: int = 4
    starts: int = 3
    seed: int = 0
    manipulability_margin: float = 0.5
    sample_dt: float = 0.1
    max_iterations: int = 100


@dataclass(frozen=True, eq=False)
class InverseSettings:
    """Inverse dynamics and load capacity (scenario `inverse`).

    Attributes:
        trajectory: 'forward' (the joint trajectory of the forward run, the paper's choice) or
            'object_motion' (object_motion, through closed-chain inverse kinematics).
        object_motion: the prescribed object motion (None: none given).
        nonsqueezing_masses: (r,) relative virtual masses of the Erhart–Hirche non-squeezing
            distribution (None: the shares whose centroid is the object's centre of mass, as equal as
            possible).
        payload_position: (3,) m, object frame: where the point payload of the payload capacity sits
            (None: no payload capacity).
        internal_force_bound: N, bound on every internal-force component (grasp-line frame) of the
            bounded minimum-energy resolution (None: half the minimum-energy distribution's peak).
        internal_moment_bound: N·m, bound on every internal-moment component, likewise.
        optimize: the payload-optimal motion settings.
    """

    trajectory: str = "forward"
    object_motion: ObjectMotion | None = None
    nonsqueezing_masses: np.ndarray | None = None
    payload_position: np.ndarray | None = None
    internal_force_bound: float | None = None
    internal_moment_bound: float | None = None
    optimize: OptimizeSettings = OptimizeSettings()


@dataclass(frozen=True, eq=False)
class Model:
    """A whole scene: r arms grasping one object in a closed chain, its torques and its settings.

    Attributes:
        name: the scenario's name.
        arms: (r,) the arms, in stacking order.
        object: the grasped object.
        gravity: (3,) m/s², world axes.
        plane: (3, 3) rows e1, e2, n (world axes) of the plane of motion for a planar scene, else None.
        rows: (k, 6) the constraint rows S kept per grasp (k = 3 planar, 6 spatial), applied to twists
            [v; ω] and wrenches [f; n] in world axes.
        q0: (n_total,) rad (m on a prismatic joint), the initial joint coordinates as given (not yet
            consistent).
        qd0: (n_total,) rad/s (m/s), the initial joint rates as given (not yet consistent).
        duration: s.
        torques: the applied joint torques: one TorqueTable per arm, or a TorqueFunction (a
            TorqueFeedback for a controller in the loop).
        motors: the joints' motors.
        integrator: the forward run's integrator settings.
        mujoco: the MuJoCo twin's numerics.
        validation: the agreement the twin must reach.
        inverse: the inverse dynamics and load capacity settings.
        joint_range: (n_total, 2) rad (m for a prismatic joint), lower and upper position limit of each
            stacked joint (±inf: none; None: no joint has one), from a robot file or a joint's `range`:
            checked at the initial state and along trajectories (object-motion IK stops, a forward run
            warns), not enforced by the dynamics.
        control: the controller in the loop (None: open loop, the torque tables alone).
    """

    name: str
    arms: tuple[ArmModel, ...]
    object: ObjectModel
    gravity: np.ndarray
    plane: np.ndarray | None
    rows: np.ndarray
    q0: np.ndarray
    qd0: np.ndarray
    duration: float
    torques: tuple[TorqueTable, ...] | TorqueFunction
    motors: Motors
    integrator: IntegratorSettings
    mujoco: MujocoSettings = MujocoSettings()
    validation: ValidationThresholds = ValidationThresholds()
    inverse: InverseSettings = InverseSettings()
    joint_range: np.ndarray | None = None
    control: ControlSettings | None = None

    @property
    def r(self) -> int:
        """The number of arms r."""
        return len(self.arms)

    @property
    def n_total(self) -> int:
        """The number of joints of all arms together."""
        return int(sum(a.n for a in self.arms))

    @cached_property
    def joint_type(self) -> np.ndarray:
        """(n_total,) int: every arm's joint types stacked (REVOLUTE, PRISMATIC)."""
        return np.concatenate([a.joint_type for a in self.arms])

    @cached_property
    def dof_slices(self) -> tuple[slice, ...]:
        """(r,) each arm's slice of the stacked joint vectors, arm after arm."""
        ends = np.cumsum([0] + [a.n for a in self.arms])
        return tuple(slice(int(a), int(b)) for a, b in zip(ends[:-1], ends[1:]))


def torque_at(tables: "tuple[TorqueTable, ...] | TorqueFunction", t: float) -> np.ndarray:
    """Stacked joint torques τ(t): linear between table rows, held outside them.

    Or the value of a TorqueFunction at t; a TorqueFeedback needs the state (`applied_torque`).

    Args:
        tables: one TorqueTable per arm, or a TorqueFunction.
        t: s, the time.

    Returns:
        np.ndarray: (n_total,) N·m (N on a prismatic joint), joints stacked arm after arm.

    Raises:
        ValueError: `tables` is a TorqueFeedback.
    """
    if isinstance(tables, TorqueFeedback):
        raise ValueError("torques fed back from the state need it: use applied_torque(torques, t, q, qd)")
    if isinstance(tables, TorqueFunction):
        return np.asarray(tables.fn(t), dtype=float)
    return np.concatenate([_table_at(tab, t) for tab in tables])


def _table_at(tab: TorqueTable, t: float) -> np.ndarray:
    """One table's row at t, all joints at once, as np.interp gives each column (the same arithmetic: one
    binary search, slope·(t − t_j) + τ_j, the row itself on a knot, held outside; nan at a nan time)."""
    times, values = tab.times, tab.values
    if len(times) == 1 or t <= times[0]:
        return np.array(values[0], dtype=float)
    if t >= times[-1]:
        return np.array(values[-1], dtype=float)
    if t != t:
        return np.full(values.shape[1], np.nan)
    j = int(np.searchsorted(times, t, side="right")) - 1
    if t == times[j]:
        return np.array(values[j], dtype=float)
    slope = (values[j + 1] - values[j]) / (times[j + 1] - times[j])
    return slope * (t - times[j]) + values[j]


def applied_torque(torques: "tuple[TorqueTable, ...] | TorqueFunction", t: float, q: np.ndarray,
                   qd: np.ndarray) -> np.ndarray:
    """Stacked joint torques applied at time t in the state (q, qd).

    A TorqueFeedback's value there, otherwise τ(t) (`torque_at`).

    Args:
        torques: one TorqueTable per arm, or a TorqueFunction (a TorqueFeedback included).
        t: s, the time.
        q: (n_total,) rad (m on a prismatic joint), stacked joint coordinates.
        qd: (n_total,) rad/s (m/s), stacked joint rates.

    Returns:
        np.ndarray: (n_total,) N·m (N on a prismatic joint), joints stacked arm after arm.
    """
    if isinstance(torques, TorqueFeedback):
        return np.asarray(torques.fn(t, q, qd), dtype=float)
    return torque_at(torques, t)
