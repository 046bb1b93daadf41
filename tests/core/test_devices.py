"""One device rule (gof_warp.core.devices): explicit > the inputs' device > CUDA only when torch and Warp agree."""

import re
from pathlib import Path

import pytest
import torch

from gof_warp.core import devices
from gof_warp.core.errors import GofError

ROOT = Path(__file__).resolve().parents[2]


def test_explicit_wins_and_names_are_checked():
    assert devices.resolve_device("cpu") == "cpu"
    assert devices.resolve_device(torch.device("cpu")) == "cpu"
    with pytest.raises(GofError, match="cpu, cuda, cuda:N or auto"):
        devices.resolve_device("tpu")


def test_inputs_decide_when_nothing_is_named():
    t = torch.zeros(3)
    assert devices.resolve_device(None, like=t) == "cpu"
    assert devices.resolve_device("auto", like=t) == "cpu"


def test_cuda_only_when_torch_and_warp_both_see_it(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)  # torch "sees" a GPU ...
    import warp as wp

    monkeypatch.setattr(wp, "get_cuda_device_count", lambda: 0)  # ... Warp does not: they must not disagree
    assert not devices.cuda_available()
    assert devices.resolve_device() == "cpu"
    with pytest.raises(GofError, match="do not both see a CUDA device"):
        devices.resolve_device("cuda")


@pytest.mark.skipif(not devices.cuda_available(), reason="no CUDA device on this machine (CPU CI)")
def test_cuda_names_are_indexed():
    assert devices.resolve_device("cuda") == f"cuda:{torch.cuda.current_device()}"
    assert devices.warp_device("cuda:0") == "cuda:0"


def test_warp_names():
    assert devices.warp_device("cpu") == "cpu" and devices.warp_device(None) in ("cpu", "cuda:0")


def test_no_other_module_decides_the_default_device():
    """The rule lives in one place: no library module asks torch or Warp for CUDA on its own or hard-codes
    ``"cuda:0"`` (the bench report names the machine; the trainer saves every GPU's RNG state — both allowed)."""
    allowed = {"core/devices.py", "benchmarking/report.py"}
    pattern = re.compile(r'torch\.cuda\.is_available\(\)|get_cuda_device_count|is_cuda_available|"cuda:0"')
    offenders = []
    for path in sorted((ROOT / "gof_warp").rglob("*.py")):
        if path.relative_to(ROOT / "gof_warp").as_posix() in allowed:
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line) and "rng_state" not in line and "cuda_rng" not in line:
                offenders.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not offenders, "device decided outside gof_warp.core.devices:\n" + "\n".join(offenders)


def test_cudnn_benchmark_is_set_inside_and_restored_after():
    cudnn_benchmark = devices.cudnn_benchmark
    before = torch.backends.cudnn.benchmark
    try:
        torch.backends.cudnn.benchmark = False
        with cudnn_benchmark(True):
            assert torch.backends.cudnn.benchmark is True
        assert torch.backends.cudnn.benchmark is False
        with cudnn_benchmark(False):  # off leaves the caller's setting alone
            assert torch.backends.cudnn.benchmark is False
        torch.backends.cudnn.benchmark = True
        with pytest.raises(RuntimeError), cudnn_benchmark(False):
            assert torch.backends.cudnn.benchmark is True
            raise RuntimeError("restored on errors too")
        assert torch.backends.cudnn.benchmark is True
    finally:
        torch.backends.cudnn.benchmark = before


def test_expandable_segments_are_set_for_cuda_only_and_never_over_the_users_setting(monkeypatch):
    import torch

    from gof_warp.core import devices

    calls = []
    monkeypatch.setattr(torch.cuda.memory, "_set_allocator_settings", calls.append, raising=False)
    monkeypatch.delenv("PYTORCH_CUDA_ALLOC_CONF", raising=False)
    assert devices.expandable_cuda_segments("cpu") is False and calls == []
    assert devices.expandable_cuda_segments("cuda:0") is True
    assert calls == [devices.EXPANDABLE_SEGMENTS]
    monkeypatch.setenv("PYTORCH_CUDA_ALLOC_CONF", "max_split_size_mb:128")
    assert devices.expandable_cuda_segments("cuda:0") is False and len(calls) == 1
