"""Animations of a run: both models' poses drawn by MuJoCo's offscreen OpenGL renderer, into a GIF or an MP4.

A :class:`Motion` is what an animation shows: the scenario's frozen `Model` and the joint angles of the
native model and of the MuJoCo twin over time, from a `coopsim run` log (:func:`motion_from_log`; the log
holds the angles, the geometry comes from the scenario file it names) or from running the scenario
(:func:`motion_from_run`; :func:`scenario_motion` prefers the scenario's log in `out/NAME/` when it was
written from the same file). :func:`render_frames` poses one MuJoCo model of the scene (the twin's spec
with the light and floor of `coopsim mjcf`, `mjcf.build_spec(scene=True)`) at each frame time with
`mj_kinematics` (nothing is stepped) and draws

- the native model (links blue, the object translucent dark blue) with the object frame and the grasp
  frames (MuJoCo's site frames: x red, y green, z blue),
- the MuJoCo twin over it as a translucent white sleeve (its boxes grown on every side by 0.8 of a link's
  typical half-thickness: coincident faces would flicker), so where the twin departs from the native
  model the two part,
- with Pillow: the time stamp, the largest joint-angle difference of the two models at that time, a legend.

The camera keeps every frame's boxes in view from the scene's azimuth and elevation. Angles between logged
samples are interpolated linearly (frame times on the log's grid, the usual case, take the samples
exactly). :func:`animate` writes a GIF with Pillow (one palette for every frame, no dithering, unchanged
pixels transparent) or an MP4 through the `ffmpeg` program, atomically. Shadows and reflections are off:
with software OpenGL (mesa's llvmpipe) they cost several times the rest.

OpenGL platform: MUJOCO_GL when set (egl, osmesa, glfw); unset on Linux: EGL (Debian/Ubuntu package
libegl1 with mesa's driver; works with or without a display), OSMesa (libosmesa6) when there is no libEGL.
The context is made here rather than by `mujoco.Renderer`, whose platform is fixed when mujoco is first
imported (glfw when MUJOCO_GL is unset, which fails without a display). A platform that cannot start is a
one-line :class:`RenderUnavailable` naming MUJOCO_GL and the package.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import importlib
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from coopsim.core.errors import CoopsimError, one_line
from coopsim.core.model import Model
from coopsim.io.log import file_sha256
from coopsim.io.mcap_codec import read_mcap
from coopsim.io.scenario import load_scenario
from coopsim.twin.harness import cross_validate
from coopsim.twin.mjcf import launch_viewer, mjcf_text


class RenderUnavailable(CoopsimError):
    """No OpenGL backend for MuJoCo's offscreen renderer (one line naming MUJOCO_GL and the package)."""


try:
    import mujoco
except Exception as _exc:   # MUJOCO_GL names a backend whose library is missing: mujoco's own import fails
    raise RenderUnavailable(f"import mujoco failed with MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r} "
                            f"({one_line(_exc, 120)}); install that backend (EGL: Debian/Ubuntu libegl1 and "
                            f"libgl1-mesa-dri; OSMesa: libosmesa6) or unset MUJOCO_GL") from None

from coopsim.io.atomic import atomic_path
from coopsim.twin.mjcf import build_spec, qpos_address

SUFFIXES = (".gif", ".mp4")

