"""Speed against error: the native closed-chain model and the MuJoCo twin at several tolerances and
steps, each measured against a tight native reference on the same machine in the same run.

    python validation/speed_error.py [SCENARIO] [--duration S] [--out validation/results]

Writes speed_error_NAME.md (a table) and speed_error_NAME.png. Wall times are reported as ratios to
one MuJoCo RK4 run at its scenario timestep (these machines are noisy: compare within a run).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from coopsim.atomic import write_text_atomic  # noqa: E402
from coopsim.mujoco_run import run_twin  # noqa: E402
from coopsim.plots import save_figure  # noqa: E402
from coopsim.scenario import load_scenario  # noqa: E402
from coopsim.simulate import simulate  # noqa: E402


def _timed(fn, repeat: int = 1):
    best, out = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return out, best


def measure(model, duration: float) -> list[dict]:
    # a coarse output grid lets the adaptive steps grow to what their tolerance allows
    model = replace(model, duration=duration, integrator=replace(model.integrator, output_dt=0.05, step=0.05))
    tight = replace(model.integrator, method="dop853", rtol=1e-13, atol=1e-14)
    ref = simulate(model, settings=tight)
    q0, qd0 = ref.initial.q, ref.initial.qd
    rows = []
    _, base = _timed(lambda: run_twin(model, q0, qd0, ref.t), repeat=3)
    cases = [("native dop853", f"rtol {r:g}", replace(model.integrator, method="dop853", rtol=r, atol=r / 10))
             for r in (1e-6, 1e-8, 1e-10, 1e-12)]
    cases += [("native rk4", f"step {h:g} s", replace(model.integrator, method="rk4", step=h)) for h in (1e-2, 5e-3, 2e-3)]
    for label, setting, s in cases:
        res, wall = _timed(lambda: simulate(model, settings=s))
        rows.append({"model": label, "setting": setting, "wall_s": wall, "ratio": wall / base,
                     "max_angle_error_rad": float(np.max(np.abs(res.q - ref.q))),
                     "max_residual": float(np.max(res.residual_pos))})
    for dt in (2e-3, 1e-3, 5e-4, 2.5e-4):
        mj = replace(model, mujoco=replace(model.mujoco, timestep=dt, weld_solref=None))
        tw, wall = _timed(lambda: run_twin(mj, q0, qd0, ref.t))
        rows.append({"model": "mujoco RK4", "setting": f"step {dt:g} s, weld timeconst {dt:g} s", "wall_s": wall,
                     "ratio": wall / base, "max_angle_error_rad": float(np.max(np.abs(tw.q - ref.q))),
                     "max_residual": float(np.max(tw.weld_violation))})
    return rows


def table(name: str, duration: float, rows: list[dict], base_dt: float) -> str:
    lines = [f"# Speed against error: {name}, {duration:g} s", "",
             f"Reference: native dop853 at rtol 1e-13. Ratio: wall time / MuJoCo RK4 at the scenario's "
             f"{base_dt:g} s step (same run, same machine).", "",
             "| model | setting | wall (s) | ratio | max angle error (rad) | max constraint violation |",
             "|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['setting']} | {r['wall_s']:.3f} | {r['ratio']:.1f} | "
                     f"{r['max_angle_error_rad']:.2e} | {r['max_residual']:.2e} |")
    return "\n".join(lines) + "\n"


def figure(name: str, rows: list[dict], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label in dict.fromkeys(r["model"] for r in rows):
        sel = [r for r in rows if r["model"] == label]
        ax.loglog([r["ratio"] for r in sel], [max(r["max_angle_error_rad"], 1e-16) for r in sel], "o-", label=label)
    ax.set_xlabel("wall time / MuJoCo RK4 run at the scenario step")
    ax.set_ylabel("max joint-angle error vs reference (rad)")
    ax.set_title(f"Speed against error: {name}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    save_figure(fig, path)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", default="scenarios/paper_planar_2x3.yaml")
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--out", default="validation/results")
    args = ap.parse_args()
    model = load_scenario(args.scenario)
    rows = measure(model, args.duration)
    out = Path(args.out)
    text = table(model.name, args.duration, rows, model.mujoco.timestep)
    write_text_atomic(out / f"speed_error_{model.name}.md", text)
    figure(model.name, rows, out / f"speed_error_{model.name}.png")
    print(text)


if __name__ == "__main__":
    main()
