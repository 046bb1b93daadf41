"""Speed anchor: gsplat's 3DGS rasteriser on the same Gaussians, camera and images as ``bench_render.py``.

    source benchmarks/render/gsplat_setup.sh                       # on the GPU machine (see the README)
    python3 benchmarks/render/bench_gsplat.py --check --out DIR    # both renderers on one small scene: PSNR
    python3 benchmarks/render/bench_gsplat.py --out DIR            # sweep: 800x600, 1920x1080 x 100k..3M
    python3 benchmarks/render/bench_gsplat.py --sizes 1920x1080 --counts 1M --packed false

What is compared: the per-image cost of two different renderers on identical Gaussians. gsplat
(``rasterization(..., render_mode="RGB+ED")``) projects each Gaussian to a 2D screen-space Gaussian (EWA
splatting, +0.3 px^2 low-pass ``eps2d``) and composites colour and expected depth (of the centres); ours
(``gof_warp.rendering.render.rasterize``) intersects every pixel ray with each 3D Gaussian (GOF) and composites
colour, alpha, expected depth and median depth of the intersection points, normals and the distortion
loss. Neither does the other's extra work, so the ratio is "what our image costs" vs "what a standard
3DGS image costs" on the same scene, not a like-for-like kernel race.

Conversions (verified against our code, see the README's "gsplat anchor" section): ``make_scene``
returns ACTIVATED parameters (unit quaternions wxyz, positive scales = standard deviations, opacities
in (0, 1), SH [N, 16, 3] dc first), which is what gsplat takes; the view matrix is our ``Camera.w2c``
(x_cam = R x_world + t, OpenCV axes: x right, y down, z forward = gsplat's convention) and ``Ks`` our
``Camera.K`` (pixel centres at i + 0.5 in both). gsplat applies ``max(SH + 0.5, 0)`` as we do.

Timing (as ``bench_render.py``): CUDA events around the public call, median (and min) of 7 runs after
2 warm-ups; fwd under ``torch.no_grad()``; fwd+bwd = forward + a fixed random weighted sum of all the
outputs gsplat returns (RGB, expected depth, alpha) + ``backward()`` into the five parameter tensors.
Peak memory: ``torch.cuda.max_memory_allocated`` since the scene was made (gsplat allocates everything
through torch; our renderer's figure is torch's plus Warp's mempool). All points run in one process;
memory is freed between them.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DEFAULT_SIZES = ("800x600", "1920x1080")
DEFAULT_COUNTS = (100_000, 500_000, 1_000_000, 3_000_000)


def _fail(msg: str) -> None:
    print(f"bench_gsplat: {msg}", file=sys.stderr)
    raise SystemExit(2)


def _import_ours():
    """bench_render (make_scene, make_camera) and our renderer; bench_render is imported, never modified."""
    sys.path.insert(0, str(HERE))
    try:
        import bench_render as br  # also puts the repo root on sys.path and imports warp + gof_warp
        from gof_warp.rendering.render import RenderConfig, rasterize
    except ImportError as e:
        _fail(f"cannot import our renderer / bench_render.py ({e}); on the GPU machine source Warp's "
              f"install.sh and benchmarks/device_setup.sh first")  # fmt: skip
    return br, RenderConfig, rasterize


def _require_cuda():
    import torch

    if not torch.cuda.is_available():
        _fail(f"CUDA unavailable: torch {torch.__version__} (built with CUDA {torch.version.cuda}) sees no CUDA "
              f"device; this benchmark runs only on the GPU machine")  # fmt: skip
    return torch


def _import_gsplat():
    try:
        import gsplat
        from gsplat import rasterization
    except ImportError as e:
        missing = getattr(e, "name", None) or str(e)
        _fail(f"cannot import gsplat (missing module: {missing}); on the GPU machine "
              f"`source benchmarks/render/gsplat_setup.sh` installs it from .whl_gs/")  # fmt: skip
    return gsplat, rasterization


def parse_count(s: str) -> int:
    s = s.strip().lower().replace("_", "")
    mult = {"k": 1_000, "m": 1_000_000}.get(s[-1:], 1)
    return int(float(s[:-1] if mult > 1 else s) * mult)


def parse_size(s: str) -> tuple[int, int]:
    w, h = s.lower().split("x")
    return int(w), int(h)


def _split(values):
    return [v for item in values for v in item.split(",") if v]


def gsplat_inputs(params, cam, torch):
    """gsplat's tensors for our activated parameters and Camera (see the module docstring)."""
    means, quats, scales, opacities, sh = params
    dev = means.device
    viewmats = torch.tensor(cam.w2c, dtype=torch.float32, device=dev)[None]  # [1, 4, 4] world-to-camera
    Ks = torch.tensor(cam.K, dtype=torch.float32, device=dev)[None]  # [1, 3, 3]
    sh_degree = int(round(math.sqrt(sh.shape[1]))) - 1
    return dict(means=means, quats=quats, scales=scales, opacities=opacities, colors=sh, viewmats=viewmats, Ks=Ks,
                width=cam.width, height=cam.height, sh_degree=sh_degree)  # fmt: skip


