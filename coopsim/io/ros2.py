"""A run as a ROS 2 bag: a rosbag2 folder (`metadata.yaml` and one MCAP file of CDR messages) that
`ros2 bag play`, RViz, Foxglove and rosbags read without coopsim (`coopsim run --ros2`, `coopsim
export-ros2`).

Built from a run log as `coopsim.io.mcap_codec` reads it (`LogData`) and the scene's `Model` (its URDF and
its kinematics), per model `{P}` = native, mujoco (whichever the log holds), `{arm}` an arm's ROS token
(`coopsim.core.labels.ros_arm_names`), frames named `{P}/` + the URDF's link (`coopsim.io.urdf`):

- `/{P}/{arm}/joint_states` (sensor_msgs/msg/JointState): the arm's joints by their labels; position,
  velocity, effort = the log's angle, rate, torque (rad, rad/s, N·m; m, m/s, N on a prismatic joint),
  the very float64 values;
- `/tf` (tf2_msgs/msg/TFMessage), one message per sample time: each link in its parent link at the logged
  joint coordinates (the URDF's joints: `{P}/{arm}/base` → `{P}/{arm}/link1` → …), and the object frame
  (centre of mass C) in `{P}/world` at its logged pose; `/tf_static` (transient local), once: `world` →
  `{P}/world` (identity), `{P}/world` → each base, each last link → its end effector. Every URDF link of
  each model is reachable from `world` at every sample, so RViz's RobotModel draws the URDF with the TF
  prefix `{P}`;
- `/{P}/object/pose` and `/{P}/object/twist` (geometry_msgs/msg/PoseStamped, TwistStamped, frame `world`):
  the object's C and orientation, its twist [v_C; ω] in world axes;
- `/native/{arm}/grasp_wrench` (geometry_msgs/msg/WrenchStamped, frame `native/{arm}/ee`: force and moment
  about the end effector's origin, in its axes) and `/native/{arm}/internal_wrench` (frame
  `native/object`: about C, object axes), rotated from the log's world axes;
- `/robot_description` (std_msgs/msg/String, transient local), once: the scene's URDF;
- `/diagnostics` (diagnostic_msgs/msg/DiagnosticArray): each warning of the native run at its time
  (WARN), and the validation verdict at the last sample (OK / ERROR; STALE when the log holds none);
- `/clock` (rosgraph_msgs/msg/Clock): each sample time, for nodes with use_sim_time.

Timestamps (log time, publish time, header stamps) are simulation time from 0, in ns. Each channel has
the MCAP ROS 2 profile's metadata: `offered_qos_profiles` (YAML, rosbag2's form) and `topic_type_hash`
(RIHS01); each schema is `ros2msg` with its dependencies (`coopsim.io.ros2_msgs`); `metadata.yaml` is
rosbag2's version 8 (read by Humble and later). The bytes depend only on the log and the model.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from mcap.writer import CompressionType, Writer
from mcap_ros2._dynamic import serialize_dynamic

from coopsim.core.errors import CoopsimError
from coopsim.core.joints import joint_transforms
from coopsim.core.labels import joint_labels, ros_arm_names
from coopsim.core.model import Model
from coopsim.core.spatial import quat_to_rot, rots_to_quats
from coopsim.dynamics.kinematics import arm_frames
from coopsim.io.atomic import staged_folder
from coopsim.io.mcap_codec import LogData, UnreadableLogError, time_ns
from coopsim.io.ros2_msgs import TYPE_HASHES, schema_text
from coopsim.io.urdf import OBJECT_LINK, ROOT, arm_links, urdf_text

LIBRARY = "coopsim.ros2"
METADATA_FILE = "metadata.yaml"
BAG_VERSION = 8
MODELS = ("native", "mujoco")
VERDICT_RECORD = "validation.verdict"      # the run log's metadata record of the validation verdict
OK, WARN, ERROR, STALE = 0, 1, 2, 3        # diagnostic_msgs/DiagnosticStatus levels


def _qos(depth: int, latched: bool = False) -> str:
    """offered_qos_profiles in rosbag2's YAML form: keep last `depth`, reliable, volatile or transient local."""
    def zero():
        return {"sec": 0, "nsec": 0}        # the rmw default (a fresh dict each: no YAML anchors)

    return yaml.safe_dump([{"history": 1, "depth": depth, "reliability": 1, "durability": 1 if latched else 2,
                            "deadline": zero(), "lifespan": zero(), "liveliness": 1,
                            "liveliness_lease_duration": zero(), "avoid_ros_namespace_conventions": False}],
                          sort_keys=False).strip()


