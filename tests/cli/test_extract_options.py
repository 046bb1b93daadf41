"""``python -m gof_warp.extract``'s options are checked before any work (issue 56): a value that means nothing is
``error: <message naming the flag>`` (exit 2, no traceback); a flag the chosen output or method does not use, a
warning. The run folder is only a name here: validation comes before the device, the ranks and the model."""

import logging

import pytest

from gof_warp.cli import extract
from gof_warp.mesh.extraction import MeshConfig
from gof_warp.mesh.marching_inputs import check_steps
from gof_warp.core.errors import GofError

HUGE = "1000000000000"

BAD = [  # (flag, value)
    ("--resolution", "0"), ("--resolution", "-5"), ("--resolution", "1"), ("--resolution", HUGE),
    ("--binary-steps", "-1"), ("--binary-steps", "1000"),
    ("--levels", "0"), ("--levels", "-0.5"), ("--levels", "1.5"), ("--levels", "nan"),
    ("--max-faces", "0"), ("--max-faces", "-3"), ("--max-faces", HUGE + "000000000"),
    ("--max-error", "0"), ("--max-error", "-1"), ("--max-error", "inf"), ("--max-error", "nan"),
    ("--min-views", "0"), ("--min-views", "-2"), ("--min-views", HUGE),
    ("--cell-factor", "0"), ("--cell-factor", "-1"), ("--cell-factor", "inf"),
    ("--piece-tets", "0"), ("--piece-tets", "-1"), ("--piece-tets", HUGE),
    ("--voxel-size", "0"), ("--voxel-size", "-0.1"), ("--voxel-size", "inf"),
    ("--volume-band", "-1"), ("--volume-band", HUGE),
    ("--opacity-min", "-0.1"), ("--opacity-min", "1"), ("--opacity-min", "2"),
    ("--corner-min-extent", "-1"), ("--corner-min-extent", "inf"),
    ("--min-component-faces", "-1"), ("--min-component-faces", HUGE),
    ("--search-steps-per-call", "-1"), ("--search-steps-per-call", "13"), ("--search-steps-per-call", HUGE),
    ("--delaunay-workers", "-1"), ("--delaunay-workers", HUGE),
]


def _run(cli_in_process, tmp_path, *args):
    return cli_in_process(extract.main, str(tmp_path / "run"), "--device", "cpu", "--no-pictures", *args)


@pytest.mark.parametrize("flag,value", BAD)
def test_a_nonsense_value_is_an_error_naming_the_flag(flag, value, tmp_path, cli_in_process):
    grid = ["--grid", "delaunay"] if flag in ("--corner-min-extent", "--delaunay-workers") else []  # its grid
    rc, err = _run(cli_in_process, tmp_path, *grid, flag, value)
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert rc == 2 and len(lines) == 1 and flag in lines[0] and "Traceback" not in err, err
    assert "neither a run folder" not in err  # refused before the run folder is read


def test_binary_steps_error_says_why(tmp_path, cli_in_process):
    rc, err = _run(cli_in_process, tmp_path, "--binary-steps", "1000")
    assert rc == 2 and "[0, 24]" in err and "halves" in err and "float32" in err


@pytest.mark.parametrize("levels", [["0.5", "0.5"], ["0.3", "0.5", "0.3"], ["0.5", "0.5000001"]])
def test_a_level_given_twice_is_an_error(levels, tmp_path, cli_in_process):
    """Was: one file written twice (``mesh_tetra_0.5.ply``)."""
    rc, err = _run(cli_in_process, tmp_path, "--levels", *levels)
    assert rc == 2 and "--levels" in err and ("0.3 twice" if levels[0] == "0.3" else "0.5") in err, err


def test_volume_takes_no_mesh_method(tmp_path, cli_in_process):
    """Was: the method ignored and NanoVDB bytes written to ``v.ply``."""
    rc, err = _run(cli_in_process, tmp_path, "--volume", "--method", "tsdf", "--out", str(tmp_path / "v.nvdb"))
    assert rc == 2 and "--volume" in err and "--method" in err and ".nvdb" in err, err


@pytest.mark.parametrize("out", ["v.ply", "v", "v.nvdb.json"])
def test_volume_out_must_be_nvdb(out, tmp_path, cli_in_process):
    rc, err = _run(cli_in_process, tmp_path, "--volume", "--out", str(tmp_path / out))
    assert rc == 2 and "--out must end in .nvdb" in err, err
    assert not (tmp_path / out).exists()


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def _checked(caplog, *argv):
    """``check_args`` on ``argv`` (the run folder need not exist): the warnings it gave."""
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="gof_warp.extract"):
        extract.check_args(extract.parse_args(["run", *argv]))
    return _warnings(caplog)


def test_mesh_flags_with_volume_warn_that_they_are_ignored(caplog):
    (w,) = _checked(caplog, "--volume", "--min-views", "2", "--max-faces", "1000", "--levels", "0.3", "--no-pictures")
    assert "--min-views" in w and "--max-faces" in w and "--levels" in w and "ignored" in w
    assert "--no-pictures" not in w  # a volume writes no pictures either way


@pytest.mark.parametrize("argv,flag", [
    (["--method", "tetra", "--resolution", "64"], "--resolution"),
    (["--resolution", "64"], "--resolution"),  # tetra by default
    (["--method", "tsdf", "--levels", "0.3"], "--levels"),
    (["--method", "tsdf", "--min-views", "2"], "--min-views"),
    (["--method", "cubes", "--cell-factor", "0.3"], "--cell-factor"),
    (["--method", "cubes", "--piece-tets", "1000"], "--piece-tets"),
    (["--voxel-size", "0.1"], "--voxel-size"),
])
def test_a_flag_the_method_does_not_use_is_a_warning(argv, flag, caplog):
    (w,) = _checked(caplog, *argv)
    assert flag in w and "ignored" in w


@pytest.mark.parametrize("argv", [[], ["--method", "cubes", "--resolution", "64", "--levels", "0.3", "0.6"],
                                  ["--method", "tsdf", "--resolution", "64"], ["--volume", "--voxel-size", "0.1"],
                                  ["--method", "cubes", "--binary-steps", "24", "--resolution", "2"]])
def test_sensible_options_pass_quietly(argv, caplog):
    assert _checked(caplog, *argv) == []


def test_library_checks():
    for bad in (dict(cubes_resolution=0), dict(binary_steps=1000), dict(levels=(0.5, 0.5)),
                dict(min_component_faces=-1)):
        with pytest.raises(GofError):
            MeshConfig(**bad).validate()
    with pytest.raises(GofError, match="float32"):
        check_steps(25)
    assert check_steps(24) == 24
