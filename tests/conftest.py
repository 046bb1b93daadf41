"""Shared test set-up: Warp's kernel cache in a known folder, devices to test on, the shared data path."""

import os
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
SHARED_DATA = REPO.parent / "shared" / "data"

# The tests mirror the packages (tests/core/, tests/mesh/, ...). The helpers here (reference_render, _scene_fixtures,
# _optim_cases) and the test modules other folders borrow from (``from test_volume import ...`` in tests/examples/)
# are imported by plain name: pytest's "prepend" import mode puts only a test file's own folder on sys.path, so
# tests/ and each of its folders go there once, here (test file basenames are unique across the tree).
for _folder in [TESTS, *sorted(p for p in TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "_")))]:
    if str(_folder) not in sys.path:
        sys.path.append(str(_folder))

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


# A few-iteration `python -m gof_warp.train` on a 5-view 32x32 default scene (the train command's tests).
_TINY_TRAIN_OVERRIDES = ["log_every=2", "checkpoint_every=100", "model.sh_degree=0", "model.init=random",
                         "model.random_init_points=300", "optim.means_lr_max_steps=6", "densify.start_iter=100",
                         "densify.stop_iter=100", "densify.filter_3d_until_iter=0", "loss.regularization_from_iter=100"]


@pytest.fixture
def tiny_train_overrides() -> list[str]:
    """``key=value`` overrides that make a training run of a few iterations cheap and deterministic."""
    return list(_TINY_TRAIN_OVERRIDES)


@pytest.fixture(scope="module")
def tiny_train_scene(tmp_path_factory):
    """A 5-view 32x32 synthetic default scene folder (module-scoped)."""
    from gof_warp.synthetic import make_scene

    return make_scene("default", tmp_path_factory.mktemp("scene") / "s", views=5, resolution=(32, 32), device="cpu")


@pytest.fixture
def cli_in_process(capsys):
    """``cli_in_process(main, *args) -> (exit code, stderr)``: a command's ``main`` run in this process (a subprocess
    start costs CI seconds; keep one real-process case per command for the exit path)."""

    def run(main, *args) -> tuple[int, str]:
        capsys.readouterr()
        try:
            rc = main(list(args))
        except SystemExit as e:  # argparse's own errors
            rc = e.code
        return rc, capsys.readouterr().err

    return run
