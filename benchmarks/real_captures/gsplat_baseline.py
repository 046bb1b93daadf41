"""Reference run: plain 3DGS (gsplat 1.5.3, ``DefaultStrategy``) on OUR split, images and SfM points.

    # on the GPU machine (gsplat_setup.sh installs gsplat 1.5.3 and its CUDA extension):
    source .device/warp-3/install.sh && source benchmarks/device_setup.sh && source benchmarks/render/gsplat_setup.sh
    python3 benchmarks/real_captures/gsplat_baseline.py .data2/colmap_can --out $OUT/gsplat_can
    # anywhere, no gsplat, no GPU: load, split, initial Gaussians, scene scale, first camera
    python3 benchmarks/real_captures/gsplat_baseline.py .data2/colmap_can --out /tmp/gsb --dry-run

What it measures: the test (and train) PSNR/SSIM that a standard 3DGS reaches on exactly the views our trainer
sees: the scene comes from ``gof_warp.data.load_scene`` (undistorted pinhole cameras, every 8th view is a test
view), the Gaussians start from the scene's SfM points, and the metrics are ``gof_warp.metrics.psnr/ssim`` on
renders clamped to [0, 1] (what our trainer reports). Training follows gsplat's ``examples/simple_trainer.py``
default config: init from the points (sh0 from their colours, shN 0, scales = log mean distance to the 3 nearest
neighbours, random quats, opacity 0.1), one Adam per parameter (eps 1e-15; lrs below, means x scene scale with an
exponential decay to 0.01x), SH degree +1 every 1000 steps up to 3, loss 0.8 L1 + 0.2 (1 - SSIM) (11x11
Gaussian window, sigma 1.5, zero padding: 3DGS's; gsplat uses fused_ssim's 'valid' variant), one training view
per step (a new random order every epoch), black background, ``packed=False``, classic rasterisation,
``DefaultStrategy()`` with its defaults. Differences from simple_trainer: no world normalisation (a similarity:
lrs and thresholds scale with the scene scale; only ``near_plane=0.01`` is then in our units) and the scene scale
is 3DGS's ``cameras_extent`` over the TRAIN cameras (gsplat's parser uses all cameras; both are printed).

Opacity reset: gsplat 1.5.3's ``DefaultStrategy.step_post_backward`` tests ``step % reset_every == 0 & step > 0``,
which Python reads as a chained comparison that is always False (``0 & step`` is 0): the library never resets
opacities (open fix: nerfstudio-project/gsplat PR #776). ``--opacity-reset 3dgs`` (default) does the reset the
strategy intends (gsplat's ``reset_opa`` to 2 x prune_opa = 0.01 at every ``reset_every`` steps below
``refine_stop_iter``, as 3DGS); ``--opacity-reset gsplat`` leaves the library as shipped.

Outputs in --out: ``metrics.json`` (rewritten atomically after every evaluation) and ``views.png`` (three test
views, each a row photo | render). ``--eval-at`` steps count completed iterations; the last one is always added.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

SH_C0 = 0.28209479177387814
LRS = {"means": 1.6e-4, "scales": 5e-3, "quats": 1e-3, "opacities": 5e-2, "sh0": 2.5e-3, "shN": 2.5e-3 / 20}
INIT_OPACITY, SH_DEGREE, SH_INTERVAL, SSIM_LAMBDA = 0.1, 3, 1000, 0.2
NEAR_PLANE, FAR_PLANE = 0.01, 1e10


def _fail(msg: str) -> None:
    print(f"gsplat_baseline: {msg}", file=sys.stderr)
    raise SystemExit(2)


def initial_params(points, colors, seed: int) -> dict:
    """gsplat's SfM initialisation, raw (pre-activation) float32 arrays keyed as its ``params``."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 4:
        _fail(f"the scene has {len(pts)} initial points; need at least 4 (3 neighbours each)")
    d, _ = cKDTree(pts).query(pts, k=4)  # itself + its 3 nearest neighbours
    dist2 = np.maximum((d[:, 1:] ** 2).mean(axis=1), 1e-7)  # 3DGS's floor: a duplicate point would give log(0)
    n = len(pts)
    rgb = np.asarray(colors, dtype=np.float32) / 255.0
    sh = np.zeros((n, (SH_DEGREE + 1) ** 2, 3), np.float32)
    sh[:, 0] = (rgb - 0.5) / SH_C0
    return {"means": pts.astype(np.float32),
            "scales": np.repeat(0.5 * np.log(dist2)[:, None], 3, axis=1).astype(np.float32),
            "quats": np.random.default_rng(seed).random((n, 4), dtype=np.float32),  # as gsplat: U[0,1), unnormalised
            "opacities": np.full(n, math.log(INIT_OPACITY / (1 - INIT_OPACITY)), np.float32),
            "sh0": sh[:, :1].copy(), "shN": sh[:, 1:].copy()}  # fmt: skip


