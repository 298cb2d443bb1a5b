"""Fuzzing every command that reads a scenario, a torque CSV or a log.

A catalogue of mutation generators over the bundled scenarios (wrong types, booleans and quoted numbers
where numbers belong, missing and unknown keys, non-finite and extreme values, inconsistent sizes,
work that cannot fit, broken CSVs, malformed YAML, non-UTF-8 bytes, deep nesting, alias bombs,
duplicate keys, path-escaping names, loops that cannot close, capacity without motors) and over
broken MCAP logs. `test_fuzz_every_reader` draws cases from it with a fixed seed (a stratified draw:
every class its share of `DRAWS`, 328 cases) and runs each through the CLI in this process (`coopsim.cli.main`)
on a command picked by the same seed, in a fresh folder. Every case is malformed, so every one must
end the same way: exit status 2, exactly one line on stderr (``coopsim: error: …``) naming the field
(`arms[0].links[1].box.density`) or the file, no traceback, and no file written anywhere (no --out
folder, nothing next to the inputs).

The targeted tests below it pin each finding of the issue.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import random
import re
import signal
import threading
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import SCENARIOS

SEED = 9
DRAWS = 330
CASE_SECONDS = 20   # a case still running after this long counts as a hang

BASES = {p.stem: p.read_text(encoding="utf-8") for p in sorted(SCENARIOS.glob("*.yaml"))}
DATA = {name: yaml.safe_load(text) for name, text in BASES.items()}

# commands that read a scenario; "{s}" is the scenario file, "{o}" the --out folder
SCENARIO_COMMANDS = {
    "mjcf": ["mjcf", "{s}", "--out", "{o}"],
    "simulate": ["simulate", "{s}"],
    "run": ["run", "{s}", "--out", "{o}"],
    "validate": ["validate", "{s}"],
    "inverse": ["inverse", "{s}", "--out", "{o}", "--method", "paper", "--no-curve"],
    "capacity": ["capacity", "{s}", "--out", "{o}", "--no-lp", "--no-optimise"],
    "bench": ["bench", "{s}", "--quick", "--out", "{o}"],
}
WITH_DURATION = ("simulate", "run", "validate", "inverse", "capacity")
SHORT = ["--duration", "0.02"]   # keeps a wrongly accepted case cheap (cases about durations go without)

TOKEN = "zzfuzztokenzz"         # a value replaced by raw YAML text after dumping
DUP = "zzfuzzdupzz"             # a key renamed after dumping, to duplicate its neighbour


@dataclass
class Case:
    cls: str                    # catalogue class
    what: str                   # what was done, for failure messages
    names: str | None           # text the error line must contain: the field (None: the file name)
    scenario: bytes | None = None              # the scenario file's bytes (None: no scenario)
    files: dict = field(default_factory=dict)   # other input files: name -> bytes (None: a folder)
    argv: list | None = None    # a fixed command line ("{s}", "{o}", "{f:NAME}" filled in)
    commands: tuple = tuple(SCENARIO_COMMANDS)  # scenario commands it may run on
    short: bool = True          # add --duration 0.02 on the commands that have it
    extra_args: list = field(default_factory=list)   # instead of that: these arguments


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------

def fmt(path) -> str:
    """A key path as the reader names it: arms[0].links[1].box.density."""
    out = ""
    for k in path:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out


def is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def is_numeric_tree(x) -> bool:
    return is_number(x) or (isinstance(x, list) and len(x) > 0 and all(is_numeric_tree(v) for v in x))


def walk(node, path=()):
    """(path, value, kind) of every node: mapping, list, array (numbers, nested), bools, number,
    bool, string."""
    if isinstance(node, dict):
        yield path, node, "mapping"
        for k, v in node.items():
            yield from walk(v, path + (k,))
    elif isinstance(node, list):
        if is_numeric_tree(node):
            yield path, node, "array"
        elif node and all(isinstance(v, bool) for v in node):
            yield path, node, "bools"
        else:
            yield path, node, "list"
            for i, v in enumerate(node):
                yield from walk(v, path + (i,))
    elif isinstance(node, bool):
        yield path, node, "bool"
    elif is_number(node):
        yield path, node, "number"
    elif isinstance(node, str):
        yield path, node, "string"


def get(data, path):
    for k in path:
        data = data[k]
    return data


def put(data, path, value):
    """A deep copy of data with value at path."""
    data = clone(data)
    if not path:
        return value
    get(data, path[:-1])[path[-1]] = value
    return data


def delete(data, path):
    data = clone(data)
    del get(data, path[:-1])[path[-1]]
    return data


def array_elements(a, path=()):
    """Index paths of the numbers in a nested numeric list."""
    if isinstance(a, list):
        for i, v in enumerate(a):
            yield from array_elements(v, path + (i,))
    else:
        yield path


def dump(data, raw: str | None = None) -> bytes:
    """YAML text of data (a line per top-level key, flow style below: what yaml.safe_dump would give,
    written directly, as its representer costs milliseconds a file); TOKEN, a value, replaced by the
    raw YAML text `raw`."""
    if isinstance(data, dict):
        text = "".join(f"{_flow(k)}: {_flow(v)}\n" for k, v in data.items())
    else:
        text = _flow(data) + "\n"
    if raw is not None:
        assert f'"{TOKEN}"' in text
        text = text.replace(f'"{TOKEN}"', raw)
    return text.encode("utf-8")


def _flow(x) -> str:
    if isinstance(x, dict):
        return "{" + ", ".join(f"{_flow(k)}: {_flow(v)}" for k, v in x.items()) + "}"
    if isinstance(x, list):
        return "[" + ", ".join(_flow(v) for v in x) + "]"
    if x is None:
        return "null"
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, int):
        return str(x)
    if isinstance(x, float):
        if math.isnan(x):
            return ".nan"
        if math.isinf(x):
            return ".inf" if x > 0 else "-.inf"
        r = repr(x)
        if "e" in r:   # YAML 1.1 floats need a dot and a signed exponent: 1.0e-05
            m, e = r.split("e")
            r = f"{m if '.' in m else m + '.0'}e{e if e[0] in '+-' else '+' + e}"
        return r
    if isinstance(x, datetime.date):
        return x.isoformat()
    return json.dumps(x, ensure_ascii=False)


def clone(x):
    """A deep copy of parsed YAML data (dicts, lists, scalars), faster than copy.deepcopy."""
    if isinstance(x, dict):
        return {k: clone(v) for k, v in x.items()}
    if isinstance(x, list):
        return [clone(v) for v in x]
    return x


def expected(path) -> str:
    """What the error must name when the value at `path` is bad: the path (a torque table's times
    can be reported through their values, so there the table)."""
    if len(path) >= 2 and path[-1] == "time" and path[-2] == "table":
        return fmt(path[:-1])
    return fmt(path)


# keys whose value must be positive (numbers or arrays of them)
POSITIVE = {"density", "length", "size", "cross_section", "mass", "duration", "rtol", "atol", "step",
            "max_step", "output_dt", "projection_tol", "max_initial_correction", "rank_tol", "timestep",
            "tolerance", "iterations", "object_mass_scale", "stall_torque", "no_load_speed", "energy_weights",
            "weld_solref", "nonsqueezing_masses"}
INF_ALLOWED = {"stall_torque", "no_load_speed"}   # +inf: no motor limit


def leaves(kinds):
    """[(base, path, value, kind)] over every bundled scenario."""
    return [(b, p, v, k) for b, d in DATA.items() for p, v, k in walk(d) if k in kinds and p]


# ------------------------------------------------------------------------------------------------
# the catalogue: each class is a list of specs (cheap tuples) and a builder spec -> Case
# ------------------------------------------------------------------------------------------------

WRONG = {
    "number": ["five", True, [1.0, 2.0], {"value": 1.0}, "", datetime.date(2001, 1, 1)],
    "array": ["abc", {"x": 1.0}, True],
    "string": [1.5, True, ["a", "b"], {"a": "b"}],
    "bools": ["abc", [1, 0, 0], 1.0],
    "mapping": [[1, 2], "abc", 3.5],
    "list": [{"a": 1}, "abc", 3.5],
}


def specs_wrong_type():
    return [(b, p, w) for b, p, v, k in leaves(WRONG) for w in WRONG[k]]


def build_wrong_type(spec):
    b, p, w = spec
    if p == ("object", "grasps") and w == ["a", "b"]:
        w = [1.5, 2.5]
    return Case("wrong_type", f"{b}: {fmt(p)} = {w!r}", expected(p), dump(put(DATA[b], p, w)))


def specs_element(kinds=("array",)):
    return [(b, p, e) for b, p, v, k in leaves(kinds) for e in array_elements(v)]


def specs_bool():
    return ([(b, p, (), x) for b, p, v, k in leaves({"number"}) for x in (True, False)]
            + [(b, p, e, x) for b, p, e in specs_element() for x in (True, False)])


def build_element(cls, raw_values=None):
    def build(spec):
        b, p, e, x = spec
        value = TOKEN if raw_values else x
        data = put(DATA[b], p + e, value)
        return Case(cls, f"{b}: {fmt(p)}{list(e) if e else ''} = {x}", expected(p), dump(data, x if raw_values else None))
    return build


def specs_quoted():
    return ([(b, p, (), f"'{v}'") for b, p, v, k in leaves({"number"})]
            + [(b, p, e, f"'{get(DATA[b], p + e)}'") for b, p, e in specs_element()])


def _skip_inf(p, raw):
    return p[-1] in INF_ALLOWED and raw in (".inf", ".Inf", "1.0e+400")


NONFINITE = [".nan", ".NaN", ".inf", "-.inf", ".Inf", "1.0e+400", "-1.0e+400"]


def specs_nonfinite():
    out = [(b, p, (), x) for b, p, v, k in leaves({"number"}) for x in NONFINITE]
    out += [(b, p, e, x) for b, p, e in specs_element() for x in NONFINITE]
    return [s for s in out if not _skip_inf(s[1], s[3])]


EXTREME = ["1.0e+308", "-1.0e+308", "1.0e+20", "-3.0e+15", "1" + "0" * 400, "-1" + "0" * 30]


def specs_extreme():
    out = [(b, p, (), x) for b, p, v, k in leaves({"number"}) for x in EXTREME]
    out += [(b, p, e, x) for b, p, e in specs_element() for x in EXTREME]
    out += [(b, p, (), x) for b, p, v, k in leaves({"number"}) if p[-1] in POSITIVE for x in ("0", "-1.0", "-1.0e-300")]
    out += [(b, p, e, x) for b, p, e in specs_element() if p[-1] in POSITIVE for x in ("0", "-2.5")]
    return out


def _required(data, path) -> bool:
    """Keys that have no default (deleting one must be refused)."""
    k = path[-1]
    parent = get(data, path[:-1])
    if len(path) == 1:
        return k in ("duration", "arms", "object")
    if path[0] == "arms" and len(path) == 3:
        return k in ("links", "initial")
    if path[0] == "arms" and len(path) == 4 and path[2] == "initial":
        return k in ("angles", "angles_deg")
    if path[0] == "arms" and len(path) == 5 and path[2] == "links":
        return k in ("box", "inertial")
    if path[0] == "arms" and len(path) == 6 and path[4] == "box":
        return k == "density" or (k in ("length", "cross_section") and "size" not in parent)
    if path[0] == "arms" and path[2] == "torque" and k in ("constant", "time", "values", "table"):
        return True
    if path[0] == "object" and len(path) == 2:
        return k in ("grasps", "box", "inertial")
    if path[0] == "object" and len(path) == 3 and path[1] == "box":
        return True
    if path[:2] == ("object", "grasps") and len(path) == 4:
        return k in ("arm", "position")
    if path[:2] == ("object", "pose") and len(path) == 3:
        return k == "position"
    if path[:2] == ("inverse", "object_motion"):
        return k == "waypoints" or (len(path) == 5 and k in ("time", "position"))
    return False


def specs_missing():
    out = []
    for b, d in DATA.items():
        for p, v, k in walk(d):
            if p and isinstance(p[-1], str) and _required(d, p):
                out.append((b, p))
    return out


def build_missing(spec):
    b, p = spec
    names = fmt(p[:-1] + ("angles",)) if p[-1] == "angles_deg" else expected(p)
    if p[-1] == "inertial" or p[-1] == "table":
        names = fmt(p[:-1])
    return Case("missing_key", f"{b}: without {fmt(p)}", names, dump(delete(DATA[b], p)))


UNKNOWN = ["colour", "densty", "Duration", "x-note", "links_", 7, None, True]


def specs_unknown():
    return [(b, p, key) for b, d in DATA.items() for p, v, k in walk(d) if k == "mapping" for key in UNKNOWN
            if p or isinstance(key, str)]


def build_unknown(spec):
    b, p, key = spec
    data = clone(DATA[b])
    get(data, p)[key] = 1.0
    names = fmt(p + (key,)) if isinstance(key, str) else (fmt(p) or "")
    return Case("unknown_key", f"{b}: {fmt(p)} gets {key!r}", names, dump(data))


def specs_sizes():
    out = []
    for b, p, v, k in leaves({"array"}):
        out += [(b, p, "drop"), (b, p, "append")]
        if isinstance(v[0], list):
            out.append((b, p, "ragged"))
    for b, d in DATA.items():
        out += [(b, ("arms", i, "links"), "drop link") for i in range(len(d["arms"]))]
        if isinstance(d["object"]["grasps"], list):
            out += [(b, ("object", "grasps"), "drop grasp"), (b, ("arms",), "extra arm")]
    return out


def build_sizes(spec):
    b, p, how = spec
    data = clone(DATA[b])
    a = get(data, p)
    names = expected(p)
    if how == "drop":
        a.pop()
    elif how == "append":
        a.append(clone(a[-1]) if isinstance(a[0], list) else 0.5)
    elif how == "ragged":
        a[-1] = a[-1][:-1]
    elif how == "drop link":
        a.pop()
        names = fmt(p[:-1] + ("initial", "angles"))
    elif how == "drop grasp":
        a.pop()
    elif how == "extra arm":
        extra = clone(a[0])
        extra["name"] = "extra"
        a.append(extra)
        names = "object.grasps"
    return Case("sizes", f"{b}: {fmt(p)} {how}", names, dump(data))


def specs_work():
    out = []
    for b, d in DATA.items():
        out += [(b, ("duration",), x, "duration") for x in (1.0e7, 2.0e8, 1.0e12, 1e308)]
        out += [(b, ("integrator", "output_dt"), x, "integrator.output_dt") for x in (1e-9, 1e-12, 1e-300)]
        out += [(b, ("integrator", "max_step"), x, "integrator.max_step") for x in (1e-9, 1e-13)]
        out += [(b, ("integrator", "step"), x, "integrator.step") for x in (1e-9, 1e-13)]
        out += [(b, ("mujoco", "timestep"), x, "mujoco.timestep") for x in (1e-10, 1e-14)]
        out += [(b, ("mujoco", "iterations"), x, "mujoco.iterations") for x in (1e12, 10 ** 12, 2 ** 31, 10 ** 30)]
        if "inverse" in d:
            out += [(b, ("inverse", "object_motion", "output_dt"), x, "inverse.object_motion.output_dt")
                    for x in (1e-9, 1e-12)]
        out += [(b, "--duration", x, "--duration") for x in ("inf", "nan", "-1", "0", "1e308", "1e12", "-inf",
                                                              "1e7", "0.0", "-0", "-1e-300")]
    return out


def build_work(spec):
    b, p, x, names = spec
    if p == "--duration":
        return Case("work", f"{b}: --duration {x}", names, BASES[b].encode(), commands=WITH_DURATION,
                    short=False, extra_args=[f"--duration={x}"])
    data = clone(DATA[b])
    sec = data.setdefault(p[0], {})
    if p[-1] == "step":
        sec["method"] = "rk4"
    get(data, p[:-1])[p[-1]] = x
    return Case("work", f"{b}: {fmt(p)} = {x!r}", names, dump(data), short=False)


def _csv_base(b):
    """(scenario bytes with arms[0].torque = {csv: tq.csv}, joints of arm 0)."""
    data = clone(DATA[b])
    data["arms"][0]["torque"] = {"csv": "tq.csv"}
    return dump(data), len(data["arms"][0]["links"])


def _csv(n, rows):
    head = "t," + ",".join(f"tau{j}" for j in range(n))
    return (head + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n").encode()


CSV_BREAKS = ["nan time", "inf value", "-inf time", "1e400 value", "abc value", "true value", "empty field",
              "short row", "long row", "header only", "empty file", "comments only", "no header", "decreasing",
              "duplicate time", "latin-1", "invalid utf-8", "utf-16", "huge field", "nul byte", "missing file",
              "folder", "nul in name", "1e20 value", "semicolons"]


def specs_csv():
    return [(b, how) for b in DATA for how in CSV_BREAKS]


def build_csv(spec):
    b, how = spec
    scen, n = _csv_base(b)
    rows = [[0.0] + [0.1] * n, [1.0] + [0.2] * n, [2.0] + [0.0] * n]
    files = {}
    good = _csv(n, rows)

    def with_row(i, j, v):
        r = clone(rows)
        r[i][j] = v
        return _csv(n, r)

    content = {
        "nan time": lambda: with_row(1, 0, "nan"), "inf value": lambda: with_row(1, 1, "inf"),
        "-inf time": lambda: with_row(2, 0, "-inf"), "1e400 value": lambda: with_row(0, 1, "1e400"),
        "abc value": lambda: with_row(1, n, "abc"), "true value": lambda: with_row(1, 1, "true"),
        "empty field": lambda: with_row(2, 1, ""), "1e20 value": lambda: with_row(1, 1, "1e20"),
        "short row": lambda: _csv(n, rows[:2] + [rows[2][:-1]]), "long row": lambda: _csv(n, rows[:2] + [rows[2] + [1.0]]),
        "header only": lambda: _csv(n, []), "empty file": lambda: b"", "comments only": lambda: b"# nothing\n# here\n",
        "no header": lambda: good.split(b"\n", 1)[1], "decreasing": lambda: with_row(2, 0, 0.5),
        "duplicate time": lambda: with_row(2, 0, 1.0), "latin-1": lambda: good.replace(b"t,", "tempé,".encode("latin-1")),
        "invalid utf-8": lambda: good[:5] + b"\xff\xfe" + good[5:], "utf-16": lambda: good.decode().encode("utf-16"),
        "huge field": lambda: good + b"3.0," + b"1" * 200000 + b"\n", "nul byte": lambda: good[:3] + b"\0" + good[3:],
        "semicolons": lambda: good.replace(b",", b";"),
    }
    if how == "missing file":
        pass
    elif how == "folder":
        files["tq.csv"] = None
    elif how == "nul in name":
        data = clone(DATA[b])
        data["arms"][0]["torque"] = {"csv": "tq\0.csv"}
        scen = dump(data)
        files["tq.csv"] = good
    else:
        files["tq.csv"] = content[how]()
    return Case("csv", f"{b}: torque CSV {how}", "arms[0].torque.csv", scen, files)


MALFORMED = ["unclosed bracket", "tab indent", "unterminated quote", "second document", "top-level list",
             "top-level number", "empty file", "null document", "comment only", "python tag", "unknown tag",
             "undefined alias", "control character", "bad indentation", "stray colon", "top-level string"]


def specs_malformed():
    return [(b, how) for b in DATA for how in MALFORMED]


# malformed cases that replace the whole file
WHOLE_DOCUMENTS = {"top-level list": "- 1\n- 2\n", "top-level number": "42\n", "top-level string": "just some words\n",
                   "empty file": "", "null document": "~\n", "comment only": "# nothing here\n"}


def build_malformed(spec):
    b, how = spec
    text = BASES[b]
    lines = text.split("\n")
    if how == "unclosed bracket":
        i = next(i for i, l in enumerate(lines) if "]" in l and not l.lstrip().startswith("#"))
        lines[i] = lines[i][::-1].replace("]", "", 1)[::-1]
        text = "\n".join(lines)
    elif how == "tab indent":
        i = next(i for i, l in enumerate(lines) if l.startswith("  ") and not l.lstrip().startswith("#"))
        lines[i] = "\t" + lines[i].lstrip()
        text = "\n".join(lines)
    elif how == "unterminated quote":
        text += '\nextra: "no end\n'
    elif how == "second document":
        text += "\n---\nname: again\n"
    elif how in WHOLE_DOCUMENTS:
        text = WHOLE_DOCUMENTS[how]
    elif how == "python tag":
        text = text.replace("description:", "description: !!python/object/apply:os.system ['echo hi']\nignored:", 1)
    elif how == "unknown tag":
        text = text.replace("duration:", "duration: !seconds", 1)
    elif how == "undefined alias":
        text = text.replace("duration:", "duration: *nowhere\nignored:", 1)
    elif how == "control character":
        text = text.replace("description: \"", "description: \"\x07", 1)
    elif how == "bad indentation":
        i = next(i for i, l in enumerate(lines) if l.startswith("  ") and ":" in l and not l.lstrip().startswith(("#", "-")))
        lines[i] = " " + lines[i]
        lines.insert(i, "   " + lines[i].lstrip())
        text = "\n".join(lines)
    elif how == "stray colon":
        text = text.replace("duration:", "duration: : :", 1)
    return Case("malformed_yaml", f"{b}: {how}", None, text.encode("utf-8"))


ENCODINGS = ["ff byte", "latin-1", "utf-16", "bad continuation", "surrogate", "overlong", "lone continuation",
             "truncated sequence", "utf-32"]


def specs_encoding():
    return [(b, how, pos) for b in DATA for how in ENCODINGS for pos in ("comment", "string", "start", "end")]


def build_encoding(spec):
    b, how, pos = spec
    text = BASES[b].replace("description: \"", "description: \"é ", 1)
    raw = text.encode("utf-8")
    bad = {"ff byte": b"\xff", "bad continuation": b"\xc3\x28", "surrogate": b"\xed\xa0\x80",
           "overlong": b"\xc0\xaf", "lone continuation": b"\x80", "truncated sequence": b"\xe2\x82"}
    if how == "latin-1":
        raw = text.encode("latin-1", errors="replace")
    elif how == "utf-16":
        raw = text.encode("utf-16")
    elif how == "utf-32":
        raw = text.encode("utf-32")
    else:
        at = {"comment": raw.index(b"\n") if raw.startswith(b"#") else 0, "start": 0, "end": len(raw),
              "string": raw.index(b"description: \"") + len(b"description: \"")}[pos]
        raw = raw[:at] + bad[how] + raw[at:]
    return Case("encoding", f"{b}: {how} at {pos}", None, raw)


def specs_nesting():
    return [(b, how, depth) for b in DATA for how in ("flow list", "flow map", "block map", "block list", "mixed")
            for depth in (40, 200, 1000, 5000, 100000)]


def build_nesting(spec):
    b, how, depth = spec
    if how in ("block map", "block list") and depth > 1000:
        depth = 1000
    if how == "flow list":
        value = "[" * depth + "1" + "]" * depth
    elif how == "flow map":
        value = "{a: " * depth + "1" + "}" * depth
    elif how == "mixed":
        value = "[{a: " * (depth // 2) + "1" + "}]" * (depth // 2)
    elif how == "block map":
        value = "".join("\n" + "  " * (i + 1) + "a:" for i in range(depth)) + " 1"
    else:
        value = "\n  " + "- " * depth + "1"
    key = ("duration", "gravity", "description", "arms")[depth % 4]
    text = BASES[b].replace(f"\n{key}:", f"\nzz_old_{key}:", 1) + f"\n{key}: {value}\n"
    return Case("deep_nesting", f"{b}: {how} {depth} deep under {key}", None, text.encode("utf-8"))


def _laughs(width, depth, leaf="1"):
    parts = [f"&l0 [{', '.join([leaf] * width)}]"]
    for i in range(1, depth):
        parts.append(f"&l{i} [{', '.join([f'*l{i - 1}'] * width)}]")
    return "[" + ", ".join(parts) + "]"


def _merge_chain(n):
    parts = ["&m0 {a0: 1}"] + [f"&m{i} {{<<: *m{i - 1}, a{i}: 1}}" for i in range(1, n)]
    return "[" + ", ".join(parts) + "]"


def _map_bomb(width, depth):
    parts = ["&k0 {" + ", ".join(f"x{j}: 1" for j in range(width)) + "}"]
    for i in range(1, depth):
        parts.append(f"&k{i} {{" + ", ".join(f"y{j}: *k{i - 1}" for j in range(width)) + "}")
    return "[" + ", ".join(parts) + "]"


BOMB_PLACES = [("gravity",), ("description",), ("name",), ("duration",), ("arms", 0, "links", 0, "box", "size"),
               ("object", "box", "size"), ("arms", 1, "initial", "angles"), ("integrator",), ("arms",)]
BOMBS = {"laughs 9x9": lambda: _laughs(9, 9), "laughs 10x8": lambda: _laughs(10, 8),
         "laughs 2x40": lambda: _laughs(2, 40), "wide 2000x2000": lambda: _laughs(2000, 2),
         "merge chain 3000": lambda: _merge_chain(3000), "mapping bomb 8x8": lambda: _map_bomb(8, 8),
         "string laughs": lambda: _laughs(9, 9, '"lol"')}


def specs_bomb():
    return [(b, place, bomb) for b in DATA for place in BOMB_PLACES for bomb in BOMBS]


def build_bomb(spec):
    b, place, bomb = spec
    data = clone(DATA[b])
    try:
        get(data, place[:-1])[place[-1]] = TOKEN
    except (KeyError, IndexError, TypeError):
        data[place[0]] = TOKEN
    return Case("alias_bomb", f"{b}: {bomb} under {fmt(place)}", None, dump(data, BOMBS[bomb]()))


def specs_duplicate():
    out = []
    for b, d in DATA.items():
        for p, v, k in walk(d):
            if k == "mapping":
                out += [(b, p, key) for key in v]
        out.append((b, None, "duration"))
    return out


def build_duplicate(spec):
    b, p, key = spec
    if p is None:   # a second top-level key at the end of the file: the last one won
        return Case("duplicate_key", f"{b}: duration twice", "duration", (BASES[b] + "\nduration: 1.0\n").encode())
    data = clone(DATA[b])
    m = get(data, p)
    items = list(m.items())
    m.clear()
    for k, v in items:
        m[k] = v
        if k == key:
            m[DUP] = clone(v)
    text = dump(data).decode().replace(f'"{DUP}"', json.dumps(key))
    return Case("duplicate_key", f"{b}: {fmt(p + (key,))} twice", fmt(p + (key,)), text.encode())


NAMES = ["../escape", "", ".hidden", "a/b", "/tmp/abs", "..", ".", "a\\b", "x" * 300, "na me", "tab\tname",
         "new\nline", "ünïcode", "con:x", "a*b", "$HOME", "~user", "nul\0x", "../../../../tmp/evil", "a/../b"]


def specs_name():
    return [(b, name) for b in DATA for name in NAMES]


def build_name(spec):
    b, name = spec
    return Case("name", f"{b}: name {name!r}", "name", dump(put(DATA[b], ("name",), name)),
                commands=("run", "inverse", "capacity", "simulate", "mjcf"))


def specs_closure():
    out = []
    for b, d in DATA.items():
        if isinstance(d["object"]["grasps"], list):
            out += [(b, "grasp", dx) for dx in (0.1, -0.15, 0.3)]
            out += [(b, "angle", dq) for dq in (20.0, -35.0)]
    return out


def build_closure(spec):
    b, how, delta = spec
    data = clone(DATA[b])
    if how == "grasp":
        data["object"]["grasps"][1]["position"][0] += delta
    else:
        data["arms"][1]["initial"]["angles_deg"][0] += delta
    return Case("closure", f"{b}: {how} moved by {delta}", "object.grasps", dump(data),
                commands=("simulate", "run", "validate"))


def specs_motors():
    return [(b, flag) for b in DATA for flag in ((), ("--no-lp",), ("--no-optimise",))]


def build_motors(spec):
    b, flag = spec
    data = clone(DATA[b])
    for arm in data["arms"]:
        arm.pop("motors", None)
    return Case("motors", f"{b}: capacity without motors {' '.join(flag)}", "motors", dump(data),
                argv=["capacity", "{s}", "--out", "{o}", "--duration", "0.05", *flag])


LOG_BREAKS = ["empty", "truncated", "flipped byte", "garbage span", "text", "yaml", "png", "magic only",
              "magic and garbage", "not a run log", "missing field", "folder", "missing", "zeros", "doubled"]


def specs_log():
    return [(how, k) for how in LOG_BREAKS for k in range(12 if how in ("truncated", "flipped byte", "garbage span") else 1)]


_LOG_CACHE: dict = {}


def valid_log() -> bytes:
    """A real run log: the paper scenario, native model (the NumPy reference engine: no compiled code to
    load), 0.03 s."""
    if "run" not in _LOG_CACHE:
        import tempfile

        from coopsim.io.log import write_run_log
        from coopsim.io.scenario import load_scenario
        from coopsim.forward.simulate import simulate

        model = load_scenario(SCENARIOS / "paper_planar_2x3.yaml")
        with tempfile.TemporaryDirectory() as tmp:
            path = write_run_log(Path(tmp) / "run.mcap", model, native=simulate(model, duration=0.03, engine='reference'))
            _LOG_CACHE["run"] = path.read_bytes()
    return _LOG_CACHE["run"]


def _other_log(missing_field: bool) -> bytes:
    import tempfile

    from coopsim.io.mcap_codec import Series, write_mcap

    t = np.array([0.0, 0.1])
    if missing_field:
        series = [Series("/native/joint_state", "coopsim.JointState", t, {"angle": np.zeros((2, 3))})]
    else:
        series = [Series("/inverse/paper/torque", "coopsim.Torque", t, {"tau": np.zeros((2, 3))})]
    with tempfile.TemporaryDirectory() as tmp:
        return write_mcap(Path(tmp) / "x.mcap", series, {"model": {"name": "x"}}).read_bytes()


def build_log(spec):
    how, k = spec
    rng = random.Random(f"{how}{k}")
    files = {}
    if how in ("truncated", "flipped byte", "garbage span", "doubled"):
        good = valid_log()
        if how == "truncated":
            content = good[:rng.randrange(len(good))]
        elif how == "flipped byte":
            i = rng.randrange(len(good))
            content = good[:i] + bytes([good[i] ^ (1 << rng.randrange(8))]) + good[i + 1:]
        elif how == "garbage span":
            i = rng.randrange(len(good) - 16)
            content = good[:i] + bytes(rng.randrange(256) for _ in range(16)) + good[i + 16:]
            if content == good:
                content = good[:-1]
        else:
            content = good + good
        files["log.mcap"] = content
    elif how in ("not a run log", "missing field"):
        files["log.mcap"] = _other_log(how == "missing field")
    elif how == "folder":
        files["log.mcap"] = None
    elif how != "missing":
        files["log.mcap"] = {"empty": b"", "text": b"hello\n", "yaml": BASES["paper_planar_2x3"].encode(),
                             "png": b"\x89PNG\r\n\x1a\n" + bytes(64), "magic only": b"\x89MCAP0\r\n",
                             "magic and garbage": b"\x89MCAP0\r\n" + bytes(range(256)) * 4,
                             "zeros": bytes(4096)}[how]
    return Case("log", f"plot: {how} {k}", "log.mcap", None, files, argv=["plot", "{f:log.mcap}", "--out", "{o}"])


CLASSES = {
    "wrong_type": (specs_wrong_type, build_wrong_type),
    "bool_number": (specs_bool, build_element("bool_number")),
    "quoted_number": (specs_quoted, build_element("quoted_number", raw_values=True)),
    "missing_key": (specs_missing, build_missing),
    "unknown_key": (specs_unknown, build_unknown),
    "non_finite": (specs_nonfinite, build_element("non_finite", raw_values=True)),
    "extreme": (specs_extreme, build_element("extreme", raw_values=True)),
    "sizes": (specs_sizes, build_sizes),
    "work": (specs_work, build_work),
    "csv": (specs_csv, build_csv),
    "malformed_yaml": (specs_malformed, build_malformed),
    "encoding": (specs_encoding, build_encoding),
    "deep_nesting": (specs_nesting, build_nesting),
    "alias_bomb": (specs_bomb, build_bomb),
    "duplicate_key": (specs_duplicate, build_duplicate),
    "name": (specs_name, build_name),
    "closure": (specs_closure, build_closure),
    "motors": (specs_motors, build_motors),
    "log": (specs_log, build_log),
}


def catalogue() -> dict[str, list]:
    return {cls: specs() for cls, (specs, _) in CLASSES.items()}


def draw(seed: int = SEED, count: int = DRAWS) -> list[tuple[Case, list[str]]]:
    """`count` cases, stratified over the classes (each class its share, drawn without replacement),
    each with the command line to run it on."""
    rng = random.Random(seed)
    cat = catalogue()
    share = math.ceil(count / len(cat))
    cases = []
    for cls, specs in cat.items():
        for spec in rng.sample(specs, min(share, len(specs))):
            case = CLASSES[cls][1](spec)
            cases.append((case, command_line(case, rng)))
    return cases


def command_line(case: Case, rng: random.Random) -> list[str]:
    extra = case.extra_args
    if case.argv is not None:
        return list(case.argv)
    cmd = rng.choice(case.commands)
    argv = list(SCENARIO_COMMANDS[cmd])
    if cmd in WITH_DURATION:
        argv += extra or (SHORT if case.short else [])
    return argv


# ------------------------------------------------------------------------------------------------
# running one case in this process
# ------------------------------------------------------------------------------------------------

class Hang(BaseException):
    """A case ran past CASE_SECONDS."""


def materialise(case: Case, folder: Path, argv: list[str]) -> tuple[list[str], set[str]]:
    """Write the case's inputs into folder/in; return the filled-in command line and the input paths
    (relative to folder)."""
    inp = folder / "in"
    inp.mkdir(parents=True)
    if case.scenario is not None:
        (inp / "s.yaml").write_bytes(case.scenario)
    for name, content in case.files.items():
        if content is None:
            (inp / name).mkdir()
        else:
            (inp / name).write_bytes(content)
    before = {str(p.relative_to(folder)) for p in folder.rglob("*")}
    filled = []
    for a in argv:
        a = a.replace("{s}", str(inp / "s.yaml")).replace("{o}", str(folder / "out"))
        if a.startswith("{f:"):
            a = str(inp / a[3:-1])
        filled.append(a)
    return filled, before


def run_case(case: Case, folder: Path, argv: list[str], capfd) -> tuple[str, str]:
    """Run one case through coopsim.cli.main in this process (a SIGALRM watchdog marks hangs);
    return `classify`'s verdict."""
    from coopsim.cli import main

    filled, before = materialise(case, folder, argv)
    capfd.readouterr()
    watchdog = threading.current_thread() is threading.main_thread()
    if watchdog:
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(CASE_SECONDS)
    status, crash = None, None
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        status = main(filled)
    except Hang:
        return "hang", f"still running after {CASE_SECONDS} s"
    except SystemExit as exc:
        status = exc.code
    except BaseException:  # noqa: BLE001 - any escape from main() is a traceback for the user
        crash = traceback.format_exc()
    finally:
        if watchdog:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, old)
        os.chdir(cwd)
    return classify(case, folder, before, status, crash, capfd.readouterr().err)


