"""What an animation shows (:class:`Motion`): the scenario's frozen `Model` and the joint angles of the
native model and of the MuJoCo twin over time, from a `coopsim run` log (the log holds the angles, the
geometry comes from the scenario file it names; the load an optimum's replay carried, its "payload"
record, comes with them) or from running the scenario (`scenario_motion` prefers the scenario's log in
`out/NAME/` when it was written from the same file); and the frame times.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from coopsim.core.errors import CoopsimError, one_line
from coopsim.core.model import Model
from coopsim.io.log import CLOSED_LOOP, file_sha256, log_model, log_overrides
from coopsim.io.mcap_codec import read_mcap
from coopsim.io.scenario import load_scenario
from coopsim.twin.harness import cross_validate


@dataclass(frozen=True, eq=False)
class Payload:
    """The load a replayed optimum carried (`coopsim optimize --replay`: its run log's "payload" record).

    Attributes:
        mass: kg, the point payload's mass ('payload'), or the whole object's ('scaled').
        mode: 'payload' (a point mass on the object) or 'scaled' (the object scaled at constant geometry).
        position: (3,) m, the point payload's position in the object frame (from the scenario object's
            centre of mass); None for 'scaled'.
    """

    mass: float
    mode: str
    position: np.ndarray | None


@dataclass(frozen=True, eq=False)
class Motion:
    """Joint angles to animate: both models' joint coordinates over time, and the model they belong to.

    Either of q_native and q_twin may be None: only the other model is drawn.

    Attributes:
        model: the scenario's frozen Model (the geometry drawn).
        t: (N,) s, the sample times, increasing.
        q_native: (N, n) rad (m on a prismatic joint), the native model's joint coordinates in coopsim's joint
            order (arm by arm, n = model.n_total), or None.
        q_twin: (N, n) rad (m on a prismatic joint), the MuJoCo twin's, in the same order, or None.
        source: where they came from, for messages ("log PATH" or "run").
        payload: the load the run carried beyond the scenario's object (an optimum's replay), or None.
    """

    model: Model
    t: np.ndarray
    q_native: np.ndarray | None
    q_twin: np.ndarray | None
    source: str
    payload: Payload | None = None

    def at(self, times: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Both models' joint coordinates at `times`: linear between samples, exact on them.

        A time within 1e-9 s of a sample takes that sample; a time outside [t[0], t[-1]] the end sample.

        Args:
            times: (F,) s, the frame times.

        Returns:
            tuple: (q_native, q_twin), each (F, n) rad (m on a prismatic joint), or None where the motion has
                none.
        """
        return _interp(self.t, self.q_native, times), _interp(self.t, self.q_twin, times)


def _interp(t: np.ndarray, q: np.ndarray | None, times: np.ndarray) -> np.ndarray | None:
    """q (N, n) sampled at t (N,), at `times`: linear between samples; a time within 1e-9 s of a sample
    takes that sample exactly; outside [t[0], t[-1]] the end sample."""
    if q is None:
        return None
    times = np.clip(times, t[0], t[-1])
    k = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
    k1 = np.minimum(k + 1, len(t) - 1)
    out = q[k] + ((times - t[k]) / np.where(k1 > k, t[k1] - t[k], 1.0))[:, None] * (q[k1] - q[k])
    for j in (k, k1):
        on = np.abs(times - t[j]) <= 1e-9
        out[on] = q[j[on]]
    return out


def _read_log(log_path: Path):
    try:
        return read_mcap(log_path)
    except Exception as exc:            # mcap's own errors, a JSON or schema mismatch, ...
        raise CoopsimError(f"{log_path}: not a readable coopsim MCAP log ({one_line(exc, 120)})") from None


def motion_from_log(log_path: str | Path, scenario: str | Path | None = None, log=None,
                    closed_loop: bool = False) -> Motion:
    """The joint angles of a `coopsim run` log (/native/joint_state and /mujoco/joint_state), or of the
    closed-loop replay an optimum's run log also holds (CLOSED_LOOP/native/joint_state and
    CLOSED_LOOP/mujoco/joint_state, `coopsim optimize --replay`).

    The log holds the joint angles but not the model's geometry: that comes from the scenario file named in
    its metadata (found relative to the current folder or a folder above the log, and checked against the
    recorded sha256), or from `scenario` when given.

    Args:
        log_path: the MCAP log written by `coopsim run`.
        scenario: the scenario file to draw the log with, in place of the one the log names (no sha256
            check); None: the log's.
        log: the file already read (`LogData`); None: read `log_path`.
        closed_loop: draw the closed-loop pair of runs (topics under CLOSED_LOOP) in place of the open loop.

    Returns:
        Motion: the log's sample times and both models' angles on them (None for a model whose topic is
            missing), source "log PATH" ("closed loop of log PATH" with closed_loop).

    Raises:
        CoopsimError: the log is missing or unreadable, holds neither joint-state topic or no samples, names no
            scenario or one that is not found or has changed since (sha256), has another joint count than
            the scenario, or samples the two models at different times.
    """
    log_path = Path(log_path)
    if log is None:
        if not log_path.is_file():
            raise CoopsimError(f"{log_path}: log file not found")
        log = _read_log(log_path)
    pre = CLOSED_LOOP if closed_loop else ""
    states = {k: log.topics.get(f"{pre}/{k}/joint_state") for k in ("native", "mujoco")}
    if all(s is None for s in states.values()):
        raise CoopsimError(f"{log_path}: no {pre}/native/joint_state or {pre}/mujoco/joint_state topic "
                           + ("(--closed-loop takes the run log of `coopsim optimize --replay` with a closed loop)"
                              if closed_loop else "(animate takes the log of `coopsim run`)"))
    model = log_model(log_path, log, scenario)
    n = model.n_total
    t = None
    q = {}
    for k, s in states.items():
        if s is None:
            q[k] = None
            continue
        if s["angle"].ndim != 2 or s["angle"].shape[1] != n:
            raise CoopsimError(f"{log_path}: {pre}/{k}/joint_state has {s['angle'].shape[-1]} joints, the scenario "
                               f"{model.name} {n}")
        if t is not None and (len(s["t"]) != len(t) or np.any(s["t"] != t)):
            raise CoopsimError(f"{log_path}: {pre}/native and {pre}/mujoco joint states are sampled at different "
                               f"times")
        t, q[k] = s["t"], s["angle"]
    if len(t) == 0:
        raise CoopsimError(f"{log_path}: the joint states hold no samples")
    return Motion(model, t, q["native"], q["mujoco"], f"{'closed loop of ' if closed_loop else ''}log {log_path}",
                  log_payload(log))


