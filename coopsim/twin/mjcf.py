"""The MuJoCo twin: an MJCF model built with `mujoco.MjSpec` from the same frozen `Model`.

Only what the scene needs: one body per link (explicit inertia, a hinge joint for a revolute joint and
a slide joint for a prismatic one, along the same axis in the body frame, a visual box without
contacts), the object as a child body of the carrier arm's last link (an exact rigid attachment),
one `weld` equality per other arm, one `motor` per joint, contacts disabled. Sites mark each
end-effector and each grasp on the object.

The files in `models/` (`mjcf_text`) add what a viewer needs and nothing the dynamics sees: a keyframe
`initial` holding the consistent initial state (`simulate.initial_state`, the state `coopsim run`
starts the twin from) and τ(0) as controls, a directional light, a floor grid below the scene
(normal against gravity; no contacts, no mass) and a fixed camera `view` with the `statistic`
center/extent and free-camera angles framing it. They are saved as written (`savecompiled="false"`),
so every number is exact and the file compiles to the same model as the spec. MuJoCo loads the
model at `qpos0` (all angles zero: the loop open), so a run from the file starts with
`mj_resetDataKeyframe(m, d, 0)`; `launch_viewer` opens MuJoCo's viewer there.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import mujoco.viewer
import numpy as np

from coopsim.control.controller import closed_loop
from coopsim.core.model import PRISMATIC, ArmModel, Model, MujocoSettings, applied_torque
from coopsim.core.spatial import axis_angle_to_rot, rot_to_quat
from coopsim.forward.simulate import initial_state

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
        kind = mujoco.mjtJoint.mjJNT_SLIDE if arm.joint_type[i] == PRISMATIC else mujoco.mjtJoint.mjJNT_HINGE
        body.add_joint(name=f"a{m}_j{i}", type=kind, axis=arm.joint_axis[i])
        body.mass, body.ipos = float(arm.link_mass[i]), arm.link_com[i]
        body.fullinertia, body.explicitinertial = _full_inertia(arm.link_inertia[i]), True
        if with_geoms and np.all(arm.link_box[i] > 0):
            _visual_box(body, arm.link_box[i], arm.box_pos[i], rot_to_quat(arm.box_rot[i]))
        bodies.append(body)
        parent = body
    parent.add_site(name=f"a{m}_ee", pos=arm.ee_pos, quat=rot_to_quat(arm.ee_rot))
    return bodies


def _visual_box(body, size: np.ndarray, pos: np.ndarray, quat=(1.0, 0.0, 0.0, 0.0), rgba=(0.6, 0.6, 0.7, 1.0)):
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=0.5 * np.asarray(size), pos=pos, quat=list(quat),
                  contype=0, conaffinity=0, mass=0.0, rgba=list(rgba))


STATIC_STEP = 1e-3   # s: the step of a twin that is looked at, not run (`static_settings`)


def static_settings(model: Model) -> MujocoSettings:
    """The twin's settings where its step plays no part (a picture; MuJoCo's quantities at one state).

    Args:
        model: the frozen Model.

    Returns:
        MujocoSettings: model.mujoco, an automatic step set to STATIC_STEP.
    """
    st = model.mujoco
    return st if st.timestep is not None else replace(st, timestep=STATIC_STEP)


def build_spec(model: Model, settings: MujocoSettings | None = None, *, with_object: bool = True,
               with_geoms: bool = True, initial: tuple[np.ndarray, np.ndarray] | None = None,
               scene: bool = False) -> mujoco.MjSpec:
    """MjSpec of the MuJoCo twin of the scene: arms, object, welds and joint motors.

    Neither `initial` nor `scene` changes the dynamics.

    Args:
        model: the frozen Model.
        settings: the MuJoCo settings (timestep, integrator, solver tolerance and iterations, weld solref /
            solimp, object mass scale); None: model.mujoco.
        with_object: False: the open arms alone (no object, no welds), for stage tests.
        with_geoms: False: no visual boxes.
        initial: (q (n,) rad or m, qd (n,) rad/s or m/s) in coopsim's stacked joint order: adds the keyframe
            `initial` (time 0, that state, ctrl τ(0) N·m or N, the controller's command there); None: none.
        scene: True: adds the light, the floor (where there is gravity) and the camera framing the scene at
            `initial` (or at qpos0).

    Returns:
        mujoco.MjSpec: the spec, not compiled.

    Raises:
        ValueError: the settings' timestep is automatic (None): `coopsim.twin.weld.twin_step` sets it
            (`static_settings` for a twin that is not run).
    """
    st = settings or model.mujoco
    if st.timestep is None:
        raise ValueError("mujoco.timestep is automatic: the twin's step is chosen from the native run "
                         "(coopsim.twin.weld.twin_step) before the twin is built")
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
    if initial is not None:
        _add_keyframe(spec, model, *initial)
    if scene:
        _add_scene(spec, model)
    return spec


KEYFRAME = "initial"


def _add_keyframe(spec: mujoco.MjSpec, model: Model, q: np.ndarray, qd: np.ndarray):
    """Keyframe `initial`: time 0, (q, qd) placed at the twin's qpos/dof addresses, ctrl τ(0) (a
    controller's command there)."""
    m = spec.compile()
    qpos, qvel = m.qpos0.copy(), np.zeros(m.nv)
    qpos[qpos_address(m, model)], qvel[dof_address(m, model)] = q, qd
    ctrl = np.zeros(m.nu)
    ctrl[[m.actuator(f"a{a}_m{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)]] = \
        applied_torque(closed_loop(model).torques, 0.0, q, qd)
    spec.add_key(name=KEYFRAME, time=0.0, qpos=qpos.tolist(), qvel=qvel.tolist(), ctrl=ctrl.tolist())


def _scene_points(spec: mujoco.MjSpec) -> np.ndarray:
    """World corners of every box geom and every site, at the first keyframe (or qpos0)."""
    m = spec.compile()
    d = mujoco.MjData(m)
    if m.nkey:
        mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_kinematics(m, d)
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    points = [d.site_xpos]
    for g in np.flatnonzero(m.geom_type == mujoco.mjtGeom.mjGEOM_BOX):
        points.append(d.geom_xpos[g] + (signs * m.geom_size[g]) @ d.geom_xmat[g].reshape(3, 3).T)
    return np.vstack(points)


def _view_angles(model: Model) -> tuple[float, float]:
    """Free-camera azimuth and elevation (deg, MuJoCo's z-up convention): a planar scene seen along its
    plane normal (tilted 15° down if the plane is vertical, from 70° above if it is horizontal), a
    spatial one obliquely."""
    if model.plane is None:
        return 120.0, -25.0
    n = model.plane[2] / np.linalg.norm(model.plane[2])
    if abs(n[2]) > np.cos(np.deg2rad(45.0)):
        return 90.0, -70.0
    azimuth = np.rad2deg(np.arctan2(n[1], n[0]))
    if not 0.0 < azimuth <= 180.0:        # look from the -y side (x to the right) where possible
        azimuth = np.rad2deg(np.arctan2(-n[1], -n[0]))
    return float(azimuth), -15.0


def _add_scene(spec: mujoco.MjSpec, model: Model):
    """Light, floor and camera: visual only (no mass, no contacts, no constraint), framing the scene."""
    points = _scene_points(spec)
    lo, hi = points.min(axis=0), points.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = max(float(np.max(np.linalg.norm(points - center, axis=1))), 0.1)
    fovy = spec.visual.global_.fovy
    distance = 1.1 * radius / np.sin(np.deg2rad(fovy) / 2)
    azimuth, elevation = _view_angles(model)
    a, e = np.deg2rad(azimuth), np.deg2rad(elevation)
    forward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([1.0, 0.0, 0.0])
    z_cam = -forward
    R_cam = np.column_stack([right, np.cross(z_cam, right), z_cam])
    spec.worldbody.add_camera(name="view", pos=center - distance * forward, quat=rot_to_quat(R_cam),
                              fovy=fovy)
    # MuJoCo's free camera looks at stat.center from 1.5·stat.extent along (azimuth, elevation).
    spec.stat.center, spec.stat.extent = center, distance / 1.5
    spec.visual.global_.azimuth, spec.visual.global_.elevation = azimuth, elevation
    g = np.linalg.norm(model.gravity)
    up = -model.gravity / g if g > 0 else np.array([0.0, 0.0, 1.0])
    spec.worldbody.add_light(name="sun", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
                             pos=center + 2.0 * radius * up, dir=-up, diffuse=[0.6, 0.6, 0.6],
                             specular=[0.2, 0.2, 0.2], castshadow=True)
    if g > 0:
        spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                         builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, mark=mujoco.mjtMark.mjMARK_EDGE,
                         rgb1=[0.22, 0.25, 0.3], rgb2=[0.28, 0.31, 0.36], markrgb=[0.6, 0.6, 0.6],
                         width=300, height=300)
        cell = 10.0 ** np.round(np.log10(radius / 5.0))     # squares of 0.1 m, 1 m, ...
        material = spec.add_material(name="grid", texrepeat=[0.5 / cell, 0.5 / cell], texuniform=True,
                                     reflectance=0.1)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
        below = float(np.max((center - points) @ up))
        tilt = np.cross([0.0, 0.0, 1.0], up)
        angle = np.arctan2(np.linalg.norm(tilt), up[2])
        R_floor = np.eye(3) if np.linalg.norm(tilt) < 1e-12 else axis_angle_to_rot(tilt, angle)
        spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, material="grid",
                                pos=center - (below + 0.05 * radius) * up, quat=rot_to_quat(R_floor),
                                size=[3.0 * radius, 3.0 * radius, cell], contype=0, conaffinity=0,
                                mass=0.0)


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
    """qpos indices of the stacked joints (arm by arm) in the compiled twin.

    Args:
        mj_model: the compiled twin (`build_spec(model)` compiled).
        model: the Model it was built from.

    Returns:
        np.ndarray: (n,) int, n the joints of all arms, in coopsim's order.
    """
    return _joint_addresses(mj_model, model, mj_model.jnt_qposadr)


def dof_address(mj_model: mujoco.MjModel, model: Model) -> np.ndarray:
    """qvel / dof indices of the stacked joints (arm by arm) in the compiled twin.

    Args:
        mj_model: the compiled twin (`build_spec(model)` compiled).
        model: the Model it was built from.

    Returns:
        np.ndarray: (n,) int, n the joints of all arms, in coopsim's order.
    """
    return _joint_addresses(mj_model, model, mj_model.jnt_dofadr)


def _joint_addresses(mj_model: mujoco.MjModel, model: Model, table: np.ndarray) -> np.ndarray:
    """table[joint id] of each stacked joint (arm by arm): the twin names joint i of arm m `a{m}_j{i}`."""
    return np.array([table[mj_model.joint(f"a{m}_j{i}").id] for m, arm in enumerate(model.arms) for i in range(arm.n)])


def mjcf_spec(model: Model) -> mujoco.MjSpec:
    """The spec of a file in `models/`: the twin with its keyframe and the scene, saved as written.

    The keyframe holds the consistent initial state of `coopsim run` (`simulate.initial_state`); the scene
    is the light, floor and camera. Angles are written in radians, every number exactly as given
    (savecompiled off).

    Args:
        model: the frozen Model.

    Returns:
        mujoco.MjSpec: the spec.
    """
    init = initial_state(model)
    spec = build_spec(model, initial=(init.q, init.qd), scene=True)
    spec.compiler.degree = False
    spec.compiler.savecompiled = False   # every number as written, exactly (not 6 digits)
    spec.compiler.savecanonical = False
    return spec


def mjcf_text(model: Model, source: str) -> str:
    """The twin as MJCF text (`mjcf_spec`), with a header naming its source scenario.

    Args:
        model: the frozen Model.
        source: the scenario file's path as the header names it (and the `coopsim mjcf` command to rerun).

    Returns:
        str: the MJCF XML.
    """
    header = (f"<!-- Generated by coopsim from {source}; do not edit: run `coopsim mjcf {source}`.\n"
              f"     Numbers are exact. MuJoCo loads the model with every joint angle at zero (the loop open):\n"
              f"     start from the keyframe '{KEYFRAME}' (mj_resetDataKeyframe(m, d, 0); in the viewer\n"
              f"     'Load key' in the Simulation panel, or `python -m coopsim.twin.mjcf FILE`). -->\n")
    return header + mjcf_spec(model).to_xml()


def launch_viewer(path: str) -> None:
    """MuJoCo's interactive viewer on an MJCF file, started (and reloaded) at its first keyframe.

    Args:
        path: the MJCF file.
    """
    def load():
        m = mujoco.MjModel.from_xml_path(str(path))
        d = mujoco.MjData(m)
        if m.nkey:
            mujoco.mj_resetDataKeyframe(m, d, 0)
        mujoco.mj_forward(m, d)
        return m, d, str(path)

    mujoco.viewer.launch(loader=load)


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 2:
        sys.exit("usage: python -m coopsim.twin.mjcf MODEL.xml   (MuJoCo's viewer, started at the keyframe)")
    launch_viewer(sys.argv[1])