@dataclass
class BagTopic:
    """One topic of a bag and its messages.

    Attributes:
        name: the topic name.
        type: the ROS 2 message type, 'pkg/msg/Type'.
        qos: offered_qos_profiles, rosbag2's YAML text.
        messages: (log time ns, message as a dict of its fields), in time order.
    """

    name: str
    type: str
    qos: str
    messages: list[tuple[int, dict]] = field(default_factory=list)


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _header(ns: int, frame: str) -> dict:
    return {"stamp": _stamp(ns), "frame_id": frame}


def _vec(v) -> dict:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _quat(q_wxyz) -> dict:
    return {"x": float(q_wxyz[1]), "y": float(q_wxyz[2]), "z": float(q_wxyz[3]), "w": float(q_wxyz[0])}


def _transform(ns: int, parent: str, child: str, p, q_wxyz) -> dict:
    return {"header": _header(ns, parent), "child_frame_id": child,
            "transform": {"translation": _vec(p), "rotation": _quat(q_wxyz)}}


def _series(log: LogData, topic: str, key: str, shape: tuple) -> np.ndarray:
    """A field of a series topic, checked to have `shape` per sample."""
    d = log.topics[topic]
    x = d.get(key)
    if x is None or x.shape != (len(d["t"]),) + shape or x.dtype.kind != "f":
        raise UnreadableLogError(f"{topic}.{key}: missing, or not {list(shape)} numbers per sample: the log is "
                                 f"not a run log of this scenario")
    return x


def _models(model: Model, log: LogData) -> list[str]:
    found = [p for p in MODELS if f"/{p}/joint_state" in log.topics]
    if not found:
        raise UnreadableLogError("no /native/joint_state or /mujoco/joint_state series: not a coopsim run log")
    for p in found:
        _series(log, f"/{p}/joint_state", "angle", (model.n_total,))
        if f"/{p}/object" not in log.topics:
            raise UnreadableLogError(f"no /{p}/object series: not a coopsim run log")
    return found


def _joint_states(model: Model, log: LogData, p: str) -> list[BagTopic]:
    topic = f"/{p}/joint_state"
    ns = time_ns(log.topics[topic]["t"]).tolist()
    cols = [_series(log, topic, k, (model.n_total,)) for k in ("angle", "rate", "torque")]
    labels = joint_labels(model)
    out = []
    for token, sl in zip(ros_arm_names([a.name for a in model.arms]), model.dof_slices):
        names = labels[sl]
        pos, vel, eff = (c[:, sl].tolist() for c in cols)
        out.append(BagTopic(f"/{p}/{token}/joint_states", "sensor_msgs/msg/JointState", _qos(10), [
            (n, {"header": _header(n, ""), "name": names, "position": a, "velocity": b, "effort": c})
            for n, a, b, c in zip(ns, pos, vel, eff)]))
    return out


def _link_transforms(model: Model, p: str, q: np.ndarray, ns: list[int]) -> list[list[dict]]:
    """Per sample, each link in its parent link at coordinates q (N, n): the URDF's moving joints."""
    per_sample: list[list[dict]] = [[] for _ in ns]
    for arm, links, sl in zip(model.arms, arm_links(model), model.dof_slices):
        parents = [links.base] + links.links[:-1]
        for i, (parent, child) in enumerate(zip(parents, links.links)):
            R_J, d_J = joint_transforms(arm.joint_type[i], arm.joint_axis[i], q[:, sl][:, i])
            pos = arm.joint_pos[i] + d_J @ arm.joint_rot[i].T
            quat = rots_to_quats(arm.joint_rot[i] @ R_J)
            for k, n in enumerate(ns):
                per_sample[k].append(_transform(n, f"{p}/{parent}", f"{p}/{child}", pos[k], quat[k]))
    return per_sample


