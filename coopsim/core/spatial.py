"""Rotation, 3-vector and rigid-body helpers shared by every stage (pure NumPy, no I/O).

Conventions: rotation matrices R map body-frame coordinates to world coordinates; quaternions are
[w, x, y, z] with w >= 0 when canonicalised; roll-pitch-yaw angles (rad) give
R = Rz(yaw) Ry(pitch) Rx(roll) (fixed-axis x, then y, then z).
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """[v×], shape (3, 3): skew(v) @ u == cross(v, u)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def axis_angle_to_rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula R = I + sinφ [a×] + (1 − cosφ)[a×]², `axis` a unit 3-vector, angle in rad."""
    K = skew(axis)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def rpy_to_rot(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for rpy = (roll, pitch, yaw) in rad."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion q = [w, x, y, z] (normalised here)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion [w, x, y, z] (w >= 0) of rotation matrix R (Shepperd's method)."""
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rots_to_quats(R: np.ndarray) -> np.ndarray:
    """`rot_to_quat` over rotation matrices R (..., 3, 3) → (..., 4) [w, x, y, z], w >= 0: Shepperd's
    branch chosen per matrix as there (the trace when positive, else the largest diagonal entry)."""
    R = np.asarray(R, dtype=float)
    shape, R = R.shape[:-2], R.reshape(-1, 3, 3)
    q = np.empty((len(R), 4))
    t = np.trace(R, axis1=1, axis2=2)
    pos = t > 0
    s, Rp = 2.0 * np.sqrt(1.0 + t[pos]), R[pos]
    q[pos] = np.stack([0.25 * s, (Rp[:, 2, 1] - Rp[:, 1, 2]) / s, (Rp[:, 0, 2] - Rp[:, 2, 0]) / s,
                       (Rp[:, 1, 0] - Rp[:, 0, 1]) / s], axis=1)
    largest = np.argmax(np.diagonal(R, axis1=1, axis2=2), axis=1)
    for i in range(3):
        sel = ~pos & (largest == i)
        j, k, Rs = (i + 1) % 3, (i + 2) % 3, R[sel]
        s = 2.0 * np.sqrt(1.0 + Rs[:, i, i] - Rs[:, j, j] - Rs[:, k, k])
        qs = np.empty((len(Rs), 4))
        qs[:, 0] = (Rs[:, k, j] - Rs[:, j, k]) / s
        qs[:, 1 + i] = 0.25 * s
        qs[:, 1 + j] = (Rs[:, j, i] + Rs[:, i, j]) / s
        qs[:, 1 + k] = (Rs[:, k, i] + Rs[:, i, k]) / s
        q[sel] = qs
    q /= np.sqrt(np.sum(q * q, axis=1))[:, None]
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(shape + (4,))


def rot_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector φ (rad, |φ| <= π) with exp([φ×]) = R, to about 1e-15 rad at every angle.

    Through the unit quaternion [w, v] = [cos(φ/2), sin(φ/2) a] (w >= 0, Shepperd's method): φ =
    2 atan2(|v|, w) v/|v|. Near the identity v carries the angle to full relative precision; near π
    Shepperd's branch takes the axis from the symmetric part of R and w from its antisymmetric part,
    so neither the axis nor the sign degrade (the form sin φ · a / sin φ lost 2e-5 rad at π − 1e-11,
    and the sign below π − 1e-12). At exactly π both ±π a are valid."""
    q = rot_to_quat(R)
    v = q[1:]
    n = float(np.sqrt(v @ v))
    if n < 1e-8:  # 2 atan2(n, w)/n = (2/w)(1 − n²/3 …): exact to rounding; v @ v may underflow
        return (2.0 / q[0]) * v
    return (2.0 * np.arctan2(n, q[0]) / n) * v


def orientation_error(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """Angle (N,) rad of the rotation between two quaternion series [w, x, y, z] (N, 4)."""
    return np.array([np.linalg.norm(rot_log(quat_to_rot(a) @ quat_to_rot(b).T)) for a, b in zip(q_a, q_b)])


def rotation_from(q: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """Rotation vectors φ (N, 3) rad, world axes, of the orientations q (N, 4) [w, x, y, z] relative to
    R0 (3, 3): exp([φ×]) R0 = R(q) (|φ| <= π)."""
    return np.array([rot_log(quat_to_rot(x) @ R0.T) for x in q]).reshape(len(q), 3)


_I1, _I2 = np.array([1, 2, 0]), np.array([2, 0, 1])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis (…, 3), broadcasting; a lean replacement of np.cross for tiny arrays."""
    a, b = np.asarray(a), np.asarray(b)
    return a.take(_I1, -1) * b.take(_I2, -1) - a.take(_I2, -1) * b.take(_I1, -1)


def rigid_acceleration(a_O: np.ndarray, w: np.ndarray, dw: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Acceleration (…, 3) of a point P of a rigid body: a_P = a_O + ω̇ × r + ω × (ω × r), for the
    acceleration a_O of a body point O, the body's angular velocity ω and acceleration ω̇, and
    r = p_P − p_O (all (…, 3), broadcasting; a_O may be 0). The one place this formula is written."""
    return a_O + cross(dw, r) + cross(w, cross(w, r))


def box_inertia(mass, size: np.ndarray) -> np.ndarray:
    """Inertia (…, 3, 3) of a solid box of `mass` (…) kg and edges `size` (…, 3) m about its centre,
    box axes: m/12 diag(b² + c², a² + c², a² + b²) (broadcasting over the leading axes)."""
    a2 = np.asarray(size, dtype=float) ** 2
    d = np.stack([a2[..., 1] + a2[..., 2], a2[..., 0] + a2[..., 2], a2[..., 0] + a2[..., 1]], axis=-1)
    return np.asarray(mass, dtype=float)[..., None, None] / 12.0 * (d[..., :, None] * np.eye(3))
