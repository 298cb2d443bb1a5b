"""Stage 3 — object and grasp: grasp matrices, object Newton–Euler, internal wrench (eqs. 1–8, 11–13).

Twists are [v; ω] and wrenches [f; n] in world axes. F_e^m is the wrench end-effector m applies to the
object, at the end-effector point; s_m = p_C − p_EE,m.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.core.model import ObjectModel
from coopsim.core.spatial import cross, skew


class ObjectPose(NamedTuple):
    """Object frame: p_C (3,) centre of mass, R_o (3, 3) world←object, K (3, 3) inertia about C,
    world axes."""

    p_C: np.ndarray
    R_o: np.ndarray
    K: np.ndarray


def grasp_matrix(s: np.ndarray) -> np.ndarray:
    """W_m (…, 6, 6) of eq. 2 for offsets s (…, 3): F_o^m = W_m F_e^m moves a wrench from the EE point
    to C, W_m = [[I₃, O₃], [−[s_m×], I₃]] (batched over leading axes)."""
    s = np.asarray(s, dtype=float)
    W = np.zeros(s.shape[:-1] + (6, 6))
    W[..., range(6), range(6)] = 1.0
    x, y, z = s[..., 0], s[..., 1], s[..., 2]
    W[..., 3, 1], W[..., 3, 2] = z, -y
    W[..., 4, 0], W[..., 4, 2] = -z, x
    W[..., 5, 0], W[..., 5, 1] = y, -x
    return W


def grasp_matrix_inv_T(s: np.ndarray) -> np.ndarray:
    """W_m⁻ᵀ (6, 6): v_o = W_m⁻ᵀ v_EE,m (eq. 3 inverted), W_m⁻ᵀ = [[I₃, −[s_m×]], [O₃, I₃]]."""
    W = np.eye(6)
    W[:3, 3:] = -skew(s)
    return W


def object_pose(obj: ObjectModel, p_ee: np.ndarray, R_ee: np.ndarray, m: int) -> ObjectPose:
    """Object pose implied by end-effector m's frame (p_ee (3,), R_ee (3, 3)) and its grasp."""
    R_o = R_ee @ obj.grasp_rot[m].T
    p_C = p_ee - R_o @ obj.grasp_pos[m]
    return ObjectPose(p_C, R_o, R_o @ obj.inertia @ R_o.T)


def object_bias_wrench(obj: ObjectModel, pose: ObjectPose, w: np.ndarray, g: np.ndarray) -> np.ndarray:
    """b_o (6,) of eqs. 11–12: Y = F_o = M_o v̇_o + b_o, b_o = [−m_o g; ω × K_o ω]."""
    return np.concatenate([-obj.mass * g, cross(w, pose.K @ w)])


def object_mass_matrix(obj: ObjectModel, pose: ObjectPose) -> np.ndarray:
    """M_o (6, 6) = diag(m_o I₃, K_o) at C, world axes (eq. 11)."""
    M = np.zeros((6, 6))
    M[:3, :3] = obj.mass * np.eye(3)
    M[3:, 3:] = pose.K
    return M


def net_object_wrench(W: list[np.ndarray], F_e: np.ndarray) -> np.ndarray:
    """F_o (6,) = Σ_m W_m F_e^m (eqs. 4–6); F_e (r, 6)."""
    return sum(Wm @ Fm for Wm, Fm in zip(W, F_e))


def internal_wrench(W: list[np.ndarray], F_e: np.ndarray) -> np.ndarray:
    """Internal wrench per arm (r, 6) at C, world axes: F_I^m = W_m F_e^m − F_o / r.

    This is eq. 7 with the paper's generalized inverse W⁺ = (1/r)[W_1⁻¹; …; W_r⁻¹] (eq. 8 for r = 2):
    F_e = W⁺ F_o + V F_I. The rows sum to zero (they do not move the object); for r = 2, row 2 is the
    paper's F_I = [f_I; n_I] and row 1 its negative."""
    moved = np.array([Wm @ Fm for Wm, Fm in zip(W, F_e)])
    return moved - moved.sum(axis=0) / len(W)
