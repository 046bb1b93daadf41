"""Warp launches ordered with torch's work, without importing torch: Warp-only programs that embed the
mesh and field code never load it."""

from __future__ import annotations

import contextlib
import sys

import warp as wp


def loaded_torch():
    """The torch module when the process has loaded it (a torch caller), else None: never imports it."""
    return sys.modules.get("torch")


def torch_stream(device: str):
    """On CUDA with torch loaded, launch on torch's current stream, so torch fields and Warp kernels are
    ordered; a pure Warp program keeps Warp's current stream (``wp.ScopedStream`` is respected)."""
    if loaded_torch() is not None and wp.get_device(device).is_cuda:
        return wp.ScopedStream(wp.stream_from_torch(wp.device_to_torch(device)))
    return contextlib.nullcontext()
