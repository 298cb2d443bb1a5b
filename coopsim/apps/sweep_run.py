"""Running a sweep: its points serially or on Dask, checkpointed as they finish, and its outputs.

Execution (`run_points`): in this process (`serial`), on an embedded `dask.distributed.LocalCluster`
(default: one worker process per core, one thread each), or on an existing cluster (`scheduler`, an
address such as tcp://10.0.0.5:8786); the rows are the same whatever runs them (each point is a pure
function of the sweep, `coopsim.apps.sweep.evaluate_point`) and are ordered by point index.

Checkpoint: `DIR/points.jsonl`, a header line {"sweep": digest, "points": P} then one line per finished
point ({"row": ...}, floats exact), appended, flushed and fsynced as each point arrives. `resume` keeps
the rows of a checkpoint of the same sweep (same digest; a line cut short by a kill is dropped) and runs
only the others.

Outputs (`write_outputs`, one set: `coopsim.io.atomic.staged_folder`, files of earlier sets listed in
sweep.json replaced, the checkpoint and anything else kept): results.parquet and results.csv (one row
per point), sweep.json (the summary), sweep.mcap (one JSON message per point on /sweep/point, log time =
the point index in seconds, for Foxglove's Plot panel), and the figures of `coopsim.plots.sweep`.
"""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import logging
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from coopsim.apps.sweep import Sweep, error_text, evaluate_point, matcher
from coopsim.core.errors import CoopsimError
from coopsim.core.labels import field_name
from coopsim.io.atomic import previous_set, staged_folder, write_text_atomic
from coopsim.io.mcap_codec import JsonTopic, nonfinite_name, stamp, time_ns, write_mcap
from coopsim.plots.sweep import sweep_figures
from coopsim.report.inverse_report import json_safe

CHECKPOINT = "points.jsonl"
# Dask's housekeeping on the embedded cluster, made sparse for points that take about a second: no
# statistical profiler (it takes the GIL every 10 ms and slows the points), no GIL monitor, event-loop,
# system and memory checks every 0.2, 2 and 1 s instead of 20, 500 and 100 ms.
QUIET = {"distributed.worker.profile.enabled": False, "distributed.admin.system-monitor.gil.enabled": False,
         "distributed.admin.tick.interval": "200ms", "distributed.admin.system-monitor.interval": "2s",
         "distributed.worker.memory.monitor-interval": "1s"}
INDEX = "sweep.json"


@dataclass(frozen=True)
class SweepRun:
    """A finished sweep: every point's row and how they were obtained.

    Attributes:
        rows: one row per point (:func:`coopsim.apps.sweep.evaluate_point`), ordered by point.
        computed: the number of points run now.
        resumed: the number of points taken from the checkpoint.
        executor: what ran the points, as text (e.g. "serial (this process)").
        wall_time_s: s, the wall time of the points run now.
    """

    rows: list[dict]
    computed: int
    resumed: int
    executor: str
    wall_time_s: float


# ------------------------------------------------------------------------------------------------
# checkpoint
# ------------------------------------------------------------------------------------------------

def read_checkpoint(path: Path, sweep: Sweep) -> dict[int, dict]:
    """The rows of the checkpoint at `path` if it is one of `sweep` (same digest).

    A line that does not parse (the last one, cut short by a kill) is dropped, as is a row whose point is
    not one of the sweep's.

    Args:
        path: the checkpoint file (DIR/points.jsonl).
        sweep: the sweep being resumed (its digest and point count).

    Returns:
        dict: point index → row; {} where there is no file.

    Raises:
        CoopsimError: the file is another sweep's checkpoint, or not a sweep checkpoint at all.
    """
    try:
        lines = path.read_text(encoding="utf-8").split("\n")
    except FileNotFoundError:
        return {}
    try:
        header = json.loads(lines[0])
        if header.get("sweep") != sweep.digest:
            raise CoopsimError(f"{path}: --resume: the checkpoint is another sweep's (the sweep file, its scenario "
                               f"or --set changed); run without --resume to start again")
    except (ValueError, AttributeError):
        raise CoopsimError(f"{path}: --resume: not a sweep checkpoint (its first line is not the sweep's header); "
                           f"run without --resume to start again") from None
    rows = {}
    for line in lines[1:]:
        try:
            row = json.loads(line)["row"]
        except (ValueError, KeyError, TypeError):     # the line a kill cut short (or an empty last line)
            continue
        if isinstance(row, dict) and isinstance(row.get("point"), int) and 0 <= row["point"] < len(sweep.points):
            rows[row["point"]] = row
    return rows


