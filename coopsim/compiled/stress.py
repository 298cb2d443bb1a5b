"""Section loads of a box object along its grasp axis at every sample and cut, compiled: the same
Newton–Euler equations of the part x_a < ξ as the NumPy reference `coopsim.inverse.stress.section_loads`,
in the object frame (where the parts' inertias are diagonal and their centres, the section centres and
the grasp points constant), one sample at a time:

    F_cut = m_p (a_c − g) − Σ f_m,
    N_cut = K_p ω̇ + ω × K_p ω + (c − p_s) × m_p (a_c − g) − Σ [n_m + p_m × f_m] + p_s × Σ f_m,

the sums over the grasps on the part, a_c = a_C + ω̇ × c + ω × (ω × c), projected on the modelled rows,
resolved along the box axes; the peak normal and shear stresses over the cuts.
"""

import numpy as np

from coopsim.compiled.toolchain.jit import entry, kernel


@kernel
def _cross(a, b, out):
    """out ← a × b (3-vectors)."""
    x = a[1] * b[2] - a[2] * b[1]
    y = a[2] * b[0] - a[0] * b[2]
    z = a[0] * b[1] - a[1] * b[0]
    out[0], out[1], out[2] = x, y, z


@kernel
def _to_object(R, v, out):
    """out ← Rᵀ v (world → object frame)."""
    for i in range(3):
        out[i] = R[0, i] * v[0] + R[1, i] * v[1] + R[2, i] * v[2]