NATIVE_RGBA = (0.25, 0.5, 0.9, 1.0)           # native links (the log's Foxglove colours: native blue)
NATIVE_OBJECT_RGBA = (0.1, 0.2, 0.55, 0.6)    # native object (see-through: the frames inside show)
TWIN_RGBA = (0.95, 0.95, 1.0, 0.22)            # MuJoCo twin: translucent orange
SLEEVE = 0.8                                  # the twin's sleeve: margin / the boxes' typical half-thickness


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
    """

    model: Model
    t: np.ndarray
    q_native: np.ndarray | None
    q_twin: np.ndarray | None
    source: str

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


# ------------------------------------------------------------------------------------------------
# sources: a log, a run, a scenario
# ------------------------------------------------------------------------------------------------

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


def _read_log(log_path: Path):
    try:
        return read_mcap(log_path)
    except Exception as exc:            # mcap's own errors, a JSON or schema mismatch, ...
        raise CoopsimError(f"{log_path}: not a readable coopsim MCAP log ({one_line(exc, 120)})") from None


def motion_from_log(log_path: str | Path, scenario: str | Path | None = None, log=None) -> Motion:
    """The joint angles of a `coopsim run` log (/native/joint_state and /mujoco/joint_state).

    The log holds the joint angles but not the model's geometry: that comes from the scenario file named in
    its metadata (found relative to the current folder or a folder above the log, and checked against the
    recorded sha256), or from `scenario` when given.

    Args:
        log_path: the MCAP log written by `coopsim run`.
        scenario: the scenario file to draw the log with, in place of the one the log names (no sha256
            check); None: the log's.
        log: the file already read (`LogData`); None: read `log_path`.

    Returns:
        Motion: the log's sample times and both models' angles on them (None for a model whose topic is
            missing), source "log PATH".

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
    states = {k: log.topics.get(f"/{k}/joint_state") for k in ("native", "mujoco")}
    if all(s is None for s in states.values()):
        raise CoopsimError(f"{log_path}: no /native/joint_state or /mujoco/joint_state topic "
                           f"(animate takes the log of `coopsim run`)")
    info = log.metadata.get("scenario", {})
    if scenario is None:
        file = info.get("file")
        if file is None:
            raise CoopsimError(f"{log_path}: the log names no scenario file, and the model's geometry is not "
                               f"in the log: pass the scenario with --scenario FILE")
        found = _log_scenario_path(log_path, file)
        if found is None:
            raise CoopsimError(f"{log_path}: its scenario {file} was not found (relative to the current folder "
                               f"or the log's); the model's geometry is not in the log: pass --scenario FILE")
        if "sha256" in info and file_sha256(found) != info["sha256"]:
            raise CoopsimError(f"{found}: changed since {log_path} was written (sha256 differs); run the "
                               f"scenario again, or pass --scenario FILE to draw the log with it anyway")
        scenario = found
    model = load_scenario(scenario)
    n = model.n_total
    t = None
    q = {}
    for k, s in states.items():
        if s is None:
            q[k] = None
            continue
        if s["angle"].ndim != 2 or s["angle"].shape[1] != n:
            raise CoopsimError(f"{log_path}: /{k}/joint_state has {s['angle'].shape[-1]} joints, the scenario "
                               f"{scenario} {n}")
        if t is not None and (len(s["t"]) != len(t) or np.any(s["t"] != t)):
            raise CoopsimError(f"{log_path}: /native and /mujoco joint states are sampled at different times")
        t, q[k] = s["t"], s["angle"]
    if len(t) == 0:
        raise CoopsimError(f"{log_path}: the joint states hold no samples")
    return Motion(model, t, q["native"], q["mujoco"], f"log {log_path}")


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

    It can when it was written from this very file (same sha256), holds both models and covers `duration`
    (its last sample at or after it). An unreadable or foreign file there is not reused.

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
        ok = (log.metadata.get("scenario", {}).get("sha256") == file_sha256(path)
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


# ------------------------------------------------------------------------------------------------
# frame times
# ------------------------------------------------------------------------------------------------

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


# ------------------------------------------------------------------------------------------------
# rendering
# ------------------------------------------------------------------------------------------------

def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or not sys.platform.startswith("linux")


def _backend() -> str:
    """The OpenGL platform: MUJOCO_GL when set (mujoco has checked the name on import: another one than
    egl/osmesa/glfw is mujoco's own choice, 'default'); unset on Linux: EGL (works with or without a
    display), OSMesa when there is no libEGL, glfw when neither is there; elsewhere mujoco's default."""
    name = os.environ.get("MUJOCO_GL", "").strip().lower()
    if name in ("egl", "osmesa", "glfw"):
        return name
    if name or not sys.platform.startswith("linux"):
        return "default"
    if ctypes.util.find_library("EGL") is None:
        if ctypes.util.find_library("OSMesa") is not None:
            return "osmesa"
        if _has_display():
            return "glfw"
    return "egl"


def _gl_context(backend: str, width: int, height: int):
    if backend == "default":
        from mujoco.rendering.classic import gl_context

        return gl_context.GLContext(width, height)
    return importlib.import_module(f"mujoco.{backend}").GLContext(width, height)


PACKAGES = ("EGL (Debian/Ubuntu: libegl1 and mesa's libgl1-mesa-dri; MUJOCO_GL=egl) or OSMesa (libosmesa6; "
            "MUJOCO_GL=osmesa)")


def _unavailable(backend: str, reason: str) -> RenderUnavailable:
    env = os.environ.get("MUJOCO_GL")
    return RenderUnavailable(
        f"MuJoCo's offscreen renderer did not start on {backend} ({f'MUJOCO_GL={env}' if env else 'MUJOCO_GL unset'}): "
        f"{reason}; headless rendering needs {PACKAGES}")


class OffscreenRenderer:
    """MuJoCo's offscreen renderer on an explicitly chosen OpenGL backend.

    Makes the calls `mujoco.Renderer` makes, on the backend of the module notes, so it works in a process
    that imported mujoco without MUJOCO_GL. A context manager: leaving the `with` block closes it.

    Args:
        m: the MuJoCo model drawn (its offscreen buffer size is raised to width × height where smaller:
            written).
        width, height: the image size in pixels.

    Attributes:
        backend: the OpenGL platform: "egl", "osmesa", "glfw" or "default" (mujoco's own choice).
        width, height: the image size in pixels.
        viewport: the MjrRect drawn into (the whole image).

    Raises:
        RenderUnavailable: the backend cannot start (one line naming MUJOCO_GL and the packages).
    """

    def __init__(self, m: mujoco.MjModel, width: int, height: int):
        self.backend = _backend()
        self.width, self.height = width, height
        self._ctx = self._con = None
        m.vis.global_.offwidth = max(m.vis.global_.offwidth, width)
        m.vis.global_.offheight = max(m.vis.global_.offheight, height)
        with warnings.catch_warnings(record=True) as caught:     # GLFW reports through warnings
            warnings.simplefilter("always")
            try:
                if self.backend == "egl":
                    os.environ.setdefault("EGL_LOG_LEVEL", "fatal")    # mesa's loader warnings: the error says it
                self._ctx = _gl_context(self.backend, width, height)
                self._ctx.make_current()
                self._con = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
                mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
                failure = None
            except Exception as exc:   # ImportError, OSError, mujoco.FatalError, EGL/GLFW errors
                failure = exc
                with contextlib.suppress(Exception):
                    self.close()
        if failure is not None:
            reason = one_line(caught[0].message, 120) if caught else one_line(failure, 120)
            reason = re.sub(r"^\(\d+\) b['\"](.*)['\"]$", r"\1", reason)      # GLFWError: (65550) b'...'
            raise _unavailable(self.backend, reason) from None
        self.viewport = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)

    def render(self, scene: mujoco.MjvScene) -> np.ndarray:
        """The scene as an RGB image, top row first (a fresh array).

        Args:
            scene: the MjvScene to draw (filled by mjv_updateScene / mjv_addGeoms).

        Returns:
            np.ndarray: (height, width, 3) uint8 RGB.

        Raises:
            RuntimeError: the renderer is closed.
        """
        if self._con is None:
            raise RuntimeError("renderer closed")
        """The scene as an RGB image (height, width, 3), top row first (a fresh array)."""
        self._ctx.make_current()
        mujoco.mjr_render(self.viewport, scene, self._con)
        mujoco.mjr_readPixels(self._rgb, None, self.viewport, self._con)
        return self._rgb[::-1].copy()

    def close(self) -> None:
        """Free the MuJoCo rendering context and the OpenGL context (a no-op once closed)."""
        if self._ctx is not None:
            try:
                with warnings.catch_warnings():      # GLFW's complaints about a context that never started
                    warnings.simplefilter("ignore")
                    self._ctx.make_current()
                    if self._con is not None:
                        self._con.free()
                    self._ctx.free()
            finally:
                self._ctx = self._con = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def probe_renderer() -> str:
    """Start and stop an OpenGL context on the backend `render_frames` would use (before a long run).

    Returns:
        str: the backend's name: "egl", "osmesa", "glfw" or "default".

    Raises:
        RenderUnavailable: the backend cannot start.
    """
    m = mujoco.MjModel.from_xml_string("<mujoco/>")
    m.vis.quality.shadowsize = 0
    with OffscreenRenderer(m, 16, 16) as r:
        return r.backend