class Checkpoint:
    """The append-only checkpoint file: `append(row)` writes one line, flushed and fsynced.

    Opening it writes the header line {"sweep": digest, "points": P, "name": NAME} (atomically, replacing
    any file there) unless `resume` finds a file, whose unfinished last line is then cut. A context
    manager: leaving the `with` block closes the file.

    Args:
        path: the checkpoint file (its folder is made when missing).
        sweep: the sweep (its digest, point count and name go into the header).
        resume: keep an existing file and append to it.

    Attributes:
        file: the text file open for appending.
    """

    def __init__(self, path: Path, sweep: Sweep, resume: bool):
        path.parent.mkdir(parents=True, exist_ok=True)
        if not resume or not path.is_file():
            write_text_atomic(path, json.dumps({"sweep": sweep.digest, "points": len(sweep.points),
                                                "name": sweep.name}) + "\n")
        else:
            _end_line(path)
        self.file = open(path, "a", encoding="utf-8")

    def append(self, row: dict) -> None:
        """Append one finished point's row as a line {"row": ...}, flushed and fsynced.

        Args:
            row: the point's row (non-finite floats written as JSON's NaN / Infinity).
        """
        self.file.write(json.dumps({"row": row}, allow_nan=True) + "\n")
        self.file.flush()
        os.fsync(self.file.fileno())

    def close(self) -> None:
        """Close the file."""
        self.file.close()

    def __enter__(self) -> Checkpoint:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _end_line(path: Path) -> None:
    """Cut a last line that a kill left unfinished (no newline), so appended lines start clean."""
    with open(path, "rb+") as f:
        data = f.read()
        if data and not data.endswith(b"\n"):
            f.truncate(data.rfind(b"\n") + 1)


# ------------------------------------------------------------------------------------------------
# execution
# ------------------------------------------------------------------------------------------------

def require_packages(dask: bool) -> None:
    """Check that what the `sweep` extra installs is there, naming what to install otherwise.

    Args:
        dask: also require Dask's distributed scheduler (a run not `serial`); pyarrow (the results table) is
            always required.

    Raises:
        CoopsimError: pyarrow or, with `dask`, distributed is missing.
    """
    missing = [m for m in ("pyarrow",) + (("distributed",) if dask else ()) if importlib.util.find_spec(m) is None]
    if missing:
        raise CoopsimError(f"coopsim sweep needs {' and '.join(missing)}, which {'is' if len(missing) == 1 else 'are'} "
                           f"not installed: pip install 'coopsim[sweep]'")


def run_sweep(sweep: Sweep, out: str | Path, serial: bool = False, scheduler: str | None = None,
              workers: int | None = None, resume: bool = False,
              progress: Callable[[float], None] | None = None) -> SweepRun:
    """Run every point of `sweep` not already in the checkpoint and return all rows ordered by point.

    Each finished point is appended to the checkpoint DIR/points.jsonl as it arrives, and
    progress(fraction of the points done) is called (first with the resumed share).

    Args:
        sweep: the sweep.
        out: the output folder DIR (holding the checkpoint).
        serial: run the points in this process (see :func:`run_points`).
        scheduler: the address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786); None: an embedded
            LocalCluster.
        workers: the LocalCluster's worker processes; None: one per core.
        resume: keep the rows of a checkpoint of the same sweep and run only the other points; False starts
            the checkpoint afresh.
        progress: called with the fraction of the points done; or None.

    Returns:
        SweepRun: the rows of every point and the counts, executor and wall time of this run.

    Raises:
        CoopsimError: with `resume`, a checkpoint of another sweep; a bad `workers` or an unreachable
            `scheduler`.
    """
    ckpt = Path(out) / CHECKPOINT
    done = read_checkpoint(ckpt, sweep) if resume else {}
    todo = [i for i in range(len(sweep.points)) if i not in done]
    resumed, total = len(done), len(sweep.points)
    start = time.perf_counter()
    with Checkpoint(ckpt, sweep, resume) as cp:
        if progress is not None:
            progress(resumed / total)
        rows, executor = run_points(sweep, todo, serial, scheduler, workers)
        for row in rows:
            cp.append(row)
            done[row["point"]] = row
            if progress is not None:
                progress(len(done) / total)
    return SweepRun([done[i] for i in range(total)], len(todo), resumed, executor, time.perf_counter() - start)


