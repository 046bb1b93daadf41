"""Atomic file output: nothing is ever left half-written.

Every file gof_warp writes goes through :func:`atomic_path` (or the helpers built on it): the data is
written to a temporary file in the same folder and renamed over the target only once complete, so a
crash, a full disk or Ctrl-C leaves either the old file or the new one, never a torn one.

Guards. :func:`check_output_path` is what a command calls on each of its output paths before its work
starts: it refuses a path that is a folder, anything but a regular file (a device, a FIFO, a socket, a
symlink to one of those), and any of the ``protected`` paths (a run's own inputs) or a path inside one.
:func:`atomic_path` refuses the same non-regular targets itself, as the last line of defence. A full disk
(``ENOSPC``, ``EDQUOT``) is a :class:`GofError` naming the file, with no partial file left. Outputs get the
permissions a plain ``open`` would give them: ``0o666`` less the process's umask.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
import tempfile
import threading
from pathlib import Path
from typing import Iterable

from .errors import GofError


def ensure_writable_dir(path) -> Path:
    """Create ``path`` (and parents) if needed and check that we can write there; clear error if not."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise GofError(f"cannot create output folder {p}: {e.strerror or e}") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise GofError(f"output folder {p} is not writable")
    return p


_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
_UMASK_LOCK = threading.Lock()


def _umask() -> int:
    """The process's umask, read without changing it where Linux tells it (``/proc/self/status``)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:  # elsewhere: set and restore it (another thread's file made in between gets 0o666)
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _non_regular(path: Path) -> str | None:
    """What ``path`` is when something exists there that an output must not replace (None: nothing, or a
    regular file, or a symlink to one, or a dangling symlink)."""
    try:
        st = os.stat(path)  # follows symlinks: a link to a device is a device
    except (FileNotFoundError, NotADirectoryError):  # nothing there (a missing parent is the writer's error)
        return None
    except OSError as e:
        return f"unreadable ({e.strerror or e})"
    mode = st.st_mode
    if stat.S_ISREG(mode):
        return None
    kind = ("a folder" if stat.S_ISDIR(mode) else "a character device" if stat.S_ISCHR(mode) else
            "a block device" if stat.S_ISBLK(mode) else "a FIFO" if stat.S_ISFIFO(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    return f"{kind} (through a symlink)" if path.is_symlink() else kind


def _refuse_non_regular(path: Path) -> None:
    kind = _non_regular(path)
    if kind is not None:
        raise GofError(f"output {path} exists and is {kind}: give the path of a file to write")


def check_output_path(path, *, protected: Iterable = ()) -> Path:
    """Check an output path before any work: :class:`GofError` when ``path`` is a folder or another non-regular
    file, when its parent exists and is not a folder, or when it is one of ``protected`` (a file, or a folder
    whose contents are all protected) or lies inside one. Symlinks are followed for the comparison. Returns
    ``Path(path)``."""
    p = Path(path)
    _refuse_non_regular(p)
    parent = p.parent if str(p.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise GofError(f"cannot write {p}: {parent} is not a folder")
    mine = {p.absolute(), p.resolve()}
    for q in protected:
        q = Path(q)
        theirs = {q.absolute(), q.resolve()}
        for a in mine:
            for b in theirs:
                if a == b or b in a.parents:
                    raise GofError(f"refusing to write {p}: it would replace {q}, an input of this command "
                                   "(choose another output path)")
    return p


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; on success rename it onto ``path``, else delete it.

    Example::

        with atomic_path("out/mesh.ply") as tmp:
            mesh.export(tmp)
    """
    target = Path(path)
    _refuse_non_regular(target)
    ensure_writable_dir(target.parent if str(target.parent) else ".")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes 0600
    finally:
        os.close(fd)
    try:
        yield Path(tmp)
        _refuse_non_regular(target)  # made while the data was being written
        os.replace(tmp, target)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.errno in _DISK_FULL:
            raise GofError(f"no space left on device writing {target} ({e.strerror or e})") from None
        raise


def write_bytes_atomic(path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def write_text_atomic(path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path, obj, indent: int = 2) -> None:
    write_text_atomic(path, json.dumps(obj, indent=indent, sort_keys=False) + "\n")
