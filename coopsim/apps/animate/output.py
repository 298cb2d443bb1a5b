"""The animation file: a GIF with Pillow (one palette for every frame, no dithering, unchanged pixels
transparent) or an MP4 through the `ffmpeg` program, written atomically.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from PIL import Image

from coopsim.core.errors import CoopsimError
from coopsim.io.atomic import atomic_path
from coopsim.apps.animate.frames import render_frames
from coopsim.apps.animate.motion import Motion, frame_times


SUFFIXES = (".gif", ".mp4")


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