def machine_info(torch, gsplat):
    props = torch.cuda.get_device_properties(0)
    return dict(gpu=torch.cuda.get_device_name(0), sm_count=props.multi_processor_count,
                memory_gb=round(props.total_memory / 2**30, 1), torch=torch.__version__, cuda=torch.version.cuda,
                gsplat=getattr(gsplat, "__version__", "?"))  # fmt: skip


def bench_point(ctx, n, size, packed, iters, eps2d):
    torch, br, rasterization = ctx["torch"], ctx["br"], ctx["rasterization"]
    W, H = parse_size(size)
    cam = br.make_camera(W, H)
    params = br.make_scene(n)
    torch.cuda.synchronize()
    torch.cuda.reset_peak_memory_stats()
    leaves = [p.clone().requires_grad_(True) for p in params]
    common = dict(near_plane=ctx["near"], eps2d=eps2d, packed=packed, render_mode="RGB+ED")
    fixed = gsplat_inputs(params, cam, torch)
    trainable = gsplat_inputs(leaves, cam, torch)

    def fwd():
        with torch.no_grad():
            rasterization(**fixed, **common)

    colors, alphas, meta = rasterization(**fixed, **common)
    g = torch.Generator(device="cuda").manual_seed(1)
    w_colors = torch.randn(colors.shape, generator=g, device="cuda")  # RGB + expected depth
    w_alphas = torch.randn(alphas.shape, generator=g, device="cuda")
    entries = int(meta["isect_ids"].numel())
    mean_alpha = float(alphas.mean())
    del colors, alphas, meta

    def fwd_bwd():
        c, a, _ = rasterization(**trainable, **common)
        ((c * w_colors).sum() + (a * w_alphas).sum()).backward()

    res = dict(image=size, N=n, packed=packed, renderer="gsplat", render_mode="RGB+ED", eps2d=eps2d,
               near_plane=ctx["near"], **ctx["machine"])  # fmt: skip
    res["fwd_ms"], res["fwd_ms_min"] = br._time(fwd, iters)
    res["fwd_bwd_ms"], res["fwd_bwd_ms_min"] = br._time(fwd_bwd, iters)
    torch.cuda.synchronize()
    res["peak_torch_mb"] = torch.cuda.max_memory_allocated() / 2**20
    res["params_mb"] = sum(p.numel() * 4 for p in params) / 2**20
    res["tile_entries"] = entries
    res["entries_per_tile"] = entries / (math.ceil(W / 16) * math.ceil(H / 16))
    res["mean_alpha"] = mean_alpha
    return res  # the scene and buffers go with this frame; the caller frees the cached memory


