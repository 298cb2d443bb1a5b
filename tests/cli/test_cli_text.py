"""What the command line says when there is nothing to do, when asked its version, when its reader
goes away (the real CLI in a subprocess); when it is interrupted or stopped: test_cli_stop."""

from __future__ import annotations

import subprocess
import sys

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