def import_gsplat(device: str) -> SimpleNamespace:
    import torch

    if device.startswith("cuda") and not torch.cuda.is_available():
        _fail(f"CUDA unavailable: torch {torch.__version__} (CUDA {torch.version.cuda}) sees no GPU; run on the GPU machine")
    try:
        import gsplat
        from gsplat import rasterization
        from gsplat.strategy import DefaultStrategy
        from gsplat.strategy.ops import reset_opa
    except ImportError as e:
        _fail(f"cannot import gsplat ({e}); on the GPU machine `source benchmarks/render/gsplat_setup.sh` installs 1.5.3")
    if gsplat.__version__ != "1.5.3":
        print(f"gsplat_baseline: note: gsplat {gsplat.__version__}, written against 1.5.3", flush=True)
    return SimpleNamespace(version=gsplat.__version__, rasterization=rasterization, DefaultStrategy=DefaultStrategy,
                           reset_opa=reset_opa)  # fmt: skip


def builtin_reset_works(strategy_cls) -> bool:
    """False for gsplat versions whose DefaultStrategy never resets opacities (see the module docstring)."""
    try:
        return "== 0 & step > 0" not in inspect.getsource(strategy_cls.step_post_backward)
    except (OSError, TypeError):
        return True


def save_views(path: Path, rows) -> None:
    """``rows``: [(photo, render)] uint8 [H, W, 3] pairs -> one PNG, a row per view (long side <= 960 px each)."""
    from PIL import Image

    tiles = []
    for photo, render in rows:
        h, w = photo.shape[:2]
        s = min(1.0, 960 / max(h, w))
        size = (max(1, round(w * s)), max(1, round(h * s)))
        tiles.append([Image.fromarray(a).resize(size, Image.BICUBIC) for a in (photo, render)])
    W, H = tiles[0][0].size
    canvas = Image.new("RGB", (2 * W, H * len(tiles)))
    for r, pair in enumerate(tiles):
        for c, im in enumerate(pair):
            canvas.paste(im, (c * W, r * H))
    tmp = path.with_name(f".{path.name}.tmp.png")
    canvas.save(tmp)
    os.replace(tmp, path)


