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
