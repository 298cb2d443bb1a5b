"""What the command line says when there is nothing to do, when asked its version, when its reader
goes away (the real CLI in a subprocess), and when its output folder cannot take its outputs; when it is
interrupted or stopped: test_cli_stop."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

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


@pytest.mark.parametrize("command, source", [("run", "paper_planar_2x3.yaml"), ("inverse", "paper_planar_2x3.yaml"),
                                             ("capacity", "paper_planar_2x3.yaml"),
                                             ("sweep", "sweeps/carry_duration.yaml")])
def test_an_out_that_is_a_file_is_one_line_before_the_work(tmp_path, command, source):
    """`--out FILE` (or a folder below a file): one line naming --out, never coopsim's temporaries, before
    anything runs; the file is left as it was."""
    (tmp_path / "iam_a_file").write_text("mine")
    serial = ("--serial",) if command == "sweep" else ()       # a sweep here without Dask
    for out, why in [("iam_a_file", "is a file, not a folder"), ("iam_a_file/x", "iam_a_file is a file, not a folder")]:
        done = run_cli(command, SCENARIOS / source, *serial, "--out", out, cwd=tmp_path)
        assert done.returncode == 2 and done.stderr == f"coopsim: error: --out {out}: {why}\n", done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["iam_a_file"]
    assert (tmp_path / "iam_a_file").read_text() == "mine"


def test_an_out_that_fails_at_the_end_is_one_line_naming_it(tmp_path, monkeypatch):
    """A folder that stops taking the set only when it is put in place (here a file made at --out while the
    run computes, past the check before the work) is the same one line, and leaves no temporary."""
    from coopsim.plots.render import FigureWorkers

    monkeypatch.setattr("coopsim.cli._check_out", lambda out: (out.write_text("mine"), None))
    monkeypatch.setattr("coopsim.plots.render.FigureWorkers", lambda: FigureWorkers(n=0))
    monkeypatch.setattr("coopsim.plots.run.comparison_plots", lambda log, folder, workers=None: [])
    done = run_cli("run", SCENARIOS / "paper_planar_2x3.yaml", "--duration", "0.05", "--out", "late", cwd=tmp_path)
    assert done.returncode == 2 and done.stderr == "coopsim: error: --out late: is a file, not a folder\n", done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late"] and (tmp_path / "late").read_text() == "mine"


_READ_ONLY_MOUNT = """
mkdir m && mount -t tmpfs tmpfs m && touch m/notes.txt && mount -o remount,ro m || exit 77
for out in m m/sub; do "$0" -m coopsim.cli run "$1" --duration 0.05 --out $out 2>&1; echo "status $?"; done
"""


@pytest.mark.skipif(shutil.which("unshare") is None or not hasattr(os, "geteuid") or os.geteuid() != 0,
                    reason="mounts a read-only file system in a mount namespace of its own: needs root and unshare")
def test_an_out_on_a_read_only_mount_is_one_line(tmp_path):
    """A read-only mount point (with a file in it) as --out, and a folder inside it: one line each naming
    --out (before: a link across file systems failed, with two ResourceWarning lines)."""
    done = subprocess.run(["unshare", "-m", "sh", "-c", _READ_ONLY_MOUNT, sys.executable,
                           str(SCENARIOS / "paper_planar_2x3.yaml")], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    if done.returncode == 77 or "unshare failed" in done.stderr:
        pytest.skip(f"no read-only mount here: {done.stderr.strip()}")
    assert done.stdout.splitlines() == [
        "coopsim: error: --out m: is a mount point, which a new set of files cannot replace as a whole: "
        "name a folder inside it", "status 2",
        "coopsim: error: --out m/sub: cannot write in m: Read-only file system", "status 2"], done.stdout + done.stderr
