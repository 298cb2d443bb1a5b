"""A per-thread scope counter: whether this thread is inside a scope (nested entries count), the
state the toolchain wrappers use to act on coopsim's own compiles only."""

from __future__ import annotations

import contextlib
import threading


class ThreadScope:
    """A scope entered with `with scope():` on a thread; `scope.active` is whether this thread is in it."""

    def __init__(self):
        self._local = threading.local()

    @contextlib.contextmanager
    def __call__(self):
        depth = getattr(self._local, "depth", 0)
        self._local.depth = depth + 1
        try:
            yield
        finally:
            self._local.depth = depth

    @property
    def active(self) -> bool:
        """Whether this thread is inside the scope (at any nesting depth)."""
        return getattr(self._local, "depth", 0) > 0
