"""The rules every YAML text coopsim reads is held to (a scenario file, a sweep file, a `--set` value):
UTF-8 text of at most MAX_FILE_BYTES, one document, no key twice in a mapping, nested at most MAX_DEPTH
levels and at most MAX_NODES values with every alias expanded (a "billion laughs" document is refused
before anything is built). Each failure is one line naming the file, the line and the key.
"""

from __future__ import annotations

import codecs
from pathlib import Path

import yaml
from yaml.events import (
    AliasEvent,
    CollectionEndEvent,
    MappingStartEvent,
    ScalarEvent,
    SequenceStartEvent,
    StreamEndEvent,
)

from coopsim.core.errors import ScenarioError, one_line

MAX_FILE_BYTES = 64 << 20       # a scenario or a torque CSV
MAX_DEPTH = 32                  # YAML nesting (the bundled scenarios use 8)
MAX_NODES = 1_000_000           # YAML values with every alias expanded


def read_text(path: Path, fail) -> str:
    """The text of a UTF-8 file (a byte-order mark is skipped) of at most MAX_FILE_BYTES.

    Args:
        path: the file.
        fail: called as fail(reason) with a one-line reason (missing or unreadable, the size, or the first
            byte that is not UTF-8 and its line) when the file breaks a rule; expected to raise.

    Returns:
        str: the decoded text.
    """
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            fail(f"{size / 2 ** 20:.0f} MiB: larger than the {MAX_FILE_BYTES >> 20} MiB a file may hold")
        raw = path.read_bytes()
    except OSError as exc:
        fail(f"cannot be read ({one_line(exc.strerror or exc)})")
    if raw.startswith(codecs.BOM_UTF8):
        raw = raw[len(codecs.BOM_UTF8):]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        fail(f"not UTF-8 text: byte 0x{raw[exc.start]:02x} on line {line} is not UTF-8 (save the file as UTF-8)")


_YAML_LOADER = yaml.CSafeLoader if getattr(yaml, "__with_libyaml__", False) else yaml.SafeLoader
_MERGE = "tag:yaml.org,2002:merge"


def load_yaml(path: Path):
    """The data of a YAML file, read defensively.

    The file must be UTF-8 text of at most MAX_FILE_BYTES, one document, no key twice in a mapping, nested
    at most MAX_DEPTH levels and holding at most MAX_NODES values with every alias expanded (a "billion
    laughs" document is refused before anything is built). A first pass over the parser's events checks
    all that (iteratively: no recursion to overflow); then the document is composed and constructed
    (libyaml's parser and composer when present, PyYAML's safe constructor).

    Args:
        path: the YAML file.

    Returns:
        Any: the document's data (dicts, lists, scalars), None for an empty document.

    Raises:
        ScenarioError: one line naming the file (and the line, and the key) when a rule is broken or the
            YAML is malformed.
    """
    def fail(reason: str):
        raise ScenarioError(f"{path}: {reason}")

    return parse_yaml_text(read_text(path, fail), fail)


def parse_yaml_text(text: str, fail):
    """The data of YAML text under the rules of `load_yaml`, e.g. a `--set` value (`coopsim.io.overrides`).

    The rules: one document, no key twice, depth, expanded size; libyaml when present.

    Args:
        text: the YAML text.
        fail: called as fail(reason) with a one-line reason (the line, and the key) when a rule is broken
            or the YAML is malformed; expected to raise.

    Returns:
        Any: the document's data (dicts, lists, scalars), None for an empty document.
    """
    try:
        _check_events(text, fail)
        loader = _YAML_LOADER(text)
        try:
            node = loader.get_single_node()
            return None if node is None else loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        context = getattr(exc, "context", None)
        fail(f"malformed YAML{at}: " + " ".join((problem + (f" ({context})" if context else "")).split()))


class _Open:
    """A collection being read in `_check_events`: its path, expanded size and height so far; for a
    mapping the keys seen (key -> line) and whether a key comes next."""

    __slots__ = ("path", "size", "height", "anchor", "keys", "key_next", "label", "index")

    def __init__(self, path: str, anchor, mapping: bool):
        self.path, self.size, self.height, self.anchor = path, 1, 1, anchor
        self.keys, self.key_next, self.label, self.index = ({} if mapping else None), True, "?", 0

    def child_path(self) -> str:
        if self.keys is None:
            return f"{self.path}[{self.index}]"
        return "?" if self.key_next else (f"{self.path}.{self.label}" if self.path else self.label)


def _check_events(text: str, fail) -> None:
    """Depth, expanded size and duplicate keys of a YAML document, from its parse events."""
    loader = _YAML_LOADER(text)
    try:
        stack: list[_Open] = []
        anchors: dict = {}          # anchor -> (expanded size, height)
        while True:
            ev = loader.get_event()
            line = ev.start_mark.line + 1 if ev.start_mark is not None else 0
            if isinstance(ev, (MappingStartEvent, SequenceStartEvent)):
                if len(stack) >= MAX_DEPTH:
                    fail(f"line {line}: nested more than {MAX_DEPTH} levels deep")
                path = stack[-1].child_path() if stack else ""
                stack.append(_Open(path, ev.anchor, isinstance(ev, MappingStartEvent)))
                continue
            if isinstance(ev, CollectionEndEvent):
                done = stack.pop()
                size, height = done.size, done.height
                if done.anchor is not None:
                    anchors[done.anchor] = (size, height)
            elif isinstance(ev, ScalarEvent):
                size, height = 1, 1
                if ev.anchor is not None:
                    anchors[ev.anchor] = (1, 1)
            elif isinstance(ev, AliasEvent):
                size, height = anchors.get(ev.anchor, (1, 1))   # undefined: the composer says so
                if len(stack) + height > MAX_DEPTH + 1:   # collections nested, the alias's own included
                    fail(f"line {line}: this alias nests its value more than {MAX_DEPTH} levels deep")
            elif isinstance(ev, StreamEndEvent):
                return
            else:               # stream and document start, document end
                continue
            if not stack:
                continue
            parent = stack[-1]
            parent.size += size
            parent.height = max(parent.height, height + 1)
            if parent.size > MAX_NODES:
                fail(f"line {line}: aliases expand {parent.path or 'the document'} to more than "
                     f"{MAX_NODES:,} values (at most {MAX_NODES:,})")
            if parent.keys is None:
                parent.index += 1
            elif parent.key_next:
                parent.key_next, parent.label = False, "?"
                if isinstance(ev, ScalarEvent):
                    parent.label = ev.value
                    tag = (ev.tag if ev.tag not in (None, "!")
                           else loader.resolve(yaml.ScalarNode, ev.value, ev.implicit))
                    if tag != _MERGE:
                        key = (tag, ev.value)
                        if key in parent.keys:
                            field = f"{parent.path}.{ev.value}" if parent.path else ev.value
                            fail(f"{field}: duplicate key (lines {parent.keys[key]} and {line}: the second would "
                                 f"silently replace the first)")
                        parent.keys[key] = line
            else:
                parent.key_next = True
    finally:
        loader.dispose()
