"""The MuJoCo twin: an MJCF model built with `mujoco.MjSpec` from the same frozen `Model`.

Only what the scene needs: one body per link (explicit inertia, hinge joint, a visual box without
contacts), the object as a child body of the carrier arm's last link (an exact rigid attachment),
one `weld` equality per other arm, one `motor` per joint, contacts disabled. Sites mark each
end-effector and each grasp on the object.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .model import ArmModel, Model, MujocoSettings
from .spatial import rot_to_quat


_INTEGRATORS = {"RK4": mujoco.mjtIntegrator.mjINT_RK4, "Euler": mujoco.mjtIntegrator.mjINT_EULER,
                "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
                "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}


def _full_inertia(I: np.ndarray) -> list[float]:
    """MJCF fullinertia order: Ixx, Iyy, Izz, Ixy, Ixz, Iyz."""
    return [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]


def _add_arm(parent, arm: ArmModel, m: int, with_geoms: bool) -> list:
    """Bodies of one arm (names 'a{m}_l{i}', joints 'a{m}_j{i}', site 'a{m}_ee'); returns the bodies."""
    bodies = []
    for i in range(arm.n):
        pos, R = arm.joint_pos[i], arm.joint_rot[i]
        if i == 0:
            pos, R = arm.base_pos + arm.base_rot @ pos, arm.base_rot @ R
        body = parent.add_body(name=f"a{m}_l{i}", pos=pos, quat=rot_to_quat(R))
        body.add_joint(name=f"a{m}_j{i}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=arm.joint_axis[i])
        body.mass, body.ipos = float(arm.link_mass[i]), arm.link_com[i]
        body.fullinertia, body.explicitinertial = _full_inertia(arm.link_inertia[i]), True
        if with_geoms and np.all(arm.link_box[i] > 0):
            _visual_box(body, arm.link_box[i], arm.link_com[i])
        bodies.append(body)
        parent = body
    parent.add_site(name=f"a{m}_ee", pos=arm.ee_pos, quat=rot_to_quat(arm.ee_rot))
    return bodies


def _visual_box(body, size: np.ndarray, pos: np.ndarray, rgba=(0.6, 0.6, 0.7, 1.0)):
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=0.5 * np.asarray(size), pos=pos,
                  contype=0, conaffinity=0, mass=0.0, rgba=list(rgba))


def build_spec(model: Model, settings: MujocoSettings | None = None, *, with_object: bool = True,
               with_geoms: bool = True) -> mujoco.MjSpec:
    """MjSpec of the scene (with_object=False: the open arms alone, for stage tests)."""
    st = settings or model.mujoco
    spec = mujoco.MjSpec()
    spec.modelname = model.name
    spec.option.timestep = st.timestep
    spec.option.integrator = _INTEGRATORS[st.integrator]
    spec.option.gravity = model.gravity
    spec.option.solver = mujoco.mjtSolver.mjSOL_NEWTON
    spec.option.tolerance = st.tolerance
    spec.option.iterations = st.iterations
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_REFSAFE
    spec.compiler.autolimits = True
    last = [_add_arm(spec.worldbody, arm, m, with_geoms)[-1] for m, arm in enumerate(model.arms)]
    for m, arm in enumerate(model.arms):
        for i in range(arm.n):
            spec.add_actuator(name=f"a{m}_m{i}", target=f"a{m}_j{i}", trntype=mujoco.mjtTrn.mjTRN_JOINT,
                              gear=[1, 0, 0, 0, 0, 0])
    if with_object:
        _add_object(spec, model, last, with_geoms, st)
    return spec


def _add_object(spec, model: Model, last: list, with_geoms: bool, st: MujocoSettings):
    """Object body under the carrier's last link, grasp sites, one weld per other arm."""
    obj, c = model.object, model.object.carrier
    ee_pos, ee_rot = model.arms[c].ee_pos, model.arms[c].ee_rot
    R_eo = obj.grasp_rot[c].T  # object frame in the carrier's EE frame
    p_eo = -R_eo @ obj.grasp_pos[c]
    body = last[c].add_body(name="object", pos=ee_pos + ee_rot @ p_eo, quat=rot_to_quat(ee_rot @ R_eo))
    scale = st.object_mass_scale
    body.mass, body.ipos = float(obj.mass * scale), [0.0, 0.0, 0.0]
    body.fullinertia, body.explicitinertial = _full_inertia(obj.inertia * scale), True
    if with_geoms and np.all(obj.box > 0):
        _visual_box(body, obj.box, np.zeros(3), rgba=(0.8, 0.5, 0.2, 1.0))
    for m in range(model.r):
        body.add_site(name=f"grasp{m}", pos=obj.grasp_pos[m], quat=rot_to_quat(obj.grasp_rot[m]))
    for m in range(model.r):
        if m == c:
            continue
        arm = model.arms[m]
        # MuJoCo welds the point `relpose[:3]` of body1 to the point `anchor` of body2 and holds
        # body2's orientation in body1 at `relpose[3:]`: both points are the grasp point.
        R_ol = obj.grasp_rot[m] @ arm.ee_rot.T  # arm m's last link in the object frame
        eq = spec.add_equality(name=f"weld{m}", type=mujoco.mjtEq.mjEQ_WELD,
                               objtype=mujoco.mjtObj.mjOBJ_BODY, name1="object", name2=f"a{m}_l{arm.n - 1}")
        data = np.zeros(11)
        data[0:3] = arm.ee_pos             # anchor: the grasp point in body2 (arm m's last link)
        data[3:6] = obj.grasp_pos[m]       # the same point in body1 (the object)
        data[6:10] = rot_to_quat(R_ol)     # body2's orientation in body1
        data[10] = 1.0                     # torquescale
        eq.data = np.concatenate([data, np.zeros(len(eq.data) - 11)])
        eq.solref, eq.solimp = list(st.solref()), list(st.weld_solimp)


def qpos_address(mj_model: mujoco.MjModel, model: Model) -> np.ndarray:
    """qpos indices (n,) of the stacked joints (arm by arm) in the compiled twin."""
    return np.array([mj_model.jnt_qposadr[mj_model.joint(f"a{m}_j{i}").id]
                     for m, arm in enumerate(model.arms) for i in range(arm.n)])


def dof_address(mj_model: mujoco.MjModel, model: Model) -> np.ndarray:
    """qvel / dof indices (n,) of the stacked joints in the compiled twin."""
    return np.array([mj_model.jnt_dofadr[mj_model.joint(f"a{m}_j{i}").id]
                     for m, arm in enumerate(model.arms) for i in range(arm.n)])


def mjcf_text(model: Model, source: str) -> str:
    """The twin as MJCF text, with a header naming its source scenario. MuJoCo's XML writer keeps 6
    significant digits, so the file is for viewing and sharing; the harness compiles the MjSpec at
    full precision."""
    header = (f"<!-- Generated by coopsim from {source}; do not edit: run `coopsim mjcf {source}`.\n"
              f"     Numbers are rounded to 6 significant digits by MuJoCo's XML writer. -->\n")
    return header + build_spec(model).to_xml()