def log_payload(log) -> Payload | None:
    """The load of a run log's "payload" record (`coopsim.report.optimum_replay.replay_run_log`), or None.

    Args:
        log: the log as read (`read_mcap`).

    Returns:
        Payload | None: None where the log has no such record (a `coopsim run` log).
    """
    rec = log.metadata.get("payload")
    if rec is None:
        return None
    position = json.loads(rec.get("position_m", "null"))
    return Payload(float(json.loads(rec["mass_kg"])), str(rec["mode"]),
                   None if position is None else np.asarray(position, dtype=float))


def motion_from_run(model: Model, duration: float | None = None, progress=None) -> Motion:
    """Run the native model and the twin and take both models' angles.

    Runs `harness.cross_validate`, as `coopsim run` does; nothing is written.

    Args:
        model: the scenario's Model.
        duration: s, in place of the model's; None: the model's.
        progress: called with (stage, fraction done), stage "native" or "mujoco"; or None.

    Returns:
        Motion: the native run's output times and both models' joint angles on them, source "run".
    """
    cv = cross_validate(model, duration=duration, progress=progress)
    return Motion(model, cv.native.t, cv.native.q, cv.twin.q, "run")


def default_log_path(model: Model) -> Path:
    """Where `coopsim run` writes a scenario's log by default: out/NAME/NAME.mcap.

    Args:
        model: the scenario's Model (its name).

    Returns:
        Path: out/NAME/NAME.mcap, relative to the current folder.
    """
    return Path("out") / model.name / f"{model.name}.mcap"


def reusable_log(path: str | Path, model: Model, duration: float | None = None):
    """The scenario's log `out/NAME/NAME.mcap` (relative to the current folder) when it can stand in for a run.

    It can when it was written from this very file (same sha256) without `--set` overrides, holds both models
    and covers `duration` (its last sample at or after it). An unreadable or foreign file there is not reused.

    Args:
        path: the scenario file (its sha256 is compared with the one the log records).
        model: the Model loaded from it (its name and duration).
        duration: s, the span the log must cover; None: the scenario's.

    Returns:
        tuple | None: (path, LogData) of the log, or None.
    """
    log_path = default_log_path(model)
    if not log_path.is_file():
        return None
    want = model.duration if duration is None else duration
    try:
        log = _read_log(log_path)
        t = log.topics["/native/joint_state"]["t"]
        ok = (log.metadata.get("scenario", {}).get("sha256") == file_sha256(path) and not log_overrides(log)
              and "/mujoco/joint_state" in log.topics and t[-1] >= want - 1e-9)
    except (CoopsimError, KeyError, IndexError):    # an unreadable or foreign file there: run instead
        return None
    return (log_path, log) if ok else None


def scenario_motion(path: str | Path, duration: float | None = None, progress=None,
                    before_run: Callable[[], None] | None = None, overrides=()) -> Motion:
    """The motion of a scenario: its :func:`reusable_log` when there is one, otherwise a fresh run of both models.

    Args:
        path: the scenario file.
        duration: s, in place of the scenario's; None: the scenario's.
        progress: called with (stage, fraction done) during a fresh run (see :func:`motion_from_run`); or None.
        before_run: called with no arguments before a fresh run, e.g. to announce it; or None.
        overrides: the `--set` (path, value) pairs of `coopsim.io.scenario.load_scenario`; with any, the log
            is never reused (the log is the file's).

    Returns:
        Motion: from the log (:func:`motion_from_log`) or from the run (:func:`motion_from_run`).
    """
    model = load_scenario(path, overrides=overrides)
    found = None if overrides else reusable_log(path, model, duration)
    if found is not None:
        return motion_from_log(found[0], scenario=path, log=found[1])
    if before_run is not None:
        before_run()
    return motion_from_run(model, duration=duration, progress=progress)


def frame_times(motion: Motion, fps: float, speed: float = 1.0, duration: float | None = None) -> np.ndarray:
    """Frame times (F,) s: from the first sample, one every speed/fps s of simulated time.

    Up to and including min(first + duration, last sample): F = floor(span·fps/speed) + 1.

    Args:
        motion: the Motion (its sample times).
        fps: frames per second of the animation, > 0.
        speed: s of simulated time per s of animation, > 0.
        duration: s of simulated time shown from the first sample; None: up to the last sample.

    Returns:
        np.ndarray: (F,) s, the frame times.

    Raises:
        CoopsimError: fps or speed not positive, or duration negative.
    """
    if not fps > 0 or not speed > 0:
        raise CoopsimError("fps and speed must be positive")
    t0, t1 = float(motion.t[0]), float(motion.t[-1])
    span = t1 - t0 if duration is None else min(float(duration), t1 - t0)
    if span < 0:
        raise CoopsimError("duration must not be negative")
    count = int(math.floor(span * fps / speed + 1e-9)) + 1
    return t0 + np.arange(count) * (speed / fps)
