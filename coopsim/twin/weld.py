"""The weld yield: how far the MuJoCo twin's soft welds let it leave the exact closed chain, predicted
from the native run; the twin step chosen from it; and whether a failed comparison is that yield.

MuJoCo (4.0 and later) holds each weld row with J q̈ = a_ref − R f, a_ref = −J̇q̇ − b J q̇ − k d r: f is the
weld's force, r its violation, k = 1/(d_max² τ² ζ²) and b = 2/(d_max τ) from solref = [τ, ζ], d the
impedance (solimp) and R = (1 − d)/d · (an estimate of the diagonal of J M⁻¹ Jᵀ, taken at qpos0) the
regularisation that makes the weld soft. Along the exact motion (J q̈ = −J̇q̇, weld force λ) the weld
settles, critically damped within a few τ, where k d r = −R λ: it yields by

    ρ = −R λ / (k d),   proportional to τ²

(the force it carries times its compliance; J̇q̇ itself is compensated by a_ref). The joint error has three
parts, each computed here along the native samples from MuJoCo's own quantities:

1. the offset: the arms stand off the closed chain by δq = P ρ, P = M⁻¹Jᵀ(J M⁻¹Jᵀ)⁺ (the displacement of
   least kinetic energy with J δq = ρ);
2. the drift: the offset chain moves differently. The deviation x = (δq, δq̇) obeys the closed chain's
   dynamics linearised along the run, ẋ = A(t) x + (0, P ρ̈), its offset held at J δq = ρ; A is MuJoCo's
   with the welds rigid (J q̈ = −J̇q̇), by forward differences, which reproduces the native accelerations
   at the native states to round-off for a twin of the same model (`acceleration_mismatch`);
3. RK4 at a step h comparable to τ does not resolve the welds' fast mode: on a curved constraint each
   step ends with r = c_r h² (−J̇q̇) and J q̇ = c_v h (−J̇q̇), c_r and c_v RK4's fixed point for β = b h,
   κ = k d h² (`rk4_weld_residue`; −11/450 and 37/900 at τ = h, O((h/τ)⁴) for τ ≫ h): an offset of the
   positions and a velocity of the rates along the weld rows.

Parts 1 and 2 scale with τ², part 3 with h and τ. The prediction is the maximum over the samples after
t = 0 (the twin starts at the native state), per compared quantity. It assumes the welds are faster than
the mechanism (τ well below the period of its fastest mode) and the output grid resolves the motion;
where a stiff controller acts faster than the grid (a PD loop of 1 ms on 50 ms samples), it
over-predicts.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco
import numpy as np

from coopsim.control.controller import closed_loop
from coopsim.core.errors import CoopsimError
from coopsim.core.model import Model, MujocoSettings, TorqueFeedback, ValidationThresholds, applied_torque
from coopsim.forward.simulate import SimResult, simulate
from coopsim.twin.compare import Comparison
from coopsim.twin.mjcf import build_spec, dof_address, qpos_address
from coopsim.twin.mujoco_run import divides

MAX_STEP = 1e-3            # s, the largest automatic step (RK4's own error on the arms is not predicted)
MIN_STEP = 1e-5            # s, the smallest automatic step
MAX_AUTO_STEPS = 1_000_000 # the most MuJoCo steps an automatic step asks for
MARGIN = 0.25              # an automatic step's predicted errors are at most this share of each threshold
EXPLAINED = 2.0            # a failure up to this multiple of its prediction is the weld yield
SAME_MODEL = 1e-6          # relative acceleration mismatch below which MuJoCo's and the native model agree
MAX_LINEARISED = 400       # samples at which the dynamics are linearised; the others interpolate
FD_STEP = 1e-6             # rad or m, rad/s or m/s: the forward-difference step of the linearisation
PINV_RCOND = 1e-10         # relative cut of J M⁻¹ Jᵀ's pseudo-inverse (planar scenes: the out-of-plane rows)

# compared quantity (`compare.Metric.name`) -> WeldPrediction attribute
PREDICTED = {"joint angle error": "angle", "joint rate error": "rate", "object position error": "object_position",
             "object orientation error": "object_orientation", "MuJoCo weld violation": "weld_violation"}


@dataclass(frozen=True)
class WeldPrediction:
    """The twin's predicted departure from the native run at one step: maxima over the samples after t = 0.

    Attributes:
        timestep: s, the twin's step.
        timeconst: s, the welds' time constant (solref[0]).
        angle: rad (m on a prismatic joint), the largest joint-coordinate error.
        rate: rad/s (m/s), the largest joint-rate error.
        object_position: m, the object's centre of mass.
        object_orientation: rad, the object frame.
        weld_violation: m or rad, the largest weld row.
        acceleration_mismatch: rad/s² (m/s²), the largest |θ̈| difference between MuJoCo with rigid welds
            and the native run at the native samples: round-off for a twin of the same model.
        acceleration_scale: rad/s² (m/s²), the largest |θ̈| of the native run.
    """

    timestep: float
    timeconst: float
    angle: float
    rate: float
    object_position: float
    object_orientation: float
    weld_violation: float
    acceleration_mismatch: float
    acceleration_scale: float

    @property
    def same_model(self) -> bool:
        """Whether MuJoCo's rigid dynamics reproduce the native accelerations (relative SAME_MODEL)."""
        return self.acceleration_mismatch <= SAME_MODEL * max(self.acceleration_scale, 1.0)

    def of(self, metric: str) -> float | None:
        """The prediction of a compared quantity.

        Args:
            metric: a `compare.Metric` name, e.g. "joint angle error".

        Returns:
            float | None: its predicted maximum (the metric's unit); None for a quantity not predicted.
        """
        return getattr(self, PREDICTED[metric]) if metric in PREDICTED else None


