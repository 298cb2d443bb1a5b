"""Peer models of the work-precision benchmark: the scenario's MuJoCo twin driven through
`mujoco.rollout`, and the same closed chain built in Pinocchio and solved with `constraintDynamics`.

Conventions are coopsim's (README, "Model and conventions"): SI units, rad; joint vectors stacked
arm after arm (`Model.dof_slices`); torques τ(t) (n,) N·m from `coopsim.core.model.torque_at`.

MuJoCo peer (`mujoco_twin`, `twin_rollout`, `mujoco_rollout`, `mujoco_forward_us`): the twin of
`coopsim.twin.mjcf.build_spec` with the integrator, step and weld time constant chosen per call. The
rollout holds each control constant over one MuJoCo step; the torque of step k, [t_k, t_k + h], is
τ(t_k + h/2): a midpoint zero-order hold, second-order accurate in h for a smooth τ (exact for
constant torques; `coopsim.twin.mujoco_run.run_twin` instead evaluates τ at every RK4 stage).

Pinocchio peer (`pinocchio_system`, `pinocchio_eval_us`, `pinocchio_trajectory`): one kinematic
chain per arm, the object's inertia appended to the carrier arm's last link, one 6D rigid constraint
(`RigidConstraintModel`, CONTACT_6D, LOCAL) per other arm between its end-effector frame and its
grasp frame on the object. A planar scene's 6D constraint has 3 identically zero directions (the
Delassus matrix is singular): the proximal solver with a small μ still returns the unique θ̈ (see
`pinocchio_system`). Pinocchio is imported lazily (`pip install -e '.[bench]'`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable

import mujoco
import mujoco.rollout
import numpy as np
from scipy.integrate import solve_ivp

from coopsim.twin.mjcf import build_spec, dof_address, qpos_address
from coopsim.twin.weld import resolved
from coopsim.core.model import Model, torque_at

INTEGRATORS = ("RK4", "Euler", "implicit", "implicitfast")


# ----------------------------------------------------------------------------------------------
# MuJoCo


@dataclass(frozen=True, eq=False)
class MujocoTwin:
    """A compiled MuJoCo twin ready for rollouts. model: the coopsim Model; mj_model / mj_data:
    compiled twin and the MjData the rollouts step; qpos_adr, dof_adr, ctrl_adr (n,): qpos, qvel and
    ctrl indices of the stacked joints; runner: persistent `mujoco.rollout.Rollout` (no thread pool:
    one trajectory runs on the calling thread); timestep s; weld_timeconst s (weld solref[0])."""

    model: Model
    mj_model: mujoco.MjModel
    mj_data: mujoco.MjData
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    ctrl_adr: np.ndarray
    runner: mujoco.rollout.Rollout
    timestep: float
    weld_timeconst: float


@dataclass(frozen=True, eq=False)
class RolloutResult:
    """A twin trajectory sampled at t (N,) s: q, qd (N, n) rad, rad/s, coopsim joint order;
    weld_violation (N,) max |efc_pos| over the weld rows at each sample (m or rad; one mj_forward per
    sample after the rollout, not timed; [-1] is the final violation); wall_time s of the
    `Rollout.rollout` call alone; nstep: MuJoCo steps taken; diverged_at: None, or the time s at
    which MuJoCo found the simulation unstable (bad qacc) and reset it; samples from then on are NaN."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    weld_violation: np.ndarray
    wall_time: float
    nstep: int
    diverged_at: float | None


def default_weld_timeconst(integrator: str, timestep: float) -> float:
    """Weld time constant s: one step for RK4 (as `MujocoSettings.solref`), two steps (MuJoCo's own
    `refsafe` minimum) for the Euler family, which goes unstable at one step (bad qacc, reset)."""
    return timestep if integrator == "RK4" else 2.0 * timestep


