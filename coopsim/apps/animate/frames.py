"""The frames: one MuJoCo model of the scene (the twin's spec with the light and floor of `coopsim mjcf`)
posed at each frame time with `mj_kinematics` (nothing is stepped), the native model drawn with the
object and grasp frames, the twin over it as a translucent sleeve, the load a replayed optimum carried (a
sphere at the point payload's position on the object, its mass in the legend), and with Pillow the time
stamp, the largest joint-angle difference and a legend.
"""

from __future__ import annotations

from typing import Iterator

import mujoco
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from coopsim.core.errors import CoopsimError
from coopsim.core.model import Model
from coopsim.twin.mjcf import build_spec, qpos_address, static_settings
from coopsim.apps.animate.gl import OffscreenRenderer
from coopsim.apps.animate.motion import Motion, Payload


NATIVE_RGBA = (0.25, 0.5, 0.9, 1.0)           # native links (the log's Foxglove colours: native blue)


NATIVE_OBJECT_RGBA = (0.1, 0.2, 0.55, 0.6)    # native object (see-through: the frames inside show)


TWIN_RGBA = (0.95, 0.95, 1.0, 0.22)            # MuJoCo twin: translucent orange


SLEEVE = 0.8                                  # the twin's sleeve: margin / the boxes' typical half-thickness


PAYLOAD_RGBA = (1.0, 0.8, 0.0, 1.0)           # a replayed optimum's point payload: gold


PAYLOAD_SIZE = 0.45                           # its sphere's radius / the object's largest half-extent


def scene_model(model: Model, q0: np.ndarray, payload: Payload | None = None) -> mujoco.MjModel:
    """The compiled MuJoCo model of the scene that :func:`render_frames` poses.

    The twin's MJCF with its scene (light, floor), posed at q0 for the floor, plus a site marking the
    object frame; the end-effector sites hidden (group 4: they coincide with the grasp sites). Multisampling
    on, shadows off. With a point payload, a sphere geom "payload" on the object at its position (visual:
    no contact, the object's inertia is explicit), radius PAYLOAD_SIZE × the object's largest half-extent.

    Args:
        model: the scenario's Model.
        q0: (n,) rad (m on a prismatic joint), joint coordinates in coopsim's joint order: the keyframe
            `initial` (zero velocities) the light, floor and camera are placed for.
        payload: the load a replayed optimum carried (a sphere where it is a point payload); None: none.

    Returns:
        mujoco.MjModel: the compiled scene.
    """
    spec = build_spec(model, static_settings(model), initial=(np.asarray(q0, float), np.zeros(model.n_total)), scene=True)
    spec.body("object").add_site(name="object_frame", size=[1e-3, 1e-3, 1e-3])
    if payload is not None and payload.position is not None:
        half = 0.5 * float(np.max(model.object.box)) if np.any(model.object.box > 0) else 0.1
        spec.body("object").add_geom(name="payload", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                                     size=[PAYLOAD_SIZE * half, 0, 0], pos=payload.position, rgba=PAYLOAD_RGBA,
                                     contype=0, conaffinity=0, density=0.0)
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

    def __init__(self, width: int, height: int, native: bool, twin: bool, payload: Payload | None = None):
        self.width, self.height = width, height
        self.size = max(9, round(height / 24))
        self.font, self.small = _font(self.size), _font(max(8, round(self.size * 0.8)))
        self.pad = max(3, self.size // 3)
        # the legend: drawn once on a transparent strip, composited onto every frame
        s = self.small.size
        self.legend = Image.new("RGBA", (width, s + 2 * self.pad), (0, 0, 0, 0))
        draw = ImageDraw.Draw(self.legend)
        x, y = self.pad, self.pad
        for on, label, rgba in ((native, "native", NATIVE_RGBA), (twin, "MuJoCo twin (sleeve)", TWIN_RGBA),
                                (payload is not None, payload_label(payload), PAYLOAD_RGBA)):
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


def payload_label(payload: Payload | None) -> str:
    """The legend's words for a replayed optimum's load.

    Args:
        payload: the Payload, or None.

    Returns:
        str: 'payload 206.04 kg' (a point payload), 'object 12.3 kg (scaled)', or '' for none.
    """
    if payload is None:
        return ""
    return f"payload {payload.mass:.5g} kg" if payload.position is not None else f"object {payload.mass:.5g} kg (scaled)"


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
    m = scene_model(motion.model, q_first, motion.payload)
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
    payload = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "payload")
    if payload >= 0 and native:        # the payload drawn once, on the native model
        twin_rgba[payload, 3] = 0.0
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
    overlay = _Overlay(width, height, native, twin, motion.payload) if text else None
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
