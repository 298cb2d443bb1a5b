"""Compiled controllers in the loop (the laws of `coopsim.control.controller`, over flat arrays).

The time loop (`integrate.rhs`) calls `feedback` at every stage after the torque tables: the law's
command is added to the tabulated torques (a disturbance) and the sum clipped to the motor lines of
eq. 36 when `saturate` is set, exactly as `coopsim.control.controller.Controller.command` does in Python:

  * joint PD: u = Kp (θ_r − θ) + Kd (θ̇_r − θ̇) + τ_comp, θ_r a set-point or the quintic Hermite
    interpolant of a joint trajectory (`coopsim.inverse.trajectory.trajectory_at_times`), τ_comp the
    closed-chain inverse dynamics at (θ, 0, 0) or (θ, θ̇, 0) (`inverse_torques`);
  * computed torque: the object pose error e = [p_r − p; log(R_r Rᵀ)] and twist error against the
    prescribed object motion (`object_reference`, `coopsim.inverse.trajectory.object_motion_at`), the object
    acceleration a = a_r + Kd ė + Kp e, each arm's θ̈ from S J_m θ̈_m = S (a_EE,m − J̇_mθ̇_m), and the
    inverse dynamics of (θ, θ̇, θ̈) with a squeeze force in the null space of the grasp matrix;
    plus, per arm, joint-space feedback on its grasp error (`grasp_feedback`).

Inverse dynamics (`coopsim.inverse.solve`): τ = τ_arms + Jᵀ f with A f = y, distributed by the paper's W⁺
(f_m = S W(−s_m) Sᵀ y / r), the non-squeezing inverse (f = M*Aᵀ(A M*Aᵀ)⁻¹ y) or weighted minimum
energy (the KKT system [JᵀQJ Aᵀ; A 0][f; λ] = [−JᵀQτ_arms; y] by Gaussian elimination with partial
pivoting: the same unique minimiser as the null-space form of `coopsim.inverse.distributions.min_energy_solve`, for
actuated arms whose equations keep their rank). The QP of 'bounded' is not compiled.

The controller evaluates its own model (`Pc`, `Wc`: the scene with the controller's object mass); every
array it writes is scratch of its `PackedControl`, so no evaluation allocates.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numba.experimental import structref

from coopsim.compiled.closed_chain import OK, arm_terms
from coopsim.compiled.grasp import object_dynamics, object_pose
from coopsim.compiled.linalg import bisect, copy1, copy2, gauss_solve
from coopsim.compiled.sample import object_acceleration, object_wrench
from coopsim.compiled.spatial import axis_rotation, matmul3, matmul3_T, rot_log
from coopsim.compiled.structs import _F, _I, StructType, _f1, _f2, _f3, _i1
from coopsim.compiled.toolchain.jit import entry, kernel

JOINT_PD, COMPUTED_TORQUE = 0, 1
COMP_NONE, COMP_GRAVITY, COMP_BIAS = 0, 1, 2
REF_SETPOINT, REF_TRAJECTORY = 0, 1
DIST_PAPER, DIST_NONSQUEEZING, DIST_MIN_ENERGY = 0, 1, 2
LAW_QUINTIC, LAW_CUBIC = 0, 1
CONTROL_SINGULAR = 8      # a failure code of the time loop (after integrate's and manifold's)


class PackedControl(NamedTuple):
    """A controller for the kernels: its codes, gains and reference tables, and the arrays it writes.

    N joints, r arms, k rows per grasp, m = rk grasp-wrench unknowns, nmax joints in the longest arm; world
    axes, SI. Built by `new_control`; compiled code reads it through its StructRef (`control_struct`). The
    "written" and scratch arrays are overwritten by the kernels, so no evaluation allocates.

    Attributes:
        law: JOINT_PD or COMPUTED_TORQUE.
        compensation: COMP_NONE, COMP_GRAVITY or COMP_BIAS: the joint PD's τ_comp, none or the closed-chain
            inverse dynamics at (θ, 0, 0) or (θ, θ̇, 0).
        reference: REF_SETPOINT or REF_TRAJECTORY, the joint PD's reference.
        distribution: DIST_PAPER, DIST_NONSQUEEZING or DIST_MIN_ENERGY, the inverse dynamics' distribution
            of the object's wrench.
        saturate: 1 to clip the torques to the motor lines of eq. 36, 0 not to.
        time_law: LAW_QUINTIC or LAW_CUBIC, the object motion's time law.
        kp, kd: (N,) joint PD gains, N·m/rad and N·m·s/rad (N/m and N·s/m on a prismatic joint).
        q_set: (N,) rad or m, the joint set-point.
        tr_t: (M,) s, the joint trajectory's times, read at tr_t[0] + t.
        tr_q, tr_qd, tr_qdd: (M, N) the joint trajectory's θ (rad or m), θ̇ and θ̈ at tr_t.
        okp, okd: (2,) object-space gains [linear, angular], 1/s² and 1/s (commanded object acceleration
            per unit pose and twist error).
        om_t: (w,) s, the object motion's waypoint times, read at om_t[0] + t.
        om_p: (w, 3) m, the waypoint positions of C, world.
        om_R: (w, 3, 3) the waypoint orientations of the object frame, world axes.
        om_axis: (w−1, 3) per segment the unit rotation axis (object axes of the segment start).
        om_angle: (w−1,) rad, per segment the rotation angle.
        om_w: (w−1, 3) rad, per segment R_a φ, the segment's rotation vector in world axes.
        squeeze: N, the computed torque's squeeze force (0: none).
        gkp: (2,) grasp-error stiffness [linear N/m, angular N·m/rad] (`grasp_feedback`).
        gkd: (2,) grasp-error damping [linear N·s/m, angular N·m·s/rad].
        weights: (N,) the diagonal of the energy weight Q (minimum-energy distribution).
        vmass: (r,) kg, the masses of the non-squeezing virtual bodies.
        vinertia: (r, 3, 3) kg·m², the inertias of the non-squeezing virtual bodies, object axes.
        stall: (N,) N·m, the motor lines' stall torques (inf: no line).
        slope: (N,) N·m·s/rad, the motor lines' slopes (0 for a flat or absent line).
        count: (3,) int, written: [evaluations, evaluations with a clipped joint, clipped (evaluation, joint)
            pairs].
        q_ref, qd_ref: (N,) written: the joint reference θ_r (rad or m) and θ̇_r.
        err, rate_err: (6,) written: the object pose and twist error [m; rad], [m/s; rad/s], world axes.
        u: (N,) written: the law's command, N·m (N on a prismatic joint).
        raw: (N,) written: the command with the torque tables added, before saturation.
        zero: (N,) zeros (the θ̇ = 0 and θ̈ = 0 of the compensation).
        qdd: (N,) scratch: the computed torque's θ̈, rad/s².
        tau_arms: (N,) scratch: the arms' own inverse dynamics I_m θ̈_m + h_m (no object).
        tau_c: (N,) scratch: the joint PD's τ_comp.
        Mb: (N, nmax) scratch: the arms' mass-matrix blocks without the object (`state_terms`).
        gerr: (r, 6) written: each arm's grasp error [m; rad], world axes (`grasp_feedback`).
        p_r: (3,) scratch: the prescribed position of C, m, world.
        v_r, a_r: (6,) scratch: the prescribed twist [v_C; ω] and acceleration [a_C; ω̇], world axes.
        a: (6,) scratch: the commanded object acceleration.
        acc: (6,) scratch: the object acceleration v̇_o of the inverse dynamics.
        Y: (6,) scratch: the object wrench M_o v̇_o + b_o at C.
        v6, v3: (6,), (3,) scratch.
        A: (k, m) scratch: the grasp rows [S W_m Sᵀ]_m (`grasp_rows`).
        JT: (N, m) scratch: blockdiag((S J_m)ᵀ).
        f, fs: (m,) scratch: the grasp wrenches in the rows S (N, N·m) and the squeeze wrenches.
        y: (k,) scratch: S Y, the object wrench in the rows S.
        kkt, x: (m+k, m+k), (m+k,) scratch: the minimum-energy KKT system and its solution (x[:m] also
            `gram_solve`'s result).
        MA: (m, k) scratch: M*Aᵀ (non-squeezing) or Aᵀ (squeeze).
        G: (k, k) scratch: A MA, or an arm's S J_m.
        xk: (k,) scratch.
        R3, R3b: (3, 3) scratch.
    """

    law: int
    compensation: int
    reference: int
    distribution: int
    saturate: int
    time_law: int
    kp: np.ndarray
    kd: np.ndarray
    q_set: np.ndarray
    tr_t: np.ndarray
    tr_q: np.ndarray
    tr_qd: np.ndarray
    tr_qdd: np.ndarray
    okp: np.ndarray
    okd: np.ndarray
    om_t: np.ndarray
    om_p: np.ndarray
    om_R: np.ndarray
    om_axis: np.ndarray
    om_angle: np.ndarray
    om_w: np.ndarray
    squeeze: float
    gkp: np.ndarray
    gkd: np.ndarray
    weights: np.ndarray
    vmass: np.ndarray
    vinertia: np.ndarray
    stall: np.ndarray
    slope: np.ndarray
    count: np.ndarray
    q_ref: np.ndarray
    qd_ref: np.ndarray
    err: np.ndarray
    rate_err: np.ndarray
    u: np.ndarray
    raw: np.ndarray
    zero: np.ndarray
    qdd: np.ndarray
    tau_arms: np.ndarray
    tau_c: np.ndarray
    Mb: np.ndarray
    gerr: np.ndarray
    p_r: np.ndarray
    v_r: np.ndarray
    a_r: np.ndarray
    a: np.ndarray
    acc: np.ndarray
    Y: np.ndarray
    v6: np.ndarray
    v3: np.ndarray
    A: np.ndarray
    JT: np.ndarray
    f: np.ndarray
    fs: np.ndarray
    y: np.ndarray
    kkt: np.ndarray
    x: np.ndarray
    MA: np.ndarray
    G: np.ndarray
    xk: np.ndarray
    R3: np.ndarray
    R3b: np.ndarray


_TYPES = {"law": _I, "compensation": _I, "reference": _I, "distribution": _I, "saturate": _I, "time_law": _I,
          "squeeze": _F, "count": _i1, "tr_q": _f2, "tr_qd": _f2, "tr_qdd": _f2, "om_p": _f2, "om_R": _f3,
          "om_axis": _f2, "om_w": _f2, "vinertia": _f3, "A": _f2, "JT": _f2, "kkt": _f2, "MA": _f2, "G": _f2,
          "R3": _f2, "R3b": _f2, "Mb": _f2, "gerr": _f2}
CONTROL_T = StructType([(name, _TYPES.get(name, _f1)) for name in PackedControl._fields])


@njit(cache=True)
def _new_control(r):
    s = structref.new(CONTROL_T)
    s.law = r.law
    s.compensation = r.compensation
    s.reference = r.reference
    s.distribution = r.distribution
    s.saturate = r.saturate
    s.time_law = r.time_law
    s.kp = r.kp
    s.kd = r.kd
    s.q_set = r.q_set
    s.tr_t = r.tr_t
    s.tr_q = r.tr_q
    s.tr_qd = r.tr_qd
    s.tr_qdd = r.tr_qdd
    s.okp = r.okp
    s.okd = r.okd
    s.om_t = r.om_t
    s.om_p = r.om_p
    s.om_R = r.om_R
    s.om_axis = r.om_axis
    s.om_angle = r.om_angle
    s.om_w = r.om_w
    s.squeeze = r.squeeze
    s.gkp = r.gkp
    s.gkd = r.gkd
    s.weights = r.weights
    s.vmass = r.vmass
    s.vinertia = r.vinertia
    s.stall = r.stall
    s.slope = r.slope
    s.count = r.count
    s.q_ref = r.q_ref
    s.qd_ref = r.qd_ref
    s.err = r.err
    s.rate_err = r.rate_err
    s.u = r.u
    s.raw = r.raw
    s.zero = r.zero
    s.qdd = r.qdd
    s.tau_arms = r.tau_arms
    s.tau_c = r.tau_c
    s.Mb = r.Mb
    s.gerr = r.gerr
    s.p_r = r.p_r
    s.v_r = r.v_r
    s.a_r = r.a_r
    s.a = r.a
    s.acc = r.acc
    s.Y = r.Y
    s.v6 = r.v6
    s.v3 = r.v3
    s.A = r.A
    s.JT = r.JT
    s.f = r.f
    s.fs = r.fs
    s.y = r.y
    s.kkt = r.kkt
    s.x = r.x
    s.MA = r.MA
    s.G = r.G
    s.xk = r.xk
    s.R3 = r.R3
    s.R3b = r.R3b
    return s


def control_struct(C: PackedControl):
    """The StructRef of a PackedControl (sharing its arrays).

    Args:
        C: the PackedControl.

    Returns:
        Struct: a CONTROL_T StructRef holding C's arrays (no copy), for the compiled laws.
    """
    return _new_control(C)


def new_control(N: int, r: int, k: int, nmax: int, law: int, **fields) -> PackedControl:
    """A PackedControl of `law` with its scratch allocated; `fields` set the rest.

    Absent fields take the first code, zero gains, two-sample tables, unit energy weights and virtual
    bodies, and no motor lines.

    Args:
        N: joints in all.
        r: arms.
        k: rows per grasp (the rows S).
        nmax: joints in the longest arm.
        law: JOINT_PD or COMPUTED_TORQUE.
        **fields: PackedControl fields by name (gains, codes, tables; see its attributes), converted
            to the field's type.

    Returns:
        PackedControl: the controller, arrays float64 / int64 and C-contiguous.
    """
    m, z = r * k, np.zeros
    base = dict(law=law, compensation=COMP_NONE, reference=REF_SETPOINT, distribution=DIST_PAPER, saturate=0,
                time_law=LAW_QUINTIC, kp=z(N), kd=z(N), q_set=z(N), tr_t=np.array([0.0, 1.0]), tr_q=z((2, N)),
                tr_qd=z((2, N)), tr_qdd=z((2, N)), okp=z(2), okd=z(2), om_t=np.array([0.0, 1.0]), om_p=z((2, 3)),
                om_R=np.tile(np.eye(3), (2, 1, 1)), om_axis=z((1, 3)), om_angle=z(1), om_w=z((1, 3)), squeeze=0.0,
                gkp=z(2), gkd=z(2), weights=np.ones(N), vmass=np.ones(r), vinertia=np.tile(np.eye(3), (r, 1, 1)),
                stall=np.full(N, np.inf), slope=z(N))
    base.update(fields)
    scratch = dict(count=np.zeros(3, dtype=np.int64), q_ref=z(N), qd_ref=z(N), err=z(6), rate_err=z(6), u=z(N),
                   raw=z(N), zero=z(N), qdd=z(N), tau_arms=z(N), tau_c=z(N), Mb=z((N, nmax)), gerr=z((r, 6)),
                   p_r=z(3), v_r=z(6), a_r=z(6), a=z(6), acc=z(6), Y=z(6), v6=z(6), v3=z(3), A=z((k, m)),
                   JT=z((N, m)), f=z(m), fs=z(m), y=z(k), kkt=z((m + k, m + k)), x=z(m + k), MA=z((m, k)),
                   G=z((k, k)), xk=z(k), R3=z((3, 3)), R3b=z((3, 3)))
    out = {}
    for name in PackedControl._fields:
        v = base[name] if name in base else scratch[name]
        typ = _TYPES.get(name, _f1)
        out[name] = int(v) if typ is _I else float(v) if typ is _F else np.ascontiguousarray(
            v, dtype=np.int64 if typ is _i1 else np.float64)
    return PackedControl(**out)


# ------------------------------------------------------------------------------------------------
# Small helpers
# ------------------------------------------------------------------------------------------------

@kernel
def gram_solve(C, k):
    """C.x[:rk] ← MA (A MA)⁻¹ C.xk.

    Args:
        C: the controller (PackedControl StructRef): reads C.A (k, rk), C.MA (rk, k) and C.xk (k,);
            C.G and C.xk are overwritten, C.x[:rk] written.
        k: rows per grasp.

    Returns:
        bool: False when A MA is singular (a zero pivot; C.x not written), else True.
    """
    mk = C.A.shape[1]
    for i in range(k):
        for b in range(k):
            v = 0.0
            for c in range(mk):
                v += C.A[i, c] * C.MA[c, b]
            C.G[i, b] = v
    if gauss_solve(C.G, k, C.xk) == 0.0:
        return False
    for c in range(mk):
        v = 0.0
        for b in range(k):
            v += C.MA[c, b] * C.xk[b]
        C.x[c] = v
    return True


@kernel
def rigid_point_acceleration(a_O, w, dw, r, out):
    """out ← a_O + ω̇ × r + ω × (ω × r), the acceleration of a point of a rigid body.

    As `coopsim.core.spatial.rigid_acceleration`; all vectors in one set of axes (world).

    Args:
        a_O: (3,) m/s², the acceleration of the reference point O.
        w: (3,) rad/s, the body's angular velocity ω.
        dw: (3,) rad/s², its angular acceleration ω̇.
        r: (3,) m, the point relative to O.
        out: (3,) written: the point's acceleration, m/s² (may not alias r, w or dw).
    """
    c0 = w[1] * r[2] - w[2] * r[1]
    c1 = w[2] * r[0] - w[0] * r[2]
    c2 = w[0] * r[1] - w[1] * r[0]
    out[0] = a_O[0] + (dw[1] * r[2] - dw[2] * r[1]) + (w[1] * c2 - w[2] * c1)
    out[1] = a_O[1] + (dw[2] * r[0] - dw[0] * r[2]) + (w[2] * c0 - w[0] * c2)
    out[2] = a_O[2] + (dw[0] * r[1] - dw[1] * r[0]) + (w[0] * c1 - w[1] * c0)


# ------------------------------------------------------------------------------------------------
# References
# ------------------------------------------------------------------------------------------------

@kernel
def segment(ts, t):
    """The interval [ts[i], ts[i+1]] holding t, and t clamped to the span of ts.

    As clip(searchsorted(ts, t, 'right') − 1, 0, len(ts) − 2).

    Args:
        ts: (n,) s, increasing knot times, n ≥ 2.
        t: s, the time.

    Returns:
        tuple[int, float]: (i, t clamped to [ts[0], ts[-1]]).
    """
    t = min(max(t, ts[0]), ts[-1])
    return bisect(ts, 0, len(ts) - 1, t), t


@kernel
def hermite(p0, v0, a0, p1, v1, a1, u, h):
    """(θ, θ̇) at u of the quintic Hermite polynomial through (p0, v0, a0) at u = 0 and (p1, v1, a1) at u = 1.

    Over an interval of h s (`coopsim.inverse.trajectory.hermite_quintic`).

    Args:
        p0, v0, a0: θ (rad or m), θ̇ (per s) and θ̈ (per s²) at the start of the interval.
        p1, v1, a1: the same at its end.
        u: the normalised time in [0, 1].
        h: s, the interval's length.

    Returns:
        tuple[float, float]: (θ, θ̇) at u, θ̇ per s.
    """
    v0, a0, v1, a1 = h * v0, h * h * a0, h * v1, h * h * a1
    d = p1 - p0
    c2 = 0.5 * a0
    c3 = 10 * d - 6 * v0 - 4 * v1 - 1.5 * a0 + 0.5 * a1
    c4 = -15 * d + 8 * v0 + 7 * v1 + 1.5 * a0 - a1
    c5 = 6 * d - 3 * v0 - 3 * v1 - 0.5 * a0 + 0.5 * a1
    q = p0 + v0 * u + c2 * u ** 2 + c3 * u ** 3 + c4 * u ** 4 + c5 * u ** 5
    qd = (v0 + 2 * c2 * u + 3 * c3 * u ** 2 + 4 * c4 * u ** 3 + 5 * c5 * u ** 4) / h
    return q, qd


@kernel
def joint_reference(C, t):
    """C.q_ref, C.qd_ref ← the joint reference at time t.

    The set-point at rest, or the joint trajectory's quintic Hermite interpolant at tr_t[0] + t,
    evaluated from the nearer end of its interval.

    Args:
        C: the controller (PackedControl StructRef): reads reference, q_set or the tr_* tables; C.q_ref
            (rad or m) and C.qd_ref (N,) written.
        t: s, the time since the start of the run.
    """
    if C.reference == REF_SETPOINT:
        for j in range(len(C.q_set)):
            C.q_ref[j], C.qd_ref[j] = C.q_set[j], 0.0
        return
    ts = C.tr_t
    i, tc = segment(ts, ts[0] + t)
    h = ts[i + 1] - ts[i]
    u = (tc - ts[i]) / h
    Q, QD, QDD = C.tr_q, C.tr_qd, C.tr_qdd
    for j in range(Q.shape[1]):
        if u <= 0.5:
            C.q_ref[j], C.qd_ref[j] = hermite(Q[i, j], QD[i, j], QDD[i, j], Q[i + 1, j], QD[i + 1, j],
                                              QDD[i + 1, j], u, h)
        else:
            q, qd = hermite(Q[i + 1, j], -QD[i + 1, j], QDD[i + 1, j], Q[i, j], -QD[i, j], QDD[i, j], 1.0 - u, h)
            C.q_ref[j], C.qd_ref[j] = q, -qd


@kernel
def time_law(kind, u):
    """(s, ds/du, d²s/du²) of the normalised time law (`coopsim.inverse.trajectory.time_law`).

    Args:
        kind: LAW_QUINTIC, or LAW_CUBIC (any other code: cubic).
        u: the normalised time in [0, 1].

    Returns:
        tuple[float, float, float]: s(u) ∈ [0, 1] and its first two derivatives in u.
    """
    if kind == LAW_QUINTIC:
        return (10 * u ** 3 - 15 * u ** 4 + 6 * u ** 5, 30 * u ** 2 - 60 * u ** 3 + 30 * u ** 4,
                60 * u - 180 * u ** 2 + 120 * u ** 3)
    return 3 * u ** 2 - 2 * u ** 3, 6 * u - 6 * u ** 2, 6 - 12 * u


@kernel
def object_reference(C, t, R):
    """The prescribed object state at om_t[0] + t (`coopsim.inverse.trajectory.object_motion_at`).

    Args:
        C: the controller (PackedControl StructRef): reads the om_* tables and time_law; writes C.p_r
            (3,) m (world), C.v_r = [v_C; ω] and C.a_r = [a_C; ω̇] (6,) (world axes), C.R3b scratch.
        t: s, the time since the start of the run.
        R: (3, 3) written: the prescribed orientation of the object frame, world axes.
    """
    ts = C.om_t
    i, tc = segment(ts, ts[0] + t)
    T = ts[i + 1] - ts[i]
    s, ds, dds = time_law(C.time_law, (tc - ts[i]) / T)
    if C.om_angle[i] > 0:
        axis_rotation(C.om_axis[i], s * C.om_angle[i], C.R3b)
        matmul3(C.om_R[i], C.R3b, R)
    else:
        for a in range(3):
            for b in range(3):
                R[a, b] = C.om_R[i, a, b]
    for a in range(3):
        dp = C.om_p[i + 1, a] - C.om_p[i, a]
        C.v_r[a], C.v_r[3 + a] = ds / T * dp, ds / T * C.om_w[i, a]
        C.a_r[a], C.a_r[3 + a] = dds / T ** 2 * dp, dds / T ** 2 * C.om_w[i, a]
        C.p_r[a] = C.om_p[i, a] + s * dp


# ------------------------------------------------------------------------------------------------
# Closed-chain inverse dynamics with a distribution
# ------------------------------------------------------------------------------------------------

@kernel
def grasp_rows(P, W, C):
    """C.A ← [S W_m Sᵀ]_m (k, rk) and C.JT ← blockdiag((S J_m)ᵀ) (N, rk), with W_m = [[I, 0], [−[s_m×], I]].

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads the grasp offsets W.s and the
            Jacobians W.J of the current state.
        C: the controller (PackedControl StructRef): C.A and C.JT written, C.v6 scratch.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    for m in range(r):
        s = W.s[m]
        for b in range(k):
            # W_m Sᵀ e_b: the row b of S as a wrench [f; n], moved: n − s × f
            f0, f1, f2 = S[b, 0], S[b, 1], S[b, 2]
            C.v6[0], C.v6[1], C.v6[2] = f0, f1, f2
            C.v6[3] = S[b, 3] - (s[1] * f2 - s[2] * f1)
            C.v6[4] = S[b, 4] - (s[2] * f0 - s[0] * f2)
            C.v6[5] = S[b, 5] - (s[0] * f1 - s[1] * f0)
            for i in range(k):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * C.v6[a]
                C.A[i, m * k + b] = v
    for j in range(C.JT.shape[0]):
        for c in range(C.JT.shape[1]):
            C.JT[j, c] = 0.0
    for m in range(r):
        o, e = P.dof[m], P.dof[m + 1]
        for j in range(o, e):
            for i in range(k):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * W.J[m, a, j - o]
                C.JT[j, m * k + i] = v


@kernel
def paper_distribution(P, W, C):
    """C.f ← the paper's distribution f_m = S W(−s_m) Sᵀ y / r (eqs. 8, 30).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads the grasp offsets W.s.
        C: the controller (PackedControl StructRef): reads C.y (k,); C.f (rk,) written (N, N·m, in the
            rows S), C.v6 scratch.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    for a in range(6):
        v = 0.0
        for i in range(k):
            v += C.y[i] * S[i, a]
        C.v6[a] = v
    f0, f1, f2 = C.v6[0], C.v6[1], C.v6[2]
    for m in range(r):
        s = W.s[m]
        n0 = C.v6[3] + (s[1] * f2 - s[2] * f1)
        n1 = C.v6[4] + (s[2] * f0 - s[0] * f2)
        n2 = C.v6[5] + (s[0] * f1 - s[1] * f0)
        for i in range(k):
            v = S[i, 0] * f0 + S[i, 1] * f1 + S[i, 2] * f2 + S[i, 3] * n0 + S[i, 4] * n1 + S[i, 5] * n2
            C.f[m * k + i] = v / r


@kernel
def nonsqueezing_distribution(P, W, C):
    """C.f ← the non-squeezing distribution M*Aᵀ (A M*Aᵀ)⁻¹ y (Erhart & Hirche).

    M* = blockdiag(S diag(m_i* I₃, R_o J_i* R_oᵀ) Sᵀ) of the virtual bodies (C.vmass, C.vinertia).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.R_o; W.m3[0] is scratch.
        C: the controller (PackedControl StructRef): reads C.A and C.y; C.f (rk,) written; C.MA, C.G,
            C.xk, C.x, C.v6, C.v3 and C.R3b scratch.

    Returns:
        bool: False when A M*Aᵀ is singular (a zero pivot; C.f not written), else True.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    B = W.m3[0]
    for m in range(r):
        matmul3(W.R_o, C.vinertia[m], C.R3b)
        matmul3_T(C.R3b, W.R_o, B)
        for b in range(k):             # column b of the block times Aᵀ: M*_m A_mᵀ (k, k)
            for a in range(6):
                v = 0.0
                for i in range(k):     # (Sᵀ A_mᵀ)[a, b] = Σ_i S[i, a] A[b, m k + i]
                    v += S[i, a] * C.A[b, m * k + i]
                C.v6[a] = v
            for a in range(3):
                C.v3[a] = B[a, 0] * C.v6[3] + B[a, 1] * C.v6[4] + B[a, 2] * C.v6[5]
            for i in range(k):
                C.MA[m * k + i, b] = (C.vmass[m] * (S[i, 0] * C.v6[0] + S[i, 1] * C.v6[1] + S[i, 2] * C.v6[2])
                                      + S[i, 3] * C.v3[0] + S[i, 4] * C.v3[1] + S[i, 5] * C.v3[2])
    for i in range(k):
        C.xk[i] = C.y[i]
    if not gram_solve(C, k):
        return False
    for c in range(r * k):
        C.f[c] = C.x[c]
    return True


@kernel
def min_energy_distribution(C, k):
    """C.f ← argmin ½ τᵀQτ, τ = τ_arms + Jᵀf, subject to A f = y (eqs. 33–35).

    By the KKT system [J Q Jᵀ, Aᵀ; A, 0][f; λ] = [−J Q τ_arms; y], Gaussian elimination with partial
    pivoting.

    Args:
        C: the controller (PackedControl StructRef): reads C.JT, C.weights (Q), C.tau_arms, C.A and C.y;
            C.f (rk,) written; C.kkt and C.x scratch.
        k: rows per grasp.

    Returns:
        bool: False when the KKT system is singular (a zero pivot; C.f not written), else True.
    """
    N, mk = C.JT.shape
    K = C.kkt
    Q = C.weights
    for p in range(mk):
        v = 0.0
        for j in range(N):
            v -= C.JT[j, p] * Q[j] * C.tau_arms[j]
        C.x[p] = v
        for c in range(p, mk):
            v = 0.0
            for j in range(N):
                v += C.JT[j, p] * Q[j] * C.JT[j, c]
            K[p, c], K[c, p] = v, v
        for i in range(k):
            K[mk + i, p], K[p, mk + i] = C.A[i, p], C.A[i, p]
    for i in range(k):
        C.x[mk + i] = C.y[i]
        for c in range(k):
            K[mk + i, mk + c] = 0.0
    if gauss_solve(K, mk + k, C.x) == 0.0:
        return False
    for p in range(mk):
        C.f[p] = C.x[p]
    return True


@kernel
def squeeze_wrenches(P, W, C, force):
    """C.f += the squeeze wrenches, projected on the null space of A (internal forces only).

    Each grasp pushes `force` N towards C along its grasp line (ρ_m = −s_m), F_m = S [−force ρ_m/|ρ_m|; 0],
    projected as F − Aᵀ(AAᵀ)⁻¹A F (`coopsim.control.laws.squeeze_wrenches`).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads the grasp offsets W.s.
        C: the controller (PackedControl StructRef): reads C.A; C.f (rk,) added to; C.fs, C.MA, C.xk, C.G
            and C.x scratch.
        force: N, the squeeze force per grasp.

    Returns:
        bool: False when A Aᵀ is singular (a zero pivot; C.f unchanged), else True.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    for m in range(r):
        s = W.s[m]
        nrm = np.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
        d = nrm if nrm > 0 else 1.0
        for i in range(k):
            C.fs[m * k + i] = -force * (S[i, 0] * -s[0] + S[i, 1] * -s[1] + S[i, 2] * -s[2]) / d
    for i in range(k):
        v = 0.0
        for c in range(r * k):
            v += C.A[i, c] * C.fs[c]
            C.MA[c, i] = C.A[i, c]
        C.xk[i] = v
    if not gram_solve(C, k):
        return False
    for c in range(r * k):
        C.f[c] += C.fs[c] - C.x[c]
    return True


@kernel
def state_terms(P, W, C, q, qd):
    """The arm and object terms of (θ, θ̇) into W, the arms' own mass-matrix blocks kept in C.Mb.

    `arm_terms`, `object_pose` and `object_dynamics`; C.Mb is copied before object_dynamics adds the
    object's inertia to the carrier's block.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): the arm and object terms written.
        C: the controller (PackedControl StructRef): C.Mb (N, nmax) written.
        q: (N,) rad or m, the joint coordinates θ.
        qd: (N,) rad/s or m/s, the joint rates θ̇.
    """
    arm_terms(P, W, q, qd)
    copy2(W.Mb, C.Mb)
    object_pose(P, W)
    object_dynamics(P, W, qd)


@kernel
def inverse_torques(P, W, C, qdd, squeeze, tau):
    """τ ← the closed-chain inverse dynamics at (θ, θ̇, θ̈ = qdd), the object's wrench distributed by C.distribution.

    τ = τ_arms + Jᵀ f with A f = y (module docstring), plus a squeeze when `squeeze` ≠ 0. W and C.Mb
    hold the terms of (θ, θ̇) (`state_terms`).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef) with the terms of (θ, θ̇), read.
        C: the controller (PackedControl StructRef): C.tau_arms, C.acc, C.Y, C.y, C.A, C.JT, C.f and the
            distribution's scratch written.
        qdd: (N,) rad/s² (m/s²), the joint accelerations θ̈.
        squeeze: N, the squeeze force (0: none).
        tau: (N,) written: N·m (N on a prismatic joint); left unchanged on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    S = P.rows
    k = S.shape[0]
    for m in range(len(P.dof) - 1):
        o, e = P.dof[m], P.dof[m + 1]
        for j in range(o, e):
            v = W.h_arm[j]
            for l in range(o, e):
                v += C.Mb[j, l - o] * qdd[l]
            C.tau_arms[j] = v
    object_acceleration(P, W, qdd, C.acc)
    object_wrench(P, W, C.acc, C.Y)
    for i in range(k):
        v = 0.0
        for a in range(6):
            v += C.Y[a] * S[i, a]
        C.y[i] = v
    grasp_rows(P, W, C)
    if C.distribution == DIST_PAPER:
        paper_distribution(P, W, C)
        ok = True
    elif C.distribution == DIST_NONSQUEEZING:
        ok = nonsqueezing_distribution(P, W, C)
    else:
        ok = min_energy_distribution(C, k)
    if ok and squeeze != 0.0:
        ok = squeeze_wrenches(P, W, C, squeeze)
    if not ok:
        return CONTROL_SINGULAR
    for j in range(len(tau)):
        v = 0.0
        for c in range(C.JT.shape[1]):
            v += C.JT[j, c] * C.f[c]
        tau[j] = C.tau_arms[j] + v
    return OK