def run_points(sweep: Sweep, todo: list[int], serial: bool = False, scheduler: str | None = None,
               workers: int | None = None) -> tuple[Iterator[dict], str]:
    """The rows of the points `todo` as they finish, and a description of what runs them.

    In this process (`serial`), on the Dask cluster at `scheduler`, or on an embedded LocalCluster of
    `workers` processes (default: one per core) with one thread each. The rows come lazily: the points run
    while the iterator is consumed.

    Args:
        sweep: the sweep.
        todo: the point indices to run (0-based).
        serial: run them in this process, in order.
        scheduler: the address of an existing Dask scheduler; None: an embedded LocalCluster.
        workers: the LocalCluster's worker processes, at least 1; None: one per core.

    Returns:
        tuple: (Iterator[dict] of the rows, in the order they finish; str, the executor's description).

    Raises:
        CoopsimError: `workers` below 1; while iterating, a `scheduler` that does not answer.
    """
    if serial:
        return (evaluate_point(sweep, i) for i in todo), "serial (this process)"
    if workers is not None and workers < 1:
        raise CoopsimError(f"--workers: must be at least 1, got {workers}")
    n = workers or os.cpu_count() or 1
    what = f"Dask cluster at {scheduler}" if scheduler else f"Dask LocalCluster, {n} worker processes × 1 thread"
    return _dask_rows(sweep, todo, scheduler, n), what


def _dask_rows(sweep: Sweep, todo: list[int], scheduler: str | None, workers: int) -> Iterator[dict]:
    """Rows from Dask as they finish; a point whose task fails (a worker killed, ...) is a row with
    that error. The embedded cluster's worker processes are forked from this one where the platform
    forks safely (Linux) after it has run the first point itself: that point loads the compiled
    kernels and the study's modules, which the workers then share instead of loading them each (a
    spawned worker takes seconds to start; a forked one a fraction of a second), with the settings
    `QUIET`."""
    if not todo:
        return
    if scheduler:
        yield from _on_cluster(sweep, todo, scheduler, None)
        return

    import dask
    import distributed  # noqa: F401 — its config defaults, before they are set in a context below

    method = "fork" if sys.platform.startswith("linux") else "spawn"
    if method == "fork":
        yield evaluate_point(sweep, todo[0])
        todo = todo[1:]
    with dask.config.set({"distributed.worker.multiprocessing-method": method} | QUIET):
        yield from _on_cluster(sweep, todo, None, workers)


CHUNK_POINTS = 64          # points per Dask task at most
CHUNKS_PER_WORKER = 8      # tasks per worker at least, where there are points enough (the load stays balanced)


