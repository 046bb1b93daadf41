"""``python -m gof_warp.extract RUN [--scene SCENE] [--out MESH.ply] [--method tetra|cubes|tsdf] ...``

Mesh extraction from trained Gaussians (GOF Sec. 3.4, appendix Algorithms 1–3):

* ``tetra`` (GOF): points from each Gaussian's centre and 3σ-box corners → Delaunay tetrahedra (cell
  filter) → opacity field at the points → marching tetrahedra with binary search on crossing edges.
* ``cubes``: the same opacity field on a dense grid → marching cubes (+ the same binary search).
* ``tsdf``: fusion of rendered median depths (the 2DGS/3DGS baseline) → marching cubes.

``RUN`` is a training output folder (``point_cloud.ply`` + ``cameras.json``) or any Gaussian PLY in the
3DGS layout together with ``--scene`` for the cameras. Writes the mesh (PLY) and ``<mesh>.json`` with
vertex/face counts and per-stage time and peak memory. An empty mesh is an error (exit 2) and writes nothing;
Gaussians whose scales overflow (see :func:`meshable`) are left out with a warning.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import resource
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .camera import Camera
from .cli import configure_output, run_command
from .errors import GofError, ModelError
from .io_utils import atomic_path, write_json_atomic
from .marching import compact_mesh
from .opacity_field import OpacityFieldConfig, opacity_field
from .render import RenderConfig
from .run_folder import cameras_from_json, load_run  # noqa: F401 - re-exported: extract.load_run is public
from .tetra import TetraConfig, tetrahedral_grid
from .tsdf import TSDFConfig, extract_tsdf_mesh, fuse_tsdf

log = logging.getLogger("gof_warp.extract")
METHODS = ("tetra", "cubes", "tsdf")


@dataclass
class MeshConfig:
    """Mesh extraction settings (defaults: GOF's — level 0.5, 8 bisection steps)."""

    method: str = "tetra"
    levels: tuple[float, ...] = (0.5,)
    binary_steps: int = 8
    cubes_resolution: int = 256  # grid nodes along the longest side (method "cubes")
    crop: tuple[float, ...] | None = None  # (xmin, ymin, zmin, xmax, ymax, zmax): drop faces outside
    min_component_faces: int = 0  # drop connected components with fewer faces (0 = keep all)
    tetra: TetraConfig = field(default_factory=TetraConfig)
    tsdf: TSDFConfig = field(default_factory=TSDFConfig)
    field: OpacityFieldConfig = field(default_factory=OpacityFieldConfig)

    def validate(self):
        if self.method not in METHODS:
            raise GofError(f"mesh method must be one of {METHODS}, got {self.method!r}")
        if not self.levels or not all(0.0 < float(v) < 1.0 for v in self.levels):
            raise GofError(f"levels must be opacities in (0, 1), got {self.levels}")
        if self.binary_steps < 0:
            raise GofError(f"binary_steps must be >= 0, got {self.binary_steps}")


class StageTimer:
    """Wall time and peak memory (host RSS; on a CUDA ``device`` its torch and Warp-pool peaks) per named stage."""

    def __init__(self, device="cpu"):
        self.stages: dict[str, dict] = {}
        self.device = torch.device(str(device))

    @contextmanager
    def __call__(self, name: str):
        cuda = self.device.type == "cuda"
        if cuda:
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
        t0 = time.perf_counter()
        log.info("%s ...", name)
        yield
        if cuda:
            torch.cuda.synchronize(self.device)
        entry = {"time_s": round(time.perf_counter() - t0, 4),
                 "host_peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)}
        if cuda:
            import warp as wp

            entry["gpu_peak_allocated_mb"] = round(torch.cuda.max_memory_allocated(self.device) / 2**20, 1)
            entry["gpu_warp_pool_high_mb"] = round(  # since start
                wp.get_mempool_used_mem_high(f"cuda:{self.device.index or 0}") / 2**20, 1)
        self.stages[name] = entry
        log.info("%s: %.2f s", name, entry["time_s"])


def _postprocess(verts, faces, config: MeshConfig):
    """Crop and small-component removal; returns compacted ``(verts, faces)``."""
    keep = np.ones(len(faces), bool)
    if config.crop is not None:
        box = np.asarray(config.crop, float)
        inside = np.all((verts >= box[:3]) & (verts <= box[3:]), axis=1)
        keep &= inside[faces].all(axis=1)
    faces = faces[keep]
    if config.min_component_faces > 0 and len(faces):
        import trimesh

        labels = trimesh.graph.connected_component_labels(trimesh.graph.face_adjacency(faces), node_count=len(faces))
        counts = np.bincount(labels)
        faces = faces[counts[labels] >= config.min_component_faces]
    verts, faces, _ = compact_mesh(verts, faces)
    return verts, faces


def meshable(gaussians):
    """The Gaussians that can be bounded and meshed, with a warning naming what was left out.

    A scale whose square overflows float32 (log-scale above ~44, e.g. a diverged model's e^50) turns the
    covariance, the 3D filter's scale and its opacity compensation into inf/NaN. The renderer already skips
    such a Gaussian (NaN opacity), but a grid cannot be sized around it nor a 3σ box triangulated, so it is
    left out here — the mesh is that of the other Gaussians, which is what they render. A model with none
    left raises :class:`~gof_warp.errors.ModelError`.
    """
    with torch.no_grad():
        s = gaussians.raw_scales
        ok = (torch.isfinite(s * s).all(dim=1) & torch.isfinite(gaussians.scales).all(dim=1)
              & torch.isfinite(gaussians.opacities))
        n_bad = int((~ok).sum())
        if n_bad == 0:
            return gaussians
        top = float(gaussians.log_scales.detach()[~ok].max())
    why = f"scales too large to represent (log-scale up to {top:.3g}; scale squared overflows float32)"
    if n_bad == len(gaussians):
        raise ModelError(f"all {n_bad} Gaussians have {why}: the model is degenerate, nothing to mesh")
    log.warning("warning: %d of %d Gaussians have %s: left out of the mesh", n_bad, len(gaussians), why)
    return gaussians.subset(ok)


def empty_mesh_message(gaussians, method: str, levels, config: MeshConfig | None = None) -> str:
    """Why a mesh came out empty, for the one-line error of a CLI that refuses to write it."""
    with torch.no_grad():
        s = gaussians.raw_scales.max(dim=1).values
        o = gaussians.opacities
        stats = (f"{len(gaussians)} Gaussians, largest scale {float(s.max()):.3g}, median {float(s.median()):.3g}, "
                 f"opacity up to {float(o.max()):.3g}")
    lv = ", ".join(f"{x:g}" for x in levels)
    removed = ""
    if config is not None and (config.crop is not None or config.min_component_faces > 0):
        removed = " or the crop/--min-component-faces removed every face"
    return (f"no surface crosses level {lv} ({method}): the mesh would be empty — the model is empty or degenerate "
            f"({stats}){removed}; nothing was written")


def extract_mesh(gaussians, cameras: list[Camera], config: MeshConfig | None = None, *,
                 render_config: RenderConfig | None = None, views=None, timer: StageTimer | None = None):
    """Extract one mesh per level from trained Gaussians.

    Args:
        gaussians: :class:`~gof_warp.model.Gaussians` (on the device to compute on).
        cameras: the training cameras (the opacity field is the minimum over them).
        views: :class:`~gof_warp.scene.View` list for TSDF masks (optional; cameras alone otherwise).
    Returns:
        list of ``(vertices [V, 3] float32, faces [F, 3] int32)``, one per ``config.levels``.
    """
    from .marching import marching_cubes, marching_tetrahedra
    from .scene import View

    config = config or MeshConfig()
    config.validate()
    render_config = render_config or RenderConfig()
    timer = timer or StageTimer(gaussians.device)
    if len(gaussians) == 0:
        raise GofError("the model has no Gaussians: nothing to extract")
    gaussians = meshable(gaussians)

    def field_fn(points, field_config=config.field):
        return opacity_field(gaussians, cameras, points, config=field_config, render_config=render_config)

    meshes = []
    if config.method == "tetra":
        substages: dict = {}
        with timer("tetra_points+delaunay"):
            points, tets, _, _ = tetrahedral_grid(gaussians.means.detach(), gaussians.rotations.detach(),
                                                  gaussians.scales.detach(), gaussians.opacities.detach(),
                                                  cameras=cameras, config=config.tetra, stats=substages)
        timer.stages["tetra_points+delaunay"]["substages_s"] = substages
        log.info("%d points, %d tetrahedra", len(points), len(tets))
        with timer("opacity_field"):
            values = field_fn(points)
        with timer("marching_tetrahedra"):
            meshes = marching_tetrahedra(torch.as_tensor(points, device=gaussians.device), tets, values, field_fn,
                                         levels=config.levels, binary_steps=config.binary_steps)
        timer.stages["counts"] = {"points": int(len(points)), "tetrahedra": int(len(tets))}
    elif config.method == "cubes":
        from .tsdf import scene_bounds

        box = np.asarray(config.crop, float) if config.crop is not None else scene_bounds(
            gaussians, cameras, near=render_config.near)
        size = box[3:] - box[:3]
        if box.shape != (6,) or not np.all(np.isfinite(box)) or not np.all(size > 0):
            raise GofError(f"marching cubes: the grid box must be 6 finite numbers with max > min, got {box.tolist()}")
        res = tuple(int(max(2, round(config.cubes_resolution * s / size.max()))) for s in size)
        for level in config.levels:
            with timer(f"marching_cubes@{level}"):
                # a dense grid reaches space no camera sees: count it as empty there (GOF's "unseen = 1" is
                # meant for tetra points, which the frustum mask already keeps in view; on a grid it builds
                # walls at the frustum boundaries)
                grid_field = dataclasses.replace(config.field, unseen_value=0.0)
                meshes.append(marching_cubes(lambda p: field_fn(p, grid_field).cpu().numpy(), np.stack([box[:3], box[3:]]), res,
                                             level=level, binary_steps=config.binary_steps))
    else:
        views = views or [View(camera=c, image=np.zeros((c.height, c.width, 3), np.uint8), name=c.name) for c in cameras]
        with timer("tsdf_fusion"):
            volume = fuse_tsdf(gaussians, views, config.tsdf, render_config)
        with timer("tsdf_marching_cubes"):
            v, f, _ = extract_tsdf_mesh(volume, binary_steps=config.binary_steps)
        meshes = [(v, f)]
    return [_postprocess(np.asarray(v, np.float32), np.asarray(f, np.int64), config) for v, f in meshes]


def save_mesh(path, verts: np.ndarray, faces: np.ndarray) -> None:
    """Write a triangle mesh as binary PLY, atomically."""
    import trimesh

    mesh = trimesh.Trimesh(vertices=verts, faces=faces, process=False)
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type="ply")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gof_warp.extract", description=__doc__.split("\n\n")[1])
    ap.add_argument("run", help="training output folder, or a 3DGS-layout Gaussian PLY (with --scene)")
    ap.add_argument("--scene", default=None, help="scene folder for the cameras (and masks for TSDF)")
    ap.add_argument("--out", default=None, help="mesh path (default RUN/mesh_<method>.ply)")
    ap.add_argument("--method", default="tetra", choices=METHODS)
    ap.add_argument("--levels", type=float, nargs="+", default=[0.5])
    ap.add_argument("--binary-steps", type=int, default=8)
    ap.add_argument("--resolution", type=int, default=None, help="grid resolution for cubes/tsdf")
    ap.add_argument("--delaunay", default="scipy", choices=("scipy", "cgal", "auto"))
    ap.add_argument("--delaunay-workers", type=int, default=TetraConfig.delaunay_workers,
                    help="threads for scipy's Delaunay in chunks (0: every CPU; 1: one Qhull call)")
    ap.add_argument("--opacity-min", type=float, default=None, help="drop Gaussians below this opacity first")
    ap.add_argument("--corner-min-extent", type=float, default=None,
                    help="tetra: only the centre point for Gaussians whose 3-sigma extent is below this (world units)")
    ap.add_argument("--min-component-faces", type=int, default=0)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--no-pictures", action="store_true",
                    help="do not write RUN/pictures/mesh_<stem>.png (views of the model and the shaded mesh)")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    configure_output(a.quiet)

    def body():
        from .devices import resolve_device as pick_device

        device = pick_device(a.device)
        run = Path(a.run)
        cfg = MeshConfig(method=a.method, levels=tuple(a.levels), binary_steps=a.binary_steps,
                         min_component_faces=a.min_component_faces,
                         tetra=TetraConfig(backend=a.delaunay, opacity_min=a.opacity_min,
                                           corner_min_extent=a.corner_min_extent,
                                           delaunay_workers=a.delaunay_workers))
        if a.resolution:
            cfg.cubes_resolution = a.resolution
            cfg.tsdf.resolution = a.resolution
        cfg.validate()
        gaussians, cameras, views, render_config = load_run(run, a.scene, device)
        timer = StageTimer(device)
        t0 = time.perf_counter()
        meshes = extract_mesh(gaussians, cameras, cfg, render_config=render_config, views=views, timer=timer)
        total = time.perf_counter() - t0
        levels = cfg.levels if a.method != "tsdf" else (0.0,)
        empty = [level for level, (_, f) in zip(levels, meshes) if len(f) == 0]
        if empty:  # before anything is written: an existing mesh of that name stays as it is
            raise GofError(empty_mesh_message(gaussians, a.method, empty, cfg))
        base = Path(a.out) if a.out else (run if run.is_dir() else run.parent) / f"mesh_{a.method}.ply"
        outputs = []
        for level, (v, f) in zip(levels, meshes):
            path = base if len(meshes) == 1 else base.with_name(f"{base.stem}_{level:g}{base.suffix}")
            save_mesh(path, v, f)
            outputs.append({"path": str(path), "level": level, "vertices": int(len(v)), "faces": int(len(f))})
            print(f"wrote {path}: {len(v)} vertices, {len(f)} faces")
        write_json_atomic(base.with_suffix(".json"), {
            "method": a.method, "binary_steps": a.binary_steps, "num_gaussians": len(gaussians),
            "num_views": len(cameras), "device": device, "total_time_s": round(total, 3),
            "stages": timer.stages, "meshes": outputs})
        if not a.no_pictures:  # a picture per mesh; a failure only warns: the mesh is already written
            from .pictures import pictures_or_warning

            for o in outputs:
                for p in pictures_or_warning(run, mesh_path=o["path"], device=device, scene=a.scene):
                    print(f"wrote {p}")

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
