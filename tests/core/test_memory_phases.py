"""MemoryPhases: per-phase peaks of torch's allocator and the driver's view (CUDA), nothing on the CPU."""

import pytest
import torch

from gof_warp.core.devices import MemoryPhases


def test_on_the_cpu_nothing_is_recorded():
    phases = MemoryPhases(torch.device("cpu"))
    phases.sample()
    phases.end_phase("warm_up")
    assert phases.phases == {} and phases.overall() == {}


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_each_phase_has_its_own_peaks():
    device = torch.device("cuda")
    phases = MemoryPhases(device)
    big = torch.empty(256 * 2**20, dtype=torch.uint8, device=device)  # 256 MB in the first phase only
    phases.sample()
    phases.end_phase("big")
    del big
    small = torch.empty(16 * 2**20, dtype=torch.uint8, device=device)
    phases.end_phase("small")
    del small
    big_phase, small_phase = phases.phases["big"], phases.phases["small"]
    assert big_phase["gpu_peak_allocated_mb"] >= 256
    assert 16 <= small_phase["gpu_peak_allocated_mb"] < 256  # the counters restarted at the phase boundary
    assert big_phase["device_used_peak_mb"] >= big_phase["gpu_peak_reserved_mb"] >= 256
    assert phases.overall()["gpu_peak_allocated_mb"] == big_phase["gpu_peak_allocated_mb"]
