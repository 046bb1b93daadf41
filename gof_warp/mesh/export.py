"""Mesh files with optional vertex colours: PLY (binary, ``uchar red green blue`` per vertex), GLB (one binary glTF
file, through trimesh's exporter; colours as the ``COLOR_0`` attribute, linear as glTF defines it, with an unlit
matte material: :func:`coloured_glb`), OBJ (``v x y z r g b``, the common vertex-colour extension, colours in
``[0, 1]``) and USD (``.usd``/``.usdc`` binary, ``.usda`` text; the mesh alone here, the stage with cameras and a
collision mesh through :func:`gof_warp.mesh.usd_export.write_usd`). Every file is written atomically; PLY through
:func:`gof_warp.core.ply.write_ply_mesh`.

Textured meshes (:class:`gof_warp.mesh.texture.TexturedMesh`, :func:`save_textured_mesh`): GLB with the texture
embedded as the PBR material's ``baseColorTexture`` (unlit, with a metallic 0 / roughness 1 fallback, double-sided:
viewers show the photo colours); OBJ + MTL + PNG side by side (``mesh.obj`` names ``mesh.mtl``, whose ``map_Kd``
names ``mesh.png``; written PNG, MTL, then OBJ, each atomically); USD with a UsdPreviewSurface reading
``<stem>_texture.png`` beside the stage; PLY keeps vertex colours, the texture sampled at each vertex.

Upright assets (``up``, the world's up direction: :func:`gof_warp.core.orientation.scene_up`): GLB and OBJ are +Y up
(glTF's rule, and what OBJ importers assume), so their vertices are written rotated by ``R`` =
:func:`~gof_warp.core.orientation.rotation_taking` ``(up, +Y)``, and ``R`` is recorded — GLB: the JSON's
``asset.extras.gof_warp.file_from_world`` (row-major 3 × 3), OBJ: a comment line ``# gof_warp file_from_world`` with
the nine numbers — so :func:`world_from_file` (:mod:`gof_warp.core.orientation`; used by every reader of mesh files) reads the
mesh back in the scene's frame. A USD stage states its up axis and holds the rotation as its ``/World`` transform
(:func:`gof_warp.mesh.usd_export.write_usd`). PLY is written in the scene's frame. ``up=None``: every format in the
scene's frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.arrays import check_triangles
from ..core.errors import GofError
from ..core.io_utils import atomic_path, write_bytes_atomic
from ..core.orientation import GLB_JSON, GLB_MAGIC, OBJ_ROTATION_TAG, Y_UP, read_glb_json, rotation_taking

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


UNLIT = "KHR_materials_unlit"


def srgb_to_linear(c) -> np.ndarray:
    """sRGB-encoded values in ``[0, 1]`` → linear (the sRGB transfer function, IEC 61966-2-1)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c) -> np.ndarray:
    """Linear values in ``[0, 1]`` → sRGB-encoded (the inverse of :func:`srgb_to_linear`)."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)


def _file_rotation(up) -> np.ndarray | None:
    """``R`` taking the world's ``up`` to +Y (None: no rotation, for ``up`` None or already +Y)."""
    if up is None:
        return None
    R = rotation_taking(up, Y_UP)
    return None if np.array_equal(R, np.eye(3)) else R


def _record_rotation(doc: dict, file_from_world: np.ndarray | None) -> None:
    """Write ``file_from_world`` (row-major) into a glTF JSON's ``asset.extras.gof_warp`` (nothing for None)."""
    if file_from_world is not None:
        doc.setdefault("asset", {}).setdefault("extras", {})["gof_warp"] = {
            "file_from_world": [float(x) for x in np.asarray(file_from_world, np.float64).ravel()]}


def _glb_with_json(glb: bytes, doc: dict, json_len: int) -> bytes:
    import json
    import struct

    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), GLB_JSON) + text + glb[20 + json_len:]
    return struct.pack("<III", GLB_MAGIC, 2, 12 + len(body)) + body


