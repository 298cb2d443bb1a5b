"""Start-up: the first run's compile and a cached run's start, each a fresh Python process, and the
wall times of the commands as a user runs them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import coopsim
from coopsim.core.errors import CoopsimError


_STARTUP_SCRIPT = ("import json, time; t0 = time.perf_counter(); from coopsim.io.scenario import load_scenario; "
                   "from coopsim.forward.simulate import simulate; m = load_scenario({path!r}); "
                   "t1 = time.perf_counter(); "
                   "{warm}simulate(m, duration=0.05); t2 = time.perf_counter(); simulate(m, duration=0.05); "
                   "t3 = time.perf_counter(); "
                   "print(json.dumps({{'imports': t1 - t0, 'first': t2 - t1, 'again': t3 - t2}}))")


_WARM_UP = "from coopsim.apps.warmup import warm_up; warm_up(); "   # what the CLI does on a first run


def _source_stamps() -> dict[str, int]:
    """Modification times (ns) of the compiled kernels' sources (coopsim/compiled/**/*.py): numba's
    cache is keyed on them."""
    root = Path(coopsim.__file__).resolve().parent / "compiled"
    return {str(p): p.stat().st_mtime_ns for p in sorted(root.rglob("*.py"))}


def startup_process(path: str, warm: bool, env: dict | None = None) -> tuple[float, dict]:
    """Wall time and phases of one fresh process running the start-up script on a scenario file.

    The process loads the scenario and simulates 0.05 s twice, with the CLI's warm-up first if `warm`.

    Args:
        path: the scenario file (absolute path).
        warm: run the CLI's warm-up (`coopsim.apps.warmup`) before the first simulation.
        env: the process's environment (None: this process's).

    Returns:
        tuple[float, dict]: (wall time s, phases): 'imports', 'first' and 'again' (the two 0.05 s
        simulations), in s, as the process measures them.

    Raises:
        CoopsimError: the process fails.
    """
    code = _STARTUP_SCRIPT.format(path=path, warm=_WARM_UP if warm else "")
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)
    wall = time.perf_counter() - start
    if done.returncode:
        raise CoopsimError(f"start-up measurement failed: {done.stderr.strip().splitlines()[-1:]}")
    return wall, json.loads(done.stdout.splitlines()[-1])


def _startup_once(path: str) -> dict:
    """One compile / cached pair of fresh processes (see `startup_times`)."""
    out = {}
    with tempfile.TemporaryDirectory(prefix="coopsim-numba-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for key, warm in (("compile", True), ("cached", False)):
            out[f"{key}_s"], phases = startup_process(path, warm, env)
            out[f"{key}_inside_s"] = phases["imports"] + phases["first"]
        out["jit_load_s"] = phases["first"] - phases["again"]
        out["interpreter_s"] = out["cached_s"] - out["cached_inside_s"] - phases["again"]
    return out


def startup_times(scenario: str | Path, attempts: int = 2) -> dict:
    """Wall times of fresh `python -c` processes that import coopsim and simulate 0.05 s of `scenario` twice.

    'compile_s' with NUMBA_CACHE_DIR an empty temporary folder, compiling every kernel first as the CLI's
    first run does (`coopsim.apps.warmup`, two processes), 'cached_s' the same again with that cache filled
    and no warm-up; '..._inside_s': imports and the first run, as the process measures them; 'jit_load_s':
    the first run less the second (numba's import and loading the compiled kernels from the cache);
    'interpreter_s': the cached process's time before its first line. A source file changed between the
    two processes invalidates the cache: the pair is then run again (up to `attempts` times) and
    'sources_changed' says whether the last pair still saw a change.

    Args:
        scenario: the scenario file.
        attempts: compile / cached pairs at most (one at least).

    Returns:
        dict: s: 'compile_s', 'compile_inside_s', 'cached_s', 'cached_inside_s', 'jit_load_s',
        'interpreter_s'; 'sources_changed' (bool).
    """
    path = str(Path(scenario).resolve())
    for _ in range(max(1, attempts)):
        before = _source_stamps()
        out = _startup_once(path)
        out["sources_changed"] = _source_stamps() != before
        if not out["sources_changed"]:
            break
    return out


COMMANDS = {"run": (["run"], 5.0), "inverse --replay": (["inverse", "--replay"], 3.0),
            "capacity": (["capacity"], 3.0)}   # wall-time targets (s), paper scene, warm cache


def command_times(scenario: str | Path, repeats: int = 2, commands=COMMANDS) -> dict:
    """Wall time of each CLI command on `scenario` as a user runs it.

    Each a fresh `python -m coopsim.cli` process writing into a temporary folder, the compiled kernels
    already cached.

    Args:
        scenario: the scenario file.
        repeats: runs of each command (one at least).
        commands: {name: (CLI words, wall-time target s)} (default COMMANDS).

    Returns:
        dict: {name: {"wall_s": the minimum over `repeats` s, "target_s": s, "met": bool}}.

    Raises:
        CoopsimError: a command exits with a status other than 0 or 1 (1: it ran, but a check failed).
    """
    out = {}
    with tempfile.TemporaryDirectory(prefix="coopsim-bench-") as folder:
        for name, (words, target) in commands.items():
            wall = command_wall([words[0], str(scenario), *words[1:], "--json", "--out", folder], repeats)
            out[name] = {"wall_s": wall, "target_s": target, "met": wall <= target}
    return out


def command_wall(words: list[str], repeats: int = 2, cwd: str | Path | None = None) -> float:
    """Wall time of a CLI command as a user runs it: fresh `python -m coopsim.cli WORDS` processes.

    Args:
        words: the command line after `coopsim`.
        repeats: processes (one at least); the minimum is returned.
        cwd: the processes' working folder (None: this process's).

    Returns:
        float: s, the minimum wall time over the processes.

    Raises:
        CoopsimError: a process exits with a status other than 0 or 1 (1: it ran, but a check failed).
    """
    walls = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "coopsim.cli", *words], cwd=cwd, capture_output=True,
                              text=True, timeout=900)
        walls.append(time.perf_counter() - start)
        if done.returncode not in (0, 1):      # 1: ran, but a check failed (reported by the command)
            raise CoopsimError(f"coopsim {words[0]} failed: {done.stderr.strip().splitlines()[-1:]}")
    return min(walls)
