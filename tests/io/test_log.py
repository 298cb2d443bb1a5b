"""MCAP run logs: bit-exact round trip, byte-identical rewrites, Foxglove schemas and frames, atomicity."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest
from mcap.reader import make_reader

from coopsim.io import log as L
from coopsim.io import mcap_codec as C
from coopsim.io import foxglove as F
from coopsim.dynamics.closed_chain import arm_poses
from coopsim.twin.mujoco_run import run_twin
from coopsim.forward.simulate import simulate
from coopsim.core.spatial import quat_to_rot

from helpers import ROOT, SCENARIOS

SCENARIO_FILE = SCENARIOS / "paper_planar_2x3.yaml"
FOXGLOVE_DATA = ROOT / "tests" / "data" / "foxglove"


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
    return path, C.read_mcap(path)


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
    s = C.Series("/x", "test.X", t, {"f": f, "i": np.array([-3, 0, 2**60]), "b": np.array([True, False, True]),
                                      "cube": np.arange(24.0).reshape(3, 2, 2, 2) / 7})
    empty = C.Series("/empty", "test.E", np.zeros(0), {"v": np.zeros((0, 3))})
    data = C.read_mcap(C.write_mcap(tmp_path / "x.mcap", [s, empty], {"rec": {"k": "v"}}))
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


def _assert_same_log(a: C.LogData, b: C.LogData) -> None:
    assert a.metadata == b.metadata and a.schemas == b.schemas and a.messages == b.messages
    assert list(a.topics) == list(b.topics)
    for topic, fields in a.topics.items():
        assert list(fields) == list(b.topics[topic]), topic
        for name, x in fields.items():
            y = b.topics[topic][name]
            assert x.dtype == y.dtype and x.shape == y.shape, (topic, name)
            assert np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y)), (topic, name)


def test_log_data_in_memory_equals_the_file_read_back(run, logged):
    """What the commands draw their figures from (`log_data`, no file) is what `read_mcap` reads back:
    same topics, field order, dtypes, bits (nan, -0.0), /tf and /scene messages and metadata."""
    model, res, tw = run
    path, data = logged
    streams, meta = L.run_log(model, res, tw, metadata_extra={"scenario_file": SCENARIO_FILE, "note": "test"})
    _assert_same_log(C.log_data(streams, meta), data)
    bare = C.log_data(streams, meta, messages=False)          # what the commands draw from: no /tf, /scene
    assert bare.messages == {} and bare.schemas == data.schemas
    _assert_same_log(dataclasses.replace(bare, messages=data.messages), data)


def test_log_data_of_edge_cases_equals_the_file_read_back(tmp_path):
    t = np.array([0.0, 0.5])
    s = C.Series("/x", "test.X", t, {"f": np.array([[np.nan, -0.0], [np.inf, 1e-310]]),
                                      "f32": np.array([0.1, -2.5], dtype=np.float32),
                                      "i": np.array([[1, -2]], dtype=np.int16).repeat(2, 0),
                                      "u": np.array([7, 255], dtype=np.uint8), "b": np.array([True, False])})
    j = F.JsonTopic("/j", "test.J", {"type": "object"}, t, ({"a": (1, 2.5)}, {"a": [None, "é"]}))
    _assert_same_log(C.log_data([s, j], {"r": {"k": "v"}}),
                     C.read_mcap(C.write_mcap(tmp_path / "e.mcap", [s, j], {"r": {"k": "v"}})))


def test_series_messages_are_the_json_encoders_bytes():
    """The hand-formatted messages equal json.dumps (no spaces, UTF-8) of the message dict, built here
    from the documented encoding: floats exact, non-finite as strings, rows of 3-D fields wrapped."""
    rng = np.random.default_rng(3)
    f = rng.normal(size=(6, 3)) * 10.0 ** rng.integers(-300, 300, size=(6, 3))
    f[1, 1], f[2, 0], f[4, 2] = -0.0, np.nan, -np.inf
    fields = {"ángulo": f, "g": f[:, 0].copy(), "w": rng.normal(size=(6, 2, 3)), "k": np.arange(6) - 3,
              "ok": np.arange(6) % 2 == 0, "h": rng.normal(size=(6, 2)).astype(np.float32)}
    t = np.linspace(0.0, 2.5, 6) + 1e-9
    spell = {"nan": "NaN", "inf": "Infinity", "-inf": "-Infinity"}

    def value(x):
        if isinstance(x, float) and not np.isfinite(x):
            return spell[repr(x)]
        return [value(v) for v in x] if isinstance(x, list) else x

    expected = []
    for i in range(6):
        msg = {"timestamp": {"sec": int(round(t[i] * 1e9)) // 10**9, "nsec": int(round(t[i] * 1e9)) % 10**9},
               "t": float(t[i]), "ángulo": value(f[i].tolist()), "g": value(float(f[i, 0])),
               "w": [{"row": r} for r in fields["w"][i].tolist()], "k": int(fields["k"][i]), "ok": bool(i % 2 == 0),
               "h": fields["h"][i].astype(float).tolist()}
        expected.append(json.dumps(msg, separators=(",", ":"), ensure_ascii=False).encode())
    assert C._series_messages(C.Series("/m", "test.M", t, fields)) == expected


def test_messages_are_ordered_by_time_then_series(tmp_path):
    a = C.Series("/a", "test.S", np.array([0.0, 0.2]), {"v": np.array([1.0, 2.0])})
    b = C.Series("/b", "test.S", np.array([0.0, 0.1, 0.2]), {"v": np.array([3.0, 4.0, 5.0])})
    C.write_mcap(tmp_path / "o.mcap", [a, b])
    with open(tmp_path / "o.mcap", "rb") as fh:
        order = [(c.topic, m.log_time, m.publish_time) for _, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    assert order == [("/a", 0, 0), ("/b", 0, 0), ("/b", 100_000_000, 100_000_000), ("/a", 200_000_000, 200_000_000),
                     ("/b", 200_000_000, 200_000_000)]


def test_series_schema_describes_fixed_shapes(run):
    _, res, _ = run
    schema = C.series_schema(L.simulation_series(res)[2])
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    w = schema["properties"]["wrench"]
    assert (w["minItems"], w["maxItems"]) == (2, 2)
    row = w["items"]["properties"]["row"]
    assert (row["minItems"], row["maxItems"], row["items"]) == (6, 6, {"type": "number"})


def test_inconsistent_schema_names_are_refused(tmp_path):
    a = C.Series("/a", "test.S", np.zeros(1), {"v": np.zeros(1)})
    b = C.Series("/b", "test.S", np.zeros(1), {"v": np.zeros((1, 2))})
    with pytest.raises(C.LogError, match="/b: schema 'test.S' differs"):
        C.write_mcap(tmp_path / "s.mcap", [a, b])
    with pytest.raises(C.LogError, match="/a: field name 't' is reserved"):
        C.write_mcap(tmp_path / "s.mcap", [C.Series("/a", "test.T", np.zeros(1), {"t": np.zeros(1)})])
    assert list(tmp_path.iterdir()) == []


# -- Foxglove view --------------------------------------------------------------------------------

def test_foxglove_schemas_and_frames_of_every_link(run, logged):
    model, res, tw = run
    path, data = logged
    assert data.schemas["/tf"] == "foxglove.FrameTransforms" and data.schemas["/scene"] == "foxglove.SceneUpdate"
    schemas = _file_schemas(path)
    item = schemas["foxglove.FrameTransforms"]["properties"]["transforms"]["items"]["properties"]
    published = _published("FrameTransforms")["properties"]["transforms"]["items"]["properties"]
    assert set(item) == set(published), f"FrameTransform fields {sorted(item)} vs published {sorted(published)}"
    assert set(item["rotation"]["properties"]) == set(published["rotation"]["properties"]) == set("xyzw")

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
    names = F.link_frame_names(model, "native")
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


# -- against Foxglove's published schemas (tests/data/foxglove: @foxglove/schemas 2.1.0, see README) --

FOXGLOVE = {"/tf": "FrameTransforms", "/scene": "SceneUpdate"}


def _published(name):
    return json.loads((FOXGLOVE_DATA / f"{name}.json").read_text())


def _unknown_fields(value, schema, where="$"):
    """Paths of the object keys in `value` that `schema` (published) does not declare: a misspelt
    field passes a JSON-Schema validator (extra properties are allowed) but Foxglove ignores it."""
    out = []
    if isinstance(value, dict):
        props = schema.get("properties", {})
        for key, sub in value.items():
            out += [f"{where}.{key}"] if key not in props else _unknown_fields(sub, props[key], f"{where}.{key}")
    elif isinstance(value, list):
        for i, item in enumerate(value):
            out += _unknown_fields(item, schema.get("items", {}), f"{where}[{i}]")
    return out


def _schema_differences(ours, published, where="$"):
    """Where our written schema departs from the published one: a field or title the published schema
    does not have, another JSON type, other enum constants or integer bounds, a field the published
    schema requires that ours does not declare."""
    out = []
    for key in ("title", "type"):
        if key in ours and ours.get(key) != published.get(key):
            out.append(f"{where}: {key} {ours.get(key)!r} vs published {published.get(key)!r}")
    for key in ("minimum", "maximum"):
        if ours.get(key) != published.get(key):
            out.append(f"{where}: {key} {ours.get(key)!r} vs published {published.get(key)!r}")
    if "oneOf" in ours or "oneOf" in published:
        got = {(a.get("title"), a["const"]) for a in ours.get("oneOf", [])}
        want = {(a.get("title"), a["const"]) for a in published.get("oneOf", [])}
        if got != want:
            out.append(f"{where}: enum {sorted(got)} vs published {sorted(want)}")
    props, pub_props = ours.get("properties", {}), published.get("properties", {})
    for key, sub in props.items():
        if key not in pub_props:
            out.append(f"{where}.{key}: not a published field")
        else:
            out += _schema_differences(sub, pub_props[key], f"{where}.{key}")
    for key in published.get("required", []):
        if key not in props:
            out.append(f"{where}.{key}: required by the published schema, not declared")
    if "items" in ours and ours.get("maxItems") != 0:  # an array always written empty has no items to describe
        out += _schema_differences(ours["items"], published.get("items", {}), f"{where}[]")
    return out


def test_vendored_foxglove_schemas_are_the_published_files():
    """The reference files are Foxglove's, byte for byte (sha256 as recorded in the README)."""
    readme = (FOXGLOVE_DATA / "README.md").read_text()
    for name in FOXGLOVE.values():
        digest = hashlib.sha256((FOXGLOVE_DATA / f"{name}.json").read_bytes()).hexdigest()
        assert f"`{name}.json` {digest}" in readme, f"{name}.json sha256 {digest} not the one recorded"
        assert _published(name)["title"] == f"foxglove.{name}", f"{name}.json title"


