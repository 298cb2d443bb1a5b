"""Stage 1 — arm kinematics: frame poses, link motion recursion, Jacobians and J̇θ̇, for revolute and
prismatic joints (the joint model: `coopsim.core.joints`).

All outputs are in world axes. The twist of a point P of the last link is [v_P; ω] and its
"acceleration" is [a_P; ω̇] with a_P = dv_P/dt (classical point acceleration), so that
[a_P; ω̇] = J_P θ̈ + J̇_P θ̇ (paper eqs. 3, 13).

Every lever arm (Jacobian columns z_j × (P − p_j), the recursion's ω × r terms, the moments of the
Gibbs–Appell backward recursion) is formed from positions relative to the arm's base point
(`ArmPose.p_rel`, `c_rel`, `p_ee_rel`, computed from the base without its world position), never from
world positions: a scene moved far from the world origin (100 km) gives the same Jacobians, mass
matrices and bias forces to the last bit, where world positions would lose ~1e-11 m to rounding.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.core.joints import joint_transform, joint_transforms, motion_subspace, revolute_mask
from coopsim.core.model import ArmModel
from coopsim.core.spatial import cross, rigid_acceleration


class ArmPose(NamedTuple):
    """Configuration-dependent geometry of one arm (world axes, SI).

    Attributes:
        p: (n, 3) m, joint origins (frame origins, a prismatic joint's slide included).
        R: (n, 3, 3) link frames.
        z: (n, 3) joint axes.
        c: (n, 3) m, link centres of mass.
        I: (n, 3, 3) kg·m², link inertias about c.
        p_ee, R_ee: (3,) m and (3, 3), the end-effector frame.
        origin: (3,) m, the arm's base point.
        p_rel, c_rel, p_ee_rel: (n, 3), (n, 3), (3,) m: p, c and p_ee relative to origin, computed
            without it (the dynamics use these: module docstring).
        joint_type: (n,) the arm's joint types (ArmModel.joint_type).
    """

    p: np.ndarray
    R: np.ndarray
    z: np.ndarray
    c: np.ndarray
    I: np.ndarray
    p_ee: np.ndarray
    R_ee: np.ndarray
    origin: np.ndarray
    p_rel: np.ndarray
    c_rel: np.ndarray
    p_ee_rel: np.ndarray
    joint_type: np.ndarray


class LinkMotion(NamedTuple):
    """Link motion from the forward recursion (`link_motion`), world axes.

    Attributes:
        w: (n, 3) rad/s, angular velocities ω_i of the links.
        dw: (n, 3) rad/s², angular accelerations ω̇_i of the links.
        a: (n, 3) m/s², accelerations a_i of the joint origins p_i (the base acceleration, −g for
            gravity, included).
    """

    w: np.ndarray
    dw: np.ndarray
    a: np.ndarray


def arm_pose(arm: ArmModel, q: np.ndarray) -> ArmPose:
    """Forward kinematics of one arm at joint coordinates q: every frame pose, centre of mass and inertia.

    With the joint transform (R_J, d_J) of joint i (`joints.joint_transform`), R_i = R_{i−1} R0_i R_J,
    p_i = p_{i−1} + R_{i−1} d_i + R_{i−1} R0_i d_J (revolute: R_J = Rot(axis_i, θ_i), d_J = 0; prismatic:
    R_J = 1, d_J = θ_i axis_i), the positions accumulated from the base point (p_rel, c_rel, p_ee_rel)
    and the world ones that plus base_pos.

    Args:
        arm: the arm's model (ArmModel).
        q: (n,) rad or m, the arm's joint coordinates.

    Returns:
        ArmPose: the configuration-dependent geometry, world axes (positions both world and relative
        to the arm's base point).
    """
    n = arm.n
    p = np.empty((n, 3))
    R = np.empty((n, 3, 3))
    p_prev, R_prev = np.zeros(3), arm.base_rot
    for i in range(n):
        R_J, d_J = joint_transform(arm.joint_type[i], arm.joint_axis[i], q[i])
        R0 = R_prev @ arm.joint_rot[i]
        p[i] = p_prev + R_prev @ arm.joint_pos[i] + R0 @ d_J
        R[i] = R0 @ R_J
        p_prev, R_prev = p[i], R[i]
    z = np.einsum("nij,nj->ni", R, arm.joint_axis)
    c = p + np.einsum("nij,nj->ni", R, arm.link_com)
    I = np.einsum("nij,njk,nlk->nil", R, arm.link_inertia, R)
    p_ee = p[-1] + R[-1] @ arm.ee_pos
    R_ee = R[-1] @ arm.ee_rot
    o = np.asarray(arm.base_pos, dtype=float)
    return ArmPose(o + p, R, z, o + c, I, o + p_ee, R_ee, o, p, c, p_ee, arm.joint_type)


def arm_frames(arm: ArmModel, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The link frames of `arm_pose` over many samples, the recursion evaluated for all samples at once.

    Args:
        arm: the arm's model (ArmModel).
        Q: (S, n) rad or m, the arm's joint coordinates at S samples.

    Returns:
        tuple[np.ndarray, np.ndarray]: joint origins p (S, n, 3) m, world positions, and link frames
        R (S, n, 3, 3), world axes.
    """
    S, n = Q.shape
    p, R = np.empty((S, n, 3)), np.empty((S, n, 3, 3))
    p_prev, R_prev = np.zeros((S, 3)), np.broadcast_to(arm.base_rot, (S, 3, 3))
    for i in range(n):
        R_J, d_J = joint_transforms(arm.joint_type[i], arm.joint_axis[i], Q[:, i])
        R0 = R_prev @ arm.joint_rot[i]
        p[:, i] = p_prev + R_prev @ arm.joint_pos[i] + np.einsum("sij,sj->si", R0, d_J)
        R[:, i] = R0 @ R_J
        p_prev, R_prev = p[:, i], R[:, i]
    return p + np.asarray(arm.base_pos, dtype=float), R


def link_motion(pose: ArmPose, qd: np.ndarray, qdd: np.ndarray, a_base: np.ndarray) -> LinkMotion:
    """Forward recursion of the recursive Gibbs–Appell formulation (paper eq. 9): every link's ω, ω̇, a.

    With ρ_i = 1 for a revolute and 0 for a prismatic joint i:

        ω_i = ω_{i−1} + ρ_i z_i θ̇_i,  ω̇_i = ω̇_{i−1} + ρ_i (z_i θ̈_i + ω_{i−1} × z_i θ̇_i),
        a_i = a_{i−1} + ω̇_{i−1} × (p_i − p_{i−1}) + ω_{i−1} × (ω_{i−1} × (p_i − p_{i−1}))
              + (1 − ρ_i)(z_i θ̈_i + 2 ω_{i−1} × z_i θ̇_i),  a_{−1} = a_base, ω_{−1} = ω̇_{−1} = 0

    (a_i the acceleration of the joint origin p_i, which a prismatic joint slides along z_i, fixed in
    link i−1: its relative acceleration and the Coriolis term; gravity enters as an upward base
    acceleration a_base = −g). The recursions are evaluated as prefix sums, which is the same
    recursion unrolled.

    Args:
        pose: the arm's ArmPose (`arm_pose`) at θ.
        qd: (n,) rad/s or m/s, joint rates θ̇.
        qdd: (n,) rad/s² or m/s², joint accelerations θ̈.
        a_base: (3,) m/s², the acceleration of the arm's base point, world axes (−g for gravity).

    Returns:
        LinkMotion: ω_i, ω̇_i and a_i of every link, world axes.
    """
    z, p, rev = pose.z, pose.p_rel, revolute_mask(pose.joint_type)
    w = np.cumsum(rev * z * qd[:, None], axis=0)
    w_prev = np.vstack([np.zeros(3), w[:-1]])
    zw = cross(w_prev, z) * qd[:, None]
    dw = np.cumsum(rev * (z * qdd[:, None] + zw), axis=0)
    slide = (1.0 - rev) * (z * qdd[:, None] + 2.0 * zw)
    da = rigid_acceleration(0.0, w[:-1], dw[:-1], p[1:] - p[:-1])
    a = a_base + np.cumsum(slide + np.vstack([np.zeros(3), da]), axis=0)
    return LinkMotion(w, dw, a)


def point_acceleration(motion: LinkMotion, pose: ArmPose, i: int, point: np.ndarray) -> np.ndarray:
    """Acceleration of a point fixed in link i: a_i + ω̇_i × r + ω_i × (ω_i × r), r = point − p_i.

    Args:
        motion: the LinkMotion (`link_motion`).
        pose: the ArmPose the motion was computed at.
        i: link index, 0-based.
        point: (3,) m, the point, relative to the arm's base point (pose.origin), world axes.

    Returns:
        np.ndarray: (3,) m/s², the point's acceleration, world axes.
    """
    return rigid_acceleration(motion.a[i], motion.w[i], motion.dw[i], point - pose.p_rel[i])


def link_com_accelerations(motion: LinkMotion, pose: ArmPose) -> np.ndarray:
    """Centre-of-mass accelerations a_ci of every link (paper eq. 9).

    Args:
        motion: the LinkMotion (`link_motion`).
        pose: the ArmPose the motion was computed at.

    Returns:
        np.ndarray: (n, 3) m/s², a_ci, world axes.
    """
    return rigid_acceleration(motion.a, motion.w, motion.dw, pose.c_rel - pose.p_rel)


def point_jacobian(pose: ArmPose, point: np.ndarray) -> np.ndarray:
    """Geometric Jacobian J of a point P fixed in the last link: the joints' motion subspaces at P.

    Columns [z_j × (P − p_j); z_j] (revolute) or [z_j; 0] (prismatic).

    Args:
        pose: the arm's ArmPose.
        point: (3,) m, P relative to the arm's base point (pose.origin), world axes.

    Returns:
        np.ndarray: (6, n), [v_P; ω] = J θ̇ (m/s, rad/s), world axes.
    """
    Jv, Jw = motion_subspace(pose.joint_type, pose.z, pose.p_rel, point)
    return np.vstack([Jv.T, Jw.T])


def point_jacobian_rate(pose: ArmPose, point: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Time derivative J̇ of `point_jacobian` at rates qd (P fixed in the last link).

    Revolute columns [ż_j × (P − p_j) + z_j × (v_P − v_j); ż_j], prismatic columns [ż_j; 0], with
    ż_j = ω_{j−1} × z_j, v_P = J_v θ̇ and v_j the velocity of frame j's origin p_j (fixed in link j):
    v_j = v_{j−1} + ω_{j−1} × (p_j − p_{j−1}) + z_j θ̇_j for a prismatic joint j (its slide moves p_j),
    without the last term for a revolute one (v_{−1} = 0, p_{−1} the base point); ω_j sums the revolute
    joints' z θ̇ up to j. J̇ θ̇ is `ee_bias_acceleration` for P = p_EE.

    Args:
        pose: the arm's ArmPose.
        point: (3,) m, P relative to the arm's base point (pose.origin), world axes.
        qd: (n,) rad/s or m/s, joint rates θ̇.

    Returns:
        np.ndarray: (6, n), J̇ (rows [v; ω], per unit rate and time), world axes.
    """
    z, p, rev = pose.z, pose.p_rel, revolute_mask(pose.joint_type)
    w = np.cumsum(z * (rev * qd[:, None]), axis=0)
    w_prev = np.vstack([np.zeros(3), w[:-1]])
    slide = z * ((1.0 - rev) * qd[:, None])
    lever = np.vstack([np.zeros(3), cross(w_prev[1:], p[1:] - p[:-1])])
    v_joint = np.cumsum(lever + slide, axis=0)
    dz = cross(w_prev, z)
    v_point = point_jacobian(pose, point)[:3] @ qd
    dJv = rev * (cross(dz, point - p) + cross(z, v_point - v_joint)) + (1.0 - rev) * dz
    return np.vstack([dJv.T, (rev * dz).T])


def ee_jacobian(pose: ArmPose) -> np.ndarray:
    """End-effector Jacobian J_m: twist [v_EE; ω] = J_m θ̇ (world axes).

    Args:
        pose: the arm's ArmPose.

    Returns:
        np.ndarray: (6, n), J_m at the end-effector point, world axes.
    """
    return point_jacobian(pose, pose.p_ee_rel)


def ee_acceleration(motion: LinkMotion, pose: ArmPose) -> np.ndarray:
    """End-effector [a_EE; ω̇] of a link motion.

    Args:
        motion: the LinkMotion (`link_motion`; its base acceleration included).
        pose: the ArmPose the motion was computed at.

    Returns:
        np.ndarray: (6,) [a_EE (m/s²); ω̇ (rad/s²)] of the end-effector point, world axes.
    """
    return np.concatenate([point_acceleration(motion, pose, len(pose.p) - 1, pose.p_ee_rel), motion.dw[-1]])


def ee_bias_acceleration(pose: ArmPose, qd: np.ndarray) -> np.ndarray:
    """J̇_m θ̇: end-effector [a_EE; ω̇] at θ̈ = 0 and no gravity.

    Args:
        pose: the arm's ArmPose.
        qd: (n,) rad/s or m/s, joint rates θ̇.

    Returns:
        np.ndarray: (6,) J̇_m θ̇ [m/s²; rad/s²] at the end-effector point, world axes.
    """
    return ee_acceleration(link_motion(pose, qd, np.zeros_like(qd), np.zeros(3)), pose)


def ee_twist(pose: ArmPose, qd: np.ndarray) -> np.ndarray:
    """End-effector twist [v_EE; ω] = J_m θ̇.

    Args:
        pose: the arm's ArmPose.
        qd: (n,) rad/s or m/s, joint rates θ̇.

    Returns:
        np.ndarray: (6,) [v_EE (m/s); ω (rad/s)], world axes.
    """
    return ee_jacobian(pose) @ qd


REACH_SLACK = 1e-9      # relative: a point at full stretch passes despite the rounding of its position


class Reach(NamedTuple):
    """The result of `reach_check`.

    Attributes:
        dist: m, distance of the point from the arm's first joint.
        reach: m, the sum of the arm's link lengths (inf with a prismatic joint).
        ok: dist <= reach (1 + REACH_SLACK).
    """

    dist: float
    reach: float
    ok: bool


def reach_check(arm: ArmModel, point: np.ndarray) -> Reach:
    """Whether `point` is within the arm's reach.

    Its distance from the first joint's origin (base_rot · joint_pos[0]) must be at most the sum of the
    distances between successive joint origins and from the last to the end-effector. The one reach test
    (scenario grasps, object-motion targets); a point relative to the base, so no world position is
    rounded. An arm with a prismatic joint has no such bound (no joint limits are modelled): reach = inf.

    Args:
        arm: the arm's model (ArmModel).
        point: (3,) m, the point relative to the arm's base point, world axes.

    Returns:
        Reach: the distance, the reach and whether it is within it.
    """
    first, reach = reach_bound(arm)
    dist = float(np.linalg.norm(np.asarray(point, dtype=float) - first))
    return Reach(dist, reach, dist <= reach * (1 + REACH_SLACK))


def reach_bound(arm: ArmModel) -> tuple[np.ndarray, float]:
    """The two numbers `reach_check` compares a point with: the first joint's origin and the arm's reach.

    Args:
        arm: the arm's model (ArmModel).

    Returns:
        tuple[np.ndarray, float]: the first joint's origin (3,) m relative to the arm's base point, world
        axes (base_rot · joint_pos[0]); the reach, m (the sum of the distances between successive joint
        origins and from the last to the end-effector; inf with a prismatic joint).
    """
    reach = float(np.sum(np.linalg.norm(arm.joint_pos[1:], axis=1)) + np.linalg.norm(arm.ee_pos))
    if np.any(arm.prismatic):
        reach = np.inf
    return arm.base_rot @ arm.joint_pos[0], reach