@dataclass(frozen=True, eq=False)
class WeldYield:
    """The weld yield along a native run, for any step (`predict`): N samples, n joints, m weld rows.

    Attributes:
        model: the twin's Model (step not needed).
        t: (N,) s, the native sample times.
        normal: (N, n, m) P = M⁻¹Jᵀ(J M⁻¹Jᵀ)⁺: joint displacement per weld violation, coopsim's joint order.
        rho: (N, m) m or rad, the yield at `timeconst`.
        curvature: (N, m) m/s² or rad/s², −J̇q̇ of each weld row (MuJoCo's a_ref at r = 0, J q̇ = 0).
        stiffness: (m,) 1/s², k d of each weld row at `timeconst`.
        damping: (m,) 1/s, b of each weld row at `timeconst`.
        drift_q: (N, n) rad or m, parts 1 and 2 of the joint error at `timeconst`.
        drift_qd: (N, n) rad/s or m/s, their rates.
        object_jacobian: (N, 6, n) the object's centre-of-mass velocity and angular velocity (world) per
            joint rate.
        timeconst: s, the time constant these are computed for.
        acceleration_mismatch: rad/s² (m/s²), as `WeldPrediction`.
        acceleration_scale: rad/s² (m/s²), as `WeldPrediction`.
    """

    model: Model
    t: np.ndarray
    normal: np.ndarray
    rho: np.ndarray
    curvature: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    drift_q: np.ndarray
    drift_qd: np.ndarray
    object_jacobian: np.ndarray
    timeconst: float
    acceleration_mismatch: float
    acceleration_scale: float


@dataclass(frozen=True)
class TwinStep:
    """The twin's step and what the weld yield predicts there.

    Attributes:
        timestep: s, the step the twin runs with.
        automatic: True when coopsim chose it (the scenario leaves `mujoco.timestep` out).
        predicted: the WeldPrediction at `timestep`.
        passing: s, the largest step (time constant one step) whose prediction is within MARGIN of every
            threshold; None: none down to the smallest automatic step.
    """

    timestep: float
    automatic: bool
    predicted: WeldPrediction
    passing: float | None

    def as_dict(self) -> dict:
        """The step as JSON-ready data (summary.json's "mujoco").

        Returns:
            dict: timestep_s, timestep_source ('automatic' or 'scenario'), passing_timestep_s and predicted
            (each WeldPrediction field).
        """
        return {"timestep_s": self.timestep, "timestep_source": "automatic" if self.automatic else "scenario",
                "passing_timestep_s": self.passing, "predicted": dict(vars(self.predicted))}


