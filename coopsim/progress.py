"""A minimal progress bar on stderr, shown only when stderr is a terminal (logs and CI stay clean)."""

from __future__ import annotations

import sys


class ProgressBar:
    """`bar(label, fraction)` redraws `label [#####.....]  50%`; `bar.close()` ends the line."""

    def __init__(self, stream=None, width: int = 30, enabled: bool = True):
        """Drawn on `stream` (default stderr) when it is a terminal and `enabled` (e.g. not with --json)."""
        self.stream = stream or sys.stderr
        self.width = width
        self.enabled = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.last = None

    def __call__(self, label: str, fraction: float) -> None:
        if not self.enabled:
            return
        fraction = min(max(fraction, 0.0), 1.0)
        filled = int(round(self.width * fraction))
        state = (label, filled, int(round(100 * fraction)))   # redraw when the printed percentage changes
        if state == self.last:
            return
        if self.last is not None and self.last[0] != label:
            self.stream.write("\n")
        self.last = state
        self.stream.write(f"\r{label:<8} [{'#' * filled}{'.' * (self.width - filled)}] {100 * fraction:3.0f}%")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.last is not None:
            self.stream.write("\n")
            self.stream.flush()
        self.last = None
