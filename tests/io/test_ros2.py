"""A run as a ROS 2 bag (`coopsim/io/ros2.py`, `coopsim run --ros2`, `coopsim export-ros2`).

Independent checks: the bag folder is opened by rosbags (an independent rosbag2 reader, with its own ROS 2
type store) and every message deserialised by it; the MCAP file is read by the mcap library's own reader
and each message decoded again with mcap-ros2-support's decoder built from the schema in the file alone
(so each schema holds its full definition); each schema's sections parse (rosbags' .msg parser) into the
fields of rosbags' ROS 2 Humble definitions of that type and its dependencies, and each channel's
`topic_type_hash` is rosbags' RIHS01 hash of the type. Joint positions equal the log's float64 bit for bit;
at every /tf sample every URDF link of each model is reachable from `world`, and composing the TF chain
gives coopsim's link frames to 1e-12. A short run of the paper scene (0.2 s).
"""

from __future__ import annotations

import io
import json
import shutil
from collections import deque

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from coopsim.core.labels import joint_labels
from coopsim.core.spatial import quat_to_rot
from coopsim.io.atomic import previous_set
from coopsim.io.foxglove import native_link_poses
from coopsim.io.log import read_run_log, run_log
from coopsim.io.mcap_codec import log_data, read_mcap
from coopsim.io.ros2 import VERDICT_RECORD, bag_files, export_bag
from coopsim.io.ros2_msgs import DEFINITIONS, TYPE_HASHES
from coopsim.io.urdf import OBJECT_LINK, ROOT, arm_links, urdf_text
from coopsim.twin.harness import cross_validate
from helpers import ROOT as REPO, SCENARIOS, run_cli

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
LATCHED = {"/tf_static", "/robot_description"}


@pytest.fixture(scope="module")
def run(paper):
    cv = cross_validate(paper, duration=0.2)
    streams, meta = run_log(paper, cv.native, cv.twin, metadata_extra={VERDICT_RECORD: {
        "passed": cv.comparison.passed, "failures": cv.comparison.failures(),
        "metrics": cv.comparison.as_dict()["metrics"]}})
    return paper, log_data(streams, meta, messages=False)


@pytest.fixture(scope="module")
def bag(run, tmp_path_factory):
    model, log = run
    return export_bag(tmp_path_factory.mktemp("bags") / "paper_bag", model, log)


def _messages(bag):
    """(connection, time ns, message) of every message, deserialised by rosbags."""
    with Reader(bag) as reader:
        return list(reader.connections), [(c, t, TYPESTORE.deserialize_cdr(raw, c.msgtype))
                                          for c, t, raw in reader.messages()]


