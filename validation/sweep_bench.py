"""Throughput of `coopsim sweep` on the bundled paper capacity map: serial against the embedded Dask
LocalCluster (2 worker processes × 1 thread), the same points, identical tables required.

    python validation/sweep_bench.py [SWEEP.yaml] [--workers 2] [--repeats 1] [--out out/sweep_bench]

Each run goes through the library as `coopsim sweep` does (`run_sweep`, then `write_outputs` for the
Dask run's figures, which are not timed); the compiled kernels are loaded before the first timing. The
Dask time is end to end: the cluster's start (workers forked from this process) and close included.
Writes OUT/sweep_bench.json and prints a Markdown table; the 1-minute load average is recorded before
and after each run (other work on the machine slows both, and the ratio more than the times), and the
CPU time of each run (this process and, for Dask, its forked workers): their ratio is the parallel
run's overhead, which other work does not change much.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from coopsim.apps.sweep import evaluate_point, load_sweep  # noqa: E402
from coopsim.apps.sweep_run import run_sweep, write_outputs  # noqa: E402


def cpu_seconds() -> float:
    """CPU time (user + system) of this process and of its children that have ended (the embedded
    cluster's workers, once it is closed)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def timed_run(sweep, out: Path, **how) -> tuple[float, float, list, tuple[float, float]]:
    """(wall s, CPU s, the run, 1-minute load average before and after)."""
    shutil.rmtree(out, ignore_errors=True)
    load = os.getloadavg()[0]
    cpu, start = cpu_seconds(), time.perf_counter()
    run = run_sweep(sweep, out, **how)
    return time.perf_counter() - start, cpu_seconds() - cpu, run, (load, os.getloadavg()[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", nargs="?", default=str(ROOT / "scenarios/sweeps/paper_capacity_map.yaml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--out", default="out/sweep_bench")
    args = ap.parse_args()
    sweep = load_sweep(args.sweep)
    out = Path(args.out)
    evaluate_point(sweep, 0)                    # load the compiled kernels and the study's modules
    runs = []
    for _ in range(args.repeats):
        for label, how in (("serial", {"serial": True}), (f"dask {args.workers} workers", {"workers": args.workers})):
            wall, cpu, run, load = timed_run(sweep, out / label.split()[0], **how)
            runs.append({"executor": label, "wall_s": wall, "cpu_s": cpu, "points": len(run.rows),
                         "points_per_s": len(run.rows) / wall, "load_average_1min": list(load), "rows": run.rows})
    tables = [json.dumps(r.pop("rows"), sort_keys=True) for r in runs]
    serial = [r for r in runs if r["executor"] == "serial"]
    dask = [r for r in runs if r["executor"] != "serial"]
    best_s, best_d = min(r["wall_s"] for r in serial), min(r["wall_s"] for r in dask)
    cpu_ratio = min(r["cpu_s"] for r in dask) / min(r["cpu_s"] for r in serial)
    report = {"sweep": args.sweep, "points": runs[0]["points"], "identical_tables": len(set(tables)) == 1,
              "speedup_best": best_s / best_d, "cpu_ratio_dask_over_serial": cpu_ratio, "runs": runs,
              "cpus": os.cpu_count(), "python": platform.python_version()}
    write_outputs(sweep, run, out / "dask")     # the last Dask run's figures (not timed)
    (out / "sweep_bench.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"{Path(args.sweep).name}: {report['points']} points, identical tables: {report['identical_tables']}")
    print("| executor | wall (s) | CPU (s) | points/s | load average (1 min) before, after |\n|---|---|---|---|---|")
    for r in runs:
        print(f"| {r['executor']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['points_per_s']:.2f} | "
              f"{r['load_average_1min'][0]:.2f}, {r['load_average_1min'][1]:.2f} |")
    print(f"speed-up (best of each): {report['speedup_best']:.2f}x; CPU time of the Dask run / the serial one: "
          f"{cpu_ratio:.2f}; wrote {out / 'sweep_bench.json'}")


if __name__ == "__main__":
    main()
