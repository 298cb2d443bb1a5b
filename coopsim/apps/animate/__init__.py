"""Animations of a run: both models' poses drawn by MuJoCo's offscreen OpenGL renderer, into a GIF or an MP4.

    gl.py      the OpenGL platform, the offscreen renderer (imported first: a MUJOCO_GL that breaks
               `import mujoco` is a one-line RenderUnavailable, not a traceback)
    motion.py  what an animation shows, from a log, a run or a scenario; the frame times
    frames.py  the frames drawn
    output.py  the GIF or MP4 written
    viewer.py  the interactive viewer

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
- the load of a replayed optimum (`coopsim optimize --replay`, its log's "payload" record): a gold sphere
  on the object at the point payload's position, its mass in the legend (a scaled object: the mass only),
- with Pillow: the time stamp, the largest joint-angle difference of the two models at that time, a legend.

The camera keeps every frame's boxes in view from the scene's azimuth and elevation. Angles between logged
samples are interpolated linearly (frame times on the log's grid, the usual case, take the samples
exactly). :func:`animate` writes a GIF with Pillow (one palette for every frame, no dithering, unchanged
pixels transparent) or an MP4 through the `ffmpeg` program, atomically. Shadows and reflections are off:
with software OpenGL (mesa's llvmpipe) they cost several times the rest.

The OpenGL platform, and the one-line error when it cannot start, are gl.py's.
"""

# gl first: it imports mujoco behind the guard that words a broken MUJOCO_GL as one line
from coopsim.apps.animate.gl import OffscreenRenderer, RenderUnavailable, probe_renderer  # isort: skip
from coopsim.apps.animate.frames import render_frames
from coopsim.apps.animate.motion import Motion, frame_times, motion_from_log, motion_from_run, scenario_motion
from coopsim.apps.animate.output import Animation, animate, check_output
from coopsim.apps.animate.viewer import view

__all__ = ["Animation", "Motion", "OffscreenRenderer", "RenderUnavailable", "animate", "check_output", "frame_times",
           "motion_from_log", "motion_from_run", "probe_renderer", "render_frames", "scenario_motion", "view"]