def _psnr(a, b):
    mse = float(((a - b) ** 2).mean())
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def check(ctx, n, size, out_dir):
    """Both renderers on one scene: PSNR of the RGB images (clamped to [0, 1]), alpha and depth gaps.

    They are expected to be close, not equal: 2D EWA footprints (+eps2d) vs 3D ray–Gaussian intersections,
    centre depth vs intersection depth, alpha_max 0.999 vs 0.99. Reported, never asserted.
    """
    torch, br, rasterization = ctx["torch"], ctx["br"], ctx["rasterization"]
    W, H = parse_size(size)
    cam = br.make_camera(W, H)
    params = br.make_scene(n)
    ours = ctx["rasterize"](*params, cam)
    ours_rgb = ours["rgb"].clamp(0, 1)
    report = dict(image=size, N=n, ours_mean_alpha=float(ours["alpha"].mean()), **ctx["machine"])
    images = {"ours": ours_rgb}
    for eps2d in (0.3, 0.0):
        with torch.no_grad():
            c, a, _ = rasterization(**gsplat_inputs(params, cam, torch), near_plane=ctx["near"], eps2d=eps2d,
                                    packed=False, render_mode="RGB+ED")  # fmt: skip
        rgb, ed, alpha = c[0, ..., :3].clamp(0, 1), c[0, ..., 3], a[0, ..., 0]
        both = (alpha > 0.5) & (ours["alpha"] > 0.5)
        rel_depth = ((ed - ours["depth"]).abs() / ours["depth"].clamp(min=1e-6))[both]
        report[f"eps2d={eps2d}"] = dict(
            psnr_rgb_db=_psnr(rgb, ours_rgb),
            rgb_mean_abs=float((rgb - ours_rgb).abs().mean()),
            alpha_mean_abs=float((alpha - ours["alpha"]).abs().mean()),
            gsplat_mean_alpha=float(alpha.mean()),
            depth_rel_mean_abs_where_both_alpha_gt_0p5=float(rel_depth.mean()) if rel_depth.numel() else None,
            pixels_both_alpha_gt_0p5=int(both.sum()),
        )
        images[f"gsplat_eps{eps2d}"] = rgb
    try:  # a side-by-side picture: ours | gsplat (eps2d 0.3) | gsplat (eps2d 0) | 4x |ours - gsplat(0.3)|
        from PIL import Image

        diff = (4 * (images["ours"] - images["gsplat_eps0.3"]).abs()).clamp(0, 1)
        row = torch.cat([images["ours"], images["gsplat_eps0.3"], images["gsplat_eps0.0"], diff], dim=1)
        path = out_dir / "gsplat_check.png"
        Image.fromarray((row.cpu().numpy() * 255 + 0.5).astype(np.uint8)).save(path)
        report["picture"] = str(path)
    except ImportError:
        pass
    return report


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Runs on a CUDA machine with gsplat installed (benchmarks/render/gsplat_setup.sh).")  # fmt: skip
    ap.add_argument("--sizes", nargs="+", default=list(DEFAULT_SIZES), help="WxH images (space- or comma-separated)")
    ap.add_argument("--counts", nargs="+", default=[str(c) for c in DEFAULT_COUNTS],
                    help="Gaussian counts, e.g. 100k 500k 1M 3M or 100000,500000")  # fmt: skip
    ap.add_argument("--packed", choices=("both", "false", "true"), default="both",
                    help="gsplat's packed mode: both = one row each, unpacked first (default)")  # fmt: skip
    ap.add_argument("--eps2d", type=float, default=0.3, help="gsplat's 2D low-pass (its default 0.3)")
    ap.add_argument("--iters", type=int, default=7)
    ap.add_argument("--check", action="store_true", help="render one small scene with both renderers, report PSNR")
    ap.add_argument("--check-n", type=parse_count, default=100_000)
    ap.add_argument("--check-size", default="800x600")
    ap.add_argument("--no-sweep", action="store_true", help="with --check: only the check")
    ap.add_argument("--out", default=str(HERE / "results"), help="folder for gsplat_sweep.json / gsplat_check.json")
    args = ap.parse_args()

    br, RenderConfig, rasterize = _import_ours()
    torch = _require_cuda()
    gsplat, rasterization = _import_gsplat()
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    ctx = dict(torch=torch, br=br, rasterization=rasterization, rasterize=rasterize, near=RenderConfig().near,
               machine=machine_info(torch, gsplat))  # fmt: skip
    print(json.dumps(ctx["machine"]), flush=True)

    # gsplat builds its CUDA extension (JIT) on the first call: do it here, outside every timing
    t0 = time.time()
    tiny = br.make_scene(1000)
    rasterization(**gsplat_inputs(tiny, br.make_camera(64, 48), torch), near_plane=ctx["near"], render_mode="RGB+ED")
    torch.cuda.synchronize()
    print(f"gsplat extension ready in {time.time() - t0:.1f} s", flush=True)
    del tiny

    if args.check:
        br.wp.init()
        rep = check(ctx, args.check_n, args.check_size, out_dir)
        print(json.dumps(rep, indent=1), flush=True)
        (out_dir / "gsplat_check.json").write_text(json.dumps(rep, indent=1))
        if args.no_sweep:
            return

    packs = {"both": (False, True), "false": (False,), "true": (True,)}[args.packed]
    results = []
    for size in _split(args.sizes):
        for n in [parse_count(c) for c in _split(args.counts)]:
            for packed in packs:
                t0 = time.time()
                try:
                    res = bench_point(ctx, n, size, packed, args.iters, args.eps2d)
                except torch.cuda.OutOfMemoryError as e:
                    res = dict(image=size, N=n, packed=packed, renderer="gsplat", error=f"out of memory: {e}"[:300])
                gc.collect()
                torch.cuda.empty_cache()
                results.append(res)
                if "error" in res:
                    print(f"{size} n={n} packed={packed}: {res['error']}", flush=True)
                else:
                    print(f"{size} n={n} packed={packed}: fwd {res['fwd_ms']:.2f} ms, fwd+bwd {res['fwd_bwd_ms']:.2f} ms, "
                          f"peak torch {res['peak_torch_mb']:.0f} MB, entries/tile {res['entries_per_tile']:.0f}, "
                          f"mean alpha {res['mean_alpha']:.2f} ({time.time() - t0:.0f} s)", flush=True)  # fmt: skip
                (out_dir / "gsplat_sweep.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
