"""Scenario files (YAML) → validated, frozen `Model`.

This is an I/O edge: kernels never import it. Every rejected input raises `ScenarioError` with one
line "FILE: FIELD: reason", FIELD a dotted path such as `arms[0].links[1].box.density`.
Angles are in radians unless the key ends in `_deg`; every other quantity is SI. A joint is revolute
(default) or prismatic (`joint.type`): its coordinate, rate and effort are rad, rad/s, N·m or m, m/s, N,
and the `_deg` forms of joint coordinates (`angles_deg`, `rates_deg`, `initial_guess_deg`) are refused
where a prismatic joint would read them.

Files are read defensively (README, "Scenario files"): UTF-8 text of at most MAX_FILE_BYTES; YAML
without duplicate keys, nested at most MAX_DEPTH levels and at most MAX_NODES values with every alias
expanded (`coopsim.io.yaml_rules`); numbers are real numbers (not booleans or quoted text), finite and
at most MAX_MAGNITUDE in size (`coopsim.io.fields`); `name` is a safe file stem; a run may ask for at
most MAX_OUTPUT_SAMPLES output samples and MAX_STEPS fixed steps (rk4, max_step, MuJoCo).
"""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml

from coopsim.core.errors import ScenarioError
from coopsim.core.joints import COORDINATE, joint_units
from coopsim.core.model import (COMPENSATIONS, FALLBACKS, JOINT_TYPES, LAWS, PRISMATIC, REFERENCES, REVOLUTE, ArmModel,
                                ControlSettings, IntegratorSettings, InverseSettings, Model, Motors, MujocoSettings,
                                ObjectModel, ObjectMotion, OptimizeSettings, PathSpline, SampledTimeLaw, TorqueTable,
                                ValidationThresholds)
from coopsim.core.spatial import box_inertia, quat_to_rot, rpy_to_rot
from coopsim.dynamics.scene import grasp_poses, plane_of_motion, row_selector
from coopsim.inverse.resolutions import METHODS
from coopsim.io.fields import MAX_MAGNITUDE, REQUIRED, Section, show_value
from coopsim.io.overrides import apply_overrides
from coopsim.io.yaml_rules import load_yaml, read_text

MAX_OUTPUT_SAMPLES = 200_000    # duration / integrator.output_dt (and an object motion's samples)


MAX_STEPS = 10_000_000          # duration / step of rk4, of max_step, of the MuJoCo twin


MAX_ITERATIONS = 10_000         # mujoco.iterations


MAX_NAME = 100                  # characters of `name`


MAX_CONTROL_POINTS = 50         # inverse.optimize.control_points


MAX_STARTS = 100                # inverse.optimize.starts


_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*\Z")


def _rotation(sec: Section, key_prefix: str = "") -> np.ndarray:
    """Rotation from `rpy`/`rpy_deg` (R = Rz Ry Rx) or `quat` [w, x, y, z]; identity if absent."""
    rpy, quat = f"{key_prefix}rpy", f"{key_prefix}quat"
    if sec.has(quat) and (sec.has(rpy) or sec.has(rpy + "_deg")):
        sec.fail(quat, "give either a quaternion or roll-pitch-yaw angles, not both")
    if sec.has(quat):
        q = sec.array(quat, (4,))
        if np.linalg.norm(q) < 1e-12:
            sec.fail(quat, "zero quaternion")
        return quat_to_rot(q)
    return rpy_to_rot(sec.angles(rpy, (3,), default=[0.0, 0.0, 0.0]))


def _unit(sec: Section, key: str, default) -> np.ndarray:
    a = sec.array(key, (3,), default=default)
    norm = np.linalg.norm(a)
    if norm < 1e-9:
        sec.fail(key, "zero-length axis")
    return a / norm


def _inertia_tensor(sec: Section, key: str) -> np.ndarray:
    """3×3 symmetric matrix or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]; must be positive definite and satisfy
    the triangle inequalities of principal moments."""
    v = sec.raw(key)
    if isinstance(v, list) and len(v) == 6:
        xx, yy, zz, xy, xz, yz = sec.array(key, (6,))
        I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    else:
        I = sec.array(key, (3, 3))
    if not np.allclose(I, I.T, rtol=0, atol=1e-12 * max(1.0, np.abs(I).max())):
        sec.fail(key, "inertia tensor must be symmetric")
    ev = np.linalg.eigvalsh(I)
    if ev[0] <= 0:
        sec.fail(key, f"inertia tensor must be positive definite (eigenvalues {ev.tolist()})")
    if ev[0] + ev[1] < ev[2] * (1 - 1e-9):
        sec.fail(key, f"principal moments {ev.tolist()} violate the triangle inequality")
    return I


