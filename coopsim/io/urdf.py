"""The scene as a URDF: what `coopsim urdf` writes and a ROS 2 bag's /robot_description holds.

One tree rooted at the link `world`: each arm an open chain — a fixed joint from `world` to the arm's
base link `{arm}/base` (the base pose), one revolute (or continuous) or prismatic joint per link
`{arm}/link{j}` (the joint's origin `joint_pos`/`joint_rot` in the parent link, its axis in the link's own
frame: coopsim's frame convention is URDF's), and a fixed joint to the end-effector link `{arm}/ee`
(`ee_pos`/`ee_rot`); the object a link `object` fixed to the carrier's end effector by its grasp. `{arm}`
is the arm's ROS name token (`coopsim.core.labels.ros_arm_names`); the moving joints are named by the
scene's joint labels (`arm 1 joint 2`), as the bag's joint states are.

Each link carries its mass, centre of mass and inertia about it (frame-link axes) and its drawing box as a
visual (`ArmModel.link_box` at `box_pos`, `box_rot`; the object's box at its centre of mass); the fixed
links (`world`, bases, end effectors) carry none. Numbers are written in full (Python's shortest
round-trip form), rotations as roll-pitch-yaw (`coopsim.core.spatial.rot_to_rpy`), so the URDF loads into
the same mass matrices and frames to rounding (tests/io/test_urdf.py: Pinocchio and MuJoCo, 1e-12).

Joint limits: a revolute joint with a finite range is `revolute` with lower/upper, one without (either end
infinite) `continuous`; a prismatic joint takes its range's finite ends (URDF has no unbounded prismatic
joint: an end it leaves out reads as 0). `effort` and `velocity` are the motor's stall torque and no-load
speed, 0 where unlimited (ros2_control's and MuJoCo's reading of 0: no limit).
"""

from __future__ import annotations

from typing import NamedTuple
from xml.sax.saxutils import quoteattr

import numpy as np

from coopsim.core.labels import arm_label, joint_labels, ros_arm_names
from coopsim.core.model import PRISMATIC, Model
from coopsim.core.spatial import rot_to_rpy

ROOT = "world"
OBJECT_LINK = "object"
LINK_RGBA = (0.2, 0.45, 0.85, 1.0)
OBJECT_RGBA = (0.85, 0.55, 0.2, 0.8)


class ArmLinks(NamedTuple):
    """The URDF link names of one arm.

    Attributes:
        base: the base link, fixed to `world`.
        links: (n,) the moving links, link j moving with joint j.
        ee: the end-effector link, fixed to the last link.
    """

    base: str
    links: list[str]
    ee: str


def arm_links(model: Model) -> list[ArmLinks]:
    """The URDF link names of every arm, in stacking order: `{arm}/base`, `{arm}/link1`…, `{arm}/ee`.

    Args:
        model: the Model (its arms' names and joint counts).

    Returns:
        list[ArmLinks]: (r,) one per arm.
    """
    tokens = ros_arm_names([a.name for a in model.arms])
    return [ArmLinks(f"{t}/base", [f"{t}/link{j + 1}" for j in range(arm.n)], f"{t}/ee")
            for t, arm in zip(tokens, model.arms)]


def _num(x) -> str:
    return repr(float(x) + 0.0)      # -0.0 written as 0.0


def _nums(v) -> str:
    return " ".join(_num(x) for x in v)


def _origin(pos, rot=None) -> str:
    rpy = np.zeros(3) if rot is None else rot_to_rpy(rot)
    return f'<origin xyz="{_nums(pos)}" rpy="{_nums(rpy)}"/>'


def _inertial(mass, com, inertia) -> list[str]:
    I = np.asarray(inertia, dtype=float)
    return ["    <inertial>", f"      {_origin(com)}", f'      <mass value="{_num(mass)}"/>',
            f'      <inertia ixx="{_num(I[0, 0])}" ixy="{_num(I[0, 1])}" ixz="{_num(I[0, 2])}" '
            f'iyy="{_num(I[1, 1])}" iyz="{_num(I[1, 2])}" izz="{_num(I[2, 2])}"/>', "    </inertial>"]


