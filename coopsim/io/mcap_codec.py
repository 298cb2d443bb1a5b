"""MCAP files of JSON messages described by JSON Schemas (draft 2020-12), viewable in Foxglove: the
format every coopsim log is written in.

A :class:`Series` is a set of arrays sampled at times t (N,) s; :func:`write_mcap` writes one JSON
message per sample, :func:`read_mcap` gives the arrays back bit for bit. A :class:`JsonTopic` carries
ready-made JSON messages with a fixed schema (the Foxglove 3D view, `coopsim.io.foxglove`).

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

import io
import json
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from coopsim.core.errors import CoopsimError
from coopsim.io.atomic import atomic_path

# The log format's own names (written into every log, and SERIES_COMMENT read back to find a series):
# identifiers of the format, not module paths, so they stay as the first logs wrote them.


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


@dataclass(frozen=True, eq=False)
class Series:
    """Arrays sampled over time, written as one JSON message per sample on `topic`.

    Floats are stored as float64, integers as int64: read back with those dtypes. Field names must not be
    "timestamp" or "t". All series sharing a schema_name must have the same fields, dtypes, shapes.

    Attributes:
        topic: the MCAP topic (channel) the messages are written on.
        schema_name: the name the series' JSON Schema is registered under.
        t: (N,) s, the sample times, finite, >= 0.
        fields: name → array (N, ...) of floats, integers or booleans, one row per sample.
    """

    topic: str
    schema_name: str
    t: np.ndarray
    fields: dict[str, np.ndarray]


@dataclass(frozen=True, eq=False)
class JsonTopic:
    """Ready-made JSON messages on `topic`, with a fixed JSON Schema.

    Attributes:
        topic: the MCAP topic (channel) the messages are written on.
        schema_name: the name `schema` is registered under.
        schema: the messages' JSON Schema (a dict).
        t: (N,) s, the log times, finite, >= 0: messages[k] is logged at t[k].
        messages: N JSON-serialisable dicts.
    """

    topic: str
    schema_name: str
    schema: dict
    t: np.ndarray
    messages: tuple[dict, ...]


@dataclass(frozen=True, eq=False)
class LogData:
    """A log read back (`read_mcap`), or built in memory as it would be read back (`log_data`).

    Attributes:
        metadata: MCAP metadata record name → {key: value}, strings.
        topics: series topic → {"t": (N,) s, field: (N, ...)} (bit-identical to what was written).
        schemas: every topic → its schema name.
        messages: every non-series topic (e.g. /tf, /scene) → its decoded JSON messages in file order.
    """

    metadata: dict[str, dict[str, str]]
    topics: dict[str, dict[str, np.ndarray]]
    schemas: dict[str, str]
    messages: dict[str, list[dict]] = field(default_factory=dict)


def time_ns(t: np.ndarray) -> np.ndarray:
    """Times in seconds to integer nanoseconds, rounded to nearest.

    Args:
        t: (N,) s, the times.

    Returns:
        np.ndarray: (N,) int64, the times in ns.
    """
    return np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)


def stamp(ns: int) -> dict[str, int]:
    """Integer nanoseconds to a Foxglove/ROS time {"sec", "nsec"}.

    Args:
        ns: the time, integer nanoseconds, >= 0.

    Returns:
        dict[str, int]: {"sec": whole seconds, "nsec": the remaining nanoseconds, 0 to 999999999}.
    """
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def time_schema(description: str) -> dict:
    """JSON Schema of a Foxglove/ROS time object {"sec", "nsec"}, the form `stamp` writes.

    Args:
        description: the schema's description text.

    Returns:
        dict: an object schema with integer sec >= 0 and nsec in 0 to 999999999, both required.
    """
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
    """JSON Schema (draft 2020-12) of the messages of series `s`, from its field dtypes and shapes.

    Args:
        s: the series.

    Returns:
        dict: the schema titled s.schema_name: "timestamp" (time object), "t" (number, s) and one property
            per field (number, array of numbers, or array of {"row": …} objects), all required; its "$comment"
            is SERIES_COMMENT, which marks a series when the log is read back.
    """
    props = {"timestamp": time_schema("Sample time, rounded to nanoseconds"),
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
    """The string a non-finite float is written as in a log.

    Args:
        x: a non-finite float (nan, +inf or -inf).

    Returns:
        str: "NaN", "Infinity" or "-Infinity".
    """
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
    """Write streams and MCAP metadata records to `path`, atomically.

    Messages are ordered by time, then by the order of the streams, then by sample.

    Args:
        path: the MCAP file written (its folder is created if missing).
        series: the Series or JsonTopic streams, one topic each.
        metadata: MCAP metadata records, name → {key: value}, strings; None: none.

    Returns:
        Path: the path written.

    Raises:
        LogError: a malformed series or JSON topic, a message JSON cannot hold, a topic given twice, two
            topics of one schema name with different schemas, or metadata keys or values that are not strings.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        _write_all(f, series, metadata or {})
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def log_data(streams: Sequence[Series | JsonTopic], metadata: dict[str, dict[str, str]] | None = None,
             messages: bool = True) -> LogData:
    """The LogData `read_mcap` gives back for a log written by `write_mcap(path, streams, metadata)`, in memory.

    It is what the commands draw their figures from while the file is written. The streams are checked as
    `write_mcap` checks them (JSON topics only when their messages are kept); tests/io/test_log.py compares
    it with the file read back.

    Args:
        streams: the Series or JsonTopic streams, one topic each.
        metadata: MCAP metadata records, name → {key: value}, strings; None: none.
        messages: False: the JSON topics' messages are left out (e.g. the thousands of /tf transforms no
            figure draws); their schema names are still given.

    Returns:
        LogData: series as float64 / int64 / bool arrays, JSON topics' messages as JSON decodes them.

    Raises:
        LogError: a malformed series, or (with `messages`) a malformed JSON topic or a message JSON cannot
            hold.
    """
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
    """Read a log written by :func:`write_mcap`.

    The whole file is read in order, checking the magic at both ends, every record's length, the data
    section's CRC (where the log carries one), each chunk's, the summary's, and that nothing follows the end.

    Args:
        path: the MCAP file.

    Returns:
        LogData: series topics as arrays (bit-identical), other JSON topics as decoded messages, metadata
            records and schema names.

    Raises:
        UnreadableLogError: naming the file, when it cannot be read or is not a whole, intact MCAP log of
            JSON messages.
    """
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