def _body(sec: Section, key_box="box", key_inertial="inertial", com_default=None):
    """(mass, com (3,), inertia about com (3, 3), box size (3,)) from a `box` (size along the local
    x, y, z; density kg/m³) or an `inertial` block (mass, com, inertia). A link box starts at the
    joint and extends along local +x (com_default = None: centred at the frame origin)."""
    if sec.has(key_box) == sec.has(key_inertial):
        sec.fail(key_box, f"give exactly one of {key_box} or {key_inertial}")
    if sec.has(key_box):
        box = sec.section(key_box)
        if box.has("size"):
            size = box.array("size", (3,), positive=True)
        else:
            if not box.has("length") and not box.has("cross_section"):
                box.fail("size", "missing required field (or length and cross_section)")
            length = box.number("length", positive=True)
            cross = box.array("cross_section", (2,), positive=True)
            size = np.array([length, cross[0], cross[1]])
        density = box.number("density", positive=True)
        box.done()
        mass = density * float(np.prod(size))
        com = np.zeros(3) if com_default is None else np.array([size[0] / 2, 0.0, 0.0])
        return mass, com, box_inertia(mass, size), size
    inertial = sec.section(key_inertial)
    mass = inertial.number("mass", positive=True)
    com = inertial.array("com", (3,), default=[0.0, 0.0, 0.0])
    I = _inertia_tensor(inertial, "inertia")
    inertial.done()
    return mass, com, I, np.zeros(3)


def _arm(sec: Section, index: int, base_dir: Path) -> tuple[ArmModel, dict]:
    """One arm, from its `links` or from a robot file (`robot` or `file`, `robots.py`); returns the
    model and its per-arm extras: n, joint_range (n, 2) rad (m for a prismatic joint), motor defaults
    stall (n,) and speed (n,)."""
    name = sec.string("name", default=f"arm{index + 1}")
    base = sec.section("base", default={})
    base_pos = base.array("position", (3,), default=[0.0, 0.0, 0.0])
    base_rot = _rotation(base)
    base.done()
    kinds = [k for k in ("links", "robot", "file") if sec.has(k)]
    if len(kinds) != 1:
        sec.fail("links", "give exactly one of links, robot (a bundled robot) or file (a URDF or MJCF file)")
    if kinds[0] != "links":
        return _robot_arm(sec, name, base_pos, base_rot, base_dir)
    links = sec.items("links", min_len=1)
    jp, jr, ja, jt, lm, lc, li, lb, rng = [], [], [], [], [], [], [], [], []
    prev_length = 0.0
    for link in links:
        joint = link.section("joint", default={})
        jt.append(JOINT_TYPES[joint.string("type", tuple(JOINT_TYPES), "revolute")])
        jp.append(joint.array("position", (3,), default=[prev_length, 0.0, 0.0]))
        jr.append(_rotation(joint))
        ja.append(_unit(joint, "axis", [0.0, 0.0, 1.0]))
        rng.append(_joint_range(joint, jt[-1]))
        joint.done()
        m, c, I, box = _body(link, com_default="link")
        lm.append(m), lc.append(c), li.append(I), lb.append(box)
        prev_length = box[0]
        link.done()
    ee = sec.section("end_effector", default={})
    ee_pos = ee.array("position", (3,), default=[prev_length, 0.0, 0.0])
    ee_rot = _rotation(ee)
    ee.done()
    n = len(links)
    arm = ArmModel(name, base_pos, base_rot, np.array(jp), np.array(jr), np.array(ja), np.array(lm),
                   np.array(lc), np.array(li), np.array(lb), ee_pos, ee_rot, np.array(jt))
    return arm, {"n": n, "joint_range": np.array(rng), "stall": np.full(n, np.inf), "speed": np.full(n, np.inf),
                 "joint_names": None}


def _joint_range(joint: Section, joint_type: int) -> np.ndarray:
    """A hand-written joint's position limits `range` [lower, upper]: rad (`range_deg`: deg) for a
    revolute joint, m for a prismatic one (its `range_deg` refused); none by default."""
    if not (joint.has("range") or joint.has("range_deg")):
        return np.array([-np.inf, np.inf])
    unit = joint_units(joint_type)[COORDINATE]
    if joint_type == PRISMATIC:
        if joint.has("range_deg"):
            joint.fail("range_deg", "the joint is prismatic (m): give range in m, not range_deg")
        lo, hi = joint.array("range", (2,))
    else:
        lo, hi = joint.angles("range", (2,))
    if not lo < hi:
        joint.fail("range", f"lower limit must be below the upper one, got [{lo:g}, {hi:g}] {unit}")
    return np.array([lo, hi])


def _robot_arm(sec: Section, name: str, base_pos, base_rot, base_dir: Path) -> tuple[ArmModel, dict]:
    """An arm read from a robot file (`robots.read_chain`): `robot` (a bundled robot, `robots.ROBOTS`)
    or `file` (URDF or MJCF, relative to the scenario's folder); `chain` {base, tip, lock} (defaults
    from the bundled robot); `end_effector` in the tip link's frame (default: that frame)."""
    from coopsim.io import robots

    try:
        if sec.has("robot"):
            key = "robot"
            robot_name = sec.string("robot")
            path = robots.robot_file(robot_name)
            default = robots.ROBOTS[robot_name]
        else:
            key = "file"
            path, default = _relative_file(sec, "file", base_dir), None
        chain_sec = sec.section("chain", default={} if default is not None else REQUIRED)
        base_link = chain_sec.string("base", default=REQUIRED if default is None else default.base)
        tip_link = chain_sec.string("tip", default=REQUIRED if default is None else default.tip)
        lock = chain_sec.raw("lock", default=[] if default is None else list(default.lock))
        if not isinstance(lock, list) or not all(isinstance(x, str) for x in lock):
            chain_sec.fail("lock", f"expected a list of joint names, got {show_value(lock)}")
        chain_sec.done()
        chain = robots.read_chain(path, base_link, tip_link, tuple(lock))
    except robots.RobotFileError as exc:
        sec.fail(key if exc.field is None else f"chain.{exc.field}", str(exc))
    ee = sec.section("end_effector", default={})
    ee_pos = ee.array("position", (3,), default=[0.0, 0.0, 0.0])
    ee_rot = _rotation(ee)
    ee.done()
    arm = chain.arm(name, base_pos, base_rot, ee_pos, ee_rot)
    return arm, {"n": chain.n, "joint_range": chain.joint_range, "stall": chain.effort, "speed": chain.velocity,
                 "joint_names": chain.joint_names}


