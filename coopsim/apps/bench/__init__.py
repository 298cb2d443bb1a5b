"""Work-precision benchmark (`coopsim bench`): the native model against its peers, each run timed and
measured against one tight native reference on the same output grid, in the same process.

    reference   native DOP853 at rtol 1e-13 (atol 1e-14), checked against a 10x looser run
    native      DOP853 and DOPRI5 over an rtol ladder (atol = rtol / 10), RK4 over a step ladder
    MuJoCo      the twin (`validation/peers.py`) through `mujoco.rollout`, RK4 / Euler / implicitfast
                over a timestep ladder; per (integrator, step) the weld time constant k·step with the
                lowest error over k in WELD_FACTORS
    Pinocchio   `constraintDynamics` + scipy DOP853 over an rtol ladder (only with `pin` installed)

Per run: wall time s (minimum over repeats; native: `simulate()` end to end, and `loop_s` the compiled
time loop alone from the same consistent state, which is what MuJoCo's timed `Rollout.rollout` call
does; Pinocchio: `solve_ivp`), max joint error rad over the output grid (OUTPUT_DT, and for the scenes
of Ladders.own_grid their own output grid as well: every sample is reported), final constraint violation
(native loop-closure residual, MuJoCo weld efc_pos, Pinocchio closure log6; m or rad). Per model: µs
per dynamics evaluation, from Python and amortised in a compiled loop. Scaling: µs per evaluation of
synthetic scenes, r arms × n joints, with power-law fits. Start-up: first-run compile time and cached
start-up, each a fresh Python process.

    measure.py  the ladders, one run's row, timing, errors, Pareto fronts, power fits
    runs.py     the reference, native, MuJoCo and Pinocchio runs on one scene
    costs.py    µs per dynamics evaluation
    study.py    one scene's benchmark and its headline
    scaling.py  synthetic scenes of r arms × n joints
    inverse.py  the inverse side: a capacity point, its cost in samples and arms, the inverse commands
    startup.py  first-run compile, cached start-up, the commands' wall times
    report.py   a report's tables and files (Markdown, CSV, JSON, figures)
    here        `run_bench`: the whole benchmark, with the environment and source state

Everything but report.py returns plain data (dicts, lists of `RunRow`); `report` turns a report into
tables and files, `coopsim.plots.bench` draws the figures. Wall times depend on the machine and its load:
compare within one report only.
"""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import Callable

import coopsim
from coopsim.apps.bench.measure import (ATOL_RATIO, FULL, OUTPUT_DT, QUICK, REFERENCE_ATOL, REFERENCE_RTOL, TARGETS,
                                        WELD_FACTORS, Ladders, RunRow, load_peers)
from coopsim.apps.bench.inverse import inverse_bench
from coopsim.apps.bench.scaling import scaling_study
from coopsim.apps.bench.startup import command_times, startup_times
from coopsim.apps.bench.study import bench_scenario, own_grid
from coopsim.forward.simulate import simulate
from coopsim.io.scenario import load_scenario

__all__ = ["FULL", "QUICK", "Ladders", "RunRow", "bench_scenario", "environment", "run_bench", "source_state"]


def run_bench(scenarios: list[str | Path], ladders: Ladders = FULL, peers=None,
              log: Callable[[str], None] = lambda s: None) -> dict:
    """Benchmark each scenario file, the scaling grid and (ladders.startup) the start-up and command times.

    Each scenario on the OUTPUT_DT grid, and those of ladders.own_grid again on their own output grid
    (no second µs-per-evaluation measurement). The start-up times and the commands' wall times are
    measured on the first scenario.

    Args:
        scenarios: the scenario files.
        ladders: the Ladders (default FULL).
        peers: the peers module (None: `load_peers`).
        log: progress callback, one line of text per stage.

    Returns:
        dict: 'settings' (what was run: the Ladders as a dict, output_dt_s, reference tolerances,
        atol_over_rtol, weld_factors, targets_rad), 'environment' (`environment`, plus 'load_average_end'),
        'scenarios' (`bench_scenario` dicts, a scenario's own-grid one after its OUTPUT_DT one), 'scaling'
        (`scaling_study`), 'inverse' (`inverse_bench`, or None without ladders.inverse_dts), 'startup'
        (`startup_times`, or None) and 'commands' (`command_times`, or None).
    """
    peers = peers or load_peers()
    models = [load_scenario(p) for p in scenarios]
    simulate(models[0], duration=OUTPUT_DT)  # warm-up: load (or compile) the kernels before timing
    report = {"settings": _settings(ladders), "environment": environment(), "scenarios": []}
    for model in models:
        report["scenarios"].append(bench_scenario(model, ladders, peers, log))
        dt = own_grid(model, ladders)
        if dt is not None:
            report["scenarios"].append(bench_scenario(model, ladders, peers, log, output_dt=dt, costs=False))
    report["scaling"] = scaling_study(ladders, peers, log)
    report["inverse"] = inverse_bench(ladders, log) if ladders.inverse_dts else None
    report["startup"] = report["commands"] = None
    if ladders.startup:
        log("start-up: fresh processes (compile, then cached)")
        report["startup"] = startup_times(scenarios[0])
        log("commands: run, inverse --replay, capacity as a user runs them")
        report["commands"] = command_times(scenarios[0])
    report["environment"]["load_average_end"] = environment()["load_average"]
    return report


def _settings(ladders: Ladders) -> dict:
    """The ladders and fixed choices, for the report."""
    return asdict(ladders) | {"output_dt_s": OUTPUT_DT, "reference": [REFERENCE_RTOL, REFERENCE_ATOL],
                              "atol_over_rtol": ATOL_RATIO, "weld_factors": list(WELD_FACTORS),
                              "targets_rad": list(TARGETS)}


def environment() -> dict:
    """Versions, machine and load, and the code's `source_state`, for the report.

    The 1/5/15-minute load averages now are included: other work on the machine inflates wall times.

    Returns:
        dict: 'python', 'platform', 'cpus', 'load_average' (list of three, or None), the 'numpy', 'scipy',
        'numba', 'mujoco' and 'pin' versions (None: absent), 'git_head', 'sources_sha256'.
    """
    def version(dist: str):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None

    return {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count(),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            **{d: version(d) for d in ("numpy", "scipy", "numba", "mujoco", "pin")}, **source_state()}


def source_state() -> dict:
    """The code a report timed: git HEAD and a digest of the package's Python sources.

    The digest covers coopsim/**/*.py, so uncommitted edits are included.

    Returns:
        dict: 'git_head' (None outside a git checkout) and 'sources_sha256': the first 12 hex digits of the
        SHA-256 of the sources.
    """
    root = Path(coopsim.__file__).resolve().parent
    digest = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        digest.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes())
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        git = head.stdout.strip() if head.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        git = None
    return {"git_head": git, "sources_sha256": digest.hexdigest()[:12]}
