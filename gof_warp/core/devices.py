"""One rule for devices, for torch and Warp alike.

1. A device the caller names wins (``"cpu"``, ``"cuda"``, ``"cuda:1"``; ``"auto"`` means "not named").
2. Otherwise the device of the inputs: work follows its data (a tensor's device, a model's device).
3. Otherwise CUDA when **both** torch and Warp see a CUDA device, else CPU — a CPU-only torch next to a
   CUDA-capable Warp (or the reverse) gets the CPU, so the two never disagree about where data lives.

Torch names (``"cuda:0"``, ``"cpu"``) are the currency; :func:`warp_device` gives Warp's name for the same
device. Memory figures and synchronisation take the device from here too, never a hard-coded ``"cuda:0"``.
"""

from __future__ import annotations

import contextlib
import resource
import threading

import torch

from .errors import GofError


def cuda_available() -> bool:
    """True when torch and Warp both see a CUDA device."""
    if not torch.cuda.is_available():
        return False
    import warp as wp

    wp.init()
    return wp.get_cuda_device_count() > 0


def resolve_device(device=None, like=None) -> str:
    """The torch device string to work on (rules in the module docstring).

    Args:
        device: a device the caller names (str or ``torch.device``), ``"auto"`` or None.
        like: a tensor (or anything with ``.device``) whose device the work follows when ``device`` is not named.
    Raises:
        GofError: a CUDA device was named but torch or Warp cannot use it, or the name is not a device.
    """
    if device is not None and str(device) != "auto":
        name = str(device)
        if name.startswith("cuda"):
            if not cuda_available():
                raise GofError(f"device {name!r} was asked for but torch and Warp do not both see a CUDA device")
            dev = torch.device(name)
            return f"cuda:{dev.index if dev.index is not None else torch.cuda.current_device()}"
        if name != "cpu":
            raise GofError(f"device must be cpu, cuda, cuda:N or auto, got {name!r}")
        return "cpu"
    if like is not None and getattr(like, "device", None) is not None:
        return resolve_device(like.device)
    return resolve_device("cuda") if cuda_available() else "cpu"


#: torch's allocator setting for training on CUDA (:func:`expandable_cuda_segments`).
EXPANDABLE_SEGMENTS = "expandable_segments:True"


def expandable_cuda_segments(device) -> bool:
    """On a CUDA ``device``, let torch's caching allocator grow a segment in place (``expandable_segments``) instead of
    asking the driver for a new one whenever a tensor is larger than every free block — unless the user set
    ``PYTORCH_CUDA_ALLOC_CONF``, which wins. Returns whether the setting was made (False on the CPU).

    Training needs it: densification makes every per-Gaussian tensor (parameters, Adam moments, gradients) a little
    larger each time, so with fixed segments each new size takes new segments while the smaller freed blocks stay
    cached for sizes never asked again. Measured on DTU scan 24 (30k iterations, one H200, ``benchmarks/train/``):
    26,756 MiB reserved at the peak for 1,573 MiB ever allocated; with expandable segments 2,440 MiB, training time
    and PSNR unchanged.
    Process-wide: callers that own the process (the ``train`` command) call it, before the first CUDA allocation.
    """
    import os

    if torch.device(str(device)).type != "cuda" or os.environ.get("PYTORCH_CUDA_ALLOC_CONF"):
        return False
    setter = getattr(torch.cuda.memory, "_set_allocator_settings", None)
    if setter is None:  # a torch without the runtime setter: the variable works if CUDA is not initialised yet
        os.environ["PYTORCH_CUDA_ALLOC_CONF"] = EXPANDABLE_SEGMENTS
        return not torch.cuda.is_initialized()
    setter(EXPANDABLE_SEGMENTS)
    return True


@contextlib.contextmanager
def cudnn_benchmark(on: bool = True):
    """Within the block, cuDNN times its algorithms for each new convolution shape (``torch.backends.cudnn.benchmark``)
    when ``on``; the previous setting is restored after it (``on=False`` leaves the setting as it is)."""
    before = torch.backends.cudnn.benchmark
    torch.backends.cudnn.benchmark = before or bool(on)
    try:
        yield
    finally:
        torch.backends.cudnn.benchmark = before


def warp_device(device) -> str:
    """Warp's name for a torch device (``"cuda:0"`` / ``"cpu"``)."""
    dev = torch.device(resolve_device(device))
    return "cpu" if dev.type == "cpu" else f"cuda:{dev.index}"


