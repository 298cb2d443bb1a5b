"""Content digests: a value's identity by what it holds, for reusing a result computed from the same
content (a sweep's points share the trajectory their axes do not touch)."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np


class _NotByValue(Exception):
    """The value holds something with no content to digest (a Python callable, an open object)."""


def content_digest(value, skip: frozenset[str] = frozenset()) -> str | None:
    """SHA-256 of a value's content: dataclasses and NamedTuples by field, arrays by dtype, shape and bytes,
    numbers and strings by type and repr.

    Args:
        value: the value (a Model, a tuple of them, arrays, numbers, strings, None).
        skip: dotted field paths left out, from the value's root (e.g. "inverse.payload_position": that
            field of the value's `inverse` field).

    Returns:
        str | None: the hex digest; None when the value holds something that has no content to digest
        (a callable, such as a Python torque function): such a value is never taken for another.
    """
    h = hashlib.sha256()
    try:
        _feed(h, value, "", skip)
    except _NotByValue:
        return None
    return h.hexdigest()


def _feed(h, value, path: str, skip: frozenset[str]) -> None:
    if value is None or isinstance(value, (bool, int, float, str, complex, np.generic)):
        h.update(f"{type(value).__name__}:{value!r};".encode())
    elif isinstance(value, np.ndarray):
        if value.dtype == object:
            raise _NotByValue(path)
        h.update(f"array:{value.dtype.str}:{value.shape};".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        _fields(h, value, [f.name for f in dataclasses.fields(value)], path, skip)
    elif isinstance(value, tuple) and hasattr(value, "_fields"):
        _fields(h, value, list(value._fields), path, skip)
    elif isinstance(value, (tuple, list)):
        h.update(f"{type(value).__name__}:{len(value)}[".encode())
        for i, item in enumerate(value):
            _feed(h, item, f"{path}[{i}]", skip)
        h.update(b"]")
    elif isinstance(value, dict):
        h.update(f"dict:{len(value)}{{".encode())
        for key in sorted(value, key=repr):
            _feed(h, key, path, skip)
            _feed(h, value[key], f"{path}.{key}", skip)
        h.update(b"}")
    else:
        raise _NotByValue(path)


def _fields(h, value, names: list[str], path: str, skip: frozenset[str]) -> None:
    h.update(f"{type(value).__module__}.{type(value).__qualname__}(".encode())
    for name in names:
        sub = f"{path}.{name}" if path else name
        if sub not in skip:
            h.update(f"{name}=".encode())
            _feed(h, getattr(value, name), sub, skip)
    h.update(b")")
