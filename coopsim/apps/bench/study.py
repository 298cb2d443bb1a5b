"""One scene's benchmark: every run, the evaluation costs and the headline (the fastest run of each
family reaching each error target)."""

from __future__ import annotations

from dataclasses import asdict, replace
from typing import Callable

import numpy as np

from coopsim.apps.bench.costs import eval_costs
from coopsim.apps.bench.measure import (CHECK_FACTOR, SPEED_TARGETS, OUTPUT_DT, REFERENCE_ATOL, REFERENCE_RTOL, TARGETS,
                                        Ladders, RunRow, bench_duration, fastest_reaching, have_pinocchio, pareto_front)
from coopsim.apps.bench.runs import Reference, mujoco_runs, native_runs, pinocchio_runs, reference
from coopsim.core.model import Model


def headline(name: str, rows: list[RunRow], targets=TARGETS) -> list[dict]:
    """Per error target: the fastest native and MuJoCo runs reaching it and MuJoCo's wall time ÷ native's.

    The native run is picked by simulate() wall time and by time-loop time. 'ratio_wall': native simulate()
    end to end; 'ratio_loop': native time loop alone, the like-for-like of the timed rollout call. The
    required ratio for this scenario (SPEED_TARGETS) is given where it sets one (None otherwise), with whether each
    ratio meets it ('met_wall', 'met_loop'; None: no requirement, or no ratio). A ratio is None when either
    side has no run within the target ('note' says which).

    Args:
        name: the scenario's name (looked up in SPEED_TARGETS).
        rows: the scenario's runs.
        targets: rad, the error targets.

    Returns:
        list[dict]: one per target: 'target_rad' rad; 'native', 'native_by_loop', 'mujoco' (method,
        setting, wall_s s, loop_s s, max_error rad of the run, or None); 'ratio_wall', 'ratio_loop',
        'required_ratio', 'met_wall', 'met_loop', 'note'.
    """
    out = []
    for target in targets:
        nat, mj = fastest_reaching(rows, "native", target), fastest_reaching(rows, "mujoco", target)
        nat_loop = fastest_reaching(rows, "native", target, key="loop_s")
        req = SPEED_TARGETS.get(name, {}).get(target)
        entry = {"target_rad": target, "native": _brief(nat), "native_by_loop": _brief(nat_loop), "mujoco": _brief(mj),
                 "ratio_wall": mj.wall_s / nat.wall_s if nat and mj else None,
                 "ratio_loop": mj.wall_s / nat_loop.loop_s if nat_loop and mj else None, "required_ratio": req}
        entry["note"] = "no MuJoCo run reaches this error" if mj is None else (
            "no native run reaches this error" if nat is None else "")
        for k in ("wall", "loop"):
            ratio = entry[f"ratio_{k}"]
            entry[f"met_{k}"] = None if req is None or ratio is None else bool(ratio >= req)
        out.append(entry)
    return out


def _brief(row: RunRow | None) -> dict | None:
    """method, setting, wall_s, loop_s, max_error of a row (None: none)."""
    if row is None:
        return None
    return {"method": row.method, "setting": row.setting, "wall_s": row.wall_s, "loop_s": row.loop_s,
            "max_error": row.max_error}


def bench_scenario(model: Model, ladders: Ladders, peers, log: Callable[[str], None] = lambda s: None,
                   output_dt: float = OUTPUT_DT, costs: bool = True) -> dict:
    """The whole benchmark of one scenario on one output grid: reference, every run, µs per evaluation, headline.

    The reference comes with its self-convergence, the runs with their Pareto flags.

    Args:
        model: the scenario's Model (its duration is cut to `bench_duration`).
        ladders: the Ladders.
        peers: the peers module (`load_peers`).
        log: progress callback, one line of text per stage.
        output_dt: s, the output grid's interval: every run is sampled and compared on it.
        costs: measure the µs per evaluation (which no grid changes).

    Returns:
        dict: 'name'; 'duration_s' s; 'output_dt_s' s; 'n_joints'; 'arms'; 'reference' (method, rtol,
        atol, check_rtol, check_atol, self_convergence_rad rad, far_below_targets,
        smallest_measured_error_rad rad or None, rhs_evaluations); 'runs' (`RunRow`s as dicts); 'eval_us'
        (`eval_costs`, None without costs); 'headline' (`headline`); 'notes' (list of str).
    """
    model = replace(model, duration=bench_duration(model, ladders, output_dt))
    where = f"{model.name} ({output_dt:g} s grid)"
    log(f"{where}: reference ({model.duration:g} s)")
    ref = reference(model, output_dt)
    log(f"{where}: native ladders")
    rows = native_runs(model, ref.result, ladders)
    log(f"{where}: MuJoCo ladders")
    rows += mujoco_runs(model, ref.result, peers, ladders)
    notes = []
    if have_pinocchio():
        log(f"{where}: Pinocchio ladder")
        rows += pinocchio_runs(model, ref.result, peers, ladders)
    else:
        notes.append("Pinocchio rows skipped: the optional 'pin' package is not installed (pip install -e '.[bench]')")
    for row, on in zip(rows, pareto_front([r.max_error for r in rows], [r.wall_s for r in rows])):
        row.pareto = bool(on)
    cost = None
    if costs:
        log(f"{where}: cost per evaluation")
        cost = eval_costs(model, ref.result, rows, peers, ladders)
    return {"name": model.name, "duration_s": model.duration, "output_dt_s": output_dt,
            "n_joints": model.n_total, "arms": model.r, "reference": _reference_summary(ref, rows),
            "runs": [asdict(r) for r in rows], "eval_us": cost, "headline": headline(model.name, rows),
            "notes": notes}


def own_grid(model: Model, ladders: Ladders) -> float | None:
    """The scenario's own output grid when it is benchmarked on it too (ladders.own_grid), else None.

    Args:
        model: the scenario's Model (its name and integrator.output_dt s).
        ladders: the Ladders (own_grid: the scenario names).

    Returns:
        float | None: s, integrator.output_dt, when the name is listed and the grid is not OUTPUT_DT.
    """
    dt = model.integrator.output_dt
    return dt if model.name in ladders.own_grid and abs(dt - OUTPUT_DT) > 1e-12 else None


def _reference_summary(ref: Reference, rows: list[RunRow]) -> dict:
    """Reference settings, its self-convergence difference rad, and whether it is far below every
    error target (≤ 1 % of the smallest) and below the smallest measured error."""
    errs = [r.max_error for r in rows if np.isfinite(r.max_error) and r.max_error > 0]
    sc = ref.self_convergence
    return {"method": "dop853", "rtol": REFERENCE_RTOL, "atol": REFERENCE_ATOL,
            "check_rtol": REFERENCE_RTOL * CHECK_FACTOR, "check_atol": REFERENCE_ATOL * CHECK_FACTOR,
            "self_convergence_rad": sc, "far_below_targets": bool(sc <= 0.01 * min(TARGETS)),
            "smallest_measured_error_rad": min(errs) if errs else None,
            "rhs_evaluations": int(ref.result.stats.n_rhs)}
