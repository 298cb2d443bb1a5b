"""The Foxglove 3D view of a run: the published schemas of `foxglove.FrameTransforms` and
`foxglove.SceneUpdate` (tests/data/foxglove holds the published files, and the tests validate the
messages against them), the `/tf` topic with a frame per link and the object (native and twin), and
the `/scene` topic with a box per link and the object.
"""

from __future__ import annotations


import numpy as np

from coopsim.dynamics.kinematics import arm_frames
from coopsim.core.model import Model
from coopsim.core.spatial import rot_to_quat, rots_to_quats

# The log format's own names (written into every log, and SERIES_COMMENT read back to find a series):
# identifiers of the format, not module paths, so they stay as the first logs wrote them.
from coopsim.io.mcap_codec import JsonTopic, time_schema, stamp, time_ns


def _number_object(title: str, description: str, keys: str, required: bool = True) -> dict:
    out = {"title": title, "description": description, "type": "object",
           "properties": {k: {"type": "number"} for k in keys}}
    if required:
        out["required"] = list(keys)
    return out


def _pose_schema(description: str) -> dict:
    return {"title": "foxglove.Pose", "description": description, "type": "object",
            "properties": {"position": _number_object("foxglove.Vector3", "Point denoting position in 3D space", "xyz"),
                           "orientation": _number_object("foxglove.Quaternion",
                                                         "Quaternion denoting orientation in 3D space", "xyzw")},
            "required": ["position", "orientation"]}


FRAME_TRANSFORMS_SCHEMA: dict = {
    "title": "foxglove.FrameTransforms",
    "description": "An array of FrameTransform messages",
    "type": "object",
    "properties": {"transforms": {
        "type": "array",
        "description": "Array of transforms",
        "items": {
            "title": "foxglove.FrameTransform",
            "description": "A transform between two reference frames in 3D space",
            "type": "object",
            "properties": {
                "timestamp": time_schema("Timestamp of transform"),
                "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
                "child_frame_id": {"type": "string", "description": "Name of the child frame"},
                "translation": _number_object("foxglove.Vector3", "Translation component of the transform", "xyz"),
                "rotation": _number_object("foxglove.Quaternion", "Rotation component of the transform", "xyzw"),
            },
            "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
        }}},
    "required": ["transforms"],
}


_CUBE_SCHEMA = {
    "title": "foxglove.CubePrimitive",
    "description": "A primitive representing a cube or rectangular prism",
    "type": "object",
    "properties": {
        "pose": _pose_schema("Position of the center of the cube and orientation of the cube"),
        "size": _number_object("foxglove.Vector3", "Size of the cube along each axis", "xyz"),
        "color": _number_object("foxglove.Color", "Color of the cube", "rgba"),
    },
    "required": ["pose", "size", "color"],
}


