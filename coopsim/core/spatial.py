"""Rotation, 3-vector and rigid-body helpers shared by every stage (pure NumPy, no I/O).

Conventions: rotation matrices R map body-frame coordinates to world coordinates; quaternions are
[w, x, y, z] with w >= 0 when canonicalised; roll-pitch-yaw angles (rad) give
R = Rz(yaw) Ry(pitch) Rx(roll) (fixed-axis x, then y, then z).
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """The skew-symmetric cross-product matrix [v×] of a 3-vector: skew(v) @ u == cross(v, u).

    Args:
        v: (3,) the vector, any units and axes.

    Returns:
        np.ndarray: (3, 3) [v×], in v's units and axes.
    """
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def axis_angle_to_rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by `angle` about `axis`, by Rodrigues' formula R = I + sinφ [a×] + (1 − cosφ)[a×]².

    Args:
        axis: (3,) unit rotation axis a (not normalised here).
        angle: rad, the rotation angle φ.

    Returns:
        np.ndarray: (3, 3) the rotation matrix, in the axes `axis` is given in.
    """
    K = skew(axis)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def rpy_to_rot(rpy: np.ndarray) -> np.ndarray:
    """Rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll) of roll-pitch-yaw angles (fixed axes x, y, z).

    Args:
        rpy: (3,) rad, (roll, pitch, yaw).

    Returns:
        np.ndarray: (3, 3) R, body-frame coordinates to world coordinates.
    """
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def rot_to_rpy(R: np.ndarray) -> np.ndarray:
    """Roll-pitch-yaw angles of a rotation matrix, the inverse of `rpy_to_rot` (URDF's `rpy`).

    Pitch comes from the first column; yaw from it too (any yaw at pitch ±π/2, where only roll ∓ yaw is
    determined: yaw 0 there); roll from what Rz(yaw) Ry(pitch) leaves, so rpy_to_rot(rot_to_rpy(R))
    equals R to rounding at every pitch, the gimbal lock included.

    Args:
        R: (3, 3) rotation matrix, body-frame coordinates to world coordinates.

    Returns:
        np.ndarray: (3,) rad, (roll, pitch, yaw), pitch in [−π/2, π/2], roll and yaw in (−π, π].
    """
    R = np.asarray(R, dtype=float)
    c = float(np.hypot(R[0, 0], R[1, 0]))
    pitch = float(np.arctan2(-R[2, 0], c))
    yaw = float(np.arctan2(R[1, 0], R[0, 0])) if c > 1e-300 else 0.0
    X = rpy_to_rot(np.array([0.0, pitch, yaw])).T @ R     # Rx(roll)
    return np.array([float(np.arctan2(X[2, 1], X[1, 1])), pitch, yaw])


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion q = [w, x, y, z] (normalised here).

    Args:
        q: (4,) [w, x, y, z], any non-zero norm.

    Returns:
        np.ndarray: (3, 3) R, body-frame coordinates to world coordinates.
    """
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion [w, x, y, z] (w >= 0) of a rotation matrix (Shepperd's method).

    Args:
        R: (3, 3) rotation matrix, body-frame coordinates to world coordinates.

    Returns:
        np.ndarray: (4,) [w, x, y, z], unit norm, w >= 0.
    """
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
    """`rot_to_quat` over a stack of rotation matrices, Shepperd's branch chosen per matrix as there.

    The branch is the trace when it is positive, else the largest diagonal entry.

    Args:
        R: (..., 3, 3) rotation matrices, body-frame coordinates to world coordinates.

    Returns:
        np.ndarray: (..., 4) unit quaternions [w, x, y, z], w >= 0.
    """
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
    and the sign below π − 1e-12). At exactly π both ±π a are valid.

    Args:
        R: (3, 3) rotation matrix.

    Returns:
        np.ndarray: (3,) rad, the rotation vector φ = angle · axis, in the axes R is written in.
    """
    q = rot_to_quat(R)
    v = q[1:]
    n = float(np.sqrt(v @ v))
    if n < 1e-8:  # 2 atan2(n, w)/n = (2/w)(1 − n²/3 …): exact to rounding; v @ v may underflow
        return (2.0 / q[0]) * v
    return (2.0 * np.arctan2(n, q[0]) / n) * v


def orientation_error(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """Angle of the rotation between two series of orientations, sample by sample.

    Args:
        q_a, q_b: (N, 4) quaternions [w, x, y, z] (normalised here).

    Returns:
        np.ndarray: (N,) rad in [0, π], the angle of R(q_a) R(q_b)ᵀ at each sample.
    """
    return np.array([np.linalg.norm(rot_log(quat_to_rot(a) @ quat_to_rot(b).T)) for a, b in zip(q_a, q_b)])


def rotation_from(q: np.ndarray, R0: np.ndarray) -> np.ndarray:
    """Rotation vectors of a series of orientations relative to a reference: exp([φ×]) R0 = R(q).

    Args:
        q: (N, 4) quaternions [w, x, y, z] (normalised here), body to world.
        R0: (3, 3) the reference orientation, body to world.

    Returns:
        np.ndarray: (N, 3) rad, world axes, the rotation vectors φ (|φ| <= π).
    """
    return np.array([rot_log(quat_to_rot(x) @ R0.T) for x in q]).reshape(len(q), 3)


_I1, _I2 = np.array([1, 2, 0]), np.array([2, 0, 1])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis, broadcasting; a lean replacement of np.cross for tiny arrays.

    Args:
        a, b: (…, 3) vectors in common axes (leading axes broadcast).

    Returns:
        np.ndarray: (…, 3) a × b, in the same axes.
    """
    a, b = np.asarray(a), np.asarray(b)
    return a.take(_I1, -1) * b.take(_I2, -1) - a.take(_I2, -1) * b.take(_I1, -1)


def rigid_acceleration(a_O: np.ndarray, w: np.ndarray, dw: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Acceleration of a point P of a rigid body: a_P = a_O + ω̇ × r + ω × (ω × r).

    The one place this formula is written. All vectors in common axes, leading axes broadcasting.

    Args:
        a_O: (…, 3) m/s², the acceleration of a body point O (may be 0).
        w: (…, 3) rad/s, the body's angular velocity ω.
        dw: (…, 3) rad/s², the body's angular acceleration ω̇.
        r: (…, 3) m, r = p_P − p_O.

    Returns:
        np.ndarray: (…, 3) m/s², the acceleration a_P of P.
    """
    return a_O + cross(dw, r) + cross(w, cross(w, r))


def box_inertia(mass, size: np.ndarray) -> np.ndarray:
    """Inertia of a solid box about its centre, box axes: m/12 diag(b² + c², a² + c², a² + b²).

    Broadcasts over the leading axes.

    Args:
        mass: (…) kg, the box's mass m (a float for one box).
        size: (…, 3) m, the edge lengths (a, b, c) along the box axes.

    Returns:
        np.ndarray: (…, 3, 3) kg·m², the inertia about the box's centre, box axes.
    """
    a2 = np.asarray(size, dtype=float) ** 2
    d = np.stack([a2[..., 1] + a2[..., 2], a2[..., 0] + a2[..., 2], a2[..., 0] + a2[..., 1]], axis=-1)
    return np.asarray(mass, dtype=float)[..., None, None] / 12.0 * (d[..., :, None] * np.eye(3))