def classify(case: Case, folder: Path, before: set[str], status, crash: str | None, err: str) -> tuple[str, str]:
    """(verdict, detail): 'clean' (exit 2, one line 'coopsim: error: ...' naming the field or file,
    nothing written), 'traceback', 'silent' (accepted: exit 0 or 1), 'other' (exit 2 but several
    lines, or not naming the field, or files left behind)."""
    if crash is not None:
        return "traceback", crash.strip().splitlines()[-1]
    if "Traceback" in err:
        return "traceback", err.strip().splitlines()[-1]
    if status in (0, 1):
        return "silent", f"exit {status}; stderr {err.strip()[-300:]!r}"
    lines = err.strip("\n").split("\n") if err.strip() else []
    after = {str(p.relative_to(folder)) for p in folder.rglob("*")}
    left = sorted(after - before)
    names = case.names if case.names is not None else "s.yaml"
    problems = []
    if status != 2:
        problems.append(f"exit {status}")
    if len(lines) != 1:
        problems.append(f"{len(lines)} stderr lines")
    elif not lines[0].startswith("coopsim: error: "):
        problems.append("not a coopsim error line")
    if not any(names in line for line in lines):
        problems.append(f"does not name {names!r}")
    if left:
        problems.append(f"left {left[:3]}")
    if problems:
        return "other", "; ".join(problems) + f": {err.strip()[:400]!r}"
    return "clean", lines[0]


