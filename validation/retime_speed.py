"""Speed of `coopsim optimize --retime`'s solvers on the paper carry against the grid: one payload's minimum
time and the heaviest payload within the scenario's 13 s, per method, grid (intervals a segment) and solver.

    python validation/retime_speed.py [--intervals 25,50,100,200] [--methods min_energy,lp] [--solvers
        reachability,grid_lp] [--repeats 3]

(the LP bound's reachability is its compiled stage-LP pass, `coopsim.inverse.retime.lp_reachability`).

Each solve as the command makes it (the rows of the check points between the grid points included,
`coopsim.inverse.retime.retime`), after one untimed solve (the compiled pass loaded, the check points'
dynamics computed); the best of `repeats` wall times (the 2-core machine is shared). Prints a Markdown
table and the exponents p of time ∝ N^p fitted by least squares in log–log over the grids, and the
1-minute load average before and after.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from coopsim.inverse import retime as rt  # noqa: E402
from coopsim.inverse.path import WaypointPath, joint_path, path_grid  # noqa: E402
from coopsim.io.scenario import load_scenario  # noqa: E402


def best_of(repeats: int, f):
    """(the least wall time in s of `repeats` calls of f, its last result)."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--intervals", default="25,50,100,200")
    ap.add_argument("--methods", default="min_energy,lp")
    ap.add_argument("--solvers", default="reachability,grid_lp")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    model = load_scenario(ROOT / "scenarios" / "paper_planar_2x3_carry.yaml")
    om = model.inverse.object_motion
    path = WaypointPath.of(om)
    T = float(om.times[-1] - om.times[0])
    grids = [int(x) for x in args.intervals.split(",")]
    methods = args.methods.split(",")
    solvers = args.solvers.split(",")
    load0 = os.getloadavg()[0]
    rows = {(m, x): [] for m in methods for x in solvers}
    for n in grids:
        s, piece = path_grid(path.knots, n)
        jp = joint_path(model, path, s, piece, om.initial_guess)
        for m in methods:
            dyn = rt.path_dynamics(model, jp, m)
            for x in solvers:
                rt.retime(dyn, dyn.nominal_mass, x)
                one, r = best_of(args.repeats, lambda: rt.retime(dyn, dyn.nominal_mass, x))
                heavy, (mass, _, solves) = best_of(max(1, args.repeats - 1), lambda: rt.max_payload(dyn, T, x))
                rows[m, x].append((n, len(s), one, heavy, solves, mass, r.duration, rt.default_solver(dyn) == x))
    print(f"paper carry, T_max {T:g} s; load average {load0:.2f} -> {os.getloadavg()[0]:.2f}\n")
    print("| method | solver | intervals a segment | grid points | one payload | heaviest payload (solves) | kg "
          "| bare min time s |")
    print("|---|---|---|---|---|---|---|---|")
    for (m, x), rr in rows.items():
        for n, N, one, heavy, solves, mass, T0, default in rr:
            print(f"| {m} | {x}{' (default)' if default else ''} | {n} | {N} | {one * 1e3:.1f} ms | {heavy:.3f} s "
                  f"({solves}) | {mass:.10g} | {T0:.12g} |")
    for (m, x), rr in rows.items():
        if len(rr) > 1:
            N = np.log([r[1] for r in rr])
            fit = [np.polyfit(N, np.log([r[k] for r in rr]), 1)[0] for k in (2, 3)]
            print(f"\n{m}, {x}: one payload ∝ N^{fit[0]:.2f}, heaviest payload ∝ N^{fit[1]:.2f}")

if __name__ == "__main__":
    main()
