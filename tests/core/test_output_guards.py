"""Output guards of the atomic writer (core/io_utils): non-regular targets, protected inputs, permissions, disk full."""

import errno
import os
import stat

import pytest

from gof_warp.core.errors import GofError
from gof_warp.core.io_utils import atomic_path, check_output_path, write_bytes_atomic


def _targets(tmp_path):
    folder = tmp_path / "folder"
    folder.mkdir()
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    link_dir = tmp_path / "link_dir"
    link_dir.symlink_to(folder)
    link_dev = tmp_path / "link_dev"
    link_dev.symlink_to("/dev/null")
    return {"folder": folder, "FIFO": fifo, "character device": "/dev/null", "symlink to a folder": link_dir,
            "symlink to a device": link_dev}


def test_atomic_writer_refuses_non_regular_targets(tmp_path):
    for what, target in _targets(tmp_path).items():
        with pytest.raises(GofError, match="exists and is"):
            write_bytes_atomic(target, b"x")
        with pytest.raises(GofError, match="exists and is"):
            check_output_path(target)
    assert (tmp_path / "folder").is_dir() and stat.S_ISFIFO(os.stat(tmp_path / "fifo").st_mode)
    assert os.path.islink(tmp_path / "link_dev") and os.path.islink(tmp_path / "link_dir")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "folder", "link_dev", "link_dir"]  # no temporaries
    # a regular file, and a symlink to one, are replaced as before
    (tmp_path / "f").write_bytes(b"old")
    write_bytes_atomic(tmp_path / "f", b"new")
    assert (tmp_path / "f").read_bytes() == b"new"


def test_check_output_path_refuses_protected_inputs(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    ply = run / "point_cloud.ply"
    ply.write_bytes(b"model")
    protected = [ply, run / "checkpoints"]
    with pytest.raises(GofError, match="point_cloud.ply"):
        check_output_path(run / "point_cloud.ply", protected=protected)
    with pytest.raises(GofError, match="checkpoints"):
        check_output_path(run / "checkpoints" / "ckpt_0000001.pt", protected=protected)
    link = tmp_path / "alias.ply"
    link.symlink_to(ply)
    with pytest.raises(GofError, match="would replace"):
        check_output_path(link, protected=protected)
    assert check_output_path(run / "mesh.ply", protected=protected) == run / "mesh.ply"
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(GofError, match="not a folder"):
        check_output_path(blocker / "mesh.ply")


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_outputs_get_the_umask_permissions(tmp_path, mask):
    old = os.umask(mask)
    try:
        write_bytes_atomic(tmp_path / "out.bin", b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "out.bin").st_mode) == 0o666 & ~mask


def test_disk_full_is_a_clear_error_and_leaves_nothing(tmp_path, monkeypatch):
    target = tmp_path / "out.bin"
    with pytest.raises(GofError, match=f"no space left on device writing {target}"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"partial")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert list(tmp_path.iterdir()) == []

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(GofError, match=f"no space left on device writing {target}"):
        write_bytes_atomic(target, b"x" * 1000)
    assert list(tmp_path.iterdir()) == []