# ------------------------------------------------------------------------------------------------
# The laws
# ------------------------------------------------------------------------------------------------

@kernel
def joint_pd(P, W, C, t, q, qd, u):
    """u ← Kp (θ_r − θ) + Kd (θ̇_r − θ̇) + τ_comp (module docstring).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten when there is a compensation.
        C: the controller (PackedControl StructRef): C.q_ref, C.qd_ref written, and with a compensation
            C.tau_c and the inverse dynamics' scratch.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) written: the command, N·m (N on a prismatic joint); not meaningful on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    joint_reference(C, t)
    for j in range(len(u)):
        u[j] = C.kp[j] * (C.q_ref[j] - q[j]) + C.kd[j] * (C.qd_ref[j] - qd[j])
    if C.compensation == COMP_NONE:
        return OK
    state_terms(P, W, C, q, qd if C.compensation == COMP_BIAS else C.zero)
    st = inverse_torques(P, W, C, C.zero, 0.0, C.tau_c)
    for j in range(len(u)):
        u[j] = u[j] + C.tau_c[j]
    return st


@kernel
def object_errors(P, W, C, t):
    """The object's pose and twist errors against the prescribed motion at t, and the commanded acceleration.

    C.err = [p_r − p; log(R_r Rᵀ)], C.rate_err = v_r − v and C.a = a_r + Kd ė + Kp e; W holds the object
    terms of (θ, θ̇).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.p_C, W.R_o and W.v_o.
        C: the controller (PackedControl StructRef): C.err [m; rad], C.rate_err [m/s; rad/s] and C.a
            [m/s²; rad/s²] (6,) written, world axes; C.p_r, C.v_r, C.a_r, C.R3, C.R3b, C.v3 scratch.
        t: s, the time since the start of the run.
    """
    object_reference(C, t, C.R3)
    for a in range(3):
        C.err[a] = C.p_r[a] - W.p_C[a]
    matmul3_T(C.R3, W.R_o, C.R3b)
    rot_log(C.R3b, C.v3)
    for a in range(3):
        C.err[3 + a] = C.v3[a]
    for a in range(6):
        C.rate_err[a] = C.v_r[a] - W.v_o[a]
        g = 0 if a < 3 else 1
        C.a[a] = C.a_r[a] + C.okd[g] * C.rate_err[a] + C.okp[g] * C.err[a]


@kernel
def arm_accelerations(P, W, C):
    """C.qdd ← each arm's θ̈_m from S J_m θ̈_m = S (a_EE,m − J̇_mθ̇_m) for the object acceleration C.a.

    a_EE,m = [a_C + ω̇ × ρ_m + ω × (ω × ρ_m); ω̇] at the object twist W.v_o (ρ_m = −s_m). S J_m must be
    square (k = n_m).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.v_o, W.s, W.J and W.Jd_qd.
        C: the controller (PackedControl StructRef): reads C.a; C.qdd (N,) rad/s² written; C.v3, C.v6,
            C.xk and C.G scratch.

    Returns:
        bool: False when an arm's S J_m is singular (a zero pivot), else True.
    """
    S = P.rows
    k = S.shape[0]
    w, dw = W.v_o[3:], C.a[3:]
    for m in range(len(P.dof) - 1):
        o = P.dof[m]
        for a in range(3):
            C.v3[a] = -W.s[m, a]
        rigid_point_acceleration(C.a[:3], w, dw, C.v3, C.v6[:3])
        for a in range(3):
            C.v6[3 + a] = dw[a]
        for i in range(k):
            v = 0.0
            for a in range(6):
                v += S[i, a] * (C.v6[a] - W.Jd_qd[m, a])
            C.xk[i] = v
            for j in range(k):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * W.J[m, a, j]
                C.G[i, j] = v
        if gauss_solve(C.G, k, C.xk) == 0.0:
            return False
        for j in range(k):
            C.qdd[o + j] = C.xk[j]
    return True


@kernel
def computed_torque(P, W, C, t, q, qd, u):
    """u ← the object-space computed torque (module docstring), with the grasp feedback added.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten with the terms of (θ, θ̇).
        C: the controller (PackedControl StructRef): C.err, C.rate_err, C.gerr written, and the
            inverse dynamics' scratch.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) written: the command, N·m (N on a prismatic joint); not meaningful on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    state_terms(P, W, C, q, qd)
    object_errors(P, W, C, t)
    if not arm_accelerations(P, W, C):
        return CONTROL_SINGULAR
    st = inverse_torques(P, W, C, C.qdd, C.squeeze, u)
    grasp_feedback(P, W, C, qd, u)
    return st


