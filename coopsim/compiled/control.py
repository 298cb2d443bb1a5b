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

from coopsim.compiled.chain import OK, arm_terms, object_dynamics, object_pose
from coopsim.compiled.toolchain.jit import entry, kernel
from coopsim.compiled.linalg import bisect, copy1, copy2, gauss_solve
from coopsim.compiled.sample import object_acceleration, object_wrench
from coopsim.compiled.spatial import axis_rotation, matmul3, matmul3_T, rot_log
from coopsim.compiled.structs import _F, _I, _f1, _f2, _f3, _i1, StructType

JOINT_PD, COMPUTED_TORQUE = 0, 1
COMP_NONE, COMP_GRAVITY, COMP_BIAS = 0, 1, 2
REF_SETPOINT, REF_TRAJECTORY = 0, 1
DIST_PAPER, DIST_NONSQUEEZING, DIST_MIN_ENERGY = 0, 1, 2
LAW_QUINTIC, LAW_CUBIC = 0, 1
CONTROL_SINGULAR = 8      # a failure code of the time loop (after integrate's and manifold's)


class PackedControl(NamedTuple):
    """A controller for the kernels (N joints, r arms, k rows per grasp, m = rk grasp-wrench unknowns).
    Codes: law (JOINT_PD | COMPUTED_TORQUE), compensation (COMP_*), reference (REF_*),
    distribution (DIST_*), saturate (0/1), time_law (LAW_*).
    Joint PD: kp, kd (N,); q_set (N,) rad; joint trajectory tr_t (M,) s, tr_q, tr_qd, tr_qdd (M, N),
    read at tr_t[0] + t. Computed torque: okp, okd (2,) [linear, angular]; object motion om_t (w,) s,
    om_p (w, 3) m, om_R (w, 3, 3), per segment om_axis (w−1, 3) unit rotation axis (object axes of the
    segment start), om_angle (w−1,) rad, om_w (w−1, 3) = R_a φ; squeeze N; grasp-error gains gkp, gkd
    (2,) [linear N/m, angular N·m/rad], [N·s/m, N·m·s/rad]. Distribution: weights (N,) diagonal of Q;
    vmass (r,) kg and vinertia (r, 3, 3) object axes, the non-squeezing virtual bodies. Motor lines:
    stall (N,) N·m, slope (N,) N·m·s/rad (0 for a flat or absent line).
    Out: count (3,) int [evaluations, evaluations with a clipped joint, clipped (evaluation, joint)
    pairs]; q_ref, qd_ref (N,); err, rate_err (6,) object pose and twist error [m; rad], [m/s; rad/s];
    u (N,) the law's command; raw (N,) with the tables added; gerr (r, 6) each arm's grasp error
    [m; rad] (`grasp_feedback`).
    Scratch: zero, qdd, tau_arms, tau_c (N,); Mb (N, nmax) the arms' mass-matrix blocks (no object);
    p_r (3,), v_r, a_r, a, acc, Y, v6 (6,), v3 (3,); A (k, m); JT (N, m);
    f, fs (m,); y (k,); kkt (m+k, m+k), x (m+k,); MA (m, k); G (k, k); xk (k,); R3, R3b (3, 3)."""

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
    """The StructRef of a PackedControl (sharing its arrays)."""
    return _new_control(C)


def new_control(N: int, r: int, k: int, nmax: int, law: int, **fields) -> PackedControl:
    """A PackedControl of `law` for N joints, r arms (nmax joints in the longest), k rows with its scratch
    allocated; `fields` set the rest (absent ones: the first code, zero gains, two-sample tables)."""
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
    """C.x[:rk] ← MA (A MA)⁻¹ C.xk (C.MA (rk, k); C.G and C.xk overwritten). Returns False when A MA is
    singular."""
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
    """out (3,) ← a_O + ω̇ × r + ω × (ω × r) (`coopsim.core.spatial.rigid_acceleration`)."""
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
    """(i, t clamped): the interval [ts[i], ts[i+1]] holding t (clamped to the span), as
    clip(searchsorted(ts, t, 'right') − 1, 0, len(ts) − 2)."""
    t = min(max(t, ts[0]), ts[-1])
    return bisect(ts, 0, len(ts) - 1, t), t


@kernel
def hermite(p0, v0, a0, p1, v1, a1, u, h):
    """(θ, θ̇) at u of the quintic Hermite polynomial through (θ, θ̇, θ̈) = (p0, v0, a0) at u = 0 and
    (p1, v1, a1) at u = 1 over h s (`coopsim.inverse.trajectory.hermite_quintic`)."""
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
    """C.q_ref, C.qd_ref at time t: the set-point at rest, or the joint trajectory's quintic Hermite
    interpolant at tr_t[0] + t, evaluated from the nearer end of its interval."""
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
    """(s, ds/du, d²s/du²) of the normalised time law (`coopsim.inverse.trajectory.time_law`)."""
    if kind == LAW_QUINTIC:
        return (10 * u ** 3 - 15 * u ** 4 + 6 * u ** 5, 30 * u ** 2 - 60 * u ** 3 + 30 * u ** 4,
                60 * u - 180 * u ** 2 + 120 * u ** 3)
    return 3 * u ** 2 - 2 * u ** 3, 6 * u - 6 * u ** 2, 6 - 12 * u


