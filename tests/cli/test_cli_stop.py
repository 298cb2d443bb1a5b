"""How a command ends when it is stopped (the real CLI in a subprocess of its own process group): killed,
it leaves no process behind (its figure workers end with it); interrupted (Ctrl-C: SIGINT) or stopped
(SIGTERM: `timeout`, systemd, Slurm, `docker stop`), sent to it alone or to its whole process group as a
terminal or a service manager does, it prints one line, exits 128 + the signal's number and leaves no
partial set and no process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
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


@pytest.mark.parametrize("sig, status, line", [(signal.SIGINT, 130, "coopsim: interrupted"),
                                               (signal.SIGTERM, 143, "coopsim: stopped by SIGTERM")])
@pytest.mark.parametrize("to_group", [False, True], ids=["command", "group"])
def test_a_stopped_command_says_so_and_leaves_nothing(tmp_path, sig, status, line, to_group):
    """The signal arrives while the outputs are being written (their staging folder exists): one line on
    stderr (no traceback from a worker), the signal's status, no output folder, no temporary, no process."""
    with tempfile.TemporaryFile("w+") as err:
        proc = _start(tmp_path, "run", err)
        try:
            _wait_for(lambda: any(tmp_path.glob(".out.*.tmp")), proc, "the outputs' staging folder")
            time.sleep(0.1)                  # inside the writing of the outputs
            os.killpg(proc.pid, sig) if to_group else proc.send_signal(sig)
            assert proc.wait(timeout=60) == status
        finally:
            left = survivors(proc.pid, within_s=1.0)
        err.seek(0)
        text = err.read()
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith(("\r", "coopsim: compiling"))]
    assert lines == [line], text
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "no partial set, no temporaries"
    assert left == {}, f"still running after the command ended: {left}"
