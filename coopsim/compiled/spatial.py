"""3-vector and rotation helpers for the compiled kernels (same conventions as `coopsim.core.spatial`:
R maps body to world coordinates, quaternions [w, x, y, z] with w ≥ 0)."""

from __future__ import annotations

import numpy as np
from coopsim.compiled.toolchain.jit import kernel


@kernel
def cross3(a0, a1, a2, b0, b1, b2):
    """a × b as three scalars.

    Args:
        a0, a1, a2: the components of a (any units, one set of axes).
        b0, b1, b2: the components of b, in the same axes.

    Returns:
        tuple[float, float, float]: the components of a × b, in those axes.
    """
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel
def cross_into(a, b, out):
    """out ← a × b for 3-vectors (out may not alias a or b).

    Args:
        a, b: (3,) the factors, in one set of axes.
        out: (3,) written: a × b, in the same axes.
    """
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@kernel
def rigid_point_acceleration(a_O, w, dw, r, out):
    """out ← a_O + ω̇ × r + ω × (ω × r), the acceleration of a point of a rigid body.

    As `coopsim.core.spatial.rigid_acceleration`; all vectors in one set of axes (world).

    Args:
        a_O: (3,) m/s², the acceleration of the reference point O.
        w: (3,) rad/s, the body's angular velocity ω.
        dw: (3,) rad/s², its angular acceleration ω̇.
        r: (3,) m, the point relative to O.
        out: (3,) written: the point's acceleration, m/s² (may alias a_O, not r, w or dw).
    """
    c0 = w[1] * r[2] - w[2] * r[1]
    c1 = w[2] * r[0] - w[0] * r[2]
    c2 = w[0] * r[1] - w[1] * r[0]
    out[0] = a_O[0] + (dw[1] * r[2] - dw[2] * r[1]) + (w[1] * c2 - w[2] * c1)
    out[1] = a_O[1] + (dw[2] * r[0] - dw[0] * r[2]) + (w[2] * c0 - w[0] * c2)
    out[2] = a_O[2] + (dw[0] * r[1] - dw[1] * r[0]) + (w[0] * c1 - w[1] * c0)


@kernel
def axis_rotation(axis, angle, out):
    """out ← the rotation of `angle` about the unit `axis`, by Rodrigues' formula.

    R = I + sinφ [a×] + (1 − cosφ)[a×]² for the unit axis a and angle φ.

    Args:
        axis: (3,) unit rotation axis a.
        angle: rad, the angle φ (right-handed about a).
        out: (3, 3) written: R.
    """
    s, c1 = np.sin(angle), 1.0 - np.cos(angle)
    x, y, z = axis[0], axis[1], axis[2]
    out[0, 0] = 1.0 - c1 * (y * y + z * z)
    out[0, 1] = -s * z + c1 * x * y
    out[0, 2] = s * y + c1 * x * z
    out[1, 0] = s * z + c1 * x * y
    out[1, 1] = 1.0 - c1 * (x * x + z * z)
    out[1, 2] = -s * x + c1 * y * z
    out[2, 0] = -s * y + c1 * x * z
    out[2, 1] = s * x + c1 * y * z
    out[2, 2] = 1.0 - c1 * (x * x + y * y)


@kernel
def matmul3(A, B, out):
    """out ← A B for 3 × 3 matrices (out may not alias A or B).

    Args:
        A, B: (3, 3) the factors.
        out: (3, 3) written: A B.
    """
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@kernel
def matmul3_T(A, B, out):
    """out ← A Bᵀ for 3 × 3 matrices (out may not alias A or B).

    Args:
        A, B: (3, 3) the factors.
        out: (3, 3) written: A Bᵀ.
    """
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[j, 0] + A[i, 1] * B[j, 1] + A[i, 2] * B[j, 2]


@kernel
def rotate_inertia(R, I, tmp, out):
    """out ← R I Rᵀ: an inertia tensor re-expressed in the axes R maps to.

    Args:
        R: (3, 3) rotation, body to world axes.
        I: (3, 3) kg·m², the inertia tensor in body axes.
        tmp: (3, 3) scratch (overwritten; may not alias R, I or out).
        out: (3, 3) written: R I Rᵀ, kg·m², world axes (may not alias R).
    """
    matmul3(R, I, tmp)
    matmul3_T(tmp, R, out)


@kernel
def rot_log(R, out):
    """out ← the rotation vector φ (|φ| ≤ π) with exp([φ×]) = R.

    Computed through the quaternion (Shepperd's branches, w ≥ 0) as `coopsim.core.spatial.rot_log`:
    φ = 2 atan2(|v|, w) v/|v|, ~1e-15 rad at every angle, near π included.

    Args:
        R: (3, 3) rotation matrix.
        out: (3,) written: φ, rad, in the axes R is expressed in.
    """
    t = R[0, 0] + R[1, 1] + R[2, 2]
    if t > 0.0:
        s = 2.0 * np.sqrt(1.0 + t)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[1, 0] + R[0, 1]) / s, (R[2, 0] + R[0, 2]) / s
    elif R[1, 1] >= R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[2, 2] - R[0, 0])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[2, 1] + R[1, 2]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    nq = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / nq, x / nq, y / nq, z / nq
    n = np.sqrt(x * x + y * y + z * z)
    f = 2.0 / w if n < 1e-8 else 2.0 * np.arctan2(n, w) / n
    out[0], out[1], out[2] = f * x, f * y, f * z


@kernel
def rot_to_quat(R, q):
    """q ← the unit quaternion [w, x, y, z], w ≥ 0, of R.

    Shepperd's method, as `coopsim.core.spatial.rot_to_quat`.

    Args:
        R: (3, 3) rotation matrix (body to world axes).
        q: (4,) written: [w, x, y, z], normalised, w ≥ 0.
    """
    t = R[0, 0] + R[1, 1] + R[2, 2]
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q[0] = 0.25 * s
        q[1] = (R[2, 1] - R[1, 2]) / s
        q[2] = (R[0, 2] - R[2, 0]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    else:
        i = 0
        if R[1, 1] > R[i, i]:
            i = 1
        if R[2, 2] > R[i, i]:
            i = 2
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    nrm = np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    sign = 1.0 if q[0] >= 0 else -1.0
    for i in range(4):
        q[i] = sign * q[i] / nrm
