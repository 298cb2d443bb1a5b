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

Imports stand at the top of their module. A function imports for itself only what DEFERRED names, each
for its reason, and only where the module does not load it anyway; the CLI's commands each import what
they run (command dispatch: `coopsim --help` and a command's start load nothing another one needs).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest
from helpers import ROOT

PACKAGE = ROOT / "coopsim"

LAYERS = [("core",), ("dynamics", "compiled"), ("forward", "inverse", "control"), ("io", "twin", "plots", "report"),
          ("apps",), ("cli",)]
NEVER = [("dynamics", "compiled", "the engines are siblings"), ("compiled", "dynamics", "the engines are siblings"),
         ("forward", "control", "simulate takes a torque source; controllers live above it"),
         ("forward", "inverse", "the inverse side replays through the forward pipeline, not the other way")]

# what a function may import for itself: module prefix → why it is loaded on first use
DEFERRED = {
    "coopsim.compiled": "the compiled engine (numba) loads where an engine runs: load_scenario, `coopsim plot` "
                        "and `coopsim animate LOG` never need it",
    "scipy": "each SciPy solver loads on the path that solves with it; every run imports the inverse side",
    "matplotlib": "figures are drawn in the figure workers (plots.render): the process that lays out the "
                  "jobs never loads matplotlib",
    "coopsim.inverse.solve": "the distributions (and HiGHS) load with a controller's first inverse dynamics: every run "
                             "imports the controller module for closed_loop",
    "coopsim.inverse.distributions": "the CLI builds its argument parser from the resolutions' registry: "
                                     "`coopsim --help` starts without NumPy",
    "coopsim.io.robots": "robot files are read with MuJoCo, only for scenarios that name a robot:",
    "mujoco.rendering": "OpenGL, present only where frames are rendered",
    "glfw": "a window system, present only where a window opens",
    "dask": "optional (coopsim[sweep])",
    "distributed": "optional (coopsim[sweep])",
    "pyarrow": "optional (coopsim[sweep])",
    "pinocchio": "optional (pin, coopsim[bench])",
}
DISPATCH = "coopsim.cli"


def modules() -> dict[str, Path]:
    """Dotted module name → file, for every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports(name: str, path: Path, known: dict) -> list[tuple[str, int]]:
    """(module imported, line) for every import of a package module in `path` (top level or inside a
    function, type-checking ones too; `from pkg import sub` counts as importing the submodule when it is
    one)."""
    out = []
    for target, line, _ in import_sites(name, path, known, typing=True):
        module = _package_module(target, known)
        if module and module != "coopsim" and module != name:
            out.append((module, line))
    return out


def import_sites(name: str, path: Path, known: dict, typing: bool = False) -> list[tuple[str, int, bool]]:
    """(module imported, line, inside a function) for every import in `path`, the package's and
    others' (dotted names as written; a package module's `from pkg import sub` names the submodule);
    with `typing`, the imports under `if TYPE_CHECKING:` too."""
    tree = ast.parse(path.read_text(), str(path))
    local = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
             for n in ast.walk(f)}
    guarded = {id(n) for node in tree.body if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
               for n in ast.walk(node)}
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if id(node) in guarded and not typing:
            continue
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
        out += [(t, node.lineno, id(node) in local) for t in targets]
    return out


def _package_module(target: str, known: dict) -> str | None:
    while target and target not in known:
        target = target.rpartition(".")[0]
    return target or None


def loaded_on_import(name: str, sites: dict, known: dict) -> set[str]:
    """Every module name (the package's and others') that importing `name` loads: its top-level imports,
    its parent packages', and theirs, transitively."""
    seen, todo = set(), [name]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        parts = m.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts)) if ".".join(parts[:i]) in known]
        for target, _, local in sites.get(m, ()):
            if not local:
                seen.add(target)
                inner = _package_module(target, known)
                if inner:
                    todo.append(inner)
    return seen


def deferred_reason(target: str) -> str | None:
    return next((why for prefix, why in DEFERRED.items() if target == prefix or target.startswith(prefix + ".")),
                None)


def deferred_family(target: str) -> str:
    """What loading `target` brings with it: its DEFERRED entry, except that SciPy's subpackages load one
    by one (scipy.optimize does not bring scipy.integrate)."""
    prefix = next(p for p in DEFERRED if target == p or target.startswith(p + "."))
    return ".".join(target.split(".")[:2]) if prefix == "scipy" else prefix


def test_a_function_imports_only_what_is_deferred_and_not_loaded_already():
    """A function-local import is of a DEFERRED module (the CLI's dispatch aside), and the module it sits
    in does not load that module anyway at import (a deferral that defers nothing). The compiled package
    itself imports its modules in a function: it sets numba's cache folder around their import."""
    known = modules()
    sites = {m: import_sites(m, p, known) for m, p in known.items()}
    bad = []
    for m, entries in sites.items():
        if m == DISPATCH:
            continue
        loaded = None
        for target, line, local in entries:
            if not local:
                continue
            if deferred_reason(target) is None:
                bad.append(f"{m}:{line} imports {target} in a function (move it to the top, or say in DEFERRED "
                           f"why it must wait)")
                continue
            loaded = loaded_on_import(m, sites, known) if loaded is None else loaded
            family = deferred_family(target)
            if m != family and any(x == family or x.startswith(family + ".") for x in loaded):
                bad.append(f"{m}:{line} defers {target}, which importing {m} loads anyway")
    assert not bad, "\n".join(bad)


def test_the_deferrals_hold_in_a_fresh_process():
    """What DEFERRED promises, in a fresh process: the CLI's parser loads no NumPy; loading a scenario
    loads neither numba, SciPy, matplotlib nor MuJoCo; importing the run-plot module loads no matplotlib."""
    import subprocess

    code = "import sys, coopsim.cli; coopsim.cli.build_parser(); print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stdout + out.stderr

    code = ("import sys; from coopsim.io.scenario import load_scenario; import coopsim.plots.run; "
            "load_scenario('scenarios/paper_planar_2x3.yaml'); "
            "print(sorted(m for m in ('numba', 'scipy', 'matplotlib', 'mujoco', 'coopsim.compiled') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


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


def test_each_folder_lists_its_files():
    """Each folder's `__init__.py` docstring names every module (`name.py` or `` `name` ``) and every
    subfolder (`name/`) in it, as README "What is there" says."""
    missing = []
    for init in sorted(PACKAGE.rglob("__init__.py")):
        if init.parent == PACKAGE:
            continue
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        for p in sorted(init.parent.iterdir()):
            if p.suffix == ".py" and p.name != "__init__.py" and p.name not in doc and f"`{p.stem}`" not in doc:
                missing.append(f"{init.relative_to(ROOT)}: {p.name}")
            if p.is_dir() and (p / "__init__.py").is_file() and f"{p.name}/" not in doc:
                missing.append(f"{init.relative_to(ROOT)}: {p.name}/")
    assert not missing, "not listed in their folder's __init__ docstring:\n" + "\n".join(missing)
