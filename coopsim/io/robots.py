"""Arms from robot files: one serial chain of a URDF or MJCF file, read by MuJoCo's own compiler.

This is an I/O edge, like `scenario.py`, which dispatches here for an arm given as `robot:` or `file:`.
The file is parsed by `mujoco.MjSpec.from_file` (URDF and MJCF alike); everything the dynamics does not
need is deleted from the spec before it is compiled (geoms, meshes, textures, materials, sites,
tendons, sensors, equalities, contact pairs, keyframes, and actuators other than joint motors), and
inertia comes from the file's inertials only (`inertiafromgeom` off): a missing mesh file never stops a
scenario. Fixed bodies are kept apart (`fusestatic` off) so that every link keeps its name. The masses
and inertias are read from the parsed file, not from MuJoCo's compiled model, and MuJoCo compiles unit
stand-ins in their place (`compile_dynamics`): a link the scene does not use (a head camera, an antenna of
the base) never stops it, whatever its inertial says. A link the chain uses whose inertial is no rigid
body's (a negative mass or principal moment, a moment above the sum of the other two) is refused, naming
it.

The chain runs from the `base` body (link) to the `tip` body, which must lie below it. Along it:
- a body with one hinge joint (URDF revolute or continuous) or one slide joint (URDF prismatic) starts
  a link of the arm, a revolute or a prismatic joint (`coopsim.core.joints`); its frame is the body frame
  moved to the joint's anchor (MuJoCo's `pos`, zero in a URDF), so the link frame turns about its own
  origin as coopsim's convention asks (`model.ArmModel`; a slide moves every point of the link alike,
  so for it the anchor changes nothing but where the frame sits);
- a body without a joint (a URDF fixed joint), or whose joint is listed in `lock` (held at its
  reference position: 0 in a URDF), is merged into the link it hangs from: its mass and its inertia
  moved to the link's combined centre of mass by the parallel-axis theorem (exact);
- bodies hanging off the chain after its first joint (sensors, flanges, a hand beyond the tip) are
  merged the same way when nothing between them and the chain moves; a moving joint there (a gripper
  finger) is refused unless it is locked. What hangs off the chain before its first joint is fixed to
  the world and plays no part.
Ball and free joints, several joints in one body, a joint with a reference position other than 0,
a link without mass, a name not in the file and a tip that is not below the base are refused with one
line naming them (`RobotFileError`; the scenario adds the file and field), and so is a chain joint that
a joint equality couples to another (a URDF `<mimic>` joint, or the joint it mimics: MuJoCo's
`equality/joint`): an arm's joints are independent, and taking it as one would change the robot; the line
says how to lock the pair.

What comes along per joint: the position range (rad, m for a slide; ±inf where the file gives none or
the joint is continuous), the effort limit (N·m, a force in N for a slide: MuJoCo's `actuatorfrcrange`
of the joint, which a URDF's `<limit effort>` becomes, else a joint motor's `forcerange` × gear; the
smaller bound in magnitude) and, from a URDF only, the velocity limit (rad/s, m/s for a slide:
`<limit velocity>`, which MuJoCo does not keep, read from the XML attribute alone). They are the
default motor lines: stall torque (a stall force for a slide) = effort, no-load speed = velocity (inf
where none). Joint damping, friction, armature and springs in the file are not modelled by coopsim and
are ignored.

`ROBOTS` names the arms of the optional `example-robot-data` package (`pip install 'coopsim[robots]'`)
that a scenario may ask for by name (`robot: ur5`), with their chain and locked joints.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from importlib import metadata
from pathlib import Path

import mujoco
import numpy as np

from coopsim.core.errors import CoopsimError, one_line
from coopsim.core.model import PRISMATIC, REVOLUTE, ArmModel
from coopsim.core.spatial import quat_to_rot

MAX_ROBOT_FILE_BYTES = 64 << 20
ROBOTS_EXTRA = "pip install 'coopsim[robots]'"
ROBOTS_PACKAGE = "example-robot-data"


class RobotFileError(CoopsimError):
    """A robot file, or a chain in it, that cannot become an arm; one line naming the element.

    Args:
        message: the one-line message.
        field: the `chain` key at fault ('base', 'tip', 'lock'), None when it is the file itself.

    Attributes:
        field: as given.
    """

    def __init__(self, message: str, field: str | None = None):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class Robot:
    """A bundled robot (README, "Real robots") of example-robot-data, with its default chain.

    Attributes:
        file: its URDF, relative to example-robot-data's `robots/` folder.
        base: the default chain's base link name.
        tip: the default chain's tip link name.
        lock: the joints locked by default (a gripper's fingers).
    """

    file: str
    base: str
    tip: str
    lock: tuple[str, ...] = ()


def _hey5(side: str) -> tuple[str, ...]:
    """The 36 finger joints of TIAGo's Hey5 hand on `side` ('left' or 'right'), to lock."""
    phalanges = {"thumb": 2, "index": 3, "middle": 3, "ring": 3, "little": 3}
    names = ["thumb", "index", "mrl"] + [f"{finger}_{kind}" for finger, k in phalanges.items()
                                         for kind in ["abd"] + [f"{v}_{i}" for i in range(1, k + 1)
                                                                for v in ("virtual", "flex")]]
    return tuple(f"hand_{side}_{name}_joint" for name in names)


def _pr2_gripper(side: str) -> tuple[str, ...]:
    """The 6 joints of PR2's gripper on `side` ('l' or 'r'): the finger and the five that mimic it, to lock."""
    return tuple(f"{side}_gripper_{name}_joint" for name in ("l_finger", "r_finger", "l_parallel_root",
                                                             "r_parallel_root", "l_finger_tip", "r_finger_tip"))


ROBOTS: dict[str, Robot] = {
    "ur3": Robot("ur_description/urdf/ur3_robot.urdf", "base_link", "tool0"),
    "ur5": Robot("ur_description/urdf/ur5_robot.urdf", "base_link", "tool0"),
    "ur10": Robot("ur_description/urdf/ur10_robot.urdf", "base_link", "tool0"),
    "panda": Robot("panda_description/urdf/panda.urdf", "panda_link0", "panda_hand_tcp",
                   ("panda_finger_joint1", "panda_finger_joint2")),
    "kinova": Robot("kinova_description/robots/kinova.urdf", "j2s6s200_link_base", "j2s6s200_end_effector"),
    "xarm7": Robot("xarm_description/urdf/xarm7.urdf", "link_base", "link_eef"),
    "baxter_left": Robot("baxter_description/urdf/baxter.urdf", "base", "left_gripper",
                         ("l_gripper_l_finger_joint", "l_gripper_r_finger_joint")),
    "baxter_right": Robot("baxter_description/urdf/baxter.urdf", "base", "right_gripper",
                          ("r_gripper_l_finger_joint", "r_gripper_r_finger_joint")),
    "tiago_dual_left": Robot("tiago_description/robots/tiago_dual.urdf", "torso_lift_link", "hand_left_grasping_frame",
                             _hey5("left")),
    "tiago_dual_right": Robot("tiago_description/robots/tiago_dual.urdf", "torso_lift_link",
                              "hand_right_grasping_frame", _hey5("right")),
    "pr2_left": Robot("pr2_description/urdf/pr2.urdf", "torso_lift_link", "l_gripper_tool_frame", _pr2_gripper("l")),
    "pr2_right": Robot("pr2_description/urdf/pr2.urdf", "torso_lift_link", "r_gripper_tool_frame", _pr2_gripper("r")),
    "so100": Robot("so_arm_description/urdf/so100.urdf", "base", "gripper", ("gripper",)),
    "so101": Robot("so_arm_description/urdf/so101.urdf", "base_link", "gripper_frame_link", ("gripper",)),
}


def robots_folder() -> Path | None:
    """example-robot-data's `robots/` folder (its URDFs).

    Returns:
        Path | None: the folder, or None when the package is not installed (or the folder is missing).
    """
    try:
        dist = metadata.distribution(ROBOTS_PACKAGE)
    except metadata.PackageNotFoundError:
        return None
    folder = Path(dist.locate_file("cmeel.prefix/share/example-robot-data/robots"))
    return folder if folder.is_dir() else None


def robot_file(name: str) -> Path:
    """The URDF of a bundled robot.

    Args:
        name: a key of ROBOTS (e.g. 'ur5').

    Returns:
        Path: the installed URDF file.

    Raises:
        RobotFileError: naming it when it is not in ROBOTS, when example-robot-data is not installed (with
            the extra to install), or when its file is missing from the installed package.
    """
    if name not in ROBOTS:
        raise RobotFileError(f"no robot {name!r} (robots: {', '.join(ROBOTS)})")
    folder = robots_folder()
    if folder is None:
        raise RobotFileError(f"robot {name!r} comes from the {ROBOTS_PACKAGE} package, which is not installed: "
                             f"{ROBOTS_EXTRA}")
    path = folder / ROBOTS[name].file
    if not path.is_file():
        raise RobotFileError(f"robot {name!r}: {path} is missing from the installed {ROBOTS_PACKAGE}")
    return path


@dataclass(frozen=True, eq=False)
class Chain:
    """One serial chain of a robot file, n joints, as an arm in coopsim's link convention.

    Attributes:
        file: the robot file read.
        base: the base link (body) name.
        tip: the tip link (body) name.
        joint_names: the n joint names, base to tip.
        links: the arm (`model.ArmModel`: link frames at the joints, fixed bodies merged, no drawing boxes
            yet, no name) with its base link's frame at the world origin and its end-effector at the tip
            body's frame.
        joint_range: (n, 2) rad (m for a prismatic joint, `links.joint_type`), the position limits [low,
            high] (±inf: none).
        effort: (n,) N·m (N for a prismatic joint), the effort limits (inf: none).
        velocity: (n,) rad/s (m/s for a prismatic joint), the velocity limits (inf: none).
    """

    file: Path
    base: str
    tip: str
    joint_names: tuple[str, ...]
    links: ArmModel
    joint_range: np.ndarray
    effort: np.ndarray
    velocity: np.ndarray

    @property
    def n(self) -> int:
        """The number of joints n."""
        return len(self.joint_names)

    def arm(self, name: str, base_pos: np.ndarray, base_rot: np.ndarray, ee_pos: np.ndarray,
            ee_rot: np.ndarray) -> ArmModel:
        """The chain placed in the world as a named arm, each link drawn as a box from its joint to the next.

        The drawing boxes are `segment_boxes`'s.

        Args:
            name: the arm's name in the scenario.
            base_pos: (3,) m, the base link frame's origin, world axes.
            base_rot: (3, 3) world ← base link frame.
            ee_pos: (3,) m, the end-effector frame's origin in the tip body's frame.
            ee_rot: (3, 3) tip body frame ← end-effector frame.

        Returns:
            ArmModel: the arm (`links` with that name, base, end-effector and drawing boxes).
        """
        tip_pos, tip_rot = self.links.ee_pos, self.links.ee_rot
        ee = tip_pos + tip_rot @ ee_pos
        size, centre, axes = segment_boxes(self.links.joint_pos, ee)
        return replace(self.links, name=name, base_pos=np.asarray(base_pos, float),
                       base_rot=np.asarray(base_rot, float), ee_pos=ee, ee_rot=tip_rot @ ee_rot,
                       link_box=size, box_pos=centre, box_rot=axes)


DRAW_WIDTH = 0.06      # m: the cross-section of a robot-file link's drawing box


def segment_boxes(joint_pos: np.ndarray, ee_pos: np.ndarray, width: float = DRAW_WIDTH):
    """Drawing boxes of a chain whose link frames sit at its joints.

    A robot file's arm has no shapes of its own (meshes are not read). Link i is a box of cross-section
    width × width from its frame's origin, the joint, to where the next joint sits on it, joint_pos[i + 1]
    in frame i, the last link to the end-effector; a link whose next joint sits on its own (Panda's
    shoulder) is a cube of side `width` at the joint. (A prismatic next joint slides its link from that
    end.)

    Args:
        joint_pos: (n, 3) m, origin of frame i in frame i−1 (`ArmModel.joint_pos`; row 0 is not used).
        ee_pos: (3,) m, the end-effector's origin in frame n−1.
        width: m, the boxes' cross-section side.

    Returns:
        tuple[np.ndarray, np.ndarray, np.ndarray]: (size (n, 3) m along the box's axes, centre (n, 3) m in
            frame i, axes (n, 3, 3): frame i ← box axes, x along the segment) — `ArmModel.link_box`, `box_pos`,
            `box_rot`.
    """
    ends = np.vstack([joint_pos[1:], ee_pos[None]])
    length = np.linalg.norm(ends, axis=1)
    size = np.column_stack([np.where(length > 1e-9, length, width), np.full(len(ends), width),
                            np.full(len(ends), width)])
    return size, 0.5 * ends, np.array([_segment_axes(e) for e in ends])


def _segment_axes(d: np.ndarray) -> np.ndarray:
    """Right-handed axes (3, 3), columns x, y, z, with x along d (along the frame's x when d is zero)."""
    norm = np.linalg.norm(d)
    x = d / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(x, np.eye(3)[np.argmin(np.abs(x))])
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


# ------------------------------------------------------------------------------------- the file
_STRIPPED = ("geoms", "sites", "cameras", "lights", "tendons", "sensors", "equalities", "excludes", "pairs", "keys",
             "meshes", "skins", "hfields", "materials", "textures", "flexes", "numerics", "texts", "tuples")


@dataclass(frozen=True, eq=False)
class Coupling:
    """A joint equality of the file (a URDF `<mimic>`, an MJCF `<equality><joint>`): θ_joint =
    c0 + c1 θ_master + c2 θ_master² + c3 θ_master³ + c4 θ_master⁴.

    Attributes:
        joint: the joint it moves (URDF: the mimic joint).
        master: the joint it follows ("" for none: the joint is held at c0).
        coef: (5,) c0 (rad, m for a slide) … c4, MuJoCo's polycoef.
    """

    joint: str
    master: str
    coef: np.ndarray

    def relation(self) -> str:
        """The coupling as text, e.g. "r_finger = 1·l_finger + 0".

        Returns:
            str: joint = c0, or joint = c1·master + c0 (and the higher powers that are not zero).
        """
        if not self.master:
            return f"{self.joint} = {self.coef[0]:g}"
        terms = [f"{c:g}·{self.master}" + (f"^{k}" if k > 1 else "") for k, c in enumerate(self.coef[1:], 1)
                 if c != 0 or k == 1]
        return f"{self.joint} = {' + '.join(terms)} + {self.coef[0]:g}"


@dataclass(frozen=True, eq=False)
class RobotDynamics:
    """A robot file compiled for its kinematics, with the inertials read from the file (not from MuJoCo).

    Attributes:
        model: the compiled model: bodies, joints and joint motors; every body's mass and inertia in it
            are stand-ins (see `compile_dynamics`), its inertial frames (body_ipos, body_iquat) are the
            file's.
        mass: (nbody,) kg, each body's mass as the file gives it (its compiler's boundmass and
            settotalmass applied; 0 for a body without an inertial).
        inertia: (nbody, 3, 3) kg·m², each body's inertia about its centre of mass, in its inertial frame
            (body_iquat), as the file gives it (boundinertia and balanceinertia applied).
        problem: per body, None, or why its inertial is not a rigid body's (refused where the scene
            uses it).
        couplings: the active joint equalities (URDF mimic joints).
    """

    model: mujoco.MjModel
    mass: np.ndarray
    inertia: np.ndarray
    problem: tuple[str | None, ...]
    couplings: tuple[Coupling, ...]


def compile_dynamics(path: Path) -> RobotDynamics:
    """A robot file compiled by MuJoCo with only bodies, joints, inertial frames and joint motors left.

    See the module docstring for what is deleted and the compiler settings. The inertials are read from
    the file's specification before compiling and replaced in it by a unit stand-in (mass 1 kg, inertia
    diag(1, 1, 1) kg·m², in the same inertial frame), so that no body's inertial, used by the scene or
    not, can stop MuJoCo's compiler: `read_chain` checks those it uses (`RobotDynamics.problem`).

    Args:
        path: the URDF or MJCF file.

    Returns:
        RobotDynamics: the compiled model, the file's masses and inertias per body, and its joint
            couplings.

    Raises:
        RobotFileError: with MuJoCo's message when the file cannot be read or compiled, or when it is larger
            than MAX_ROBOT_FILE_BYTES.
    """
    size = path.stat().st_size
    if size > MAX_ROBOT_FILE_BYTES:
        raise RobotFileError(f"{path.name}: {size / 2 ** 20:.0f} MiB: larger than the "
                             f"{MAX_ROBOT_FILE_BYTES >> 20} MiB a robot file may hold")
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:          # MuJoCo reports a bad file as ValueError (FatalError on some)
        raise RobotFileError(f"MuJoCo cannot read {path.name}: {one_line(exc)}") from None
    couplings = tuple(Coupling(e.name1, e.name2 or "", np.array(e.data[:5], dtype=float))
                      for e in spec.equalities if e.type == mujoco.mjtEq.mjEQ_JOINT and e.active)
    for kind in _STRIPPED:
        for element in list(getattr(spec, kind)):
            spec.delete(element)
    for act in list(spec.actuators):
        if act.trntype != mujoco.mjtTrn.mjTRN_JOINT:
            spec.delete(act)
    spec.compiler.fusestatic = False
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    bodies = spec.bodies[1:]          # [0] is the world
    mass, inertia = _file_inertials(spec, bodies)
    try:
        model = spec.compile()
    except Exception as exc:
        raise RobotFileError(f"MuJoCo cannot compile {path.name} (meshes and geoms left out): "
                             f"{one_line(exc)}") from None
    ids = [b.id for b in bodies]
    full_mass, full_inertia = np.zeros(model.nbody), np.zeros((model.nbody, 3, 3))
    full_mass[ids], full_inertia[ids] = mass, inertia
    problem = [None] * model.nbody
    for i, mi, Ii in zip(ids, mass, inertia):
        problem[i] = _inertia_problem(mi, Ii, spec.compiler.balanceinertia)
        if problem[i] is None and spec.compiler.balanceinertia:
            full_inertia[i] = _balanced(Ii)
    return RobotDynamics(model, full_mass, full_inertia, tuple(problem), couplings)


def _file_inertials(spec: mujoco.MjSpec, bodies: list) -> tuple[np.ndarray, np.ndarray]:
    """(mass (k,) kg, inertia (k, 3, 3) kg·m² in each body's inertial frame) of the bodies as the file
    gives them, MuJoCo's boundmass, boundinertia and settotalmass applied as its compiler would; each
    body's inertial is then replaced in the spec by the unit stand-in (same frame)."""
    c = spec.compiler
    mass, inertia = np.zeros(len(bodies)), np.zeros((len(bodies), 3, 3))
    for k, b in enumerate(bodies):
        if b.explicitinertial:
            f = np.array(b.fullinertia, dtype=float)
            I = np.array([[f[0], f[3], f[4]], [f[3], f[1], f[5]], [f[4], f[5], f[2]]]) if np.isfinite(f[0]) \
                else np.diag(np.array(b.inertia, dtype=float))
            mass[k], inertia[k] = b.mass, I
        else:                          # no inertial: nothing from geoms (inertiafromgeom off), at the body frame
            b.ipos, b.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        if c.boundinertia > 0:
            ev, V = np.linalg.eigh(inertia[k])
            inertia[k] = V @ np.diag(np.maximum(ev, c.boundinertia)) @ V.T
        b.explicitinertial, b.mass, b.fullinertia, b.inertia = True, 1.0, [np.nan] + [0.0] * 5, [1.0, 1.0, 1.0]
    if c.boundmass > 0:
        mass = np.maximum(mass, c.boundmass)
    if c.settotalmass > 0 and mass.sum() > 0:
        scale = c.settotalmass / mass.sum()
        mass, inertia = mass * scale, inertia * scale
        c.settotalmass = -1.0
    return mass, inertia


def _inertia_problem(mass: float, inertia: np.ndarray, balance: bool) -> str | None:
    """Why (mass, inertia) is no rigid body's, None when it is one: a negative mass, a principal moment
    below zero, or one above the sum of the other two (unless the file asks MuJoCo to balance them),
    each beyond 1e-9 of the largest moment (a thin rod sits on the bound)."""
    if mass < 0:
        return f"its mass is negative ({mass:g} kg)"
    ev = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    tol = 1e-9 * max(float(np.max(np.abs(ev))), np.finfo(float).tiny)
    moments = ", ".join(f"{x:.6g}" for x in ev)
    if ev[0] < -tol:
        return f"its principal moments {moments} kg·m² are not all ≥ 0 (the matrix is not positive semi-definite)"
    if ev[0] + ev[1] < ev[2] - tol and not balance:
        return (f"its principal moments {moments} kg·m² break the triangle inequality (the largest is more than "
                f"the sum of the other two)")
    return None


def _balanced(inertia: np.ndarray) -> np.ndarray:
    """MuJoCo's balanceinertia: principal moments that break the triangle inequality all become their
    mean (the inertia unchanged when they do not)."""
    ev = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    return np.eye(3) * ev.mean() if ev[0] + ev[1] < ev[2] else inertia


def _urdf_velocity(path: Path) -> dict[str, float]:
    """{joint name: `<limit velocity>`} of a URDF (rad/s, m/s for a prismatic joint; MuJoCo's importer
    drops it); {} for MJCF."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:
        return {}
    if root.tag != "robot":
        return {}
    out = {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("velocity") is not None:
            try:
                v = float(limit.get("velocity"))
            except ValueError:
                raise RobotFileError(f"{path.name}: joint {joint.get('name')!r}: <limit velocity> is not a number, "
                                     f"got {limit.get('velocity')!r}") from None
            if v > 0:
                out[joint.get("name")] = v
    return out


# ------------------------------------------------------------------------------------ the chain
class _Pose:
    """A rigid transform (R, p): a frame's axes and origin in another frame."""

    __slots__ = ("R", "p")

    def __init__(self, R=None, p=None):
        self.R = np.eye(3) if R is None else R
        self.p = np.zeros(3) if p is None else p

    def __mul__(self, other: "_Pose") -> "_Pose":
        return _Pose(self.R @ other.R, self.R @ other.p + self.p)


def _body_pose(m: mujoco.MjModel, b: int) -> _Pose:
    return _Pose(quat_to_rot(m.body_quat[b]), m.body_pos[b].copy())


class _Link:
    """Mass properties being merged into one link (the one joint `joint` moves): point masses and inertias
    in the link frame."""

    def __init__(self, dyn: RobotDynamics, joint: str, path: Path):
        self.parts: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.dyn, self.joint, self.path = dyn, joint, path

    def add(self, b: int, X: _Pose):
        """Body b, whose frame is X in the link frame; a body whose inertial is no rigid body's is refused."""
        m, dyn = self.dyn.model, self.dyn
        if dyn.problem[b] is not None:
            raise RobotFileError(f"link {_name(m, mujoco.mjtObj.mjOBJ_BODY, b)!r} of {self.path.name}, part of the "
                                 f"link moved by joint {self.joint!r}, has an inertia no rigid body has: "
                                 f"{dyn.problem[b]}")
        if dyn.mass[b] > 0:
            R = X.R @ quat_to_rot(m.body_iquat[b])
            self.parts.append((float(dyn.mass[b]), X.p + X.R @ m.body_ipos[b], R @ dyn.inertia[b] @ R.T))

    def combined(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(mass, centre of mass, inertia about it): parallel-axis theorem, exact."""
        if not self.parts:
            return 0.0, np.zeros(3), np.zeros((3, 3))
        mass = sum(p[0] for p in self.parts)
        com = sum(p[0] * p[1] for p in self.parts) / mass
        inertia = np.zeros((3, 3))
        for mk, ck, Ik in self.parts:
            d = ck - com
            inertia += Ik + mk * (d @ d * np.eye(3) - np.outer(d, d))
        return mass, com, 0.5 * (inertia + inertia.T)


_JOINT_KIND = {mujoco.mjtJoint.mjJNT_FREE: "free (floating)", mujoco.mjtJoint.mjJNT_BALL: "ball",
               mujoco.mjtJoint.mjJNT_SLIDE: "prismatic (slide)", mujoco.mjtJoint.mjJNT_HINGE: "revolute"}
_JOINT_TYPE = {int(mujoco.mjtJoint.mjJNT_HINGE): REVOLUTE, int(mujoco.mjtJoint.mjJNT_SLIDE): PRISMATIC}   # an arm's


def _name(m: mujoco.MjModel, kind, i: int) -> str:
    return mujoco.mj_id2name(m, kind, i) or f"#{i}"


def _body_id(m: mujoco.MjModel, name: str, role: str, path: Path) -> int:
    b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
    if b < 0:
        names = [_name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(m.nbody)]
        raise RobotFileError(f"{role} link {name!r} is not in {path.name} (links: {_listed(names)})", role)
    return b


def _listed(names: list[str], limit: int = 12) -> str:
    return ", ".join(names[:limit]) + (f", … ({len(names)} in all)" if len(names) > limit else "")


def _path(m: mujoco.MjModel, base: int, tip: int, names: tuple[str, str], path: Path) -> list[int]:
    """Bodies from base (excluded) down to tip (included)."""
    bodies, b = [], tip
    while b != base:
        if b == 0:
            up_base = _ancestors(m, base)
            fork = next(a for a in _ancestors(m, tip) if a in up_base)
            where = "it is above it (swap base and tip?)" if fork == tip else \
                f"the path between them branches at link {_name(m, mujoco.mjtObj.mjOBJ_BODY, fork)!r}"
            raise RobotFileError(f"tip link {names[1]!r} is not below base link {names[0]!r} in {path.name}: {where}",
                                 "tip")
        bodies.append(b)
        b = int(m.body_parentid[b])
    return bodies[::-1]


def _ancestors(m: mujoco.MjModel, b: int) -> list[int]:
    out = [b]
    while b != 0:
        b = int(m.body_parentid[b])
        out.append(b)
    return out


def _joint_of(m: mujoco.MjModel, b: int, locked: set[int], path: Path) -> int | None:
    """The hinge or slide joint that moves body b, None if b is fixed to its parent (no joint, or
    locked)."""
    joints = [j for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]) if j not in locked]
    if not joints:
        return None
    body = _name(m, mujoco.mjtObj.mjOBJ_BODY, b)
    if len(joints) > 1:
        named = ", ".join(repr(_name(m, mujoco.mjtObj.mjOBJ_JOINT, j)) for j in joints)
        raise RobotFileError(f"link {body!r} of {path.name} has {len(joints)} joints ({named}): an arm takes one "
                             f"joint per link")
    j = joints[0]
    jname = _name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
    if int(m.jnt_type[j]) not in _JOINT_TYPE:
        raise RobotFileError(f"joint {jname!r} (link {body!r}) of {path.name} is "
                             f"{_JOINT_KIND[mujoco.mjtJoint(m.jnt_type[j])]}: an arm from a robot file takes revolute "
                             f"and prismatic joints only (lock it to hold it fixed)")
    if m.qpos0[m.jnt_qposadr[j]] != 0.0:
        what, unit = ("position", "m") if _JOINT_TYPE[int(m.jnt_type[j])] == PRISMATIC else ("angle", "rad")
        raise RobotFileError(f"joint {jname!r} of {path.name} has a reference {what} (ref) of "
                             f"{m.qpos0[m.jnt_qposadr[j]]:g} {unit}: only 0 is supported")
    return j


def _children(m: mujoco.MjModel) -> list[list[int]]:
    kids = [[] for _ in range(m.nbody)]
    for b in range(1, m.nbody):
        kids[int(m.body_parentid[b])].append(b)
    return kids


def _merge_branch(m, kids, link: _Link, top: int, X_top: _Pose, locked: set[int], on_chain: set[int], path):
    """Merge every body hanging off chain body `top` (frame X_top in the link frame) that is not on the
    chain; a moving joint among them is refused (lock it, or put it on the chain)."""
    stack = [(c, X_top * _body_pose(m, c)) for c in kids[top] if c not in on_chain]
    while stack:
        b, X = stack.pop()
        moving = [j for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]) if j not in locked]
        if moving:
            jname = _name(m, mujoco.mjtObj.mjOBJ_JOINT, moving[0])
            raise RobotFileError(
                f"the chain branches at link {_name(m, mujoco.mjtObj.mjOBJ_BODY, top)!r}: joint {jname!r} "
                f"(link {_name(m, mujoco.mjtObj.mjOBJ_BODY, b)!r}) of {path.name} moves a branch off the chain "
                f"(lock it, or choose a tip past it)")
        link.add(b, X)
        stack.extend((c, X * _body_pose(m, c)) for c in kids[b])


def _locked_ids(m: mujoco.MjModel, lock, path: Path) -> set[int]:
    ids = set()
    for name in lock:
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0:
            names = [_name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(m.njnt)]
            raise RobotFileError(f"locked joint {name!r} is not in {path.name} (joints: {_listed(names)})", "lock")
        ids.add(j)
    return ids


def read_chain(path: str | Path, base: str, tip: str, lock: tuple[str, ...] | list[str] = ()) -> Chain:
    """The serial chain from link `base` to link `tip` of a URDF or MJCF file, joints in `lock` held fixed.

    See the module docstring for how bodies are merged into links and what is refused.

    Args:
        path: the URDF or MJCF file.
        base: the base link (body) name.
        tip: the tip link (body) name, below `base`.
        lock: names of joints held at their reference position (0).

    Returns:
        Chain: the chain, its links' frames relative to the base link's frame.

    Raises:
        RobotFileError: naming what cannot be taken (a missing file, link or joint, a tip not below the base,
            an unsupported or moving off-chain joint, a link without mass, ...); `field` says which `chain`
            key is at fault.
    """
    path = Path(path)
    if not path.is_file():
        raise RobotFileError(f"robot file not found: {path}")
    dyn = compile_dynamics(path)
    m = dyn.model
    b0, bt = _body_id(m, base, "base", path), _body_id(m, tip, "tip", path)
    locked = _locked_ids(m, lock, path)
    chain = _path(m, b0, bt, (base, tip), path)
    on_chain, kids = set(chain), _children(m)
    X = _Pose()                 # the body being walked, in the current link frame (the base frame first)
    links: list[_Link] = []
    joints, placements = [], []
    for b in chain:
        X = X * _body_pose(m, b)
        j = _joint_of(m, b, locked, path)
        if j is not None:
            anchor = m.jnt_pos[j].copy()
            placements.append(_Pose(X.R, X.p + X.R @ anchor))
            joints.append(j)
            links.append(_Link(dyn, _name(m, mujoco.mjtObj.mjOBJ_JOINT, j), path))
            X = _Pose(np.eye(3), -anchor)             # body frame in the new link frame
        if links:
            links[-1].add(b, X)
            _merge_branch(m, kids, links[-1], b, X, locked, on_chain, path)
    if not joints:
        raise RobotFileError(f"no moving joint between base link {base!r} and tip link {tip!r} in {path.name}")
    parts = [link.combined() for link in links]
    for j, (mass, _, inertia) in zip(joints, parts):
        if mass <= 0 or np.linalg.eigvalsh(inertia)[0] <= 0:
            raise RobotFileError(f"the link moved by joint {_name(m, mujoco.mjtObj.mjOBJ_JOINT, j)!r} in {path.name} "
                                 f"has no mass or a singular inertia (mass {mass:g} kg): give it an <inertial>")
    names = tuple(_name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints)
    _check_couplings(dyn.couplings, names, path)
    velocity = _urdf_velocity(path)
    links = ArmModel("", np.zeros(3), np.eye(3), np.array([P.p for P in placements]),
                     np.array([P.R for P in placements]),
                     np.array([m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j]) for j in joints]),
                     np.array([p[0] for p in parts]), np.array([p[1] for p in parts]), np.array([p[2] for p in parts]),
                     np.zeros((len(joints), 3)), X.p.copy(), X.R.copy(),
                     np.array([_JOINT_TYPE[int(m.jnt_type[j])] for j in joints]))
    return Chain(path, base, tip, names, links, np.array([_range(m, j) for j in joints]),
                 np.array([_effort(m, j) for j in joints]), np.array([velocity.get(name, np.inf) for name in names]))


def _check_couplings(couplings: tuple[Coupling, ...], names: tuple[str, ...], path: Path):
    """Refuse a chain joint that a joint equality couples (a URDF mimic joint, or the joint it mimics):
    an arm's joints are independent, so taking it would change the robot."""
    for c in couplings:
        on = c.joint if c.joint in names else c.master if c.master in names else None
        if on is None:
            continue
        how = f"mimics joint {c.master!r}" if on == c.joint and c.master else \
            "is held by an equality" if on == c.joint else f"is mimicked by joint {c.joint!r}"
        pair = [x for x in (c.joint, c.master) if x]
        fix = (f"lock {' and '.join(map(repr, pair))} (chain.lock), which holds {'them' if len(pair) > 1 else 'it'} "
               f"at 0, or end the chain before {on!r}") if c.coef[0] == 0 else f"end the chain before {on!r}"
        raise RobotFileError(f"joint {on!r} on the chain of {path.name} {how} ({c.relation()}): coopsim does not "
                             f"model coupled joints; {fix}")


def _range(m: mujoco.MjModel, j: int) -> tuple[float, float]:
    return tuple(m.jnt_range[j]) if m.jnt_limited[j] else (-np.inf, np.inf)


def _effort(m: mujoco.MjModel, j: int) -> float:
    """The joint's torque limit (N·m; a force limit, N, for a slide): its actuatorfrcrange, else the
    forcerange × gear of a motor on it (the smaller bound in magnitude); inf when the file gives none."""
    if m.jnt_actfrclimited[j]:
        return float(np.min(np.abs(m.jnt_actfrcrange[j])))
    limits = [float(np.min(np.abs(m.actuator_forcerange[a])) * abs(m.actuator_gear[a, 0]))
              for a in range(m.nu) if m.actuator_trnid[a, 0] == j and m.actuator_forcelimited[a]]
    return min(limits) if limits else np.inf