# The published foxglove.SceneEntity requires every primitive array; these are written empty.
_UNUSED_PRIMITIVES = ("arrows", "spheres", "cylinders", "lines", "triangles", "texts", "models")
SCENE_UPDATE_SCHEMA: dict = {
    "title": "foxglove.SceneUpdate",
    "description": "An update to the entities displayed in a 3D scene",
    "type": "object",
    "properties": {
        "deletions": {
            "type": "array",
            "description": "Scene entities to delete",
            "items": {
                "title": "foxglove.SceneEntityDeletion",
                "description": "Command to remove previously published entities",
                "type": "object",
                "properties": {
                    "timestamp": time_schema("Timestamp of the deletion. Only matching entities earlier than "
                                              "this timestamp will be deleted."),
                    "type": {"title": "foxglove.SceneEntityDeletionType",
                             "description": "Type of deletion action to perform",
                             "oneOf": [{"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}]},
                    "id": {"type": "string", "description": "Identifier which must match if `type` is `MATCHING_ID`."},
                },
                "required": ["timestamp", "type", "id"]}},
        "entities": {
            "type": "array",
            "description": "Scene entities to add or replace",
            "items": {
                "title": "foxglove.SceneEntity",
                "description": "A visual element in a 3D scene. An entity may be composed of multiple primitives "
                               "which all share the same frame of reference.",
                "type": "object",
                "properties": {
                    "timestamp": time_schema("Timestamp of the entity"),
                    "frame_id": {"type": "string", "description": "Frame of reference"},
                    "id": {"type": "string", "description": "Identifier for the entity"},
                    "lifetime": {"type": "object", "title": "duration",
                                 "description": "Length of time (relative to `timestamp`) after which the entity "
                                                "should be automatically removed. Zero: visible until replaced.",
                                 "properties": {"sec": {"type": "integer"},
                                                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
                                 "required": ["sec", "nsec"]},
                    "frame_locked": {"type": "boolean",
                                     "description": "Whether the entity follows the frame `frame_id` (true)"},
                    "metadata": {"type": "array", "description": "Additional user-provided metadata",
                                 "items": {"title": "foxglove.KeyValuePair", "type": "object",
                                           "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                                           "required": ["key", "value"]}},
                    "cubes": {"type": "array", "description": "Cube primitives", "items": _CUBE_SCHEMA},
                    **{kind: {"type": "array", "description": f"{kind.capitalize()} primitives (none written)",
                              "maxItems": 0, "items": {"type": "object", "properties": {}}}
                       for kind in _UNUSED_PRIMITIVES},
                },
                "required": ["timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata", "cubes",
                             *_UNUSED_PRIMITIVES],
            }},
    },
    "required": ["deletions", "entities"],
}


NATIVE_COLOR = {"r": 0.2, "g": 0.45, "b": 0.85, "a": 0.9}
MUJOCO_COLOR = {"r": 0.95, "g": 0.55, "b": 0.1, "a": 0.5}


def link_frame_names(model: Model, root: str) -> list[str]:
    """Frame names of every link, arm after arm: f"{root}/{arm.name}/l{i}" (joints stacked as q).

    Args:
        model: the Model.
        root: the frames' root name, "native" or "mujoco".

    Returns:
        list[str]: (n,) one name per link (joint), i counting from 0 in each arm.
    """
    return [f"{root}/{arm.name}/l{i}" for arm in model.arms for i in range(arm.n)]


def _transform(ns: int, child: str, p, quat_wxyz) -> dict:
    w, x, y, z = (float(v) for v in quat_wxyz)
    return {"timestamp": stamp(ns), "parent_frame_id": "world", "child_frame_id": child,
            "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "rotation": {"x": x, "y": y, "z": z, "w": w}}


def native_link_poses(model: Model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Link frame poses of the native model over samples (`coopsim.dynamics.kinematics.arm_frames`).

    Args:
        model: the Model.
        q: (N, n) rad or m, the stacked joint coordinates of N samples.

    Returns:
        tuple[np.ndarray, np.ndarray]: positions (N, n, 3) m of the link frames' origins (the joint
        origins) and orientations (N, n, 4) quaternions [w, x, y, z], world axes, joints stacked as q.
    """
    frames = [arm_frames(arm, q[:, sl]) for arm, sl in zip(model.arms, model.dof_slices)]
    return np.concatenate([p for p, _ in frames], axis=1), rots_to_quats(np.concatenate([R for _, R in frames], axis=1))


def _model_frames(model: Model, root: str, t, link_pos, link_quat, obj_pos, obj_quat) -> dict[int, list[dict]]:
    """Transforms of one model's links and object per sample, keyed by time in ns."""
    names = link_frame_names(model, root)
    out: dict[int, list[dict]] = {}
    for k, ns in enumerate(time_ns(t).tolist()):
        frames = [_transform(ns, n, p, q) for n, p, q in zip(names, link_pos[k], link_quat[k])]
        frames.append(_transform(ns, f"{root}/object", obj_pos[k], obj_quat[k]))
        out.setdefault(ns, []).extend(frames)
    return out


def frame_transforms(model: Model, native=None, twin=None, topic: str = "/tf") -> JsonTopic:
    """foxglove.FrameTransforms on `topic`: every link and object frame of each model given, per sample.

    The frames are children of "world": "native/…" frames come from the link frames of the native q,
    "mujoco/…" from the twin's link poses; the object frames from each result's object pose (centre of
    mass C). Samples at the same time (to the ns) share one message.

    Args:
        model: the Model.
        native: the native SimResult, or None.
        twin: the MuJoCo TwinResult, or None.
        topic: the topic name.

    Returns:
        JsonTopic: one message {"transforms": [...]} per distinct sample time, times (M,) s ascending.
    """
    by_time: dict[int, list[dict]] = {}
    if native is not None:
        pos, quat = native_link_poses(model, native.q)
        for ns, fr in _model_frames(model, "native", native.t, pos, quat, native.object_pos,
                                    native.object_quat).items():
            by_time.setdefault(ns, []).extend(fr)
    if twin is not None:
        for ns, fr in _model_frames(model, "mujoco", twin.t, twin.link_pos, twin.link_quat, twin.object_pos,
                                    twin.object_quat).items():
            by_time.setdefault(ns, []).extend(fr)
    times = sorted(by_time)
    return JsonTopic(topic, "foxglove.FrameTransforms", FRAME_TRANSFORMS_SCHEMA,
                     np.array(times, dtype=np.float64) * 1e-9, tuple({"transforms": by_time[ns]} for ns in times))


def _cube_entity(frame: str, center, size, color: dict, quat_wxyz=(1.0, 0.0, 0.0, 0.0)) -> dict:
    v3 = lambda v: {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}  # noqa: E731
    w, x, y, z = (float(v) for v in quat_wxyz)
    return {"timestamp": stamp(0), "frame_id": frame, "id": frame, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": True, "metadata": [],
            "cubes": [{"pose": {"position": v3(center), "orientation": {"x": x, "y": y, "z": z, "w": w}},
                       "size": v3(size), "color": dict(color)}],
            **{kind: [] for kind in _UNUSED_PRIMITIVES}}


def _model_entities(model: Model, root: str, color: dict) -> list[dict]:
    out = []
    names = iter(link_frame_names(model, root))
    for arm in model.arms:
        for i in range(arm.n):
            name = next(names)
            if np.any(arm.link_box[i] > 0):
                out.append(_cube_entity(name, arm.box_pos[i], arm.link_box[i], color, rot_to_quat(arm.box_rot[i])))
    if np.any(model.object.box > 0):
        out.append(_cube_entity(f"{root}/object", np.zeros(3), model.object.box, color))
    return out


def scene_update(model: Model, native: bool, twin: bool, topic: str = "/scene") -> JsonTopic:
    """foxglove.SceneUpdate on `topic`, once at t = 0: a cube per link and one for the object.

    Each cube is locked to its frame. A link's cube is ArmModel.link_box (m) centred at box_pos, axes
    box_rot, in the link frame; the object's is ObjectModel.box centred at the object frame's origin;
    links and objects without a box (all sizes 0) get none. Lifetime 0 (forever); native in blue,
    mujoco in translucent orange.

    Args:
        model: the Model.
        native: draw the native model's cubes (frames "native/…").
        twin: draw the twin's cubes (frames "mujoco/…").
        topic: the topic name.

    Returns:
        JsonTopic: one message {"deletions": [], "entities": [...]} at t = 0.
    """
    entities = (_model_entities(model, "native", NATIVE_COLOR) if native else []) + \
               (_model_entities(model, "mujoco", MUJOCO_COLOR) if twin else [])
    return JsonTopic(topic, "foxglove.SceneUpdate", SCENE_UPDATE_SCHEMA, np.zeros(1),
                     ({"deletions": [], "entities": entities},))