def _tf(model: Model, log: LogData, models: list[str]) -> BagTopic:
    by_time: dict[int, list[dict]] = {}
    for p in models:
        js, obj = log.topics[f"/{p}/joint_state"], f"/{p}/object"
        ns = time_ns(js["t"]).tolist()
        frames = _link_transforms(model, p, js["angle"], ns)
        pos, quat = _series(log, obj, "position", (3,)), _series(log, obj, "quaternion", (4,))
        obj_ns = time_ns(log.topics[obj]["t"]).tolist()
        for n, fr in zip(ns, frames):
            by_time.setdefault(n, []).extend(fr)
        for k, n in enumerate(obj_ns):
            by_time.setdefault(n, []).append(_transform(n, f"{p}/{ROOT}", f"{p}/{OBJECT_LINK}", pos[k], quat[k]))
    return BagTopic("/tf", "tf2_msgs/msg/TFMessage", _qos(100),
                    [(n, {"transforms": by_time[n]}) for n in sorted(by_time)])


def _tf_static(model: Model, models: list[str]) -> BagTopic:
    identity = (1.0, 0.0, 0.0, 0.0)
    frames = []
    for p in models:
        frames.append(_transform(0, ROOT, f"{p}/{ROOT}", np.zeros(3), identity))
        for arm, links in zip(model.arms, arm_links(model)):
            frames.append(_transform(0, f"{p}/{ROOT}", f"{p}/{links.base}", arm.base_pos,
                                     rots_to_quats(arm.base_rot)))
            frames.append(_transform(0, f"{p}/{links.links[-1]}", f"{p}/{links.ee}", arm.ee_pos,
                                     rots_to_quats(arm.ee_rot)))
    return BagTopic("/tf_static", "tf2_msgs/msg/TFMessage", _qos(1, latched=True), [(0, {"transforms": frames})])


def _object(log: LogData, p: str) -> list[BagTopic]:
    topic = f"/{p}/object"
    ns = time_ns(log.topics[topic]["t"]).tolist()
    pos, quat = _series(log, topic, "position", (3,)), _series(log, topic, "quaternion", (4,))
    twist = _series(log, topic, "twist", (6,))
    return [BagTopic(f"{topic}/pose", "geometry_msgs/msg/PoseStamped", _qos(10), [
                (n, {"header": _header(n, ROOT), "pose": {"position": _vec(a), "orientation": _quat(b)}})
                for n, a, b in zip(ns, pos, quat)]),
            BagTopic(f"{topic}/twist", "geometry_msgs/msg/TwistStamped", _qos(10), [
                (n, {"header": _header(n, ROOT), "twist": {"linear": _vec(v[:3]), "angular": _vec(v[3:])}})
                for n, v in zip(ns, twist)])]


def _wrench_topic(name: str, frame: str, ns: list[int], R: np.ndarray, w: np.ndarray) -> BagTopic:
    """WrenchStamped of wrenches w (N, 6) [f; n] in world axes, given in the axes R (N, 3, 3) of `frame`."""
    f, m = np.einsum("kji,kj->ki", R, w[:, :3]), np.einsum("kji,kj->ki", R, w[:, 3:])
    return BagTopic(name, "geometry_msgs/msg/WrenchStamped", _qos(10), [
        (n, {"header": _header(n, frame), "wrench": {"force": _vec(a), "torque": _vec(b)}})
        for n, a, b in zip(ns, f, m)])


