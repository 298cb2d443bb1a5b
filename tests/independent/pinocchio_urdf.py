"""Scenario arms that name a robot file, built in Pinocchio from the URDF itself.

`RobotScene` is `PinocchioScene` (the scene from the YAML text, the README's conventions) whose arms
given as `robot:` or `file:` are read by Pinocchio's own URDF parser (`pinocchio.buildModelFromUrdf`),
not by coopsim: every joint of the file that is not on the chain from the `base` link to the `tip`
link, and every joint the scenario locks, is locked at 0 by `pinocchio.buildReducedModel` (which
merges the bodies that joint carries, and the fixed links, into the link they hang from). The arm's
links are the reduced model's joints with their placements, axes and inertias; its base is the base
link's frame placed at the scenario's base pose; its end-effector the tip link's frame, moved by the
scenario's `end_effector`. Nothing here imports coopsim: a bundled robot's file and default chain
come from the `robots` callable the test passes in (name -> (file, base, tip, lock)).

What the README states and this follows: a robot arm's joints, frames and inertials come from the file
(a URDF prismatic joint is a prismatic joint of the arm);
fixed joints are merged into their parent link; `chain` {base, tip, lock} names the chain, defaulting
to the bundled robot's; `base` places the base link's frame in the world; `end_effector` is given in
the tip link's frame (default: that frame).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pinocchio as pin

from .pinocchio_scene import README, ArmSpec, Conventions, PinocchioScene, _Link, _angles, _pose, _torque_table


PRISMATIC_JOINTS = ("JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned")   # URDF prismatic


def urdf_chain(path: Path, base: str, tip: str, lock=()) -> tuple[list[_Link], pin.SE3, pin.SE3]:
    """(links, X_root_base, X_last_tip): the chain from link `base` to link `tip` of a URDF as links
    (joint placement in the previous joint's frame, the first in the URDF's root frame; unit axis;
    inertia; prismatic for a URDF prismatic joint, whose axis is the linear part of Pinocchio's motion
    subspace, else revolute), the base link's frame in the root frame and the tip link's frame in the
    last joint's."""
    full = pin.buildModelFromUrdf(str(path))
    tip_frame = full.frames[full.getFrameId(tip, pin.FrameType.BODY)]
    base_frame = full.frames[full.getFrameId(base, pin.FrameType.BODY)]
    above_base = set(full.supports[base_frame.parentJoint])
    chain = [j for j in full.supports[tip_frame.parentJoint] if j not in above_base and full.names[j] not in lock]
    locked = [j for j in range(1, full.njoints) if j not in chain]
    model = pin.buildReducedModel(full, locked, pin.neutral(full))
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    links = []
    for j in range(1, model.njoints):
        jm = model.joints[j]
        kind = jm.shortname()
        prismatic = kind in PRISMATIC_JOINTS
        if jm.nv != 1 or not (prismatic or kind.startswith("JointModelR")):   # RX, RUBX, RevoluteUnaligned, ...
            raise RuntimeError(f"{path.name}: joint {model.names[j]} is {kind}, not a revolute or prismatic joint")
        jd = jm.createData()
        jm.calc(jd, pin.neutral(model)[jm.idx_q:jm.idx_q + jm.nq])     # a continuous joint: nq = 2 (cos, sin)
        S = np.asarray(jd.S).reshape(6, -1)[:, 0]                       # [v; ω] per unit rate, joint frame
        axis = S[:3] if prismatic else S[3:]
        links.append(_Link(model.jointPlacements[j].copy(), axis / np.linalg.norm(axis), model.inertias[j].copy(),
                           prismatic))
    if [model.names[j] for j in range(1, model.njoints)] != [full.names[j] for j in chain]:
        raise RuntimeError(f"{path.name}: the reduced model's joints are not the chain's")
    X_root_base = data.oMf[model.getFrameId(base, pin.FrameType.BODY)].copy()
    X_last_tip = model.frames[model.getFrameId(tip, pin.FrameType.BODY)].placement.copy()
    return links, X_root_base, X_last_tip


class RobotScene(PinocchioScene):
    """`PinocchioScene` with arms from robot files (URDF), read by Pinocchio. `robots` maps a bundled
    robot's name to (file, base, tip, lock)."""

    def __init__(self, path: str | Path, robots: Callable[[str], tuple] | None = None,
                 conventions: Conventions = README):
        self.robots = robots
        super().__init__(path, conventions)

    def _read_arm(self, arm: dict, index: int, folder: Path, conv: Conventions) -> ArmSpec:
        if "robot" not in arm and "file" not in arm:
            return super()._read_arm(arm, index, folder, conv)
        if "robot" in arm:
            file, base, tip, lock = self.robots(arm["robot"])
        else:
            file, base, tip, lock = folder / arm["file"], None, None, ()
        chain = arm.get("chain") or {}
        links, X_root_base, X_last_tip = urdf_chain(Path(file), chain.get("base", base), chain.get("tip", tip),
                                                    tuple(chain.get("lock", lock)))
        n = len(links)
        init = arm["initial"]
        return ArmSpec(arm.get("name", f"arm{index + 1}"), _pose(arm.get("base"), conv) * X_root_base.inverse(),
                       links, X_last_tip * _pose(arm.get("end_effector"), conv), _angles(init, "angles"),
                       _angles(init, "rates", np.zeros(n)), _torque_table(arm, n, folder))