@kernel
def grasp_feedback(P, W, C, qd, u):
    """u += J_mᵀ Sᵀ S (Kp e_m + Kd ė_m) for every arm m (`coopsim.control.laws.grasp_errors`).

    e_m = [p_t − p_EE; log(R_t R_EEᵀ)] is the pose error of its end effector against where its grasp
    puts it on the object (p_t = p_C + R_o g_m, R_t = R_o G_m), ė_m = [v_C + ω × R_o g_m; ω] − J_m θ̇_m
    the twist error; gains gkp, gkd (2,) [linear, angular]. W holds the terms of (θ, θ̇).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.R_o, W.p_C, W.v_o, W.p_ee, W.R_ee
            and W.J.
        C: the controller (PackedControl StructRef): C.gerr (r, 6) [m; rad] written, world axes; C.v3,
            C.v6, C.R3, C.R3b and C.xk scratch.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) N·m (N on a prismatic joint), added to.
    """
    S = P.rows
    k = S.shape[0]
    w = W.v_o[3:]
    for m in range(len(P.dof) - 1):
        o, e = P.dof[m], P.dof[m + 1]
        for a in range(3):
            g = P.grasp_pos[m]
            C.v3[a] = W.R_o[a, 0] * g[0] + W.R_o[a, 1] * g[1] + W.R_o[a, 2] * g[2]
        matmul3(W.R_o, P.grasp_rot[m], C.R3)
        matmul3_T(C.R3, W.R_ee[m], C.R3b)
        for a in range(3):
            C.gerr[m, a] = (W.p_C[a] + C.v3[a]) - W.p_ee[m, a]
        rot_log(C.R3b, C.gerr[m, 3:])
        rho = C.v3
        C.v6[0] = W.v_o[0] + (w[1] * rho[2] - w[2] * rho[1])
        C.v6[1] = W.v_o[1] + (w[2] * rho[0] - w[0] * rho[2])
        C.v6[2] = W.v_o[2] + (w[0] * rho[1] - w[1] * rho[0])
        for a in range(3):
            C.v6[3 + a] = w[a]
        for a in range(6):
            v = C.v6[a]
            for j in range(o, e):
                v -= W.J[m, a, j - o] * qd[j]
            g = 0 if a < 3 else 1
            C.v6[a] = C.gkp[g] * C.gerr[m, a] + C.gkd[g] * v
        for i in range(k):
            v = 0.0
            for a in range(6):
                v += S[i, a] * C.v6[a]
            C.xk[i] = v
        for j in range(o, e):
            v = 0.0
            for i in range(k):
                sj = 0.0
                for a in range(6):
                    sj += S[i, a] * W.J[m, a, j - o]
                v += sj * C.xk[i]
            u[j] += v


