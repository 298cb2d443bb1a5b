"""The progress bar: drawn only on a terminal, redrawn when the printed percentage changes, ends at 100 %."""

from __future__ import annotations

import io

from coopsim.progress import ProgressBar


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
    ending at 100 %; with --json nothing."""
    from coopsim.cli import main

    monkeypatch.chdir(workdir)
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
