"""The prescribed object motion's state at a time, compiled: pose, twist and acceleration of the object
along waypoints at rest under a time law (quintic, cubic, linear, or a sampled law σ(t)), or along a B-spline
path (`coopsim.inverse.spline_path`) with the time law once over the whole span. The kernels of the
object-motion inverse kinematics (`coopsim.compiled.object_motion`) and of the computed-torque controller's
reference (`coopsim.compiled.control.references`, which may track a body point other than the frame's origin,
`body_point`); the references are `coopsim.inverse.trajectory.object_motion_at` and `body_point_state`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.compiled.linalg import bisect
from coopsim.compiled.spatial import axis_rotation, cross3, matmul3, rigid_point_acceleration, rot_log
from coopsim.compiled.toolchain.jit import kernel

QUINTIC, CUBIC, SAMPLED, LINEAR = 0, 1, 2, 3
LAWS = {"quintic": QUINTIC, "cubic": CUBIC, "sampled": SAMPLED, "linear": LINEAR}
SMALL_ANGLE = 0.1   # rad: J_l's coefficients from their Taylor series below it (`coopsim.inverse.spline_path`'s)


class Motion(NamedTuple):
    """The prescribed object motion and the redundancy resolution's settings, as the kernels take them.

    Attributes:
        times: (w,) s, waypoint times, strictly increasing.
        positions: (w, 3) m, the centre of mass C at the waypoints, world.
        rotations: (w, 3, 3) world ← object, at the waypoints.
        origin: (3,) m, world: the point positions are taken relative to (the first waypoint).
        law: QUINTIC, CUBIC, SAMPLED or LINEAR.
        rest: (N,) rad or m, the stacked rest posture of the redundant arms' null-space pull.
        gain: 1/s, the pull's gain.
        law_t: (K,) s, a SAMPLED law's sample times (`coopsim.core.model.SampledTimeLaw`; any two values
            otherwise).
        law_s: (K,) its path parameter σ at the samples (waypoint i at σ = i/(w − 1)).
        law_rate: (K,) 1/s, its σ̇ at the samples (σ̈ constant between them).
        pull: 1/s·s, the null-space pull per unit of the path parameter σ (rest_pull 'path': rest_gain × the
            motion's duration; the gain at time t is then pull · σ̇); 0: the constant gain `gain` (rest_pull
            'time').
        knots: (n + d + 1,) a B-spline path's clamped knot vector on [0, 1] (`coopsim.inverse.spline_path.knots`;
            empty for a waypoint path).
        ctrl: (n, 6) its control coefficients [p − origin (m); φ (rad)], world axes ((0, 6) for a waypoint path).
        degree: its degree d, 1 to 3 (0: a waypoint path, two waypoints otherwise).
        R0: (3, 3) the orientation φ is relative to, R = Exp(φ) R0 (the first waypoint's).
    """

    times: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    origin: np.ndarray
    law: int
    rest: np.ndarray
    gain: float
    law_t: np.ndarray
    law_s: np.ndarray
    law_rate: np.ndarray
    pull: float
    knots: np.ndarray
    ctrl: np.ndarray
    degree: int
    R0: np.ndarray


class Buffers(NamedTuple):
    """Scratch of one pass (N joints in all).

    Attributes:
        y: (N,) stacked joint coordinates being solved.
        qd, qdd: (N,) stacked rates of a right-hand side evaluation.
        pc: (3,) m, C relative to Motion.origin, world axes.
        Ro: (3, 3) world ← object.
        tw, ac: (6,) the object's twist [v_C; ω] and acceleration [a_C; ω̇], world axes.
        E: (3, 3) scratch.
        v: (3,) scratch.
        p, R, tw_m, ac_m: (3,), (3, 3), (6,), (6,): one arm's grasp target (`grasp_target`).
        e: (6,) a pose error.
        x: (n_red,) the redundant arms' coordinates, one after the other (a dense-output value).
        info: (3,) the square solve's diagnostics (`ik.solve`).
        det: (r,) det S J of each square arm at the previous sample.
        law: (2,) [σ̇ 1/s, σ̈ 1/s²] of the whole path's parameter σ ∈ [0, 1] at the object's time.
    """

    y: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    pc: np.ndarray
    Ro: np.ndarray
    tw: np.ndarray
    ac: np.ndarray
    E: np.ndarray
    v: np.ndarray
    p: np.ndarray
    R: np.ndarray
    tw_m: np.ndarray
    ac_m: np.ndarray
    e: np.ndarray
    x: np.ndarray
    info: np.ndarray
    det: np.ndarray
    law: np.ndarray


def buffers(n: int, n_red: int, r: int) -> Buffers:
    """Fresh scratch for a model of n joints in all, n_red of them in redundant arms, and r arms.

    Args:
        n: the stacked joint count N.
        n_red: the redundant arms' joints, in all.
        r: the number of arms.

    Returns:
        Buffers: zeros, float64 C-contiguous.
    """
    z = np.zeros
    return Buffers(z(n), z(n), z(n), z(3), z((3, 3)), z(6), z(6), z((3, 3)), z(3), z(3), z((3, 3)), z(6), z(6),
                   z(6), z(n_red), z(3), z(r), z(2))


@kernel
def time_law(law, u):
    """(s, ds/du, d²s/du²) of the normalised time law at u ∈ [0, 1] (`coopsim.inverse.trajectory.time_law`).

    Args:
        law: QUINTIC (s = 10u³ − 15u⁴ + 6u⁵), CUBIC (s = 3u² − 2u³) or LINEAR (s = u).
        u: the normalised time (dimensionless).

    Returns:
        tuple[float, float, float]: s, ds/du and d²s/du².
    """
    if law == LINEAR:
        return u, 1.0, 0.0
    if law == QUINTIC:
        return (10 * u**3 - 15 * u**4 + 6 * u**5, 30 * u**2 - 60 * u**3 + 30 * u**4,
                60 * u - 180 * u**2 + 120 * u**3)
    return 3 * u**2 - 2 * u**3, 6 * u - 6 * u**2, 6 - 12 * u


@kernel
def segment_law(mo, i, t, T):
    """(s, ds/du, d²s/du²) on waypoint segment i (duration T s) at time t: the normalised law at
    u = (t − t_i)/T, or of a SAMPLED law σ(t) (`coopsim.inverse.trajectory.sampled_time_law_at`):
    s = (w − 1)σ − i, ds/du = (w − 1)σ̇T, d²s/du² = (w − 1)σ̈T².

    Args:
        mo: the Motion.
        i: the segment (waypoints i and i + 1).
        t: s, the time, within the waypoints' span.
        T: s, the segment's duration.

    Returns:
        tuple[float, float, float]: s, ds/du and d²s/du².
    """
    if mo.law != SAMPLED:
        return time_law(mo.law, (t - mo.times[i]) / T)
    ts, K, w1 = mo.law_t, len(mo.law_t), len(mo.times) - 1
    tc = min(max(t, ts[0]), ts[K - 1])
    k = K - 2 if tc >= ts[K - 2] else bisect(ts, 0, K - 2, tc)
    tau = tc - ts[k]
    acc = (mo.law_rate[k + 1] - mo.law_rate[k]) / (ts[k + 1] - ts[k])
    sigma = mo.law_s[k] + mo.law_rate[k] * tau + 0.5 * acc * tau * tau
    return w1 * sigma - i, w1 * (mo.law_rate[k] + acc * tau) * T, w1 * acc * T**2


@kernel
def basis_derivatives(U, d, n, u, N):
    """The knot span of u and the clamped B-spline basis functions there with their first two derivatives.

    The Cox–de Boor triangle and its derivatives (Piegl & Tiller, The NURBS Book, A2.1 and A2.3):
    N[k, j] = dᵏB_{span−d+j}/duᵏ (u), k = 0, 1, 2, j = 0 … d (zero for k > d). The span is the i in
    [d, n) with U[i] <= u < U[i + 1], the last one at u >= U[n] and the first at u < U[d] (the end
    polynomials extended, as scipy's BSpline).

    Args:
        U: (n + d + 1,) the knot vector, non-decreasing.
        d: the degree, 1 to 3.
        n: the number of control coefficients.
        u: the parameter.
        N: (3, 4) written.

    Returns:
        int: the span.
    """
    span = n - 1 if u >= U[n] else (d if u < U[d] else bisect(U, d, n, u))
    ndu, left, right, a = np.zeros((4, 4)), np.zeros(4), np.zeros(4), np.zeros((2, 4))
    ndu[0, 0] = 1.0
    for j in range(1, d + 1):
        left[j], right[j] = u - U[span + 1 - j], U[span + j] - u
        saved = 0.0
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r]
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    N[:, :] = 0.0
    for j in range(d + 1):
        N[0, j] = ndu[j, d]
    for r in range(d + 1):
        s1, s2 = 0, 1
        a[0, 0] = 1.0
        for k in range(1, min(2, d) + 1):
            v, rk, pk = 0.0, r - k, d - k
            if r >= k:
                a[s2, 0] = a[s1, 0] / ndu[pk + 1, rk]
                v = a[s2, 0] * ndu[rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else d - r
            for j in range(j1, j2 + 1):
                a[s2, j] = (a[s1, j] - a[s1, j - 1]) / ndu[pk + 1, rk + j]
                v += a[s2, j] * ndu[rk + j, pk]
            if r <= pk:
                a[s2, k] = -a[s1, k - 1] / ndu[pk + 1, r]
                v += a[s2, k] * ndu[r, pk]
            N[k, r] = v
            s1, s2 = s2, s1
    f = float(d)
    for k in range(1, min(2, d) + 1):
        for j in range(d + 1):
            N[k, j] *= f
        f *= d - k
    return span


@kernel
def left_jacobian_coefficients(theta):
    """(A, B, A′/θ, B′/θ) of J_l(φ) = I + A[φ]× + B[φ]×² at θ = |φ| (`coopsim.inverse.spline_path`):
    A = (1 − cos θ)/θ², B = (θ − sin θ)/θ³ and their θ-derivatives over θ, from their Taylor series below
    SMALL_ANGLE.

    Args:
        theta: rad, |φ| >= 0.

    Returns:
        tuple[float, float, float, float]: A (1/rad²), B (1/rad³), A′/θ (1/rad⁴), B′/θ (1/rad⁵).
    """
    if theta < SMALL_ANGLE:
        t2 = theta * theta
        return (1 / 2 - t2 / 24 + t2**2 / 720 - t2**3 / 40320, 1 / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880,
                -1 / 12 + t2 / 180 - t2**2 / 6720 + t2**3 / 453600,
                -1 / 60 + t2 / 1260 - t2**2 / 60480 + t2**3 / 4989600)
    s, c = np.sin(theta), np.cos(theta)
    return ((1 - c) / theta**2, (theta - s) / theta**3, s / theta**3 - 2 * (1 - c) / theta**4,
            (1 - c) / theta**4 - 3 * (theta - s) / theta**5)


@kernel
def spline_state(mo, s, ds, dds, B):
    """The object on mo's B-spline path at s with ṡ = ds, s̈ = dds: B.pc, B.Ro, B.tw, B.ac
    (`coopsim.inverse.spline_path.spline_state`).

    [p − origin, φ] and their s-derivatives from the basis (`basis_derivatives`), R = Exp(φ) R0,
    ω′ = J_l(φ) φ′, ω″ = J_l(φ) φ″ + A′/θ (φ·φ′) φ × φ′ + B′/θ (φ·φ′) φ × (φ × φ′) + B φ′ × (φ × φ′);
    v = p′ṡ, a = p″ṡ² + p′s̈, ω = ω′ṡ, ω̇ = ω″ṡ² + ω′s̈.

    Args:
        mo: the Motion (knots, ctrl, degree, R0).
        s: the path parameter (in [0, 1]).
        ds: 1/s, ṡ.
        dds: 1/s², s̈.
        B: the Buffers: pc (m, relative to mo.origin), Ro, tw, ac written (world axes); E, v scratch.
    """
    d, n = mo.degree, mo.ctrl.shape[0]
    N, V = np.empty((3, 4)), np.zeros((3, 6))
    span = basis_derivatives(mo.knots, d, n, s, N)
    for k in range(3):
        for j in range(d + 1):
            for c in range(6):
                V[k, c] += N[k, j] * mo.ctrl[span - d + j, c]
    phi = B.v
    for a in range(3):
        phi[a] = V[0, 3 + a]
    angle = np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    if angle > 0:
        ax = np.empty(3)
        for a in range(3):
            ax[a] = phi[a] / angle
        axis_rotation(ax, angle, B.E)
        matmul3(B.E, mo.R0, B.Ro)
    else:
        B.Ro[:, :] = mo.R0
    A, Bc, a1, b1 = left_jacobian_coefficients(angle)
    f0, f1, f2 = phi[0], phi[1], phi[2]
    d0, d1, d2 = V[1, 3], V[1, 4], V[1, 5]
    pd0, pd1, pd2 = cross3(f0, f1, f2, d0, d1, d2)
    q0, q1, q2 = cross3(f0, f1, f2, pd0, pd1, pd2)
    w0, w1, w2 = d0 + A * pd0 + Bc * q0, d1 + A * pd1 + Bc * q1, d2 + A * pd2 + Bc * q2
    e0, e1, e2 = V[2, 3], V[2, 4], V[2, 5]
    u0, u1, u2 = cross3(f0, f1, f2, e0, e1, e2)
    v0, v1, v2 = cross3(f0, f1, f2, u0, u1, u2)
    dot = f0 * d0 + f1 * d1 + f2 * d2
    x0, x1, x2 = cross3(d0, d1, d2, pd0, pd1, pd2)
    dw, ddw = (w0, w1, w2), (e0 + A * u0 + Bc * v0 + a1 * dot * pd0 + b1 * dot * q0 + Bc * x0,
                             e1 + A * u1 + Bc * v1 + a1 * dot * pd1 + b1 * dot * q1 + Bc * x1,
                             e2 + A * u2 + Bc * v2 + a1 * dot * pd2 + b1 * dot * q2 + Bc * x2)
    for a in range(3):
        B.pc[a] = V[0, a]
        B.tw[a], B.tw[3 + a] = ds * V[1, a], ds * dw[a]
        B.ac[a] = ds * ds * V[2, a] + dds * V[1, a]
        B.ac[3 + a] = ds * ds * ddw[a] + dds * dw[a]


@kernel
def object_state(mo, t, B):
    """The object at time t (clamped to the waypoints): B.pc, B.Ro, B.tw, B.ac.

    On segment [t_a, t_b], u = (t − t_a)/T: p = (p_a − origin) + s(u)(p_b − p_a), R = R_a Exp(s(u) φ) with
    φ = log(R_aᵀ R_b), v = (ṡ/T)(p_b − p_a), ω = (ṡ/T) R_a φ, a = (s̈/T²)(p_b − p_a), ω̇ = (s̈/T²) R_a φ.
    A B-spline path (mo.degree > 0): the time law once over the whole span T, `spline_state` at s(u)
    with ṡ/T and s̈/T² (`coopsim.inverse.trajectory.object_motion_at`).

    Args:
        mo: the Motion.
        t: s, the time.
        B: the Buffers: pc (m, relative to mo.origin), Ro, tw, ac written (world axes), law [σ̇, σ̈]; E, v
            scratch.
    """
    ts, P, Rs = mo.times, mo.positions, mo.rotations
    w = len(ts)
    t = min(max(t, ts[0]), ts[w - 1])
    if mo.degree > 0:
        T = ts[w - 1] - ts[0]
        s, ds, dds = segment_law(mo, 0, t, T)
        B.law[0], B.law[1] = ds / T, dds / (T * T)
        spline_state(mo, s, ds / T, dds / T**2, B)
        return
    i = w - 2 if t >= ts[w - 2] else bisect(ts, 0, w - 2, t)
    T = ts[i + 1] - ts[i]
    s, ds, dds = segment_law(mo, i, t, T)
    B.law[0], B.law[1] = ds / (T * (w - 1)), dds / (T * T * (w - 1))
    Ra, Rb, E, phi = Rs[i], Rs[i + 1], B.E, B.v
    for a in range(3):
        for b in range(3):
            E[a, b] = Ra[0, a] * Rb[0, b] + Ra[1, a] * Rb[1, b] + Ra[2, a] * Rb[2, b]
    rot_log(E, phi)
    angle = np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    if angle > 0:
        ax = np.empty(3)
        for a in range(3):
            ax[a] = phi[a] / angle
        axis_rotation(ax, s * angle, E)
        matmul3(Ra, E, B.Ro)
    else:
        B.Ro[:, :] = Ra
    fv, fa = ds / T, dds / T**2
    for a in range(3):
        dp = P[i + 1, a] - P[i, a]
        wa = Ra[a, 0] * phi[0] + Ra[a, 1] * phi[1] + Ra[a, 2] * phi[2]
        B.tw[a], B.tw[3 + a] = fv * dp, fv * wa
        B.ac[a], B.ac[3 + a] = fa * dp, fa * wa
        B.pc[a] = (P[i, a] - mo.origin[a]) + s * dp


@kernel
def body_point(c, B):
    """B.pc, B.tw, B.ac ← the state of the object's body point c in place of its frame's origin
    (`coopsim.inverse.trajectory.body_point_state`): with r = R c (R = B.Ro), p + r, v + ω × r and
    a + ω̇ × r + ω × (ω × r); R, ω and ω̇ unchanged.

    Args:
        c: (3,) m, the point, object frame (zero: the origin itself, every value unchanged).
        B: the Buffers as `object_state` wrote them: pc, tw[:3] and ac[:3] updated; v scratch.
    """
    r, R = B.v, B.Ro
    for a in range(3):
        r[a] = R[a, 0] * c[0] + R[a, 1] * c[1] + R[a, 2] * c[2]
    w0, w1, w2 = cross3(B.tw[3], B.tw[4], B.tw[5], r[0], r[1], r[2])
    rigid_point_acceleration(B.ac[:3], B.tw[3:], B.ac[3:], r, B.ac[:3])
    B.tw[0], B.tw[1], B.tw[2] = B.tw[0] + w0, B.tw[1] + w1, B.tw[2] + w2
    for a in range(3):
        B.pc[a] += r[a]