def _alarm(signum, frame):
    raise Hang()


# ------------------------------------------------------------------------------------------------
# the fuzz test
# ------------------------------------------------------------------------------------------------

def test_catalogue_is_larger_than_a_draw():
    """Every class has specs; the catalogue holds several times what one run draws."""
    cat = catalogue()
    assert all(cat.values()), [k for k, v in cat.items() if not v]
    assert sum(len(v) for v in cat.values()) >= 10 * DRAWS
    cases = draw()
    assert len(cases) >= 300 and {c.cls for c, _ in cases} == set(CLASSES)
    assert [c.what for c, _ in cases] == [c.what for c, _ in draw()]   # deterministic


def test_fuzz_every_reader(tmp_path, capfd):
    """Every drawn case: exit 2, one stderr line naming the field or file, no traceback, nothing written."""
    failures = []
    for i, (case, argv) in enumerate(draw()):
        verdict, detail = run_case(case, tmp_path / f"c{i:03d}", argv, capfd)
        if verdict != "clean":
            failures.append(f"[{case.cls}] {case.what} | {argv[0]}: {verdict}: {detail}")
    assert not failures, f"{len(failures)} of {len(draw())} cases:\n" + "\n".join(failures)


# ------------------------------------------------------------------------------------------------
# targeted tests: each finding of the fuzz run of 908 mutated scenarios
# ------------------------------------------------------------------------------------------------

