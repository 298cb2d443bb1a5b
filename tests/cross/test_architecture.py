"""The package's import graph, read statically from the source: no import circles, and no import from
a lower layer to a higher one (README, "What is there").

Layers, bottom up; a module imports from its own layer and the ones below only:

    core                        data, maths, vocabulary (NumPy only)
    dynamics, compiled          the two engines: reference stages and their compiled twin
    forward, inverse, control   the forward pipeline, the inverse side, controllers
    io, twin, plots, report     files, the MuJoCo twin, figures, reports
    apps                        animation, benchmark, sweeps, warm-up, progress
    cli                         the command line

and within them: the two engines never import each other; the forward pipeline imports neither the
inverse side nor the controllers (it takes a torque source; callers build controllers first).
Every import counts, a function's own included.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from helpers import ROOT

PACKAGE = ROOT / "coopsim"

LAYERS = [("core",), ("dynamics", "compiled"), ("forward", "inverse", "control"), ("io", "twin", "plots", "report"),
          ("apps",), ("cli",)]
NEVER = [("dynamics", "compiled", "the engines are siblings"), ("compiled", "dynamics", "the engines are siblings"),
         ("forward", "control", "simulate takes a torque source; controllers live above it"),
         ("forward", "inverse", "the inverse side replays through the forward pipeline, not the other way")]


def modules() -> dict[str, Path]:
    """Dotted module name → file, for every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports(name: str, path: Path, known: dict) -> list[tuple[str, int]]:
    """(module imported, line) for every import of a package module in `path` (top level or inside a
    function; `from pkg import sub` counts as importing the submodule when it is one)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != "coopsim" and target != name:
                out.append((target, node.lineno))
    return out


def area(module: str) -> str:
    """The folder (or top-level module) a module belongs to: coopsim.inverse.capacity → inverse."""
    return module.split(".")[1] if module.count(".") else ""


def layer(module: str) -> int:
    return next(i for i, names in enumerate(LAYERS) if area(module) in names)


@pytest.fixture(scope="module")
def graph():
    known = modules()
    return {m: imports(m, p, known) for m, p in known.items()}


def test_every_module_has_a_layer(graph):
    lost = [m for m in graph if m != "coopsim" and not any(area(m) in names for names in LAYERS)]
    assert not lost, f"modules outside every layer (add their folder to LAYERS and the README): {lost}"


def test_no_import_runs_up_a_layer(graph):
    up = [f"{m}:{line} imports {t} ({LAYERS[layer(m)][0]}… → {LAYERS[layer(t)][0]}…)"
          for m, edges in graph.items() if m != "coopsim" for t, line in edges if layer(t) > layer(m)]
    assert not up, "imports from a lower layer to a higher one:\n" + "\n".join(up)


def test_what_must_never_import_what(graph):
    bad = [f"{m}:{line} imports {t}: {why}" for low, high, why in NEVER for m, edges in graph.items()
           if area(m) == low for t, line in edges if area(t) == high]
    assert not bad, "\n".join(bad)


def test_no_import_circles(graph):
    """Tarjan's strongly connected components of the module graph: each must be one module."""
    index, low, stack, on, circles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w, _ in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                on.discard(w)
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                circles.append(sorted(part))

    for v in graph:
        if v not in index:
            visit(v)
    assert not circles, "import circles:\n" + "\n".join(" ↔ ".join(c) for c in circles)


def test_the_public_face_names_real_objects_and_imports_nothing_heavy():
    """`coopsim.NAME` is the object of the module the face names, and `import coopsim` alone loads none
    of numba, MuJoCo, SciPy or matplotlib (a fresh process: each name is imported on first use)."""
    import subprocess
    import sys

    import coopsim

    for name, module in coopsim._PUBLIC.items():
        assert getattr(coopsim, name) is getattr(__import__(module, fromlist=[name]), name), name
    assert set(coopsim._PUBLIC) <= set(dir(coopsim)) and set(coopsim.__all__) == {"__version__", *coopsim._PUBLIC}
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        coopsim.nothing
    code = ("import sys, coopsim; print(sorted(m for m in ('numba', 'mujoco', 'scipy', 'matplotlib', 'numpy') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr
