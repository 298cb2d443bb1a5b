"""The scene's geometry that a model is built with: where each arm grasps the object (given and checked
for reach, or derived from the initial configuration), the plane of motion of a planar scene, and
the constraint rows S (k × 6) the closed chain keeps (k = 3 planar, 6 spatial).
"""

from __future__ import annotations


import numpy as np

from coopsim.core.errors import ScenarioError
from coopsim.dynamics.kinematics import arm_pose, reach_check
from coopsim.core.model import REVOLUTE, ArmModel


def _arm_poses(arms: list[ArmModel], q: np.ndarray):
    ends = np.cumsum([0] + [a.n for a in arms])
    return [arm_pose(a, q[s:e]) for a, s, e in zip(arms, ends[:-1], ends[1:])]


def grasp_poses(arms, q0, order, grasp, pose, where):
    """Each arm's grasp: its end-effector frame in the object frame.

    Args:
        arms: the ArmModels, r of them.
        q0 (n,): the initial joint coordinates, stacked arm by arm (rad or m).
        order: arm indices, the carrier first (the order reach is checked in).
        grasp: per arm (position (3,) m, rotation (3, 3), field name for messages), object frame;
            None: derived from the initial configuration.
        pose: (p_C (3,) m, R_o (3, 3)) the object's pose in the world when grasps are derived; None:
            at the centroid of the end-effectors with the first arm's end-effector orientation.
        where: the scenario's name for error messages.

    Returns:
        (positions (r, 3) m, rotations (r, 3, 3)), rows by arm index, object frame.

    Raises:
        ScenarioError: an arm cannot reach its given grasp (names the field, distance and reach).
    """
    poses = _arm_poses(arms, q0)
    r = len(arms)
    if grasp is None:
        if pose is None:
            pose = (np.mean([p.p_ee for p in poses], axis=0), poses[0].R_ee)
        p_C, R_o = pose
        # p_EE − p_C as (base − p_C) + p_EE relative to the base: no world position in the difference
        gp = np.array([R_o.T @ ((p.origin - p_C) + p.p_ee_rel) for p in poses])
        gr = np.array([R_o.T @ p.R_ee for p in poses])
        return gp, gr
    gp = np.array([grasp[m][0] for m in range(r)])
    gr = np.array([grasp[m][1] for m in range(r)])
    c = order[0]
    R_o = poses[c].R_ee @ gr[c].T
    for m in order[1:]:
        # grasp point m relative to arm m's base: (o_c − o_m) + p_EE,c (relative to o_c) + R_o (g_m − g_c)
        dist, reach, ok = reach_check(arms[m], (poses[c].origin - poses[m].origin) + poses[c].p_ee_rel
                                      + R_o @ (gp[m] - gp[c]))
        if not ok:
            raise ScenarioError(f"{where}: {grasp[m][2]}: arm {arms[m].name!r} cannot reach its grasp: "
                                f"the grasp point is {dist:.4g} m from its first joint, its reach is {reach:.4g} m")
    return gp, gr


def plane_of_motion(arms: list[ArmModel], q0: np.ndarray) -> np.ndarray | None:
    """The plane the scene moves in, if it is planar.

    Rotations about parallel axes and slides keep every axis's direction, so one configuration decides.

    Args:
        arms: the ArmModels.
        q0 (n,): any joint coordinates, stacked arm by arm (rad or m).

    Returns:
        (3, 3) rows (e1, e2, n), world axes, when every revolute joint axis is parallel to one n and
        every prismatic one perpendicular to it; None otherwise, or without a revolute joint.
    """
    z = np.vstack([p.z for p in _arm_poses(arms, q0)])
    rev = np.concatenate([a.joint_type for a in arms]) == REVOLUTE
    if not rev.any():
        return None
    nrm = z[rev][0]
    if np.max(np.linalg.norm(np.cross(z[rev], nrm), axis=1)) > 1e-12 or np.any(np.abs(z[~rev] @ nrm) > 1e-12):
        return None
    e2 = np.cross(nrm, [1.0, 0.0, 0.0] if abs(nrm[0]) < 0.9 else [0.0, 1.0, 0.0])
    e2 /= np.linalg.norm(e2)
    return np.array([np.cross(e2, nrm), e2, nrm])


def row_selector(plane: np.ndarray | None) -> np.ndarray:
    """The constraint-row selector S of eqs. 14–16, which keeps the rows of a wrench or twist [f; n]
    the scene constrains.

    Args:
        plane: the (3, 3) rows (e1, e2, n) of `plane_of_motion`, or None for a spatial scene.

    Returns:
        S (k, 6): planar (k = 3) [e1ᵀ 0; e2ᵀ 0; 0 nᵀ], spatial (k = 6) I₆.
    """
    if plane is None:
        return np.eye(6)
    S = np.zeros((3, 6))
    S[0, :3], S[1, :3], S[2, 3:] = plane[0], plane[1], plane[2]
    return S