def rk4_weld_residue(beta: np.ndarray, kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RK4's fixed point for a soft weld on a curved constraint, per unit curvature.

    A point held on a curve by a_ref = −J̇q̇ − (β/h) J q̇ − (κ/h²) r, integrated by classical RK4 in joint
    coordinates at step h: to first order in the curvature the step ends with r = c_r h² (−J̇q̇) and
    J q̇ = c_v h (−J̇q̇) (derived symbolically; exact for a constant J̇q̇).

    Args:
        beta: b h, dimensionless (2 h/τ at critical damping).
        kappa: k d h², dimensionless ((h/τ)² at critical damping).

    Returns:
        tuple[np.ndarray, np.ndarray]: (c_r, c_v), dimensionless, shaped as beta.
    """
    b, k = np.asarray(beta, float), np.asarray(kappa, float)
    den = 4 * (24 * b**3 - 12 * b**2 * k - 96 * b**2 + 4 * b * k**2 - 24 * b * k + 288 * b - k**3 + 8 * k**2
               + 48 * k - 576)
    return k * (b * k - 4 * k + 24) / den, -k * (24 * b + k**2 - 12 * k) / den


def _timeconst(st: MujocoSettings, timestep: float) -> float:
    return st.weld_solref[0] if st.weld_solref is not None else timestep


class _RigidTwin:
    """The twin compiled once; MuJoCo's quantities at a state with its welds taken as rigid."""

    def __init__(self, model: Model, settings: MujocoSettings):
        self.model = closed_loop(model)
        self.m = build_spec(self.model, settings, with_geoms=False).compile()
        self.d = mujoco.MjData(self.m)
        self.qadr, self.dadr = qpos_address(self.m, model), dof_address(self.m, model)
        self.ctrl = np.array([self.m.actuator(f"a{a}_m{i}").id for a, arm in enumerate(model.arms)
                              for i in range(arm.n)])
        self.feedback = isinstance(self.model.torques, TorqueFeedback)

    def forward(self, t: float, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> dict:
        """mj_forward at (q, qd) with torques tau (a controller's own where it feeds back); the weld rows'
        Jacobian, gains, regularisation, curvature, their rigid force and the rigid θ̈."""
        m, d = self.m, self.d
        d.qpos[self.qadr], d.qvel[self.dadr], d.time = q, qd, t
        d.ctrl[self.ctrl] = applied_torque(self.model.torques, t, q, qd) if self.feedback else tau
        mujoco.mj_forward(m, d)
        rows = np.flatnonzero(d.efc_type[: d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
        J = np.ascontiguousarray(d.efc_J[: d.nefc * m.nv].reshape(d.nefc, m.nv)[rows])
        kbip = d.efc_KBIP[: d.nefc][rows]
        stiffness = kbip[:, 0] * kbip[:, 2]
        curvature = d.efc_aref[rows] + kbip[:, 1] * d.efc_vel[rows] + stiffness * d.efc_pos[rows]
        MiJ = np.zeros_like(J)
        mujoco.mj_solveM(m, d, MiJ, J)
        inverse = np.linalg.pinv(J @ MiJ.T, rcond=PINV_RCOND)
        force = inverse @ (curvature - J @ d.qacc_smooth)
        qdd = d.qacc_smooth + MiJ.T @ force
        P = MiJ.T @ inverse
        return {"J": J[:, self.dadr], "P": P[self.dadr], "stiffness": stiffness, "damping": kbip[:, 1],
                "R": d.efc_R[rows].copy(), "curvature": curvature, "force": force, "qdd": qdd[self.dadr]}

    def object_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(6, n) the object's centre-of-mass velocity and angular velocity per joint rate, world axes."""
        m, d = self.m, self.d
        d.qpos[self.qadr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        body = m.body("object").id
        mujoco.mj_jacBodyCom(m, d, jp, None, body)
        mujoco.mj_jacBody(m, d, None, jr, body)
        return np.vstack([jp, jr])[:, self.dadr]


def _linearised(twin: _RigidTwin, t: float, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                qdd: np.ndarray) -> np.ndarray:
    """(2n, 2n) A of ẋ = (θ̇, θ̈(t, θ, θ̇)) with rigid welds at (q, qd), by forward differences."""
    n = len(q)
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    x = np.concatenate([q, qd])
    for k in range(2 * n):
        y = x.copy()
        y[k] += FD_STEP
        A[n:, k] = (twin.forward(t, y[:n], y[n:], tau)["qdd"] - qdd) / FD_STEP
    return A


def _rk4_linear(A0: np.ndarray, A1: np.ndarray, b0: np.ndarray, b1: np.ndarray, x: np.ndarray, dt: float,
                substeps: int) -> np.ndarray:
    """x after dt of ẋ = A(s) x + b(s), A and b linear in s between their values at both ends (classical
    RK4 in `substeps` steps)."""
    f = lambda s, y: ((1 - s) * A0 + s * A1) @ y + (1 - s) * b0 + s * b1  # noqa: E731
    h = dt / substeps
    for j in range(substeps):
        s0, s1 = j / substeps, (j + 1) / substeps
        sm = 0.5 * (s0 + s1)
        k1 = f(s0, x)
        k2 = f(sm, x + 0.5 * h * k1)
        k3 = f(sm, x + 0.5 * h * k2)
        k4 = f(s1, x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def _drift(t: np.ndarray, A_at, radius: np.ndarray, P: np.ndarray, J: np.ndarray, rho: np.ndarray):
    """Parts 1 and 2 of the joint error: ẋ = A(t) x + (0, P ρ̈) from x(0) = (P ρ, P ρ̇), its offset reset to
    J δq = ρ, J δq̇ = ρ̇ at each sample. A_at(i): A at sample i; radius (N,): a bound on A's spectral radius."""
    N, n = P.shape[0], P.shape[1]
    order = 2 if N > 2 else 1
    rd = np.gradient(rho, t, axis=0, edge_order=order) if N > 1 else np.zeros_like(rho)
    rdd = np.gradient(rd, t, axis=0, edge_order=order) if N > 1 else np.zeros_like(rho)
    b = np.zeros((N, 2 * n))
    b[:, n:] = np.einsum("nij,nj->ni", P, rdd)
    x = np.zeros((N, 2 * n))
    x[0] = np.concatenate([P[0] @ rho[0], P[0] @ rd[0]])
    A_next = A_at(0)
    for i in range(N - 1):
        A_i, A_next = A_next, A_at(i + 1)
        dt = t[i + 1] - t[i]
        y = _rk4_linear(A_i, A_next, b[i], b[i + 1], x[i], dt, max(1, int(np.ceil(dt * radius[i] / 0.5))))
        y[:n] += P[i + 1] @ (rho[i + 1] - J[i + 1] @ y[:n])
        y[n:] += P[i + 1] @ (rd[i + 1] - J[i + 1] @ y[n:])
        x[i + 1] = y
    return x[:, :n], x[:, n:]


def _interpolated(idx: np.ndarray, mats: list[np.ndarray]):
    """A_at(i) interpolating linearly between the matrices computed at sample indices idx."""
    def at(i: int) -> np.ndarray:
        j = int(np.searchsorted(idx, i, side="right")) - 1
        if j >= len(idx) - 1:
            return mats[-1]
        s = (i - idx[j]) / (idx[j + 1] - idx[j])
        return mats[j] if s == 0 else (1 - s) * mats[j] + s * mats[j + 1]
    return at


def weld_yield(model: Model, native: SimResult) -> WeldYield:
    """The weld yield of `model`'s twin along a native run (any step; `predict` evaluates one).

    Args:
        model: the twin's Model (its `mujoco` solref and solimp; the step need not be set).
        native: the native run (`coopsim.forward.simulate.SimResult`): t, q, qd, qdd and tau at its samples.

    Returns:
        WeldYield: the yield, offsets and drift at the welds' time constant (one MAX_STEP when it follows
        the step), the object's Jacobian and the acceleration mismatch along the run.
    """
    solref = model.mujoco.weld_solref or (MAX_STEP, 1.0)     # the yield at one MAX_STEP, scaled by `predict`
    twin = _RigidTwin(model, replace(model.mujoco, timestep=MAX_STEP, weld_solref=solref))
    t, N = native.t, len(native.t)
    ev = [twin.forward(t[i], native.q[i], native.qd[i], native.tau[i]) for i in range(N)]
    stack = lambda key: np.array([e[key] for e in ev])  # noqa: E731
    P, J, curvature, qdd = stack("P"), stack("J"), stack("curvature"), stack("qdd")
    stiffness, damping = ev[0]["stiffness"], ev[0]["damping"]
    a_native = np.einsum("nij,nj->ni", J, native.qdd)
    rho = (curvature - a_native - stack("R") * stack("force")) / stiffness
    idx = np.unique(np.linspace(0, N - 1, min(N, MAX_LINEARISED)).round().astype(int))
    mats = [_linearised(twin, t[i], native.q[i], native.qd[i], native.tau[i], qdd[i]) for i in idx]
    radius = np.interp(np.arange(N), idx, [np.max(np.abs(np.linalg.eigvals(A))) for A in mats])
    drift_q, drift_qd = _drift(t, _interpolated(idx, mats), radius, P, J, rho)
    return WeldYield(model, t, P, rho, curvature, stiffness, damping, drift_q, drift_qd,
                     np.array([twin.object_jacobian(q) for q in native.q]), solref[0],
                     float(np.max(np.abs(qdd - native.qdd))), float(np.max(np.abs(native.qdd))))


def predict(y: WeldYield, timestep: float) -> WeldPrediction:
    """The twin's departure from the native run at a step, from the weld yield along it.

    Args:
        y: the WeldYield of the run.
        timestep: s, the twin's step (the welds' time constant too, unless the scenario sets weld_solref).

    Returns:
        WeldPrediction: the maxima over the samples after t = 0 (the RK4 part only with MuJoCo's RK4).
    """
    st = y.model.mujoco
    tc = _timeconst(st, timestep)
    scale = (tc / y.timeconst) ** 2
    dq, dqd, weld = scale * y.drift_q, scale * y.drift_qd, scale * y.rho
    if st.integrator == "RK4":
        c_r, c_v = rk4_weld_residue(y.damping / (tc / y.timeconst) * timestep,
                                    y.stiffness / scale * timestep**2)
        r_art, v_art = c_r * timestep**2 * y.curvature, c_v * timestep * y.curvature
        dq = dq + np.einsum("nij,nj->ni", y.normal, r_art)
        dqd = dqd + np.einsum("nij,nj->ni", y.normal, v_art)
        weld = weld + r_art
    obj = np.einsum("nij,nj->ni", y.object_jacobian, dq)[1:]
    peak = lambda a: float(np.max(np.abs(a[1:]))) if len(a) > 1 else 0.0  # noqa: E731
    return WeldPrediction(timestep, tc, peak(dq), peak(dqd),
                          float(np.max(np.linalg.norm(obj[:, :3], axis=1), initial=0.0)),
                          float(np.max(np.linalg.norm(obj[:, 3:], axis=1), initial=0.0)), peak(weld),
                          y.acceleration_mismatch, y.acceleration_scale)


def _within(p: WeldPrediction, th: ValidationThresholds, share: float) -> bool:
    """Whether every predicted quantity is within `share` of its threshold."""
    limits = {"angle": th.max_angle_error, "rate": th.max_rate_error, "object_position": th.max_object_position_error,
              "object_orientation": th.max_object_orientation_error, "weld_violation": th.max_weld_violation}
    return all(getattr(p, k) <= share * v for k, v in limits.items())


def _fractions(lo: int, hi: int, decimal: bool) -> np.ndarray:
    """The integers in [lo, hi], increasing; with `decimal` only those 2^a 5^b (interval / k is then written
    exactly in decimals)."""
    if not decimal:
        return np.arange(lo, hi + 1, dtype=float)
    return np.array(sorted({2**a * 5**b for a in range(64) for b in range(28) if lo <= 2**a * 5**b <= hi}),
                    dtype=float)


def step_candidates(t_out: np.ndarray, timeconst: float | None = None) -> np.ndarray:
    """The steps an automatic choice may take, largest first: the output interval divided by 2^a 5^b
    (decimal numbers: 1 ms, 0.8 ms, 0.625 ms, 0.5 ms, … for 10 ms; by any whole number where none of those
    divides a shorter last interval), from MAX_STEP (or the welds' fixed time constant, if smaller) down to
    MIN_STEP or MAX_AUTO_STEPS steps.

    Args:
        t_out: (N,) s, the output times (every interval a whole number of steps).
        timeconst: s, the welds' time constant when the scenario fixes it (a step no larger); None: it
            follows the step.

    Returns:
        np.ndarray: (K,) s, decreasing; empty when none divides the output intervals.
    """
    dt = float(t_out[1] - t_out[0]) if len(t_out) > 1 else MAX_STEP
    top = min(MAX_STEP, timeconst) if timeconst is not None else MAX_STEP
    bottom = max(MIN_STEP, float(t_out[-1] - t_out[0]) / MAX_AUTO_STEPS)
    lo, hi = max(1, int(np.ceil(dt / top - 1e-9))), int(np.floor(dt / bottom + 1e-9))
    for decimal in (True, False):
        steps = np.array([h for h in dt / _fractions(lo, hi, decimal) if divides(t_out, h)])
        if len(steps):
            return steps
    return steps


def largest_step(y: WeldYield, thresholds: ValidationThresholds,
                 share: float = MARGIN) -> tuple[float, WeldPrediction] | None:
    """The largest candidate step (`step_candidates`) whose prediction is within `share` of every threshold.

    The predicted errors shrink with the step; a bisection over the candidates finds it.

    Args:
        y: the WeldYield of the run (its model's weld_solref, if set, fixes the time constant).
        thresholds: the ValidationThresholds to meet.
        share: the fraction of each threshold the prediction may reach.

    Returns:
        tuple[float, WeldPrediction] | None: the step s and its prediction; None when even the smallest
        candidate is predicted outside.
    """
    solref = y.model.mujoco.weld_solref
    steps = step_candidates(y.t, solref[0] if solref is not None else None)
    lo, hi, best = 0, len(steps) - 1, None
    while lo <= hi:
        mid = (lo + hi) // 2
        p = predict(y, float(steps[mid]))
        if _within(p, thresholds, share):
            best, hi = (float(steps[mid]), p), mid - 1
        else:
            lo = mid + 1
    return best


def with_default_solref(y: WeldYield) -> WeldYield:
    """The same yield with the welds' time constant following the step (the scenario's weld_solref dropped).

    Args:
        y: a WeldYield.

    Returns:
        WeldYield: y with its model's `mujoco.weld_solref` None, at critical damping.
    """
    solref = y.model.mujoco.weld_solref
    if solref is None:
        return y
    z2 = solref[1] ** 2               # k ∝ 1/ζ²: the yield at ζ = 1
    return replace(y, model=replace(y.model, mujoco=replace(y.model.mujoco, weld_solref=None)), rho=y.rho / z2,
                   drift_q=y.drift_q / z2, drift_qd=y.drift_qd / z2, stiffness=y.stiffness * z2)


def twin_step(model: Model, native: SimResult, y: WeldYield | None = None) -> tuple[Model, TwinStep]:
    """The twin's step: the scenario's, or (`mujoco.timestep` left out) the largest candidate whose
    predicted errors are within MARGIN of every threshold (the smallest candidate if none is).

    Args:
        model: the twin's Model.
        native: the native run it is compared with.
        y: its WeldYield if already computed; None: computed here.

    Returns:
        tuple[Model, TwinStep]: the model with `mujoco.timestep` set, and the step with its prediction.

    Raises:
        CoopsimError: no candidate step divides the output intervals.
    """
    y = y or weld_yield(model, native)
    st = model.mujoco
    passing = largest_step(with_default_solref(y), model.validation)
    if st.timestep is not None:
        return model, TwinStep(st.timestep, False, predict(y, st.timestep), passing and passing[0])
    chosen = largest_step(y, model.validation)
    if chosen is None:
        steps = step_candidates(native.t, st.weld_solref[0] if st.weld_solref is not None else None)
        if not len(steps):
            raise CoopsimError(f"mujoco.timestep: no step from {MAX_STEP:g} s to {MIN_STEP:g} s divides the output "
                               f"intervals (integrator.output_dt and the last one); set mujoco.timestep")
        chosen = (float(steps[-1]), predict(y, float(steps[-1])))
    h, p = chosen
    return replace(model, mujoco=replace(st, timestep=h)), TwinStep(h, True, p, passing and passing[0])


def resolved(model: Model) -> Model:
    """The model with the step its twin runs with: the scenario's, or the automatic one (`twin_step`, from
    a native run of the model), as `coopsim run` chooses it.

    Args:
        model: the scenario's Model.

    Returns:
        Model: `model` when its `mujoco.timestep` is set; otherwise a copy with the chosen step.
    """
    if model.mujoco.timestep is not None:
        return model
    return twin_step(model, simulate(closed_loop(model)))[0]


def describe(step: TwinStep) -> str:
    """One line naming the twin's step and, when automatic, its predicted joint error.

    Args:
        step: a TwinStep.

    Returns:
        str: e.g. "MuJoCo step 6.25e-05 s, automatic (predicted joint angle error 2e-07)".
    """
    if not step.automatic:
        return f"MuJoCo step {step.timestep:.10g} s, from the scenario"
    return (f"MuJoCo step {step.timestep:.10g} s, automatic (predicted joint angle error "
            f"{step.predicted.angle:.3g}, weld violation {step.predicted.weld_violation:.3g})")


def cause(metric, step: TwinStep, fixed_solref: bool) -> str | None:
    """Why a failed quantity differs: the twin's weld yield; a disagreement of the models (MuJoCo's
    accelerations at the native states are not the native model's); or, with the dynamics agreeing, the
    integration of one run or the other.

    Args:
        metric: the failed `compare.Metric`.
        step: the TwinStep the twin ran with.
        fixed_solref: whether the scenario sets `mujoco.weld_solref` (the passing step assumes it left out).

    Returns:
        str | None: the explanation to append to the failure line; None for a quantity not predicted.
    """
    p = step.predicted
    predicted = p.of(metric.name)
    if predicted is None:
        return None
    yielded = f"predicted {predicted:.3g} {metric.unit}"
    if p.same_model and metric.max <= EXPLAINED * predicted:
        fix = (f"mujoco.timestep: {step.passing:.10g} s{' with weld_solref left out' if fixed_solref else ''} "
               f"would pass" if step.passing is not None else
               f"no step down to {MIN_STEP:g} s is predicted to pass")
        return f"the twin's weld yield ({yielded} at mujoco.timestep {step.timestep:.10g} s); {fix}"
    if not p.same_model:
        return (f"not the twin's weld yield ({yielded}): the models disagree; MuJoCo's accelerations at the "
                f"native states differ by up to {p.acceleration_mismatch:.3g} (of {p.acceleration_scale:.3g}) "
                f"rad/s²")
    return (f"not the twin's weld yield ({yielded}), and MuJoCo's accelerations at the native states are the "
            f"native model's (to {p.acceleration_mismatch:.2g} rad/s²): the integration of one run or the other "
            f"(a smaller mujoco.timestep, or integrator.rtol, shows which)")


def explain(comparison: Comparison, step: TwinStep, fixed_solref: bool) -> Comparison:
    """The comparison with each failed, predicted quantity's `cause` set.

    Args:
        comparison: the Comparison of the native run and the twin.
        step: the TwinStep the twin ran with.
        fixed_solref: whether the scenario sets `mujoco.weld_solref`.

    Returns:
        Comparison: the same metrics, the failed ones explained (`cause`).
    """
    return replace(comparison, metrics=tuple(m if m.passed else replace(m, cause=cause(m, step, fixed_solref))
                                             for m in comparison.metrics))
