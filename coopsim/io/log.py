"""Run logs: a run of the native model (and its MuJoCo twin) as MCAP, in the format of
`coopsim.io.mcap_codec`. :func:`simulation_series` / :func:`twin_series` turn a native
:class:`SimResult` / MuJoCo :class:`TwinResult` into series, `coopsim.io.foxglove` builds the `/tf`
and `/scene` topics, :func:`run_metadata` the metadata records, and :func:`write_run_log` composes
all of them; :func:`read_run_log` reads one back.
"""

from __future__ import annotations

import hashlib
import json
import platform
from dataclasses import asdict
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from coopsim.core.errors import CoopsimError
from coopsim.core.joints import type_names
from coopsim.core.labels import joint_labels
from coopsim.core.model import Model

# The log format's own names (written into every log, and SERIES_COMMENT read back to find a series):
# identifiers of the format, not module paths, so they stay as the first logs wrote them.
from coopsim.io.foxglove import frame_transforms, scene_update
from coopsim.io.mcap_codec import LogData, Series, UnreadableLogError, read_mcap, write_mcap
from coopsim.io.overrides import parse_assignment
from coopsim.io.scenario import load_scenario


# what the comparison plots draw: topic -> {field: trailing shape, "n": the joint count}
_RUN_LOG_SERIES = {"joint_state": {"angle": ("n",), "rate": ("n",)}, "object": {"position": (3,), "twist": (6,)},
                   "constraint": {}}


_RUN_LOG_CONSTRAINT = {"/native": "residual_pos", "/mujoco": "weld_violation"}

# the topics' prefix of a second pair of runs in one log: the closed-loop replay of an optimum
# (`coopsim optimize --replay`, `coopsim.report.closed_replay`), /closed_loop/native/… and /closed_loop/mujoco/…
CLOSED_LOOP = "/closed_loop"


def has_closed_loop(log: LogData) -> bool:
    """Whether a run log holds a closed-loop pair of runs (topics under CLOSED_LOOP).

    Args:
        log: the LogData (`read_mcap`).

    Returns:
        bool: True where some topic starts with CLOSED_LOOP + "/".
    """
    return any(t.startswith(CLOSED_LOOP + "/") for t in log.topics)


def read_run_log(path: str | Path) -> LogData:
    """A `coopsim run` log (`read_mcap`), checked to hold what its comparison plots draw.

    That is the native model's joint_state (angle, rate (N, n)), object (position (N, 3), twist (N, 6))
    and constraint (residual_pos (N,)) series, N >= 1 finite sample times, and the twin's (weld_violation)
    if any of its series is there; and the same of the closed-loop pair (CLOSED_LOOP/native/…, its twin's
    CLOSED_LOOP/mujoco/…) when the log has any topic under CLOSED_LOOP, with the same joint count.

    Args:
        path: the MCAP file.

    Returns:
        LogData: the whole log as `read_mcap` reads it.

    Raises:
        UnreadableLogError: naming the file, when it is not a readable MCAP log or lacks one of those
            series or fields (or a field has the wrong shape or is not floating point).
    """
    log = read_mcap(path)

    def fail(reason: str):
        raise UnreadableLogError(f"{path}: not a coopsim run log: {reason}")

    n = None
    pairs = [(p, p, c) for p, c in _RUN_LOG_CONSTRAINT.items()]
    if has_closed_loop(log):
        pairs += [(CLOSED_LOOP + p, p, c) for p, c in _RUN_LOG_CONSTRAINT.items()]
    for prefix, model, constraint in pairs:
        if model == "/mujoco" and not any(t.startswith(prefix + "/") for t in log.topics):
            continue
        for name, fields in _RUN_LOG_SERIES.items():
            topic = f"{prefix}/{name}"
            d = log.topics.get(topic)
            if d is None:
                fail(f"no {topic} series")
            t = d["t"]
            if t.ndim != 1 or len(t) == 0 or not np.all(np.isfinite(t)):
                fail(f"{topic}: no samples, or sample times that are not finite")
            for key, shape in (fields | ({constraint: ()} if name == "constraint" else {})).items():
                x = d.get(key)
                if x is None:
                    fail(f"{topic}: no field {key!r}")
                if shape == ("n",):
                    n = x.shape[1] if n is None and x.ndim == 2 else n
                    shape = (n,)
                if x.shape != (len(t),) + tuple(shape) or x.dtype.kind != "f":
                    fail(f"{topic}.{key}: shape {list(x.shape)}, expected {[len(t), *shape]} numbers")
    return log


