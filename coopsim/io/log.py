"""Run logs as MCAP files: JSON messages described by JSON Schemas (draft 2020-12), viewable in Foxglove.

Two layers:

- generic: a :class:`Series` is a set of arrays sampled at times t (N,) s; :func:`write_mcap` writes one
  JSON message per sample, :func:`read_mcap` gives the arrays back bit for bit. A :class:`JsonTopic`
  carries ready-made JSON messages with a fixed schema (the Foxglove 3D view).
- domain: :func:`simulation_series` / :func:`twin_series` turn a native :class:`SimResult` / MuJoCo
  :class:`TwinResult` into series, :func:`frame_transforms` and :func:`scene_update` build the Foxglove
  ``/tf`` and ``/scene`` topics, :func:`run_metadata` the metadata records, and :func:`write_run_log`
  composes all of them.

Encoding of a series message (one per sample):
``{"timestamp": {"sec", "nsec"}, "t": <float s>, <field>: <value>, ...}``. ``timestamp`` (and the
MCAP log_time = publish_time) is t rounded to integer nanoseconds; ``t`` is the exact float64 sample
time, so the reader rebuilds t bit for bit. A per-sample value of shape () is a number, of shape (d,)
an array of d numbers, of shape (d, ...) an array of d objects ``{"row": <value of shape (...)>}``:
Foxglove's JSON-schema parser rejects arrays of arrays, so a (r, 6) wrench per sample reads as
``grasp_wrench.wrench[1].row[2]`` in Foxglove's message paths.

Floats are written with Python's repr (shortest round-trip form: exact). Non-finite floats, which JSON
cannot carry as numbers, are written explicitly as the strings ``"NaN"``, ``"Infinity"`` and
``"-Infinity"`` (JavaScript's spellings) and read back as nan / ±inf; the schema still says "number"
(Foxglove's parser accepts nothing else), so a strict JSON-Schema validator flags exactly those
samples. The condition number ``cond`` of a rank-deficient constraint matrix is +inf, which is why
non-finite values are encoded rather than refused. A NaN's sign and payload are not kept.

Files are written atomically (:func:`coopsim.io.atomic.atomic_path`: a temporary file in the target folder,
``os.replace`` when complete; the folder is created if missing) and
deterministically: no wall-clock content, a fixed library string, messages ordered by time then by the
order of the streams given, so the same input gives a byte-identical file.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from dataclasses import asdict, dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from mcap.writer import CompressionType, Writer

from coopsim.io.atomic import atomic_path
from coopsim.dynamics.kinematics import arm_frames
from coopsim.core.joints import type_names
from coopsim.core.labels import joint_labels
from coopsim.core.model import Model
from coopsim.core.errors import CoopsimError
from coopsim.core.spatial import rot_to_quat, rots_to_quats

# The log format's own names (written into every log, and SERIES_COMMENT read back to find a series):
# identifiers of the format, not module paths, so they stay as the first logs wrote them.
LIBRARY = "coopsim.log"
JSON_SCHEMA_DRAFT = "https://json-schema.org/draft/2020-12/schema"
SERIES_COMMENT = "coopsim.log series v1: one message per sample; t is the sample time in s (float64)"
_RESERVED = ("timestamp", "t")
_NONFINITE = {"NaN": float("nan"), "Infinity": float("inf"), "-Infinity": float("-inf")}
_LEAF = {"f": "number", "i": "integer", "u": "integer", "b": "boolean"}
_DTYPE = {"number": np.float64, "integer": np.int64, "boolean": np.bool_}


class LogError(ValueError):
    """A series or a log file is malformed; the message names the topic and field."""


class UnreadableLogError(CoopsimError):
    """A file that is not a complete, intact log (empty, cut short, corrupted, not MCAP, not the log
    asked for); the one-line message names the file."""


# ------------------------------------------------------------------------------------------------
# generic layer
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Series:
    """Arrays sampled over time, written as one JSON message per sample on `topic`.

    t (N,) s, finite, >= 0; fields: name → array (N, ...) of floats, integers or booleans (floats
    are stored as float64, integers as int64: read back with those dtypes). Field names must not be
    "timestamp" or "t". All series sharing a schema_name must have the same fields, dtypes, shapes."""

    topic: str
    schema_name: str
    t: np.ndarray
    fields: dict[str, np.ndarray]


@dataclass(frozen=True, eq=False)
class JsonTopic:
    """Ready-made JSON messages on `topic`: messages[k] (a JSON-serialisable dict) is logged at t[k] s;
    `schema` is its JSON Schema (a dict) registered under schema_name."""

    topic: str
    schema_name: str
    schema: dict
    t: np.ndarray
    messages: tuple[dict, ...]


@dataclass(frozen=True, eq=False)
class LogData:
    """A log read back. metadata: record name → {key: value}; topics: series topic → {"t": (N,),
    field: (N, ...)} (bit-identical to what was written); schemas: every topic → its schema name;
    messages: every non-series topic (e.g. /tf, /scene) → its decoded JSON messages in file order."""

    metadata: dict[str, dict[str, str]]
    topics: dict[str, dict[str, np.ndarray]]
    schemas: dict[str, str]
    messages: dict[str, list[dict]] = field(default_factory=dict)


def time_ns(t: np.ndarray) -> np.ndarray:
    """Times t (N,) s → integer nanoseconds (N,) int64 (rounded to nearest)."""
    return np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def stamp(ns: int) -> dict[str, int]:
    """Integer nanoseconds → Foxglove/ROS time {"sec", "nsec"}."""
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def _time_schema(description: str) -> dict:
    return {"type": "object", "title": "time", "description": description,
            "properties": {"sec": {"type": "integer", "minimum": 0},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
            "required": ["sec", "nsec"]}


def _value_schema(shape: tuple[int, ...], leaf: str) -> dict:
    """Schema of one sample of shape `shape`: number, array of numbers, or array of {"row": …}."""
    if not shape:
        return {"type": leaf}
    items = ({"type": leaf} if len(shape) == 1 else
             {"type": "object", "properties": {"row": _value_schema(shape[1:], leaf)}, "required": ["row"]})
    return {"type": "array", "items": items, "minItems": shape[0], "maxItems": shape[0]}


def series_schema(s: Series) -> dict:
    """JSON Schema (draft 2020-12) of the messages of series `s`, from its field dtypes and shapes."""
    props = {"timestamp": _time_schema("Sample time, rounded to nanoseconds"),
             "t": {"type": "number", "description": "Sample time (s), exact"}}
    for name, a in s.fields.items():
        props[name] = _value_schema(tuple(a.shape[1:]), _LEAF[a.dtype.kind])
    return {"$schema": JSON_SCHEMA_DRAFT, "$comment": SERIES_COMMENT, "title": s.schema_name,
            "type": "object", "properties": props, "required": list(props)}


def _check_times(topic: str, t: np.ndarray, n: int | None = None) -> None:
    if t.ndim != 1 or (n is not None and len(t) != n):
        raise LogError(f"{topic}: t must have shape ({'N' if n is None else n},), got {t.shape}")
    if t.dtype.kind not in "fiu" or not np.all(np.isfinite(t)) or np.any(t < 0):
        raise LogError(f"{topic}: t must be finite and >= 0")


def _check_series(s: Series) -> None:
    t = np.asarray(s.t)
    _check_times(s.topic, t)
    for name, a in s.fields.items():
        if name in _RESERVED or not isinstance(name, str) or not name:
            raise LogError(f"{s.topic}: field name {name!r} is reserved or empty")
        if not isinstance(a, np.ndarray) or a.dtype.kind not in _LEAF:
            raise LogError(f"{s.topic}: field {name!r} must be a float, integer or bool array")
        if a.ndim < 1 or a.shape[0] != len(t):
            raise LogError(f"{s.topic}: field {name!r} has shape {a.shape}, expected ({len(t)}, ...)")


def nonfinite_name(x: float) -> str:
    """The string a non-finite float is written as: "NaN", "Infinity" or "-Infinity"."""
    return "NaN" if np.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


def _wrap_rows(x: Any, depth: int) -> Any:
    """Nested list of one sample (depth = ndim) → its JSON form (rows as {"row": …} objects)."""
    if depth <= 1:
        return x
    return [{"row": _wrap_rows(r, depth - 1)} for r in x]


def _field_values(a: np.ndarray) -> list:
    """Array (N, ...) → list of N JSON values (floats exact, non-finite as strings)."""
    if a.dtype.kind == "f":
        a = a.astype(np.float64, copy=False)
        bad = ~np.isfinite(a)
        if bad.any():
            obj = a.astype(object)
            obj[bad] = [nonfinite_name(x) for x in a[bad]]
            a = obj
    elif a.dtype.kind in "iu":
        a = a.astype(np.int64)
    rows = a.tolist()
    return [_wrap_rows(r, a.ndim - 1) for r in rows]


def _field_texts(a: np.ndarray) -> list[str]:
    """Array (N, ...) → the JSON text of each of its N samples, as `_dumps(_field_values(a)[i])` writes
    it. Finite floats of up to one array axis per sample, integers and booleans are formatted directly
    (Python's float repr is what JSON's encoder writes); anything else goes through `_dumps`."""
    if a.ndim > 2 or not a.size or (a.dtype.kind == "f" and not np.isfinite(a).all()):
        return [_dumps(v).decode("utf-8") for v in _field_values(a)]
    flat = a.reshape(len(a), -1)
    if a.dtype.kind == "b":
        text = np.where(flat, "true", "false").tolist()
    else:
        text = [list(map(repr, row)) for row in flat.astype(np.float64 if a.dtype.kind == "f" else np.int64).tolist()]
    if a.ndim == 1:
        return [row[0] for row in text]
    return ["[" + ",".join(row) + "]" for row in text]


def _series_messages(s: Series) -> list[bytes]:
    """Encoded JSON messages (N) of one series: {"timestamp": {"sec", "nsec"}, "t": t, <field>: value, …}
    with no spaces, byte for byte what `_dumps` writes for that dict."""
    ns = time_ns(s.t).tolist()
    t = np.asarray(s.t, dtype=np.float64).tolist()
    names = [json.dumps(k, ensure_ascii=False) for k in s.fields]
    cols = [_field_texts(a) for a in s.fields.values()]
    rows = zip(*cols) if cols else ((),) * len(t)
    return [("{\"timestamp\":{\"sec\":%d,\"nsec\":%d},\"t\":%r" % (n // 1_000_000_000, n % 1_000_000_000, ti)
             + "".join("," + k + ":" + v for k, v in zip(names, row)) + "}").encode("utf-8")
            for n, ti, row in zip(ns, t, rows)]


def _dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode("utf-8")


def _stream_parts(stream: Series | JsonTopic) -> tuple[dict, np.ndarray, list[bytes]]:
    """(schema, log times ns (N,), encoded messages (N)) of a series or JSON topic."""
    if isinstance(stream, Series):
        _check_series(stream)
        return series_schema(stream), time_ns(stream.t), _series_messages(stream)
    t = np.asarray(stream.t, dtype=np.float64)
    _check_times(stream.topic, t, len(stream.messages))
    try:
        return stream.schema, time_ns(t), [_dumps(m) for m in stream.messages]
    except (TypeError, ValueError) as exc:  # a non-finite float or a value JSON cannot hold
        raise LogError(f"{stream.topic}: message not JSON-serialisable: {exc}") from None


def _register(writer: Writer, streams: Sequence[Series | JsonTopic]) -> list[tuple[int, np.ndarray, list[bytes]]]:
    """Register one schema per schema name and one channel per topic; return per stream
    (channel id, log times, messages)."""
    schema_ids: dict[str, tuple[int, dict]] = {}
    topics: set[str] = set()
    out = []
    for s in streams:
        schema, ns, msgs = _stream_parts(s)
        if s.topic in topics:
            raise LogError(f"{s.topic}: topic given twice")
        topics.add(s.topic)
        if s.schema_name in schema_ids:
            if schema_ids[s.schema_name][1] != schema:
                raise LogError(f"{s.topic}: schema {s.schema_name!r} differs from an earlier topic's")
        else:
            sid = writer.register_schema(s.schema_name, "jsonschema", _dumps(schema))
            schema_ids[s.schema_name] = (sid, schema)
        cid = writer.register_channel(s.topic, "json", schema_ids[s.schema_name][0])
        out.append((cid, ns, msgs))
    return out


def _write_all(f, streams: Sequence[Series | JsonTopic], metadata: dict[str, dict[str, str]]) -> None:
    writer = Writer(f, compression=CompressionType.ZSTD, enable_data_crcs=True)   # every byte under a CRC
    writer.start(profile="", library=LIBRARY)
    parts = _register(writer, streams)
    ns = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, np.int64)
    which = np.concatenate([np.full(len(p[1]), k) for k, p in enumerate(parts)]) if parts else ns
    index = np.concatenate([np.arange(len(p[1])) for p in parts]) if parts else ns
    for j in np.lexsort((index, which, ns)):
        cid, times, msgs = parts[which[j]]
        k = int(index[j])
        writer.add_message(cid, log_time=int(times[k]), data=msgs[k], publish_time=int(times[k]), sequence=k)
    for name, record in metadata.items():
        bad = [k for k, v in record.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise LogError(f"metadata {name!r}: keys and values must be strings ({bad[0]!r})")
        writer.add_metadata(name, dict(record))
    writer.finish()


def write_mcap(path: str | Path, series: Sequence[Series | JsonTopic],
               metadata: dict[str, dict[str, str]] | None = None) -> Path:
    """Write `series` (Series or JsonTopic streams, one topic each) and MCAP metadata records
    (name → {key: value}, strings) to `path`, atomically. Messages are ordered by time, then by the
    order of the streams, then by sample. Returns the path."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        _write_all(f, series, metadata or {})
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def log_data(streams: Sequence[Series | JsonTopic], metadata: dict[str, dict[str, str]] | None = None,
             messages: bool = True) -> LogData:
    """The LogData that `read_mcap` gives back for a log written by `write_mcap(path, streams, metadata)`,
    built in memory (what the commands draw their figures from while the file is written): series as
    float64 / int64 / bool arrays, JSON topics' messages as JSON decodes them (`messages` False: left
    out, e.g. the thousands of /tf transforms no figure draws). Checked as `write_mcap` checks them;
    tests/io/test_log.py compares it with the file read back."""
    topics, schemas, decoded = {}, {}, {}
    for st in streams:
        if isinstance(st, Series):
            _check_series(st)
            topics[st.topic] = {"t": np.array(st.t, dtype=np.float64)} | {
                k: np.array(a, dtype=_DTYPE[_LEAF[a.dtype.kind]]) for k, a in st.fields.items()}
        elif messages:
            decoded[st.topic] = [json.loads(m) for m in _stream_parts(st)[2]]
        schemas[st.topic] = st.schema_name
    return LogData({k: dict(v) for k, v in (metadata or {}).items()}, topics, schemas, decoded)