def test_rosbags_reads_every_topic_type_qos_and_message(run, bag):
    model, log = run
    connections, msgs = _messages(bag)
    tokens = [links.base.split("/")[0] for links in arm_links(model)]
    expected = {"/robot_description": "std_msgs/msg/String", "/tf_static": "tf2_msgs/msg/TFMessage",
                "/tf": "tf2_msgs/msg/TFMessage", "/clock": "rosgraph_msgs/msg/Clock",
                "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
    for p in ("native", "mujoco"):
        expected |= {f"/{p}/{a}/joint_states": "sensor_msgs/msg/JointState" for a in tokens}
        expected |= {f"/{p}/object/pose": "geometry_msgs/msg/PoseStamped",
                     f"/{p}/object/twist": "geometry_msgs/msg/TwistStamped"}
    expected |= {f"/native/{a}/{w}": "geometry_msgs/msg/WrenchStamped" for a in tokens
                 for w in ("grasp_wrench", "internal_wrench")}
    assert {c.topic: c.msgtype for c in connections} == expected
    for c in connections:
        (qos,) = c.ext.offered_qos_profiles
        assert qos.durability.name == ("TRANSIENT_LOCAL" if c.topic in LATCHED else "VOLATILE"), c.topic
        assert qos.reliability.name == "RELIABLE" and qos.history.name == "KEEP_LAST", c.topic
    assert len(msgs) == sum(c.msgcount for c in connections) > 0
    n = len(log.topics["/native/joint_state"]["t"])
    counts = {c.topic: c.msgcount for c in connections}
    assert counts["/tf"] == counts["/clock"] == counts["/native/arm1/joint_states"] == n
    by_topic = {}
    for c, t, m in msgs:
        by_topic.setdefault(c.topic, []).append((t, m))
    assert by_topic["/robot_description"][0][1].data == urdf_text(model)
    (t_end, diag), = by_topic["/diagnostics"]
    assert t_end == by_topic["/clock"][-1][0] == round(0.2e9) and diag.status[0].level == 0, diag.status[0].message
    assert diag.status[0].name == "coopsim/validation" and len(diag.status[0].values) == 7


def test_joint_states_are_the_logs_values_to_the_last_bit(run, bag):
    model, log = run
    _, msgs = _messages(bag)
    labels = joint_labels(model)
    for p in ("native", "mujoco"):
        js = log.topics[f"/{p}/joint_state"]
        for links, sl in zip(arm_links(model), model.dof_slices):
            got = [(t, m) for c, t, m in msgs if c.topic == f"/{p}/{links.base.split('/')[0]}/joint_states"]
            assert [t for t, _ in got] == [round(x * 1e9) for x in js["t"]]
            assert all(list(m.name) == labels[sl] for _, m in got)
            for field, key in (("position", "angle"), ("velocity", "rate"), ("effort", "torque")):
                x = np.array([getattr(m, field) for _, m in got])
                assert np.array_equal(x.view(np.uint64), js[key][:, sl].view(np.uint64)), f"{p} {field}"
            stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in got]
            assert stamps == [t for t, _ in got]


def _world_poses(transforms):
    """Frame → (p, R) in `world`, composing parent → child transforms from world outwards (BFS)."""
    children = {}
    for tr in transforms:
        children.setdefault(tr.header.frame_id, []).append(tr)
    poses, todo = {ROOT: (np.zeros(3), np.eye(3))}, deque([ROOT])
    while todo:
        parent = todo.popleft()
        p0, R0 = poses[parent]
        for tr in children.get(parent, []):
            t, q = tr.transform.translation, tr.transform.rotation
            poses[tr.child_frame_id] = (p0 + R0 @ [t.x, t.y, t.z], R0 @ quat_to_rot([q.w, q.x, q.y, q.z]))
            todo.append(tr.child_frame_id)
    return poses


def test_tf_tree_is_complete_at_every_sample_and_gives_the_link_frames(run, bag):
    model, log = run
    _, msgs = _messages(bag)
    (static,) = [m for c, _, m in msgs if c.topic == "/tf_static"]
    links = [ROOT, OBJECT_LINK] + [n for a in arm_links(model) for n in (a.base, *a.links, a.ee)]
    native_p, native_R = native_link_poses(model, log.topics["/native/joint_state"]["angle"])
    samples = [m for c, _, m in msgs if c.topic == "/tf"]
    assert len(samples) == len(native_p)
    worst = 0.0
    for k, m in enumerate(samples):
        poses = _world_poses(list(static.transforms) + list(m.transforms))
        missing = [f"{p}/{n}" for p in ("native", "mujoco") for n in links if f"{p}/{n}" not in poses]
        assert not missing, f"/tf sample {k}: not reachable from world: {missing}"
        names = [f"native/{n}" for a in arm_links(model) for n in a.links]
        for j, name in enumerate(names):
            p, R = poses[name]
            worst = max(worst, np.max(np.abs(p - native_p[k, j])), np.max(np.abs(R - quat_to_rot(native_R[k, j]))))
        obj = log.topics["/native/object"]
        worst = max(worst, np.max(np.abs(poses["native/object"][0] - obj["position"][k])))
    assert worst <= 1e-12, f"TF-composed link frames off coopsim's by {worst:.2g}"