def _joint_state(prefix: str, t, q, qd, qdd, tau) -> Series:
    return Series(f"{prefix}/joint_state", "coopsim.JointState", t,
                  {"angle": q, "rate": qd, "acceleration": qdd, "torque": tau})


def _object_state(prefix: str, t, pos, quat, twist) -> Series:
    return Series(f"{prefix}/object", "coopsim.ObjectState", t,
                  {"position": pos, "quaternion": quat, "twist": twist})


def simulation_series(res, prefix: str = "/native") -> list[Series]:
    """The log series of a native SimResult, on its sample times t (N,) s.

    Args:
        res: the SimResult (N samples, n joints, r arms).
        prefix: the topics' prefix.

    Returns:
        list[Series]: {prefix}/joint_state (angle, rate, acceleration, torque (N, n) rad, rad/s, rad/s²,
        N·m; m, m/s, m/s², N on a prismatic joint); {prefix}/object (position (N, 3) m of the centre of
        mass C, quaternion (N, 4) [w, x, y, z], twist (N, 6) [v_C; ω] m/s, rad/s, world axes);
        {prefix}/grasp_wrench and {prefix}/internal_wrench (wrench (N, r, 6) [f; n] N, N·m, world axes);
        {prefix}/constraint (residual_pos, residual_vel, cond (N,) and manipulability (N, r): each arm's
        √det(A Aᵀ), A its end-effector Jacobian in the scene's rows).
    """
    t = res.t
    return [
        _joint_state(prefix, t, res.q, res.qd, res.qdd, res.tau),
        _object_state(prefix, t, res.object_pos, res.object_quat, res.object_twist),
        Series(f"{prefix}/grasp_wrench", "coopsim.Wrenches", t, {"wrench": res.grasp_wrench}),
        Series(f"{prefix}/internal_wrench", "coopsim.Wrenches", t, {"wrench": res.internal_wrench}),
        Series(f"{prefix}/constraint", "coopsim.NativeConstraint", t,
               {"residual_pos": res.residual_pos, "residual_vel": res.residual_vel, "cond": res.cond,
                "manipulability": res.manipulability}),
    ]


def twin_series(tw, prefix: str = "/mujoco") -> list[Series]:
    """The log series of a MuJoCo TwinResult, on its sample times t (N,) s.

    Args:
        tw: the TwinResult (N samples, n joints in coopsim's order).
        prefix: the topics' prefix.

    Returns:
        list[Series]: {prefix}/joint_state and {prefix}/object as for the native model
        (`simulation_series`), {prefix}/constraint (weld_violation (N,) m or rad).
    """
    t = tw.t
    return [
        _joint_state(prefix, t, tw.q, tw.qd, tw.qdd, tw.tau),
        _object_state(prefix, t, tw.object_pos, tw.object_quat, tw.object_twist),
        Series(f"{prefix}/constraint", "coopsim.TwinConstraint", t, {"weld_violation": tw.weld_violation}),
    ]


def control_series(rec, t, prefix: str, law: str) -> Series:
    """The {prefix}/control series of a controller along a run.

    Args:
        rec: the controller's `coopsim.control.controller.Command` along the run ((N, …) arrays).
        t: (N,) s, the run's sample times.
        prefix: the topic's prefix ("/native" or "/mujoco").
        law: the control law, 'joint_pd' or 'computed_torque'.

    Returns:
        Series: joint_pd (coopsim.JointControl): reference_angle, reference_rate (N, n) rad, rad/s,
        angle_error (N, n) rad (m, m/s on a prismatic joint); computed_torque (coopsim.ObjectControl):
        pose_error (N, 6) [m; rad], twist_error (N, 6) [m/s; rad/s] world axes; both: command (N, n) N·m
        before saturation, torque (N, n) N·m applied (N on a prismatic joint), saturated (N, n) bool.
    """
    common = {"command": rec.raw, "torque": rec.tau, "saturated": rec.saturated}
    if law == "joint_pd":
        return Series(f"{prefix}/control", "coopsim.JointControl", t,
                      {"reference_angle": rec.q_ref, "reference_rate": rec.qd_ref,
                       "angle_error": rec.angle_error, **common})
    return Series(f"{prefix}/control", "coopsim.ObjectControl", t,
                  {"pose_error": rec.object_error, "twist_error": rec.object_rate_error, **common})