def _unwrap_rows(v: Any, depth: int) -> Any:
    if depth <= 1:
        return v
    return [_unwrap_rows(r["row"], depth - 1) for r in v]


def _schema_shape(schema: dict) -> tuple[tuple[int, ...], str]:
    """(per-sample shape, leaf type) of a value schema written by :func:`_value_schema`."""
    shape = []
    while schema["type"] == "array":
        shape.append(int(schema["minItems"]))
        items = schema["items"]
        schema = items["properties"]["row"] if items["type"] == "object" else items
    return tuple(shape), schema["type"]


def _decode_field(values: list, shape: tuple[int, ...], leaf: str) -> np.ndarray:
    """Values of one field (N messages) → array (N, *shape). Numbers only convert at once; a field
    holding strings (the non-finite spellings) goes through `_replace_nonfinite`."""
    rows = [_unwrap_rows(v, len(shape)) for v in values] if len(shape) > 1 else values
    out = np.asarray(rows)
    if out.dtype.kind not in "biuf" or (leaf == "boolean") != (out.dtype.kind == "b"):
        out = np.asarray(_replace_nonfinite(rows) if leaf == "number" else rows, dtype=_DTYPE[leaf])
    return out.astype(_DTYPE[leaf], copy=False).reshape((len(values),) + shape)