def _joint_values(sec: Section, key: str, types: np.ndarray, labels: list[str], ranges: np.ndarray | None = None,
                  rates: bool = False, default=REQUIRED) -> np.ndarray:
    """Joint coordinates (rates: joint rates) under `key`, per joint type: rad or m (rad/s or m/s); the
    degree form `key_deg` only where no joint is prismatic (ScenarioError naming the field and the
    first prismatic joint, labels[j]); radians that look like degrees are refused (`_check_turns`, with
    the joints' ranges (n, 2), ±inf: none)."""
    deg, n = f"{key}_deg", len(types)
    prismatic = np.flatnonzero(types == PRISMATIC)
    if sec.has(deg) and prismatic.size:
        unit = "m/s" if rates else "m"
        sec.fail(deg, f"{labels[prismatic[0]]} is prismatic ({unit}): give {key} in {'rad/s' if rates else 'rad'} "
                      f"and {unit}, not {deg}")
    values = sec.rad_or_deg(key, (n,), default)
    if not rates and not sec.has(deg):
        _check_turns(sec, key, values, types, labels, np.tile([-np.inf, np.inf], (n, 1)) if ranges is None else ranges)
    return values


def _check_turns(sec: Section, key: str, q: np.ndarray, types: np.ndarray, labels: list[str], ranges: np.ndarray):
    """Refuse revolute joint angles given in rad (q (n,)) that are more than a turn where that can only be
    degrees: outside the joint's range (ranges (n, 2) rad) when it has one, a whole number when it has
    none (a joint without limits may turn past 2π: 6.5 rad is an angle, 90 is taken for degrees)."""
    lo, hi = ranges.T
    past = (types == REVOLUTE) & (np.abs(q) > 2 * np.pi + 1e-9)
    ranged = np.isfinite(lo) | np.isfinite(hi)
    suspect = past & np.where(ranged, (q < lo) | (q > hi), q == np.round(q))
    if np.any(suspect):
        j = int(np.flatnonzero(suspect)[0])
        why = f"outside its range [{lo[j]:.6g}, {hi[j]:.6g}] rad" if ranged[j] else "a whole number of radians"
        sec.fail(key, f"{labels[j]} at {q[j]:g} rad is more than a turn, {why}: degrees? use {key}_deg")


class _Joints(NamedTuple):
    """The joints of every arm, stacked: types (n,) (`JOINT_TYPES` values), labels (n,) as error lines name
    them, ranges (n, 2) rad (m on a prismatic joint; ±inf: none)."""

    types: np.ndarray
    labels: list[str]
    ranges: np.ndarray


def _arm_state(sec: Section, arm: ArmModel, info: dict):
    """Initial coordinates (rad, m for a prismatic joint; within the joints' ranges) and rates of one
    arm."""
    n, types, names = info["n"], arm.joint_type, info["joint_names"]
    labels = [f"joint {j + 1}" + ("" if names is None else f" ({names[j]})") for j in range(n)]
    init = sec.section("initial")
    q0 = _joint_values(init, "angles", types, labels, info["joint_range"])
    qd0 = _joint_values(init, "rates", types, labels, rates=True, default=np.zeros(n))   # no turn limit
    lo, hi = info["joint_range"].T
    outside = np.flatnonzero((q0 < lo) | (q0 > hi))
    if outside.size:
        i = int(outside[0])
        unit = joint_units(types[i])[COORDINATE]
        init.fail("angles", f"{labels[i]} at {q0[i]:.6g} {unit} is outside its range [{lo[i]:.6g}, {hi[i]:.6g}] {unit}")
    init.done()
    return q0, qd0


def _torque(sec: Section, n: int, where_dir: Path) -> TorqueTable:
    tq = sec.section("torque", default={"constant": [0.0] * n})
    kinds = [k for k in ("constant", "table", "csv") if tq.has(k)]
    if len(kinds) != 1:
        tq.fail("constant", "give exactly one of constant, table or csv")
    if kinds[0] == "constant":
        table = TorqueTable(np.zeros(1), tq.array("constant", (n,))[None, :])
    elif kinds[0] == "table":
        tab = tq.section("table")
        times = tab.array("time", (None,))
        values = tab.array("values", (len(times), n))
        tab.done()
        table = _checked_table(tq, "table", times, values)
    else:
        table = _csv_table(tq, n, where_dir)
    tq.done()
    return table


def _check_passive_torque(sec: Section, table: TorqueTable, passive: np.ndarray) -> None:
    """A passive joint has no motor: its torque must be zero throughout (ScenarioError naming it)."""
    loaded = passive & np.any(table.values != 0, axis=0)
    if np.any(loaded):
        j = int(np.flatnonzero(loaded)[0])
        sec.fail("torque", f"joint {j + 1} is passive ({sec.field('passive')}) but its torque is not zero "
                           f"(up to {np.max(np.abs(table.values[:, j])):g} N·m)")