PAPER = DATA["paper_planar_2x3"]


def cli(folder: Path, capfd, *argv) -> tuple[int, str, str]:
    """coopsim.cli.main(argv) in `folder`, in this process: (status, stdout, stderr); never a traceback."""
    from coopsim.cli import main

    capfd.readouterr()
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        status = main([str(a) for a in argv])
    finally:
        os.chdir(cwd)
    out, err = capfd.readouterr()
    assert "Traceback" not in err
    return status, out, err


def error_line(folder: Path, capfd, *argv) -> str:
    """The one stderr line of a command that must fail with status 2 and write nothing."""
    before = set(folder.rglob("*"))
    status, _, err = cli(folder, capfd, *argv)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("coopsim: error: "), (status, err)
    assert set(folder.rglob("*")) == before, "the failed command wrote files"
    return lines[0]


def scenario(folder: Path, data_or_text, name: str = "s.yaml") -> Path:
    path = folder / name
    if isinstance(data_or_text, bytes):
        path.write_bytes(data_or_text)
    else:
        path.write_text(data_or_text if isinstance(data_or_text, str) else yaml.safe_dump(data_or_text))
    return path


def with_csv(rows: str) -> dict:
    return put(PAPER, ("arms", 0, "torque"), {"csv": "tq.csv"}) if rows is not None else PAPER


