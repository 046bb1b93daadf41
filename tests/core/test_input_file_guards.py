"""Bad PLY and config files that used to give MemoryError / UnicodeDecodeError / RecursionError tracebacks (issue 56)."""

from __future__ import annotations

import pytest

from gof_warp.cli import train
from gof_warp.core.config import ConfigError, load_yaml
from gof_warp.core.errors import PlyError
from gof_warp.core.ply import read_ply_vertices


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_ply_header_claiming_1e13_vertices_is_a_ply_error_before_allocating(tmp_path, fmt):
    path = tmp_path / "huge.ply"
    path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex 10000000000000\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n".encode() + b"\0" * 24)
    with pytest.raises(PlyError, match=r"huge.ply: truncated: the header claims 10000000000000 vertices"):
        read_ply_vertices(path)


def test_ply_of_the_claimed_size_still_reads(tmp_path):
    path = tmp_path / "ok.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nend_header\n"
                     + b"\0" * 8)
    assert len(read_ply_vertices(path)["x"]) == 2


@pytest.mark.parametrize("content, needle", [(b"iterations: 5\n# caf\xe9\n", "not UTF-8"),
                                             (b"[" * 3_000_000, "nested too deeply")], ids=["latin1", "deep"])
def test_bad_config_file_is_a_config_error_naming_it(tmp_path, capsys, content, needle):
    path = tmp_path / "bad.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=needle) as e:
        load_yaml(path)
    assert str(path) in str(e.value)
    assert train.main([str(tmp_path / "no_scene"), "--out", str(tmp_path / "run"), "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and any(ln.startswith("error: ") and str(path) in ln for ln in err.splitlines()), err
