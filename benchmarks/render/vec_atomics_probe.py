"""Which PTX spellings of the sm_90 vector reduction (``red.global.add.v4.f32``) Warp's compiler accepts, and whether
each adds correctly: the check behind ``kernels.rasterize_backward.atomic_add4`` (session 21: all three below compile
and add correctly on an H100).

    python benchmarks/render/vec_atomics_probe.py      # on a CUDA machine; prints one line per spelling

Each spelling goes into a ``wp.func_native`` of its own module (written to a temporary folder and imported), which
100,000 threads call on a ``[7, 16]`` array; the sums are compared with NumPy's.
"""

from __future__ import annotations

import importlib.util
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

SPELLINGS = {
    "add_v4": "red.global.add.v4.f32 [ga], {%1, %2, %3, %4};",
    "v4_add": "red.global.v4.f32.add [ga], {%1, %2, %3, %4};",
    "relaxed_gpu_add_v4": "red.relaxed.gpu.global.add.v4.f32 [ga], {%1, %2, %3, %4};",
}
THREADS = 100_000

MODULE = '''
import warp as wp

@wp.func_native({snippet!r})
def add4(buf: wp.array2d(dtype=float), i: int, j: int, v: wp.vec4): ...

@wp.kernel
def add_rows(buf: wp.array2d(dtype=float)):
    t = wp.tid()
    add4(buf, t % 7, 4 * (t % 4), wp.vec4(1.0, 2.0, 3.0, float(t % 3)))
'''


def probe(name: str, instruction: str, folder: Path) -> str:
    snippet = ('float* p = wp::address(buf, i, j);\n#if defined(__CUDA_ARCH__) && (__CUDA_ARCH__ >= 900)\n'
               'asm volatile("{ .reg .u64 ga; cvta.to.global.u64 ga, %0; ' + instruction + ' }" '
               ':: "l"(p), "f"(v[0]), "f"(v[1]), "f"(v[2]), "f"(v[3]) : "memory");\n'
               '#else\nfor (int c = 0; c < 4; ++c) wp::atomic_add(p + c, v[c]);\n#endif\n')
    path = folder / f"probe_{name}.py"
    path.write_text(MODULE.format(snippet=snippet))
    spec = importlib.util.spec_from_file_location(f"probe_{name}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
        buf = wp.zeros((7, 16), dtype=float, device="cuda")
        wp.launch(module.add_rows, dim=THREADS, inputs=[buf], device="cuda")
        got = buf.numpy()
    except Exception as e:  # noqa: BLE001 - a spelling the compiler refuses is a result, not a crash
        return f"FAILED {type(e).__name__}: {str(e)[-600:]}"
    t = np.arange(THREADS)
    want = np.zeros((7, 16), np.float64)
    for q in range(4):
        rows = t[t % 4 == q]
        np.add.at(want[:, 4 * q:4 * q + 4], rows % 7, np.stack([np.ones_like(rows), 2 * np.ones_like(rows),
                                                                3 * np.ones_like(rows), rows % 3], 1))
    return "OK" if np.allclose(got, want) else f"WRONG (max error {np.abs(got - want).max()})"


def main() -> None:
    wp.init()
    with tempfile.TemporaryDirectory() as d:
        for name, instruction in SPELLINGS.items():
            print(name, probe(name, instruction, Path(d)))


if __name__ == "__main__":
    main()
