"""Stage 8 — object stress: what an internal wrench does to the object (paper sec. 3.2).

Two views, both at every sample:
  * the internal wrench of one arm (at the centre of mass C, world axes; either definition, see
    `coopsim.inverse.solve`) resolved in that arm's grasp-line frame: axial force (squeeze < 0 < stretch),
    shear force, torsion (moment about the grasp line) and bending moment;
  * for a box object, the section loads along its grasp axis — the wrench one part of the object
    exerts on the other across a plane cut, from the Newton–Euler equations of the part (exact for a
    rigid body: a cut splits it in two, so the resultant is statically determined) — and from them
    estimates of the peak normal and shear stress of the rectangular cross-section.

In a planar scene only the in-plane rows S are modelled (in-plane force, moment about the normal):
out-of-plane loads (the weight of a horizontal-plane scene) are carried by the joint bearings and
reported as zero, so torsion and out-of-plane bending are zero there.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.core.spatial import box_inertia, cross, rigid_acceleration
from coopsim.inverse.problem import check_engine


class SectionLoads(NamedTuple):
    """Section resultants at the cuts of a box object along its grasp axis, per sample (N samples, c cuts).

    Attributes:
        xi: (c,) m, the cuts' object-frame coordinate along the box axis `axis`.
        axis: the box axis (0, 1 or 2, object frame) the cuts are across.
        axial: (N, c) N, the axial force N (tension > 0).
        shear: (N, c) N, the shear force V (magnitude).
        torsion: (N, c) N·m, the torsion T (signed, about the axis).
        bending: (N, c) N·m, the bending moment M (magnitude).
        peak_normal: (N,) Pa, the largest over the cuts of |N|/A + |M₁|/Z₁ + |M₂|/Z₂.
        peak_shear: (N,) Pa, the largest over the cuts of 1.5|V|/A + |T|(3b + 1.8c)/(b²c²) (b ≥ c the
            section's sides; Roark's torsion formula).
    """

    xi: np.ndarray
    axis: int
    axial: np.ndarray
    shear: np.ndarray
    torsion: np.ndarray
    bending: np.ndarray
    peak_normal: np.ndarray
    peak_shear: np.ndarray


def grasp_line_axes(rho: np.ndarray) -> np.ndarray:
    """Unit axis e_m of each arm's grasp line, pointing from the object's inside towards grasp m.

    For r = 2 the line through both grasp points (e₂ = −e₁ = (ρ₂ − ρ₁)/|ρ₂ − ρ₁|); for r > 2 the line
    from C to the grasp point (e_m = ρ_m/|ρ_m|). A force of the arm along +e_m stretches the object.
    Relative positions: no world position (rounded far from the origin) enters the axes.

    Args:
        rho: (…, r, 3) m, the grasp points relative to the centre of mass, ρ_m = p_grasp,m − p_C, world
            axes.

    Returns:
        np.ndarray: (…, r, 3) the unit axes e_m, world axes.
    """
    rho = np.asarray(rho, dtype=float)
    if rho.shape[-2] == 2:
        d = rho[..., 1, :] - rho[..., 0, :]
        e = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return np.stack([-e, e], axis=-2)
    return rho / np.linalg.norm(rho, axis=-1, keepdims=True)


def line_frame(e: np.ndarray, normal: np.ndarray | None) -> np.ndarray:
    """Rows (…, 3, 3) of a right-handed frame whose first axis is e.

    In a planar scene (normal given) the second axis is normal × e (in-plane shear direction) and the
    third the normal; otherwise the second is perpendicular to e and to the world axis least aligned
    with it.

    Args:
        e: (…, 3) unit axes (e.g. `grasp_line_axes`), world axes.
        normal: (3,) the unit plane normal of a planar scene, world axes; None: spatial.

    Returns:
        np.ndarray: (…, 3, 3) the frames' axes as rows, world axes.
    """
    e = np.asarray(e, dtype=float)
    ref = normal if normal is not None else np.eye(3)[np.argmin(np.abs(e), axis=-1)]
    e2 = np.cross(ref, e)
    e2 = e2 / np.linalg.norm(e2, axis=-1, keepdims=True)
    return np.stack([e, e2, np.cross(e, e2)], axis=-2)


def decompose_internal(F_I: np.ndarray, axes: np.ndarray) -> dict[str, np.ndarray]:
    """Internal wrench F_I [f; n] at C resolved along the grasp-line axes.

    Args:
        F_I: (…, r, 6) [f; n] N, N·m, the internal wrench of each arm at C, world axes.
        axes: (…, r, 3) the unit grasp-line axes e (`grasp_line_axes`), world axes.

    Returns:
        dict[str, np.ndarray]: arrays of shape (…, r): "axial" = f·e (N; > 0 stretch, < 0 squeeze),
        "shear" = |f − (f·e)e| (N), "torsion" = n·e (N·m), "bending" = |n − (n·e)e| (N·m).
    """
    f, n = F_I[..., :3], F_I[..., 3:]
    axial = np.einsum("...i,...i->...", f, axes)
    torsion = np.einsum("...i,...i->...", n, axes)
    shear = np.linalg.norm(f - axial[..., None] * axes, axis=-1)
    bending = np.linalg.norm(n - torsion[..., None] * axes, axis=-1)
    return {"axial": axial, "shear": shear, "torsion": torsion, "bending": bending}


def grasp_axis(box: np.ndarray, grasp_pos: np.ndarray) -> int:
    """Index of the box axis (object frame) along which the grasp points lie farthest apart.

    The spread of the grasp points along each axis is measured relative to the box's edge along it.

    Args:
        box: (3,) m, the box's edges.
        grasp_pos: (r, 3) m, the grasp points, object frame.

    Returns:
        int: 0, 1 or 2, the axis whose grasp spread divided by the edge is largest.
    """
    spread = grasp_pos.max(axis=0) - grasp_pos.min(axis=0)
    return int(np.argmax(spread / np.maximum(box, 1e-300)))


def section_loads(mass: float, box: np.ndarray, grasp_pos: np.ndarray, R_o: np.ndarray, twist: np.ndarray,
                  acc: np.ndarray, gravity: np.ndarray, F_e: np.ndarray, rows: np.ndarray,
                  cuts: int = 81, engine: str = "compiled") -> SectionLoads:
    """Section loads of a uniform box object along the box axis a holding the grasps, over N samples.

    The axis a is `grasp_axis`'s, of length L; the cuts are `cuts` planes evenly inside (−L/2, L/2).
    For the part x_a < ξ (mass m_p = m(ξ + L/2)/L, centre c at ((ξ − L/2)/2) e_a, inertia K_p), with
    ρ = R_o c, a_c = a_C + ω̇ × ρ + ω × (ω × ρ) and the grasp wrenches F_e^m (at the grasp points p_m)
    of the grasps on that part, the wrench the other part exerts on it at the section centre
    p_s = R_o ξ e_a (relative to C) is
        F_cut = m_p (a_c − g) − Σ f_m,
        N_cut = K_p ω̇ + ω × K_p ω + (ρ − p_s) × m_p (a_c − g) − Σ [n_m + (p_m − p_s) × f_m].
    Resolved in the section frame (e_a and the two other box axes): axial = F_cut·e_a (tension > 0),
    shear, torsion = N_cut·e_a, bending. Every sample and cut at once, in the object frame (where K_p is
    diagonal and c, p_s, p_m are constant): one compiled pass over the samples (`coopsim.compiled.stress`),
    or in NumPy (engine 'reference', the readable reference; the same numbers to rounding).

    Args:
        mass: kg, the object's mass (uniform density).
        box: (3,) m, the box's edges, object frame at its centre.
        grasp_pos: (r, 3) m, the grasp points p_m, object frame.
        R_o: (N, 3, 3) the object's orientation, world axes.
        twist: (N, 6) [v_C; ω] m/s, rad/s, world axes.
        acc: (N, 6) [a_C; ω̇] m/s², rad/s², world axes.
        gravity: (3,) m/s², g, world axes.
        F_e: (N, r, 6) [f_m; n_m] N, N·m, the grasp wrenches each arm applies at its grasp point, world
            axes.
        rows: (k, 6) the row selector S (world axes), restricting the loads to the modelled rows (planar:
            in-plane force, moment about the normal).
        cuts: the number of section planes c.
        engine: 'compiled' or 'reference' (`coopsim.inverse.problem.ENGINES`).

    Returns:
        SectionLoads: the cuts xi (c,), the axis, the resultants (N, c) and the peak stresses (N,).
    """
    a = grasp_axis(box, grasp_pos)
    others = [i for i in range(3) if i != a]
    L = box[a]
    xi = np.linspace(-L / 2, L / 2, cuts + 2)[1:-1]
    frac = (xi + L / 2) / L                             # mass fraction of the part x < ξ (c,)
    sizes = np.tile(box, (cuts, 1))
    sizes[:, a] = xi + L / 2
    K_diag = np.diagonal(box_inertia(mass * frac, sizes), axis1=-2, axis2=-1)   # part inertias, box axes (c, 3)
    c_o, ps_o = np.zeros((cuts, 3)), np.zeros((cuts, 3))
    c_o[:, a], ps_o[:, a] = (xi - L / 2) / 2, xi        # part centre, section centre (object frame)
    on = (grasp_pos[:, a][:, None] < xi).astype(float)  # grasp m on the part x < ξ (r, c)
    d1, d2 = box[others[0]], box[others[1]]
    b, t = max(d1, d2), min(d1, d2)
    if check_engine(engine) == "compiled":
        from coopsim.compiled import api

        loads = api.section_loads(mass, R_o, twist, acc, gravity, F_e, rows, grasp_pos, a, frac, K_diag, c_o, ps_o, on,
                                  (d1, d2, b, t))
        return SectionLoads(xi, a, *loads)

    def body(v):                                        # world vectors (N, …, 3) → object frame
        return np.einsum("nji,n...j->n...i", R_o, v)

    w, dw = body(twist[:, 3:])[:, None], body(acc[:, 3:])[:, None]     # (N, 1, 3), object frame
    a_c = rigid_acceleration(body(acc[:, :3])[:, None], w, dw, c_o)    # every sample × cut (N, c, 3)
    inert_f = (mass * frac)[:, None] * (a_c - body(np.broadcast_to(gravity, (len(R_o), 3)))[:, None])
    f_m, n_m = body(F_e[..., :3]), body(F_e[..., 3:])
    f_on = np.einsum("nmk,mc->nck", f_m, on)
    force = inert_f - f_on
    moment = (K_diag * dw + cross(w, K_diag * w) + cross(c_o - ps_o, inert_f)
              - np.einsum("nmk,mc->nck", n_m + cross(grasp_pos, f_m), on) + cross(ps_o, f_on))
    Rb = np.zeros((len(R_o), 6, 6))
    Rb[:, :3, :3] = Rb[:, 3:, 3:] = R_o
    Q = np.swapaxes(Rb, 1, 2) @ (rows.T @ rows) @ Rb    # projector on the modelled rows, object frame
    wrench = np.concatenate([force, moment], axis=-1) @ np.swapaxes(Q, 1, 2)
    fl, ml = wrench[..., :3], wrench[..., 3:]           # box axes
    out = {"axial": fl[..., a], "torsion": ml[..., a], "shear": np.hypot(fl[..., others[0]], fl[..., others[1]]),
           "bending": np.hypot(ml[..., others[0]], ml[..., others[1]]), "m1": ml[..., others[0]],
           "m2": ml[..., others[1]]}
    area = d1 * d2
    Z1, Z2 = d1 * d2 ** 2 / 6.0, d2 * d1 ** 2 / 6.0    # a moment about axis 1 varies the stress along axis 2
    normal = np.abs(out["axial"]) / area + np.abs(out["m1"]) / Z1 + np.abs(out["m2"]) / Z2
    shear = 1.5 * out["shear"] / area + np.abs(out["torsion"]) * (3 * b + 1.8 * t) / (b * b * t * t)
    return SectionLoads(xi, a, out["axial"], out["shear"], out["torsion"], out["bending"],
                        normal.max(axis=1), shear.max(axis=1))