def scene_model(model: Model, q0: np.ndarray) -> mujoco.MjModel:
    """The compiled MuJoCo model of the scene that :func:`render_frames` poses.

    The twin's MJCF with its scene (light, floor), posed at q0 for the floor, plus a site marking the
    object frame; the end-effector sites hidden (group 4: they coincide with the grasp sites). Multisampling
    on, shadows off.

    Args:
        model: the scenario's Model.
        q0: (n,) rad (m on a prismatic joint), joint coordinates in coopsim's joint order: the keyframe
            `initial` (zero velocities) the light, floor and camera are placed for.

    Returns:
        mujoco.MjModel: the compiled scene.
    """
    spec = build_spec(model, initial=(np.asarray(q0, float), np.zeros(model.n_total)), scene=True)
    spec.body("object").add_site(name="object_frame", size=[1e-3, 1e-3, 1e-3])
    for m in range(model.r):
        spec.site(f"a{m}_ee").group = 4
    for site in spec.sites:
        site.size = [1e-3, 1e-3, 1e-3]
    m = spec.compile()
    m.vis.quality.offsamples = 4          # multisampling: thin links without jagged edges
    m.vis.quality.shadowsize = 0          # shadows are off (software OpenGL draws them slowly)
    m.vis.headlight.ambient[:], m.vis.headlight.diffuse[:] = 0.3, 0.5
    return m


