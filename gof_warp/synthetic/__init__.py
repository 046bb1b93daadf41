"""Synthetic scenes with exact ground truth, rendered by Warp mesh ray casting.

``make_scene("default", "out/default")`` writes a Blender/NeRF-synthetic scene folder (see
:mod:`gof_warp.synthetic.writer` for the layout): RGBA images, exact per-view depth and normal maps and
the ground-truth mesh. CLI: ``python -m gof_warp.synthetic --preset NAME --out DIR``.

The folder appears complete or not at all: everything is written into a hidden temporary folder
beside ``out`` which is renamed onto ``out`` at the end. Output bytes are a function of
(preset, views, resolution, seed, device).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.errors import GofError
from ..core.io_utils import ensure_writable_dir, write_bytes_atomic, write_json_atomic
from . import writer
from .meshes import Material, SyntheticMesh
from .presets import DEFAULT_RESOLUTION, GPU_RESOLUTION, CameraRig, Preset, get_preset, list_presets, with_rig
from .render import Lighting, RayCaster, RenderedView, default_device

GENERATOR_VERSION = 2  # 2: scene.json has units, ground, per-part bbox
log = logging.getLogger(__name__)


def _check_args(views, resolution, seed, supersample):
    if views is not None and (int(views) != views or views < 1):
        raise GofError(f"--views must be a positive integer, got {views}")
    if resolution is not None:
        if len(resolution) != 2 or any(int(r) != r or r < 1 or r > 16384 for r in resolution):
            raise GofError(f"--resolution must be two positive integers W H (at most 16384), got {resolution}")
    if int(seed) != seed or seed < 0:
        raise GofError(f"--seed must be a non-negative integer, got {seed}")
    if supersample is not None and (int(supersample) != supersample or not 1 <= supersample <= 8):
        raise GofError(f"supersample must be an integer in 1..8, got {supersample}")


GENERATOR = "gof_warp.synthetic"  # scene.json's "generator": the mark of a folder make_scene wrote


def is_generated_scene(folder) -> bool:
    """Whether ``folder`` is a scene :func:`make_scene` wrote: its ``scene.json`` names :data:`GENERATOR`."""
    import json

    try:
        meta = json.loads((Path(folder) / "scene.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("generator") == GENERATOR


def _check_out(out: Path, force: bool) -> None:
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise GofError(f"output {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise GofError(f"output folder {out} is not empty (pass --force to replace it)")
        if not is_generated_scene(out):  # force replaces only what make_scene made: never a folder of someone's
            raise GofError(f"output folder {out} is not a synthetic scene gof_warp generated (its scene.json does not "
                           f"name {GENERATOR}): refusing to replace it; empty it or choose another folder")


def _publish(tmp: Path, out: Path) -> None:
    """Rename the finished ``tmp`` folder onto ``out``; an existing ``out`` is moved aside, then deleted."""
    old = None
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
        os.replace(out, old / out.name)
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _bbox(parts: list[SyntheticMesh]) -> list[list[float]]:
    v = np.concatenate([p.vertices.astype(np.float32) for p in parts])
    return [[float(x) for x in v.min(0)], [float(x) for x in v.max(0)]]


def _ground(parts: list[SyntheticMesh]) -> dict | None:
    """The ground plane for scoring: the part named ``ground`` when it is flat and horizontal (z up)."""
    g = next((q for q in parts if q.name == "ground"), None)
    if g is None:
        return None
    v = g.vertices.astype(np.float32)
    if np.ptp(v[:, 2]) > 1e-6 * max(1.0, float(np.ptp(v[:, :2]))):
        return None
    return {"part": g.name, "height": float(v[0, 2]), "normal": [0.0, 0.0, 1.0],
            "extent": [[float(v[:, 0].min()), float(v[:, 1].min())], [float(v[:, 0].max()), float(v[:, 1].max())]]}


def _write_split(folder: Path, split: str, cameras, caster: RayCaster, supersample: int, depth_range: list):
    frames = []
    for cam in cameras:
        view = caster.render(cam, supersample)
        frames.append(writer.write_view(folder, split, cam, view))
        if view.mask.any():
            d = view.depth[view.mask]
            depth_range[0], depth_range[1] = min(depth_range[0], float(d.min())), max(depth_range[1], float(d.max()))
    write_json_atomic(folder / f"transforms_{split}.json", {**writer.intrinsics_json(cameras[0]), "frames": frames})


def make_scene(preset: str | Preset, out, views: int | None = None,
               resolution: tuple[int, int] | None = None, seed: int = 0, device=None, *, force: bool = False,
               mesh_path=None, supersample: int | None = None) -> Path:
    """Render a synthetic scene into the folder ``out`` and return its path.

    Args:
        preset: a name from :func:`list_presets` or a :class:`Preset`.
        out: output folder; must not exist or be empty, unless ``force`` (then it is replaced, but only when it
            is a scene this function wrote: :func:`is_generated_scene`).
        views: number of training views (default: the preset's); test views are the preset's.
        resolution: ``(width, height)`` (default: the preset's CPU-sized resolution; benchmarks use
            ``GPU_RESOLUTION``).
        seed: rotates the camera rig and selects the procedural noise; same seed, same bytes.
        device: Warp device (default: cuda if available, else cpu).
        mesh_path: OBJ (or a folder with one) for the ``spot`` preset (default ``../shared/data/spot``).
        supersample: samples per pixel axis for colour and alpha (default: the preset's).
    """
    p = preset if isinstance(preset, Preset) else get_preset(str(preset))
    if out is None or str(out) == "":
        raise GofError("make_scene needs an output folder")
    _check_args(views, resolution, seed, supersample)
    w, h = (int(r) for r in (resolution or p.resolution))
    ss = int(supersample or p.supersample)
    out = Path(out)
    _check_out(out, force)
    t0 = time.perf_counter()
    parts = p.build(mesh_path)
    train, test = p.rig.cameras(w, h, views, seed)
    caster = RayCaster(parts, p.lighting, seed=seed, device=device)
    ensure_writable_dir(out.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        depth_range = [np.inf, 0.0]
        _write_split(tmp, "train", train, caster, ss, depth_range)
        _write_split(tmp, "test", test, caster, ss, depth_range)
        objects = [q for q in parts if q.role == "object"]
        write_bytes_atomic(tmp / "gt_mesh.ply", writer.ply_bytes(caster.points, caster.faces))
        if len(objects) < len(parts):
            obj_faces = caster.faces[np.isin(caster.face_part, [i for i, q in enumerate(parts) if q.role == "object"])]
            write_bytes_atomic(tmp / "gt_object.ply", writer.ply_bytes(caster.points, obj_faces))
        write_json_atomic(tmp / "scene.json", {
            "generator": GENERATOR,
            "generator_version": GENERATOR_VERSION,
            "preset": p.name,
            "intent": p.intent,
            "seed": int(seed),
            "resolution": [w, h],
            "supersample": ss,
            "views": {"train": len(train), "test": len(test)},
            "up": [0.0, 0.0, 1.0],
            "object_bbox": _bbox(objects or parts),
            "scene_bbox": _bbox(parts),
            "depth_range": [float(depth_range[0]) if np.isfinite(depth_range[0]) else 0.0, depth_range[1]],
            "gt_mesh": "gt_mesh.ply",
            "gt_object": "gt_object.ply" if len(objects) < len(parts) else "gt_mesh.ply",
            "background": "geometry" if len(objects) < len(parts) else "transparent",
            "units": p.units,
            "ground": _ground(parts),
            "parts": [{"name": q.name, "role": q.role, "material": q.material.kind, "faces": int(len(q.faces)),
                       "bbox": _bbox([q])} for q in parts],
        })
        _publish(tmp, out)
    except BaseException:
        with contextlib.suppress(OSError):
            shutil.rmtree(tmp)
        raise
    log.info("synthetic scene %r: %d+%d views at %dx%d on %s in %.1f s -> %s", p.name, len(train), len(test), w, h,
             caster.device, time.perf_counter() - t0, out)
    return out


__all__ = ["CameraRig", "DEFAULT_RESOLUTION", "GENERATOR", "GENERATOR_VERSION", "GPU_RESOLUTION", "Lighting",
           "Material", "Preset", "RayCaster", "RenderedView", "SyntheticMesh", "default_device", "get_preset",
           "is_generated_scene", "list_presets", "make_scene", "with_rig"]
