"""``python -m gof_warp.prepare``: bad inputs give one ``error:`` line and exit 2 (no traceback, nothing written),
and ``train`` on a folder of plain photos says to run ``prepare`` first."""

from __future__ import annotations

import numpy as np
import pytest

from gof_warp.cli import prepare, train


def _photos(folder, n):
    from PIL import Image

    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        Image.fromarray(rng.integers(0, 255, (40, 60, 3), dtype=np.uint8)).save(folder / f"IMG_{i:04d}.jpg")
    return folder


def _error(capsys, rc) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, (rc, err)
    return lines[0]


def test_empty_folder(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    line = _error(capsys, prepare.main([str(tmp_path / "photos"), "--out", str(tmp_path / "scene"), "-q"]))
    assert "no images" in line and ".jpg" in line and ".png" in line
    assert not (tmp_path / "scene").exists()


def test_not_a_folder(tmp_path, capsys):
    f = tmp_path / "one.jpg"
    f.write_bytes(b"")
    assert "not a folder" in _error(capsys, prepare.main([str(f), "--out", str(tmp_path / "scene"), "-q"]))


def test_two_images(tmp_path, capsys):
    photos = _photos(tmp_path / "photos", 2)
    line = _error(capsys, prepare.main([str(photos), "--out", str(tmp_path / "scene"), "-q"]))
    assert "2 image(s)" in line and "at least 3" in line


def test_non_empty_output_is_refused(tmp_path, capsys):
    photos = _photos(tmp_path / "photos", 3)
    out = tmp_path / "scene"
    out.mkdir()
    (out / "notes.txt").write_text("keep")
    assert "--overwrite" in _error(capsys, prepare.main([str(photos), "--out", str(out), "-q"]))
    assert "not written by prepare" in _error(capsys, prepare.main([str(photos), "--out", str(out), "--overwrite", "-q"]))
    assert (out / "notes.txt").read_text() == "keep" and sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos", "scene"]


def test_bad_option_values(tmp_path, capsys):
    photos = _photos(tmp_path / "photos", 3)
    assert "max size" in _error(capsys, prepare.main([str(photos), "--out", str(tmp_path / "s"), "--max-size", "10"]))
    with pytest.raises(SystemExit):
        prepare.main([str(photos), "--out", str(tmp_path / "s"), "--matcher", "vocab_tree"])


def test_train_on_plain_photos_says_run_prepare(tmp_path, capsys):
    photos = _photos(tmp_path / "photos", 4)
    line = _error(capsys, train.main([str(photos), "--out", str(tmp_path / "run")]))
    assert "holds photos but no camera poses: run `gof-warp prepare PHOTOS --out SCENE` first" in line