def _wrenches(model: Model, log: LogData) -> list[BagTopic]:
    if "/native/grasp_wrench" not in log.topics or "/native/internal_wrench" not in log.topics:
        return []
    js = log.topics["/native/joint_state"]
    ns = time_ns(js["t"]).tolist()
    R_o = np.array([quat_to_rot(q) for q in _series(log, "/native/object", "quaternion", (4,))])
    grasp = _series(log, "/native/grasp_wrench", "wrench", (model.r, 6))
    internal = _series(log, "/native/internal_wrench", "wrench", (model.r, 6))
    if not (len(grasp) == len(internal) == len(ns) == len(R_o)):
        raise UnreadableLogError("/native series of different lengths: not a coopsim run log")
    out = []
    for m, (arm, links, sl, token) in enumerate(zip(model.arms, arm_links(model), model.dof_slices,
                                                   ros_arm_names([a.name for a in model.arms]))):
        R_ee = arm_frames(arm, js["angle"][:, sl])[1][:, -1] @ arm.ee_rot
        out.append(_wrench_topic(f"/native/{token}/grasp_wrench", f"native/{links.ee}", ns, R_ee, grasp[:, m]))
        out.append(_wrench_topic(f"/native/{token}/internal_wrench", f"native/{OBJECT_LINK}", ns, R_o,
                                 internal[:, m]))
    return out


def _status(level: int, name: str, message: str, hardware_id: str, values: dict) -> dict:
    return {"level": level, "name": name, "message": message, "hardware_id": hardware_id,
            "values": [{"key": str(k), "value": str(v)} for k, v in values.items()]}


def _diagnostics(model: Model, log: LogData, end_ns: int) -> BagTopic:
    """The native run's warnings at their times, and the validation verdict at end_ns."""
    msgs = []
    rec = log.metadata.get("native.warnings", {})
    for i in range(1, int(rec.get("count", "0")) + 1):
        w = json.loads(rec[str(i)])
        n = int(min(max(time_ns(np.array([w["t_s"]]))[0], 0), end_ns))
        values = {"t_s": repr(w["t_s"]), "q": json.dumps(w["q_rad"])} | {k: repr(v) for k, v in w["values"].items()}
        msgs.append((n, _status(WARN, f"coopsim/native/{w['kind']}", w["reason"], model.name, values)))
    verdict = log.metadata.get(VERDICT_RECORD)
    if verdict is None:
        status = _status(STALE, "coopsim/validation", "the log holds no validation verdict", model.name, {})
    else:
        passed, failures = json.loads(verdict["passed"]), json.loads(verdict["failures"])
        message = ("PASS: the MuJoCo twin agrees with the native model within the scenario's thresholds"
                   if passed else "FAIL: " + "; ".join(failures))
        metrics = json.loads(verdict["metrics"])
        values = {name: f"{m['max']!r} {m['unit']} (threshold {m['threshold']!r})" for name, m in metrics.items()}
        status = _status(OK if passed else ERROR, "coopsim/validation", message, model.name, values)
    msgs.append((end_ns, status))
    return BagTopic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", _qos(10), [
        (n, {"header": _header(n, ""), "status": [s]}) for n, s in msgs])


def bag_topics(model: Model, log: LogData) -> list[BagTopic]:
    """Every topic of a run's bag (module docstring), in the order they are written.

    Args:
        model: the scene's Model (the log's joint count).
        log: the run log (`coopsim.io.log.read_run_log`, or `coopsim.io.mcap_codec.log_data` of its streams).

    Returns:
        list[BagTopic]: /robot_description, /tf_static, then per model the joint states and the object's
        pose and twist, the native wrenches, /tf, /diagnostics and /clock.

    Raises:
        UnreadableLogError: the log lacks a series the bag needs, or one has the wrong shape (e.g. a log of
            another scenario).
    """
    models = _models(model, log)
    topics = [BagTopic("/robot_description", "std_msgs/msg/String", _qos(1, latched=True),
                       [(0, {"data": urdf_text(model)})]), _tf_static(model, models)]
    for p in models:
        topics += _joint_states(model, log, p) + _object(log, p)
    topics += _wrenches(model, log)
    tf = _tf(model, log, models)
    times = [n for n, _ in tf.messages]
    topics += [tf, _diagnostics(model, log, times[-1] if times else 0),
               BagTopic("/clock", "rosgraph_msgs/msg/Clock", _qos(10), [(n, {"clock": _stamp(n)}) for n in times])]
    return topics


