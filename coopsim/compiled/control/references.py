"""The compiled controllers' references at time t: the joint trajectory's quintic Hermite interpolant
(`coopsim.inverse.trajectory.trajectory_at_times`) and the prescribed object motion with its time law
(`coopsim.inverse.trajectory.object_motion_at`; the kernel is the object-motion IK's own,
`coopsim.compiled.object_state.object_state`), at the tracked body point (`body_point`).
"""

from __future__ import annotations

from coopsim.compiled.control.record import REF_SETPOINT
from coopsim.compiled.linalg import bisect
from coopsim.compiled.object_state import Buffers, Motion, body_point, object_state
from coopsim.compiled.toolchain.jit import kernel


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
def object_reference(C, t, R):
    """The prescribed state of the tracked point at om_t[0] + t: `coopsim.compiled.object_state.object_state` of
    the motion the om_* fields hold (waypoints under a quintic, cubic or sampled time law, or a B-spline path),
    as `coopsim.inverse.trajectory.object_motion_at`, moved to the body point om_point (`body_point`, as
    `coopsim.inverse.trajectory.body_point_state`; zero: the motion's own point).

    Args:
        C: the controller (PackedControl StructRef): reads the om_* fields and time_law; writes C.p_r
            (3,) m (world), C.v_r = [v; ω] and C.a_r = [a; ω̇] (6,) of the point (world axes), the ob_*
            scratch.
        t: s, the time since the start of the run.
        R: (3, 3) written: the prescribed orientation of the object frame, world axes.
    """
    mo = Motion(C.om_t, C.om_p, C.om_R, C.om_origin, C.time_law, C.zero, 0.0, C.om_law_t, C.om_law_s,
                C.om_law_rate, 0.0, C.om_knots, C.om_ctrl, C.om_degree, C.om_R0)
    B = Buffers(C.zero, C.zero, C.zero, C.ob_pc, C.ob_Ro, C.ob_tw, C.ob_ac, C.ob_E, C.ob_v, C.v3, C.R3b, C.v6,
                C.v6, C.v6, C.zero, C.v3, C.zero, C.ob_law)
    object_state(mo, C.om_t[0] + t, B)
    body_point(C.om_point, B)
    for a in range(3):
        for b in range(3):
            R[a, b] = C.ob_Ro[a, b]
        C.p_r[a] = C.om_origin[a] + C.ob_pc[a]
    for a in range(6):
        C.v_r[a], C.a_r[a] = C.ob_tw[a], C.ob_ac[a]
