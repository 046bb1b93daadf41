"""Mesh files as the viewer and the pictures show them: geometry plus whatever appearance the file carries.

:func:`find_mesh` picks a run's newest mesh; :func:`load_mesh_file` reads a PLY, OBJ (with its MTL and texture
image) or GLB through trimesh into a :class:`MeshFile`: the triangles, and the appearance trimesh found —

* per-vertex colours (``ColorVisuals`` of kind ``vertex``: PLY ``red green blue``, OBJ ``v x y z r g b``, glTF
  ``COLOR_0``, also beside a material without an image), or per-face colours (kind ``face``), returned sRGB: PLY and
  OBJ colours are sRGB as they stand, a GLB's are linear as glTF defines them (and as
  :func:`gof_warp.mesh.export.save_mesh_file` writes them) and are converted;
* a texture (``TextureVisuals``): per-vertex ``uv`` and the material's base colour image (glTF
  ``baseColorTexture`` times its ``baseColorFactor``; OBJ ``map_Kd`` times ``Kd``);
* nothing: an uncoloured mesh, drawn shaded.

A GLB or OBJ that ``extract`` wrote upright (its recorded rotation: :func:`gof_warp.core.orientation.world_from_file`) is
read back in the scene's frame, where the run's cameras see it.

:meth:`MeshFile.colour_at` gives the surface colour at ray hits (face index and Warp's barycentrics), so that a
ray caster can draw the mesh with its own colours.

UV convention: trimesh's (``v = 0`` at the image's bottom row; it flips glTF's ``t`` on loading). Texture lookups
are bilinear with texel centres at ``((i + 0.5) / W, 1 - (j + 0.5) / H)`` and wrap around (glTF's default
``REPEAT`` sampler).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import GofError
from ..core.orientation import world_from_file
from ..mesh.export import linear_to_srgb

MESH_SUFFIXES = (".ply", ".glb", ".obj")  # what ``extract --format`` writes


def run_meshes(run_dir) -> list[Path]:
    """The mesh files ``extract`` writes into a run folder: ``RUN/mesh_*.ply|glb|obj``, oldest first (by
    modification time; equal times by name)."""
    found = [p for p in Path(run_dir).glob("mesh_*") if p.suffix.lower() in MESH_SUFFIXES and p.is_file()]
    return sorted(found, key=lambda p: (p.stat().st_mtime_ns, p.name))


def find_mesh(run_dir) -> Path | None:
    """The run's newest mesh: of ``RUN/mesh_*.ply``, ``mesh_*.glb`` and ``mesh_*.obj``, the one modified last (equal
    times: the last name in sorted order); None when there is none."""
    meshes = run_meshes(run_dir)
    return meshes[-1] if meshes else None


@dataclass
class MeshFile:
    """A mesh read by :func:`load_mesh_file`.

    ``vertices`` ``[V, 3]`` float64, ``faces`` ``[F, 3]`` int64; at most one appearance: ``vertex_colors``
    ``[V, 3]`` uint8, ``face_colors`` ``[F, 3]`` uint8, or ``uv`` ``[V, 2]`` float64 with ``texture``
    ``[H, W, 3]`` uint8 (already multiplied by the material's base colour factor). ``mesh`` is the
    ``trimesh.Trimesh`` as loaded (what the viewer sends to the browser)."""

    path: Path
    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None
    face_colors: np.ndarray | None = None
    uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    mesh: object = None

    @property
    def appearance(self) -> str:
        """``"vertex"``, ``"face"``, ``"texture"`` or ``"none"``."""
        if self.texture is not None:
            return "texture"
        if self.vertex_colors is not None:
            return "vertex"
        return "face" if self.face_colors is not None else "none"

    @property
    def coloured(self) -> bool:
        """Whether the file carries colours (vertex, face or texture)."""
        return self.appearance != "none"

    def colour_at(self, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Surface colour ``[N, 3]`` float in ``[0, 1]`` at ``N`` hits: ``face [N]`` indices and ``bary [N, 2]``
        Warp's barycentrics ``(u, v)`` (the hit is ``u p0 + v p1 + (1 - u - v) p2``). Vertex colours and uvs are
        interpolated with these weights. Raises :class:`GofError` for an uncoloured mesh."""
        face = np.asarray(face, np.int64)
        b = np.asarray(bary, np.float64).reshape(-1, 2)
        w = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)[:, :, None]  # [N, 3 corners, 1]
        corners = self.faces[face]  # [N, 3]
        kind = self.appearance
        if kind == "vertex":
            return (self.vertex_colors[corners].astype(np.float64) / 255.0 * w).sum(1)
        if kind == "face":
            return self.face_colors[face].astype(np.float64) / 255.0
        if kind == "texture":
            return sample_texture(self.texture, (self.uv[corners] * w).sum(1))
        raise GofError(f"{self.path}: the mesh has no colours")