@kernel
def object_reference(C, t, R):
    """The prescribed object state at om_t[0] + t (`coopsim.inverse.trajectory.object_motion_at`): C.p_r (3,),
    R (3, 3), C.v_r and C.a_r (6,) [linear; angular]."""
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
    """C.A (k, rk) = [S W_m Sᵀ]_m (W_m = [[I, 0], [−[s_m×], I]]) and C.JT (N, rk) = blockdiag((S J_m)ᵀ)."""
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
    """C.f ← f_m = S W(−s_m) Sᵀ y / r (eqs. 8, 30)."""
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
    """C.f ← M*Aᵀ (A M*Aᵀ)⁻¹ y, M* = blockdiag(S diag(m_i* I₃, R_o J_i* R_oᵀ) Sᵀ) (Erhart & Hirche).
    Returns False when A M*Aᵀ is singular."""
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
    """C.f ← argmin ½ τᵀQτ, τ = τ_arms + Jᵀf, s.t. A f = y: the KKT system [J Q Jᵀ, Aᵀ; A, 0][f; λ] =
    [−J Q τ_arms; y] (eqs. 33–35). Returns False when it is singular."""
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
    """C.f += the squeeze: each grasp pushes `force` N towards C along its grasp line (ρ_m = −s_m),
    F_m = S [−force ρ_m/|ρ_m|; 0], projected on the null space of A: F − Aᵀ(AAᵀ)⁻¹A F
    (`coopsim.control.laws.squeeze_wrenches`). Returns False when A Aᵀ is singular."""
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
    """The arm and object terms of (θ, θ̇) into W (`arm_terms`, `object_pose`, `object_dynamics`), the
    arms' own mass-matrix blocks kept in C.Mb (object_dynamics adds the object's to the carrier's)."""
    arm_terms(P, W, q, qd)
    copy2(W.Mb, C.Mb)
    object_pose(P, W)
    object_dynamics(P, W, qd)


@kernel
def inverse_torques(P, W, C, qdd, squeeze, tau):
    """τ (N,) ← the closed-chain inverse dynamics at (θ, θ̇, θ̈ = qdd) with the object's wrench
    distributed by C.distribution, plus a squeeze; W and C.Mb hold the terms of (θ, θ̇)
    (`state_terms`). Returns OK or CONTROL_SINGULAR."""
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
    """u ← Kp (θ_r − θ) + Kd (θ̇_r − θ̇) + τ_comp (module docstring). Returns OK or CONTROL_SINGULAR."""
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
    """C.err = [p_r − p; log(R_r Rᵀ)] and C.rate_err = v_r − v against the prescribed motion at t, and
    the commanded object acceleration C.a = a_r + Kd ė + Kp e; W holds the object terms of (θ, θ̇)."""
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
    """C.qdd: each arm's θ̈_m from S J_m θ̈_m = S (a_EE,m − J̇_mθ̇_m), a_EE,m = [a_C + ω̇ × ρ_m +
    ω × (ω × ρ_m); ω̇] for the object acceleration C.a at the twist W.v_o (ρ_m = −s_m). Returns False
    when an arm's S J_m is singular."""
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
    """u ← the object-space computed torque (module docstring). Returns OK or CONTROL_SINGULAR."""
    state_terms(P, W, C, q, qd)
    object_errors(P, W, C, t)
    if not arm_accelerations(P, W, C):
        return CONTROL_SINGULAR
    st = inverse_torques(P, W, C, C.qdd, C.squeeze, u)
    grasp_feedback(P, W, C, qd, u)
    return st


@kernel
def grasp_feedback(P, W, C, qd, u):
    """u += J_mᵀ Sᵀ S (Kp e_m + Kd ė_m) for every arm m (`coopsim.control.laws.grasp_errors`): e_m = [p_t − p_EE;
    log(R_t R_EEᵀ)] the pose error of its end effector against where its grasp puts it on the object
    (p_t = p_C + R_o g_m, R_t = R_o G_m), ė_m = [v_C + ω × R_o g_m; ω] − J_m θ̇_m the twist error; the
    errors are kept in C.gerr. Gains gkp, gkd (2,) [linear, angular]; W holds the terms of (θ, θ̇)."""
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
    """u (N,) ← the law's command at (t, θ, θ̇) on the controller's model (P, W). Returns OK or
    CONTROL_SINGULAR."""
    if C.law == JOINT_PD:
        return joint_pd(P, W, C, t, q, qd, u)
    return computed_torque(P, W, C, t, q, qd, u)


@kernel
def feedback(P, W, C, t, q, qd, tau):
    """τ (N,) (holding the torque tables at t) ← the law's command plus the tables (C.raw), clipped to
    the motor lines τ_min(θ̇) ≤ τ ≤ τ_max(θ̇) of eq. 36 with `saturate`; counted in C.count. Returns OK
    or CONTROL_SINGULAR."""
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
    """The controller at S samples (t (S,), Y (S, 2N) = [θ; θ̇], tables (S, N) the torque tables there):
    raw, tau (S, N) before and after saturation, q_ref, qd_ref (S, N), err, rate_err (S, 6) as the law
    sets them (nan for the other law's), status (S,)."""
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
    """τ (N,) (the torque tables at t on entry) ← the controller's torque at (t, y = [θ; θ̇]) (`feedback`),
    for one state (the MuJoCo twin's control callback). Returns OK or CONTROL_SINGULAR."""
    N = len(tau)
    return feedback(P, W, C, t, y[:N], y[N:], tau)
