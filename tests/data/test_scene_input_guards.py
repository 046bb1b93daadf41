"""Bad scene inputs that used to give tracebacks, hangs or silent reads (issue 56): each is now a clear error
(``inspect`` exits 2 with one ``error:`` line naming the file and the problem) or a warning."""

from __future__ import annotations

import json
import os
import struct
import threading
import zlib

import numpy as np

import pytest

from _scene_fixtures import make_colmap_scene, make_dtu_scene, make_ingp_scene, random_image, save_image
from gof_warp.cli import inspect_scene as inspect
from gof_warp.core.errors import SceneError
from gof_warp.data import DataConfig, load_scene


def _error(capsys, root) -> str:
    assert inspect.main([str(root)]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _edit_frames(root, edit):
    path = root / "transforms.json"
    d = json.loads(path.read_text())
    edit(d["frames"])
    path.write_text(json.dumps(d))


# ----------------------------------------------------------------------------- 1: paths stay inside the scene
@pytest.mark.parametrize("key", ["file_path", "mask_path"])
def test_transforms_path_outside_the_scene_is_an_error_before_the_file_is_read(tmp_path, capsys, key):
    outside = save_image(tmp_path / "outside.png", random_image())
    root = make_ingp_scene(tmp_path / "a" / "scene")
    _edit_frames(root, lambda frames: frames[2].update({key: "../../outside.png"}))
    err = _error(capsys, root)
    assert "transforms.json frame 2" in err and key in err and "outside the scene folder" in err, err
    assert "allow_outside_paths" in err
    # allowed explicitly: read as before
    scene = load_scene(root, DataConfig(allow_outside_paths=True, test_every=0))
    assert len(scene.train) == 9 and outside.is_file()


def test_absolute_path_and_etc_passwd_are_refused_without_reading(tmp_path, capsys):
    root = make_ingp_scene(tmp_path / "scene")
    _edit_frames(root, lambda frames: frames[0].update(file_path="../../../../../../etc/passwd"))
    err = _error(capsys, root)
    assert "outside the scene folder" in err and "not a readable image" not in err, err
    _edit_frames(root, lambda frames: frames[0].update(file_path=str(tmp_path / "elsewhere.png")))
    assert "outside the scene folder" in _error(capsys, root)


def test_colmap_image_name_outside_the_image_folder_is_an_error(tmp_path, capsys):
    save_image(tmp_path / "outside.png", random_image())
    root = make_colmap_scene(tmp_path / "scene", n=4)
    images_txt = root / "sparse" / "0" / "images.txt"
    text = images_txt.read_text()
    first = sorted(p.name for p in (root / "images").iterdir())[0]
    images_txt.write_text(text.replace(f" {first}\n", " ../../outside.png\n", 1))
    err = _error(capsys, root)
    assert "images.txt (image ../../outside.png)" in err and "outside the scene folder" in err, err


# ----------------------------------------------------------------------------- 2: only regular files
def _in_thread(fn, fifo, timeout=30.0):
    """``fn()``'s exception (or None); fails instead of hanging when ``fn`` blocks opening ``fifo``."""
    box = {}

    def go():
        try:
            fn()
        except BaseException as e:  # noqa: BLE001
            box["e"] = e
    t = threading.Thread(target=go, daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():  # a regression blocks in open(): a writer releases it
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        pytest.fail(f"reading the scene blocked on the FIFO {fifo}")
    return box.get("e")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_fifo_image_is_an_error_not_a_hang(tmp_path):
    root = make_colmap_scene(tmp_path / "scene", n=4)
    first = sorted((root / "images").iterdir())[0]
    first.unlink()
    os.mkfifo(first)
    e = _in_thread(lambda: load_scene(root), first)
    assert isinstance(e, SceneError) and str(first) in str(e) and "not a regular file" in str(e), e


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_fifo_mask_is_an_error_not_a_hang(tmp_path):
    root = make_ingp_scene(tmp_path / "scene")
    os.mkfifo(root / "mask.png")
    _edit_frames(root, lambda frames: frames[1].update(mask_path="mask.png"))
    e = _in_thread(lambda: load_scene(root), root / "mask.png")
    assert isinstance(e, SceneError) and "mask.png" in str(e) and "not a regular file" in str(e), e


# ----------------------------------------------------------------------------- 3: image size before decoding
def _png_header_only(path, width, height):
    """A PNG whose IHDR claims ``width`` x ``height`` (RGB), with one tiny IDAT: header checks must stop it."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 16))
                     + chunk(b"IEND", b""))


@pytest.mark.parametrize("side", [20000, 10500])  # over Pillow's own bomb limit, and between ours and Pillow's
def test_image_header_over_the_pixel_limit_is_a_clear_error(tmp_path, capsys, side):
    root = make_colmap_scene(tmp_path / "scene", n=4)
    first = sorted((root / "images").iterdir())[0]
    _png_header_only(first, side, side)
    err = _error(capsys, root)
    assert first.name in err and "100 megapixels" in err, err


# ----------------------------------------------------------------------------- 4: transform_matrix of strings
@pytest.mark.parametrize("matrix", [[["a", "b", "c", "d"]] * 4, [[1, 0, 0], [0, 1]], "eye"])
def test_transform_matrix_not_numbers_names_the_frame(tmp_path, capsys, matrix):
    root = make_ingp_scene(tmp_path / "scene")
    _edit_frames(root, lambda frames: frames[3].update(transform_matrix=matrix))
    err = _error(capsys, root)
    assert "transforms.json frame 3" in err and "transform_matrix" in err, err


# ----------------------------------------------------------------------------- 5: DTU cameras that are no npz
def test_dtu_cameras_npy_renamed_npz_is_a_clear_error(tmp_path, capsys):
    root, _ = make_dtu_scene(tmp_path / "dtu")
    with open(root / "cameras_sphere.npz", "wb") as f:
        np.save(f, np.eye(4))
    err = _error(capsys, root)
    assert "cameras_sphere.npz" in err and "npz" in err and ".npy" in err, err


def test_dtu_cameras_of_strings_is_a_clear_error(tmp_path, capsys):
    root, _ = make_dtu_scene(tmp_path / "dtu")
    np.savez(root / "cameras_sphere.npz", **{f"world_mat_{i}": np.array(["x"] * 16) for i in range(5)})
    err = _error(capsys, root)
    assert "cameras_sphere.npz" in err and "world_mat_0" in err, err


# ----------------------------------------------------------------------------- 8: a stale .bin beside a newer .txt
def test_stale_colmap_bin_beside_a_newer_txt_warns(tmp_path, capsys):
    root = make_colmap_scene(tmp_path / "scene", n=4, binary=True)
    model = root / "sparse" / "0"
    assert (model / "cameras.bin").is_file()
    for stem in ("cameras", "images"):
        b = model / f"{stem}.bin"
        (model / f"{stem}.txt").write_text("# edited\n")
        os.utime(b, (b.stat().st_atime, b.stat().st_mtime - 100))
    assert inspect.main([str(root), "--json"]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    for stem in ("cameras", "images"):
        assert any(f"{stem}.bin is used but {stem}.txt beside it is newer" in w for w in warnings), warnings
    assert not any("points3D" in w for w in warnings), warnings
    # an older .txt beside the .bin is what COLMAP writes: nothing said
    for stem in ("cameras", "images"):
        t = model / f"{stem}.txt"
        os.utime(t, (t.stat().st_atime, (model / f"{stem}.bin").stat().st_mtime - 100))
    assert not any("newer" in w for w in load_scene(root).warnings)