def _checked_table(sec: Section, key: str, times: np.ndarray, values: np.ndarray) -> TorqueTable:
    if len(times) < 1 or np.any(np.diff(times) <= 0):
        sec.fail(key, "times must be strictly increasing")
    return TorqueTable(times, values)


def _csv_table(sec: Section, n: int, where_dir: Path) -> TorqueTable:
    """CSV (UTF-8) with a header row; first column time (s), then one column per joint (N·m); every
    value a finite number of at most MAX_MAGNITUDE; rows starting with # are skipped."""
    path = _relative_file(sec, "csv", where_dir)

    def bad(reason: str, line: int | None = None):
        sec.fail("csv", f"{path.name}: " + ("" if line is None else f"line {line}: ") + reason)

    text = read_text(path, bad)
    if "\0" in text:
        bad("holds a NUL character: not a text file", text.count("\n", 0, text.index("\0")) + 1)
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = []
    try:
        for r in reader:
            if r and not r[0].lstrip().startswith("#"):
                rows.append((reader.line_num, r))
    except csv.Error as exc:
        bad(str(exc), reader.line_num)
    want = f"time, then {n} torque{'s' if n > 1 else ''}"
    if len(rows) < 2:
        bad(f"expected a header row, then rows of {want}; got {len(rows)} row{'s' * (len(rows) != 1)}")
    if all(_csv_number(x) is not None for x in rows[0][1]):
        bad(f"the first row must be a header ({want}), got numbers", rows[0][0])
    data = np.empty((len(rows) - 1, n + 1))
    for i, (line, r) in enumerate(rows[1:]):
        if len(r) != n + 1:
            bad(f"expected 1 + {n} columns ({want}), got {len(r)}", line)
        for j, x in enumerate(r):
            v = _csv_number(x)
            if v is None:
                bad(f"column {j + 1}: expected a number, got {show_value(x)}", line)
            if not math.isfinite(v):
                bad(f"column {j + 1}: must be finite, got {x.strip()}", line)
            if abs(v) > MAX_MAGNITUDE:
                bad(f"column {j + 1}: must be at most {MAX_MAGNITUDE:g} in magnitude, got {v:g}", line)
            data[i, j] = v
    return _checked_table(sec, "csv", data[:, 0], data[:, 1:])


def _relative_file(sec: Section, key: str, base_dir: Path) -> Path:
    """The existing file named by `key`, relative to the scenario's folder."""
    rel = sec.string(key)
    if "\0" in rel:
        sec.fail(key, f"a file name cannot hold a NUL character, got {show_value(rel)}")
    path = (base_dir / rel).resolve()
    if not path.is_file():
        sec.fail(key, f"file not found: {path}")
    return path


def _csv_number(x: str) -> float | None:
    try:
        return float(x)
    except ValueError:
        return None


def _motors(sec: Section, info: dict):
    """Motor lines (defaults: none for hand-written links; a robot file's effort and velocity limits),
    energy weights, passive joints of one arm."""
    n = info["n"]
    mot = sec.section("motors", default={})
    stall = mot.array("stall_torque", (n,), default=info["stall"], positive=True, allow_inf=True)
    speed = mot.array("no_load_speed", (n,), default=info["speed"], positive=True, allow_inf=True)
    mot.done()
    weights = sec.array("energy_weights", (n,), default=np.ones(n), positive=True)
    passive = sec.raw("passive", default=[False] * n)
    if not isinstance(passive, list) or len(passive) != n or not all(isinstance(p, bool) for p in passive):
        sec.fail("passive", f"expected a list of {n} true/false values")
    return stall, speed, weights, np.array(passive, dtype=bool)


def _integrator(sec: Section | None) -> IntegratorSettings:
    if sec is None:
        return IntegratorSettings()
    d = IntegratorSettings()
    s = IntegratorSettings(
        method=sec.string("method", ("dop853", "dopri5", "rk4"), d.method),
        rtol=sec.number("rtol", d.rtol, positive=True),
        atol=sec.number("atol", d.atol, positive=True),
        step=sec.number("step", d.step, positive=True),
        max_step=sec.number("max_step", d.max_step, positive=True),
        output_dt=sec.number("output_dt", d.output_dt, positive=True),
        stabilization=sec.string("stabilization", ("projection", "baumgarte", "none"), d.stabilization),
        baumgarte_alpha=sec.number("baumgarte_alpha", d.baumgarte_alpha, nonneg=True),
        baumgarte_beta=sec.number("baumgarte_beta", d.baumgarte_beta, nonneg=True),
        projection_tol=sec.number("projection_tol", d.projection_tol, positive=True),
        max_initial_correction=sec.number("max_initial_correction", d.max_initial_correction, positive=True),
        constraint_rows=sec.string("constraint_rows", ("auto", "spatial"), d.constraint_rows),
        rank_tol=sec.number("rank_tol", d.rank_tol, positive=True),
        on_rank_deficiency=sec.string("on_rank_deficiency", ("warn", "error"), d.on_rank_deficiency),
        condition_limit=sec.number("condition_limit", d.condition_limit, positive=True),
        on_ill_conditioning=sec.string("on_ill_conditioning", ("warn", "error"), d.on_ill_conditioning),
        initial_correction_warning=sec.number("initial_correction_warning", d.initial_correction_warning,
                                              positive=True),
        singularity_limit=sec.number("singularity_limit", d.singularity_limit, positive=True),
    )
    sec.done()
    return s


