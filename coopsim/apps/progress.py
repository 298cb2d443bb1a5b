"""A minimal progress bar on stderr, shown only when stderr is a terminal (logs and CI stay clean)."""

from __future__ import annotations

import sys
import time

ETA_AFTER = 0.5   # s into a stage before its remaining time is estimated (a guess from less is noise)


def _duration(seconds: float) -> str:
    """'7 s', '2:05' (min:s), '1:02:05' (h:min:s)."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    m, s = divmod(s, 60)
    return f"{m}:{s:02d}" if m < 60 else f"{m // 60}:{m % 60:02d}:{s:02d}"


class ProgressBar:
    """A progress bar: `bar(label, fraction)` redraws `label    ETA 12 s [#####.....]  50%`.

    The ETA is the remaining time of the stage from its pace so far; when the stage is done, the time
    it took. `bar.close()` (or leaving a `with` block) ends the line. A new label starts a new line
    and a new stage clock. Drawn on `stream` only when it is a terminal and `enabled`.

    Args:
        stream: the text stream drawn on (None: stderr).
        width: characters of the bar between the brackets.
        enabled: False: draw nothing (e.g. with --json).
        clock: a function giving seconds (the stages' elapsed times).
    """

    def __init__(self, stream=None, width: int = 30, enabled: bool = True, clock=time.monotonic):
        """Drawn on `stream` (default stderr) when it is a terminal and `enabled` (e.g. not with --json);
        `clock()` gives seconds (the stages' elapsed times)."""
        self.stream = stream or sys.stderr
        self.width = width
        self.enabled = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.clock = clock
        self.last = None
        self.started = None

    def _timing(self, fraction: float) -> str:
        """'ETA 12 s' while the stage runs (blank before ETA_AFTER s), its elapsed time when done."""
        elapsed = self.clock() - self.started
        if fraction >= 1.0:
            return _duration(elapsed)
        if elapsed < ETA_AFTER or fraction <= 0.0:
            return ""
        return "ETA " + _duration(elapsed * (1.0 - fraction) / fraction)

    def __call__(self, label: str, fraction: float) -> None:
        if not self.enabled:
            return
        fraction = min(max(fraction, 0.0), 1.0)
        filled = int(round(self.width * fraction))
        state = (label, filled, int(round(100 * fraction)))   # redraw when the printed percentage changes
        if state == self.last:
            return
        if self.last is None or self.last[0] != label:
            self.started = self.clock()
        if self.last is not None and self.last[0] != label:
            self.stream.write("\n")
        self.last = state
        self.stream.write(f"\r{label:<8} {self._timing(fraction):>11} [{'#' * filled}{'.' * (self.width - filled)}] "
                          f"{100 * fraction:3.0f}%")
        self.stream.flush()

    def close(self) -> None:
        """End the bar's line (a newline when something was drawn); the next call starts afresh."""
        if self.enabled and self.last is not None:
            self.stream.write("\n")
            self.stream.flush()
        self.last = None

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        """Ends the line, also when the command fails (its one-line error then starts a line of its own)."""
        self.close()
