"""The compiled controller's record: PackedControl (gains, references, the distribution's data and
the scratch every evaluation writes), its StructRef type and constructors, and the codes of its laws,
references, compensations and distributions (`coopsim.core.model`'s control vocabulary, as integers).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numba.experimental import structref

from coopsim.compiled.object_state import CUBIC, QUINTIC
from coopsim.compiled.structs import _F, _I, StructType, _f1, _f2, _f3, _i1

JOINT_PD, COMPUTED_TORQUE = 0, 1
COMP_NONE, COMP_GRAVITY, COMP_BIAS = 0, 1, 2
REF_SETPOINT, REF_TRAJECTORY = 0, 1
DIST_PAPER, DIST_NONSQUEEZING, DIST_MIN_ENERGY = 0, 1, 2
LAW_QUINTIC, LAW_CUBIC = QUINTIC, CUBIC          # the object motion's law codes (`coopsim.compiled.object_state`)
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
        time_law: the object motion's time law, `coopsim.compiled.object_state`'s code (QUINTIC, CUBIC, SAMPLED,
            LINEAR).
        kp, kd: (N,) joint PD gains, N·m/rad and N·m·s/rad (N/m and N·s/m on a prismatic joint).
        q_set: (N,) rad or m, the joint set-point.
        tr_t: (M,) s, the joint trajectory's times, read at tr_t[0] + t.
        tr_q, tr_qd, tr_qdd: (M, N) the joint trajectory's θ (rad or m), θ̇ and θ̈ at tr_t.
        okp, okd: (2,) object-space gains [linear, angular], 1/s² and 1/s (commanded object acceleration
            per unit pose and twist error).
        om_t: (w,) s, the object motion's waypoint times, read at om_t[0] + t.
        om_p: (w, 3) m, the waypoint positions of C, world.
        om_R: (w, 3, 3) the waypoint orientations of the object frame, world axes.
        om_origin, om_law_t, om_law_s, om_law_rate, om_knots, om_ctrl, om_degree, om_R0: the rest of the object
            motion as `coopsim.compiled.object_state.Motion` holds it (origin = the first waypoint's position;
            a sampled time law's samples; a B-spline path's knots, coefficients, degree (0: waypoints) and
            reference orientation), read by `coopsim.compiled.control.references.object_reference`.
        om_point: (3,) m, object axes: the body point the prescribed motion is moved to, where the plant's
            object frame sits relative to the motion's point (`Controller`'s point; zero: the motion's own).
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
        ob_pc, ob_v: (3,) scratch of the object motion's state (`coopsim.compiled.object_state.Buffers`).
        ob_tw, ob_ac: (6,) scratch, likewise.
        ob_law: (2,) scratch, likewise.
        ob_Ro, ob_E: (3, 3) scratch, likewise.
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
    om_origin: np.ndarray
    om_law_t: np.ndarray
    om_law_s: np.ndarray
    om_law_rate: np.ndarray
    om_knots: np.ndarray
    om_ctrl: np.ndarray
    om_degree: int
    om_R0: np.ndarray
    om_point: np.ndarray
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
    ob_pc: np.ndarray
    ob_v: np.ndarray
    ob_tw: np.ndarray
    ob_ac: np.ndarray
    ob_law: np.ndarray
    ob_Ro: np.ndarray
    ob_E: np.ndarray


_TYPES = {"law": _I, "compensation": _I, "reference": _I, "distribution": _I, "saturate": _I, "time_law": _I,
          "squeeze": _F, "count": _i1, "tr_q": _f2, "tr_qd": _f2, "tr_qdd": _f2, "om_p": _f2, "om_R": _f3,
          "om_ctrl": _f2, "om_degree": _I, "om_R0": _f2, "ob_Ro": _f2, "ob_E": _f2, "vinertia": _f3, "A": _f2, "JT": _f2, "kkt": _f2, "MA": _f2, "G": _f2,
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
    s.om_origin = r.om_origin
    s.om_law_t = r.om_law_t
    s.om_law_s = r.om_law_s
    s.om_law_rate = r.om_law_rate
    s.om_knots = r.om_knots
    s.om_ctrl = r.om_ctrl
    s.om_degree = r.om_degree
    s.om_R0 = r.om_R0
    s.om_point = r.om_point
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
    s.ob_pc = r.ob_pc
    s.ob_v = r.ob_v
    s.ob_tw = r.ob_tw
    s.ob_ac = r.ob_ac
    s.ob_law = r.ob_law
    s.ob_Ro = r.ob_Ro
    s.ob_E = r.ob_E
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
                om_R=np.tile(np.eye(3), (2, 1, 1)), om_origin=z(3), om_law_t=np.array([0.0, 1.0]), om_law_s=z(2),
                om_law_rate=z(2), om_knots=z(0), om_ctrl=z((0, 6)), om_degree=0, om_R0=np.eye(3), om_point=z(3),
                squeeze=0.0, gkp=z(2), gkd=z(2), weights=np.ones(N), vmass=np.ones(r),
                vinertia=np.tile(np.eye(3), (r, 1, 1)), stall=np.full(N, np.inf), slope=z(N))
    base.update(fields)
    scratch = dict(count=np.zeros(3, dtype=np.int64), q_ref=z(N), qd_ref=z(N), err=z(6), rate_err=z(6), u=z(N),
                   raw=z(N), zero=z(N), qdd=z(N), tau_arms=z(N), tau_c=z(N), Mb=z((N, nmax)), gerr=z((r, 6)),
                   p_r=z(3), v_r=z(6), a_r=z(6), a=z(6), acc=z(6), Y=z(6), v6=z(6), v3=z(3), A=z((k, m)),
                   JT=z((N, m)), f=z(m), fs=z(m), y=z(k), kkt=z((m + k, m + k)), x=z(m + k), MA=z((m, k)),
                   G=z((k, k)), xk=z(k), R3=z((3, 3)), R3b=z((3, 3)), ob_pc=z(3), ob_v=z(3), ob_tw=z(6), ob_ac=z(6),
                   ob_law=z(2), ob_Ro=z((3, 3)), ob_E=z((3, 3)))
    out = {}
    for name in PackedControl._fields:
        v = base[name] if name in base else scratch[name]
        typ = _TYPES.get(name, _f1)
        out[name] = int(v) if typ is _I else float(v) if typ is _F else np.ascontiguousarray(
            v, dtype=np.int64 if typ is _i1 else np.float64)
    return PackedControl(**out)