def _mujoco(sec: Section | None) -> MujocoSettings:
    if sec is None:
        return MujocoSettings()
    d = MujocoSettings()
    solref = sec.array("weld_solref", (2,), default=None, positive=True) if sec.has("weld_solref") else None
    timestep = sec.number("timestep", None, positive=True)        # None: automatic (coopsim.twin.weld)
    integrator = sec.string("integrator", ("RK4", "Euler", "implicit", "implicitfast"), d.integrator)
    if integrator != "RK4" and timestep is None:
        sec.fail("timestep", f"required with integrator {integrator} (the automatic step is RK4's)")
    s = MujocoSettings(
        timestep=timestep,
        integrator=integrator,
        weld_solref=None if solref is None else (float(solref[0]), float(solref[1])),
        weld_solimp=tuple(float(x) for x in sec.array("weld_solimp", (5,), default=d.weld_solimp)),
        tolerance=sec.number("tolerance", d.tolerance, positive=True),
        iterations=sec.whole("iterations", d.iterations, positive=True, maximum=MAX_ITERATIONS),
        object_mass_scale=sec.number("object_mass_scale", d.object_mass_scale, positive=True),
    )
    sec.done()
    return s


def _validation(sec: Section | None) -> ValidationThresholds:
    if sec is None:
        return ValidationThresholds()
    d = ValidationThresholds()
    s = ValidationThresholds(**{k: sec.number(k, getattr(d, k), positive=True) for k in d.__dataclass_fields__})
    sec.done()
    return s


SAMPLED_LAW_RTOL = 1e-9     # s_{k+1} − s_k against (ṡ_k + ṡ_{k+1})(t_{k+1} − t_k)/2, relative to the path (1)


def _sampled_law(om: Section, times: np.ndarray) -> SampledTimeLaw:
    """The `time_law_samples` {t, s, rate} of a sampled time law (SampledTimeLaw), checked: t strictly
    increasing from the first waypoint's time to the last's, s non-decreasing from 0 to 1, rate ≥ 0 and 0
    at every waypoint (waypoint k of w at s = k/(w − 1), at its time), consecutive samples consistent with a
    constant s̈ between them."""
    sec = om.section("time_law_samples")
    t, s, rate = (sec.array(k, (None,), nonneg=(k != "t")) for k in ("t", "s", "rate"))
    if not len(t) == len(s) == len(rate) or len(t) < 2:
        sec.fail("t", f"t, s and rate need one length of at least 2, got {len(t)}, {len(s)}, {len(rate)}")
    if np.any(np.diff(t) <= 0) or t[0] != times[0] or t[-1] != times[-1]:
        sec.fail("t", f"must increase strictly from the first waypoint's time {times[0]:g} s to the last's "
                      f"{times[-1]:g} s")
    if np.any(np.diff(s) < 0) or s[0] != 0.0 or s[-1] != 1.0:
        sec.fail("s", "must not decrease, from 0 to 1")
    err = np.abs(np.diff(s) - 0.5 * (rate[1:] + rate[:-1]) * np.diff(t))
    if np.any(err > SAMPLED_LAW_RTOL):
        k = int(np.argmax(err))
        sec.fail("rate", f"samples {k} and {k + 1} do not meet a constant acceleration between them "
                         f"(s differs by {err[k]:.3g})")
    for k, tw in enumerate(times):
        hit = np.flatnonzero(t == tw)
        if not len(hit) or rate[hit[0]] != 0.0 or abs(s[hit[0]] - k / (len(times) - 1)) > SAMPLED_LAW_RTOL:
            sec.fail("t", f"waypoint {k} (time {tw:g} s) needs a sample at its time with s = {k}/{len(times) - 1} "
                          f"and rate 0")
    sec.done()
    return SampledTimeLaw(t, s, rate)


def _inverse(sec: Section | None, r: int, joints: "_Joints") -> InverseSettings:
    """The optional `inverse` section: trajectory to invert, object motion, non-squeezing virtual
    masses, payload position and internal-wrench bounds (see InverseSettings, ObjectMotion); `joints`
    are the stacked joints the initial guess and rest posture are read for."""
    if sec is None:
        return InverseSettings()
    trajectory = sec.string("trajectory", ("forward", "object_motion"), "forward")
    om = sec.section("object_motion", default=None)
    motion = None
    if om is not None:
        law = om.string("time_law", ("quintic", "cubic", "sampled"), "quintic")
        dt = om.number("output_dt", 1e-2, positive=True)
        guess, rest = (_joint_values(om, key, *joints) if om.has(key) or om.has(f"{key}_deg") else None
                       for key in ("initial_guess", "rest_posture"))
        gain = om.number("rest_gain", 1.0, nonneg=True)
        pull = om.string("rest_pull", ("time", "path"), "time")
        times, pos, rot = [], [], []
        for wp in om.items("waypoints", min_len=2):
            times.append(wp.number("time", nonneg=True))
            pos.append(wp.array("position", (3,)))
            rot.append(_rotation(wp))
            wp.done()
        if np.any(np.diff(times) <= 0):
            om.fail("waypoints", f"times must be strictly increasing, got {times}")
        samples = _sampled_law(om, np.array(times)) if law == "sampled" else None
        path = _object_path(om.section("path", default=None), len(times), om)
        om.done()
        motion = ObjectMotion(np.array(times), np.array(pos), np.array(rot), law, dt, guess, rest, gain, samples,
                              path, pull)
    if trajectory == "object_motion" and motion is None:
        sec.fail("object_motion", "trajectory: object_motion needs an object_motion section")
    masses = sec.array("nonsqueezing_masses", (r,), positive=True) if sec.has("nonsqueezing_masses") else None
    payload = sec.section("payload", default=None)
    payload_pos = None
    if payload is not None:
        payload_pos = payload.array("position", (3,))
        payload.done()
    bound = sec.section("internal_bound", default=None)
    force = moment = None
    if bound is not None:
        force = bound.number("force", None, nonneg=True) if bound.has("force") else None
        moment = bound.number("moment", None, nonneg=True) if bound.has("moment") else None
        bound.done()
    optimize = _optimize(sec.section("optimize", default=None))
    sec.done()
    return InverseSettings(trajectory, motion, masses, payload_pos, force, moment, optimize)


