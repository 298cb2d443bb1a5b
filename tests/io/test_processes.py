"""Helper processes that end with their parent (coopsim.io.processes): by the kernel's parent-death signal
and by the watching thread, when the parent is killed; at once when the parent has ended already."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
from helpers import survivors

from coopsim.io import processes

_PARENT = """
import ctypes, os, sys, time
from coopsim.io.processes import end_with_parent
parent = os.getpid()
if os.fork() == 0:
    end_with_parent(parent, kernel=sys.argv[1] == "kernel")
    sig = ctypes.c_int(-1)
    if sys.platform == "linux":
        ctypes.CDLL(None).prctl(2, ctypes.byref(sig), 0, 0, 0)   # PR_GET_PDEATHSIG
    print("tied", sig.value, flush=True)
    time.sleep(60)
    os._exit(0)
time.sleep(60)
"""


@pytest.mark.parametrize("kernel", [True, False], ids=["kernel", "watching thread"])
def test_a_helper_ends_when_its_parent_is_killed(kernel):
    proc = subprocess.Popen([sys.executable, "-c", _PARENT, "kernel" if kernel else "thread"], stdout=subprocess.PIPE,
                            text=True, start_new_session=True)
    try:
        tied = proc.stdout.readline().split()
        assert tied[0] == "tied"
        if sys.platform == "linux":          # the kernel's signal, or none where the thread watches
            assert int(tied[1]) == (signal.SIGKILL if kernel else 0), tied
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=60) == -signal.SIGKILL
    finally:
        left = survivors(proc.pid, within_s=5 * processes.WATCH_S + 2.0)
        proc.stdout.close()
    assert left == {}, f"the helper outlived its parent: {left}"


@pytest.mark.parametrize("kernel", [True, False], ids=["kernel", "watching thread"])
def test_a_helper_whose_parent_has_ended_ends_at_once(kernel):
    """A parent that ended before the helper tied itself to it (the helper's parent is another process by
    then): end_with_parent ends the helper, status ORPHANED."""
    code = ("import os\nfrom coopsim.io.processes import end_with_parent\n"
            f"end_with_parent(os.getppid() + 1_000_000, kernel={kernel})\nprint('still here')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == processes.ORPHANED and done.stdout == "", (done.stdout, done.stderr)
