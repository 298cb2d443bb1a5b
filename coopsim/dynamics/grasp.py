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
    """Object frame and inertia, world axes.

    Attributes:
        p_C: (3,) m, the object's centre of mass C, world position.
        R_o: (3, 3) rotation world←object.
        K: (3, 3) kg·m², the object's inertia about C, world axes.
    """

    p_C: np.ndarray
    R_o: np.ndarray
    K: np.ndarray


def grasp_matrix(s: np.ndarray) -> np.ndarray:
    """Grasp matrix W_m of eq. 2: F_o^m = W_m F_e^m moves a wrench from the EE point to C.

    W_m = [[I₃, O₃], [−[s_m×], I₃]] (batched over leading axes).

    Args:
        s: (…, 3) m, offsets s_m = p_C − p_EE,m, world axes.

    Returns:
        np.ndarray: (…, 6, 6) W_m, acting on wrenches [f; n] (N, N·m) in world axes.
    """
    s = np.asarray(s, dtype=float)
    W = np.zeros(s.shape[:-1] + (6, 6))
    W[..., range(6), range(6)] = 1.0
    x, y, z = s[..., 0], s[..., 1], s[..., 2]
    W[..., 3, 1], W[..., 3, 2] = z, -y
    W[..., 4, 0], W[..., 4, 2] = -z, x
    W[..., 5, 0], W[..., 5, 1] = y, -x
    return W


def grasp_matrix_inv_T(s: np.ndarray) -> np.ndarray:
    """W_m⁻ᵀ: v_o = W_m⁻ᵀ v_EE,m (eq. 3 inverted), W_m⁻ᵀ = [[I₃, −[s_m×]], [O₃, I₃]].

    Args:
        s: (3,) m, the offset s_m = p_C − p_EE,m, world axes.

    Returns:
        np.ndarray: (6, 6) W_m⁻ᵀ, acting on twists [v; ω] (m/s, rad/s) in world axes.
    """
    W = np.eye(6)
    W[:3, 3:] = -skew(s)
    return W


def object_pose(obj: ObjectModel, p_ee: np.ndarray, R_ee: np.ndarray, m: int) -> ObjectPose:
    """Object pose implied by end-effector m's frame and its grasp.

    Args:
        obj: the object's model (ObjectModel: its grasp poses in the object frame, inertia).
        p_ee: (3,) m, end-effector m's position, world.
        R_ee: (3, 3) end-effector m's frame, world axes.
        m: arm index, 0-based (the row of obj.grasp_pos, obj.grasp_rot).

    Returns:
        ObjectPose: C, R_o and the inertia about C in world axes.
    """
    R_o = R_ee @ obj.grasp_rot[m].T
    p_C = p_ee - R_o @ obj.grasp_pos[m]
    return ObjectPose(p_C, R_o, R_o @ obj.inertia @ R_o.T)


def object_bias_wrench(obj: ObjectModel, pose: ObjectPose, w: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Object bias wrench b_o of eqs. 11–12: Y = F_o = M_o v̇_o + b_o, b_o = [−m_o g; ω × K_o ω].

    Args:
        obj: the object's model (ObjectModel; its mass, kg).
        pose: the ObjectPose (its inertia K about C, world axes).
        w: (3,) rad/s, the object's angular velocity ω, world axes.
        g: (3,) m/s², gravity, world axes.

    Returns:
        np.ndarray: (6,) b_o [N; N·m] at C, world axes.
    """
    return np.concatenate([-obj.mass * g, cross(w, pose.K @ w)])


def object_mass_matrix(obj: ObjectModel, pose: ObjectPose) -> np.ndarray:
    """Object mass matrix M_o = diag(m_o I₃, K_o) at C, world axes (eq. 11).

    Args:
        obj: the object's model (ObjectModel; its mass, kg).
        pose: the ObjectPose (its inertia K about C, world axes).

    Returns:
        np.ndarray: (6, 6) M_o, kg (force block) and kg·m² (moment block).
    """
    M = np.zeros((6, 6))
    M[:3, :3] = obj.mass * np.eye(3)
    M[3:, 3:] = pose.K
    return M


def net_object_wrench(W: list[np.ndarray], F_e: np.ndarray) -> np.ndarray:
    """Net object wrench F_o = Σ_m W_m F_e^m (eqs. 4–6).

    Args:
        W: r grasp matrices W_m (6, 6) (`grasp_matrix`).
        F_e: (r, 6) [f; n] N, N·m, the wrench each end-effector applies to the object at its
            end-effector point, world axes.

    Returns:
        np.ndarray: (6,) F_o [N; N·m] at C, world axes.
    """
    return sum(Wm @ Fm for Wm, Fm in zip(W, F_e))


def internal_wrench(W: list[np.ndarray], F_e: np.ndarray) -> np.ndarray:
    """Internal wrench per arm at C, world axes: F_I^m = W_m F_e^m − F_o / r.

    This is eq. 7 with the paper's generalized inverse W⁺ = (1/r)[W_1⁻¹; …; W_r⁻¹] (eq. 8 for r = 2):
    F_e = W⁺ F_o + V F_I. The rows sum to zero (they do not move the object); for r = 2, row 2 is the
    paper's F_I = [f_I; n_I] and row 1 its negative.

    Args:
        W: r grasp matrices W_m (6, 6) (`grasp_matrix`).
        F_e: (r, 6) [f; n] N, N·m, the grasp wrenches (end-effector on object, at the end-effector
            point, world axes).

    Returns:
        np.ndarray: (r, 6) F_I^m [N; N·m] at C, world axes.
    """
    moved = np.array([Wm @ Fm for Wm, Fm in zip(W, F_e)])
    return moved - moved.sum(axis=0) / len(W)