# -- tracebacks ------------------------------------------------------------------------------------

def test_non_utf8_scenario_names_the_file_and_line(tmp_path, capfd):
    text = BASES["paper_planar_2x3"].replace('description: "', 'description: "\xe9', 1).encode("latin-1", "replace")
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, text))
    assert "s.yaml: not UTF-8 text: byte 0xe9 on line" in line
    utf16 = BASES["paper_planar_2x3"].encode("utf-16")
    assert "not UTF-8 text: byte 0xff on line 1" in error_line(tmp_path, capfd, "mjcf", scenario(tmp_path, utf16, "u.yaml"))
    # a UTF-8 byte-order mark is fine
    bom = scenario(tmp_path, b"\xef\xbb\xbf" + BASES["paper_planar_2x3"].encode(), "bom.yaml")
    from coopsim.io.scenario import load_scenario

    assert load_scenario(bom).name == "paper_planar_2x3"


def test_non_utf8_csv_names_the_field_and_file(tmp_path, capfd):
    (tmp_path / "tq.csv").write_bytes("tempé,a,b,c\n0,0,0,0\n1,1,1,1\n".encode("latin-1"))
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, with_csv("")))
    assert "arms[0].torque.csv: tq.csv: not UTF-8 text: byte 0xe9 on line 1" in line