def _frame_points(m: mujoco.MjModel, d: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """World corners of the given box geoms and the visible sites, at d's pose."""
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    pts = [d.site_xpos]
    for g in geoms:
        pts.append(d.geom_xpos[g] + (signs * m.geom_size[g]) @ d.geom_xmat[g].reshape(3, 3).T)
    return np.vstack(pts)


def _camera(m: mujoco.MjModel, points: np.ndarray, width: int, height: int) -> mujoco.MjvCamera:
    """A free camera at the scene's azimuth/elevation (`mjcf` framing) that keeps `points` in view."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.azimuth, cam.elevation = m.vis.global_.azimuth, m.vis.global_.elevation
    a, e = np.deg2rad(cam.azimuth), np.deg2rad(cam.elevation)
    forward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([np.sin(a), -np.cos(a), 0.0])
    up = np.cross(right, forward)
    # centre the points' extent across the view, then back off until every point is inside both angles
    x, y = points @ right, points @ up
    center = points.mean(axis=0)
    center += (0.5 * (x.max() + x.min()) - center @ right) * right + (0.5 * (y.max() + y.min()) - center @ up) * up
    rel = points - center
    tan_v = np.tan(np.deg2rad(m.vis.global_.fovy) / 2)
    tan_h = tan_v * width / height
    margin = 1.08
    distance = np.max(np.maximum(margin * np.abs(rel @ right) / tan_h, margin * np.abs(rel @ up) / tan_v)
                      - rel @ forward)
    cam.lookat[:] = center
    cam.distance = max(float(distance), 1e-3)
    return cam


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, ImportError, OSError):      # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


class _Overlay:
    """Text on each frame: the time stamp (top left), a legend (bottom left; drawn once) and the joint-angle
    difference of the two models (bottom right, when it fits)."""

    def __init__(self, width: int, height: int, native: bool, twin: bool):
        self.width, self.height = width, height
        self.size = max(9, round(height / 24))
        self.font, self.small = _font(self.size), _font(max(8, round(self.size * 0.8)))
        self.pad = max(3, self.size // 3)
        # the legend: drawn once on a transparent strip, composited onto every frame
        s = self.small.size
        self.legend = Image.new("RGBA", (width, s + 2 * self.pad), (0, 0, 0, 0))
        draw = ImageDraw.Draw(self.legend)
        x, y = self.pad, self.pad
        for on, label, rgba in ((native, "native", NATIVE_RGBA), (twin, "MuJoCo twin (sleeve)", TWIN_RGBA)):
            if on:
                draw.rectangle([x, y + 1, x + s - 2, y + s - 1], fill=tuple(round(255 * c) for c in rgba[:3]),
                               outline=(0, 0, 0))
                x += s + 2
                draw.text((x, y), label, font=self.small, fill=(255, 255, 255), stroke_width=1,
                          stroke_fill=(0, 0, 0))
                x += round(draw.textlength(label, font=self.small)) + 2 * self.pad
        self.legend_right = x
        self.legend_y = height - self.legend.height

    def draw(self, image, t: float, dq: float | None):
        image.paste(self.legend, (0, self.legend_y), self.legend)
        draw = ImageDraw.Draw(image)
        stamp = f"t = {t:5.2f} s"
        draw.rectangle([0, 0, 2 * self.pad + draw.textlength(stamp, font=self.font), 2 * self.pad + self.font.size],
                       fill=(20, 20, 24))
        draw.text((self.pad, self.pad), stamp, font=self.font, fill=(255, 255, 255))
        if dq is not None:
            text = f"max |q_native - q_MuJoCo| = {dq:.1e} rad"
            w = draw.textlength(text, font=self.small)
            if self.legend_right + w + self.pad <= self.width:
                x, y = self.width - self.pad - w, self.legend_y + self.pad
                draw.rectangle([x - self.pad, y - self.pad, self.width, self.height], fill=(20, 20, 24))
                draw.text((x, y), text, font=self.small, fill=(255, 255, 255))


def render_frames(motion: Motion, times: np.ndarray, width: int = 480, height: int = 360, *,
                  native: bool = True, twin: bool = True, text: bool = True, floor: bool = True,
                  twin_sleeve: bool = True) -> Iterator[np.ndarray]:
    """RGB frames of `motion` at `times`, drawn by MuJoCo's offscreen renderer.

    The native model in its colours with the object and grasp frames, the twin as a translucent sleeve over
    it, the time stamp, the joint-angle difference and a legend. The camera frames both models at every one
    of `times`, whichever are drawn. Poses are set with mj_kinematics; nothing is simulated.

    Args:
        motion: the Motion drawn.
        times: (F,) s, the frame times (:func:`frame_times`).
        width, height: the frame size in pixels.
        native: False leaves the native model out.
        twin: False leaves the twin out.
        text: False leaves out the time stamp, the joint-angle difference and the legend.
        floor: False leaves the floor out (plain background).
        twin_sleeve: False draws the twin's boxes at their true size instead of grown into a sleeve.

    Yields:
        np.ndarray: (height, width, 3) uint8 RGB, one frame per entry of `times`, in order.

    Raises:
        CoopsimError: neither model is left to draw (on the first frame: this is a generator).
        RenderUnavailable: no OpenGL backend starts.
    """
    q_native, q_twin = motion.at(np.asarray(times, float))
    native = native and q_native is not None
    twin = twin and q_twin is not None
    if not (native or twin):
        raise CoopsimError("nothing to draw: neither model's angles are given")
    q_first = (q_native if q_native is not None else q_twin)[0]
    m = scene_model(motion.model, q_first)
    qadr = qpos_address(m, motion.model)
    dyn = np.flatnonzero((m.geom_bodyid > 0) & (m.geom_type == mujoco.mjtGeom.mjGEOM_BOX))
    obj_geoms = np.flatnonzero(m.geom_bodyid == m.body("object").id)
    if not floor:
        m.geom_rgba[m.geom_bodyid == 0, 3] = 0.0
    native_rgba = m.geom_rgba.copy()
    native_rgba[dyn] = NATIVE_RGBA
    native_rgba[np.intersect1d(dyn, obj_geoms)] = NATIVE_OBJECT_RGBA
    twin_rgba = native_rgba.copy()
    twin_rgba[dyn] = TWIN_RGBA
    native_size = m.geom_size.copy()
    twin_size = native_size.copy()
    if twin_sleeve:                    # every box grown by the same margin: a sleeve of even thickness
        twin_size[dyn] += SLEEVE * np.median(np.min(native_size[dyn], axis=1))
    # the object and grasp frames: arrows 0.35 of the object's largest dimension long
    length = 0.35 * 2 * float(np.max(m.geom_size[obj_geoms])) if len(obj_geoms) else 0.3 * m.stat.meansize
    m.vis.scale.framelength = length / m.stat.meansize
    m.vis.scale.framewidth = m.vis.scale.framelength / 9

    d_native, d_twin = mujoco.MjData(m), mujoco.MjData(m)
    # camera: every box and site of every frame in view, both models' (drawn or not: the same view for each)
    points = []
    for q in (q_native, q_twin):
        if q is None:
            continue
        for k in np.unique(np.linspace(0, len(q) - 1, min(len(q), 60)).round().astype(int)):
            d_native.qpos[qadr] = q[k]
            mujoco.mj_kinematics(m, d_native)
            points.append(_frame_points(m, d_native, dyn))
    cam = _camera(m, np.vstack(points), width, height)

    opt_native, opt_twin = mujoco.MjvOption(), mujoco.MjvOption()
    opt_native.frame = mujoco.mjtFrame.mjFRAME_SITE
    opt_twin.sitegroup[:] = 0
    if not native:                      # the twin alone: it carries the frames
        opt_twin = opt_native
    scn = mujoco.MjvScene(m, maxgeom=1000)
    for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX):
        scn.flags[flag] = 0
    overlay = _Overlay(width, height, native, twin) if text else None
    dq = (np.max(np.abs(q_native - q_twin), axis=1) if native and twin else [None] * len(times))
    catall = int(mujoco.mjtCatBit.mjCAT_ALL)
    pert = mujoco.MjvPerturb()
    with OffscreenRenderer(m, width, height) as renderer:
        for k, t in enumerate(times):
            first = True
            for d, q, opt, rgba, size, on in ((d_native, q_native, opt_native, native_rgba, native_size, native),
                                              (d_twin, q_twin, opt_twin, twin_rgba, twin_size, twin)):
                if not on:
                    continue
                d.qpos[qadr] = q[k]
                mujoco.mj_kinematics(m, d)
                m.geom_rgba[:], m.geom_size[:] = rgba, size
                if first:
                    mujoco.mjv_updateScene(m, d, opt, pert, cam, catall, scn)
                    first = False
                else:                  # the second model: its moving geoms only
                    mujoco.mjv_addGeoms(m, d, opt, pert, int(mujoco.mjtCatBit.mjCAT_DYNAMIC), scn)
            m.geom_rgba[:], m.geom_size[:] = native_rgba, native_size
            rgb = renderer.render(scn)
            if overlay is not None:
                image = Image.fromarray(rgb)
                overlay.draw(image, float(t), dq[k])
                rgb = np.asarray(image)
            yield rgb


# ------------------------------------------------------------------------------------------------
# output
# ------------------------------------------------------------------------------------------------

def check_output(path: str | Path) -> str:
    """The output format of `path`, from its suffix.

    Args:
        path: the output file (.gif or .mp4, any case).

    Returns:
        str: 'gif' or 'mp4'.

    Raises:
        CoopsimError: an unknown suffix (named), or an MP4 without the ffmpeg program on PATH (naming the
            program).
    """
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise CoopsimError(f"--out {path}: unknown suffix {suffix or '(none)'!r}; use .gif or .mp4")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise CoopsimError(f"--out {path}: writing an MP4 needs the program ffmpeg on PATH (Debian/Ubuntu: "
                           f"apt install ffmpeg); use .gif without it")
    return suffix[1:]


def _write_gif(frames: list[np.ndarray], path: Path, fps: float) -> None:
    images = [Image.fromarray(f) for f in frames]
    # one palette for every frame (from the first, middle and last): no flicker, and frames compress as
    # differences from the previous one
    picks = sorted({0, len(images) // 2, len(images) - 1})
    sample = Image.fromarray(np.vstack([frames[i] for i in picks]))
    palette = sample.quantize(colors=255, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    quantized = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    quantized[0].save(path, format="GIF", save_all=True, append_images=quantized[1:], loop=0,
                      duration=round(1000.0 / fps), optimize=True, disposal=1)


def _write_mp4(frames: Iterable[np.ndarray], path: Path, fps: float, width: int, height: int) -> None:
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise CoopsimError("writing an MP4 needs the program ffmpeg on PATH (Debian/Ubuntu: apt install ffmpeg)")
    cmd = [ffmpeg, "-nostdin", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
           "-s", f"{width}x{height}", "-framerate", f"{fps:g}", "-i", "pipe:0",
           "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-movflags", "+faststart",
           "-f", "mp4", str(path)]
    with subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) as proc:
        try:
            for f in frames:
                proc.stdin.write(np.ascontiguousarray(f).tobytes())
            proc.stdin.close()
        except BrokenPipeError:     # ffmpeg stopped: its message follows
            pass
        err = proc.stderr.read().decode(errors="replace")
        rc = proc.wait()
    if rc != 0:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        raise CoopsimError(f"ffmpeg failed (status {rc}): {lines[-1] if lines else 'no message'}")


@dataclass(frozen=True)
class Animation:
    """What :func:`animate` wrote.

    Attributes:
        path: the file written.
        frames: the frame count.
        width, height: the frame size in pixels.
        fps: frames per second.
        span: s, the frame times' span (simulated time from the first frame to the last).
        max_angle_difference: rad (m on a prismatic joint), the largest joint-angle difference of the two
            models over the frames; None with one model.
        render_time: s, the wall time of rendering the frames.
        write_time: s, the wall time of encoding and writing the file.
        source: where the angles came from (`Motion.source`).
    """

    path: Path
    frames: int
    width: int
    height: int
    fps: float
    span: float
    max_angle_difference: float | None
    render_time: float
    write_time: float
    source: str

    def as_dict(self) -> dict:
        """The record as JSON-ready values, keys carrying their units.

        Returns:
            dict: path (str), frames, width, height, fps, span_s, max_angle_difference_rad, render_time_s,
                write_time_s, source.
        """
        return {"path": str(self.path), "frames": self.frames, "width": self.width, "height": self.height,
                "fps": self.fps, "span_s": self.span, "max_angle_difference_rad": self.max_angle_difference,
                "render_time_s": self.render_time, "write_time_s": self.write_time, "source": self.source}


def animate(motion: Motion, out: str | Path, *, fps: float = 20.0, speed: float = 1.0,
            duration: float | None = None, width: int = 480, height: int = 360,
            progress: Callable[[float], None] | None = None) -> Animation:
    """Render `motion` at :func:`frame_times` and write it to `out`, atomically.

    The frames are those of :func:`render_frames` (both models, text, floor); a .gif is written with
    Pillow, an .mp4 through ffmpeg.

    Args:
        motion: the Motion drawn.
        out: the output file, .gif or .mp4 (written atomically).
        fps: frames per second of the animation.
        speed: s of simulated time per s of animation.
        duration: s of simulated time shown from the first sample; None: up to the last sample.
        width, height: the frame size in pixels, 16 ... 4096.
        progress: called with the fraction of the frames rendered; or None.

    Returns:
        Animation: what was written.

    Raises:
        CoopsimError: a bad suffix or no ffmpeg for an MP4 (:func:`check_output`), a frame size outside
            16 ... 4096, fps, speed or duration out of range (:func:`frame_times`), or ffmpeg failing.
        RenderUnavailable: no OpenGL backend starts.
    """
    fmt = check_output(out)
    if width < 16 or height < 16 or width > 4096 or height > 4096:
        raise CoopsimError(f"frame size {width}x{height}: width and height must be 16 ... 4096 pixels")
    times = frame_times(motion, fps, speed, duration)
    q_native, q_twin = motion.at(times)
    dq = float(np.max(np.abs(q_native - q_twin))) if q_native is not None and q_twin is not None else None
    start = time.perf_counter()
    frames = []
    for k, f in enumerate(render_frames(motion, times, width, height)):
        frames.append(f)
        if progress is not None:
            progress((k + 1) / len(times))
    rendered = time.perf_counter()
    out = Path(out)
    with atomic_path(out) as tmp:
        if fmt == "gif":
            _write_gif(frames, tmp, fps)
        else:
            _write_mp4(frames, tmp, fps, width, height)
    return Animation(out, len(times), width, height, fps, float(times[-1] - times[0]), dq,
                     rendered - start, time.perf_counter() - rendered, motion.source)


# ------------------------------------------------------------------------------------------------
# the interactive viewer
# ------------------------------------------------------------------------------------------------

def _check_window() -> None:
    """GLFW can open a window here (MuJoCo's viewer exits the process when it cannot): else CoopsimError."""
    import glfw

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ok = glfw.init()
        if ok:
            glfw.terminate()
    if not ok:
        reason = one_line(caught[0].message, 120) if caught else "glfw.init() failed"
        reason = re.sub(r"^\(\d+\) b['\"](.*)['\"]$", r"\1", reason)
        raise CoopsimError(f"MuJoCo's interactive viewer cannot open a window ({reason}); without a display, "
                           f"`coopsim animate` renders the run into a GIF")


def view(source: str | Path, label: str | None = None, overrides=()) -> None:
    """Open MuJoCo's interactive viewer (`mjcf.launch_viewer`) at the consistent initial state.

    On an MJCF file (`models/NAME.xml`, started at its keyframe) or on a scenario (its twin written as
    `coopsim mjcf` would, to a temporary file, `overrides` applied as `load_scenario` does). Returns when
    the window is closed.

    Args:
        source: an MJCF file (.xml) or a scenario file.
        label: the source named in the temporary MJCF's header (`mjcf_text`); None: the scenario's path.
            Unused for an MJCF file.
        overrides: the `--set` (path, value) pairs applied to a scenario; unused for an MJCF file.

    Raises:
        CoopsimError: the file is missing or MuJoCo cannot load it, there is no display or no window opens,
            or the viewer does not start.
    """
    source = Path(source)
    if not source.is_file():
        raise CoopsimError(f"{source}: file not found")
    if not _has_display():
        raise CoopsimError("MuJoCo's interactive viewer needs a display (DISPLAY is not set); without one, "
                           "`coopsim animate` renders the run into a GIF")
    _check_window()
    with tempfile.TemporaryDirectory(prefix="coopsim-view-") as tmp:
        if source.suffix.lower() == ".xml":
            try:
                mujoco.MjModel.from_xml_path(str(source))
            except ValueError as exc:
                raise CoopsimError(f"{source}: MuJoCo cannot load it: {str(exc).splitlines()[0]}") from None
            path = source
        else:
            model = load_scenario(source, overrides=overrides)
            path = Path(tmp) / f"{model.name}.xml"
            path.write_text(mjcf_text(model, label or str(source)), encoding="utf-8")
        try:
            launch_viewer(str(path))
        except Exception as exc:       # GLFW cannot open a window, ...
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise CoopsimError(f"MuJoCo's viewer did not start: {reason}") from None