@kernel
def _projector(R, S, Q, B):
    """Q ← Rbᵀ SᵀS Rb (6 × 6), Rb = blockdiag(R, R): the projector on the modelled rows, object frame
    (B (6, 6) work)."""
    k = S.shape[0]
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for q in range(k):
                acc += S[q, i] * S[q, j]
            B[i, j] = acc
    for i in range(6):                            # Q = Rbᵀ B Rb, block by block
        for j in range(6):
            bi, bj = 3 * (i // 3), 3 * (j // 3)
            acc = 0.0
            for p in range(3):
                for q in range(3):
                    acc += R[p, i - bi] * B[bi + p, bj + q] * R[q, j - bj]
            Q[i, j] = acc


@entry
def section_loads(mass, R_o, twist, acc, gravity, F_e, rows, grasp_pos, axis, frac, K_diag, c_o, ps_o, on, sizes,
                  axial, shear, torsion, bending, peak_normal, peak_shear):
    """Section resultants at c cuts of N samples and the peak stresses (module docstring).

    Args:
        mass: kg, the object's mass.
        R_o: (N, 3, 3) the object's orientation, world ← object frame.
        twist: (N, 6) [v_C; ω] m/s, rad/s, world axes.
        acc: (N, 6) [a_C; ω̇] m/s², rad/s², world axes.
        gravity: (3,) m/s², world axes.
        F_e: (N, r, 6) [f_m; n_m] N, N·m, the grasp wrenches at the grasp points, world axes.
        rows: (k, 6) the row selector S, world axes.
        grasp_pos: (r, 3) m, the grasp points, object frame.
        axis: the box axis a the cuts are across (0, 1, 2).
        frac: (c,) the parts' mass fractions.
        K_diag: (c, 3) kg·m², the parts' inertias about their centres, box axes (diagonal).
        c_o: (c, 3) m, the parts' centres, object frame.
        ps_o: (c, 3) m, the section centres, object frame.
        on: (r, c) 1.0 where grasp m is on the part x_a < ξ, else 0.0.
        sizes: (4,) m, the section's sides d₁, d₂ (the other two box axes, in order), then b ≥ t of them.
        axial: (N, c) N, written: the axial force (tension > 0).
        shear: (N, c) N, written: the shear force's magnitude.
        torsion: (N, c) N·m, written: the torsion about the axis.
        bending: (N, c) N·m, written: the bending moment's magnitude.
        peak_normal: (N,) Pa, written: max over the cuts of |N|/A + |M₁|/Z₁ + |M₂|/Z₂.
        peak_shear: (N,) Pa, written: max over the cuts of 1.5|V|/A + |T|(3b + 1.8t)/(b²t²).
    """
    N, r, C = R_o.shape[0], grasp_pos.shape[0], frac.shape[0]
    o1, o2 = (axis + 1) % 3, (axis + 2) % 3
    if o1 > o2:
        o1, o2 = o2, o1
    d1, d2, b, t = sizes[0], sizes[1], sizes[2], sizes[3]
    area, Z1, Z2 = d1 * d2, d1 * d2 * d2 / 6.0, d2 * d1 * d1 / 6.0
    Q, B = np.empty((6, 6)), np.empty((6, 6))
    w, dw, aC, g = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    fm, nm = np.empty((r, 3)), np.empty((r, 3))
    t1, t2, t3 = np.empty(3), np.empty(3), np.empty(3)
    x, y = np.empty(6), np.empty(6)
    f_on, inert = np.empty(3), np.empty(3)
    for n in range(N):
        R = R_o[n]
        _to_object(R, twist[n, 3:], w)
        _to_object(R, acc[n, 3:], dw)
        _to_object(R, acc[n, :3], aC)
        _to_object(R, gravity, g)
        for m in range(r):
            _to_object(R, F_e[n, m, :3], fm[m])
            _to_object(R, F_e[n, m, 3:], nm[m])
            _cross(grasp_pos[m], fm[m], t1)
            for i in range(3):
                nm[m, i] += t1[i]                 # n_m + p_m × f_m
        _projector(R, rows, Q, B)
        peak_n, peak_s = -np.inf, -np.inf
        for c in range(C):
            _cross(dw, c_o[c], t1)                # a_c = a_C + ω̇ × c + ω × (ω × c)
            _cross(w, c_o[c], t2)
            _cross(w, t2, t3)
            mp = mass * frac[c]
            for i in range(3):
                inert[i] = mp * (aC[i] + t1[i] + t3[i] - g[i])
                f_on[i] = 0.0
                x[3 + i] = 0.0
            for m in range(r):
                if on[m, c] != 0.0:
                    for i in range(3):
                        f_on[i] += on[m, c] * fm[m, i]
                        x[3 + i] -= on[m, c] * nm[m, i]
            for i in range(3):
                x[i] = inert[i] - f_on[i]
                t1[i] = K_diag[c, i] * w[i]
                t2[i] = c_o[c, i] - ps_o[c, i]
            _cross(w, t1, t3)                     # ω × K ω
            for i in range(3):
                x[3 + i] += K_diag[c, i] * dw[i] + t3[i]
            _cross(t2, inert, t1)                 # (c − p_s) × m_p (a_c − g)
            _cross(ps_o[c], f_on, t3)             # p_s × Σ f_m
            for i in range(3):
                x[3 + i] += t1[i] + t3[i]
            for i in range(6):
                s = 0.0
                for j in range(6):
                    s += Q[i, j] * x[j]
                y[i] = s
            axial[n, c], torsion[n, c] = y[axis], y[3 + axis]
            shear[n, c] = np.hypot(y[o1], y[o2])
            bending[n, c] = np.hypot(y[3 + o1], y[3 + o2])
            normal = abs(y[axis]) / area + abs(y[3 + o1]) / Z1 + abs(y[3 + o2]) / Z2
            tau = 1.5 * shear[n, c] / area + abs(y[3 + axis]) * (3 * b + 1.8 * t) / (b * b * t * t)
            if normal > peak_n or np.isnan(normal):    # nan (an unsolved sample's wrenches) is kept
                peak_n = normal
            if tau > peak_s or np.isnan(tau):
                peak_s = tau
        peak_normal[n], peak_shear[n] = peak_n, peak_s