@pytest.mark.parametrize("depth", [33, 5000, 100000])
def test_deep_nesting_is_refused_before_recursion(tmp_path, capfd, depth):
    text = BASES["paper_planar_2x3"].replace("\nduration:", "\nold_duration:", 1) + \
        "\nduration: " + "[" * depth + "1" + "]" * depth + "\n"
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, text))
    # (past 1000 levels libyaml's parser stops first: "exceeded maximum nesting depth")
    assert "s.yaml: " in line and ("line 65: nested more than 32 levels deep" in line or
                                   "at line 65, column 1010: exceeded maximum nesting depth" in line), line
    # 32 levels are fine (and then the value is wrong, naming the field)
    ok = BASES["paper_planar_2x3"].replace("\nduration: 5.0", "\nduration: " + "[" * 31 + "1" + "]" * 31, 1)
    assert "duration: expected a number" in error_line(tmp_path, capfd, "mjcf", scenario(tmp_path, ok, "ok.yaml"))


@pytest.mark.parametrize("value", [1e308, 1e12, float("inf"), 10 ** 400])
def test_huge_durations_are_refused(tmp_path, capfd, value):
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, dump(put(PAPER, ("duration",), value))))
    assert "s.yaml: duration: must be" in line


@pytest.mark.parametrize("value", ["inf", "1e308", "nan", "-1", "0", "-inf", "0.0", "1e12"])
def test_bad_duration_option_is_one_line(tmp_path, capfd, value):
    """--duration inf|1e308|nan|-1 were tracebacks, --duration 0 was accepted (duration: 0 is not)."""
    path = scenario(tmp_path, BASES["paper_planar_2x3"])
    for command in ("simulate", "run", "validate", "inverse", "capacity"):
        line = error_line(tmp_path, capfd, command, path, f"--duration={value}", *(["--out", "o"] if command in (
            "run", "inverse", "capacity") else []))
        assert line.startswith("coopsim: error: --duration: must be a positive, finite number of seconds"), line


def test_duration_option_is_held_to_the_work_limits(tmp_path, capfd):
    """--duration 1e7 at output_dt 0.01 s: 1e9 samples, refused up front naming --duration."""
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, BASES["paper_planar_2x3"]), "--duration", "1e7")
    assert "s.yaml: --duration: 1e+07 s at integrator.output_dt = 0.01 s is 1e+09 output samples, more than" in line


