"""Stage 2 — recursive Gibbs–Appell dynamics of one open arm (paper eqs. 9–10).

The Gibbs function of link i (mass m_i, inertia I_i about its centre of mass c_i, world axes) is
    S_i = ½ m_i a_ci·a_ci + ½ ω̇_iᵀ I_i ω̇_i + ω̇_iᵀ (ω_i × I_i ω_i) + (terms free of θ̈),
and Appell's equations ∂S/∂θ̈ = τ with S = Σ S_i give, since ∂a_ci/∂θ̈_j = z_j × (c_i − p_j) and
∂ω̇_i/∂θ̈_j = z_j (j ≤ i) for a revolute joint j,
    ∂S/∂θ̈_j = z_j · Σ_{i≥j} [(c_i − p_j) × m_i a_ci + I_i ω̇_i + ω_i × I_i ω_i],
and, since ∂a_ci/∂θ̈_j = z_j and ∂ω̇_i/∂θ̈_j = 0 for a prismatic joint j (its motion subspace,
`coopsim.core.joints`), ∂S/∂θ̈_j = z_j · Σ_{i≥j} m_i a_ci (a force, N).
∂S/∂θ̈ is affine in θ̈: ∂S/∂θ̈ = I_m θ̈ − Re_m, where the mass matrix I_m = ∂²S/∂θ̈² is the Gram
matrix of the partial accelerations and −Re_m (velocity and gravity terms, "bias forces" h) is
∂S/∂θ̈ evaluated at θ̈ = 0. Arm m alone: I_m θ̈_m = Re_m + τ_m − J_mᵀ F_e^m (eq. 10).
"""

from __future__ import annotations

import numpy as np

from coopsim.core.joints import motion_subspace
from coopsim.dynamics.kinematics import ArmPose, LinkMotion, ee_acceleration, link_com_accelerations, link_motion
from coopsim.core.model import PRISMATIC, ArmModel
from coopsim.core.spatial import cross


def gibbs_gradient(arm: ArmModel, pose: ArmPose, qd: np.ndarray, qdd: np.ndarray, g: np.ndarray) -> np.ndarray:
    """∂S/∂θ̈ at (θ, θ̇, θ̈) with gravity g (forward recursion, then `gibbs_gradient_of_motion`).

    Args:
        arm: the arm's model (ArmModel).
        pose: the ArmPose at θ (`kinematics.arm_pose`).
        qd: (n,) rad/s or m/s, joint rates θ̇.
        qdd: (n,) rad/s² or m/s², joint accelerations θ̈.
        g: (3,) m/s², gravity, world axes.

    Returns:
        np.ndarray: (n,) N·m (N on a prismatic joint), ∂S/∂θ̈ = I_m θ̈ − Re_m.
    """
    return gibbs_gradient_of_motion(arm, pose, link_motion(pose, qd, qdd, -g))


def gibbs_gradient_of_motion(arm: ArmModel, pose: ArmPose, motion: LinkMotion) -> np.ndarray:
    """∂S/∂θ̈ for a link motion of the forward recursion, by the backward recursion.

        F_j = m_j a_cj + F_{j+1},
        N_j = (c_j − p_j) × m_j a_cj + I_j ω̇_j + ω_j × I_j ω_j + N_{j+1} + (p_{j+1} − p_j) × F_{j+1},

    ∂S/∂θ̈_j = z_j · N_j for a revolute joint, z_j · F_j for a prismatic one (evaluated with reverse
    prefix sums: moments about the arm's base point, then moved to p_j, positions relative to the base
    point so that no lever arm is a world position).

    Args:
        arm: the arm's model (ArmModel; its link masses).
        pose: the ArmPose the motion was computed at.
        motion: the LinkMotion (`kinematics.link_motion`; gravity as the base acceleration −g).

    Returns:
        np.ndarray: (n,) N·m (N on a prismatic joint), ∂S/∂θ̈.
    """
    ma = arm.link_mass[:, None] * link_com_accelerations(motion, pose)
    Iw = np.einsum("nij,nj->ni", pose.I, motion.w)
    local = cross(pose.c_rel, ma) + np.einsum("nij,nj->ni", pose.I, motion.dw) + cross(motion.w, Iw)
    F = np.cumsum(ma[::-1], axis=0)[::-1]
    N = np.cumsum(local[::-1], axis=0)[::-1] - cross(pose.p_rel, F)
    return np.einsum("ni,ni->n", pose.z, np.where(pose.joint_type[:, None] == PRISMATIC, F, N))


def mass_matrix(arm: ArmModel, pose: ArmPose) -> np.ndarray:
    """Mass matrix I_m = ∂²S/∂θ̈² = Σ_i m_i Jv_ciᵀ Jv_ci + Jω_iᵀ I_i Jω_i.

    The partial accelerations [Jv_ci; Jω_i][:, j] are the motion subspace of joint j at c_i for j ≤ i
    (revolute [z_j × (c_i − p_j); z_j], prismatic [z_j; 0]; zero for j > i).

    Args:
        arm: the arm's model (ArmModel; its link masses).
        pose: the ArmPose at θ (link inertias in world axes).

    Returns:
        np.ndarray: (n, n) I_m, symmetric (kg·m², kg·m or kg by joint types).
    """
    n = arm.n
    below = np.tril(np.ones((n, n)))[:, :, None]  # [i, j] = 1 where j <= i
    Jv, Jw = motion_subspace(pose.joint_type, pose.z, pose.p_rel, pose.c_rel[:, None, :])
    Jv, Jw = Jv * below, Jw * below
    M = np.einsum("i,ijk,ilk->jl", arm.link_mass, Jv, Jv)
    M += np.einsum("ijk,ikm,ilm->jl", Jw, pose.I, Jw)
    return 0.5 * (M + M.T)


def bias_forces(arm: ArmModel, pose: ArmPose, qd: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Bias forces h = −Re_m: Coriolis, centrifugal and gravity terms, ∂S/∂θ̈ at θ̈ = 0.

    Args:
        arm: the arm's model (ArmModel).
        pose: the ArmPose at θ.
        qd: (n,) rad/s or m/s, joint rates θ̇.
        g: (3,) m/s², gravity, world axes.

    Returns:
        np.ndarray: (n,) N·m (N on a prismatic joint), h.
    """
    return gibbs_gradient(arm, pose, qd, np.zeros_like(qd), g)


def arm_dynamics(arm: ArmModel, pose: ArmPose, qd: np.ndarray,
                 g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(I_m, h, J̇_mθ̇_m) of eq. 10 written as I_m θ̈ + h = τ_m − J_mᵀ F_e^m, from one forward recursion.

    The recursion runs at θ̈ = 0 (the end-effector bias acceleration is that motion's, less the base's −g).

    Args:
        arm: the arm's model (ArmModel).
        pose: the ArmPose at θ.
        qd: (n,) rad/s or m/s, joint rates θ̇.
        g: (3,) m/s², gravity, world axes.

    Returns:
        tuple[np.ndarray, np.ndarray, np.ndarray]: the mass matrix I_m (n, n) (`mass_matrix`), the bias
        forces h (n,) N·m (N on a prismatic joint) and J̇_mθ̇_m (6,) [m/s²; rad/s²] at the end-effector
        point, world axes.
    """
    motion = link_motion(pose, qd, np.zeros_like(qd), -g)
    Jd_qd = ee_acceleration(motion, pose) + np.concatenate([g, np.zeros(3)])
    return mass_matrix(arm, pose), gibbs_gradient_of_motion(arm, pose, motion), Jd_qd
