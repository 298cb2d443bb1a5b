"""How a command ends when it is stopped (the real CLI in a subprocess of its own process group): killed,
it leaves no process behind (its figure workers end with it)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from helpers import SCENARIOS, running_processes, survivors

SCENARIO = SCENARIOS / "paper_planar_2x3.yaml"


def _start(tmp_path, command: str, err=subprocess.DEVNULL) -> subprocess.Popen:
    """`coopsim COMMAND` on the paper's scene (0.5 s) writing into tmp_path/out, the leader of a new
    process group (its pid is the group's id), its stdout dropped: a pipe would stay open in a survivor."""
    return subprocess.Popen([sys.executable, "-m", "coopsim.cli", command, str(SCENARIO), "--duration", "0.5",
                             "--out", str(tmp_path / "out")], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=err,
                            start_new_session=True)


def _wait_for(condition, proc: subprocess.Popen, what: str) -> None:
    deadline = time.monotonic() + 60
    while not condition():
        assert proc.poll() is None, f"the command ended (status {proc.returncode}) before {what}"
        assert time.monotonic() < deadline, f"no {what} after 60 s"
        time.sleep(0.02)


@pytest.mark.parametrize("command", ["run", "inverse", "capacity"])
def test_a_killed_command_leaves_no_process(tmp_path, command):
    """SIGKILL of the command, once its two figure workers (forked: children with its command line) run:
    within a few seconds no process of its group is left."""
    proc = _start(tmp_path, command)
    try:
        _wait_for(lambda: sum(ppid == proc.pid for ppid in running_processes(proc.pid).values()) >= 2, proc,
                  "two figure workers")
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=60) == -signal.SIGKILL
    finally:
        left = survivors(proc.pid)
    assert left == {}, f"still running after the command was killed (pid: parent pid): {left}"