def _object_path(sec: Section | None, waypoints: int, om: Section) -> PathSpline | None:
    """The optional `inverse.object_motion.path` (see PathSpline): a B-spline between exactly two waypoints,
    its interior control points each a `position` (m, world) and a `rotation_vector` (rad, world axes,
    relative to the first waypoint's orientation; default zero)."""
    if sec is None:
        return None
    sec.string("kind", ("bspline",))
    if waypoints != 2:
        om.fail("waypoints", f"a path runs between two waypoints (its ends), got {waypoints}")
    pos, rot = [], []
    for cp in sec.items("control_points", min_len=1):
        pos.append(cp.array("position", (3,)))
        phi = cp.array("rotation_vector", (3,), default=[0.0, 0.0, 0.0])
        if np.linalg.norm(phi) >= np.pi:
            cp.fail("rotation_vector", f"must be shorter than pi rad, got {np.linalg.norm(phi):.6g}")
        rot.append(phi)
        cp.done()
    sec.done()
    return PathSpline("bspline", np.array(pos), np.array(rot))


def _optimize(sec: Section | None) -> OptimizeSettings:
    """The optional `inverse.optimize` section (see OptimizeSettings)."""
    d = OptimizeSettings()
    if sec is None:
        return d
    out = OptimizeSettings(
        control_points=sec.whole("control_points", d.control_points, positive=True, maximum=MAX_CONTROL_POINTS),
        starts=sec.whole("starts", d.starts, positive=True, maximum=MAX_STARTS),
        seed=sec.whole("seed", d.seed, nonneg=True),
        manipulability_margin=sec.number("manipulability_margin", d.manipulability_margin, nonneg=True),
        sample_dt=sec.number("sample_dt", d.sample_dt, positive=True),
        max_iterations=sec.whole("max_iterations", d.max_iterations, positive=True, maximum=MAX_ITERATIONS))
    if out.manipulability_margin >= 1:
        sec.fail("manipulability_margin", f"must be below 1 (a fraction of the first pose's), got "
                                          f"{out.manipulability_margin:g}")
    sec.done()
    return out


def _gains(sec: Section, key: str, n: int) -> np.ndarray:
    """Non-negative gains (n,): one number for every joint, or one per joint."""
    if isinstance(sec.raw(key), (int, float)) and not isinstance(sec.raw(key), bool):
        return np.full(n, sec.number(key, nonneg=True))
    return sec.array(key, (n,), nonneg=True)


def _control(sec: Section | None, joints: "_Joints", inverse: InverseSettings,
             passive: np.ndarray) -> ControlSettings | None:
    """The optional `control` section (see ControlSettings; the fields a law does not read are refused);
    `joints` are the stacked joints the setpoint is read for (rad, m on a prismatic joint)."""
    if sec is None:
        return None
    n = len(joints.types)
    law = sec.string("law", LAWS)
    if np.any(passive):
        sec.fail("law", "a controller needs every joint actuated (arms[].passive has a passive joint)")
    opts = dict(distribution=sec.string("distribution", METHODS, "paper"),
                mass_scale=sec.number("mass_scale", 1.0, positive=True))
    if sec.has("fallback"):
        if opts["distribution"] != "bounded":
            sec.fail("fallback", "only with distribution: bounded")
        opts["fallback"] = sec.string("fallback", FALLBACKS)
    saturate = sec.raw("saturate", default=False)
    if not isinstance(saturate, bool):
        sec.fail("saturate", f"expected true or false, got {show_value(saturate)}")
    if law == "joint_pd":
        kp, kd = _gains(sec, "kp", n), _gains(sec, "kd", n)
        reference = sec.string("reference", REFERENCES, "setpoint")
        setpoint = None
        if sec.has("setpoint") or sec.has("setpoint_deg"):
            if reference != "setpoint":
                sec.fail("setpoint", "only with reference: setpoint")
            setpoint = _joint_values(sec, "setpoint", *joints)
        opts.update(compensation=sec.string("compensation", COMPENSATIONS, "gravity"), reference=reference,
                    setpoint=setpoint)
    else:
        kp = kd = np.zeros(n)
        reference = "object_motion"
        opts.update(object_kp=sec.array("object_kp", (2,), nonneg=True),
                    object_kd=sec.array("object_kd", (2,), nonneg=True),
                    grasp_kp=sec.array("grasp_kp", (2,), default=np.zeros(2), nonneg=True),
                    grasp_kd=sec.array("grasp_kd", (2,), default=np.zeros(2), nonneg=True),
                    squeeze=sec.number("squeeze", 0.0), reference=reference)
    if reference == "object_motion" and inverse.object_motion is None:
        sec.fail("reference" if law == "joint_pd" else "law",
                 "tracking an object motion needs the inverse.object_motion section")
    sec.done()
    return ControlSettings(law, kp, kd, saturate=saturate, **opts)


