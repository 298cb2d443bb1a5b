"""Atomic file output: write to a temporary file beside the target, rename when complete; a set of files
(a run's outputs) is written into a temporary sibling folder and swapped into place as a whole.

Temporaries are hidden and named `.{target name}.{process id}.{random}.tmp`; one left behind by a process
that no longer runs (killed, or the machine stopped) is removed by the next atomic write beside it. A
failure of the writing itself names the target, never a temporary (`naming`); `folder_problem` says what
stands in the way of an output folder before anything is written.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

# .NAME.PID.RANDOM.tmp (RANDOM: tempfile's 8 characters); .NAME.RANDOM.tmp: an older coopsim's
_TEMP = re.compile(r"\.(?P<name>.+?)(?:\.(?P<pid>\d+))?\.[a-z0-9_]{8}\.tmp\Z")
LEGACY_AGE_S = 3600   # a temporary without a process id counts as stale after an hour


def _temp_prefix(name: str) -> str:
    return f".{name}.{os.getpid()}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's process
        return True
    return True


def is_stale_temporary(path: str | Path) -> bool:
    """Whether `path` is a coopsim temporary whose process no longer runs.

    A temporary of an older coopsim, which wrote no process id, counts as stale when untouched for
    LEGACY_AGE_S.

    Args:
        path: the file or folder (only its name is matched; its modification time read for an old one).

    Returns:
        bool: True for a stale coopsim temporary; False for anything else, this process's own, or one that
            has gone.
    """
    m = _TEMP.match(Path(path).name)
    if m is None:
        return False
    if m["pid"] is None:
        with contextlib.suppress(OSError):
            return time.time() - os.lstat(path).st_mtime > LEGACY_AGE_S
        return False
    return int(m["pid"]) != os.getpid() and not _alive(int(m["pid"]))


def sweep_stale(folder: str | Path) -> list[Path]:
    """Remove the stale coopsim temporaries (files and folders) in `folder`.

    Args:
        folder: the folder swept; a missing one, or a file, is left alone.

    Returns:
        list[Path]: what was removed.
    """
    removed = []
    with contextlib.suppress(FileNotFoundError, NotADirectoryError), os.scandir(folder) as entries:
        for entry in entries:
            if is_stale_temporary(entry.path):
                path = Path(entry.path)
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    with contextlib.suppress(FileNotFoundError):
                        path.unlink()
                removed.append(path)
    return removed


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Context manager giving a temporary path in the target's folder that replaces `path` on success.

    On any exception the temporary is removed and `path` is left as it was. The folder is created if
    missing; stale temporaries in it are removed first.

    Args:
        path: the file to write.

    Yields:
        Path: the temporary file (created empty, with the mode open() would give) to write to.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path.parent)
    with naming(path):
        fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path.name), suffix=".tmp", dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file the mode open() would
    try:
        yield Path(tmp)
        with naming(path):
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def naming(path: str | Path):
    """Context manager re-raising an OSError of the block (e.g. the rename of a temporary) as the same
    error about `path`, what the caller gave, so that its message never names a temporary.

    Args:
        path: the file or folder the block writes.

    Yields:
        None.

    Raises:
        OSError: the block's, with `path` as its only file name (the same errno and subclass); one without
            an errno passes unchanged.
    """
    try:
        yield
    except OSError as exc:
        if exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from exc


def folder_problem(out: str | Path) -> str | None:
    """What stands in the way of writing a set of files as folder `out` (`staged_folder`), in words.

    Args:
        out: the output folder.

    Returns:
        str | None: "is a file, not a folder"; "PATH is a file, not a folder" (a folder above `out`);
            that `out` is a mount point (a set replaces its folder by a rename, which a mount point
            refuses); "cannot write in PATH: Read-only file system" (or "Permission denied"), PATH the
            folder the set is staged in (`out`'s parent, or the nearest folder above it that exists);
            None when none of these is seen.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        return "is a file, not a folder"
    if out.is_dir() and os.path.ismount(out):
        return "is a mount point, which a new set of files cannot replace as a whole: name a folder inside it"
    base = next((p for p in out.parents if p.exists()), None)
    if base is None:
        return None
    if not base.is_dir():
        return f"{base} is a file, not a folder"
    if not os.access(base, os.W_OK | os.X_OK):
        code = errno.EROFS if os.statvfs(base).f_flag & os.ST_RDONLY else errno.EACCES
        return f"cannot write in {'the current folder' if base == Path('.') else base}: {os.strerror(code)}"
    return None


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically (`atomic_path`).

    Args:
        path: the file written (its folder is created if missing).
        text: the content.

    Returns:
        Path: the path written.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


_RENAME_EXCHANGE = 2


@functools.cache
def _renameat2():
    """libc's renameat2 (the process's own C library), or None where there is none."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return fn


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where that is not available."""
    fn = _renameat2()
    at_fdcwd = -100
    return fn is not None and fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0


def _keep_others(old: Path, new: Path, replaced: set[str]) -> None:
    """Hard-link into `new` every entry of `old` that is not in `replaced`, not in `new` and not a
    temporary (files another command wrote there: they stay; the old ones are left untouched)."""
    with os.scandir(old) as entries:
        for entry in entries:
            if entry.name in replaced or _TEMP.match(entry.name) or (new / entry.name).exists():
                continue
            src, dst = Path(entry.path), new / entry.name
            if entry.is_dir(follow_symlinks=False):
                shutil.copytree(src, dst, symlinks=True, copy_function=os.link)
            elif entry.is_symlink():
                os.symlink(os.readlink(src), dst)
            else:
                os.link(src, dst)


def previous_set(index: str):
    """`staged_folder`'s replaces= for a command whose JSON summary `index` lists its files.

    Args:
        index: the summary's file name in the output folder; its "files" entry is a list of names, or
            {"log": name, "plots": [names]} and optionally "ros2": the bag folder's name.

    Returns:
        Callable[[Path], set[str]]: folder `out` → the names (last path component) of the previous set
            that `out`'s summary lists, and `index` itself (only `index` when the summary is missing or
            unreadable).
    """
    def names(out) -> set[str]:
        try:
            files = json.loads((Path(out) / index).read_text(encoding="utf-8"))["files"]
            listed = [files["log"], *files["plots"], *([files["ros2"]] if "ros2" in files else [])] \
                if isinstance(files, dict) else list(files)
            return {index} | {str(n).replace("\\", "/").rsplit("/", 1)[-1] for n in listed}
        except (OSError, ValueError, KeyError, TypeError):
            return {index}
    return names


@contextlib.contextmanager
def staged_folder(out: str | Path, replaces=lambda old: set()):
    """Context manager writing a set of files as a whole, through a temporary sibling folder of `out`.

    On success the folder becomes `out` in one rename (an atomic swap where `out` exists), on any exception
    it is removed and `out` is left as it was. Where `out` already exists, the entries of it named by
    `replaces(out)` (a previous set) go, every other entry stays (hard links, so nothing is copied).
    Stale temporaries beside `out` and in it are removed first.

    Args:
        out: the output folder (its parent is created if missing).
        replaces: existing folder `out` → the entry names of the previous set to drop (e.g.
            `previous_set`); default: none.

    Yields:
        Path: the temporary folder to write the files into.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(out.parent)
    sweep_stale(out)
    with naming(out):
        tmp = Path(tempfile.mkdtemp(prefix=_temp_prefix(out.name), suffix=".tmp", dir=out.parent))
    os.chmod(tmp, 0o777 & ~_umask())   # mkdtemp creates 0700; give the folder the mode mkdir would
    try:
        yield tmp
        with naming(out):
            _swap_in(tmp, out, replaces)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _swap_in(tmp: Path, out: Path, replaces) -> None:
    """Make the complete folder `tmp` folder `out` (`staged_folder`, its `replaces`)."""
    if not out.is_dir():
        os.replace(tmp, out)
        return
    _keep_others(out, tmp, set(replaces(out)))
    if _exchange(tmp, out):
        shutil.rmtree(tmp)
        return
    old = Path(tempfile.mkdtemp(prefix=_temp_prefix(out.name), suffix=".tmp", dir=out.parent))
    try:
        os.replace(out, old / "old")
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old / "old", out)     # the previous set back in its place
            raise
    except BaseException:
        with contextlib.suppress(OSError):
            os.rmdir(old)                    # empty: nothing was moved, or it was moved back
        raise
    shutil.rmtree(old)
