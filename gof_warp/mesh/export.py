"""Mesh files with optional vertex colours: PLY (binary, ``uchar red green blue`` per vertex), GLB (one binary glTF
file, through trimesh's exporter; colours as the ``COLOR_0`` attribute), OBJ (``v x y z r g b``, the common
vertex-colour extension, colours in ``[0, 1]``) and USD (``.usd``/``.usdc`` binary, ``.usda`` text; the mesh alone
here, the stage with cameras and a collision mesh through :func:`gof_warp.mesh.usd_export.write_usd`). Every file is
written atomically; PLY through :func:`gof_warp.core.ply.write_ply_mesh`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.arrays import check_triangles
from ..core.errors import GofError
from ..core.io_utils import atomic_path, write_bytes_atomic

FORMATS = ("ply", "glb", "obj", "usd")
USD_SUFFIXES = (".usd", ".usda", ".usdc")


def format_of(path, fmt: str | None = None) -> str:
    """The file format: ``fmt`` when given, else the suffix of ``path`` when it is ``.glb`` or ``.obj``, ``usd``
    for ``.usd``, ``.usda`` and ``.usdc``, else ``ply``."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise GofError(f"mesh format must be one of {FORMATS}, got {fmt!r}")
        return fmt
    if Path(path).suffix.lower() in USD_SUFFIXES:
        return "usd"
    suffix = Path(path).suffix.lower().lstrip(".")
    return suffix if suffix in ("glb", "obj") else "ply"


def _uint8(colours, n: int) -> np.ndarray:
    c = np.asarray(colours)
    if c.shape != (n, 3):
        raise GofError(f"vertex colours must be [{n}, 3], got {list(c.shape)}")
    if c.dtype == np.uint8:
        return c
    return np.round(np.clip(c.astype(np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def save_mesh_file(path, vertices, faces, colours=None, fmt: str | None = None) -> str:
    """Write ``vertices [V, 3]``, ``faces [F, 3]`` and optional ``colours [V, 3]`` (uint8, or float in ``[0, 1]``)
    to ``path`` in ``fmt`` (:func:`format_of`). Returns the format written."""
    fmt = format_of(path, fmt)
    v, f = check_triangles(vertices, np.asarray(faces, np.int64), path, GofError)
    c = None if colours is None else _uint8(colours, len(v))
    if fmt == "ply":
        from ..core.ply import write_ply_mesh

        write_ply_mesh(path, v, f, c)
    elif fmt == "usd":
        from .usd_export import write_usd

        write_usd(path, v, f, colours=c)
    elif fmt == "obj":
        _write_obj(path, v, f, c)
    else:
        import trimesh

        mesh = trimesh.Trimesh(vertices=np.asarray(v, np.float64), faces=f, process=False,
                               vertex_colors=None if c is None else np.concatenate(
                                   [c, np.full((len(c), 1), 255, np.uint8)], 1))
        write_bytes_atomic(path, mesh.export(file_type="glb"))
    return fmt


def _write_obj(path, v, f, c) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii") as out:
            out.write("# written by gof_warp\n")
            if c is None:
                np.savetxt(out, np.asarray(v, np.float32), fmt="v %.7g %.7g %.7g")
            else:
                rows = np.concatenate([np.asarray(v, np.float64), c.astype(np.float64) / 255.0], 1)
                np.savetxt(out, rows, fmt="v %.7g %.7g %.7g %.6g %.6g %.6g")
            np.savetxt(out, np.asarray(f, np.int64) + 1, fmt="f %d %d %d")
