"""The interactive viewer: the twin opened in MuJoCo's viewer at its keyframe (`coopsim view`)."""

from __future__ import annotations

import re
import tempfile
import warnings
from pathlib import Path

import mujoco


from coopsim.core.errors import CoopsimError, one_line
from coopsim.io.scenario import load_scenario
from coopsim.twin.mjcf import launch_viewer, mjcf_text
from coopsim.twin.weld import resolved
from coopsim.apps.animate.gl import has_display


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
    if not has_display():
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
            model = resolved(load_scenario(source, overrides=overrides))
            path = Path(tmp) / f"{model.name}.xml"
            path.write_text(mjcf_text(model, label or str(source)), encoding="utf-8")
        try:
            launch_viewer(str(path))
        except Exception as exc:       # GLFW cannot open a window, ...
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise CoopsimError(f"MuJoCo's viewer did not start: {reason}") from None