def test_written_foxglove_schemas_agree_with_the_published_ones(logged):
    """Every field, title, type, enum and bound of the schemas in the file is the published one, and
    every field the published schema requires is declared (the /scene entities write the primitive
    arrays they do not use as empty arrays)."""
    path, data = logged
    schemas = _file_schemas(path)
    for topic, name in FOXGLOVE.items():
        assert data.schemas[topic] == f"foxglove.{name}", f"{topic} schema name {data.schemas[topic]!r}"
        diffs = _schema_differences(schemas[f"foxglove.{name}"], _published(name))
        assert diffs == [], f"{name}: written schema departs from Foxglove's: {diffs}"


def test_written_foxglove_messages_validate_against_the_published_schemas(logged):
    """Every /tf message and the /scene message: valid under Foxglove's schema (Draft 2020-12,
    jsonschema) and without fields Foxglove does not know."""
    jsonschema = pytest.importorskip("jsonschema")
    path, data = logged
    for topic, name in FOXGLOVE.items():
        validator = jsonschema.Draft202012Validator(_published(name))
        assert len(data.messages[topic]) >= 1, f"{topic}: no messages"
        for k, msg in enumerate(data.messages[topic]):
            errors = [f"{list(e.absolute_path)}: {e.message}" for e in validator.iter_errors(msg)]
            assert errors == [], f"{topic} message {k} invalid under foxglove.{name}: {errors[:5]}"
            assert _unknown_fields(msg, _published(name)) == [], f"{topic} message {k}: fields unknown to Foxglove"
    # our own series schemas still describe their messages
    with open(path, "rb") as fh:
        _, _, msg = next(make_reader(fh).iter_messages(topics=["/native/grasp_wrench"]))
    jsonschema.Draft202012Validator(_file_schemas(path)["coopsim.Wrenches"]).validate(json.loads(msg.data))


