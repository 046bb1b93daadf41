"""Shared test set-up: Warp's kernel cache in a known folder, devices to test on, the shared data path."""

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"

# Warp compiles kernels once per module; keep the cache beside the repo so CI can reuse it between steps.
os.environ.setdefault("WARP_CACHE_PATH", str(REPO / ".warp_cache"))


def _devices():
    devs = ["cpu"]
    try:
        import torch

        if torch.cuda.is_available():
            devs.append("cuda")
    except ImportError:  # pragma: no cover
        pass
    return devs


DEVICES = _devices()


@pytest.fixture(params=DEVICES)
def device(request):
    """Every test that takes ``device`` runs on the CPU, and on CUDA where present."""
    return request.param


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (real scenes); skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder {SHARED_DATA} is absent")
    return SHARED_DATA