def _sections(text: str) -> dict[str, str]:
    """A ros2msg schema's sections: 'pkg/msg/Type' → its .msg text (the first one under `None`)."""
    parts = text.split("=" * 80 + "\n")
    out = {None: parts[0]}
    for part in parts[1:]:
        head, _, body = part.partition("\n")
        assert head.startswith("MSG: "), head
        name = head[5:].strip()
        out[name.replace("/", "/msg/", 1)] = body
    return out


def _closure(type_name: str) -> set[str]:
    out, todo = set(), [type_name]
    while todo:
        for _, (kind, sub) in TYPESTORE.fielddefs[todo.pop()][1]:
            inner = sub[0] if kind.name in ("ARRAY", "SEQUENCE") else (kind, sub)
            if inner[0].name == "NAME" and inner[1] not in out:
                out.add(inner[1])
                todo.append(inner[1])
    return out


def test_mcap_file_follows_the_ros2_profile_with_full_schemas(run, bag):
    model, log = run
    (mcap_file,) = bag.glob("*.mcap")
    reader = make_reader(io.BytesIO(mcap_file.read_bytes()), decoder_factories=[DecoderFactory()])
    assert reader.get_header().profile == "ros2"
    summary = reader.get_summary()
    meta_yaml = (bag / "metadata.yaml").read_text(encoding="utf-8")
    for ch in summary.channels.values():
        schema = summary.schemas[ch.schema_id]
        assert ch.message_encoding == "cdr" and schema.encoding == "ros2msg", ch.topic
        assert set(ch.metadata) == {"offered_qos_profiles", "topic_type_hash"}, ch.topic
        assert parse_qos(ch.metadata["offered_qos_profiles"]), ch.topic
        assert ch.metadata["topic_type_hash"] == TYPESTORE.hash_rihs01(schema.name), ch.topic
        assert ch.metadata["topic_type_hash"] in meta_yaml
        sections = _sections(schema.data.decode("utf-8"))
        assert set(sections) - {None} == _closure(schema.name), f"{schema.name}: dependencies"
        for name, text in sections.items():
            name = name or schema.name
            (consts, fields), = get_types_from_msg(text, name).values()
            assert [f for f, _ in fields] == [f for f, _ in TYPESTORE.fielddefs[name][1]], name
            assert get_types_from_msg(text, name)[name] == TYPESTORE.fielddefs[name], name
    decoded = sum(1 for _ in reader.iter_decoded_messages())
    assert decoded == summary.statistics.message_count
    assert set(TYPE_HASHES) == {s.name for s in summary.schemas.values()}
    assert {k.replace("/", "/msg/", 1) for k in DEFINITIONS} <= set(TYPESTORE.fielddefs)


def test_bag_is_deterministic_and_carries_warnings(run):
    model, log = run
    files = bag_files(model, log, "b")
    assert files == bag_files(model, log, "b")
    warning = {"kind": "singularity", "t_s": 0.1234, "q_rad": [0.0] * model.n_total, "reason": "an elbow is straight",
               "values": {"sigma_ratio": 1e-4}}
    meta = dict(log.metadata) | {"native.warnings": {"count": "1", "1": json.dumps(warning)}}
    warned = type(log)(meta, log.topics, log.schemas)
    mcap_file = bag_files(model, warned, "b")["b_0.mcap"]
    reader = make_reader(io.BytesIO(mcap_file), decoder_factories=[DecoderFactory()])
    diag = [(m.log_time, d) for _, _, m, d in reader.iter_decoded_messages(topics=["/diagnostics"])]
    assert [t for t, _ in diag] == [123_400_000, 200_000_000]
    status = diag[0][1].status[0]
    assert (status.level, status.name, status.message) == (1, "coopsim/native/singularity", "an elbow is straight")
    assert {v.key: v.value for v in status.values}["sigma_ratio"] == "0.0001"


