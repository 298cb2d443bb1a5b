"""Helper processes that end with the command that started them, however it ends (SIGKILL included).

A helper process (a figure worker, a first run's compile process) calls `end_with_parent` as it starts.
On Linux the kernel then sends it SIGKILL when its parent ends (prctl PR_SET_PDEATHSIG); elsewhere, or
where the parent thread that started it may end before the parent does (the kernel's signal follows that
thread), a daemon thread of the helper watches its parent's process id, which changes when the parent has
ended (the helper is adopted by another process), and ends the helper then.
"""

from __future__ import annotations

import ctypes
import os
import signal
import threading
import time

PR_SET_PDEATHSIG = 1      # linux/prctl.h
WATCH_S = 0.2             # how often the watching thread looks at the parent's process id
ORPHANED = 1              # the exit status of a helper whose parent has ended


def _parent_death_signal(sig: int) -> bool:
    """Ask the kernel for signal `sig` when the parent thread ends (Linux); False where there is no prctl."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return False
    return prctl(PR_SET_PDEATHSIG, sig, 0, 0, 0) == 0


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_S)
    os._exit(ORPHANED)


def end_with_parent(parent: int, kernel: bool = True) -> None:
    """Make this (helper) process end when process `parent`, which started it, ends.

    Called first thing in the helper. Where `parent` has ended already, the helper ends here.

    Args:
        parent: the process id of the parent, as the parent saw it (os.getpid() there), so that a parent
            that ended before this call is noticed.
        kernel: the kernel's parent-death signal may be used: the thread of `parent` that started this
            process lasts as long as `parent` does (its main thread, or one that waits for this process);
            False: the watching thread alone.
    """
    if not (kernel and _parent_death_signal(signal.SIGKILL)):
        threading.Thread(target=_watch, args=(parent,), name="end-with-parent", daemon=True).start()
    if os.getppid() != parent:
        os._exit(ORPHANED)
