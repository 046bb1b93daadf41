"""Which PTX spelling of the sm_90 vector reduction compiles and adds correctly (GPU probe, not part of the repo)."""
import sys
import numpy as np
import warp as wp

wp.init()
SYNTAX = {
    "add_v4": "red.global.add.v4.f32 [ga], {%1, %2, %3, %4};",
    "v4_add": "red.global.v4.f32.add [ga], {%1, %2, %3, %4};",
    "relaxed_gpu_add_v4": "red.relaxed.gpu.global.add.v4.f32 [ga], {%1, %2, %3, %4};",
}
for name, instr in SYNTAX.items():
    snippet = ('float* p = wp::address(buf, i, j);\n#if defined(__CUDA_ARCH__) && (__CUDA_ARCH__ >= 900)\n'
               'asm volatile("{ .reg .u64 ga; cvta.to.global.u64 ga, %0; ' + instr + ' }" :: "l"(p), "f"(v[0]), "f"(v[1]), "f"(v[2]), "f"(v[3]) : "memory");\n'
               '#else\nfor (int c = 0; c < 4; ++c) wp::atomic_add(p + c, v[c]);\n#endif\n')
    try:
        mod = {}
        src = f'''
import warp as wp
@wp.func_native({snippet!r})
def add4(buf: wp.array2d(dtype=float), i: int, j: int, v: wp.vec4): ...
@wp.kernel(module="unique")
def k(buf: wp.array2d(dtype=float)):
    t = wp.tid()
    add4(buf, t % 7, 4 * (t % 4), wp.vec4(1.0, 2.0, 3.0, float(t % 3)))
'''
        path = f"/tmp/probe_{name}.py"
        open(path, "w").write(src)
        import importlib.util
        spec = importlib.util.spec_from_file_location(f"probe_{name}", path)
        m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)
        buf = wp.zeros((7, 16), dtype=float, device="cuda")
        wp.launch(m.k, dim=100000, inputs=[buf], device="cuda")
        got = buf.numpy()
        want = np.zeros((7, 16), np.float32)
        for t in range(100000):
            want[t % 7, 4 * (t % 4):4 * (t % 4) + 4] += [1, 2, 3, t % 3]
        print(name, "OK" if np.allclose(got, want) else f"WRONG {np.abs(got-want).max()}")
    except Exception as e:
        print(name, "FAILED", type(e).__name__, str(e)[-600:])