def test_a_log_without_a_verdict_converts_with_a_stale_status(paper):
    """A log written before runs recorded their verdict (tests/data/logs/paper_planar_2x3_v1.mcap)."""
    log = read_run_log(REPO / "tests" / "data" / "logs" / "paper_planar_2x3_v1.mcap")
    reader = make_reader(io.BytesIO(bag_files(paper, log, "v1")["v1_0.mcap"]), decoder_factories=[DecoderFactory()])
    (diag,) = [d for _, _, _, d in reader.iter_decoded_messages(topics=["/diagnostics"])]
    assert (diag.status[0].level, diag.status[0].message) == (3, "the log holds no validation verdict")


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """`coopsim run --ros2` of the paper scene (0.05 s) with an aluminium bar (`--set`) in a folder of its own:
    (folder, output folder)."""
    work = tmp_path_factory.mktemp("cli")
    shutil.copytree(SCENARIOS, work / "scenarios")
    res = run_cli("run", "scenarios/paper_planar_2x3.yaml", "--duration", "0.05", "--ros2",
                  "--set", "object.box.density=2700", cwd=work)
    assert res.returncode == 0, res.stderr
    return work, work / "out" / "paper_planar_2x3"


def test_run_ros2_and_export_ros2_write_the_same_bag(cli_run):
    work, out = cli_run
    bag = out / "paper_planar_2x3_ros2"
    assert json.loads((out / "summary.json").read_text())["files"]["ros2"] == "out/paper_planar_2x3/paper_planar_2x3_ros2"
    assert bag.name in previous_set("summary.json")(out), "a later run would leave this run's bag behind"
    log = out / "paper_planar_2x3.mcap"
    assert read_mcap(log).metadata[VERDICT_RECORD]["passed"] == "true"
    (work / "exported").mkdir()
    (work / "exported" / "notes.txt").write_text("mine")
    res = run_cli("export-ros2", log, work / "exported" / bag.name, cwd=work)
    assert res.returncode == 0, res.stderr
    assert sorted(f.name for f in bag.iterdir()) == ["metadata.yaml", "paper_planar_2x3_ros2_0.mcap"]
    for f in bag.iterdir():
        assert (work / "exported" / bag.name / f.name).read_bytes() == f.read_bytes(), f.name
    assert (work / "exported" / "notes.txt").read_text() == "mine"
    mass = 2700 * 0.4 * 0.06 * 0.1    # the run's --set, recorded in the log and applied again by export-ros2
    reader = make_reader(io.BytesIO((bag / "paper_planar_2x3_ros2_0.mcap").read_bytes()),
                         decoder_factories=[DecoderFactory()])
    (urdf,) = [d.data for _, _, _, d in reader.iter_decoded_messages(topics=["/robot_description"])]
    assert f'<mass value="{mass!r}"/>' in urdf


def test_export_ros2_refuses_with_one_line_and_writes_nothing(cli_run, tmp_path):
    work, out = cli_run
    shutil.copytree(work / "scenarios", tmp_path / "scenarios")
    shutil.copy(out / "paper_planar_2x3.mcap", tmp_path / "log.mcap")
    (tmp_path / "scenarios" / "paper_planar_2x3.yaml").write_text(
        (SCENARIOS / "paper_planar_2x3.yaml").read_text() + "\n# edited\n")
    cases = [(["scenarios/spatial_6r_pair.yaml", "b1"], "not a readable MCAP log"),
             (["missing.mcap", "b2"], "log file not found"),
             (["log.mcap", "b3"], "changed since"),
             (["log.mcap", "b4", "--scenario", "scenarios/spatial_6r_pair.yaml"], "/native/joint_state.angle")]
    for args, reason in cases:
        res = run_cli("export-ros2", *args, cwd=tmp_path)
        assert res.returncode == 2 and res.stderr.count("\n") == 1 and reason in res.stderr, (args, res.stderr)
        assert not (tmp_path / args[1]).exists()
