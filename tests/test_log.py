"""MCAP run logs: bit-exact round trip, byte-identical rewrites, Foxglove schemas and frames, atomicity."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest
from mcap.reader import make_reader

from coopsim import log as L
from coopsim.closed_chain import arm_poses
from coopsim.mujoco_run import run_twin
from coopsim.simulate import simulate
from coopsim.spatial import quat_to_rot

from conftest import SCENARIOS

SCENARIO_FILE = SCENARIOS / "paper_planar_2x3.yaml"


@pytest.fixture(scope="module")
def run(paper):
    model = dataclasses.replace(paper, duration=0.2)
    res = simulate(model)
    return model, res, run_twin(model, res.initial.q, res.initial.qd, res.t)


@pytest.fixture(scope="module")
def logged(run, tmp_path_factory):
    model, res, tw = run
    path = tmp_path_factory.mktemp("log") / "run.mcap"
    L.write_run_log(path, model, res, tw, metadata_extra={"scenario_file": SCENARIO_FILE, "note": "test"})
    return path, L.read_mcap(path)


# -- a JSON-Schema subset validator (type, properties, required, items, lengths, bounds, oneOf const) --

_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool}


def _validate(value, schema, where="$"):
    if "oneOf" in schema:
        assert any(value == alt["const"] for alt in schema["oneOf"]), where
        return
    kind = schema["type"]
    if kind in ("number", "integer"):
        assert isinstance(value, (int, float)) and not isinstance(value, bool), f"{where}: {value!r}"
        if kind == "integer":
            assert isinstance(value, int), where
        assert value >= schema.get("minimum", -np.inf) and value <= schema.get("maximum", np.inf), where
        return
    assert isinstance(value, _TYPES[kind]), f"{where}: expected {kind}, got {type(value).__name__}"
    if kind == "object":
        for key in schema.get("required", []):
            assert key in value, f"{where}: missing {key}"
        for key, sub in schema.get("properties", {}).items():
            if key in value:
                _validate(value[key], sub, f"{where}.{key}")
    elif kind == "array":
        assert schema.get("minItems", 0) <= len(value) <= schema.get("maxItems", np.inf), where
        for i, item in enumerate(value):
            _validate(item, schema["items"], f"{where}[{i}]")


def _file_schemas(path):
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return {s.name: json.loads(s.data) for s in summary.schemas.values()}


# -- round trip -----------------------------------------------------------------------------------

def test_round_trip_is_bit_identical_for_both_models(run, logged):
    model, res, tw = run
    _, data = logged
    series = L.simulation_series(res) + L.twin_series(tw)
    assert {s.topic for s in series} == set(data.topics)
    for s in series:
        got = data.topics[s.topic]
        assert data.schemas[s.topic] == s.schema_name
        assert set(got) == set(s.fields) | {"t"}
        assert got["t"].dtype == np.float64 and np.array_equal(got["t"], s.t), s.topic
        for name, a in s.fields.items():
            assert got[name].dtype == a.dtype and got[name].shape == a.shape, (s.topic, name)
            assert np.array_equal(got[name], a), (s.topic, name)
    assert data.topics["/native/grasp_wrench"]["wrench"].shape == (len(res.t), model.r, 6)


def test_rewrite_gives_byte_identical_file(run, logged, tmp_path):
    model, res, tw = run
    path, _ = logged
    again = L.write_run_log(tmp_path / "again.mcap", model, res, tw,
                            metadata_extra={"scenario_file": SCENARIO_FILE, "note": "test"})
    assert again.read_bytes() == path.read_bytes()


def test_generic_series_edge_cases_round_trip(tmp_path):
    t = np.array([0.0, 0.1, 0.30000000000000004])
    f = np.array([[np.nan, np.inf], [-np.inf, -0.0], [5e-324, 1.7976931348623157e308]])
    s = L.Series("/x", "test.X", t, {"f": f, "i": np.array([-3, 0, 2**60]), "b": np.array([True, False, True]),
                                      "cube": np.arange(24.0).reshape(3, 2, 2, 2) / 7})
    empty = L.Series("/empty", "test.E", np.zeros(0), {"v": np.zeros((0, 3))})
    data = L.read_mcap(L.write_mcap(tmp_path / "x.mcap", [s, empty], {"rec": {"k": "v"}}))
    got = data.topics["/x"]
    assert np.array_equal(got["f"], f, equal_nan=True) and np.signbit(got["f"][1, 1])
    assert got["i"].dtype == np.int64 and np.array_equal(got["i"], s.fields["i"])
    assert got["b"].dtype == np.bool_ and np.array_equal(got["b"], s.fields["b"])
    assert np.array_equal(got["cube"], s.fields["cube"]) and np.array_equal(got["t"], t)
    assert data.topics["/empty"]["v"].shape == (0, 3) and data.metadata == {"rec": {"k": "v"}}
    with open(tmp_path / "x.mcap", "rb") as fh:
        first = json.loads(next(make_reader(fh).iter_messages())[2].data)
    assert first["f"] == ["NaN", "Infinity"] and first["timestamp"] == {"sec": 0, "nsec": 0}
    assert first["cube"][1] == {"row": [{"row": [4 / 7, 5 / 7]}, {"row": [6 / 7, 1.0]}]}


def test_messages_are_ordered_by_time_then_series(tmp_path):
    a = L.Series("/a", "test.S", np.array([0.0, 0.2]), {"v": np.array([1.0, 2.0])})
    b = L.Series("/b", "test.S", np.array([0.0, 0.1, 0.2]), {"v": np.array([3.0, 4.0, 5.0])})
    L.write_mcap(tmp_path / "o.mcap", [a, b])
    with open(tmp_path / "o.mcap", "rb") as fh:
        order = [(c.topic, m.log_time, m.publish_time) for _, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    assert order == [("/a", 0, 0), ("/b", 0, 0), ("/b", 100_000_000, 100_000_000), ("/a", 200_000_000, 200_000_000),
                     ("/b", 200_000_000, 200_000_000)]


def test_series_schema_describes_fixed_shapes(run):
    _, res, _ = run
    schema = L.series_schema(L.simulation_series(res)[2])
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    w = schema["properties"]["wrench"]
    assert (w["minItems"], w["maxItems"]) == (2, 2)
    row = w["items"]["properties"]["row"]
    assert (row["minItems"], row["maxItems"], row["items"]) == (6, 6, {"type": "number"})


def test_inconsistent_schema_names_are_refused(tmp_path):
    a = L.Series("/a", "test.S", np.zeros(1), {"v": np.zeros(1)})
    b = L.Series("/b", "test.S", np.zeros(1), {"v": np.zeros((1, 2))})
    with pytest.raises(L.LogError, match="/b: schema 'test.S' differs"):
        L.write_mcap(tmp_path / "s.mcap", [a, b])
    with pytest.raises(L.LogError, match="/a: field name 't' is reserved"):
        L.write_mcap(tmp_path / "s.mcap", [L.Series("/a", "test.T", np.zeros(1), {"t": np.zeros(1)})])
    assert list(tmp_path.iterdir()) == []


# -- Foxglove view --------------------------------------------------------------------------------

def test_foxglove_schemas_and_frames_of_every_link(run, logged):
    model, res, tw = run
    path, data = logged
    assert data.schemas["/tf"] == "foxglove.FrameTransforms" and data.schemas["/scene"] == "foxglove.SceneUpdate"
    schemas = _file_schemas(path)
    assert schemas["foxglove.FrameTransforms"] == L.FRAME_TRANSFORMS_SCHEMA
    item = schemas["foxglove.FrameTransforms"]["properties"]["transforms"]["items"]["properties"]
    assert set(item) == {"timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"}
    assert set(item["rotation"]["properties"]) == set("xyzw")

    expected = {f"{root}/{arm.name}/l{i}" for root in ("native", "mujoco") for arm in model.arms
                for i in range(arm.n)} | {"native/object", "mujoco/object"}
    assert len(expected) == 2 * (model.n_total + 1)
    tf = data.messages["/tf"]
    assert len(tf) == len(res.t)
    for k, msg in enumerate(tf):
        _validate(msg, schemas["foxglove.FrameTransforms"])
        assert {f["child_frame_id"] for f in msg["transforms"]} == expected
        assert {f["parent_frame_id"] for f in msg["transforms"]} == {"world"}
        ns = int(round(res.t[k] * 1e9))
        assert {(f["timestamp"]["sec"] * 10**9 + f["timestamp"]["nsec"]) for f in msg["transforms"]} == {ns}


def test_frames_place_links_where_both_models_put_them(run, logged):
    model, res, tw = run
    _, data = logged
    k = len(res.t) - 1
    frames = {f["child_frame_id"]: f for f in data.messages["/tf"][k]["transforms"]}
    native = [p for pose in arm_poses(model, res.q[k]) for p in zip(pose.p, pose.R)]
    names = L.link_frame_names(model, "native")
    for j, (name, (p, R)) in enumerate(zip(names, native)):
        nat, muj = frames[name], frames[name.replace("native/", "mujoco/", 1)]
        xyz = lambda d: np.array([d["x"], d["y"], d["z"]])  # noqa: E731
        wxyz = lambda d: np.array([d["w"], d["x"], d["y"], d["z"]])  # noqa: E731
        assert np.array_equal(xyz(nat["translation"]), p)
        np.testing.assert_allclose(quat_to_rot(wxyz(nat["rotation"])), R, atol=1e-15)
        np.testing.assert_array_equal(xyz(muj["translation"]), tw.link_pos[k, j])
        # the two models agree on where each link frame is (same frame convention)
        np.testing.assert_allclose(xyz(muj["translation"]), p, atol=1e-7)
        np.testing.assert_allclose(quat_to_rot(wxyz(muj["rotation"])), R, atol=1e-7)
    np.testing.assert_allclose(xyz(frames["mujoco/object"]["translation"]), res.object_pos[k], atol=1e-7)


def test_scene_draws_a_box_per_link_and_object_forever(run, logged):
    model, _, _ = run
    path, data = logged
    scene = data.messages["/scene"]
    assert len(scene) == 1
    _validate(scene[0], _file_schemas(path)["foxglove.SceneUpdate"])
    entities = {e["id"]: e for e in scene[0]["entities"]}
    frames = {f["child_frame_id"] for f in data.messages["/tf"][0]["transforms"]}
    assert set(entities) == frames
    colors = set()
    for e in entities.values():
        assert e["frame_id"] == e["id"] and e["lifetime"] == {"sec": 0, "nsec": 0} and e["frame_locked"]
        assert e["timestamp"] == {"sec": 0, "nsec": 0} and len(e["cubes"]) == 1
        colors.add((e["id"].split("/")[0], tuple(e["cubes"][0]["color"].values())))
    assert len(colors) == 2
    cube = entities["mujoco/arm1/l1"]["cubes"][0]
    assert [cube["size"][c] for c in "xyz"] == model.arms[0].link_box[1].tolist()
    assert [cube["pose"]["position"][c] for c in "xyz"] == model.arms[0].link_com[1].tolist()
    assert [entities["native/object"]["cubes"][0]["size"][c] for c in "xyz"] == model.object.box.tolist()
    with open(path, "rb") as fh:
        stamps = [m.log_time for _, c, m in make_reader(fh).iter_messages(topics=["/scene"])]
    assert stamps == [0]


def test_frame_transforms_validate_with_jsonschema(logged):
    jsonschema = pytest.importorskip("jsonschema")
    path, data = logged
    schemas = _file_schemas(path)
    jsonschema.Draft202012Validator(schemas["foxglove.FrameTransforms"]).validate(data.messages["/tf"][0])
    jsonschema.Draft202012Validator(schemas["foxglove.SceneUpdate"]).validate(data.messages["/scene"][0])
    with open(path, "rb") as fh:
        _, _, msg = next(make_reader(fh).iter_messages(topics=["/native/grasp_wrench"]))
    jsonschema.Draft202012Validator(schemas["coopsim.Wrenches"]).validate(json.loads(msg.data))


# -- metadata -------------------------------------------------------------------------------------

def test_metadata_records(run, logged):
    model, res, _ = run
    _, data = logged
    meta = data.metadata
    assert meta["scenario"] == {"name": model.name, "file": str(SCENARIO_FILE),
                                "sha256": hashlib.sha256(SCENARIO_FILE.read_bytes()).hexdigest()}
    assert set(meta["versions"]) >= {"coopsim", "mujoco", "numpy"}
    proj = meta["native.initial_projection"]
    assert np.array_equal(json.loads(proj["dq"]), res.initial.dq)
    assert float(proj["residual_before"]) == res.initial.residual_before
    assert float(proj["residual_after"]) == res.initial.residual_after
    assert meta["native.integrator"]["method"] == model.integrator.method
    assert float(meta["native.integrator"]["rtol"]) == model.integrator.rtol
    assert float(meta["mujoco"]["timestep"]) == model.mujoco.timestep
    assert json.loads(meta["model"]["dofs"]) == [a.n for a in model.arms]
    assert meta["extra"] == {"note": "test"}
    merged = L.run_metadata(model, None, {"scenario": {"file": "s.yaml", "sha256": "ab"}, "agreement": {"q": 1e-9}})
    assert merged["scenario"] == {"name": model.name, "file": "s.yaml", "sha256": "ab"}
    assert merged["agreement"] == {"q": "1e-09"} and "native.initial_projection" not in merged


# -- atomicity ------------------------------------------------------------------------------------

def test_failure_while_writing_leaves_no_file(run, tmp_path, monkeypatch):
    model, res, _ = run
    calls = []

    def failing(self, *args, **kwargs):
        calls.append(1)
        if len(calls) > 5:
            raise OSError("disk full (simulated)")
        return original(self, *args, **kwargs)

    original = L.Writer.add_message
    monkeypatch.setattr(L.Writer, "add_message", failing)
    target = tmp_path / "run.mcap"
    with pytest.raises(OSError, match="simulated"):
        L.write_run_log(target, model, res, None)
    assert list(tmp_path.iterdir()) == []

    target.write_bytes(b"old log")
    calls.clear()
    with pytest.raises(OSError, match="simulated"):
        L.write_run_log(target, model, res, None)
    assert list(tmp_path.iterdir()) == [target] and target.read_bytes() == b"old log"


def test_malformed_series_leaves_no_file(tmp_path):
    bad = L.Series("/bad", "test.B", np.array([0.0, 0.1]), {"v": np.zeros((3, 2))})
    with pytest.raises(L.LogError, match=r"/bad: field 'v' has shape \(3, 2\), expected \(2, \.\.\.\)"):
        L.write_mcap(tmp_path / "bad.mcap", [bad])
    with pytest.raises(L.LogError, match="/bad: t must be finite"):
        L.write_mcap(tmp_path / "bad.mcap", [L.Series("/bad", "test.B", np.array([np.nan]), {"v": np.zeros(1)})])
    assert list(tmp_path.iterdir()) == []
