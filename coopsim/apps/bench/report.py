"""Tables and files of a work-precision benchmark report (`coopsim.apps.bench.run_bench`): Markdown, CSV,
strict JSON, and `write_outputs` (every file written atomically)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from coopsim.apps.bench.measure import (ATOL_RATIO, EVAL_RATIO_SCENES, EVAL_RATIO_TARGET, OUTPUT_DT, REFERENCE_ATOL,
                                        REFERENCE_RTOL)
from coopsim.io.atomic import write_text_atomic
from coopsim.io.mcap_codec import nonfinite_name
from coopsim.plots.bench import scaling_figure, work_precision_figure

CSV_FIELDS = ("scenario", "output_dt_s", "family", "method", "setting", "param", "wall_s", "loop_s", "max_error_rad",
              "final_violation", "evals", "weld_factor", "pareto", "note")
SCALING_FIELDS = ("r", "n", "n_total", "rows", "planar", "native_amortised_us", "native_cholesky_us",
                  "native_python_us", "mujoco_forward_us", "pinocchio_us", "bad_states")


def _num(x, fmt: str = ".4g") -> str:
    """A number as text ('' for None, 'nan' / 'inf' as Python formats them, booleans as 'true' / 'false')."""
    if x is None:
        return ""
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x)).lower()
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return format(float(x), fmt)


def _csv(rows: list[list]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return buf.getvalue()


def csv_text(report: dict) -> str:
    """Every run of every scenario as CSV, one row per run (columns CSV_FIELDS).

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        str: the CSV text, header first: output_dt_s the output grid's interval s, param rtol or step s,
        wall_s and loop_s s, max_error_rad rad, final_violation m or rad, weld_factor (MuJoCo rows only),
        pareto 0 / 1.
    """
    rows = [list(CSV_FIELDS)]
    for sc in report["scenarios"]:
        for r in sc["runs"]:
            rows.append([sc["name"], _num(sc["output_dt_s"], ".6g"), r["family"], r["method"], r["setting"],
                         _num(r["param"], ".6g"),
                         _num(r["wall_s"]), _num(r["loop_s"]), _num(r["max_error"]), _num(r["final_violation"]),
                         r["evals"], r["extra"].get("weld_factor", ""), int(r["pareto"]), r["note"]])
    return _csv(rows)


def scaling_csv_text(report: dict) -> str:
    """The scaling points as CSV (columns SCALING_FIELDS).

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        str: the CSV text, header first, one row per scaling point (the µs columns in µs per evaluation,
        '' where a point lacks the field).
    """
    rows = [list(SCALING_FIELDS)]
    rows += [[_num(p.get(k)) for k in SCALING_FIELDS] for p in report["scaling"]["points"]]
    return _csv(rows)


def json_safe(obj):
    """A copy strict JSON can carry.

    Non-finite floats become "NaN", "Infinity", "-Infinity" (as in coopsim.io.log), numpy scalars plain
    Python ones.

    Args:
        obj: a report or any part of it (dicts, lists, tuples, numbers, strings, None).

    Returns:
        object: the copy (dict keys as str, tuples as lists); any other object as it is.
    """
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else nonfinite_name(float(obj))
    return obj


def json_text(report: dict) -> str:
    """The report as indented strict JSON.

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        str: the JSON text (`json_safe`), ending in a newline.
    """
    return json.dumps(json_safe(report), indent=2, allow_nan=False) + "\n"


def _table(header: list[str], rows: list[list[str]], align: str | None = None) -> list[str]:
    """Markdown table lines; align: one of 'l'/'r' per column (default: first left, others right)."""
    align = align or "l" + "r" * (len(header) - 1)
    sep = ["---" if a == "l" else "---:" for a in align]
    return ["| " + " | ".join(header) + " |", "| " + " | ".join(sep) + " |"] + \
           ["| " + " | ".join(r) + " |" for r in rows]


def _e(x) -> str:
    return "—" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.1e}"


def _ms(x) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{1e3 * x:.3g}"


def _ratio(x, fmt=".1f") -> str:
    return "—" if x is None else format(x, fmt) + "×"


def scenario_label(sc: dict) -> str:
    """'NAME' for a scenario benchmarked on OUTPUT_DT, 'NAME, X s grid' on another grid.

    Args:
        sc: one scenario of the report (`coopsim.apps.bench.bench_scenario`).

    Returns:
        str: the label.
    """
    dt = sc["output_dt_s"]
    return sc["name"] if abs(dt - OUTPUT_DT) <= 1e-12 else f"{sc['name']}, {dt:g} s grid"


def headline_lines(report: dict) -> list[str]:
    """The headline table: per scenario (and grid) and error target, the fastest native and MuJoCo runs reaching it.

    With MuJoCo ÷ native for native simulate() and for its time loop alone, and whether a required ratio
    is met.

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        list[str]: the Markdown table lines (times in ms, errors in rad).
    """
    rows = []
    for sc in report["scenarios"]:
        for h in sc["headline"]:
            nat, loop, mj = h["native"], h["native_by_loop"], h["mujoco"]
            rows.append([scenario_label(sc), f"{h['target_rad']:.0e}", _run_text(nat, "wall_s"),
                         _run_text(loop, "loop_s"),
                         _run_text(mj, "wall_s"), _ratio(h["ratio_wall"]) + _met(h, "wall"),
                         _ratio(h["ratio_loop"]) + _met(h, "loop")])
            if h["note"]:
                rows[-1][-2] = rows[-1][-1] = f"— ({h['note']})"
    return _table(["scenario", "error ≤ (rad)", "fastest native simulate()", "fastest native time loop",
                   "fastest MuJoCo rollout", "MuJoCo ÷ native simulate()", "MuJoCo ÷ native time loop"],
                  rows, "lllllrr")


def _run_text(run: dict | None, key: str) -> str:
    """'method setting: time ms, error rad' of a headline run ('none')."""
    if run is None:
        return "none"
    return f"{run['method']} {run['setting']}: {_ms(run[key])} ms, {_e(run['max_error'])} rad"


def _met(h: dict, kind: str) -> str:
    """' (target ≥ R×: met)' for a headline entry with a required ratio, else ''."""
    req, met = h["required_ratio"], h[f"met_{kind}"]
    return "" if req is None or met is None else f" (≥ {req:g}×: {'met' if met else 'NOT met'})"


def eval_lines(report: dict) -> list[str]:
    """µs per dynamics evaluation per scenario.

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        list[str]: the Markdown table lines, with native amortised ÷ constraintDynamics checked against
        EVAL_RATIO_TARGET on EVAL_RATIO_SCENES (a scenario's second grid has none: no grid changes them).
    """
    rows = []
    for sc in report["scenarios"]:
        c = sc["eval_us"]
        if c is None:
            continue
        f = lambda k: "—" if c.get(k) is None else f"{c[k]:.3g}"
        ratio = c.get("native_amortised_over_pinocchio")
        verdict = "" if sc["name"] not in EVAL_RATIO_SCENES or ratio is None else (
            f" (target ≤ {EVAL_RATIO_TARGET:g}: {'met' if ratio <= EVAL_RATIO_TARGET else 'NOT met'})")
        rows.append([sc["name"], f("native_amortised_us"), f("native_python_us"), f("native_loop_us_per_rhs"),
                     f("mujoco_forward_us"), f("mujoco_amortised_us"), f("pinocchio_us"),
                     f("pinocchio_in_integrator_us"),
                     "—" if ratio is None else f"{ratio:.2f}{verdict}"])
    return _table(["scenario", "native amortised", "native from Python", "native in time loop (per rhs)",
                   "mj_forward from Python", "MuJoCo RK4 rollout (per stage)", "constraintDynamics from Python",
                   "Pinocchio in scipy DOP853 (per rhs)", "native amortised ÷ constraintDynamics"], rows)


def scaling_lines(report: dict) -> list[str]:
    """Scaling points and fits.

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        list[str]: Markdown lines: the table of points (µs per evaluation), then one bullet per power-law
        fit, and those of the forced-Cholesky diagnostic where the report has them.
    """
    sc = report["scaling"]
    f = lambda x: "—" if x is None else f"{x:.3g}"
    rows = [[str(p["r"]), str(p["n"]), str(p["n_total"]), f"{p['rows']}{' (planar)' if p['planar'] else ''}",
             f(p["native_amortised_us"]), f(p.get("native_cholesky_us")), f(p["native_python_us"]),
             f(p.get("mujoco_forward_us")), f(p.get("pinocchio_us")), str(p["bad_states"])] for p in sc["points"]]
    lines = _table(["arms r", "joints n", "total N", "constraint rows K", "native amortised µs",
                    "native amortised, Cholesky path forced µs", "native from Python µs", "mj_forward µs",
                    "constraintDynamics µs", "bad states"], rows)
    lines += ["", "Least-squares power laws of the native amortised µs/eval (µs ≈ c·x^p; rms residual in "
                  "decades):", ""]
    lines += _fit_lines(sc["fits"])
    if sc.get("fits_cholesky"):
        lines += ["", "The same with the dense path's Cholesky forced (rank_tol 1e-300): with the default rank_tol "
                      "1e-10 the pivoted-Cholesky fast path is taken whenever its certified bound "
                      "λ_min/λ_max ≥ 1/(‖L⁻¹‖_F² tr A) proves full rank, and for three arms or more the O(r) "
                      "Schur path wherever its own certificate holds, so the two should agree:", ""]
        lines += _fit_lines(sc["fits_cholesky"])
    return lines


def _fit_lines(fits: dict) -> list[str]:
    """One bullet per power-law fit of `scaling_fits`."""
    lines = []
    for r, fit in fits.get("in_total_joints", {}).items():
        lines.append(f"- r = {r}, in total joints N: p = {fit['exponent']:.2f}, c = {fit['coefficient']:.3g} µs "
                     f"(rms {fit['rms_log10']:.3f})")
    for n, fit in fits.get("in_arms", {}).items():
        lines.append(f"- n = {n}, in arms r: p = {fit['exponent']:.2f}, c = {fit['coefficient']:.3g} µs "
                     f"(rms {fit['rms_log10']:.3f})")
    if "all" in fits:
        a = fits["all"]
        lines.append(f"- every point, in total joints N: p = {a['exponent']:.2f}, c = {a['coefficient']:.3g} µs "
                     f"(rms {a['rms_log10']:.3f})")
    return lines


def fit_text(fit: dict | None) -> str:
    """'p = 1.02 (rms 0.011 decades)' of a `power_fit` dict ('—' without one).

    Args:
        fit: the `power_fit` dict or None.

    Returns:
        str: the exponent and the fit's rms residual.
    """
    return "—" if fit is None else f"p = {fit['exponent']:.2f} (rms {fit['rms_log10']:.3f} decades)"


def inverse_lines(inv: dict | None) -> list[str]:
    """Markdown lines of `inverse_bench`'s figures.

    Args:
        inv: the `inverse_bench` dict, or None.

    Returns:
        list[str]: a sentence on the capacity point, the scaling tables with their fits, the commands
        table; ["not measured"] without figures.
    """
    if not inv:
        return ["not measured"]
    p = inv["point"]
    lines = [f"A capacity point of `scenarios/sweeps/paper_capacity_map.yaml` (the paper carry, {p['samples']} "
             f"samples, every linear resolution and the LP bound in both capacity modes): {p['point_ms']:.1f} ms "
             f"as a payload sweep's point (the trajectory, per-sample terms and scaled LP bound shared; "
             f"{1e3 / p['point_ms']:.0f} points/s on one core); the trajectory's "
             f"closed-chain IK itself {p['trajectory_ms']:.1f} ms.", ""]
    sc, fits = inv["scaling"], inv["scaling"]["fits"]
    lines += ["| output dt s | samples | IK ms | capacity point ms |", "|---|---|---|---|"]
    lines += [f"| {q['output_dt_s']:g} | {q['samples']} | {q['trajectory_ms']:.2f} | {q['point_ms']:.2f} |"
              for q in sc["in_samples"]]
    lines += ["", f"In samples: the point {fit_text(fits.get('point_in_samples'))}, the IK "
                  f"{fit_text(fits.get('trajectory_in_samples'))}.", ""]
    lines += ["| arms r × 6 joints | samples | IK ms | capacity point ms |", "|---|---|---|---|"]
    lines += [f"| {q['r']} | {q['samples']} | {q['trajectory_ms']:.2f} | {q['point_ms']:.2f} |" for q in sc["in_arms"]]
    lines += ["", f"In arms: the point {fit_text(fits.get('point_in_arms'))}, the IK "
                  f"{fit_text(fits.get('trajectory_in_arms'))}."]
    if inv.get("commands"):
        lines += ["", "| scene | command | wall s | at its fewest samples s | above s | met (≤ 1 s) |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {c['scene']} | `coopsim {c['command']}` | {c['wall_s']:.2f} | {c['startup_s']:.2f} | "
                  f"{c['above_s']:.2f} | {'yes' if c['met'] else 'NO'} |" for c in inv["commands"]]
    return lines


def runs_lines(sc: dict) -> list[str]:
    """Every run of one scenario, Pareto-front runs marked ★.

    Args:
        sc: one scenario of the report (`coopsim.apps.bench.bench_scenario`).

    Returns:
        list[str]: the Markdown table lines (times in ms, errors in rad, violations in m or rad).
    """
    rows = []
    for r in sc["runs"]:
        extra = r["extra"]
        weld = "" if "weld_factor" not in extra else " · errors by k: " + ", ".join(
            f"{k}: {_e(v)}" for k, v in extra["errors_by_weld_factor"].items())
        rows.append([r["family"], r["method"], r["setting"], _ms(r["wall_s"]), _ms(r["loop_s"]), _e(r["max_error"]),
                     _e(r["final_violation"]), str(r["evals"]), "★" if r["pareto"] else "",
                     (r["note"] + weld).strip()])
    return _table(["family", "method", "setting", "wall (ms)", "native loop (ms)", "max joint error (rad)",
                   "final constraint violation", "evaluations", "Pareto", "note"], rows, "llllrrrrll")


def reference_line(sc: dict) -> str:
    """One sentence on the reference and its self-convergence.

    Args:
        sc: one scenario of the report (`coopsim.apps.bench.bench_scenario`).

    Returns:
        str: the sentence (tolerances, evaluations, self-convergence and smallest measured error in rad).
    """
    ref = sc["reference"]
    verdict = "far below every target" if ref["far_below_targets"] else "NOT far below the targets"
    small = ref["smallest_measured_error_rad"]
    return (f"Reference: native DOP853 rtol {ref['rtol']:.0e}, atol {ref['atol']:.0e} ({ref['rhs_evaluations']} "
            f"evaluations); against rtol {ref['check_rtol']:.0e} it differs by {_e(ref['self_convergence_rad'])} rad "
            f"({verdict}; smallest error measured {_e(small)} rad — errors within ~10× of the self-convergence "
            f"difference are at the reference's floor).")


def startup_line(st: dict) -> str:
    """One sentence on the compile and cached start-up times (`bench.startup_times`).

    Args:
        st: the `bench.startup_times` dict (s).

    Returns:
        str: the sentence (times in s).
    """
    text = (f"First run with an empty numba cache (fresh process compiling every kernel on two processes, as the "
            f"CLI's first run): {st['compile_s']:.1f} s; the same with the cache filled: {st['cached_s']:.2f} s "
            f"(of which imports and a 0.05 s run: {st['cached_inside_s']:.2f} s")
    if "jit_load_s" in st:
        text += (f"; loading numba and the compiled kernels from the cache: {st['jit_load_s']:.2f} s; the "
                 f"interpreter's own start: {st['interpreter_s']:.2f} s")
    text += ")."
    if st.get("sources_changed"):
        text += " Sources changed between the two processes: the cached time includes a recompilation."
    return text


def command_lines(commands: dict | None) -> list[str]:
    """A table of the commands' wall times against their targets (`bench.command_times`).

    Args:
        commands: the `bench.command_times` dict (s), or None.

    Returns:
        list[str]: the Markdown table lines; ["not measured"] without commands.
    """
    if not commands:
        return ["not measured"]
    lines = ["| command | wall s | target s | met |", "|---|---|---|---|"]
    lines += [f"| `coopsim {name}` | {c['wall_s']:.2f} | {c['target_s']:g} | {'yes' if c['met'] else 'NO'} |"
              for name, c in commands.items()]
    return lines


def _load(env: dict) -> str:
    """'a → b' 1-minute load averages at the start and end of the run ('unknown')."""
    a, b = env.get("load_average"), env.get("load_average_end")
    return "unknown" if not a else f"{a[0]:.2f}" + ("" if not b else f" → {b[0]:.2f} (1 min)")


def markdown_report(report: dict) -> str:
    """The whole report as Markdown.

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).

    Returns:
        str: the Markdown text: machine and method, headline, µs per evaluation, start-up, commands,
        scaling, the inverse side, then every scenario's reference and runs; ending in a newline.
    """
    env, st = report["environment"], report.get("startup")
    lines = ["# Work-precision benchmark", "",
             f"Machine: {env['cpus']} CPUs, {env['platform']}; Python {env['python']}, numba {env['numba']}, "
             f"MuJoCo {env['mujoco']}, pin {env['pin'] or 'not installed'}; load average {_load(env)}; code "
             f"{(env.get('git_head') or 'unknown')[:10]} + sources {env.get('sources_sha256')}. "
             f"Wall times: minimum over repeats in one "
             f"process. Native: `simulate()` end to end (initial projection and sampling included), and its compiled "
             f"time loop alone; MuJoCo: the `Rollout.rollout` call alone; Pinocchio: `solve_ivp` alone. Errors: max "
             f"|Δθ| over every joint on a {OUTPUT_DT:g} s grid (and for {_own(report)} on its own output grid "
             f"too: every sample is reported) against the native reference on the same grid "
             f"(DOP853 rtol {REFERENCE_RTOL:.0e}, atol {REFERENCE_ATOL:.0e}). Adaptive ladders use "
             f"atol = {ATOL_RATIO:g}·rtol and no step bound.", "", "## Headline", ""]
    lines += headline_lines(report) + ["", "## µs per dynamics evaluation", ""] + eval_lines(report)
    lines += ["", "## Start-up", ""]
    lines.append("not measured" if st is None else startup_line(st))
    lines += ["", "## Commands (first scenario, fresh processes, cache filled)", ""]
    lines += command_lines(report.get("commands"))
    lines += ["", "## Scaling (synthetic scenes)", ""] + scaling_lines(report)
    lines += ["", "## The inverse side", ""] + inverse_lines(report.get("inverse"))
    for sc in report["scenarios"]:
        lines += ["", f"## {sc['name']}, {sc['duration_s']:g} s, {sc['output_dt_s']:g} s grid", "",
                  reference_line(sc), ""]
        lines += [f"- {n}" for n in sc["notes"]] + ([""] if sc["notes"] else [])
        lines += runs_lines(sc)
    return "\n".join(lines) + "\n"


def _own(report: dict) -> str:
    """The scenarios also benchmarked on their own output grid, as text ('none')."""
    names = [sc["name"] for sc in report["scenarios"] if abs(sc["output_dt_s"] - OUTPUT_DT) > 1e-12]
    return ", ".join(names) or "none"


def figure_name(sc: dict) -> str:
    """work_precision_NAME.png (OUTPUT_DT grid), work_precision_NAME_Xms.png on another grid.

    Args:
        sc: one scenario of the report (`coopsim.apps.bench.bench_scenario`).

    Returns:
        str: the file name.
    """
    dt = sc["output_dt_s"]
    grid = "" if abs(dt - OUTPUT_DT) <= 1e-12 else f"_{1e3 * dt:g}ms"
    return f"work_precision_{sc['name']}{grid}.png"


def write_outputs(report: dict, out: str | Path) -> list[Path]:
    """Write the report's files into `out`, each atomically.

    bench.json, bench.md, runs.csv, scaling.csv, a work-precision figure per scenario and grid
    (`figure_name`) and scaling.png (only with scaling points).

    Args:
        report: the benchmark report (`coopsim.apps.bench.run_bench`).
        out: the folder (created if missing).

    Returns:
        list[Path]: the paths, in that order.
    """
    out = Path(out)
    paths = [write_text_atomic(out / "bench.json", json_text(report)),
             write_text_atomic(out / "bench.md", markdown_report(report)),
             write_text_atomic(out / "runs.csv", csv_text(report)),
             write_text_atomic(out / "scaling.csv", scaling_csv_text(report))]
    paths += [work_precision_figure(sc, out / figure_name(sc)) for sc in report["scenarios"]]
    if report["scaling"]["points"]:
        paths.append(scaling_figure(report["scaling"], out / "scaling.png"))
    return paths