def sample_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``image`` ``[H, W, 3]`` uint8 at ``uv`` ``[N, 2]`` (trimesh's convention, wrapping; see the
    module docstring) → ``[N, 3]`` float in ``[0, 1]``."""
    img = np.asarray(image, np.float64) / 255.0
    h, w = img.shape[:2]
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    x = uv[:, 0] * w - 0.5
    y = (1.0 - uv[:, 1]) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xa, xb, ya, yb = x0 % w, (x0 + 1) % w, y0 % h, (y0 + 1) % h
    top = img[ya, xa] * (1 - fx) + img[ya, xb] * fx
    bottom = img[yb, xa] * (1 - fx) + img[yb, xb] * fx
    return top * (1 - fy) + bottom * fy


def _rgb8(colors) -> np.ndarray:
    return np.asarray(colors)[:, :3].astype(np.uint8)


def _texture_of(material) -> np.ndarray | None:
    """The base colour image ``[H, W, 3]`` uint8 of a trimesh material, as glTF shows it: the PBR
    ``baseColorTexture`` times ``baseColorFactor`` (a simple material, e.g. OBJ's, counts as its PBR form: ``map_Kd``
    times ``Kd``, which is also what the viewer's GLB of it carries); None without an image."""
    if material is None:
        return None
    if not hasattr(material, "baseColorTexture") and hasattr(material, "to_pbr"):
        material = material.to_pbr()
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        return None
    rgb = np.asarray(image.convert("RGB"), np.uint8)
    factor = getattr(material, "baseColorFactor", None)
    if factor is not None:
        f = np.asarray(factor).ravel()[:3]
        f = f / 255.0 if f.dtype == np.uint8 else f.astype(np.float64)
        if not np.allclose(f, 1.0):
            rgb = np.round(np.clip(rgb * f, 0, 255)).astype(np.uint8)
    return rgb


def load_mesh_file(path) -> MeshFile:
    """Read a mesh file (PLY, OBJ with its MTL/texture, GLB; anything trimesh reads as triangles) with its colours or
    texture (module docstring). Raises :class:`GofError` naming the file when it is missing, unreadable or holds no
    triangles."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise GofError(f"mesh {path} does not exist")
    attribute_colours = None  # COLOR_0 of a glTF primitive that also has a material (trimesh keeps it aside)
    try:
        m = trimesh.load(path, process=False)
        if isinstance(m, trimesh.Scene):  # GLB/OBJ: one mesh per node or material, placed by the scene's transforms
            nodes = m.graph.nodes_geometry
            if len(nodes) == 1 and isinstance(m.geometry.get(m.graph[nodes[0]][1]), trimesh.Trimesh):
                transform, name = m.graph[nodes[0]]
                visual = m.geometry[name].visual
                attribute_colours = getattr(visual, "vertex_attributes", {}).get("color")  # copies drop it
                m = m.geometry[name].copy()
                m.apply_transform(transform)
            else:
                m = trimesh.util.concatenate([g for g in m.dump() if isinstance(g, trimesh.Trimesh)])
    except Exception as e:  # trimesh raises many types for unreadable files
        raise GofError(f"{path}: cannot read the mesh: {e}") from None
    if not isinstance(m, trimesh.Trimesh):
        raise GofError(f"{path}: not a triangle mesh (trimesh read a {type(m).__name__})")
    v = np.asarray(m.vertices, np.float64).reshape(-1, 3)
    back = world_from_file(path)  # a GLB/OBJ written upright: back to the scene's frame
    if back is not None:
        v = v @ back.T
        m.vertices = v
    f = np.asarray(m.faces, np.int64).reshape(-1, 3)
    if len(f) == 0:
        raise GofError(f"{path}: no triangles in the file")
    out = MeshFile(path=path, vertices=v, faces=f, mesh=m)
    visual = m.visual
    kind = getattr(visual, "kind", None)
    if kind == "texture":
        uv = getattr(visual, "uv", None)
        texture = _texture_of(getattr(visual, "material", None))
        colours = attribute_colours
        if uv is not None and texture is not None and len(uv) == len(v):
            out.uv, out.texture = np.asarray(uv, np.float64).reshape(-1, 2), texture
        elif colours is not None and len(colours) == len(v):  # a material without an image, and COLOR_0
            out.vertex_colors = _rgb8(colours)
    elif kind == "vertex":
        out.vertex_colors = _rgb8(visual.vertex_colors)
    elif kind == "face":
        out.face_colors = _rgb8(visual.face_colors)
    if path.suffix.lower() in (".glb", ".gltf"):  # glTF colours are linear
        for attr in ("vertex_colors", "face_colors"):
            c = getattr(out, attr)
            if c is not None:
                setattr(out, attr, np.round(linear_to_srgb(c / 255.0) * 255.0).astype(np.uint8))
    return out