def train(scene, args, gs, report: dict, out: Path) -> None:
    import torch

    from gof_warp.io_utils import write_json_atomic
    from gof_warp.metrics import psnr, ssim

    dev = torch.device(args.device)
    cuda = dev.type == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    torch.manual_seed(args.seed)
    scale = report["scene_scale"]
    params = torch.nn.ParameterDict({k: torch.nn.Parameter(torch.from_numpy(v).to(dev))
                                     for k, v in initial_params(scene.points, scene.point_colors, args.seed).items()})  # fmt: skip
    optimizers = {k: torch.optim.Adam([{"params": params[k], "lr": LRS[k] * (scale if k == "means" else 1.0), "name": k}],
                                      eps=1e-15, fused=cuda) for k in params}  # fmt: skip
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimizers["means"], gamma=0.01 ** (1.0 / args.iterations))
    strategy = gs.DefaultStrategy(verbose=False)
    strategy.check_sanity(params, optimizers)
    state = strategy.initialize_state(scene_scale=scale)
    builtin = builtin_reset_works(gs.DefaultStrategy)
    our_reset = args.opacity_reset == "3dgs" and not builtin
    resets: list[int] = []
    report["settings"].update(strategy=dataclasses.asdict(strategy), gsplat_builtin_opacity_reset_works=builtin,
                              opacity_resets_by_this_script=our_reset, opacity_resets_at=resets)  # fmt: skip

    def cams(views):
        return [(torch.tensor(v.camera.w2c, dtype=torch.float32, device=dev)[None],
                 torch.tensor(v.camera.K, dtype=torch.float32, device=dev)[None], v.camera.width, v.camera.height)
                for v in views]  # fmt: skip

    def render(cam, sh_degree):
        viewmat, K, W, H = cam
        img, _, info = gs.rasterization(
            means=params["means"], quats=params["quats"], scales=torch.exp(params["scales"]),
            opacities=torch.sigmoid(params["opacities"]), colors=torch.cat([params["sh0"], params["shN"]], 1),
            viewmats=viewmat, Ks=K, width=W, height=H, near_plane=NEAR_PLANE, far_plane=FAR_PLANE,
            sh_degree=sh_degree, packed=False, absgrad=strategy.absgrad, rasterize_mode="classic")  # fmt: skip
        return img[0], info  # [H, W, 3], black background

    train_cams, test_cams = cams(scene.train), cams(scene.test)
    train_gt = [torch.from_numpy(v.image).to(dev) for v in scene.train]  # uint8 on the device (~190 MB here)
    shown = sorted({round(x) for x in np.linspace(0, len(scene.test) - 1, 3)}) if scene.test else []

    @torch.no_grad()
    def evaluate(views, cams_, keep=()):
        rows, kept = [], []
        for j, (v, cam) in enumerate(zip(views, cams_)):
            pred = render(cam, SH_DEGREE)[0].clamp(0, 1)
            gt = torch.from_numpy(v.image).to(dev).float() / 255.0
            p, g = pred.permute(2, 0, 1), gt.permute(2, 0, 1)
            rows.append({"name": v.name, "psnr": psnr(p, g).item(), "ssim": ssim(p, g).item()})
            if j in keep:
                kept.append((v.image, (pred * 255 + 0.5).to(torch.uint8).cpu().numpy()))
        mean = {k: (math.fsum(r[k] for r in rows) / len(rows) if rows else None) for k in ("psnr", "ssim")}
        return {**mean, "num_images": len(rows), "per_image": rows}, kept

    # warm-up render (gsplat JIT-builds its extension on the first CUDA call when no prebuilt one is installed)
    t = time.perf_counter()
    try:
        with torch.no_grad():
            render(train_cams[0], 0)
        sync()
    except Exception as e:  # noqa: BLE001 -- any failure here means gsplat's kernels are unusable
        _fail(f"gsplat's rasterization failed on the first render ({type(e).__name__}: {str(e).splitlines()[0][:200]})")
    print(f"gsplat ready in {time.perf_counter() - t:.1f} s; {len(params['means'])} initial Gaussians", flush=True)

    eval_steps = sorted({s for s in args.eval_at if 0 < s <= args.iterations} | {args.iterations})
    rng = np.random.default_rng(args.seed)
    order: list[int] = []
    train_time, t0 = 0.0, time.perf_counter()
    for step in range(args.iterations):  # gsplat's 0-based step
        if not order:
            order = list(rng.permutation(len(train_cams)))
        i = order.pop()
        img, info = render(train_cams[i], min(step // SH_INTERVAL, SH_DEGREE))
        strategy.step_pre_backward(params, optimizers, state, step, info)
        gt = train_gt[i].float() / 255.0
        l1 = (img - gt).abs().mean()
        loss = (1 - SSIM_LAMBDA) * l1 + SSIM_LAMBDA * (1 - ssim(img.permute(2, 0, 1), gt.permute(2, 0, 1)))
        loss.backward()
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        scheduler.step()
        strategy.step_post_backward(params, optimizers, state, step, info, packed=False)
        if our_reset and 0 < step < strategy.refine_stop_iter and step % strategy.reset_every == 0:
            gs.reset_opa(params=params, optimizers=optimizers, state=state, value=strategy.prune_opa * 2.0)
            resets.append(step)
        done = step + 1
        if done % 1000 == 0 or done == args.iterations:
            n, lv = len(params["means"]), loss.item()
            report["curve"].append({"step": done, "loss": lv, "num_gaussians": n})
            print(f"step {done}: loss {lv:.4f}, {n} Gaussians, {train_time + time.perf_counter() - t0:.0f} s", flush=True)
            if not math.isfinite(lv):
                _fail(f"loss is {lv} at step {done}")
        if done in eval_steps:
            sync()
            train_time += time.perf_counter() - t0
            test, kept = evaluate(scene.test, test_cams, keep=shown)
            tr, _ = evaluate(scene.train, train_cams)
            report["evals"][str(done)] = {"num_gaussians": len(params["means"]), "train_time_s": train_time,
                                          "test": test, "train": {k: tr[k] for k in ("psnr", "ssim", "num_images")},
                                          "train_per_image_psnr": [r["psnr"] for r in tr["per_image"]]}  # fmt: skip
            report.update(iterations_done=done, complete=done == args.iterations, train_time_s=train_time,
                          num_gaussians=len(params["means"]), test_psnr=test["psnr"], test_ssim=test["ssim"],
                          train_psnr=tr["psnr"], train_ssim=tr["ssim"],
                          test_per_image_psnr={r["name"]: r["psnr"] for r in test["per_image"]})  # fmt: skip
            if cuda:
                report["peak_memory_gb"] = torch.cuda.max_memory_allocated(dev) / 2**30
            write_json_atomic(out / "metrics.json", report, indent=1)
            if kept:
                save_views(out / "views.png", kept)
            print(f"eval @ {done}: test PSNR {test['psnr']:.2f} dB SSIM {test['ssim']:.4f} | train PSNR "
                  f"{tr['psnr']:.2f} dB SSIM {tr['ssim']:.4f} | {len(params['means'])} Gaussians | train time "
                  f"{train_time:.0f} s", flush=True)  # fmt: skip
            sync()
            t0 = time.perf_counter()


def main(argv=None, gs=None) -> None:
    """``gs``: gsplat's entry points (``import_gsplat``'s namespace); a test may pass stand-ins."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="scene folder (any format load_scene reads), e.g. .data2/colmap_can")
    ap.add_argument("--out", required=True, help="folder for metrics.json and views.png")
    ap.add_argument("--iterations", type=int, default=30_000)
    ap.add_argument("--eval-at", type=int, nargs="+", default=[7_000, 30_000], help="completed-iteration counts")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--downscale", type=float, default=1.0, help="DataConfig.downscale (1 = full resolution)")
    ap.add_argument("--opacity-reset", choices=("3dgs", "gsplat"), default="3dgs",
                    help="3dgs: reset as 3DGS/DefaultStrategy intend; gsplat: as 1.5.3 ships (never)")  # fmt: skip
    ap.add_argument("--dry-run", action="store_true", help="load + initialise + print; no gsplat, no training")
    args = ap.parse_args(argv)
    if args.iterations < 1:
        _fail("--iterations must be >= 1")
    if not args.dry_run and gs is None:
        gs = import_gsplat(args.device)  # before the scene: fail fast

    from gof_warp.camera import camera_extent
    from gof_warp.data import DataConfig, load_scene

    t = time.perf_counter()
    scene = load_scene(args.scene, DataConfig(downscale=args.downscale))
    load_s = time.perf_counter() - t
    if scene.points is None or scene.point_colors is None:
        _fail(f"{args.scene}: the scene has no SfM points (this baseline starts from them, as simple_trainer's sfm init)")
    if not scene.test:
        _fail(f"{args.scene}: the scene has no test views")
    scale = camera_extent(scene.train_cameras)  # 3DGS's cameras_extent
    scale_all = camera_extent([v.camera for v in scene.all_views])
    cam = scene.train[0].camera
    print(f"scene {scene.source}: {len(scene.train)} train / {len(scene.test)} test views "
          f"(test: {[v.name for v in scene.test]}), {cam.width}x{cam.height}, {len(scene.points)} SfM points, "
          f"loaded in {load_s:.1f} s", flush=True)  # fmt: skip
    print(f"scene scale (3DGS cameras_extent over the train cameras, used): {scale:.6f}; scene.extent (loader): "
          f"{scene.extent:.6f}; over all {len(scene.all_views)} cameras (gsplat's parser): {scale_all:.6f}")  # fmt: skip
    print(f"first train view {scene.train[0].name!r}: {cam!r}\n  K =\n{cam.K}\n  w2c =\n{cam.w2c}")
    if args.dry_run:
        init = initial_params(scene.points, scene.point_colors, args.seed)
        std = np.exp(init["scales"][:, 0])
        print(f"initial Gaussians: {len(init['means'])}; std dev (m) min/median/max {std.min():.4g}/{np.median(std):.4g}/"
              f"{std.max():.4g}; shapes " + ", ".join(f"{k} {tuple(v.shape)}" for k, v in init.items()))  # fmt: skip
        print("learning rates: " + ", ".join(f"{k} {lr * (scale if k == 'means' else 1):.3g}" for k, lr in LRS.items()))
        return

    import torch

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    device_name = torch.cuda.get_device_name(torch.device(args.device)) if args.device.startswith("cuda") else args.device
    report = {"method": "3DGS: gsplat rasterization + DefaultStrategy, simple_trainer's default config",
              "scene": str(args.scene), "scene_source": scene.source, "complete": False, "iterations": args.iterations,
              "iterations_done": 0, "train_time_s": None, "num_gaussians": None, "device": device_name,
              "gsplat": gs.version, "torch": torch.__version__, "cuda": torch.version.cuda,
              "scene_scale": scale, "scene_scale_note": "1.1 x max distance of the train camera centres from their mean",
              "scene_extent_loader": scene.extent, "scene_scale_all_cameras": scale_all,
              "split": {"train": len(scene.train), "test": len(scene.test), "test_names": [v.name for v in scene.test]},
              "resolution": [cam.width, cam.height], "initial_points": len(scene.points),
              "settings": {"seed": args.seed, "downscale": args.downscale, "eval_at": args.eval_at,
                           "opacity_reset": args.opacity_reset, "lrs": LRS, "means_lr_scaled": LRS["means"] * scale,
                           "means_lr_final_factor": 0.01, "adam_eps": 1e-15, "init_opacity": INIT_OPACITY,
                           "sh_degree": SH_DEGREE, "sh_degree_interval": SH_INTERVAL, "ssim_lambda": SSIM_LAMBDA,
                           "ssim": "gof_warp.metrics.ssim (11x11 Gaussian, sigma 1.5, zero padding)",
                           "near_plane": NEAR_PLANE, "far_plane": FAR_PLANE, "packed": False,
                           "rasterize_mode": "classic", "background": "black"},
              "curve": [], "evals": {}}  # fmt: skip
    train(scene, args, gs, report, out)
    print(f"wrote {out / 'metrics.json'} and {out / 'views.png'}", flush=True)


if __name__ == "__main__":
    main()
