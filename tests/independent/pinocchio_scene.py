"""A coopsim scenario file built in Pinocchio from the YAML text alone.

Nothing here imports coopsim: the file is read with PyYAML and turned into Pinocchio models by the
conventions of README.md ("Model and conventions", "Scenario files"), so that the tests can check
coopsim's own parsing (rotations, joint frames, inertias, grasp derivation, end-effector frames) and
dynamics against a build that shares none of its code.

What the README states and this follows: SI units, radians unless a key ends in `_deg`; twists
[v; ω] and wrenches [f; n] in world axes; `F_e^m` is the wrench end-effector m applies to the object,
at its end-effector point; the object is rigidly attached to the first grasping arm (the first entry
of `grasps`, arm 0 for `grasps: derive`) and the other arms close the loop; a link `joint.position`
is in the previous link frame and defaults to the end of the previous box; a link `box` lies along
local +x; the object frame sits at its centre of mass; `grasps` give the end-effector frame in the
object frame, or are derived from the initial configuration and the object `pose`; torque tables are
piecewise linear, a csv has a header row, then time and one column per joint.

What the README does not state, assumed here (each is a `Conventions` field where a wrong choice is
cheap to build, so that a test can prove the comparison notices it):
- `rpy` = [roll, pitch, yaw] gives R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes x, then y, then z);
- `quat` = [w, x, y, z] (normalised here);
- `cross_section` [a, b] = the box's sizes along local y and z; a `box` `size` is along x, y, z;
- a link frame is the previous link frame (the base frame for the first joint) moved by the joint's
  `position`, turned by its `rpy`/`quat`, then by θ about `axis` (given in that turned frame,
  normalised, default +z) — or, for a joint of `type: prismatic`, slid θ (m) along that axis; the joint
  position default for the first joint (no previous box) and after an `inertial` link is the frame
  origin;
- a link box's centre of mass is at (length/2, 0, 0), inertia that of a solid box; an `inertial`
  block's `com` is in the link frame (default 0) and its `inertia` is about the centre of mass in
  link axes, a 3×3 matrix or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz];
- `end_effector` defaults to the end of the last box, (length, 0, 0), unrotated;
- `grasps: derive` without an object `pose`: the object frame at the centroid of the end-effector
  points, turned as the first arm's end-effector;
- torque tables are held constant outside their time range, a missing `torque` is zero, a csv path
  is relative to the scenario file's folder; missing `initial.rates` are zero; missing `gravity` is
  [0, 0, −9.81].
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml
from scipy.integrate import solve_ivp

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class Conventions:
    """Reading choices where a scenario key could mean more than one thing. The defaults are this
    module's reading of the README (see the module docstring); the alternatives exist only to prove
    that the comparison catches a wrong reading.
    rpy_order: the product order of the elementary rotations, "zyx" = Rz(yaw) Ry(pitch) Rx(roll),
    "xyz" = Rx(roll) Ry(pitch) Rz(yaw); quat_order: "wxyz" or "xyzw"; cross_section: "yz" (the two
    sizes along local y then z) or "zy"; joint_default: "box_end" ((previous box length, 0, 0)) or
    "origin"."""

    rpy_order: str = "zyx"
    quat_order: str = "wxyz"
    cross_section: str = "yz"
    joint_default: str = "box_end"


README = Conventions()


def rpy_matrix(rpy, order: str = "zyx") -> np.ndarray:
    """R = R_{order[0]} R_{order[1]} R_{order[2]}, each an elementary rotation by its angle of
    rpy = [roll (about x), pitch (about y), yaw (about z)] rad."""
    angle = {"x": rpy[0], "y": rpy[1], "z": rpy[2]}
    R = np.eye(3)
    for a in order:
        R = R @ pin.exp3(float(angle[a]) * np.eye(3)["xyz".index(a)])
    return R


def quat_matrix(quat, order: str = "wxyz") -> np.ndarray:
    """Rotation of the quaternion `quat` listed in `order` (normalised)."""
    c = dict(zip(order, np.asarray(quat, dtype=float)))
    q = pin.Quaternion(c["w"], c["x"], c["y"], c["z"])
    q.normalize()
    return q.matrix()


def _angles(d: dict, key: str, default=None) -> np.ndarray | None:
    if f"{key}_deg" in d:
        return np.deg2rad(np.asarray(d[f"{key}_deg"], dtype=float))
    if key in d:
        return np.asarray(d[key], dtype=float)
    return None if default is None else np.asarray(default, dtype=float)


def _rotation(d: dict, conv: Conventions) -> np.ndarray:
    if "quat" in d:
        return quat_matrix(d["quat"], conv.quat_order)
    rpy = _angles(d, "rpy")
    return np.eye(3) if rpy is None else rpy_matrix(rpy, conv.rpy_order)


def _pose(d: dict | None, conv: Conventions) -> pin.SE3:
    d = d or {}
    return pin.SE3(_rotation(d, conv), np.asarray(d.get("position", [0.0, 0.0, 0.0]), dtype=float))


def _inertia_matrix(v) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape == (6,):
        xx, yy, zz, xy, xz, yz = a
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return a.reshape(3, 3)


def _box(box: dict, conv: Conventions) -> tuple[float, np.ndarray]:
    """(mass, size along local x, y, z) of a `box` block."""
    if "size" in box:
        size = np.asarray(box["size"], dtype=float)
    else:
        a, b = box["cross_section"]
        if conv.cross_section == "zy":
            a, b = b, a
        size = np.array([box["length"], a, b], dtype=float)
    return float(box["density"]) * float(np.prod(size)), size


def _solid_box(mass: float, size: np.ndarray) -> np.ndarray:
    x2, y2, z2 = size ** 2
    return mass / 12.0 * np.diag([y2 + z2, x2 + z2, x2 + y2])


@dataclass
class _Link:
    placement: pin.SE3        # joint frame at θ = 0 in the previous link frame
    axis: np.ndarray          # unit, joint frame
    inertia: pin.Inertia      # link frame (= joint frame)
    prismatic: bool = False   # joint `type: prismatic` (slides along axis), else revolute


@dataclass
class ArmSpec:
    """One arm as read: name; base (SE3, world ← base); links; ee (SE3, last link ← end-effector);
    q0, qd0 (n,) initial state as given; torque (times (k,), values (k, n))."""

    name: str
    base: pin.SE3
    links: list
    ee: pin.SE3
    q0: np.ndarray
    qd0: np.ndarray
    torque: tuple

    @property
    def n(self) -> int:
        return len(self.links)


def _torque_table(arm: dict, n: int, folder: Path) -> tuple[np.ndarray, np.ndarray]:
    tq = arm.get("torque")
    if tq is None:
        return np.zeros(1), np.zeros((1, n))
    if "constant" in tq:
        return np.zeros(1), np.asarray(tq["constant"], dtype=float).reshape(1, n)
    if "table" in tq:
        return np.asarray(tq["table"]["time"], dtype=float), np.asarray(tq["table"]["values"], dtype=float)
    with open(folder / tq["csv"], newline="") as fh:
        rows = [r for r in csv.reader(fh) if r]
    data = np.array([[float(x) for x in r] for r in rows[1:]])
    return data[:, 0], data[:, 1:]


def _read_arm(arm: dict, index: int, folder: Path, conv: Conventions) -> ArmSpec:
    links = []
    prev_length = 0.0
    for link in arm["links"]:
        joint = link.get("joint") or {}
        default = [prev_length if conv.joint_default == "box_end" else 0.0, 0.0, 0.0]
        position = np.asarray(joint.get("position", default), dtype=float)
        axis = np.asarray(joint.get("axis", [0.0, 0.0, 1.0]), dtype=float)
        if "box" in link:
            mass, size = _box(link["box"], conv)
            inertia = pin.Inertia(mass, np.array([size[0] / 2.0, 0.0, 0.0]), _solid_box(mass, size))
            prev_length = float(size[0])
        else:
            block = link["inertial"]
            inertia = pin.Inertia(float(block["mass"]), np.asarray(block.get("com", [0.0, 0.0, 0.0]), dtype=float),
                                  _inertia_matrix(block["inertia"]))
            prev_length = 0.0
        links.append(_Link(pin.SE3(_rotation(joint, conv), position), axis / np.linalg.norm(axis), inertia,
                           joint.get("type", "revolute") == "prismatic"))
    ee = dict(arm.get("end_effector") or {})
    ee.setdefault("position", [prev_length, 0.0, 0.0])
    n = len(links)
    init = arm["initial"]
    return ArmSpec(arm.get("name", f"arm{index + 1}"), _pose(arm.get("base"), conv), links, _pose(ee, conv),
                   _angles(init, "angles"), _angles(init, "rates", np.zeros(n)), _torque_table(arm, n, folder))


def _joint_model(link: _Link):
    """Pinocchio's revolute (RX/RY/RZ, RevoluteUnaligned) or prismatic (PX/PY/PZ, PrismaticUnaligned)
    joint about/along the link's axis."""
    aligned = (pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ) if link.prismatic else \
        (pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ)
    for k, jm in enumerate(aligned):
        if np.array_equal(link.axis, np.eye(3)[k]):
            return jm()
    return (pin.JointModelPrismaticUnaligned if link.prismatic else pin.JointModelRevoluteUnaligned)(link.axis)


