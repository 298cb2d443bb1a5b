"""What the command line says when there is nothing to do, when asked its version, when its reader
goes away, and when it is interrupted (the real CLI in a subprocess)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import coopsim
from helpers import SCENARIOS, run_cli


def test_bare_command_prints_help(tmp_path):
    done = run_cli(cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: coopsim") and "capacity" in done.stdout and done.stderr == ""


def test_version(tmp_path):
    done = run_cli("--version", cwd=tmp_path)
    assert done.returncode == 0 and done.stdout.strip() == f"coopsim {coopsim.__version__}", done.stdout
    assert coopsim.__version__[0].isdigit(), f"installed version {coopsim.__version__!r}"


def test_closed_pipe_is_quiet(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "coopsim.cli", "mjcf", str(SCENARIOS / "spatial_6r_pair.yaml"),
                             "--out", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    proc.stdout.close()                       # the reader goes away before the command prints
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 1, err
    assert "Traceback" not in err and "BrokenPipe" not in err, err


def test_ctrl_c_prints_one_line_and_exits_130(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "coopsim.cli", "run", str(SCENARIOS / "paper_planar_2x3.yaml"),
                             "--out", str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not any(tmp_path.glob(".out.*.tmp")) and time.monotonic() < deadline:   # the outputs' staging folder
        time.sleep(0.02)
    time.sleep(0.1)                           # inside the writing of the outputs
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("\r")]
    assert proc.returncode == 130, (proc.returncode, err)
    assert lines[-1] == "coopsim: interrupted" and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "no partial set, no temporaries"