def chunks(todo: list[int], workers: int) -> list[list[int]]:
    """The points `todo` cut into consecutive tasks of one size: at most CHUNK_POINTS each, and at least
    CHUNKS_PER_WORKER tasks per worker where there are enough points, so a point of a few milliseconds
    does not pay a task's scheduling each.

    Args:
        todo: the points' indices.
        workers: the cluster's workers (one at least).

    Returns:
        list[list[int]]: the tasks' points, in order, covering `todo` once.
    """
    size = max(1, min(CHUNK_POINTS, len(todo) // (CHUNKS_PER_WORKER * max(1, workers))))
    return [todo[i:i + size] for i in range(0, len(todo), size)]


def evaluate_points(sweep: Sweep, indices: list[int]) -> list[dict[str, Any]]:
    """The rows of several points (`evaluate_point` each): one Dask task.

    Args:
        sweep: the sweep.
        indices: the points, 0-based.

    Returns:
        list[dict]: their rows, in the order of `indices`.
    """
    return [evaluate_point(sweep, i) for i in indices]


def _on_cluster(sweep: Sweep, todo: list[int], scheduler: str | None, workers: int | None) -> Iterator[dict]:
    """Rows of the points `todo` from the cluster at `scheduler`, or from a LocalCluster of `workers`
    processes × 1 thread started (and closed) here."""
    from dask.distributed import Client, LocalCluster, as_completed

    if not todo:
        return
    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise CoopsimError(f"--scheduler {scheduler}: no Dask scheduler answers there ({error_text(exc)})") from None
        cluster = None
    else:
        with warnings.catch_warnings():     # "Port 8787 is already in use": the scheduler's HTTP routes move
            warnings.filterwarnings("ignore", message="Port .* is already in use")
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
        client = Client(cluster)
    try:
        shared = client.scatter(sweep, broadcast=True)
        futures = {client.submit(evaluate_points, shared, part, pure=False,
                                 key=f"coopsim-sweep-{sweep.digest[:12]}-{part[0]}-{part[-1]}"): part
                   for part in chunks(todo, workers or len(client.scheduler_info()["workers"]) or 1)}
        for fut in as_completed(futures):
            try:
                yield from fut.result()
            except Exception as exc:     # noqa: BLE001 — the task itself failed (evaluate_point catches the point's)
                for i in futures[fut]:
                    yield {"point": i} | {a.name: float(v) for a, v in zip(sweep.axes, sweep.points[i])} \
                        | {"error": f"Dask: {error_text(exc)}"}
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# ------------------------------------------------------------------------------------------------
# outputs
# ------------------------------------------------------------------------------------------------

def columns_of(rows: list[dict]) -> list[str]:
    """Every column of `rows`, in first-seen order (a failed point's row holds fewer).

    Args:
        rows: the rows.

    Returns:
        list: the column names.
    """
    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    return list(seen)


def table(rows: list[dict]):
    """The rows as a pyarrow Table.

    A column of numbers is float64 (int64 when every value is a whole number given as an int), of booleans
    bool, anything else string; a missing value is null.

    Args:
        rows: the rows (one per point).

    Returns:
        pyarrow.Table: one column per name of :func:`columns_of`, one row per point.
    """
    import pyarrow as pa

    cols = {}
    for name in columns_of(rows):
        values = [row.get(name) for row in rows]
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            kind = pa.bool_()
        elif present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
            kind = pa.int64()
        elif present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            kind, values = pa.float64(), [None if v is None else float(v) for v in values]
        else:
            kind, values = pa.string(), [None if v is None else str(v) for v in values]
        cols[name] = pa.array(values, type=kind)
    return pa.table(cols)


def _csv_text(rows: list[dict]) -> str:
    """The rows as CSV: header, then one line per point; floats exact (repr), missing values empty."""
    names = columns_of(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for row in rows:
        w.writerow(["" if row.get(k) is None else repr(row[k]) if isinstance(row[k], float) else row[k] for k in names])
    return buf.getvalue()


def plotted_columns(sweep: Sweep, rows: list[dict]) -> list[str]:
    """The numeric columns the sweep's `plot` patterns name, in the rows' order (the axes left out).

    Args:
        sweep: the sweep (its plot patterns and axis names).
        rows: the rows.

    Returns:
        list: the names of the columns that match and hold a number (not a bool) in some row.
    """
    match = matcher(sweep.plot)
    axis_names = {a.name for a in sweep.axes}
    return [c for c in columns_of(rows) if match(c) and c not in axis_names and
            any(isinstance(r.get(c), (int, float)) and not isinstance(r.get(c), bool) for r in rows)]


def summary(sweep: Sweep, run: SweepRun, files: list[str]) -> dict:
    """The content of sweep.json: what was swept and how, and what came of it.

    The counts and throughput, per plotted column its range over the points (and at which point), the
    failed points with their errors, the files written.

    Args:
        sweep: the sweep.
        run: its finished run.
        files: the paths of the files written (as text).

    Returns:
        dict: the summary; non-finite floats left as they are (`write_outputs` writes it through `json_safe`).
    """
    rows = run.rows
    stats = {}
    for c in plotted_columns(sweep, rows):
        v = np.array([np.nan if not isinstance(r.get(c), (int, float)) else float(r[c]) for r in rows])
        ok = np.isfinite(v)
        if ok.any():
            lo, hi = int(np.nanargmin(np.where(ok, v, np.nan))), int(np.nanargmax(np.where(ok, v, np.nan)))
            stats[c] = {"min": float(v[lo]), "min_point": lo, "max": float(v[hi]), "max_point": hi}
    failed = [{"point": r["point"], "error": r["error"]} for r in rows if r.get("error")]
    return {
        "name": sweep.name, "description": sweep.description, "sweep_file": sweep.file, "scenario": sweep.scenario,
        "set": [[p, v] for p, v in sweep.fixed], "design": sweep.design,
        "axes": [{"name": a.name, "path": a.path} | ({"values": list(a.values)} if a.values is not None else
                                                      {"range": list(a.bounds)}) for a in sweep.axes],
        "study": {"kind": sweep.study.kind, "duration_s": sweep.study.duration, **dict(sweep.study.options)},
        "points": len(rows), "failed": len(failed), "computed": run.computed, "resumed": run.resumed,
        "executor": run.executor, "wall_time_s": run.wall_time_s,
        "points_per_s": run.computed / run.wall_time_s if run.wall_time_s > 0 else None,
        "ranges": stats, "failed_points": failed, "digest": sweep.digest, "files": files,
    }


def _json_value(v: Any) -> Any:
    return nonfinite_name(v) if isinstance(v, float) and not math.isfinite(v) else v


def point_log(sweep: Sweep, rows: list[dict]):
    """The streams and metadata of sweep.mcap: /sweep/point, one JSON message per point.

    Each message at log time = the point's index (s), its fields named by `field_name`, non-finite numbers
    as the strings "Infinity", "-Infinity", "NaN".

    Args:
        sweep: the sweep (its name, files, digest and study kind go into the metadata).
        rows: the rows, one per point.

    Returns:
        tuple: ([JsonTopic] of /sweep/point, metadata {"sweep": {key: text}}), the arguments of
            `write_mcap` after the path.
    """
    names = columns_of(rows)
    fields = {c: field_name(c) for c in names}
    t = np.array([float(r["point"]) for r in rows])
    ns = time_ns(t)
    messages = tuple({"timestamp": stamp(int(k))} | {fields[c]: _json_value(r.get(c)) for c in names}
                     for k, r in zip(ns, rows))
    schema = {"type": "object", "title": "coopsim.sweep.Point",
              "description": "one sweep point: its axis values, error (null if none) and study columns",
              "properties": {"timestamp": {"type": "object"}} | {fields[c]: {} for c in names}}
    meta = {"sweep": {"name": sweep.name, "file": sweep.file, "scenario": sweep.scenario, "digest": sweep.digest,
                      "study": sweep.study.kind, "columns": json.dumps(fields)}}
    return [JsonTopic("/sweep/point", "coopsim.sweep.Point", schema, t, messages)], meta


def write_outputs(sweep: Sweep, run: SweepRun, out: str | Path, figures: bool = True) -> list[Path]:
    """Write the sweep's outputs into folder `out` as one set (module docstring).

    results.parquet, results.csv, sweep.mcap, the figures (with `figures`) and sweep.json, staged and then
    swapped in; files of earlier sets listed in sweep.json are replaced, the checkpoint and anything else
    kept.

    Args:
        sweep: the sweep.
        run: its finished run.
        out: the output folder.
        figures: also draw the figures of `coopsim.plots.sweep`.

    Returns:
        list: the Paths of the files written, sweep.json last.
    """
    import pyarrow.parquet as pq

    out = Path(out)
    with staged_folder(out, replaces=previous_set(INDEX)) as stage:
        pq.write_table(table(run.rows), stage / "results.parquet")
        (stage / "results.csv").write_text(_csv_text(run.rows), encoding="utf-8")
        write_mcap(stage / "sweep.mcap", *point_log(sweep, run.rows))
        plots = sweep_figures(sweep, run.rows, plotted_columns(sweep, run.rows), stage) if figures else []
        names = ["results.parquet", "results.csv", "sweep.mcap"] + [p.name for p in plots] + [INDEX]
        text = json.dumps(json_safe(summary(sweep, run, [str(out / n) for n in names])), indent=2) + "\n"
        (stage / INDEX).write_text(text, encoding="utf-8")
    return [out / n for n in names]


def read_rows(path: str | Path) -> list[dict]:
    """The rows of a results.parquet (pyarrow), as dicts.

    Args:
        path: the results.parquet file.

    Returns:
        list: one dict per row, column name → value (None where missing).
    """
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pylist()