def _add_arms(pm: pin.Model, arms: list[ArmSpec]) -> list[list[int]]:
    """Every arm as its own chain from the world, arm after arm (Pinocchio's q is then the arms'
    angles stacked in file order); returns the joint ids of each arm."""
    ids = []
    for m, arm in enumerate(arms):
        parent, own = 0, []
        for i, link in enumerate(arm.links):
            placement = arm.base * link.placement if i == 0 else link.placement
            parent = pm.addJoint(parent, _joint_model(link), placement, f"{arm.name}_j{i}")
            pm.appendBodyToJoint(parent, link.inertia, pin.SE3.Identity())
            own.append(parent)
        pm.addFrame(pin.Frame(f"{arm.name}_ee", parent, arm.ee, pin.FrameType.OP_FRAME))
        ids.append(own)
    return ids


class PinocchioScene:
    """The scene of one scenario file in Pinocchio.

    `open`: the arms alone (no object); `model`: the arms with the object's inertia appended to the
    carrier's last link and one 6D rigid constraint (LOCAL_WORLD_ALIGNED) per other arm m between its
    end-effector frame and its grasp frame carried by the object. Pinocchio's q and v are the arms'
    joint angles and rates stacked in file order (coopsim's stacked order)."""

    def __init__(self, path: str | Path, conventions: Conventions = README):
        path = Path(path)
        data = yaml.safe_load(path.read_text())
        conv = self.conventions = conventions
        self.name = data.get("name", path.stem)
        self.gravity = np.asarray(data.get("gravity", [0.0, 0.0, -9.81]), dtype=float)
        self.duration = float(data["duration"])
        self.arms = [self._read_arm(a, i, path.parent, conv) for i, a in enumerate(data["arms"])]
        self.r = len(self.arms)
        ends = np.cumsum([0] + [a.n for a in self.arms])
        self.slices = [slice(int(a), int(b)) for a, b in zip(ends[:-1], ends[1:])]
        self.n = int(ends[-1])
        self.q0 = np.concatenate([a.q0 for a in self.arms])
        self.qd0 = np.concatenate([a.qd0 for a in self.arms])

        self.open = pin.Model()
        self.model = pin.Model()
        for pm in (self.open, self.model):
            pm.gravity = pin.Motion(self.gravity, np.zeros(3))
        self.joint_ids = _add_arms(self.open, self.arms)
        _add_arms(self.model, self.arms)
        for pm in (self.open, self.model):
            if pm.nq != self.n or pm.nv != self.n or [pm.joints[j].idx_q for ids in self.joint_ids for j in ids] \
                    != list(range(self.n)):
                raise RuntimeError("pinocchio's joint order is not the arms' stacked order")
        self.ee_frames = [self.open.getFrameId(f"{a.name}_ee") for a in self.arms]
        self.open_data = self.open.createData()

        obj = data["object"]
        if "box" in obj:
            self.object_mass, size = _box(obj["box"], conv)
            self.object_inertia = _solid_box(self.object_mass, size)
        else:
            self.object_mass = float(obj["inertial"]["mass"])
            self.object_inertia = _inertia_matrix(obj["inertial"]["inertia"])
        self.carrier, self.grasps = self._grasps(obj, conv)

        c = self.carrier
        last = [ids[-1] for ids in self.joint_ids]
        X_lo = self.arms[c].ee * self.grasps[c].inverse()       # object frame in the carrier's last link
        self.model.appendBodyToJoint(last[c], pin.Inertia(self.object_mass, np.zeros(3), self.object_inertia), X_lo)
        self.object_frame = self.model.addFrame(pin.Frame("object", last[c], X_lo, pin.FrameType.OP_FRAME))
        self.others = [m for m in range(self.r) if m != c]
        self.constraints = pin.StdVec_RigidConstraintModel()
        self.grasp_frames = {}
        for m in self.others:
            X_g = X_lo * self.grasps[m]
            self.grasp_frames[m] = self.model.addFrame(pin.Frame(f"grasp_{m}", last[c], X_g, pin.FrameType.OP_FRAME))
            self.constraints.append(pin.RigidConstraintModel(pin.ContactType.CONTACT_6D, self.model, last[m],
                                                             self.arms[m].ee, last[c], X_g, LWA))
        self.chain_ee_frames = [self.model.getFrameId(f"{a.name}_ee") for a in self.arms]
        self.data = self.model.createData()
        self.constraint_data = pin.StdVec_RigidConstraintData()
        for cm in self.constraints:
            self.constraint_data.append(cm.createData())
        pin.initConstraintDynamics(self.model, self.data, self.constraints, self.constraint_data)
        self.normal = self._plane_normal()
        # a planar scene's out-of-plane constraint rows vanish identically (rank-deficient): the
        # proximal iterations regularise them; a spatial scene's are an exact Cholesky solve
        self.settings = pin.ProximalSettings(1e-14, 0.0, 1) if self.normal is None else \
            pin.ProximalSettings(1e-14, 1e-12, 50)

    # ---------------------------------------------------------------- reading
    def _read_arm(self, arm: dict, index: int, folder: Path, conv: Conventions) -> ArmSpec:
        """One arm of the file (a subclass reads other kinds of arm, `pinocchio_urdf.RobotScene`)."""
        return _read_arm(arm, index, folder, conv)

    def _grasps(self, obj: dict, conv: Conventions) -> tuple[int, list[pin.SE3]]:
        """(carrier index, grasp frames G_m = object ← end-effector m)."""
        names = [a.name for a in self.arms]
        if obj["grasps"] == "derive":
            ees = self.ee_poses(self.q0)
            if "pose" in obj:
                T_o = _pose(obj["pose"], conv)
            else:
                T_o = pin.SE3(ees[0].rotation, np.mean([e.translation for e in ees], axis=0))
            return 0, [T_o.inverse() * e for e in ees]
        grasps, order = [None] * self.r, []
        for g in obj["grasps"]:
            m = names.index(g["arm"]) if g["arm"] in names else int(g["arm"])
            grasps[m] = _pose(g, conv)
            order.append(m)
        return order[0], grasps

    def _plane_normal(self) -> np.ndarray | None:
        """The common direction of every revolute joint axis (world) at the initial angles if they are
        all parallel and every prismatic axis is perpendicular to it (a planar scene; rotations about
        parallel axes and slides keep them so), else None."""
        pin.forwardKinematics(self.open, self.open_data, self.q0)
        turn, slide = [], []
        for arm, ids in zip(self.arms, self.joint_ids):
            for link, j in zip(arm.links, ids):
                (slide if link.prismatic else turn).append(self.open_data.oMi[j].rotation @ link.axis)
        if not turn:
            return None
        nrm = turn[0]
        planar = all(np.linalg.norm(np.cross(a, nrm)) < 1e-12 for a in turn) and all(abs(a @ nrm) < 1e-12 for a in slide)
        return nrm if planar else None

    # ---------------------------------------------------------------- open arms
    def link_poses(self, q) -> list[list[pin.SE3]]:
        """Per arm, the world pose of each link frame (at its joint)."""
        pin.forwardKinematics(self.open, self.open_data, np.asarray(q, dtype=float))
        return [[self.open_data.oMi[j].copy() for j in ids] for ids in self.joint_ids]

    def ee_poses(self, q) -> list[pin.SE3]:
        pin.forwardKinematics(self.open, self.open_data, np.asarray(q, dtype=float))
        return [pin.updateFramePlacement(self.open, self.open_data, f).copy() for f in self.ee_frames]

    def arm_dynamics(self, q, qd, with_object: bool = False) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per arm (mass matrix (n_m, n_m), bias forces h = C θ̇ + g (n_m,)) of M θ̈ + h = τ, the arms
        alone or (with_object) the object's inertia on the carrier."""
        pm, d = (self.model, self.data) if with_object else (self.open, self.open_data)
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        M = pin.crba(pm, d, q).copy()
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(pm, d, q, qd).copy()
        if np.any(np.abs(M[self._off_block()]) > 0):
            raise RuntimeError("arms coupled in the mass matrix")
        return [M[s, s] for s in self.slices], [h[s] for s in self.slices]

    def _off_block(self) -> np.ndarray:
        mask = np.ones((self.n, self.n), dtype=bool)
        for s in self.slices:
            mask[s, s] = False
        return mask

    # ---------------------------------------------------------------- loop closure
    def _frames(self, q):
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        return [(self.data.oMf[self.chain_ee_frames[m]], self.data.oMf[self.grasp_frames[m]]) for m in self.others]

    def closure_error(self, q) -> np.ndarray:
        """Per other arm, [p_grasp − p_ee; log(R_grasp R_eeᵀ)] (world), stacked (6(r−1),)."""
        q = np.asarray(q, dtype=float)
        return np.concatenate([np.concatenate([g.translation - e.translation, pin.log3(g.rotation @ e.rotation.T)])
                               for e, g in self._frames(q)])

    def closure_jacobian(self, q) -> np.ndarray:
        """The closure error's Jacobian: per other arm, J_grasp − J_ee (LOCAL_WORLD_ALIGNED, each at its
        frame's origin), stacked (6(r−1), n) (exact for the position rows; for the rotation rows where
        the error vanishes). On the manifold the two frames coincide and J θ̇ = 0 is the velocity
        constraint."""
        q = np.asarray(q, dtype=float)
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        rows = []
        for m in self.others:
            fe, fg = self.chain_ee_frames[m], self.grasp_frames[m]
            Je = pin.getFrameJacobian(self.model, self.data, fe, LWA)
            rows.append(pin.getFrameJacobian(self.model, self.data, fg, LWA) - Je)
        return np.vstack(rows)

    def project(self, q, qd, tol: float = 1e-14, max_iter: int = 30) -> tuple[np.ndarray, np.ndarray] | None:
        """A consistent state near (q, qd): Gauss–Newton steps of minimum norm on the closure error,
        then the rates projected onto the null space of the closure Jacobian; None if it does not
        converge."""
        q = np.array(q, dtype=float)
        for _ in range(max_iter):
            err = self.closure_error(q)
            if np.max(np.abs(err)) <= tol:
                J = self.closure_jacobian(q)
                qd = np.asarray(qd, dtype=float)
                return q, qd - np.linalg.lstsq(J, J @ qd, rcond=1e-12)[0]
            q -= np.linalg.lstsq(self.closure_jacobian(q), err, rcond=1e-12)[0]
        return None

    # ---------------------------------------------------------------- closed chain
    def forward(self, q, qd, tau) -> tuple[np.ndarray, np.ndarray]:
        """Closed-chain forward dynamics (pinocchio.constraintDynamics): (θ̈ (n,), F_e (r, 6)) with
        F_e[m] = [f; n] the wrench end-effector m applies to the object at its end-effector point,
        world axes. The other arms' come from the constraint forces, the carrier's from the object's
        Newton–Euler equations."""
        q, qd, tau = (np.asarray(x, dtype=float) for x in (q, qd, tau))
        qdd = pin.constraintDynamics(self.model, self.data, q, qd, tau, self.constraints, self.constraint_data,
                                     self.settings).copy()
        lam = self.data.lambda_c.copy().reshape(-1, 6)
        # λ_m: the wrench the constraint applies to joint 1 (arm m's end-effector), at its origin,
        # world axes (M θ̈ + h = τ + Jᵀ λ, J = J_ee − J_grasp); the object applies it, so F_e^m = −λ_m
        F = np.zeros((self.r, 6))
        for row, m in enumerate(self.others):
            F[m] = -lam[row]
        pin.forwardKinematics(self.model, self.data, q, qd, qdd)
        pin.updateFramePlacements(self.model, self.data)
        X = self.data.oMf[self.object_frame]
        v = pin.getFrameVelocity(self.model, self.data, self.object_frame, LWA)
        a = pin.getFrameClassicalAcceleration(self.model, self.data, self.object_frame, LWA)
        K = X.rotation @ self.object_inertia @ X.rotation.T
        w = v.angular
        f_net = self.object_mass * (a.linear - self.gravity)         # Σ grasp forces
        n_net = K @ a.angular + np.cross(w, K @ w)                    # Σ grasp moments about C
        C = X.translation
        points = [e.translation for e in self.ee_poses(q)]
        for m in self.others:
            f_net = f_net - F[m, :3]
            n_net = n_net - F[m, 3:] - np.cross(points[m] - C, F[m, :3])
        c = self.carrier
        F[c] = np.concatenate([f_net, n_net - np.cross(points[c] - C, f_net)])
        return qdd, F

    def kkt_residual(self, q, qd, tau, qdd) -> tuple[float, float]:
        """(max |Jθ̈ + J̇θ̇| of the closure, max |M θ̈ + h − τ − Jᵀλ| with λ = −F_e of the other arms):
        checks the solve and the reading of λ."""
        q, qd, tau = (np.asarray(x, dtype=float) for x in (q, qd, tau))
        J = self.closure_jacobian(q)
        pin.forwardKinematics(self.model, self.data, q, qd, np.zeros(self.n))
        pin.updateFramePlacements(self.model, self.data)
        bias = []
        for m in self.others:
            ae = pin.getFrameClassicalAcceleration(self.model, self.data, self.chain_ee_frames[m], LWA)
            ag = pin.getFrameClassicalAcceleration(self.model, self.data, self.grasp_frames[m], LWA)
            bias.append(np.concatenate([ag.linear - ae.linear, ag.angular - ae.angular]))
        acc = float(np.max(np.abs(J @ qdd + np.concatenate(bias))))
        _, F = self.forward(q, qd, tau)
        lam = np.concatenate([-F[m] for m in self.others])
        M = pin.crba(self.model, self.data, q)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(self.model, self.data, q, qd)
        return acc, float(np.max(np.abs(M @ qdd + h - tau + J.T @ lam)))

    # ---------------------------------------------------------------- time
    def torque(self, t: float) -> np.ndarray:
        """Stacked τ(t): linear between table rows, held outside them."""
        return np.concatenate([np.array([np.interp(t, a.torque[0], col) for col in a.torque[1].T])
                               for a in self.arms])

    def trajectory(self, q0, qd0, t_out, rtol: float = 1e-12, atol: float = 1e-12):
        """θ(t) (len(t_out), n) from the consistent state (q0, qd0) at t_out[0]: scipy's DOP853 on
        θ̈ = constraintDynamics(θ, θ̇, τ(t)); returns (Q, solve_ivp result)."""
        n = self.n

        def rhs(t, y):
            return np.concatenate([y[n:], self.forward_qdd(y[:n], y[n:], self.torque(t))])

        y0 = np.concatenate([q0, qd0]).astype(float)
        sol = solve_ivp(rhs, (float(t_out[0]), float(t_out[-1])), y0, method="DOP853", t_eval=t_out,
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"{self.name}: solve_ivp: {sol.message}")
        return sol.y[:n].T, sol

    def forward_qdd(self, q, qd, tau) -> np.ndarray:
        return pin.constraintDynamics(self.model, self.data, q, qd, tau, self.constraints, self.constraint_data,
                                      self.settings)
