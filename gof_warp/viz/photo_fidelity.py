"""How faithful a coloured or textured mesh is to the photos: the mesh rendered in its own colours (vertex colours,
face colours or its texture, no view dependence) by the Warp ray caster from a run's views, scored against the photos
with the Gaussians' render of the same views beside it.

``mesh_photo_fidelity(run, mesh_path, split="test")`` is what ``python -m gof_warp.evaluate --mesh M --photos RUN``
prints: PSNR and SSIM over the whole image (pixels the mesh misses show the run's background) and over the pixels the
mesh covers, the coverage, and the Gaussians' PSNR/SSIM on the same views.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import GofError

SPLITS = ("test", "train")


def mesh_photo_fidelity(run, mesh_path, *, split: str = "test", device: str = "auto") -> dict:
    """Score the mesh file ``mesh_path`` (PLY, OBJ + MTL + texture, GLB) against the photos of run folder ``run``'s
    ``split`` views (``RUN/cameras.json`` at the training resolution, photos from the scene the run names).

    Returns ``{"split", "views", "appearance", "mesh": {psnr, ssim, psnr_masked, ssim_masked, coverage, views},
    "gaussians": {psnr, ssim}}`` (means over the views). :class:`GofError` for a mesh without colours, a run without
    such views or whose photos cannot be found.
    """
    import torch

    from ..core.devices import resolve_device, warp_device
    from ..mesh.colour import _wp_mesh, gaussian_images, render_fidelity, render_surface
    from ..training.run_folder import load_run
    from ..eval.image_metrics import psnr, ssim
    from .mesh_files import load_mesh_file
    from .pictures import run_views

    if split not in SPLITS:
        raise GofError(f"--split must be one of {SPLITS}, got {split!r}")
    run = Path(run)
    if not (run.is_dir() and (run / "cameras.json").is_file()):
        raise GofError(f"--photos {run}: not a training run folder (it needs cameras.json and point_cloud.ply)")
    mesh = load_mesh_file(mesh_path)
    if not mesh.coloured:
        raise GofError(f"--mesh {mesh_path} has no colours to compare with photos: extract it with --color photos, "
                       "--color gaussians or --texture")
    device = resolve_device(device)
    cameras, photos = run_views(run, split, device)
    gaussians, _, _, render_config = load_run(run, None, device)
    background = tuple(float(b) for b in render_config.background)
    wmesh = _wp_mesh(mesh.vertices, mesh.faces, warp_device(device))
    fidelity = render_fidelity(lambda cam: render_surface(mesh.vertices, mesh.faces, mesh.colour_at, cam,
                                                          background=background, mesh=wmesh), cameras, photos)
    renders = np.stack(list(gaussian_images(gaussians, cameras, render_config)))
    x = torch.from_numpy(renders).permute(0, 3, 1, 2)
    y = torch.from_numpy(np.stack(photos).astype(np.float32) / 255.0).permute(0, 3, 1, 2)
    return {"run": str(run), "split": split, "views": len(cameras), "appearance": mesh.appearance,
            "faces": int(len(mesh.faces)), "mesh": fidelity,
            "gaussians": {"psnr": float(psnr(x, y)), "ssim": float(ssim(x, y))}}


def format_photo_report(report: dict) -> str:
    """The human-readable lines of a :func:`mesh_photo_fidelity` result."""
    m, g = report["mesh"], report["gaussians"]
    return "\n".join([
        f"photos: {report['views']} {report['split']} views of {report['run']}; mesh of {report['faces']:,} faces "
        f"in its {report['appearance']} colours",
        f"  mesh       PSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.4f}   covered pixels ({100 * m['coverage']:.1f} %): "
        f"PSNR {m['psnr_masked']:.2f} dB  SSIM {m['ssim_masked']:.4f}",
        f"  Gaussians  PSNR {g['psnr']:.2f} dB  SSIM {g['ssim']:.4f}   (the trained model's render of the same views)"])