def mujoco_twin(model: Model, integrator: str = "RK4", timestep: float | None = None,
                weld_timeconst: float | None = None) -> MujocoTwin:
    """Compile the twin with `integrator` ('RK4' | 'Euler' | 'implicit' | 'implicitfast'), step
    `timestep` s (None: the scenario's, or the automatic step `coopsim run` takes) and weld solref [weld_timeconst, 1] (critical damping; None:
    `default_weld_timeconst`). build_spec disables MuJoCo's `refsafe` clamp (timeconst >= 2 steps),
    so the time constant is used as given; RK4 stays stable down to about timestep / 2.8, Euler and
    implicitfast need about two steps. The weld yields about ∝ timeconst² (`coopsim.twin.weld`)."""
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, not {integrator!r}")
    dt = float(resolved(model).mujoco.timestep if timestep is None else timestep)
    tc = default_weld_timeconst(integrator, dt) if weld_timeconst is None else float(weld_timeconst)
    settings = replace(model.mujoco, timestep=dt, integrator=integrator, weld_solref=(tc, 1.0))
    m = build_spec(model, settings, with_geoms=False).compile()
    ctrl = np.array([m.actuator(f"a{a}_m{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)])
    return MujocoTwin(model, m, mujoco.MjData(m), qpos_address(m, model), dof_address(m, model), ctrl,
                      mujoco.rollout.Rollout(nthread=0), dt, tc)


def step_counts(t_out: np.ndarray, timestep: float) -> np.ndarray:
    """Steps (N,) from t_out[0] to each output time; raises ValueError unless every t_out − t_out[0]
    is a whole, non-decreasing multiple of `timestep` (to 1e-6 of a step)."""
    k = (np.asarray(t_out, dtype=float) - t_out[0]) / timestep
    steps = np.round(k).astype(int)
    if np.any(np.abs(k - steps) > 1e-6) or np.any(np.diff(steps) < 0):
        raise ValueError(f"output times must be non-decreasing whole multiples of the timestep {timestep:g} s")
    return steps


def midpoint_controls(twin: MujocoTwin, t0: float, nstep: int) -> np.ndarray:
    """Control sequence (nstep, nu): row k holds τ(t0 + (k + ½) h) N·m at the joints' actuators
    (midpoint zero-order hold over step k, h = twin.timestep)."""
    ctrl = np.zeros((nstep, twin.mj_model.nu))
    h = twin.timestep
    for k in range(nstep):
        ctrl[k, twin.ctrl_adr] = torque_at(twin.model.torques, t0 + (k + 0.5) * h)
    return ctrl


def _initial_state(twin: MujocoTwin, q0: np.ndarray, qd0: np.ndarray, t0: float) -> np.ndarray:
    """MuJoCo full-physics state (1, nstate) holding time t0, joints q0 and rates qd0."""
    m, d = twin.mj_model, mujoco.MjData(twin.mj_model)
    d.time, d.qpos[twin.qpos_adr], d.qvel[twin.dof_adr] = t0, q0, qd0
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS.value
    state = np.zeros((1, mujoco.mj_stateSize(m, spec)))
    mujoco.mj_getState(m, d, state[0], spec)
    return state


def _state_slices(m: mujoco.MjModel) -> tuple[slice, slice]:
    """Where qpos and qvel sit in a full-physics state vector (time, qpos, qvel, ...; time at 0)."""
    S = mujoco.mjtState
    a = mujoco.mj_stateSize(m, S.mjSTATE_TIME.value)
    b = mujoco.mj_stateSize(m, S.mjSTATE_TIME.value | S.mjSTATE_QPOS.value)
    c = mujoco.mj_stateSize(m, S.mjSTATE_TIME.value | S.mjSTATE_QPOS.value | S.mjSTATE_QVEL.value)
    return slice(a, b), slice(b, c)


def _first_reset(times: np.ndarray, t0: float, h: float) -> int | None:
    """Index of the first state (row k: after k steps) whose time is not t0 + k h: MuJoCo reset
    the data after an instability (rollout then repeats the reset state); None if there is none."""
    bad = np.nonzero(np.abs(times - (t0 + h * np.arange(len(times)))) > 1e-6 * h)[0]
    return int(bad[0]) if bad.size else None


def weld_violation(twin: MujocoTwin, q: np.ndarray, qd: np.ndarray) -> float:
    """max |efc_pos| over the twin's weld rows at joints q (n,) rad (m or rad; 0 without welds),
    from one mj_forward on a scratch MjData."""
    m, d = twin.mj_model, mujoco.MjData(twin.mj_model)
    d.qpos[twin.qpos_adr], d.qvel[twin.dof_adr] = q, qd
    mujoco.mj_forward(m, d)
    rows = d.efc_type[: d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    efc = d.efc_pos[: d.nefc][rows]
    return float(np.max(np.abs(efc))) if efc.size else 0.0


def twin_rollout(twin: MujocoTwin, q0: np.ndarray, qd0: np.ndarray, t_out: np.ndarray) -> RolloutResult:
    """Roll the twin out from (q0, qd0) (n,) rad, rad/s at time t_out[0] s with the scenario's
    torques (midpoint zero-order hold) and sample it at t_out (N,) s, whole multiples of the step
    after t_out[0]. One `Rollout.rollout` call (no Python per step, zero initial warm start, output
    buffer allocated beforehand) is timed."""
    t_out = np.asarray(t_out, dtype=float)
    steps = step_counts(t_out, twin.timestep)
    nstep = int(steps[-1])
    state0 = _initial_state(twin, q0, qd0, t_out[0])
    ctrl = midpoint_controls(twin, t_out[0], nstep)[None]
    out = np.empty((1, nstep, state0.shape[1]))
    sensors = np.empty((1, nstep, twin.mj_model.nsensordata))
    warm = np.zeros((1, twin.mj_model.nv))
    start = time.perf_counter()
    twin.runner.rollout([twin.mj_model], [twin.mj_data], state0, ctrl, skip_checks=True, nstep=nstep,
                        initial_warmstart=warm, state=out, sensordata=sensors)
    wall = time.perf_counter() - start
    traj = np.concatenate([state0, out[0]])  # row k: the state after k steps
    qs, vs = _state_slices(twin.mj_model)
    q = traj[steps, qs][:, twin.qpos_adr]
    qd = traj[steps, vs][:, twin.dof_adr]
    reset = _first_reset(traj[:, 0], t_out[0], twin.timestep)
    lost = steps >= (nstep + 1 if reset is None else reset)
    q[lost], qd[lost] = np.nan, np.nan
    viol = np.array([np.nan if bad else weld_violation(twin, a, b) for a, b, bad in zip(q, qd, lost)])
    diverged = None if reset is None else float(t_out[0] + reset * twin.timestep)
    return RolloutResult(t_out, q, qd, viol, wall, nstep, diverged)


def mujoco_rollout(model: Model, q0: np.ndarray, qd0: np.ndarray, t_out: np.ndarray, integrator: str,
                   timestep: float, weld_timeconst: float | None = None) -> RolloutResult:
    """Build the twin (`mujoco_twin`, not timed) and roll it out (`twin_rollout`): q, qd at t_out
    (N,) s in coopsim order, weld violation per sample, wall time of the rollout call alone."""
    return twin_rollout(mujoco_twin(model, integrator, timestep, weld_timeconst), q0, qd0, t_out)


def _best_us(fn: Callable[[], None], calls: int, repeats: int) -> float:
    """µs per call of fn: the minimum over `repeats` loops of `calls` calls."""
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, time.perf_counter() - start)
    return 1e6 * best / calls


def mujoco_forward_us(twin: MujocoTwin, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                      calls: int = 2000, repeats: int = 5) -> float:
    """µs per `mj_forward` of the twin at state (q, qd) with torques tau (n,) N·m, called from
    Python (binding overhead included), minimum over `repeats` loops of `calls` calls. The solver is
    warm-started with the state's own acceleration (as a step is, with the previous step's); the
    integrator does not enter mj_forward, RK4 costs four of them per step."""
    m, d = twin.mj_model, mujoco.MjData(twin.mj_model)
    d.qpos[twin.qpos_adr], d.qvel[twin.dof_adr], d.ctrl[twin.ctrl_adr] = q, qd, tau
    mujoco.mj_forward(m, d)
    d.qacc_warmstart[:] = d.qacc
    return _best_us(lambda: mujoco.mj_forward(m, d), calls, repeats)


# ----------------------------------------------------------------------------------------------
# Pinocchio


def _pinocchio():
    """The pinocchio module, or an ImportError saying how to install it."""
    try:
        import pinocchio
    except ImportError as exc:
        raise ImportError("the Pinocchio peer needs the 'pin' package (import pinocchio): "
                          "pip install -e '.[bench]'") from exc
    return pinocchio


@dataclass(frozen=True, eq=False)
class PinocchioSystem:
    """The closed chain in Pinocchio. model: the coopsim Model; pin_model / pin_data; constraints /
    constraint_data: one CONTACT_6D RigidConstraintModel (and its data) per non-carrier arm;
    settings: the ProximalSettings of constraintDynamics (mutated by each call: iter, residuals).
    Pinocchio's q and v are coopsim's stacked joint vectors (checked when built)."""

    model: Model
    pin_model: object
    pin_data: object
    constraints: object
    constraint_data: object
    settings: object

    def qdd(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Closed-chain joint accelerations θ̈ (n,) rad/s² at (q, qd) (n,) rad, rad/s, torques tau
        (n,) N·m (the loop closed at acceleration level, no stabilisation)."""
        pin = _pinocchio()
        return pin.constraintDynamics(self.pin_model, self.pin_data, q, qd, tau, self.constraints,
                                      self.constraint_data, self.settings).copy()


def _joint_model(pin, axis: np.ndarray, prismatic: bool = False):
    """JointModelRX/RY/RZ (PX/PY/PZ for a prismatic joint) where the axis is +x, +y or +z exactly, else
    RevoluteUnaligned(axis) (PrismaticUnaligned)."""
    aligned = (pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ) if prismatic else \
        (pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ)
    for k, jm in enumerate(aligned):
        if np.array_equal(axis, np.eye(3)[k]):
            return jm()
    unaligned = pin.JointModelPrismaticUnaligned if prismatic else pin.JointModelRevoluteUnaligned
    return unaligned(np.asarray(axis, dtype=float))


def _add_arm(pin, pm, arm, m: int) -> int:
    """Add arm m's joints and link inertias to pm (joints 'a{m}_j{i}'); returns its last joint id.
    Joint i sits at SE3(joint_rot[i], joint_pos[i]) in link i−1; the first at base ∘ that."""
    parent = 0
    for i in range(arm.n):
        R, p = arm.joint_rot[i], arm.joint_pos[i]
        if i == 0:
            R, p = arm.base_rot @ R, arm.base_pos + arm.base_rot @ p
        parent = pm.addJoint(parent, _joint_model(pin, arm.joint_axis[i], bool(arm.prismatic[i])), pin.SE3(R, p), f"a{m}_j{i}")
        inertia = pin.Inertia(float(arm.link_mass[i]), np.asarray(arm.link_com[i], float), arm.link_inertia[i])
        pm.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    return parent


def _object_in_carrier(pin, model: Model):
    """SE3 of the object frame (its centre of mass) in the carrier's last link frame:
    ee pose ∘ inverse(carrier's grasp pose)."""
    obj, c = model.object, model.object.carrier
    arm = model.arms[c]
    return pin.SE3(arm.ee_rot, arm.ee_pos) * pin.SE3(obj.grasp_rot[c], obj.grasp_pos[c]).inverse()


def default_proximal(model: Model) -> tuple[float, float, int]:
    """(accuracy, mu, max_iter) for constraintDynamics: a spatial scene's 6D rows are independent,
    μ = 0 and one iteration are an exact Cholesky solve; a planar scene's are rank-deficient (3 of 6
    directions vanish), μ = 1e-12 regularises them and converges in 3–4 iterations to 1e-14."""
    return (1e-14, 0.0, 1) if model.plane is None else (1e-14, 1e-12, 50)


def pinocchio_system(model: Model, proximal: tuple[float, float, int] | None = None) -> PinocchioSystem:
    """Build the closed chain in Pinocchio: arm after arm (so pinocchio's q is coopsim's stacked
    q), the object inertia appended to the carrier's last link, one CONTACT_6D constraint (LOCAL) per
    other arm m between its last joint (placement: its ee frame) and the carrier's last joint
    (placement: the grasp frame of arm m in that link). proximal: (accuracy, mu, max_iter) of
    pinocchio.ProximalSettings (None: `default_proximal`)."""
    pin = _pinocchio()
    pm = pin.Model()
    pm.gravity = pin.Motion(np.asarray(model.gravity, dtype=float), np.zeros(3))
    last = [_add_arm(pin, pm, arm, m) for m, arm in enumerate(model.arms)]
    stacked = [pm.joints[pm.getJointId(f"a{m}_j{i}")].idx_q for m, arm in enumerate(model.arms) for i in range(arm.n)]
    if stacked != list(range(model.n_total)) or pm.nq != model.n_total or pm.nv != model.n_total:
        raise RuntimeError("pinocchio joint order differs from coopsim's stacked order")
    obj, c = model.object, model.object.carrier
    X_lo = _object_in_carrier(pin, model)
    pm.appendBodyToJoint(last[c], pin.Inertia(float(obj.mass), np.zeros(3), obj.inertia), X_lo)
    constraints = pin.StdVec_RigidConstraintModel()
    for m, arm in enumerate(model.arms):
        if m != c:
            constraints.append(pin.RigidConstraintModel(
                pin.ContactType.CONTACT_6D, pm, last[m], pin.SE3(arm.ee_rot, arm.ee_pos),
                last[c], X_lo * pin.SE3(obj.grasp_rot[m], obj.grasp_pos[m]), pin.ReferenceFrame.LOCAL))
    data = pm.createData()
    cdata = pin.StdVec_RigidConstraintData()
    for cm in constraints:
        cdata.append(cm.createData())
    pin.initConstraintDynamics(pm, data, constraints, cdata)
    settings = pin.ProximalSettings(*(proximal or default_proximal(model)))
    return PinocchioSystem(model, pm, data, constraints, cdata, settings)


def closure_residual(system: PinocchioSystem, q: np.ndarray) -> float:
    """Loop-closure error at joints q (n,) rad: max over constraints of |log6(ee⁻¹ ∘ grasp)| (m and
    rad mixed, LOCAL frame of the end-effector); 0 on the manifold."""
    pin = _pinocchio()
    pm, d = system.pin_model, system.pin_model.createData()
    pin.forwardKinematics(pm, d, q)
    worst = 0.0
    for cm in system.constraints:
        a = d.oMi[cm.joint1_id] * cm.joint1_placement
        b = d.oMi[cm.joint2_id] * cm.joint2_placement
        worst = max(worst, float(np.max(np.abs(pin.log6(a.inverse() * b).vector))))
    return worst


def pinocchio_eval_us(system: PinocchioSystem, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                      calls: int = 2000, repeats: int = 5) -> float:
    """µs per `pinocchio.constraintDynamics` call at (q, qd, tau) (n,) with the system's proximal
    settings, from Python (binding overhead included), minimum over `repeats` loops of `calls`."""
    pin = _pinocchio()
    s = system
    args = (s.pin_model, s.pin_data, np.asarray(q, float), np.asarray(qd, float), np.asarray(tau, float),
            s.constraints, s.constraint_data, s.settings)
    return _best_us(lambda: pin.constraintDynamics(*args), calls, repeats)


@dataclass(frozen=True, eq=False)
class PinocchioTrajectory:
    """t (N,) s; q, qd (N, n) rad, rad/s; wall_time s of solve_ivp; nfev right-hand-side
    evaluations (each one constraintDynamics); residual (N,) loop-closure error (`closure_residual`,
    the constraint is held at acceleration level only, so it drifts)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    wall_time: float
    nfev: int
    residual: np.ndarray


def pinocchio_trajectory(system: PinocchioSystem, q0: np.ndarray, qd0: np.ndarray, t_out: np.ndarray,
                         torque_fn: Callable[[float], np.ndarray] | None, rtol: float,
                         atol: float) -> PinocchioTrajectory:
    """Integrate θ̈ = constraintDynamics(θ, θ̇, τ(t)) from (q0, qd0) at t_out[0] with scipy's DOP853
    (rtol, atol) and sample at t_out (N,) s (DOP853's dense output). torque_fn(t) -> (n,) N·m (None:
    the scenario's torques, `torque_at`). Wall time covers solve_ivp alone."""
    n = system.model.n_total
    tau = torque_fn or (lambda t: torque_at(system.model.torques, t))

    def rhs(t, y):
        return np.concatenate([y[n:], system.qdd(y[:n], y[n:], tau(t))])

    t_out = np.asarray(t_out, dtype=float)
    y0 = np.concatenate([q0, qd0]).astype(float)
    start = time.perf_counter()
    sol = solve_ivp(rhs, (t_out[0], t_out[-1]), y0, method="DOP853", t_eval=t_out, rtol=rtol, atol=atol)
    wall = time.perf_counter() - start
    if not sol.success:
        raise RuntimeError(f"pinocchio peer: solve_ivp failed: {sol.message}")
    q, qd = sol.y[:n].T, sol.y[n:].T
    return PinocchioTrajectory(t_out, q, qd, wall, int(sol.nfev), np.array([closure_residual(system, x) for x in q]))
