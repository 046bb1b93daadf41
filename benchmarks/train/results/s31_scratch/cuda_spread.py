"""How far CUDA gradients move between two renders of the same inputs (float atomics), without a RenderScratch and
with one: the scale the CUDA tolerance of tests/test_render_host_glue.py must cover.

    python benchmarks/train/results/s31_scratch/cuda_spread.py [DEVICE]
"""
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path.cwd() / "tests"))
import test_render_host_glue as t  # noqa: E402

from gof_warp.render import RenderScratch  # noqa: E402


def spread(got, ref):
    """Largest |difference| over the gradient's largest |element|, and largest elementwise relative difference."""
    worst_scaled = worst_rel = 0.0
    for g, r in zip(got[1], ref[1]):
        if g is None or r.numel() == 0 or float(r.abs().max()) == 0.0:
            continue
        d = (g - r).abs()
        worst_scaled = max(worst_scaled, float(d.max() / r.abs().max()))
        big = r.abs() > 1e-3 * r.abs().max()
        worst_rel = max(worst_rel, float((d[big] / r.abs()[big]).max()))
    return worst_scaled, worst_rel


DEVICE = sys.argv[1] if len(sys.argv) > 1 else "cuda"
scratch = RenderScratch()
rows = {"none_vs_none": [0.0, 0.0], "scratch_vs_none": [0.0, 0.0]}
for rep in range(3):
    for call in t._mixed_calls():
        ref = call.render(DEVICE, None)
        for name, other in (("none_vs_none", call.render(DEVICE, None)), ("scratch_vs_none", call.render(DEVICE, scratch))):
            assert all(bool((other[0][k] == ref[0][k]).all()) for k in t.OUTPUTS), "forward outputs differ"
            s, r = spread(other, ref)
            rows[name] = [max(rows[name][0], s), max(rows[name][1], r)]
print(json.dumps({k: {"max_abs_over_max": v[0], "max_rel_of_elements_over_1e-3_max": v[1]} for k, v in rows.items()}))