def _visual(size, pos, rot, material: str) -> list[str]:
    if not np.any(np.asarray(size) > 0):
        return []
    return ["    <visual>", f"      {_origin(pos, rot)}", f'      <geometry><box size="{_nums(size)}"/></geometry>',
            f'      <material name="{material}"/>', "    </visual>"]


def _link(name: str, body: list[str] = ()) -> list[str]:
    return [f"  <link name={quoteattr(name)}/>"] if not body else \
        [f"  <link name={quoteattr(name)}>", *body, "  </link>"]


def _fixed(name: str, parent: str, child: str, pos, rot) -> list[str]:
    return [f"  <joint name={quoteattr(name)} type=\"fixed\">", f"    <parent link={quoteattr(parent)}/>",
            f"    <child link={quoteattr(child)}/>", f"    {_origin(pos, rot)}", "  </joint>"]


def _limit(joint_type: int, lo: float, hi: float, effort: float, velocity: float) -> str:
    ends = "".join(f' {k}="{_num(v)}"' for k, v in (("lower", lo), ("upper", hi)) if np.isfinite(v)) \
        if joint_type == PRISMATIC or (np.isfinite(lo) and np.isfinite(hi)) else ""
    lim = [0.0 if not np.isfinite(x) else x for x in (effort, velocity)]
    return f'<limit{ends} effort="{_num(lim[0])}" velocity="{_num(lim[1])}"/>'


def _moving(name: str, parent: str, child: str, arm, i: int, lo: float, hi: float, effort: float,
            velocity: float) -> list[str]:
    jt = int(arm.joint_type[i])
    kind = "prismatic" if jt == PRISMATIC else ("revolute" if np.isfinite(lo) and np.isfinite(hi) else "continuous")
    return [f"  <joint name={quoteattr(name)} type=\"{kind}\">", f"    <parent link={quoteattr(parent)}/>",
            f"    <child link={quoteattr(child)}/>", f"    {_origin(arm.joint_pos[i], arm.joint_rot[i])}",
            f'    <axis xyz="{_nums(arm.joint_axis[i])}"/>', f"    {_limit(jt, lo, hi, effort, velocity)}", "  </joint>"]


def urdf_text(model: Model) -> str:
    """The scene's URDF (module docstring), deterministic: the same model gives the same text.

    Args:
        model: the Model.

    Returns:
        str: the URDF document, UTF-8 text ending in a newline.
    """
    n = model.n_total
    rng = model.joint_range if model.joint_range is not None else np.tile([-np.inf, np.inf], (n, 1))
    stall, speed = model.motors.stall_torque, model.motors.no_load_speed
    labels = iter(enumerate(joint_labels(model)))
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(model.name)}>",
             f'  <material name="link"><color rgba="{_nums(LINK_RGBA)}"/></material>',
             f'  <material name="object"><color rgba="{_nums(OBJECT_RGBA)}"/></material>', *_link(ROOT)]
    names = arm_links(model)
    for m, (arm, links) in enumerate(zip(model.arms, names)):
        label = arm_label(arm.name, m)
        lines += _link(links.base) + _fixed(f"{label} base", ROOT, links.base, arm.base_pos, arm.base_rot)
        parent = links.base
        for i, link in enumerate(links.links):
            k, joint = next(labels)
            lines += _link(link, _inertial(arm.link_mass[i], arm.link_com[i], arm.link_inertia[i])
                           + _visual(arm.link_box[i], arm.box_pos[i], arm.box_rot[i], "link"))
            lines += _moving(joint, parent, link, arm, i, rng[k, 0], rng[k, 1], stall[k], speed[k])
            parent = link
        lines += _link(links.ee) + _fixed(f"{label} end effector", parent, links.ee, arm.ee_pos, arm.ee_rot)
    obj, c = model.object, model.object.carrier
    R = obj.grasp_rot[c].T                       # end effector ← object
    lines += _link(OBJECT_LINK, _inertial(obj.mass, np.zeros(3), obj.inertia)
                   + _visual(obj.box, np.zeros(3), None, "object"))
    lines += _fixed("object grasp", names[c].ee, OBJECT_LINK, -R @ obj.grasp_pos[c], R)
    return "\n".join(lines + ["</robot>", ""])