def test_published_schema_checks_catch_wrong_messages_and_schemas(logged):
    """The checks above can fail: a misspelt field, a quaternion component as a string, nsec out of
    range, a missing primitive array, and a schema with a misspelt field or a wrong type."""
    jsonschema = pytest.importorskip("jsonschema")
    path, data = logged
    tf = _published("FrameTransforms")
    validator = jsonschema.Draft202012Validator(tf)
    good = data.messages["/tf"][0]

    def mutated(edit):
        msg = json.loads(json.dumps(good))
        edit(msg["transforms"][0])
        return msg

    misspelt = mutated(lambda f: f.update(translaton=f.pop("translation")))
    assert _unknown_fields(misspelt, tf) == ["$.transforms[0].translaton"], "misspelt field not reported"
    assert not validator.is_valid(misspelt), "missing translation accepted"
    assert not validator.is_valid(mutated(lambda f: f["rotation"].update(w="1.0"))), "string quaternion accepted"
    assert not validator.is_valid(mutated(lambda f: f["timestamp"].update(nsec=10**9))), "nsec = 1e9 accepted"
    scene = json.loads(json.dumps(data.messages["/scene"][0]))
    del scene["entities"][0]["spheres"]
    assert not jsonschema.Draft202012Validator(_published("SceneUpdate")).is_valid(scene), "entity without spheres accepted"

    ours = _file_schemas(path)["foxglove.FrameTransforms"]
    bad = json.loads(json.dumps(ours))
    item = bad["properties"]["transforms"]["items"]["properties"]
    item["child_frame"] = item.pop("child_frame_id")
    item["translation"]["properties"]["x"]["type"] = "string"
    assert _schema_differences(bad, tf) == [
        "$.transforms[].translation.x: type 'string' vs published 'number'",
        "$.transforms[].child_frame: not a published field",
        "$.transforms[].child_frame_id: required by the published schema, not declared",
    ], "schema comparison missed a departure"


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

    original = C.Writer.add_message
    monkeypatch.setattr(C.Writer, "add_message", failing)
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
    bad = C.Series("/bad", "test.B", np.array([0.0, 0.1]), {"v": np.zeros((3, 2))})
    with pytest.raises(C.LogError, match=r"/bad: field 'v' has shape \(3, 2\), expected \(2, \.\.\.\)"):
        C.write_mcap(tmp_path / "bad.mcap", [bad])
    with pytest.raises(C.LogError, match="/bad: t must be finite"):
        C.write_mcap(tmp_path / "bad.mcap", [C.Series("/bad", "test.B", np.array([np.nan]), {"v": np.zeros(1)})])
    assert list(tmp_path.iterdir()) == []


