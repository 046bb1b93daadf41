"""Every Warp kernel module compiles for CUDA, on any machine: Warp's wheel carries NVRTC, so ``wp.compile_aot_module``
builds the sm_90 (H100/H200) code without a GPU. A construct the CPU backend accepts and NVRTC does not, a
``wp.func_native`` CUDA branch or a shared-memory tile that no longer fits would otherwise first fail on a GPU machine
(the CPU tests run the same kernels on the CPU backend only).

The per-pixel CUDA kernels also keep their shared memory under the 48 KiB a block gets without opting in: three blocks
per SM is what their register cap was chosen for (``kernels/rasterize_tiled.py``)."""

from __future__ import annotations

import importlib
import json
import pkgutil

import pytest
import warp as wp

import gof_warp.kernels as K

pytestmark = pytest.mark.slow  # compiles every kernel module for CUDA

ARCH = 90  # sm_90: H100 / H200, the GPUs the project is measured on
STATIC_SMEM_LIMIT = 48 * 1024


def _kernel_modules() -> list[str]:
    names = []
    for info in pkgutil.iter_modules(K.__path__):
        module = importlib.import_module(f"gof_warp.kernels.{info.name}")
        if any(isinstance(v, wp.Kernel) and getattr(v, "module", None) is not None and
               v.module.name == module.__name__ for v in vars(module).values()):
            names.append(info.name)
    return names


def _nvrtc_archs() -> list[int]:
    wp.init()
    from warp._src.context import runtime

    return list(runtime.nvrtc_supported_archs or []) if runtime.toolkit_version else []


@pytest.mark.parametrize("name", _kernel_modules())
def test_kernel_module_compiles_for_cuda(name, tmp_path):
    if ARCH not in _nvrtc_archs():
        pytest.skip(f"this Warp build has no NVRTC for sm_{ARCH}: CUDA code cannot be compiled without a GPU here")
    module = importlib.import_module(f"gof_warp.kernels.{name}")
    outputs = wp.compile_aot_module(module, device=None, arch=ARCH, module_dir=tmp_path)
    assert any(str(p).endswith(f".sm{ARCH}.cubin") for p in outputs), outputs
    if name == "rasterize_tiled":
        meta = json.loads(next(tmp_path.glob("*.meta")).read_text())
        smem = {k: v for k, v in meta.items() if k.endswith("_smem_bytes")}
        assert len(smem) == 2 and all(0 < v <= STATIC_SMEM_LIMIT for v in smem.values()), smem


def test_the_compile_check_covers_the_renderer_and_the_field():
    names = _kernel_modules()
    assert {"project", "rasterize", "rasterize_backward", "rasterize_tiled", "opacity_field", "binning"} <= set(names)