def _meta_value(v: Any) -> str:
    """Metadata value as a string: strings as they are, everything else as JSON (floats exact)."""
    if isinstance(v, str):
        return v
    if isinstance(v, np.ndarray):
        v = v.tolist()
    elif isinstance(v, np.generic):
        v = v.item()
    return json.dumps(v)


def _solref_effective(st) -> list | str:
    """The welds' solref as the twin uses it; 'automatic' while it follows a step not chosen yet."""
    return "automatic" if st.timestep is None and st.weld_solref is None else list(st.solref())


def _record(d: dict) -> dict[str, str]:
    return {str(k): _meta_value(v) for k, v in d.items()}


def _version(dist: str) -> str:
    try:
        return importlib_metadata.version(dist)
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes.

    Args:
        path: the file.

    Returns:
        str: 64 hex digits.
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_metadata(model: Model, res=None, extra: dict | None = None) -> dict[str, dict[str, str]]:
    """MCAP metadata records of a run (all values strings; numbers and arrays as JSON, floats exact).

    The records: scenario (name; file and sha256 when extra["scenario_file"] is given; `coopsim run` adds the
    file, its sha256 and the --set overrides it was given), versions, model
    (arm names, joints per arm, joint names, joint types (revolute / prismatic)), native.integrator,
    mujoco, validation, and for a native result native.initial_projection (dq, dqd, residual
    before/after, iterations), native.integrator_stats and native.warnings (count; "1", "2", …: each
    warning as JSON, `coopsim.forward.diagnostics.RunWarning.as_dict`).

    Args:
        model: the Model that ran.
        res: the native SimResult, or None (no native.* result records).
        extra: more entries: "scenario_file" (the scenario's path, read to hash it); a dict value is
            merged into the record of that name (e.g. {"scenario": {"file": …, "sha256": …}} adds to the
            scenario record), anything else goes to record "extra". Not changed.

    Returns:
        dict[str, dict[str, str]]: record name → {key: value}.
    """
    extra = dict(extra or {})
    scenario = {"name": model.name}
    file = extra.pop("scenario_file", None)
    if file is not None:
        scenario |= {"file": str(file), "sha256": file_sha256(file)}
    meta = {
        "scenario": scenario,
        "versions": {"coopsim": _version("coopsim"), "mujoco": _version("mujoco"), "numpy": np.__version__,
                     "mcap": _version("mcap"), "python": platform.python_version()},
        "model": _record({"arms": [a.name for a in model.arms], "dofs": [a.n for a in model.arms],
                          "joint_names": joint_labels(model), "joint_types": type_names(model.joint_type),
                          "carrier": model.object.carrier, "duration": model.duration,
                          "gravity": model.gravity}),
        "native.integrator": _record(asdict(model.integrator)),
        "mujoco": _record(asdict(model.mujoco) | {"weld_solref_effective": _solref_effective(model.mujoco)}),
        "validation": _record(asdict(model.validation)),
    }
    if res is not None:
        p = res.initial
        meta["native.initial_projection"] = _record({
            "dq": p.dq, "dqd": p.dqd, "residual_before": p.residual_before, "residual_after": p.residual_after,
            "iterations": p.iterations})
        meta["native.integrator_stats"] = _record(asdict(res.stats))
        meta["native.warnings"] = _record({"count": len(res.warnings)}
                                          | {str(i + 1): w.as_dict() for i, w in enumerate(res.warnings)})
    rest = {}
    for k, v in extra.items():
        if isinstance(v, dict):
            meta.setdefault(str(k), {}).update(_record(v))
        else:
            rest[str(k)] = _meta_value(v)
    if rest:
        meta["extra"] = rest
    return meta


