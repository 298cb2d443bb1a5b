"""`coopsim sweep` (coopsim/apps/sweep.py, sweep_run.py): rows equal the single-run commands, serial = LocalCluster
= a real Dask cluster bit for bit, resume after a kill, bad sweep files as one-line errors."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import ROOT, SCENARIOS, run_cli
from coopsim.apps.sweep import evaluate_point, flatten, load_sweep, study_row
from coopsim.apps.sweep_run import read_rows, run_sweep, write_outputs

pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

PAPER = SCENARIOS / "paper_planar_2x3.yaml"
# a 2 × 3 grid of the paper scene's capacity over 1 s of its forward run
GRID = {"name": "grid", "scenario": str(PAPER),
        "axes": [{"path": "object.box.density", "values": [2700, 7850]},
                 {"path": "arms[0].torque.constant[0]", "name": "tau1", "linspace": [0.3, 0.7, 3]}],
        "study": {"kind": "capacity", "duration": 1.0, "lp": False, "optimise": False}, "plot": []}


def write_sweep(folder: Path, spec: dict, name: str = "s.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(spec), encoding="utf-8")
    return path


def test_grid_points_and_rows_equal_the_single_run_commands(tmp_path, monkeypatch):
    """Each row holds the numbers of `coopsim capacity --set … --json` (and `simulate`) on its point (the
    command's figures, which are not compared, are skipped: they would cost seconds of the suite)."""
    import contextlib

    import coopsim.plots.inverse
    import coopsim.plots.render

    monkeypatch.setattr(coopsim.plots.render, "FigureWorkers", lambda *a, **k: contextlib.nullcontext())
    monkeypatch.setattr(coopsim.plots.inverse, "capacity_plots", lambda log, folder, workers=None: [])
    monkeypatch.setattr(coopsim.plots.inverse, "inverse_plots", lambda log, folder, workers=None: [])
    sweep = load_sweep(write_sweep(tmp_path, GRID))
    assert sweep.points.tolist() == [[2700, 0.3], [2700, 0.5], [2700, 0.7], [7850, 0.3], [7850, 0.5], [7850, 0.7]]
    row = evaluate_point(sweep, 4)
    assert row["error"] is None and row["object.box.density"] == 7850 and row["tau1"] == 0.5
    out = run_cli("capacity", PAPER, "--duration", "1", "--no-lp", "--no-optimise", "--json", "--out", tmp_path / "c",
                  "--set", "object.box.density=7850", "--set", "arms[0].torque.constant[0]=0.5", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    single = study_row(json.loads(out.stdout), sweep.study)
    assert len(single) == 18 and {k: row[k] for k in single} == single   # 3 resolutions × 5 entries + 3 energies
    assert row["capacity.scaled.min_energy.mass_kg"] > 0
    sweep_sim = load_sweep(write_sweep(tmp_path, GRID | {"study": {"kind": "simulate", "duration": 0.2}}, "sim.yaml"))
    row = evaluate_point(sweep_sim, 1)
    out = run_cli("simulate", PAPER, "--duration", "0.2", "--json", "--set", "object.box.density=2700",
                  "--set", "arms[0].torque.constant[0]=0.5", cwd=tmp_path)
    single = study_row(json.loads(out.stdout), sweep_sim.study)
    assert len(single) == 17 and {k: row[k] for k in single} == single
    sets = ["--set", "object.box.density=2700", "--set", "arms[0].torque.constant[0]=0.5"]
    for study, command in (({"kind": "validate", "duration": 0.2}, ["validate", "--duration", "0.2"]),
                           ({"kind": "inverse", "duration": 0.2}, ["inverse", "--duration", "0.2", "--no-curve",
                                                                   "--out", tmp_path / "i"])):
        row = evaluate_point(load_sweep(write_sweep(tmp_path, GRID | {"study": study}, "k.yaml")), 1)
        out = run_cli(*command[:1], PAPER, *command[1:], "--json", *sets, cwd=tmp_path)
        summary = json.loads(out.stdout)
        single = study_row(summary["scenarios"][0] if study["kind"] == "validate" else summary,
                           load_sweep(tmp_path / "k.yaml").study)
        assert len(single) == (8 if study["kind"] == "validate" else 43), (study, len(single))
        assert {k: row[k] for k in single} == single, study


def test_a_failing_point_records_its_error_and_the_sweep_goes_on(tmp_path):
    """Density −1 fails at two points of six; the others run. Outputs: the Parquet table, sweep.json, the
    MCAP's messages (the table's numbers), and a heat map of the capacity (blank where a point failed)."""
    from coopsim.io.mcap_codec import read_mcap

    spec = GRID | {"axes": [{"path": "object.box.density", "values": [2700, -1, 7850]},
                            {"path": "arms[0].torque.constant[0]", "name": "tau1", "values": [0.3, 0.5]}],
                   "plot": ["capacity.scaled.min_energy.mass_kg"]}
    sweep = load_sweep(write_sweep(tmp_path, spec))
    run = run_sweep(sweep, tmp_path / "out", serial=True)
    paths = write_outputs(sweep, run, tmp_path / "out")
    errors = [r["error"] for r in run.rows]
    assert errors[2] == errors[3] == f"{PAPER}: object.box.density: must be positive, got -1.0"
    assert errors[:2] + errors[4:] == [None] * 4
    rows = read_rows(tmp_path / "out" / "results.parquet")
    assert [r["point"] for r in rows] == list(range(6)) and rows[2]["capacity.scaled.paper.mass_kg"] is None
    assert [r["capacity.scaled.paper.mass_kg"] for r in rows] == [r.get("capacity.scaled.paper.mass_kg") for r in run.rows]
    summary = json.loads((tmp_path / "out" / "sweep.json").read_text())
    assert summary["failed"] == 2 and summary["points"] == 6 and summary["computed"] == 6
    assert [p.name for p in paths] == ["results.parquet", "results.csv", "sweep.mcap",
                                       "map_capacity_scaled_min_energy_mass_kg.png", "sweep.json"]
    assert (tmp_path / "out" / paths[3].name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    msgs = read_mcap(tmp_path / "out" / "sweep.mcap").messages["/sweep/point"]
    assert [m["capacity_scaled_min_energy_mass_kg"] for m in msgs] == \
        [r["capacity.scaled.min_energy.mass_kg"] for r in rows]
    assert [m["timestamp"]["sec"] for m in msgs] == list(range(6)) and msgs[2]["error"] == errors[2]


@pytest.mark.parametrize("change, message", [
    ({"scenario": "nope.yaml"}, "s.yaml: scenario: scenario file not found"),
    ({"axes": []}, "s.yaml: axes: expected a list of at least 1 entries"),
    ({"axes": [{"path": "object.box.density"}]}, "s.yaml: axes[0].values: give either values"),
    ({"axes": [{"path": "object.box..density", "values": [1]}]}, "axes[0].path: object.box..density: malformed path"),
    ({"axes": [{"path": "object.bx.density", "values": [1]}]}, "axes[0].path: --set object.bx.density: object has no key 'bx'"),
    ({"axes": [{"path": "x", "linspace": [0, 1, 2.5]}]}, "axes[0].linspace: the count (third entry) must be a whole number"),
    ({"design": "lhs"}, "s.yaml: design: must be one of grid, sobol, halton; got 'lhs'"),
    ({"design": "sobol", "samples": 8, "seed": 1}, "s.yaml: axes[0].range: missing required field"),
    ({"samples": 8}, "s.yaml: samples: only for a sobol or halton design"),
    ({"study": {"kind": "capacity", "lp": "yes"}}, "s.yaml: study.lp: expected true or false, got 'yes'"),
    ({"study": {"kind": "fly"}}, "s.yaml: study.kind: must be one of simulate, validate, inverse, capacity"),
    ({"stduy": 1}, "s.yaml: stduy: unknown field (known here: axes,"),
    ({"set": {"duration": -2}}, "paper_planar_2x3.yaml: duration: must be positive, got -2.0"),
])
def test_bad_sweep_files_are_one_line_errors_naming_the_field(tmp_path, change, message):
    path = write_sweep(tmp_path, GRID | change)
    out = run_cli("sweep", path, "--serial", "--out", tmp_path / "o", cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    assert message in out.stderr, out.stderr
    assert not (tmp_path / "o").exists()


def test_without_dask_the_sweep_says_what_to_install(tmp_path, monkeypatch):
    import importlib.util

    find = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else find(name, *a))
    out = run_cli("sweep", write_sweep(tmp_path, GRID), "--out", tmp_path / "o", cwd=tmp_path)
    assert out.returncode == 2 and out.stderr == ("coopsim: error: coopsim sweep needs distributed, which is not "
                                                  "installed: pip install 'coopsim[sweep]'\n")


def test_quasi_random_designs_are_seeded_and_scaled(tmp_path):
    from scipy.stats import qmc

    spec = GRID | {"design": "sobol", "samples": 8, "seed": 3,
                   "axes": [{"path": "object.box.density", "range": [1000, 9000]}, {"path": "gravity[2]", "range": [-10, 0]}]}
    a, b = load_sweep(write_sweep(tmp_path, spec)), load_sweep(write_sweep(tmp_path, spec, "t.yaml"))
    assert np.array_equal(a.points, b.points) and a.digest == b.digest
    unit = qmc.Sobol(2, scramble=True, rng=3).random(8)   # scipy's own sequence, scaled by hand
    assert np.array_equal(a.points, np.column_stack([1000 + 8000 * unit[:, 0], -10 + 10 * unit[:, 1]]))
    halton = load_sweep(write_sweep(tmp_path, spec | {"design": "halton"}, "h.yaml"))
    assert halton.points.shape == (8, 2) and not np.array_equal(halton.points, a.points)
    # the bundled sweeps (in this test: the Monte Carlo one imports scipy.stats, about a second, once)
    sweeps = {path.stem: load_sweep(path) for path in (SCENARIOS / "sweeps").glob("*.yaml")}
    assert {k: v.points.shape for k, v in sweeps.items()} == {"paper_capacity_map": (45, 2), "carry_duration": (11, 1),
                                                              "paper_payload_map": (5151, 2),
                                                              "spatial_mc_agreement": (16, 6)}
    mc = sweeps["spatial_mc_agreement"]
    lo, hi = np.array([a.bounds for a in mc.axes]).T
    assert np.all((lo <= mc.points) & (mc.points <= hi)) and np.all(hi - lo == pytest.approx(0.2))


def test_flatten_names_columns_as_paths():
    assert flatten({"a": {"b c": [1, 2]}, "w": [{"x": 1}], "e": []}) == {"a.b_c[0]": 1, "a.b_c[1]": 2, "w": 1, "e": 0}


# ------------------------------------------------------------------------------------------------
# execution: one real cluster (scheduler and worker processes on the loopback) shared by the module
# ------------------------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def real_cluster():
    """`dask scheduler` and one `dask worker` (1 process, 1 thread) as separate processes on 127.0.0.1,
    importing coopsim from this checkout (PYTHONPATH); torn down at the end."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    bin_dir = Path(sys.executable).parent
    procs = [subprocess.Popen([bin_dir / "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    procs.append(subprocess.Popen([bin_dir / "dask", "worker", address, "--nworkers", "1", "--nthreads", "1",
                                   "--no-nanny", "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL))
    try:
        yield address
    finally:
        for p in reversed(procs):
            p.kill()
            p.wait()


def _wait_for_worker(address: str, timeout: float = 60.0) -> None:
    from dask.distributed import Client

    with Client(address, timeout="30s") as client:
        client.wait_for_workers(1, timeout=timeout)


def test_serial_local_cluster_and_real_cluster_give_identical_tables(tmp_path, real_cluster):
    path = write_sweep(tmp_path, GRID)
    serial = run_cli("sweep", path, "--serial", "--out", tmp_path / "serial", "--json", cwd=tmp_path)
    assert serial.returncode == 0, serial.stderr
    local = run_cli("sweep", path, "--workers", "2", "--out", tmp_path / "local", "--json", cwd=tmp_path)
    assert local.returncode == 0, local.stderr
    _wait_for_worker(real_cluster)
    remote = run_cli("sweep", path, "--scheduler", real_cluster, "--out", tmp_path / "remote", "--json", cwd=tmp_path)
    assert remote.returncode == 0, remote.stderr
    assert "LocalCluster, 2 worker processes" in json.loads(local.stdout)["executor"]
    again = run_sweep(load_sweep(path), tmp_path / "again", workers=2)     # a second embedded cluster, same process
    assert again.rows == read_rows(tmp_path / "local" / "results.parquet")
    assert json.loads(remote.stdout)["executor"] == f"Dask cluster at {real_cluster}"
    tables = [(tmp_path / k / "results.csv").read_bytes() for k in ("serial", "local", "remote")]
    assert tables[0] == tables[1] == tables[2]
    rows = [read_rows(tmp_path / k / "results.parquet") for k in ("serial", "local", "remote")]
    assert rows[0] == rows[1] == rows[2] and len(rows[0]) == 6 and all(r["error"] is None for r in rows[0])
    assert [r["point"] for r in rows[0]] == list(range(6))


def _run_serial(path: Path, out: Path) -> None:
    from coopsim.apps.sweep_run import run_sweep

    run_sweep(load_sweep(path), out, serial=True)


def test_resume_after_a_kill_gives_the_same_table_without_recomputing(tmp_path, monkeypatch):
    """A serial sweep in a process of its own (forked from this one: it starts with the kernels loaded),
    killed (SIGKILL) once two points are checkpointed, its last line torn as a kill mid-write leaves it,
    then resumed: the same table as an uninterrupted run; only the other points run."""
    import multiprocessing

    spec = GRID | {"study": GRID["study"] | {"duration": 2.0}}
    path = write_sweep(tmp_path, spec)
    ckpt = tmp_path / "out" / "points.jsonl"
    proc = multiprocessing.get_context("fork").Process(target=_run_serial, args=(path, tmp_path / "out"))
    proc.start()
    try:
        deadline = time.monotonic() + 60
        while (not ckpt.is_file() or ckpt.read_text().count("\n") < 3) and proc.is_alive() \
                and time.monotonic() < deadline:
            time.sleep(0.002)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.join()
    assert proc.exitcode == -signal.SIGKILL
    finished = ckpt.read_text().count("\n") - 1
    assert 2 <= finished < 6, f"killed after {finished} points"
    with open(ckpt, "a") as f:
        f.write('{"row": {"point": 5, "error": nu')              # a line cut short
    import coopsim.apps.sweep_run

    ran = []
    monkeypatch.setattr(coopsim.apps.sweep_run, "evaluate_point", lambda sw, i: ran.append(i) or evaluate_point(sw, i))
    out = run_cli("sweep", path, "--serial", "--resume", "--out", tmp_path / "out", "--json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    assert ran == list(range(finished, 6))                   # the finished points are not run again
    assert (s["resumed"], s["computed"]) == (finished, 6 - finished)
    whole = run_cli("sweep", path, "--serial", "--out", tmp_path / "whole", cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    assert (tmp_path / "out" / "results.csv").read_bytes() == (tmp_path / "whole" / "results.csv").read_bytes()
    ran.clear()
    again = run_cli("sweep", path, "--serial", "--resume", "--out", tmp_path / "out", "--json", cwd=tmp_path)
    assert ran == [] and (json.loads(again.stdout)["computed"], json.loads(again.stdout)["resumed"]) == (0, 6)
    other = write_sweep(tmp_path, GRID, "other.yaml")
    refused = run_cli("sweep", other, "--serial", "--resume", "--out", tmp_path / "out", cwd=tmp_path)
    assert refused.returncode == 2 and "the checkpoint is another sweep's" in refused.stderr


def test_dask_tasks_cover_every_point_once_in_balanced_chunks():
    """5151 points on 2 workers: tasks of 64 (the cap), at least 8 per worker; 45 points: tasks of 2;
    3 points on 4 workers: one each. Every point once, in order."""
    from coopsim.apps.sweep_run import chunks

    for n, workers, size in ((5151, 2, 64), (45, 2, 2), (3, 4, 1)):
        parts = chunks(list(range(n)), workers)
        assert sum(parts, []) == list(range(n)) and {len(p) for p in parts[:-1]} == {size}
        assert len(parts) >= min(n, 8 * workers) or size == 64
