"""Figures of the work-precision benchmark (`coopsim.apps.bench`), PNG via matplotlib's Agg canvas.

`work_precision_figure`: one scenario, log–log, x the max joint error rad, y the wall time s; one
line per (family, method) in ladder order, each point labelled with its tolerance or step (native:
`simulate()` end to end; hollow markers on dotted lines: its time loop alone), the
Pareto front over every run drawn as a staircase with ringed points, the error targets and the
reference's self-convergence difference as vertical lines. Runs with a non-finite error (diverged,
failed) are left out; the legend stands beside the axes. `scaling_figure`: µs per evaluation against
total joints, one line per r.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from coopsim.plots.figure import legend_beside, legend_width, panel_grid
from coopsim.plots.render import save_figure

ERROR_FLOOR = 1e-17  # rad: where an error of exactly zero is drawn
_STYLE = {("native", "dop853"): ("C0", "o"), ("native", "dopri5"): ("C1", "o"), ("native", "rk4"): ("C2", "o"),
          ("mujoco", "RK4"): ("C3", "s"), ("mujoco", "Euler"): ("C4", "s"), ("mujoco", "implicitfast"): ("C5", "s"),
          ("mujoco", "implicit"): ("C6", "s")}


def _series(runs: list[dict]) -> dict[tuple[str, str], list[dict]]:
    """Runs with a finite error and time, grouped by (family, method), in order of appearance."""
    out: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        if np.isfinite(r["max_error"]) and np.isfinite(r["wall_s"]):
            out.setdefault((r["family"], r["method"]), []).append(r)
    return out


def _draw_pareto(ax, runs: list[dict]) -> None:
    """The Pareto front as a staircase (error increasing, time decreasing) with ringed points."""
    front = sorted((max(r["max_error"], ERROR_FLOOR), r["wall_s"]) for r in runs if r["pareto"])
    if not front:
        return
    e, t = zip(*front)
    ax.step(e, t, where="post", color="0.3", lw=1.0, ls="--", zorder=1, label="Pareto front")
    ax.scatter(e, t, s=140, facecolors="none", edgecolors="0.2", lw=1.2, zorder=4)


def work_precision_plot(scenario: dict) -> Figure:
    """The work-precision figure of one `bench_scenario` dict (module docstring); legend beside it.

    Args:
        scenario: one `bench_scenario` dict (`coopsim.apps.bench`): its name, duration_s, output_dt_s, reference
            (self_convergence_rad, rad) and runs (family, method, label, max_error rad, wall_s s,
            loop_s s or None, pareto).

    Returns:
        Figure: the matplotlib figure (not yet written).
    """
    series = _series(scenario["runs"])
    sc = scenario["reference"]["self_convergence_rad"]
    labels = [f"{family} {method}" for family, method in series] + [
        "Pareto front", "reference self-convergence", "native time loop alone"]
    fig = Figure()
    ax = panel_grid(fig, 1, 1, (7.0, 5.2), legend=legend_width(labels), suptitle=False)[0, 0]
    for (family, method), rows in series.items():
        color, marker = _STYLE.get((family, method), ("k", "^"))
        e = [max(r["max_error"], ERROR_FLOOR) for r in rows]
        t = [r["wall_s"] for r in rows]
        ax.loglog(e, t, marker=marker, color=color, ms=5, lw=1, label=f"{family} {method}", zorder=3)
        for x, y, r in zip(e, t, rows):
            ax.annotate(r["label"], (x, y), xytext=(3, 3), textcoords="offset points", fontsize=6, color=color)
        loop = [(x, r["loop_s"]) for x, r in zip(e, rows) if r.get("loop_s")]
        if loop:
            ax.loglog(*zip(*loop), marker=marker, color=color, ms=4, lw=0.6, ls=":", mfc="none", zorder=2)
    _draw_pareto(ax, scenario["runs"])
    for target in (1e-3, 1e-6, 1e-8):
        ax.axvline(target, color="0.6", lw=0.8, ls=":")
    if sc > 0:
        ax.axvline(sc, color="C0", lw=0.8, ls="-.", label=labels[-2])
    ax.set_xlabel("max joint error against the reference (rad)")
    ax.set_ylabel("wall time (s)")
    ax.set_title(f"Work–precision: {scenario['name']}, {scenario['duration_s']:g} s, "
                 f"{scenario['output_dt_s']:g} s grid")
    ax.grid(True, which="both", alpha=0.25)
    ax.plot([], [], "o:", color="0.4", mfc="none", ms=4, lw=0.6, label=labels[-1])
    legend_beside(ax)
    return fig


def work_precision_figure(scenario: dict, path: Path) -> Path:
    """Work-precision plot of one `bench_scenario` dict, written to `path` (PNG, atomically).

    Args:
        scenario: one `bench_scenario` dict (`coopsim.apps.bench`): its name, duration_s, output_dt_s, reference
            (self_convergence_rad, rad) and runs (family, method, label, max_error rad, wall_s s,
            loop_s s or None, pareto).
        path: the PNG file to write.

    Returns:
        Path: `path`, written.
    """
    return save_figure(work_precision_plot(scenario), path)


def scaling_figure(scaling: dict, path: Path) -> Path:
    """Native amortised µs per evaluation against total joints (log–log), one colour per r.

    Dots: default; crosses: the Cholesky path forced; with the per-r power-law fits of the default;
    written to `path` (PNG, atomically).

    Args:
        scaling: the `scaling_study` dict (`coopsim.apps.bench`): points (each with r, n_total,
            native_amortised_us µs and native_cholesky_us µs) and fits (in_total_joints: per r as a
            string, coefficient and exponent).
        path: the PNG file to write.

    Returns:
        Path: `path`, written.
    """
    pts = scaling["points"]
    fig = Figure()
    ax = panel_grid(fig, 1, 1, (5.0, 3.6), legend=legend_width(["r = 4, Cholesky forced", "fit: N^0.00"]),
                    suptitle=False)[0, 0]
    for i, r in enumerate(sorted({p["r"] for p in pts})):
        sel = sorted((p for p in pts if p["r"] == r), key=lambda p: p["n_total"])
        x = np.array([p["n_total"] for p in sel], float)
        ax.loglog(x, [p["native_amortised_us"] for p in sel], "o", color=f"C{i}", label=f"r = {r}")
        if all(p.get("native_cholesky_us") for p in sel):
            ax.loglog(x, [p["native_cholesky_us"] for p in sel], "x", color=f"C{i}", label=f"r = {r}, Cholesky forced")
        fit = scaling["fits"].get("in_total_joints", {}).get(str(r))
        if fit:
            xs = np.linspace(x.min(), x.max(), 20)
            ax.loglog(xs, fit["coefficient"] * xs ** fit["exponent"], "-", color=f"C{i}", lw=0.8,
                      label=f"fit: N^{fit['exponent']:.2f}")
    ax.set_xlabel("total joints N")
    ax.set_ylabel("native µs per evaluation (amortised, 1 thread)")
    ax.set_title("Cost per closed-chain evaluation")
    ax.grid(True, which="both", alpha=0.25)
    legend_beside(ax)
    return save_figure(fig, path)