def _replace_nonfinite(x: Any) -> Any:
    if isinstance(x, list):
        return [_replace_nonfinite(v) for v in x]
    if isinstance(x, str):
        try:
            return _NONFINITE[x]
        except KeyError:
            raise LogError(f"unexpected string {x!r} in a number field") from None
    return x


def _decode_series(schema: dict, msgs: list[dict]) -> dict[str, np.ndarray]:
    out = {"t": np.array([m["t"] for m in msgs], dtype=np.float64)}
    for name, sub in schema["properties"].items():
        if name in _RESERVED:
            continue
        shape, leaf = _schema_shape(sub)
        out[name] = _decode_field([m[name] for m in msgs], shape, leaf)
    return out


def read_mcap(path: str | Path) -> LogData:
    """Read a log written by :func:`write_mcap`: series topics as arrays (bit-identical), other JSON
    topics as decoded messages, metadata records and schema names. A file that is not a whole, intact
    MCAP log of JSON messages raises UnreadableLogError naming the file: the whole file is read in
    order, checking the magic at both ends, every record's length, the data section's CRC (where the
    log carries one), each chunk's, the summary's, and that nothing follows the end."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise UnreadableLogError(f"{path}: cannot read the log: {exc.strerror or exc}") from None
    try:
        return _parse_log(data)
    except Exception as exc:  # noqa: BLE001 - a broken file can fail anywhere in the parser: one line
        reason = " ".join(str(exc).split())[:160] or type(exc).__name__
        raise UnreadableLogError(f"{path}: not a readable MCAP log ({reason})") from None


_MAGIC = b"\x89MCAP0\r\n"


def _parse_log(data: bytes) -> LogData:
    """`read_mcap` on the file's bytes; any exception means a broken file."""
    import io
    import zlib

    from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    if len(data) < 2 * len(_MAGIC) or data[:len(_MAGIC)] != _MAGIC or data[-len(_MAGIC):] != _MAGIC:
        raise LogError("no MCAP magic at its start and end: not an MCAP file, or cut short")
    # first pass, chunks left compressed: structure, the data section's CRC, the summary's, the end
    stream = io.BytesIO(data)
    footer = data_end = None
    for record in StreamReader(stream, emit_chunks=True, validate_crcs=True, record_size_limit=len(data)).records:
        if isinstance(record, Footer):
            footer = record
        elif isinstance(record, DataEnd):
            data_end = record
    if data_end is None:   # (its opcode damaged: the reader skips it as an unknown record, CRC unchecked)
        raise LogError("no data-end record")
    if stream.tell() != len(data):
        raise LogError(f"{len(data) - stream.tell()} bytes after the end of the log")
    if footer.summary_start and footer.summary_crc and \
            zlib.crc32(data[footer.summary_start:len(data) - len(_MAGIC) - 4]) != footer.summary_crc:
        raise LogError("the summary section's CRC does not match")
    schemas, channels, data_by_channel, meta = {}, {}, {}, {}
    for record in StreamReader(io.BytesIO(data), validate_crcs=True, record_size_limit=len(data)).records:
        if isinstance(record, Schema):
            schemas[record.id] = (record.name, record.data)
        elif isinstance(record, Channel):
            channels[record.id] = (record.topic, record.schema_id)
        elif isinstance(record, Message):
            data_by_channel.setdefault(record.channel_id, []).append(record.data)
        elif isinstance(record, Metadata):
            meta[record.name] = dict(record.metadata)
    decoded = {sid: (name, json.loads(text)) for sid, (name, text) in schemas.items()}
    topic_schema = {topic: decoded[sid] for topic, sid in channels.values()}
    messages_of = {topic: data_by_channel.get(cid, []) for cid, (topic, _) in channels.items()}
    raw = {t: json.loads(b"[" + b",".join(msgs) + b"]") for t, msgs in messages_of.items()}   # one parse per topic
    topics, messages = {}, {}
    for topic, (_, schema) in topic_schema.items():
        if schema.get("$comment") == SERIES_COMMENT:
            topics[topic] = _decode_series(schema, raw[topic])
        else:
            messages[topic] = raw[topic]
    return LogData(metadata=meta, topics=topics, schemas={t: s[0] for t, s in topic_schema.items()},
                   messages=messages)