def unlit_glb(glb: bytes, file_from_world: np.ndarray | None = None) -> bytes:
    """``glb`` (a GLB trimesh wrote) with every material drawn in its own colours: ``KHR_materials_unlit`` (photo
    colours already hold the scene's light), a matte PBR fallback (metallic 0, roughness 1) for viewers without the
    extension, double-sided; primitives without a material get one. ``file_from_world``: the rotation the vertices
    were written with, recorded in ``asset.extras`` (module docstring)."""
    try:
        doc, json_len = read_glb_json(glb)
    except GofError:
        raise GofError("trimesh wrote a GLB that cannot be read back") from None
    _record_rotation(doc, file_from_world)
    materials = doc.setdefault("materials", [])
    for mesh_entry in doc.get("meshes", []):
        for prim in mesh_entry.get("primitives", []):
            if "material" not in prim:
                materials.append({})
                prim["material"] = len(materials) - 1
    for material in materials:
        pbr = material.setdefault("pbrMetallicRoughness", {})
        pbr["metallicFactor"], pbr["roughnessFactor"] = 0.0, 1.0
        material.setdefault("extensions", {})[UNLIT] = {}
        material["doubleSided"] = True
    used = doc.setdefault("extensionsUsed", [])
    if UNLIT not in used:
        used.append(UNLIT)
    return _glb_with_json(glb, doc, json_len)


def coloured_glb(vertices, faces, colours, file_from_world: np.ndarray | None = None) -> bytes:
    """A GLB of ``vertices [V, 3]``, ``faces [F, 3]`` and sRGB ``colours [V, 3]`` (uint8) as glTF defines vertex
    colours: ``COLOR_0`` linear (8 bits: the darkest sRGB levels round by a few steps), unlit (:func:`unlit_glb`);
    ``file_from_world``: recorded (the vertices are taken as given)."""
    import trimesh

    linear = np.round(srgb_to_linear(np.asarray(colours, np.float64) / 255.0) * 255.0).astype(np.uint8)
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int64),
                           process=False,
                           vertex_colors=np.concatenate([linear, np.full((len(linear), 1), 255, np.uint8)], 1))
    return unlit_glb(mesh.export(file_type="glb"), file_from_world)


def _rotated(v: np.ndarray, R: np.ndarray | None) -> np.ndarray:
    return v if R is None else np.asarray(v, np.float64) @ R.T


def save_mesh_file(path, vertices, faces, colours=None, fmt: str | None = None, up=None) -> str:
    """Write ``vertices [V, 3]``, ``faces [F, 3]`` and optional ``colours [V, 3]`` (uint8, or float in ``[0, 1]``)
    to ``path`` in ``fmt`` (:func:`format_of`); ``up`` (``[3]``, the scene's up; None: the scene's frame): GLB and OBJ
    written upright, USD with its ``/World`` rotation (module docstring). Returns the format written."""
    fmt = format_of(path, fmt)
    v, f = check_triangles(vertices, np.asarray(faces, np.int64), path, GofError)
    c = None if colours is None else _uint8(colours, len(v))
    R = _file_rotation(up) if fmt in ("glb", "obj") else None
    if fmt == "ply":
        from ..core.ply import write_ply_mesh

        write_ply_mesh(path, v, f, c)
    elif fmt == "usd":
        from .usd_export import write_usd

        write_usd(path, v, f, colours=c, up=up)
    elif fmt == "obj":
        _write_obj(path, _rotated(v, R), f, c, R)
    elif c is not None:
        write_bytes_atomic(path, coloured_glb(_rotated(v, R), f, c, R))
    else:
        import trimesh

        glb = trimesh.Trimesh(vertices=np.asarray(_rotated(v, R), np.float64), faces=f,
                              process=False).export(file_type="glb")
        if R is not None:
            doc, json_len = read_glb_json(glb)
            _record_rotation(doc, R)
            glb = _glb_with_json(glb, doc, json_len)
        write_bytes_atomic(path, glb)
    return fmt


