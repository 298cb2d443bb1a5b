"""3-vector and rotation helpers for the compiled kernels (same conventions as `coopsim.core.spatial`:
R maps body to world coordinates, quaternions [w, x, y, z] with w ≥ 0)."""

from __future__ import annotations

import numpy as np
from coopsim.compiled.toolchain.jit import kernel


@kernel
def cross3(a0, a1, a2, b0, b1, b2):
    """a × b as three scalars."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel
def cross_into(a, b, out):
    """out ← a × b (3-vectors; out may not alias a or b)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@kernel
def axis_rotation(axis, angle, out):
    """out (3, 3) ← Rodrigues' R = I + sinφ [a×] + (1 − cosφ)[a×]² for the unit axis a, angle φ rad."""
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
    """out (3, 3) ← A B (out may not alias A or B)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@kernel
def matmul3_T(A, B, out):
    """out (3, 3) ← A Bᵀ."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[j, 0] + A[i, 1] * B[j, 1] + A[i, 2] * B[j, 2]


@kernel
def rotate_inertia(R, I, tmp, out):
    """out ← R I Rᵀ (3, 3); tmp (3, 3) scratch."""
    matmul3(R, I, tmp)
    matmul3_T(tmp, R, out)


@kernel
def rot_log(R, out):
    """out (3,) ← rotation vector φ (|φ| ≤ π) with exp([φ×]) = R, through the quaternion (Shepperd's
    branches, w ≥ 0) as `coopsim.core.spatial.rot_log`: φ = 2 atan2(|v|, w) v/|v|, ~1e-15 rad at every
    angle, near π included."""
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
    """q (4,) ← unit quaternion [w, x, y, z], w ≥ 0, of R (Shepperd's method, as
    `coopsim.core.spatial.rot_to_quat`)."""
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