# what the comparison plots draw: topic -> {field: trailing shape, "n": the joint count}
_RUN_LOG_SERIES = {"joint_state": {"angle": ("n",), "rate": ("n",)}, "object": {"position": (3,), "twist": (6,)},
                   "constraint": {}}
_RUN_LOG_CONSTRAINT = {"/native": "residual_pos", "/mujoco": "weld_violation"}


def read_run_log(path: str | Path) -> LogData:
    """A `coopsim run` log (`read_mcap`), checked to hold what its comparison plots draw: the native
    model's joint_state (angle, rate (N, n)), object (position (N, 3), twist (N, 6)) and constraint
    (residual_pos (N,)) series, N >= 1 finite sample times, and the twin's (weld_violation) if any of
    its series is there; UnreadableLogError naming the file otherwise."""
    log = read_mcap(path)

    def fail(reason: str):
        raise UnreadableLogError(f"{path}: not a coopsim run log: {reason}")

    n = None
    for prefix, constraint in _RUN_LOG_CONSTRAINT.items():
        if prefix == "/mujoco" and not any(t.startswith(prefix + "/") for t in log.topics):
            continue
        for name, fields in _RUN_LOG_SERIES.items():
            topic = f"{prefix}/{name}"
            d = log.topics.get(topic)
            if d is None:
                fail(f"no {topic} series")
            t = d["t"]
            if t.ndim != 1 or len(t) == 0 or not np.all(np.isfinite(t)):
                fail(f"{topic}: no samples, or sample times that are not finite")
            for key, shape in (fields | ({constraint: ()} if name == "constraint" else {})).items():
                x = d.get(key)
                if x is None:
                    fail(f"{topic}: no field {key!r}")
                if shape == ("n",):
                    n = x.shape[1] if n is None and x.ndim == 2 else n
                    shape = (n,)
                if x.shape != (len(t),) + tuple(shape) or x.dtype.kind != "f":
                    fail(f"{topic}.{key}: shape {list(x.shape)}, expected {[len(t), *shape]} numbers")
    return log