def test_tiny_rk4_step_is_refused_not_run(tmp_path, capfd):
    data = put(put(PAPER, ("integrator", "method"), "rk4"), ("integrator", "step"), 1e-13)
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, data))
    assert "duration: 5 s at integrator.step = 1e-13 s is 5e+13 rk4 steps, more than the 10,000,000" in line


@pytest.mark.parametrize("key", ["size", "density"])
def test_extreme_object_box_is_refused(tmp_path, capfd, key):
    """object.box.size: 1e308 ended in LinAlgError; object.box.density: 1e308 gave Infinity in
    capacity.json with exit 0."""
    value = [1e308, 0.06, 0.1] if key == "size" else 1e308
    line = error_line(tmp_path, capfd, "capacity", scenario(tmp_path, dump(put(PAPER, ("object", "box", key), value))),
                      "--out", "o")
    assert f"object.box.{key}: must be at most 1e+09 in magnitude" in line


@pytest.mark.parametrize("path,value,field", [
    (("duration",), 1.0e7, "duration: 1e+07 s at integrator.output_dt"),
    (("integrator", "output_dt"), 1e-9, "duration: 5 s at integrator.output_dt = 1e-09 s is 5e+09 output samples"),
    (("integrator", "max_step"), 1e-9, "integrator.max_step = 1e-09 s is 5e+09 steps at least"),
    (("mujoco", "timestep"), 1e-10, "mujoco.timestep = 1e-10 s is 5e+10 MuJoCo steps"),
    (("mujoco", "iterations"), 1e12, "mujoco.iterations: must be at most 1e+09 in magnitude"),
    (("mujoco", "iterations"), 20000, "mujoco.iterations: must be at most 10,000, got 20000"),
])
def test_work_that_cannot_fit_is_refused_up_front(tmp_path, capfd, path, value, field):
    assert field in error_line(tmp_path, capfd, "simulate", scenario(tmp_path, dump(put(PAPER, path, value))))


def test_object_motion_samples_are_bounded(tmp_path, capfd):
    data = put(DATA["paper_planar_2x3_carry"], ("inverse", "object_motion", "output_dt"), 1e-9)
    line = error_line(tmp_path, capfd, "inverse", scenario(tmp_path, dump(data)), "--out", "o")
    assert "inverse.object_motion.output_dt: waypoints over 13 s every 1e-09 s are 1.3e+10 samples" in line


@pytest.mark.parametrize("how", ["empty", "truncated", "flipped", "text", "scenario", "not a run log", "trailing"])
def test_plot_of_a_broken_log_is_one_line(tmp_path, capfd, how):
    good = valid_log()
    content = {"empty": b"", "truncated": good[:len(good) // 2], "flipped": good[:5000] + bytes([good[5000] ^ 4]) + good[5001:],
               "text": b"hello\n", "scenario": BASES["paper_planar_2x3"].encode(), "not a run log": _other_log(False),
               "trailing": good + b"\0"}[how]
    (tmp_path / "log.mcap").write_bytes(content)
    line = error_line(tmp_path, capfd, "plot", "log.mcap", "--out", "o")
    assert line.startswith("coopsim: error: log.mcap: not a"), line


def test_every_damaged_byte_of_a_log_is_detected(tmp_path):
    """Every truncation, and a flipped bit at sampled offsets (and the data-end record's opcode, which
    the MCAP reader would skip as an unknown record), raises UnreadableLogError naming the file."""
    import io

    from mcap.records import DataEnd
    from mcap.stream_reader import StreamReader

    from coopsim.io.log import read_run_log
    from coopsim.io.mcap_codec import UnreadableLogError

    good = valid_log()
    path = tmp_path / "x.mcap"
    stream, start, data_end = io.BytesIO(good), 8, None
    for record in StreamReader(stream, emit_chunks=True).records:
        data_end = start if isinstance(record, DataEnd) else data_end
        start = stream.tell()
    offsets = sorted(set(random.Random(9).sample(range(len(good)), 300)) | {data_end})
    for i in offsets:
        path.write_bytes(good[:i] + bytes([good[i] ^ 0x80]) + good[i + 1:])
        with pytest.raises(UnreadableLogError, match="x.mcap: not a"):
            read_run_log(path)
    for k in random.Random(10).sample(range(len(good)), 100):
        path.write_bytes(good[:k])
        with pytest.raises(UnreadableLogError, match="x.mcap: not a"):
            read_run_log(path)


def test_logs_without_a_data_crc_still_read(tmp_path, monkeypatch):
    """Logs written before the data-section CRC (a zero CRC: not checked) read as before."""
    import functools

    from coopsim.io import mcap_codec as C

    series = [C.Series("/a", "coopsim.A", np.array([0.0, 1.0]), {"x": np.array([[1.0, 2.0], [3.0, np.nan]])})]
    new = C.read_mcap(C.write_mcap(tmp_path / "new.mcap", series, {"m": {"k": "v"}}))
    monkeypatch.setattr(C, "Writer", functools.partial(C.Writer, enable_data_crcs=False))
    old = C.read_mcap(C.write_mcap(tmp_path / "old.mcap", series, {"m": {"k": "v"}}))
    assert old.metadata == new.metadata == {"m": {"k": "v"}}
    assert np.array_equal(old.topics["/a"]["x"], new.topics["/a"]["x"], equal_nan=True)


@pytest.mark.parametrize("flag", [[], ["--no-lp"]])
def test_capacity_without_motors_is_refused(tmp_path, capfd, flag):
    """Was a HiGHS traceback (with --no-lp: 'inf kg' and exit 0)."""
    line = error_line(tmp_path, capfd, "capacity", scenario(tmp_path, BASES["spatial_6r_pair"]), "--out", "o", *flag)
    assert line.endswith("s.yaml: arms[].motors: the load capacity needs motor limits (stall_torque, no_load_speed), "
                         "and no joint has one")


# -- silently accepted --------------------------------------------------------------------------

def test_duplicate_keys_are_refused_naming_both_lines(tmp_path, capfd):
    line = error_line(tmp_path, capfd, "mjcf", scenario(tmp_path, BASES["paper_planar_2x3"] + "duration: 1.0\n"),
                      "--out", "o")
    text = BASES["paper_planar_2x3"]
    first = text[:text.index("\nduration:")].count("\n") + 2
    assert f"s.yaml: duration: duplicate key (lines {first} and {text.count(chr(10)) + 1}: the second" in line
    nested = text.replace("density: 7850}", "density: 7850, density: 1}", 1)
    at = text[:text.index("density: 7850}")].count("\n") + 1
    line = error_line(tmp_path, capfd, "mjcf", scenario(tmp_path, nested), "--out", "o")
    assert f"s.yaml: arms[0].links[0].box.density: duplicate key (lines {at} and {at}" in line


def test_aliases_and_merge_keys_still_work(tmp_path):
    """Anchors, aliases and merge keys are fine within the limits: a link reused by alias loads as the
    plain file does."""
    from coopsim.io.scenario import load_scenario

    text = BASES["paper_planar_2x3"].replace(
        "      - {joint: {axis: [0, 0, 1]}, box: {length: 0.6, cross_section: [0.04, 0.04], density: 7850}}\n", "", 4)
    text = text.replace("    links:\n", "    links:\n      - &long {joint: {axis: [0, 0, 1]}, box: "
                        "{length: 0.6, cross_section: [0.04, 0.04], density: 7850}}\n      - *long\n", 1)
    text = text.replace("    links:\n      - {joint", "    links:\n      - *long\n      - {<<: *long, joint: "
                        "{axis: [0, 0, 1]}}\n      - {joint", 1)
    a, b = load_scenario(scenario(tmp_path, text, "alias.yaml")), load_scenario(SCENARIOS / "paper_planar_2x3.yaml")
    assert np.array_equal(a.arms[1].link_mass, b.arms[1].link_mass) and np.array_equal(a.q0, b.q0)


@pytest.mark.parametrize("bomb", ["laughs", "wide", "merge chain"])
def test_alias_bombs_are_refused_quickly(tmp_path, capfd, bomb):
    import time

    value = {"laughs": _laughs(10, 9), "wide": _laughs(3000, 2), "merge chain": _merge_chain(5000)}[bomb]
    start = time.perf_counter()
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, dump(put(PAPER, ("gravity",), TOKEN), value)))
    assert time.perf_counter() - start < 2.0
    assert "s.yaml: line 3: " in line and ("more than 1,000,000 values" in line or "levels deep" in line), line