def _bag_info(topics: list[BagTopic], file: str) -> dict:
    times = [n for t in topics for n, _ in t.messages]
    start, count = min(times, default=0), len(times)
    duration = max(times, default=0) - start
    return {
        "version": BAG_VERSION, "storage_identifier": "mcap", "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start}, "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.type, "serialization_format": "cdr",
                                "offered_qos_profiles": t.qos, "type_description_hash": TYPE_HASHES[t.type]},
             "message_count": len(t.messages)} for t in topics],
        "compression_format": "", "compression_mode": "", "relative_file_paths": [file],
        "files": [{"path": file, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": count}],
        "custom_data": {}, "ros_distro": "",
    }


def _mcap_bytes(topics: list[BagTopic], info_text: str, metadata: dict[str, dict[str, str]]) -> bytes:
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD, enable_data_crcs=True)
    writer.start(profile="ros2", library=LIBRARY)
    schemas, encoders, rows = {}, {}, []
    for k, t in enumerate(topics):
        if t.type not in schemas:
            text = schema_text(t.type)
            schemas[t.type] = writer.register_schema(t.type, "ros2msg", text.encode("utf-8"))
            encoders[t.type] = serialize_dynamic(t.type, text)[t.type]
        cid = writer.register_channel(t.name, "cdr", schemas[t.type],
                                      {"offered_qos_profiles": t.qos, "topic_type_hash": TYPE_HASHES[t.type]})
        rows += [(n, k, seq, cid, t.type, msg) for seq, (n, msg) in enumerate(t.messages)]
    for n, _, seq, cid, type_name, msg in sorted(rows, key=lambda r: r[:3]):
        writer.add_message(cid, log_time=n, data=encoders[type_name](msg), publish_time=n, sequence=seq)
    for name, record in metadata.items():
        writer.add_metadata(name, dict(record))
    writer.add_metadata("rosbag2", {"serialized_metadata": info_text})
    writer.finish()
    return out.getvalue()


def bag_files(model: Model, log: LogData, name: str) -> dict[str, bytes]:
    """The files of a run's rosbag2 folder named `name`: metadata.yaml and `{name}_0.mcap`.

    The MCAP file also carries the log's metadata records (scenario, versions, settings, warnings) and
    rosbag2's own record ("rosbag2": serialized_metadata).

    Args:
        model: the scene's Model.
        log: the run log.
        name: the folder's name (the MCAP file is named after it, as rosbag2 does).

    Returns:
        dict[str, bytes]: file name → its bytes, deterministic.

    Raises:
        UnreadableLogError: as `bag_topics`.
    """
    topics = bag_topics(model, log)
    file = f"{name}_0.mcap"
    info = _bag_info(topics, file)
    info_text = yaml.safe_dump(info, sort_keys=False)
    meta_text = yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)
    return {METADATA_FILE: meta_text.encode("utf-8"), file: _mcap_bytes(topics, info_text, log.metadata)}


def write_bag(folder: str | Path, model: Model, log: LogData) -> Path:
    """Write a run's rosbag2 folder's files (`bag_files`) into `folder`, created (with its parents) if missing.

    Not atomic by itself: `coopsim run --ros2` writes it inside its staged set, `export_bag` stages it.

    Args:
        folder: the bag folder.
        model: the scene's Model.
        log: the run log.

    Returns:
        Path: the folder.

    Raises:
        UnreadableLogError: as `bag_topics`.
    """
    folder = Path(folder)
    files = bag_files(model, log, folder.name)
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return folder


def export_bag(folder: str | Path, model: Model, log: LogData) -> Path:
    """Write a run's rosbag2 folder as one set (`coopsim.io.atomic.staged_folder`): the bag's two files
    replace a previous bag's there, any other file in the folder stays.

    Args:
        folder: the bag folder (its parent is created if missing).
        model: the scene's Model.
        log: the run log.

    Returns:
        Path: the folder.

    Raises:
        CoopsimError: `folder` is an existing file.
        UnreadableLogError: as `bag_topics`.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise CoopsimError(f"{folder}: exists and is not a folder (the bag is a folder)")
    files = bag_files(model, log, folder.name)
    with staged_folder(folder, replaces=lambda old: set(files)) as stage:
        for name, data in files.items():
            (stage / name).write_bytes(data)
    return folder