def _object(sec: Section, arms: list[ArmModel]):
    """Object inertia and grasps; grasps given explicitly or `derive` (from the initial state)."""
    mass, com, inertia, box = _body(sec)
    if np.linalg.norm(com) > 0:
        sec.fail("inertial.com", "the object frame is at its centre of mass: com must be [0, 0, 0]")
    names = [a.name for a in arms]
    pose = sec.section("pose", default=None)
    grasps_raw = sec.raw("grasps")
    if grasps_raw == "derive":
        order = list(range(len(arms)))
        grasp = None
    else:
        order, grasp = [], {}
        for g in sec.items("grasps", min_len=2):
            arm = g.raw("arm")
            idx = names.index(arm) if arm in names else arm
            if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < len(arms):
                g.fail("arm", f"no arm {arm!r} (arms: {', '.join(names)})")
            if idx in grasp:
                g.fail("arm", f"arm {names[idx]!r} grasps twice")
            grasp[idx] = (g.array("position", (3,)), _rotation(g), g.field("arm").rsplit(".", 1)[0])
            order.append(idx)
            g.done()
        if len(grasp) != len(arms):
            missing = [names[i] for i in range(len(arms)) if i not in grasp]
            sec.fail("grasps", f"every arm must grasp the object; missing: {', '.join(missing)}")
    pose_data = None
    if pose is not None:
        pose_data = (pose.array("position", (3,)), _rotation(pose))
        pose.done()
    sec.done()
    return mass, inertia, box, order, grasp, pose_data


def _check_work(where: str, duration: float, field: str, s: IntegratorSettings, mj: MujocoSettings,
                inverse: InverseSettings) -> None:
    """Refuse, up front, a run that asks for more than MAX_OUTPUT_SAMPLES output samples or MAX_STEPS
    fixed steps (rk4 steps, the steps max_step forces on an adaptive method, MuJoCo steps): it could
    not fit in memory, or would run for hours without a word. `field` names where the duration came
    from (`duration` or `--duration`)."""
    def fail(count: float, what: str, limit: int, other: str, value: float, unit: str = "s"):
        if count > limit:
            raise ScenarioError(f"{where}: {field}: {duration:g} s at {other} = {value:g} {unit} is {count:.3g} "
                                f"{what}, more than the {limit:,} a run may ask for")

    fail(duration / s.output_dt + 1, "output samples", MAX_OUTPUT_SAMPLES, "integrator.output_dt", s.output_dt)
    if s.method == "rk4":
        fail(duration / s.step, "rk4 steps", MAX_STEPS, "integrator.step", s.step)
    elif s.max_step is not None:
        fail(duration / s.max_step, "steps at least", MAX_STEPS, "integrator.max_step", s.max_step)
    if mj.timestep is not None:          # an automatic step asks for at most weld.MAX_AUTO_STEPS
        fail(duration / mj.timestep, "MuJoCo steps", MAX_STEPS, "mujoco.timestep", mj.timestep)
    om = inverse.object_motion
    if om is not None:
        samples = (om.times[-1] - om.times[0]) / om.output_dt + 1
        if samples > MAX_OUTPUT_SAMPLES:
            span = om.times[-1] - om.times[0]
            raise ScenarioError(f"{where}: inverse.object_motion.output_dt: waypoints over {span:g} "
                                f"s every {om.output_dt:g} s are {samples:.3g} samples, more than the "
                                f"{MAX_OUTPUT_SAMPLES:,} a run may ask for")


def require_motor_limits(model: Model, where: str) -> None:
    """Check that the load capacity has a limit to reach: a finite `motors.stall_torque` on some joint
    that is not passive (without one every capacity is unbounded).

    Args:
        model: the Model.
        where: the name the error message starts with (the scenario file).

    Raises:
        ScenarioError: no joint has a motor limit.
    """
    m = model.motors
    if not np.any(np.isfinite(m.stall_torque) & ~m.passive):
        raise ScenarioError(f"{where}: arms[].motors: the load capacity needs motor limits (stall_torque, "
                            f"no_load_speed), and no joint has one")


def load_scenario(path: str | Path, duration: float | None = None, overrides=()) -> Model:
    """Read and validate a scenario YAML file (README, "Scenario files"; scenarios/*.yaml).

    Args:
        path: the scenario file; relative paths inside it (torque CSVs, robot files) are read from
            its folder.
        duration: s, in place of the file's (the command line's --duration); checked as the file's
            is, and the work limits apply to it.
        overrides: (PATH, value) pairs set in the file's data before it is validated
            (`coopsim.io.overrides.apply_overrides`: the command line's `--set PATH=VALUE`).

    Returns:
        The frozen, validated Model (SI units, radians, world axes).

    Raises:
        ScenarioError: one line "FILE: FIELD: reason" for the first field that is wrong.
    """
    if duration is not None:
        check_duration(duration)
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: scenario file not found")
    data = load_yaml(path)
    if overrides:
        data = apply_overrides(data, overrides, where=f"{path}: --set")
    return model_from_dict(data, where=str(path), base_dir=path.parent, default_name=path.stem, duration=duration)


