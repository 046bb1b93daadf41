"""Host (Python) cost of one differentiable render, forward + backward, measured on the CPU (issue 14).

On the GPU the host issues ``gof_warp.render.render`` forward + backward while the GPU runs the kernels, and a slow
host makes training host-bound (``host_budget.py --parts render``). That host work is Python glue — wrapping torch
tensors as Warp arrays, allocating scratch, filling structs, packing launch arguments, torch ops around the Warp
calls — and most of it is the same on the CPU, where it can be measured without a GPU: render a tiny scene (64
Gaussians, 32×32 pixels by default), so the kernels cost little, and take the kernels' own time out of the wall clock.

Printed per forward + backward (median and minimum of ``--reps`` measurements of ``--calls`` calls each):

- ``wall``: wall clock (no profiler);
- ``kernels``: time inside Warp's CPU ``invoke`` (the call into a compiled kernel) and the CPU radix sort and scan,
  taken by thin timing wrappers;
- ``outside``: ``wall − kernels``, the host glue, with the toy loss of ``host_budget.py``'s render part;
- ``floor``: the same step with the Warp render replaced by a ``torch.autograd.Function`` that returns ready maps (the
  model's activations, the toy loss and its backward, one Function): the part of ``outside`` that is not the
  renderer's;

and, from one cProfile run, the calls per render of ``wp.launch``, ``wp.from_torch`` (arrays and descriptors),
``wp.empty``/``wp.zeros``, Warp memory allocations, ``wp.array`` constructions, Warp struct field sets and all
Python-level calls, and the torch operators dispatched.

The box's speed drifts, and one process differs from the next by a few per cent (memory layout): compare code
versions by alternating processes, several of each (e.g. ``PYTHONPATH=<other tree>`` for the other version).
``--scratch`` renders through one ``gof_warp.render.RenderScratch``, as the trainer does (a tree that has it).

    python benchmarks/train/host_glue_cpu.py [--gaussians 64] [--size 32] [--calls 50] [--reps 5] [--cprofile 25]
                                             [--scratch]
"""

from __future__ import annotations

import argparse
import cProfile
import collections
import pstats
import statistics
import time

import torch
import warp as wp
import warp._src.codegen as wp_codegen
import warp._src.context as wp_context
from torch.utils._python_dispatch import TorchDispatchMode

wp.config.quiet = True

#: The Warp functions counted per render: (label, functions).
COUNTED = (
    ("wp.launch", (wp.launch,)),
    ("wp.from_torch", (wp.from_torch,)),
    ("wp.empty", (wp.empty,)),
    ("wp.zeros", (wp.zeros,)),
    ("Warp allocations", tuple(c.allocate for c in (wp_context.CpuDefaultAllocator, wp_context.CpuPinnedAllocator,
                                                    wp_context.CudaDefaultAllocator, wp_context.CudaMempoolAllocator))),
    ("wp.array constructions", (wp.array.__init__,)),
    ("struct field sets", (wp_codegen.StructInstance.__setattr__,)),
)


class _CountOps(TorchDispatchMode):
    """Counts the torch operators dispatched (forward and backward)."""

    def __init__(self):
        super().__init__()
        self.ops = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.ops[str(func)] += 1
        return func(*args, **(kwargs or {}))