def write_run_log(path: str | Path, model: Model, native=None, twin=None, extra_series: Sequence = (),
                  metadata_extra: dict | None = None) -> Path:
    """Write a run's MCAP log (`run_log`), atomically.

    Args:
        path: the MCAP file written.
        model: the Model that ran.
        native: the native SimResult, or None.
        twin: the MuJoCo TwinResult, or None.
        extra_series: more Series / JsonTopic streams (e.g. `control_series`).
        metadata_extra: `run_metadata`'s `extra`.

    Returns:
        Path: the path written.
    """
    return write_mcap(path, *run_log(model, native, twin, extra_series, metadata_extra))


def run_log(model: Model, native=None, twin=None, extra_series: Sequence = (),
            metadata_extra: dict | None = None) -> tuple[list, dict[str, dict[str, str]]]:
    """(streams, metadata) of a run's log, as `write_run_log` writes it.

    Args:
        model: the Model that ran.
        native: the native SimResult, or None.
        twin: the MuJoCo TwinResult, or None.
        extra_series: more Series / JsonTopic streams, appended after the native and twin series.
        metadata_extra: `run_metadata`'s `extra`.

    Returns:
        tuple[list, dict[str, dict[str, str]]]: the streams — native series (/native/…), twin series
        (/mujoco/…), `extra_series`, and /tf and /scene for Foxglove when either result is given — and the
        run's metadata records (see :func:`run_metadata`).
    """
    streams: list = []
    if native is not None:
        streams += simulation_series(native)
    if twin is not None:
        streams += twin_series(twin)
    streams += list(extra_series)
    if native is not None or twin is not None:
        streams += [frame_transforms(model, native, twin), scene_update(model, native is not None, twin is not None)]
    return streams, run_metadata(model, native, metadata_extra)


def _log_scenario_path(log_path: Path, file: str) -> Path | None:
    """The scenario file named in a log's metadata: absolute, or relative to the current folder or to
    a folder above the log (a log in out/NAME/ names scenarios/X.yaml relative to the project)."""
    p = Path(file)
    if p.is_absolute():
        return p if p.is_file() else None
    for base in [Path.cwd(), *log_path.resolve().parents]:
        if (base / p).is_file():
            return base / p
    return None


def log_overrides(log: LogData) -> list[str]:
    """The `--set PATH=VALUE` texts a run log was written with (its "scenario" record's "overrides").

    Args:
        log: the log as read.

    Returns:
        list[str]: the texts in order; empty for a run without any (or a log written before they were
            recorded).
    """
    text = log.metadata.get("scenario", {}).get("overrides")
    return [] if text is None else [str(x) for x in json.loads(text)]


def log_model(log_path: str | Path, log: LogData, scenario: str | Path | None = None) -> Model:
    """The Model a run log was written from: the geometry is not in the log, it comes from a scenario file.

    That is the file named in the log's "scenario" record (found relative to the current folder or a folder
    above the log, and checked against the recorded sha256), or `scenario` when given (no check), with the
    `--set` overrides the run was given (`log_overrides`) applied again.

    Args:
        log_path: the log file (for the messages and the search).
        log: the log as read (`read_mcap`, `read_run_log`).
        scenario: the scenario file to take instead of the one the log names; None: the log's.

    Returns:
        Model: the scenario's Model.

    Raises:
        CoopsimError: the log names no scenario, or one that is not found or has changed since (sha256);
            a ScenarioError when that file (with the overrides) is not a valid scenario.
    """
    log_path = Path(log_path)
    if scenario is None:
        info = log.metadata.get("scenario", {})
        file = info.get("file")
        if file is None:
            raise CoopsimError(f"{log_path}: the log names no scenario file, and the model's geometry is not "
                               f"in the log: pass the scenario with --scenario FILE")
        scenario = _log_scenario_path(log_path, file)
        if scenario is None:
            raise CoopsimError(f"{log_path}: its scenario {file} was not found (relative to the current folder "
                               f"or the log's); the model's geometry is not in the log: pass --scenario FILE")
        if "sha256" in info and file_sha256(scenario) != info["sha256"]:
            raise CoopsimError(f"{scenario}: changed since {log_path} was written (sha256 differs); run the "
                               f"scenario again, or pass --scenario FILE to take the log with it anyway")
    return load_scenario(scenario, overrides=[parse_assignment(text) for text in log_overrides(log)])