def check_duration(duration, option: str = "--duration") -> float:
    """Check a duration given on the command line by the rule of the file's `duration`.

    Args:
        duration: s, the value given.
        option: the option's name, for the message.

    Returns:
        float: the duration, s.

    Raises:
        ScenarioError: naming the option, unless it is a positive, finite number of seconds of at most
            MAX_MAGNITUDE.
    """
    if isinstance(duration, bool) or not isinstance(duration, (int, float)) or not math.isfinite(duration) \
            or not 0 < duration <= MAX_MAGNITUDE:
        raise ScenarioError(f"{option}: must be a positive, finite number of seconds of at most "
                            f"{MAX_MAGNITUDE:g}, got {duration!r}")
    return float(duration)


def safe_name(stem: str) -> str:
    """A file stem made a valid `name`, for a scenario without one.

    Args:
        stem: the file name without its suffix.

    Returns:
        str: characters other than letters, digits, '_', '-' and '.' become '_', leading dots go, at
        most MAX_NAME characters ('scenario' when nothing is left).
    """
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", stem).lstrip(".")[:MAX_NAME]
    return name or "scenario"


def model_from_dict(data, where: str = "<scenario>", base_dir: Path = Path("."), default_name="scenario",
                    duration: float | None = None) -> Model:
    """Build the frozen, validated `Model` from parsed scenario data, checked field by field as a file is.

    Args:
        data: the dict a scenario file holds (`coopsim.io.yaml_rules.load_yaml`, or built in Python).
        where: the name error messages start with (the file).
        base_dir: the folder that relative paths in the data (torque CSVs, robot files) are read from.
        default_name: the `name` when the data has none (made a safe file stem).
        duration: s, in place of the data's (see `load_scenario`).

    Returns:
        The frozen, validated Model.

    Raises:
        ScenarioError: one line "WHERE: FIELD: reason".

    With `coopsim.io.overrides.apply_overrides` it is how a script varies a scenario:

        data = load_yaml(Path("scenarios/paper_planar_2x3.yaml"))
        for rho in (2700.0, 7850.0):
            model = model_from_dict(apply_overrides(data, [("object.box.density", rho)]), where="paper")
    """
    root = Section(data, "", where)
    name = root.string("name", default=safe_name(default_name))
    if not (_NAME.match(name) and len(name) <= MAX_NAME):
        root.fail("name", f"must be a file name of 1 to {MAX_NAME} letters, digits, '_', '-' or '.', not "
                          f"starting with '.' (outputs are written as NAME.mcap, out/NAME/), got {show_value(name)}")
    root.string("description", default="")
    gravity = root.array("gravity", (3,), default=[0.0, 0.0, -9.81])
    file_duration = root.number("duration", positive=True)
    duration, duration_field = (file_duration, "duration") if duration is None else \
        (check_duration(duration), "--duration")
    arm_secs = root.items("arms", min_len=2)
    arms, q0, qd0, torques, motor_parts, ranges = [], [], [], [], [], []
    for i, sec in enumerate(arm_secs):
        arm, info = _arm(sec, i, base_dir)
        q, qd = _arm_state(sec, arm, info)
        torques.append(_torque(sec, info["n"], base_dir))
        motor_parts.append(_motors(sec, info))
        _check_passive_torque(sec, torques[-1], motor_parts[-1][3])
        sec.done()
        arms.append(arm), q0.append(q), qd0.append(qd), ranges.append(info["joint_range"])
    names = [a.name for a in arms]
    if len(set(names)) != len(names):
        root.fail("arms", f"arm names must be unique, got {names}")
    mass, inertia, box, order, grasp, pose = _object(root.section("object"), arms)
    integrator = _integrator(root.section("integrator", default=None))
    mujoco_settings = _mujoco(root.section("mujoco", default=None))
    validation = _validation(root.section("validation", default=None))
    joints = _Joints(np.concatenate([a.joint_type for a in arms]),
                     [f"arm {a.name!r} joint {j + 1}" for a in arms for j in range(a.n)], np.concatenate(ranges))
    inverse = _inverse(root.section("inverse", default=None), len(arms), joints)
    motors = Motors(*(np.concatenate([m[k] for m in motor_parts]) for k in range(4)))
    control = _control(root.section("control", default=None), joints, inverse, motors.passive)
    root.done()
    _check_work(where, duration, duration_field, integrator, mujoco_settings, inverse)
    q0, qd0 = np.concatenate(q0), np.concatenate(qd0)
    grasp_pos, grasp_rot = grasp_poses(arms, q0, order, grasp, pose, where)
    obj = ObjectModel(mass, inertia, box, grasp_pos, grasp_rot, carrier=order[0])
    planar_basis = plane_of_motion(arms, q0) if integrator.constraint_rows == "auto" else None
    return Model(name, tuple(arms), obj, gravity, planar_basis, row_selector(planar_basis), q0, qd0, duration,
                 tuple(torques), motors, integrator, mujoco_settings, validation, inverse=inverse,
                 joint_range=np.concatenate(ranges), control=control)


def scenario_text(data: dict, comment: str = "") -> str:
    """A scenario's data as YAML text that `load_scenario` reads back to the same values (floats exact).

    Args:
        data: the scenario's data (plain dicts, lists, numbers, strings), e.g. a file's data changed.
        comment: a first comment line (none: "").

    Returns:
        str: the YAML text, keys in the data's order.
    """
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    return head + yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=120, default_flow_style=None)
