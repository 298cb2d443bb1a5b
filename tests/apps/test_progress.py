"""The progress bar: drawn only on a terminal, redrawn when the printed percentage changes, ends at 100 %."""

from __future__ import annotations

import io
import sys

from coopsim.apps.progress import ProgressBar


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_ends_at_100_percent_and_switches_lines_between_stages():
    out = _Tty()
    bar = ProgressBar(out, width=30)
    for i in range(1, 201):
        bar("native", i / 200)
    for i in range(1, 101):
        bar("mujoco", i / 100)
    bar.close()
    frames = out.getvalue().replace("\n", "\r").split("\r")
    native = [f for f in frames if f.startswith("native")]
    assert native[-1].endswith("100%") and "." not in native[-1].split("[")[1], native[-1]
    assert [f for f in frames if f.startswith("mujoco")][-1].endswith("100%")
    assert out.getvalue().count("\n") == 2, "one line per stage"
    assert 100 <= len(native) <= 100 + 30 + 1, f"a redraw per printed percentage or bar cell, got {len(native)}"


def test_bar_is_silent_when_not_a_terminal():
    out = io.StringIO()
    bar = ProgressBar(out)
    bar("native", 0.5)
    bar.close()
    assert out.getvalue() == ""


def test_inverse_and_capacity_report_their_stages_on_a_terminal(workdir, monkeypatch, capsys):
    """`coopsim inverse --replay` and `coopsim capacity` draw one bar per stage on a terminal, each
    ending at 100 %; with --json nothing. (The figures are left out: stand-ins draw nothing.)"""
    from coopsim.cli import main

    monkeypatch.chdir(workdir)
    from coopsim.plots.render import FigureWorkers

    for name in ("inverse_plots", "capacity_plots"):
        monkeypatch.setattr(f"coopsim.plots.inverse.{name}", lambda log, folder, workers=None: [])
    monkeypatch.setattr("coopsim.plots.render.FigureWorkers", lambda: FigureWorkers(n=0))   # no worker processes
    err = _Tty()
    monkeypatch.setattr("sys.stderr", err)
    scenario = "scenarios/paper_planar_2x3.yaml"
    assert main(["inverse", scenario, "--duration", "0.3", "--replay", "--no-curve", "--out", "a"]) == 0
    assert main(["capacity", scenario, "--duration", "0.3", "--out", "b"]) == 0
    frames = err.getvalue().replace("\n", "\r").split("\r")
    last = {}
    for f in frames:
        if f.strip():
            last[f.split()[0]] = f
    assert list(last) == ["forward", "inverse", "replay", "capacity", "lp", "weights"], list(last)
    assert all(f.endswith("100%") for f in last.values()), last
    quiet = _Tty()
    monkeypatch.setattr("sys.stderr", quiet)
    assert main(["capacity", scenario, "--duration", "0.3", "--out", "c", "--json"]) == 0
    assert quiet.getvalue() == "", quiet.getvalue()[:200]


def test_bar_gives_the_remaining_time_then_the_time_taken():
    """ETA from the stage's pace (a fake clock): 25 % done after 3 s leaves 9 s; nothing is guessed in the
    first half second; at 100 % the time the stage took; a new stage restarts the clock."""
    now = [0.0]
    out = _Tty()
    bar = ProgressBar(out, width=10, clock=lambda: now[0])
    bar("native", 0.0)
    now[0] = 0.2
    bar("native", 0.1)
    now[0] = 3.0
    bar("native", 0.25)
    now[0] = 150.0
    bar("native", 0.5)
    now[0] = 151.0
    bar("native", 1.0)
    now[0] = 160.0
    bar("mujoco", 0.5)
    bar.close()
    frames = [f for f in out.getvalue().replace("\n", "\r").split("\r") if f]
    expected = [("native", "", 0, "  0"), ("native", "", 1, " 10"), ("native", "ETA 9 s", 2, " 25"),
                ("native", "ETA 2:30", 5, " 50"), ("native", "2:31", 10, "100"), ("mujoco", "", 5, " 50")]
    assert frames == [f"{label:<8} {timing:>11} [{'#' * k}{'.' * (10 - k)}] {pct}%"
                      for label, timing, k, pct in expected], frames


