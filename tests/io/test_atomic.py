"""Atomic outputs (coopsim.io.atomic): a failure names what the caller gave, never a temporary, and leaves
the target as it was; what stands in the way of an output folder, in words. (Whole sets through the CLI:
tests/cross/test_hard_cases.py.)"""

from __future__ import annotations

import errno
import gc
import os
import warnings
from pathlib import Path

import pytest

from coopsim.io import atomic
from coopsim.io.atomic import atomic_path, folder_problem, staged_folder


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_set_whose_folder_became_a_file_fails_naming_the_folder(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(NotADirectoryError) as exc, staged_folder(out) as stage:
        (stage / "log.mcap").write_bytes(b"log")
        out.write_text("mine")               # the folder's place taken while the set is written
    assert exc.value.filename == str(out) and exc.value.filename2 is None and ".tmp" not in str(exc.value)
    assert _names(tmp_path) == ["out"] and out.read_text() == "mine"


def test_a_file_whose_place_is_a_folder_fails_naming_the_file(tmp_path):
    (tmp_path / "f").mkdir()
    with pytest.raises(IsADirectoryError) as exc, atomic_path(tmp_path / "f") as tmp:
        tmp.write_text("x")
    assert str(exc.value) == f"[Errno {errno.EISDIR}] {os.strerror(errno.EISDIR)}: '{tmp_path / 'f'}'"
    assert _names(tmp_path) == ["f"]


def test_a_set_that_cannot_keep_the_other_files_fails_naming_the_folder_and_warns_nothing(tmp_path, monkeypatch):
    """The other files of an existing folder are hard-linked into the new set; a file system that refuses
    (a link across file systems) fails naming `out`, with no unclosed directory scan (a ResourceWarning,
    two more lines on the command's stderr)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")

    def no_link(src, dst):
        raise OSError(errno.EXDEV, os.strerror(errno.EXDEV), str(src), str(dst))

    monkeypatch.setattr(atomic.os, "link", no_link)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(OSError) as exc, staged_folder(out) as stage:
            (stage / "log.mcap").write_bytes(b"log")
        error = exc.value
        del exc
        gc.collect()
    assert error.errno == errno.EXDEV and error.filename == str(out) and error.filename2 is None
    assert [w for w in caught if issubclass(w.category, ResourceWarning)] == []
    assert _names(tmp_path) == ["out"] and _names(out) == ["notes.txt"]


def test_without_an_exchange_a_failed_rename_puts_the_previous_set_back(tmp_path, monkeypatch):
    """Where the two folders cannot be swapped in one call, `out` is moved aside and the new set renamed
    into its place; when that rename fails, the previous set goes back to `out`."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("previous")
    real_replace = os.replace

    def replace(src, dst):
        if Path(dst) == out and ".out." in Path(src).name:     # the new set into place
            raise OSError(errno.EIO, os.strerror(errno.EIO), str(src), str(dst))
        real_replace(src, dst)

    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    monkeypatch.setattr(atomic.os, "replace", replace)
    with pytest.raises(OSError) as exc, staged_folder(out) as stage:
        (stage / "summary.json").write_text("new")
    assert exc.value.errno == errno.EIO and exc.value.filename == str(out)
    assert _names(tmp_path) == ["out"] and (out / "summary.json").read_text() == "previous"


def test_what_stands_in_the_way_of_an_output_folder(tmp_path):
    (tmp_path / "file").write_text("x")
    assert folder_problem(tmp_path / "file") == "is a file, not a folder"
    assert folder_problem(tmp_path / "file" / "a" / "b") == f"{tmp_path / 'file'} is a file, not a folder"
    assert folder_problem("/").startswith("is a mount point")       # a rename cannot replace it
    assert folder_problem(tmp_path / "new" / "out") is None and folder_problem(tmp_path) is None
