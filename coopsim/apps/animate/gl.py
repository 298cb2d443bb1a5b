"""The OpenGL platform of MuJoCo's offscreen renderer: MUJOCO_GL when set (egl, osmesa, glfw); unset on
Linux: EGL (Debian/Ubuntu package libegl1 with mesa's driver; works with or without a display), OSMesa
(libosmesa6) when there is no libEGL. The context is made here rather than by `mujoco.Renderer`, whose
platform is fixed when mujoco is first imported (glfw when MUJOCO_GL is unset, which fails without a
display). A platform that cannot start, or a MUJOCO_GL that breaks `import mujoco` itself, is a one-line
:class:`RenderUnavailable` naming MUJOCO_GL and the package.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import importlib
import os
import re
import sys
import warnings

import numpy as np

from coopsim.core.errors import CoopsimError, one_line


class RenderUnavailable(CoopsimError):
    """No OpenGL backend for MuJoCo's offscreen renderer (one line naming MUJOCO_GL and the package)."""


try:
    import mujoco
except Exception as _exc:   # MUJOCO_GL names a backend whose library is missing: mujoco's own import fails
    raise RenderUnavailable(f"import mujoco failed with MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r} "
                            f"({one_line(_exc, 120)}); install that backend (EGL: Debian/Ubuntu libegl1 and "
                            f"libgl1-mesa-dri; OSMesa: libosmesa6) or unset MUJOCO_GL") from None


def has_display() -> bool:
    """Whether a window system is there (DISPLAY or WAYLAND_DISPLAY set; always True off Linux).

    Returns:
        bool: True when a glfw window can be tried.
    """
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
        if has_display():
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