def test_simulate_and_mjcf_report_their_stage_on_a_terminal(tmp_path, monkeypatch, capsys):
    """`coopsim simulate` draws its 'native' stage, `coopsim mjcf` its 'mjcf' stage (the paths printed
    after the bar) and `coopsim validate` (as `run`) 'native' and 'mujoco', each ending at 100 %; with
    --json, or not on a terminal, nothing."""
    from helpers import SCENARIOS

    from coopsim.cli import main

    paper, spatial = str(SCENARIOS / "paper_planar_2x3.yaml"), str(SCENARIOS / "spatial_6r_pair.yaml")
    err = _Tty()
    monkeypatch.setattr("sys.stderr", err)
    assert main(["simulate", paper, "--duration", "0.5"]) == 0
    assert main(["mjcf", paper, spatial, "--out", str(tmp_path)]) == 0
    assert main(["validate", paper, "--duration", "0.2"]) == 0     # run's stages too (the same harness)
    frames = [f for f in err.getvalue().replace("\n", "\r").split("\r") if f.strip()]
    last = {f.split()[0]: f for f in frames}
    assert list(last) == ["native", "mjcf", "mujoco"] and all(f.endswith("100%") for f in last.values()), frames
    printed = capsys.readouterr().out.splitlines()
    assert [str(tmp_path / "paper_planar_2x3.xml"), str(tmp_path / "spatial_6r_pair.xml")] == [
        line for line in printed if line.endswith(".xml")]
    quiet = _Tty()
    monkeypatch.setattr("sys.stderr", quiet)
    assert main(["simulate", paper, "--duration", "0.5", "--json"]) == 0
    monkeypatch.setattr("sys.stderr", io.StringIO())      # not a terminal
    assert main(["mjcf", paper, "--out", str(tmp_path)]) == 0
    assert quiet.getvalue() == "" and sys.stderr.getvalue() == ""


def test_plot_reports_its_stages_on_a_terminal(tmp_path, monkeypatch, capsys):
    """`coopsim plot` draws 'read log' and 'figures', each ending at 100 % (the log reader and the
    figures replaced here by stand-ins: the stages are what is checked), then prints the paths."""
    from coopsim.cli import main

    log = tmp_path / "run.mcap"
    log.write_bytes(b"stand-in")
    monkeypatch.setattr("coopsim.io.log.read_run_log", lambda path: "log")
    monkeypatch.setattr("coopsim.plots.run.comparison_plots", lambda data, out: [out / "joint_angles.png"])
    err = _Tty()
    monkeypatch.setattr("sys.stderr", err)
    assert main(["plot", str(log)]) == 0
    frames = [f for f in err.getvalue().replace("\n", "\r").split("\r") if f.strip()]
    assert [f.split("  ")[0].strip() for f in frames if f.endswith("100%")] == ["read log", "figures"], frames
    assert capsys.readouterr().out.splitlines() == [str(tmp_path / "joint_angles.png")]


def test_bench_shows_one_bar_per_stage(tmp_path, monkeypatch):
    """`coopsim bench` on a terminal: each stage it announces is a bar that ends at 100 % (with the time
    it took) when the next begins or the benchmark ends (run_bench and its outputs are stand-ins here:
    the stages are what is checked); with --json nothing."""
    from coopsim.apps import bench
    from coopsim.apps.bench import report as bench_report
    from coopsim.cli import main

    def fake_bench(paths, ladders, log):
        for msg in ("paper: reference", "paper: native ladders", "scaling: 2 arms x 3 joints"):
            log(msg)
        return {}

    monkeypatch.setattr(bench, "run_bench", fake_bench)
    monkeypatch.setattr(bench_report, "write_outputs", lambda report, out: [])
    monkeypatch.setattr(bench_report, "markdown_report", lambda report: "report")
    monkeypatch.setattr(bench_report, "json_text", lambda report: "{}")
    for flags, expected in (([], ["paper: reference", "paper: native ladders", "scaling: 2 arms x 3 joints"]),
                            (["--json"], [])):
        err = _Tty()
        monkeypatch.setattr("sys.stderr", err)
        assert main(["bench", "scenarios/x.yaml", "--out", str(tmp_path), *flags]) == 0
        done = [f.split("  ")[0].strip() for f in err.getvalue().replace("\n", "\r").split("\r") if f.endswith("100%")]
        assert done == expected, err.getvalue()