def textured_companions(path, fmt: str | None = None) -> list[Path]:
    """The files besides ``path`` that a textured mesh writes: ``[<stem>.mtl, <stem>.png]`` for OBJ,
    ``[<stem>_texture.png]`` for USD (:func:`gof_warp.mesh.usd_export.texture_path`), none for GLB and PLY."""
    p = Path(path)
    fmt = format_of(p, fmt)
    if fmt == "usd":
        from .usd_export import texture_path

        return [texture_path(p)]
    return [p.with_suffix(".mtl"), p.with_suffix(".png")] if fmt == "obj" else []


def save_textured_mesh(path, textured, fmt: str | None = None, up=None) -> str:
    """Write a :class:`~gof_warp.mesh.texture.TexturedMesh` to ``path`` in ``fmt`` (:func:`format_of`; module
    docstring); ``up`` as :func:`save_mesh_file`'s (PLY and USD are written by the caller's own paths: PLY here in
    the scene's frame). Returns the format written."""
    fmt = format_of(path, fmt)
    R = _file_rotation(up) if fmt in ("glb", "obj") else None
    v = _rotated(np.asarray(textured.vertices, np.float64), R)
    f = np.asarray(textured.faces, np.int64)
    uv = np.asarray(textured.uv, np.float64)
    if uv.shape != (len(v), 2):
        raise GofError(f"textured mesh: uv must be [{len(v)}, 2], got {list(uv.shape)}")
    tex = textured.texture_uint8()
    if fmt == "ply":
        n = int(np.max(textured.vmap)) + 1
        mesh_v = np.zeros((n, 3), np.float64)
        mesh_v[textured.vmap] = np.asarray(textured.vertices, np.float64)
        mesh_f = np.asarray(textured.vmap, np.int64)[f]
        return save_mesh_file(path, mesh_v, mesh_f, textured.vertex_colours(), "ply")
    from PIL import Image

    image = Image.fromarray(tex, "RGB")
    gl_uv = textured.uv_up()  # OpenGL/OBJ convention: v up (trimesh flips it for glTF)
    if fmt == "glb":
        import trimesh
        from trimesh.visual.material import PBRMaterial
        from trimesh.visual.texture import TextureVisuals

        material = PBRMaterial(name="texture", baseColorTexture=image, metallicFactor=0.0, roughnessFactor=1.0,
                               doubleSided=True)
        mesh = trimesh.Trimesh(vertices=v, faces=f, process=False,
                               visual=TextureVisuals(uv=gl_uv, material=material))
        write_bytes_atomic(path, unlit_glb(mesh.export(file_type="glb"), R))
        return fmt
    mtl, png = textured_companions(path, "obj")
    with atomic_path(png) as tmp:
        image.save(tmp, format="PNG")
    with atomic_path(mtl) as tmp:
        Path(tmp).write_text("# written by gof_warp\nnewmtl texture\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\n"
                             f"map_Kd {png.name}\n", encoding="ascii")
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii") as out:
            out.write(f"# written by gof_warp\n{_obj_rotation_line(R)}mtllib {mtl.name}\n")
            np.savetxt(out, v.astype(np.float32), fmt="v %.7g %.7g %.7g")
            np.savetxt(out, gl_uv, fmt="vt %.7g %.7g")
            out.write("usemtl texture\n")
            k = f + 1
            np.savetxt(out, np.stack([k[:, 0], k[:, 0], k[:, 1], k[:, 1], k[:, 2], k[:, 2]], 1),
                       fmt="f %d/%d %d/%d %d/%d")
    return fmt


def _obj_rotation_line(R: np.ndarray | None) -> str:
    return "" if R is None else OBJ_ROTATION_TAG + " " + " ".join(f"{x:.17g}" for x in R.ravel()) + "\n"


def _write_obj(path, v, f, c, R: np.ndarray | None = None) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii") as out:
            out.write("# written by gof_warp\n" + _obj_rotation_line(R))
            if c is None:
                np.savetxt(out, np.asarray(v, np.float32), fmt="v %.7g %.7g %.7g")
            else:
                rows = np.concatenate([np.asarray(v, np.float64), c.astype(np.float64) / 255.0], 1)
                np.savetxt(out, rows, fmt="v %.7g %.7g %.7g %.6g %.6g %.6g")
            np.savetxt(out, np.asarray(f, np.int64) + 1, fmt="f %d %d %d")