@kernel
def command(P, W, C, t, q, qd, u):
    """u ← the law's command at (t, θ, θ̇) on the controller's model (P, W).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): the law's references, errors and scratch written.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) written: the command, N·m (N on a prismatic joint); not meaningful on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    if C.law == JOINT_PD:
        return joint_pd(P, W, C, t, q, qd, u)
    return computed_torque(P, W, C, t, q, qd, u)


@kernel
def feedback(P, W, C, t, q, qd, tau):
    """τ ← the law's command plus the torque tables, clipped to the motor lines with `saturate`.

    The sum (C.raw) is clipped to τ_min(θ̇) ≤ τ ≤ τ_max(θ̇) of eq. 36 when C.saturate is set; the
    evaluation and its clipped joints are counted in C.count.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): C.u, C.raw and the law's outputs written, C.count
            incremented.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        tau: (N,) N·m (N on a prismatic joint): holds the torque tables at t on entry, overwritten
            with the controller's torque (not meaningful on CONTROL_SINGULAR).

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    st = command(P, W, C, t, q, qd, C.u)
    C.count[0] += 1
    clipped = 0
    for j in range(len(tau)):
        raw = C.u[j] + tau[j]
        C.raw[j] = raw
        if C.saturate:
            drop = C.slope[j] * qd[j]
            v = min(max(raw, -C.stall[j] - drop), C.stall[j] - drop)
            clipped += v != raw
            raw = v
        tau[j] = raw
    if clipped:
        C.count[1] += 1
        C.count[2] += clipped
    return st