V1_LOG = ROOT / "tests" / "data" / "logs" / "paper_planar_2x3_v1.mcap"


def test_a_log_written_before_the_package_was_reorganised_reads_as_a_fresh_one(tmp_path):
    """The format's names (library, the series $comment the reader finds series by, schema names) are
    identifiers, not module paths: a log `coopsim run scenarios/paper_planar_2x3.yaml --duration 0.05`
    wrote with the flat package (tests/data/logs/paper_planar_2x3_v1.mcap, committed) reads back with
    the same topics, schemas and metadata records as one written now, its series decoded as arrays,
    and its joint angles equal to a fresh run's within 1e-9 rad (both at rtol 1e-12; the file was
    written on another machine's rounding)."""
    from helpers import run_cli

    old = L.read_run_log(V1_LOG)
    assert run_cli("run", SCENARIO_FILE, "--duration", "0.05", "--out", tmp_path / "out", cwd=ROOT).returncode == 0
    new = L.read_run_log(tmp_path / "out" / "paper_planar_2x3.mcap")
    assert old.schemas == new.schemas and set(new.metadata) - set(old.metadata) == {"validation.verdict"}, \
        "the same metadata records, and the validation verdict that later logs add"
    with open(V1_LOG, "rb") as f:
        assert make_reader(f).get_header().library == C.LIBRARY
    for topic in ("/native/joint_state", "/mujoco/joint_state"):
        a, b = old.topics[topic], new.topics[topic]
        assert isinstance(a["angle"], np.ndarray) and np.array_equal(a["t"], b["t"])
        assert np.max(np.abs(a["angle"] - b["angle"])) <= 1e-9, topic