class StreamWrappers:
    """Warp's wrappers of torch's CUDA streams, one per (device, stream handle), made on first use and kept: Warp work
    launched through :meth:`current` runs on torch's current stream, ordered with torch's own work. One wrapper per
    handle because a second would unregister the stream when it dies (Warp 1.19 does not count registrations); safe to
    share between threads (torch runs a CUDA backward on a thread of its own)."""

    def __init__(self):
        self._streams: dict[tuple[int, int], object] = {}  # (device ordinal, stream handle) -> Warp's wrapper
        self._lock = threading.Lock()

    def current(self, device: torch.device):
        """The Warp stream wrapping torch's current stream on the CUDA ``device``."""
        stream = torch.cuda.current_stream(device)
        key = (stream.device_index, stream.cuda_stream)
        wrapper = self._streams.get(key)
        if wrapper is None:
            with self._lock:
                wrapper = self._streams.get(key)
                if wrapper is None:
                    import warp as wp

                    wrapper = self._streams[key] = wp.stream_from_torch(stream)
        return wrapper

    def launch_stream(self, device: torch.device):
        """The ``stream`` to give a recorded Warp launch for tensors on ``device``: :meth:`current` on CUDA, ``None``
        (none needed) on the CPU."""
        return self.current(device) if device.type == "cuda" else None


def is_cuda(device) -> bool:
    return torch.device(str(device)).type == "cuda"


class MemoryPhases:
    """Peak device memory per phase of a run, on a CUDA ``device`` (on the CPU every method is a no-op).

    For each phase: torch's allocated and reserved peaks (its caching allocator: reserved is what the process holds
    from the driver for torch), Warp's pool high-water mark, and the device's used memory as the driver reports it
    (``cudaMemGetInfo``: every process and context on the device), sampled at :meth:`sample`. A phase ends at
    :meth:`end_phase`, which resets torch's peak counters, so each phase's peaks are its own.
    """

    def __init__(self, device: torch.device):
        self.device = device
        self.cuda = device.type == "cuda"
        self.phases: dict[str, dict] = {}
        self._driver_peak = 0
        if self.cuda:
            torch.cuda.reset_peak_memory_stats(device)

    def sample(self) -> None:
        """Read the driver's used memory now (call where the host waits for the device anyway)."""
        if self.cuda:
            free, total = torch.cuda.mem_get_info(self.device)
            self._driver_peak = max(self._driver_peak, total - free)

    def end_phase(self, name: str) -> None:
        """Record the peaks since the last phase ended under ``name`` and start counting the next phase."""
        if not self.cuda:
            return
        import warp as wp

        self.sample()
        self.phases[name] = {
            "gpu_peak_allocated_mb": round(torch.cuda.max_memory_allocated(self.device) / 2**20, 1),
            "gpu_peak_reserved_mb": round(torch.cuda.max_memory_reserved(self.device) / 2**20, 1),
            "gpu_reserved_at_end_mb": round(torch.cuda.memory_reserved(self.device) / 2**20, 1),
            "gpu_warp_pool_high_mb": round(wp.get_mempool_used_mem_high(warp_device(self.device)) / 2**20, 1),
            "device_used_peak_mb": round(self._driver_peak / 2**20, 1),
        }
        self._driver_peak = 0
        torch.cuda.reset_peak_memory_stats(self.device)

    def overall(self) -> dict:
        """The run's peaks over every phase recorded so far (empty on the CPU)."""
        if not self.phases:
            return {}
        keys = ("gpu_peak_allocated_mb", "gpu_peak_reserved_mb", "device_used_peak_mb")
        return {k: max(ph[k] for ph in self.phases.values()) for k in keys}


def peak_memory(device: torch.device) -> dict:
    """Host peak RSS and, on a CUDA ``device``, its torch and Warp-pool peaks (MB)."""
    out = {"host_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    if device.type == "cuda":
        import warp as wp

        out["gpu_peak_allocated_mb"] = torch.cuda.max_memory_allocated(device) / 2**20
        out["gpu_peak_reserved_mb"] = torch.cuda.max_memory_reserved(device) / 2**20
        # the renderer's temporaries live in Warp's own memory pool, which torch does not see
        out["gpu_peak_warp_pool_mb"] = wp.get_mempool_used_mem_high(warp_device(device)) / 2**20
    return out
