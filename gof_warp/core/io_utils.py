"""Atomic file output: nothing is ever left half-written.

Every file gof_warp writes goes through :func:`atomic_path` (or the helpers built on it): the data is
written to a temporary file in the same folder and renamed over the target only once complete, so a
crash, a full disk or Ctrl-C leaves either the old file or the new one, never a torn one.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

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


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path``; on success rename it onto ``path``, else delete it.

    Example::

        with atomic_path("out/mesh.ply") as tmp:
            mesh.export(tmp)
    """
    target = Path(path)
    ensure_writable_dir(target.parent if str(target.parent) else ".")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
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