def test_nan_in_a_csv_time_column_is_refused(tmp_path, capfd):
    (tmp_path / "tq.csv").write_text("t,a,b,c\n0,0,0,0\nnan,1,1,1\n2,0,0,0\n")
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, with_csv("")))
    assert line.endswith("arms[0].torque.csv: tq.csv: line 3: column 1: must be finite, got nan")


@pytest.mark.parametrize("row,reason", [
    ("1,inf,1,1", "line 3: column 2: must be finite, got inf"), ("1,1e400,1,1", "column 2: must be finite, got 1e400"),
    ("1,true,1,1", "column 2: expected a number, got 'true'"), ("1,1,1", "line 3: expected 1 + 3 columns"),
    ("1,1e20,1,1", "column 2: must be at most 1e+09 in magnitude"), ("0,1,1,1", "times must be strictly increasing")])
def test_bad_csv_values_name_the_line(tmp_path, capfd, row, reason):
    (tmp_path / "tq.csv").write_text(f"t,a,b,c\n0,0,0,0\n{row}\n")
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, with_csv("")))
    assert "arms[0].torque.csv: " in line and reason in line, line


def test_csv_without_a_header_is_refused(tmp_path, capfd):
    """The first row was dropped as the header even when it held numbers."""
    (tmp_path / "tq.csv").write_text("0,0,0,0\n1,1,1,1\n")
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, with_csv("")))
    assert "tq.csv: line 1: the first row must be a header (time, then 3 torques), got numbers" in line


@pytest.mark.parametrize("where,value", [(("gravity",), [0, True, -9.81]), (("arms", 0, "torque", "constant"), [1, 0, False]),
                                          (("arms", 0, "base", "position"), [0, "0", 0]), (("duration",), True)])
def test_booleans_and_text_are_not_numbers(tmp_path, capfd, where, value):
    """`true` inside a number array was taken as 1 (and "0" as 0)."""
    line = error_line(tmp_path, capfd, "mjcf", scenario(tmp_path, dump(put(PAPER, where, value))), "--out", "o")
    assert re.search(rf"s\.yaml: {re.escape(fmt(where))}: expected (a number|numbers), got (True|False|'0')", line), line


def test_duration_zero_is_refused_from_the_file_and_the_option(tmp_path, capfd):
    assert "duration: must be positive, got 0.0" in error_line(
        tmp_path, capfd, "simulate", scenario(tmp_path, dump(put(PAPER, ("duration",), 0))))
    assert "--duration: must be a positive" in error_line(
        tmp_path, capfd, "simulate", scenario(tmp_path, BASES["paper_planar_2x3"], "p.yaml"), "--duration", "0")


# -- unclear errors ---------------------------------------------------------------------------------

@pytest.mark.parametrize("where,value", [(("arms", 0, "torque", "constant"), [0.5, float("nan"), 0.0]),
                                          (("gravity",), [0.0, 0.0, float("inf")]),
                                          (("arms", 1, "links", 0, "box", "density"), float("nan")),
                                          (("arms", 1, "links", 0, "box", "density"), 1e300)])
def test_non_finite_inputs_name_the_field(tmp_path, capfd, where, value):
    """These stopped mid-run with 'non-finite joint accelerations', naming no field."""
    line = error_line(tmp_path, capfd, "simulate", scenario(tmp_path, dump(put(PAPER, where, value))))
    assert f"s.yaml: {fmt(where)}: must be" in line


def test_no_numpy_warning_before_the_error(tmp_path, capfd):
    """An axis of 1e308 printed a RuntimeWarning (overflow in the norm) before the error."""
    line = error_line(tmp_path, capfd, "validate", scenario(tmp_path, dump(put(PAPER, ("arms", 0, "links", 2, "joint", "axis"),
                                                                              [0, 0, -1e308]))))
    assert "arms[0].links[2].joint.axis: must be at most 1e+09 in magnitude" in line


def test_loop_closure_errors_are_one_line_and_leave_no_output(tmp_path, capfd):
    """One line each; `run` made its --out folder before running, and left it empty on a failure."""
    path = scenario(tmp_path, dump(put(PAPER, ("object", "grasps", 1, "position"), [0.3, 0.0, 0.0])))
    for argv in (["simulate"], ["run", "--out", tmp_path / "out"]):
        line = error_line(tmp_path, capfd, argv[0], path, *argv[1:])
        assert "object.grasps: closing the loop from arms[].initial needs a joint correction" in line
    assert not (tmp_path / "out").exists()


def test_a_multiline_error_prints_as_one_line(tmp_path, capfd, monkeypatch):
    from coopsim import cli as C
    from coopsim.core.errors import CoopsimError

    def boom(args):
        raise CoopsimError("first\n  second\nthird")

    monkeypatch.setattr(C, "_cmd_mjcf", boom)
    status, _, err = cli(tmp_path, capfd, "mjcf", "x.yaml")
    assert status == 2 and err == "coopsim: error: first second third\n"


# -- path escape ----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["../escape", "", ".hidden", "a/b", "/tmp/abs", "..", "na me", "x" * 101, "ünï"])
def test_names_must_be_safe_file_stems(tmp_path, capfd, name):
    """name: "../escape" made `run` write outside --out; name: "" wrote a hidden file."""
    (tmp_path / "work").mkdir()
    line = error_line(tmp_path, capfd, "run", scenario(tmp_path / "work", dump(put(PAPER, ("name",), name))),
                      "--out", tmp_path / "work" / "out", "--duration", "0.02")
    assert "s.yaml: name: must be a file name of 1 to 100 letters, digits" in line


def test_default_name_is_the_file_stem_made_safe(tmp_path):
    from coopsim.io.scenario import load_scenario

    for stem, name in (("my scenario", "my_scenario"), (".hidden", "hidden"), ("ok-1.2", "ok-1.2")):
        assert load_scenario(scenario(tmp_path, dump(delete(PAPER, ("name",))), f"{stem}.yaml")).name == name
