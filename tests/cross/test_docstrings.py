"""Every public function, method and class of the package has a docstring a tool can render: an
`Args:` block naming each argument, a `Returns:` (or `Yields:`) block when it returns a value, and an
`Attributes:` block naming each field of a record (dataclass, NamedTuple, jitclass spec). A method that
implements one of a base class of its module (an engine's `run`, the Engine protocol's) may give its own
summary and say "as `Base.method`" for the sections the base documents.

Run as a script to list what is missing in some files: `python tests/cross/test_docstrings.py FILE…`.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "coopsim"
SECTION = re.compile(r"^\s*(Args|Arguments|Returns|Yields|Raises|Attributes|Example|Examples|Note|Notes):\s*$")


def _sections(doc: str) -> dict[str, str]:
    """Section name → its text, for the Google-style sections of a docstring."""
    out, name = {}, None
    for line in doc.splitlines():
        m = SECTION.match(line)
        if m:
            name = m.group(1)
            out[name] = ""
        elif name:
            out[name] += line + "\n"
    return out


def _names_in(block: str) -> set[str]:
    """The entry names of an Args:/Attributes: block (`name:` or `name (type):` at the block's indent,
    several names allowed as `a, b:`)."""
    lines = [line for line in block.splitlines() if line.strip()]
    if not lines:
        return set()
    indent = min(len(line) - len(line.lstrip()) for line in lines)
    out = set()
    for line in lines:
        if len(line) - len(line.lstrip()) != indent or ":" not in line:
            continue
        head = line.split(":", 1)[0].split("(", 1)[0]
        out |= {name.strip().lstrip("*") for name in head.split(",")}
    return out


def _arguments(fn: ast.FunctionDef) -> list[str]:
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    names += [x.arg for x in (a.vararg, a.kwarg) if x is not None]
    return [n for n in names if n not in ("self", "cls")]


def _own_nodes(fn: ast.FunctionDef):
    """The nodes of a function's body, not descending into nested functions, classes or lambdas."""
    stack = list(fn.body)
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            stack.extend(ast.iter_child_nodes(node))


def _returns_value(fn: ast.FunctionDef) -> str | None:
    """'Yields' for a generator, 'Returns' when a `return` gives a value, else None."""
    nodes = list(_own_nodes(fn))
    if any(isinstance(n, (ast.Yield, ast.YieldFrom)) for n in nodes):
        return "Yields"
    for n in nodes:
        if isinstance(n, ast.Return) and n.value is not None and not (
                isinstance(n.value, ast.Constant) and n.value.value is None):
            return "Returns"
    return None


def _decorators(node) -> set[str]:
    return {ast.unparse(d).split("(")[0].rpartition(".")[2] for d in node.decorator_list}


def function_problems(fn: ast.FunctionDef, where: str) -> list[str]:
    """What the docstring of one public function or method lacks."""
    doc = ast.get_docstring(fn)
    if not doc:
        return [f"{where}: no docstring"]
    if {"property", "cached_property", "setter"} & _decorators(fn):
        return []
    sections, out = _sections(doc), []
    args = _arguments(fn)
    if args:
        missing = [a for a in args if a not in _names_in(sections.get("Args", sections.get("Arguments", "")))]
        if missing:
            out.append(f"{where}: Args: lacks {', '.join(missing)}")
    kind = _returns_value(fn)
    if kind and kind not in sections and not (kind == "Yields" and "Returns" in sections):
        out.append(f"{where}: no {kind}: block")
    return out


def _fields(cls: ast.ClassDef) -> list[str]:
    """The declared fields of a record class (class-level annotated names, not ClassVar)."""
    return [n.target.id for n in cls.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)
            and "ClassVar" not in ast.unparse(n.annotation) and not n.target.id.startswith("_")]


def _documented_in_base(fn: ast.FunctionDef, cls: ast.ClassDef, classes: dict) -> bool:
    """Whether `fn` points to the method it implements in a base class of the same module
    ("as `Base.name`"), and that method's own docstring is complete."""
    doc = ast.get_docstring(fn) or ""
    for base in cls.bases:
        name = ast.unparse(base)
        parent = classes.get(name)
        if parent is None or f"`{name}.{fn.name}`" not in doc:
            continue
        own = next((n for n in parent.body if isinstance(n, ast.FunctionDef) and n.name == fn.name), None)
        if own is not None and not function_problems(own, name):
            return True
    return False


def class_problems(cls: ast.ClassDef, where: str, classes: dict | None = None) -> list[str]:
    """What the docstring of one public class, and of its public methods, lacks (`classes`: the module's
    classes by name, for methods documented in a base)."""
    doc = ast.get_docstring(cls)
    if not doc:
        return [f"{where}: no docstring"]
    out = []
    fields = _fields(cls)
    if fields:
        sections = _sections(doc)
        named = _names_in(sections.get("Attributes", "")) | _names_in(sections.get("Args", ""))
        missing = [f for f in fields if f not in named]
        if missing:
            out.append(f"{where}: Attributes: lacks {', '.join(missing)}")
    for node in cls.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
            if ast.get_docstring(node) and _documented_in_base(node, cls, classes or {}):
                continue
            out += function_problems(node, f"{where}.{node.name}")
    return out


def file_problems(path: Path) -> list[str]:
    """Every docstring problem of one module's public names."""
    tree = ast.parse(path.read_text(), str(path))
    rel = path.relative_to(ROOT)
    classes = {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}
    out = []
    for node in tree.body:
        if getattr(node, "name", "_").startswith("_"):
            continue
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out += function_problems(node, f"{rel}:{node.lineno} {node.name}")
        elif isinstance(node, ast.ClassDef):
            out += class_problems(node, f"{rel}:{node.lineno} {node.name}", classes)
    return out


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_public_docstrings_name_arguments_returns_and_fields(path):
    problems = file_problems(path)
    assert not problems, "\n".join(problems)


def test_the_checker_finds_what_a_docstring_lacks():
    src = '''
def f(a, b):
    """Do.

    Args:
        a: one.
    """
    return a

class R:
    """A record."""
    x: float

def g(a, *rest):
    """Do.

    Args:
        a, *rest: the values.

    Returns:
        float: a.
    """
    return a

class Base:
    """An interface."""

    def run(self, a):
        """Run.

        Args:
            a: the input.

        Returns:
            int: a.
        """


class Impl(Base):
    """One implementation."""

    def run(self, a):
        """Run fast.

        Args, Returns: as `Base.run`.
        """
        return a


class Other(Base):
    """Another, pointing nowhere."""

    def run(self, a):
        """Run slow."""
        return a
'''
    tree = ast.parse(src)
    f, r, g, base, impl, other = tree.body
    classes = {"Base": base, "Impl": impl, "Other": other}
    assert function_problems(f, "f") == ["f: Args: lacks b", "f: no Returns: block"]
    assert class_problems(r, "R") == ["R: Attributes: lacks x"]
    assert function_problems(g, "g") == []
    assert class_problems(impl, "Impl", classes) == []
    assert class_problems(other, "Other", classes) == ["Other.run: Args: lacks a", "Other.run: no Returns: block"]


if __name__ == "__main__":
    paths = [Path(p).resolve() for p in sys.argv[1:]] or sorted(PACKAGE.rglob("*.py"))
    found = [p for path in paths for p in file_problems(path)]
    print("\n".join(found))
    print(f"{len(found)} problems", file=sys.stderr)
