"""Scenario overrides: `--set PATH=VALUE` on the command line, the axes and fixed settings of a sweep.

An override replaces one field of the parsed scenario data (the dict `coopsim.io.yaml_rules.load_yaml`
returns) before the model is built, so the result is validated exactly like a file that says so, with
the same one-line errors (`coopsim.io.scenario.model_from_dict`). No I/O here.

PATH addresses a field as the error lines name it: mapping keys joined by dots, list items by a
0-based index in brackets — `object.box.density`, `arms[1].motors.stall_torque[0]`,
`inverse.object_motion.waypoints[2].position`. Every key and index before the last must exist in the
data; the last key of a mapping may be new (an optional field or section the file leaves out, set whole:
`inverse.optimize={control_points: 3}`; the validator then checks that it is one), a list index must be
within the list. VALUE is YAML (`0.25`, `[0.1, 0, 0]`,
`{position: [0.1, 0, 0]}`, `rk4`), read with the scenario file's rules (`coopsim.io.yaml_rules.parse_yaml_text`).
"""

from __future__ import annotations

import copy
import re
from typing import Any, Iterable

from coopsim.core.errors import CoopsimError
from coopsim.io.yaml_rules import parse_yaml_text

_KEY = re.compile(r"[^.\[\]=\s]+")
_INDEX = re.compile(r"\[(\d+)\]")


class OverrideError(CoopsimError):
    """A `--set` that cannot be applied: malformed, or a path that does not lead to a field."""


def parse_path(path: str, where: str = "--set") -> tuple[str | int, ...]:
    """The keys (str) and list indices (int) of PATH.

    E.g. 'arms[1].motors.stall_torque[0]' → ('arms', 1, 'motors', 'stall_torque', 0).

    Args:
        path: the field path (keys joined by '.', list items as [INDEX]).
        where: what the error line names first (the option, e.g. "--set").

    Returns:
        tuple[str | int, ...]: the keys and indices in order.

    Raises:
        OverrideError: naming `where`, PATH and the character where it is malformed.
    """
    parts: list[str | int] = []
    pos = 0
    while True:
        m = _KEY.match(path, pos)
        if m is None:
            raise OverrideError(f"{where} {path}: malformed path at character {pos + 1} (expected a key: "
                                f"keys joined by '.', list items as [INDEX], e.g. arms[1].motors.stall_torque[0])")
        parts.append(m.group())
        pos = m.end()
        while (m := _INDEX.match(path, pos)) is not None:
            parts.append(int(m.group(1)))
            pos = m.end()
        if pos == len(path):
            return tuple(parts)
        if path[pos] != ".":
            raise OverrideError(f"{where} {path}: malformed path at character {pos + 1} ({path[pos]!r}: expected "
                                f"'.', '[INDEX]' or the end)")
        pos += 1


def format_path(parts: Iterable[str | int]) -> str:
    """The inverse of `parse_path`: ('arms', 1, 'name') → 'arms[1].name'.

    Args:
        parts: keys (str) and list indices (int).

    Returns:
        str: the path ("" for no parts).
    """
    text = ""
    for p in parts:
        text += f"[{p}]" if isinstance(p, int) else (f".{p}" if text else p)
    return text


def parse_assignment(text: str, where: str = "--set") -> tuple[str, Any]:
    """'PATH=VALUE' → (PATH, the YAML value).

    Args:
        text: the assignment; PATH is stripped of surrounding blanks, VALUE is YAML read with the scenario
            file's rules.
        where: what the error line names first (the option, e.g. "--set").

    Returns:
        tuple[str, Any]: PATH (checked with `parse_path`) and the parsed value.

    Raises:
        OverrideError: naming `where`, when there is no '=' or no PATH, PATH is malformed, or VALUE is
            not valid YAML by those rules.
    """
    path, eq, value = text.partition("=")
    path = path.strip()
    if not eq or not path:
        raise OverrideError(f"{where} {text}: expected PATH=VALUE, e.g. object.box.density=2700")
    parse_path(path, where)

    def fail(reason: str):
        raise OverrideError(f"{where} {path}: value {value!r}: {reason}")

    return path, parse_yaml_text(value, fail)


def apply_overrides(data: Any, overrides: Iterable[tuple[str, Any]], where: str = "--set") -> Any:
    """A copy of scenario data `data` with each (PATH, value) of `overrides` set in turn.

    A later override of the same field wins; `data` itself is not changed.

    Args:
        data: the parsed scenario data (nested dicts and lists, as `load_yaml` returns).
        overrides: (PATH, value) pairs, e.g. from `parse_assignment`; each value is copied in.
        where: what the error line names first (the option, e.g. "--set").

    Returns:
        Any: the overridden deep copy of `data`.

    Raises:
        OverrideError: naming `where`, PATH and the first key or index that is missing (with the keys or
            the length there) when a path does not lead to a field, or a malformed PATH.
    """
    data = copy.deepcopy(data)
    for path, value in overrides:
        parts = parse_path(path, where)
        node = data
        for depth, part in enumerate(parts):
            last = depth == len(parts) - 1
            here = format_path(parts[:depth]) or "the scenario"
            if isinstance(part, int):
                if not isinstance(node, list):
                    raise OverrideError(f"{where} {path}: {here} is not a list (it holds {_kind(node)}), so "
                                        f"[{part}] does not exist")
                if part >= len(node):
                    raise OverrideError(f"{where} {path}: {here} has {len(node)} items, so [{part}] does not exist")
            else:
                if not isinstance(node, dict):
                    raise OverrideError(f"{where} {path}: {here} is not a mapping (it holds {_kind(node)}), so "
                                        f"it has no key {part!r}")
                if part not in node and not last:
                    keys = ", ".join(str(k) for k in node) or "none"
                    whole = format_path(parts[:depth + 1])
                    raise OverrideError(f"{where} {path}: {here} has no key {part!r} (its keys: {keys}; a section "
                                        f"the file leaves out is set whole, e.g. {whole}={{...}})")
            if last:
                node[part] = copy.deepcopy(value)
            else:
                node = node[part]
    return data


def _kind(v: Any) -> str:
    return "a mapping" if isinstance(v, dict) else "a list" if isinstance(v, list) else repr(v)[:40]
