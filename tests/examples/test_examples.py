"""Every program in examples/ runs on the CPU with its tiny defaults and prints what it promises."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # runs every example in a fresh interpreter

EXAMPLES = sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.py"))
# What each example must print (beyond exiting 0); examples not listed must print something.
EXPECTED = {
    "load_scene": ["format: blender", "train_views: 6"],
}


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(path, tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.run([sys.executable, str(path), "--device", "cpu"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{path.name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    assert proc.stdout.strip(), f"{path.name} printed nothing"
    for text in EXPECTED.get(path.stem, []):
        assert text in proc.stdout, f"{path.name} output lacks {text!r}:\n{proc.stdout[-2000:]}"
