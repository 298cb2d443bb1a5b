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


def axis_angle_rotations(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """`axis_angle_to_rot` of n unit axes (n, 3) and angles (n,) at once: (n, 3, 3), the same numbers."""
    K = np.zeros((len(axes), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axes[:, 2], axes[:, 1], -axes[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = axes[:, 2], -axes[:, 1], axes[:, 0]
    return np.eye(3) + np.sin(angles)[:, None, None] * K + (1.0 - np.cos(angles))[:, None, None] * (K @ K)


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