# ------------------------------------------------------------------------------------------------
# Foxglove schemas (field names as published in foxglove/schemas, schemas/jsonschema/*.json; the
# "required" lists are ours: the fields this module always writes)
# ------------------------------------------------------------------------------------------------

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
                "timestamp": _time_schema("Timestamp of transform"),
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
                    "timestamp": _time_schema("Timestamp of the deletion. Only matching entities earlier than "
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
                    "timestamp": _time_schema("Timestamp of the entity"),
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


# ------------------------------------------------------------------------------------------------
# domain layer
# ------------------------------------------------------------------------------------------------

def _joint_state(prefix: str, t, q, qd, qdd, tau) -> Series:
    return Series(f"{prefix}/joint_state", "coopsim.JointState", t,
                  {"angle": q, "rate": qd, "acceleration": qdd, "torque": tau})


def _object_state(prefix: str, t, pos, quat, twist) -> Series:
    return Series(f"{prefix}/object", "coopsim.ObjectState", t,
                  {"position": pos, "quaternion": quat, "twist": twist})


def simulation_series(res, prefix: str = "/native") -> list[Series]:
    """Series of a native SimResult: {prefix}/joint_state (angle, rate, acceleration, torque (N, n)
    rad, rad/s, rad/s², N·m); {prefix}/object (position (N, 3) m, quaternion (N, 4) [w, x, y, z],
    twist (N, 6) [v_C; ω] world axes); {prefix}/grasp_wrench and {prefix}/internal_wrench (wrench
    (N, r, 6) [f; n]); {prefix}/constraint (residual_pos, residual_vel, cond (N,) and manipulability
    (N, r): each arm's √det(A Aᵀ), A its end-effector Jacobian in the scene's rows)."""
    t = res.t
    return [
        _joint_state(prefix, t, res.q, res.qd, res.qdd, res.tau),
        _object_state(prefix, t, res.object_pos, res.object_quat, res.object_twist),
        Series(f"{prefix}/grasp_wrench", "coopsim.Wrenches", t, {"wrench": res.grasp_wrench}),
        Series(f"{prefix}/internal_wrench", "coopsim.Wrenches", t, {"wrench": res.internal_wrench}),
        Series(f"{prefix}/constraint", "coopsim.NativeConstraint", t,
               {"residual_pos": res.residual_pos, "residual_vel": res.residual_vel, "cond": res.cond,
                "manipulability": res.manipulability}),
    ]


def twin_series(tw, prefix: str = "/mujoco") -> list[Series]:
    """Series of a MuJoCo TwinResult: {prefix}/joint_state and {prefix}/object as for the native model,
    {prefix}/constraint (weld_violation (N,) m or rad)."""
    t = tw.t
    return [
        _joint_state(prefix, t, tw.q, tw.qd, tw.qdd, tw.tau),
        _object_state(prefix, t, tw.object_pos, tw.object_quat, tw.object_twist),
        Series(f"{prefix}/constraint", "coopsim.TwinConstraint", t, {"weld_violation": tw.weld_violation}),
    ]


def control_series(rec, t, prefix: str, law: str) -> Series:
    """{prefix}/control of a controller along a run (`coopsim.control.controller.Command` along the run): joint_pd
    (coopsim.JointControl): reference_angle, reference_rate (N, n) rad, rad/s, angle_error (N, n) rad;
    computed_torque (coopsim.ObjectControl): pose_error (N, 6) [m; rad], twist_error (N, 6) [m/s; rad/s]
    world axes; both: command (N, n) N·m before saturation, torque (N, n) N·m applied, saturated (N, n)
    bool."""
    common = {"command": rec.raw, "torque": rec.tau, "saturated": rec.saturated}
    if law == "joint_pd":
        return Series(f"{prefix}/control", "coopsim.JointControl", t,
                      {"reference_angle": rec.q_ref, "reference_rate": rec.qd_ref,
                       "angle_error": rec.angle_error, **common})
    return Series(f"{prefix}/control", "coopsim.ObjectControl", t,
                  {"pose_error": rec.object_error, "twist_error": rec.object_rate_error, **common})


def link_frame_names(model: Model, root: str) -> list[str]:
    """Frame names of every link, arm after arm: f"{root}/{arm.name}/l{i}" (joints stacked as q)."""
    return [f"{root}/{arm.name}/l{i}" for arm in model.arms for i in range(arm.n)]


def _transform(ns: int, child: str, p, quat_wxyz) -> dict:
    w, x, y, z = (float(v) for v in quat_wxyz)
    return {"timestamp": stamp(ns), "parent_frame_id": "world", "child_frame_id": child,
            "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "rotation": {"x": x, "y": y, "z": z, "w": w}}


def native_link_poses(model: Model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Link frame poses of the native model over samples: q (N, n) → positions (N, n, 3) m and
    quaternions (N, n, 4) [w, x, y, z], world, joints stacked as q."""
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
    """foxglove.FrameTransforms on `topic`: per sample, every link frame and the object frame of each
    model given ("native/…" from the link frames of the native q, "mujoco/…" from the twin's link poses),
    children of "world". Samples at the same time (to the ns) share one message."""
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
    """foxglove.SceneUpdate on `topic`, once at t = 0: a cube per link (ArmModel.link_box centred at
    box_pos, axes box_rot, in the link frame) and for the object (ObjectModel.box), locked to its frame, lifetime 0
    (forever); native in blue, mujoco in translucent orange."""
    entities = (_model_entities(model, "native", NATIVE_COLOR) if native else []) + \
               (_model_entities(model, "mujoco", MUJOCO_COLOR) if twin else [])
    return JsonTopic(topic, "foxglove.SceneUpdate", SCENE_UPDATE_SCHEMA, np.zeros(1),
                     ({"deletions": [], "entities": entities},))


def _meta_value(v: Any) -> str:
    """Metadata value as a string: strings as they are, everything else as JSON (floats exact)."""
    if isinstance(v, str):
        return v
    if isinstance(v, np.ndarray):
        v = v.tolist()
    elif isinstance(v, np.generic):
        v = v.item()
    return json.dumps(v)


def _record(d: dict) -> dict[str, str]:
    return {str(k): _meta_value(v) for k, v in d.items()}


def _version(dist: str) -> str:
    try:
        return importlib_metadata.version(dist)
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_metadata(model: Model, res=None, extra: dict | None = None) -> dict[str, dict[str, str]]:
    """MCAP metadata records of a run (all values strings; numbers and arrays as JSON, floats exact):
    scenario (name; file and sha256 when extra["scenario_file"] is given), versions, model (arm names,
    joints per arm, joint names, joint types (revolute / prismatic)), native.integrator, mujoco, validation,
    and for a native result native.initial_projection (dq, dqd, residual before/after, iterations),
    native.integrator_stats and native.warnings (count; "1", "2", …: each warning as JSON,
    `coopsim.forward.diagnostics.RunWarning.as_dict`).
    Other `extra` entries: a dict value is merged into the record of that name (e.g. {"scenario":
    {"file": …, "sha256": …}} adds to the scenario record), anything else goes to record "extra"."""
    extra = dict(extra or {})
    scenario = {"name": model.name}
    file = extra.pop("scenario_file", None)
    if file is not None:
        scenario |= {"file": str(file), "sha256": file_sha256(file)}
    meta = {
        "scenario": scenario,
        "versions": {"coopsim": _version("coopsim"), "mujoco": _version("mujoco"), "numpy": np.__version__,
                     "mcap": _version("mcap"), "python": platform.python_version()},
        "model": _record({"arms": [a.name for a in model.arms], "dofs": [a.n for a in model.arms],
                          "joint_names": joint_labels(model), "joint_types": type_names(model.joint_type),
                          "carrier": model.object.carrier, "duration": model.duration,
                          "gravity": model.gravity}),
        "native.integrator": _record(asdict(model.integrator)),
        "mujoco": _record(asdict(model.mujoco) | {"weld_solref_effective": list(model.mujoco.solref())}),
        "validation": _record(asdict(model.validation)),
    }
    if res is not None:
        p = res.initial
        meta["native.initial_projection"] = _record({
            "dq": p.dq, "dqd": p.dqd, "residual_before": p.residual_before, "residual_after": p.residual_after,
            "iterations": p.iterations})
        meta["native.integrator_stats"] = _record(asdict(res.stats))
        meta["native.warnings"] = _record({"count": len(res.warnings)}
                                          | {str(i + 1): w.as_dict() for i, w in enumerate(res.warnings)})
    rest = {}
    for k, v in extra.items():
        if isinstance(v, dict):
            meta.setdefault(str(k), {}).update(_record(v))
        else:
            rest[str(k)] = _meta_value(v)
    if rest:
        meta["extra"] = rest
    return meta


def write_run_log(path: str | Path, model: Model, native=None, twin=None, extra_series: Sequence = (),
                  metadata_extra: dict | None = None) -> Path:
    """Write a run's MCAP log (`run_log`). Returns the path."""
    return write_mcap(path, *run_log(model, native, twin, extra_series, metadata_extra))


def run_log(model: Model, native=None, twin=None, extra_series: Sequence = (),
            metadata_extra: dict | None = None) -> tuple[list, dict[str, dict[str, str]]]:
    """(streams, metadata) of a run's log: native series (/native/…), twin series (/mujoco/…),
    `extra_series`, /tf and /scene for Foxglove, and the run's metadata (see :func:`run_metadata`)."""
    streams: list = []
    if native is not None:
        streams += simulation_series(native)
    if twin is not None:
        streams += twin_series(twin)
    streams += list(extra_series)
    if native is not None or twin is not None:
        streams += [frame_transforms(model, native, twin), scene_update(model, native is not None, twin is not None)]
    return streams, run_metadata(model, native, metadata_extra)