def _time(step, calls: int, reps: int, clock) -> list[float]:
    """ms per call of ``step``, ``reps`` times."""
    times = []
    for _ in range(reps):
        t0 = clock()
        for _ in range(calls):
            step()
        times.append((clock() - t0) / calls * 1e3)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gaussians", type=int, default=64)
    ap.add_argument("--size", type=int, default=32, help="image width = height in pixels")
    ap.add_argument("--calls", type=int, default=50, help="renders per measurement")
    ap.add_argument("--reps", type=int, default=5, help="measurements (median and minimum printed)")
    ap.add_argument("--cprofile", type=int, default=0, help="also print the N functions of most own time")
    ap.add_argument("--clock", choices=("wall", "thread"), default="wall",
                    help="thread: this thread's CPU time (time.thread_time) instead of the wall clock")
    ap.add_argument("--scratch", action="store_true", help="render through a RenderScratch, as the trainer")
    args = ap.parse_args()

    from gof_warp.camera import look_at
    from gof_warp.kernels.binning import TileListSizer
    from gof_warp.model import Gaussians
    from gof_warp.render import render

    torch.manual_seed(0)
    size = args.size
    cam = look_at((3.0, 0.0, 1.0), (0.0, 0.0, 0.0), fx=0.9 * size, width=size, height=size)
    g = Gaussians.random_in_box(args.gaussians, sh_degree=3)
    g.requires_grad_(True)
    sizer = TileListSizer()
    clock = time.thread_time if args.clock == "thread" else time.perf_counter
    kept = {}
    if args.scratch:
        from gof_warp.render import RenderScratch

        kept["scratch"] = RenderScratch()

    def step():  # as host_budget.py's render part
        out = render(g, cam, tile_lists=sizer, **kept)
        (out["rgb"].sum() + out["alpha"].sum() + out["median_depth"].sum() + out["normal"].sum()
         + out["distortion"].sum()).backward()

    # the kernels' work: thin timing wrappers around Warp's invoke (looked up as a module global) and the CPU radix
    # sort and scan (looked up as attributes of wp.utils)
    in_kernels = [0.0]
    originals = {(wp_context, "invoke"): wp_context.invoke, (wp.utils, "radix_sort_pairs"): wp.utils.radix_sort_pairs,
                 (wp.utils, "array_scan"): wp.utils.array_scan}

    def timed(fn):
        def call(*a, **k):
            t0 = clock()
            try:
                return fn(*a, **k)
            finally:
                in_kernels[0] += clock() - t0
        return call

    for _ in range(20):  # compile, warm the caches
        step()
    walls, kernels = [], []
    for (module, name), fn in originals.items():
        setattr(module, name, timed(fn))
    try:
        for _ in range(args.reps):
            in_kernels[0] = 0.0
            walls += _time(step, args.calls, 1, clock)
            kernels.append(in_kernels[0] / args.calls * 1e3)
    finally:
        for (module, name), fn in originals.items():
            setattr(module, name, fn)

    # the floor: the same step around a Function that returns this render's maps
    with torch.no_grad():
        maps = render(g, cam, tile_lists=sizer)
    ready = [maps[k].clone() for k in ("rgb", "alpha", "median_depth", "normal", "distortion")]

    class Ready(torch.autograd.Function):
        @staticmethod
        def forward(ctx, *params):
            ctx.shapes = [p.shape for p in params]
            return tuple(m.clone() for m in ready)

        @staticmethod
        def backward(ctx, *grads):
            return tuple(torch.zeros(s) for s in ctx.shapes)

    def floor_step():
        rgb, alpha, median, normal, dist = Ready.apply(g.means, g.rotations, g.scales, g.opacities, g.sh_dc, g.sh_rest)
        (rgb.sum() + alpha.sum() + median.sum() + normal.sum() + dist.sum()).backward()

    for _ in range(20):
        floor_step()
    floor = _time(floor_step, args.calls, args.reps, clock)

    outside = [w - k for w, k in zip(walls, kernels)]
    print(f"{args.gaussians} Gaussians, {size}x{size} pixels, {args.calls} renders x {args.reps}"
          f"{' through a RenderScratch' if args.scratch else ''} (ms per forward+backward: median, min, then all):")
    for name, values in (("wall", walls), ("kernels", kernels), ("outside", outside), ("floor", floor)):
        all_values = ", ".join(f"{v:.3f}" for v in values)
        print(f"  {name:8s} {statistics.median(values):7.3f} {min(values):7.3f}   [{all_values}]")

    for _ in range(3):  # back to the training loop's steady state
        step()
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(args.calls):
        step()
    prof.disable()
    stats = pstats.Stats(prof)
    with _CountOps() as counter:
        step()
    print(f"calls per forward+backward (cProfile, {args.calls} renders):")
    for label, funcs in COUNTED:
        where = {(f.__code__.co_filename, f.__code__.co_firstlineno) for f in funcs}
        n = sum(v[1] for (file, line, _), v in stats.stats.items() if (file, line) in where)
        print(f"  {label:24s} {n / args.calls:6.1f}")
    print(f"  {'all Python-level calls':24s} {stats.total_calls / args.calls:6.0f}")
    print(f"  {'torch operators':24s} {sum(counter.ops.values()):6d}")
    if args.cprofile:
        stats.sort_stats("tottime").print_stats(args.cprofile)


if __name__ == "__main__":
    main()