@entry
def commands(P, W, C, t, Y, tables, raw, tau, q_ref, qd_ref, err, rate_err, status):
    """The controller at S samples, with what the law sets at each (`feedback`).

    q_ref, qd_ref, err and rate_err hold what the law sets and nan for the other law's.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): scratch, C.count incremented.
        t: (S,) s, the sample times since the start of the run.
        Y: (S, 2N) the states [θ; θ̇] (rad or m, rad/s or m/s).
        tables: (S, N) N·m, the torque tables at t.
        raw: (S, N) written: N·m, command plus tables before saturation.
        tau: (S, N) written: N·m, the torques (after saturation when C.saturate is set).
        q_ref, qd_ref: (S, N) written: the joint reference θ_r, θ̇_r (rad or m, per s).
        err, rate_err: (S, 6) written: the object pose and twist error [m; rad], [m/s; rad/s], world axes.
        status: (S,) int written: OK or CONTROL_SINGULAR per sample.
    """
    N = tables.shape[1]
    for i in range(len(t)):
        for j in range(N):
            tau[i, j] = tables[i, j]
        for a in range(6):
            C.err[a], C.rate_err[a] = np.nan, np.nan
        for j in range(N):
            C.q_ref[j], C.qd_ref[j] = np.nan, np.nan
        status[i] = feedback(P, W, C, t[i], Y[i, :N], Y[i, N:], tau[i])
        copy1(C.raw, raw[i])
        copy1(C.q_ref, q_ref[i])
        copy1(C.qd_ref, qd_ref[i])
        copy1(C.err, err[i])
        copy1(C.rate_err, rate_err[i])


@entry
def evaluate(P, W, C, t, y, tau):
    """τ ← the controller's torque at (t, y = [θ; θ̇]) for one state (`feedback`).

    For the MuJoCo twin's control callback.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): scratch, C.count incremented.
        t: s, the time since the start of the run.
        y: (2N,) the state [θ; θ̇] (rad or m, rad/s or m/s).
        tau: (N,) N·m (N on a prismatic joint): the torque tables at t on entry, overwritten with the
            controller's torque.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    N = len(tau)
    return feedback(P, W, C, t, y[:N], y[N:], tau)
