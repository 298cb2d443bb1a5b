"""The inverse side: what a capacity point costs, how that grows in samples and in arms, and what the
inverse commands cost above their fixed start-up."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Callable

from coopsim.apps.bench.measure import Ladders, best_time, power_fit
from coopsim.apps.bench.scaling import synthetic_scene
from coopsim.apps.bench.startup import command_wall
from coopsim.core.model import Model
from coopsim.core.spatial import rot_to_rpy
from coopsim.inverse.trajectory import object_motion_trajectory, object_pose_of
from coopsim.io.scenario import load_scenario, model_from_dict
from coopsim.report.inverse_report import capacity_study

CARRY = Path(__file__).resolve().parents[3] / "scenarios" / "paper_planar_2x3_carry.yaml"

# The scenes of the command figures: the paper carry (an object motion), the 3-arm vertical scene and a
# robot scene (forward-run trajectories); paths relative to the repository root.
COMMAND_SCENES = ("scenarios/paper_planar_2x3_carry.yaml", "scenarios/planar_3arm_vertical.yaml",
                  "scenarios/robots/ur5_pair_box.yaml")
INVERSE_COMMANDS = {"capacity": ["capacity"], "inverse --replay": ["inverse", "--replay"]}
COMMAND_MARGIN_S = 1.0      # a command's wall time above its fixed start-up, at most


def capacity_point(model: Model, repeats: int = 3) -> dict:
    """The cost of one capacity point of a scenario with an object motion, as a sweep computes it.

    The point is `capacity_study(model, with_lp=True, optimise=False)`: every linear resolution in each
    capacity mode and the LP bound, with what a sweep over payload axes shares between its points (the
    object-motion trajectory, the per-sample terms, the 'scaled' LP bound) computed once before the
    timing; the trajectory (closed-chain IK of every sample) is timed on its own.

    Args:
        model: a Model whose inverse.trajectory is 'object_motion'.
        repeats: timings of each (the minimum is reported).

    Returns:
        dict: 'samples' N, 'arms' r, 'joints' n_total; ms: 'trajectory_ms' (the IK pass),
        'point_ms' (the capacity study on the shared trajectory).
    """
    motion = model.inverse.object_motion
    traj, traj_s = best_time(lambda: object_motion_trajectory(model, motion), repeats)
    capacity_study(model, with_lp=True, optimise=False)           # fills the shared trajectory
    _, point_s = best_time(lambda: capacity_study(model, with_lp=True, optimise=False), repeats)
    return {"samples": len(traj.t), "arms": len(model.arms), "joints": model.n_total,
            "trajectory_ms": 1e3 * traj_s, "point_ms": 1e3 * point_s}


def with_output_dt(model: Model, dt: float) -> Model:
    """The model with its object motion sampled every dt.

    Args:
        model: a Model with an inverse.object_motion.
        dt: s, the sample interval.

    Returns:
        Model: the same model, its inverse.object_motion.output_dt = dt.
    """
    inverse = model.inverse
    return replace(model, inverse=replace(inverse, object_motion=replace(inverse.object_motion, output_dt=dt)))


def synthetic_carry(r: int, n: int, lift: float = 0.05, duration: float = 1.0) -> Model:
    """`synthetic_scene(r, n)` lifting its box by `lift` m in `duration` s, rest to rest (quintic law).

    Every joint gets a motor (stall torque 100 N·m, no-load speed 4 rad/s, energy weight 1), the
    payload capacity a point payload at the box's centre.

    Args:
        r: the number of arms.
        n: joints per arm (`synthetic_scene`).
        lift: m, the vertical travel of the box's centre of mass.
        duration: s, the motion's duration.

    Returns:
        Model: the frozen model, inverse.trajectory 'object_motion' sampled every 0.01 s.
    """
    scene = synthetic_scene(r, n)
    start = model_from_dict(scene, where=scene["name"])
    p0, R0 = object_pose_of(start, start.q0)
    for arm in scene["arms"]:
        arm["motors"] = {"stall_torque": [100.0] * n, "no_load_speed": [4.0] * n}
    rpy = [float(a) for a in rot_to_rpy(R0)]
    scene["inverse"] = {"trajectory": "object_motion", "payload": {"position": [0.0, 0.0, 0.0]},
                        "object_motion": {"time_law": "quintic", "output_dt": 0.01, "waypoints": [
                            {"time": 0.0, "position": [float(x) for x in p0], "rpy": rpy},
                            {"time": duration, "position": [float(p0[0]), float(p0[1]), float(p0[2] + lift)],
                             "rpy": rpy}]}}
    return model_from_dict(scene, where=scene["name"])


def inverse_scaling(ladders: Ladders, log: Callable[[str], None] = lambda s: None) -> dict:
    """Capacity points in samples (the paper carry at the ladders' output intervals) and in arms (the
    synthetic carries of r arms × 6 joints), with power-law fits of the point's and the IK's cost.

    Args:
        ladders: the Ladders (inverse_dts, inverse_arms, repeats).
        log: progress callback, one line of text per point.

    Returns:
        dict: 'in_samples' and 'in_arms' (`capacity_point` dicts, with 'output_dt_s' or 'r'), and 'fits':
        {'point_in_samples', 'trajectory_in_samples', 'point_in_arms', 'trajectory_in_arms'} (`power_fit`
        dicts; a fit needs two points).
    """
    carry = load_scenario(CARRY)
    in_samples, in_arms = [], []
    for dt in ladders.inverse_dts:
        log(f"inverse: paper carry every {dt:g} s")
        in_samples.append({"output_dt_s": dt} | capacity_point(with_output_dt(carry, dt), ladders.repeats))
    for r in ladders.inverse_arms:
        log(f"inverse: synthetic carry of {r} arms x 6 joints")
        in_arms.append({"r": r} | capacity_point(synthetic_carry(r, 6), ladders.repeats))
    fits = {}
    for name, rows, x in (("in_samples", in_samples, "samples"), ("in_arms", in_arms, "arms")):
        if len({p[x] for p in rows}) >= 2:
            for key in ("point", "trajectory"):
                fits[f"{key}_{name}"] = power_fit([p[x] for p in rows], [p[f"{key}_ms"] for p in rows])
    return {"in_samples": in_samples, "in_arms": in_arms, "fits": fits}


def minimal_overrides(model: Model) -> list[str]:
    """`--set` overrides that cut a scenario's inverse study to its fewest samples: the object motion
    sampled only at its first and last instants, or a forward run of one 0.01 s step.

    Args:
        model: the scenario's Model.

    Returns:
        list[str]: the command-line words ('--set', 'KEY=VALUE', ...).
    """
    om = model.inverse.object_motion
    if model.inverse.trajectory == "object_motion":
        return ["--set", f"inverse.object_motion.output_dt={float(om.times[-1] - om.times[0])!r}"]
    return ["--set", "duration=0.01", "--set", "integrator.output_dt=0.01"]


def command_overheads(scenes=COMMAND_SCENES, commands=INVERSE_COMMANDS, repeats: int = 2) -> list[dict]:
    """Each inverse command on each scene as a user runs it, against the same command at its fewest
    samples (`minimal_overrides`): the difference is what the study itself costs above the command's
    fixed start-up (interpreter, imports, cached kernels, figure workers, writing the set).

    Args:
        scenes: scenario paths relative to the repository root.
        commands: {name: CLI words after `coopsim`, before the scenario}.
        repeats: fresh processes per measurement (the minimum is reported).

    Returns:
        list[dict]: per (scene, command): 'scene', 'command', 'wall_s', 'startup_s' (the minimal run),
        'above_s' (their difference), 'target_s' (COMMAND_MARGIN_S), 'met'.

    Raises:
        CoopsimError: a command exits with a status other than 0 or 1.
    """
    root = CARRY.parents[1]
    rows = []
    with tempfile.TemporaryDirectory(prefix="coopsim-bench-") as folder:
        for scene in scenes:
            cut = minimal_overrides(load_scenario(root / scene))
            for name, words in commands.items():
                base = [words[0], scene, *words[1:], "--json", "--out", folder]
                wall = command_wall(base, repeats, root)
                startup = command_wall(base + cut, repeats, root)
                rows.append({"scene": Path(scene).stem, "command": name, "wall_s": wall, "startup_s": startup,
                             "above_s": wall - startup, "target_s": COMMAND_MARGIN_S,
                             "met": wall - startup <= COMMAND_MARGIN_S})
    return rows


def inverse_bench(ladders: Ladders, log: Callable[[str], None] = lambda s: None) -> dict:
    """The inverse side's figures: the capacity point of the paper carry, the scaling in samples and arms,
    and (ladders.startup) the inverse commands above their start-up.

    Args:
        ladders: the Ladders.
        log: progress callback, one line of text per stage.

    Returns:
        dict: 'point' (`capacity_point` of the paper carry), 'scaling' (`inverse_scaling`), 'commands'
        (`command_overheads`, or None).
    """
    log("inverse: a capacity point of the paper carry")
    out = {"point": capacity_point(load_scenario(CARRY), max(ladders.repeats, 5)),
           "scaling": inverse_scaling(ladders, log), "commands": None}
    if ladders.startup:
        log("inverse: capacity and inverse --replay against their start-up")
        out["commands"] = command_overheads()
    return out
