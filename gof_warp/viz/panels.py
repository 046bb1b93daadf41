"""Drawing the pictures of :mod:`gof_warp.viz.pictures`: mesh shading, depth and normal colour maps, and tiles
composed into one labelled picture (library code; the run loading and the CLI are in :mod:`gof_warp.viz.pictures`).

:func:`view_panels` draws one row per camera, with the columns

    photo | Gaussian render | median depth | rendered normal | shaded mesh

* **Gaussian render**: :func:`gof_warp.rendering.render.render` with the given render settings.
* **median depth**: :func:`colorize_depth`, colour-mapped between the 2nd and 98th percentile of the covered
  pixels (near = bright yellow, far = dark purple), composited on the background by the rendered alpha.
* **rendered normal**: :func:`colorize_normal`, the renderer's normal map turned to world space, colour
  ``(n + 1) / 2``.
* **distortion** (optional, the loss-spike pictures): :func:`colorize_distortion`, the per-pixel distortion term's map
  (how far apart along the ray the pixel's weight lies), square root of its share of the image's maximum.
* **shaded mesh**: :func:`shade_mesh` — the mesh ray cast with Warp's BVH from the same camera, lit by a
  headlight plus ambient light; faces seen from behind (inside-out parts, holes into the interior) are
  tinted red.
* **coloured mesh** / **textured mesh** (instead of the shaded mesh when the mesh carries colours: per-vertex or
  per-face colours, or a texture, :class:`~gof_warp.viz.mesh_files.MeshFile`): the same ray cast, each sample
  showing the surface's own colour at its hit, unlit (front and back alike), so that it compares with the photo.

Wide images are downscaled (cameras scaled exactly, photos resampled) so that the picture stays at most
``max_width`` (2000) pixels wide. The mesh is made ready for ray casting once (:class:`CastMesh`: its BVH) and
drawn from every row's camera. Memory: one view at a time; :func:`shade_cast_mesh` holds ``H·W·s²`` samples
(``s`` = supersampling) of a few floats each, besides the mesh and its BVH.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from ..core.arrays import check_triangles
from ..core.camera import Camera
from ..core.devices import resolve_device, warp_device
from ..core.errors import GofError
from ..kernels import raycast
from ..rendering.render import RenderConfig

log = logging.getLogger(__name__)

BACKGROUND = (0.2, 0.2, 0.2)  # neutral dark grey behind every tile
FRONT_COLOR = (0.82, 0.82, 0.80)  # mesh seen from the side its normal points to
BACK_COLOR = (0.85, 0.22, 0.18)  # mesh seen from behind: inside-out or a hole into the interior
AMBIENT = 0.25  # share of light that does not depend on the angle to the headlight
PANEL_COLOR = (24, 24, 24)  # gaps and label strips
TEXT_COLOR = (225, 225, 225)
MARGIN, GAP, HEADER_H, LABEL_H = 4, 4, 14, 13  # layout in pixels (see panel_layout)
MAX_WIDTH = 2000
DEPTH_PERCENTILES = (2.0, 98.0)  # robust depth range: ignores a few stray near/far pixels
COVERED_ALPHA = 0.5  # a pixel is "covered" by the Gaussians (for the depth range) above this alpha
COLUMN_TITLES = {"photo": "photo", "render": "Gaussian render", "depth": "median depth", "normal": "rendered normal",
                 "distortion": "distortion (sqrt)", "mesh": "shaded mesh"}
MESH_TITLES = {"none": "shaded mesh", "vertex": "coloured mesh", "face": "coloured mesh", "texture": "textured mesh"}
# Viridis sampled at 0, 1/4, 1/2, 3/4, 1 (far → near); linear in between is close enough for a preview.
_DEPTH_ANCHORS = np.array([[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551],
                           [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]], np.float32)


# ------------------------------------------------------------------------------------------ mesh shading
def _warp_device(device, *inputs):
    """The Warp device under :mod:`gof_warp.core.devices`' rule: ``device`` (a Warp or torch device, or its name) if
    given, else that of the first torch tensor / ``wp.array`` among ``inputs``, else the default."""
    import warp as wp

    wp.init()
    like = next((x for x in inputs if hasattr(x, "device") and hasattr(x, "shape")), None)
    name = None if device is None else str(device)
    if like is not None and not torch.is_tensor(like):  # a wp.array: its device's name
        like = type("_Dev", (), {"device": str(like.device)})()
    return wp.get_device(warp_device(resolve_device(name, like=like)))


def _as_numpy(x, dtype):
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    elif hasattr(x, "numpy"):
        x = x.numpy()
    return np.asarray(x, dtype=dtype)


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v, f = check_triangles(_as_numpy(vertices, np.float64), _as_numpy(faces, np.int64), "shade_mesh")
    if not np.all(np.isfinite(v)):
        raise ValueError("shade_mesh: vertices hold NaN/inf")
    return v, f


def _sample_directions(camera: Camera, samples: int) -> np.ndarray:
    """``[H*s, W*s, 3]`` unit world directions of the rays :func:`raycast.cast_pinhole_rays` casts."""
    s = samples
    u = (np.arange(camera.width * s) + 0.5) / s
    v = (np.arange(camera.height * s) + 0.5) / s
    uu, vv = np.meshgrid((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, indexing="xy")
    d = np.stack([uu, vv, np.ones_like(uu)], axis=-1) @ camera.R  # R^T applied to row vectors
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@dataclass
class CastMesh:
    """A triangle mesh made ready for ray casting once (checked, uploaded, its ``wp.Mesh`` BVH built), then drawn
    from any number of cameras by :func:`shade_cast_mesh`. ``vertices`` ``[V, 3]`` float64 and ``faces`` ``[F, 3]``
    int64 are host copies (the face normals of the hit faces come from them); ``bvh`` lives on ``device``.
    ``colours``: the mesh's appearance, a :class:`~gof_warp.viz.mesh_files.MeshFile` of these triangles that
    carries colours or a texture (its :meth:`~gof_warp.viz.mesh_files.MeshFile.colour_at` gives the colour at a
    hit), or None for an uncoloured mesh."""

    vertices: np.ndarray
    faces: np.ndarray
    bvh: object | None  # wp.Mesh; None for a mesh with no faces
    device: object
    colours: object = None

    @property
    def appearance(self) -> str:
        """``"none"`` (uncoloured), ``"vertex"``, ``"face"`` or ``"texture"``."""
        return "none" if self.colours is None else self.colours.appearance

    @classmethod
    def build(cls, vertices, faces, device=None, colours=None) -> "CastMesh":
        """Check ``vertices`` ``[V, 3]`` / ``faces`` ``[F, 3]`` (numpy, torch or array-like) and build the BVH on
        ``device`` (Warp/torch device name; default: the device of ``vertices`` if it is a tensor, else CPU).
        ``colours``: a :class:`~gof_warp.viz.mesh_files.MeshFile` of the same triangles (kept only when it carries
        colours), or vertex colours ``[V, 3]`` (uint8, or float in ``[0, 1]``), or None."""
        import warp as wp

        dev = _warp_device(device, vertices)
        v, f = _check_mesh(vertices, faces)
        colours = _as_appearance(colours, v, f)
        bvh = None
        if len(f):
            points = wp.array(v.astype(np.float32), dtype=wp.vec3, device=dev)
            indices = wp.array(f.astype(np.int32).ravel(), dtype=wp.int32, device=dev)
            bvh = wp.Mesh(points=points, indices=indices)
        return cls(vertices=v, faces=f, bvh=bvh, device=dev, colours=colours)

    @classmethod
    def of(cls, mesh, device=None) -> "CastMesh":
        """A :class:`CastMesh` of what :func:`view_panels` accepts as ``mesh``: a :class:`CastMesh` (as is), a
        :class:`~gof_warp.viz.mesh_files.MeshFile`, or ``(vertices, faces)`` / ``(vertices, faces, colours [V, 3])``."""
        if isinstance(mesh, CastMesh):
            return mesh
        if hasattr(mesh, "vertices") and hasattr(mesh, "faces") and hasattr(mesh, "colour_at"):
            return cls.build(mesh.vertices, mesh.faces, device, colours=mesh)
        if not isinstance(mesh, (tuple, list)) or len(mesh) not in (2, 3):
            raise GofError("a mesh to draw must be (vertices, faces), (vertices, faces, colours), a MeshFile or a "
                           f"CastMesh, got {type(mesh).__name__}")
        return cls.build(mesh[0], mesh[1], device, colours=mesh[2] if len(mesh) == 3 else None)


def _as_appearance(colours, vertices: np.ndarray, faces: np.ndarray):
    """``colours`` of :meth:`CastMesh.build` as a coloured :class:`~gof_warp.viz.mesh_files.MeshFile`, or None."""
    from .mesh_files import MeshFile

    if colours is None:
        return None
    if isinstance(colours, MeshFile):
        if not colours.coloured:
            return None
        if len(colours.vertices) != len(vertices) or len(colours.faces) != len(faces):
            raise GofError(f"{colours.path}: its colours are for another mesh ({len(colours.vertices)} vertices, "
                           f"{len(colours.faces)} faces; drawing {len(vertices)}, {len(faces)})")
        return colours
    c = _as_numpy(colours, None)
    if c.shape != (len(vertices), 3):
        raise GofError(f"vertex colours must be [{len(vertices)}, 3], got {list(c.shape)}")
    if c.dtype != np.uint8:
        c = np.round(np.clip(c.astype(np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
    return MeshFile(path="vertex colours", vertices=vertices, faces=faces, vertex_colors=c)


def shade_mesh(vertices, faces, camera: Camera, *, mode: str = "shaded", supersample: int = 2, device=None,
               background=BACKGROUND, near: float = 0.0) -> np.ndarray:
    """Ray cast a triangle mesh from ``camera`` and shade it for viewing (:func:`shade_cast_mesh` on
    ``CastMesh.build(vertices, faces, device)``; build a :class:`CastMesh` once to draw one mesh from many cameras).

    Args:
        vertices: ``[V, 3]`` world positions (numpy, torch or anything array-like).
        faces: ``[F, 3]`` vertex indices.
        camera, mode, supersample, background, near: as in :func:`shade_cast_mesh`.
        device: Warp/torch device name; default: the device of ``vertices`` if it is a tensor, else CPU.

    Returns:
        ``[H, W, 3]`` uint8 image.
    """
    _check_shading(camera, mode, supersample)
    return shade_cast_mesh(CastMesh.build(vertices, faces, device), camera, mode=mode, supersample=supersample,
                           background=background, near=near)


SHADE_MODES = ("shaded", "normals", "colour")


def _check_shading(camera, mode: str, supersample) -> None:
    if not isinstance(camera, Camera):
        raise TypeError(f"shade_mesh: camera must be a gof_warp.core.camera.Camera, got {type(camera).__name__}")
    if mode not in SHADE_MODES:
        raise ValueError(f"shade_mesh: mode must be one of {SHADE_MODES}, got {mode!r}")
    if int(supersample) != supersample or supersample < 1:
        raise ValueError(f"shade_mesh: supersample must be an integer >= 1, got {supersample}")


def shade_cast_mesh(mesh: CastMesh, camera: Camera, *, mode: str = "shaded", supersample: int = 2,
                    background=BACKGROUND, near: float = 0.0) -> np.ndarray:
    """Ray cast a :class:`CastMesh` from ``camera`` and shade it for viewing.

    Each sample ray (``supersample²`` per pixel, on the grid of :mod:`gof_warp.kernels.raycast`; 1 = the
    pixel centres) finds its closest triangle through the mesh's BVH. A hit on a face whose normal
    ``(p1 - p0) × (p2 - p0)`` points towards the camera is shaded ``FRONT_COLOR``, one seen from behind
    ``BACK_COLOR`` (two-sided: inside-out parts and holes show red); both times
    ``AMBIENT + (1 - AMBIENT) · |n · d|`` (a headlight). ``mode="normals"`` colours the camera-facing
    world normal as ``(n + 1) / 2`` instead (back faces mixed half with red). ``mode="colour"`` (a mesh with
    colours only) gives each sample the surface colour at its hit (:meth:`MeshFile.colour_at
    <gof_warp.viz.mesh_files.MeshFile.colour_at>`: vertex colours interpolated, a face's colour, or the texture
    looked up at the interpolated uv), unlit, on both sides. Misses get ``background``.
    Pixels average their samples. Only the faces some ray hits have their normals computed.

    Args:
        mesh: :class:`CastMesh`.
        camera: :class:`~gof_warp.core.camera.Camera` (OpenCV axes, world-to-camera).
        mode: ``"shaded"``, ``"normals"`` or ``"colour"``.
        supersample: samples per pixel axis (≥ 1).
        background: RGB in ``[0, 1]``.
        near: depth in front of which nothing is drawn (the camera's clip; 0: none).

    Returns:
        ``[H, W, 3]`` uint8 image.
    """
    _check_shading(camera, mode, supersample)
    if mode == "colour" and mesh.colours is None:
        raise ValueError("shade_mesh: mode 'colour' needs a mesh with colours or a texture")
    s = int(supersample)
    bg = np.asarray(background, np.float32)
    h, w = camera.height, camera.width
    if mesh.bvh is None:
        log.warning("shade_mesh: the mesh has no faces; the picture is background only")
        return np.broadcast_to(np.round(bg * 255).astype(np.uint8), (h, w, 3)).copy()

    hits = raycast.cast_pinhole_rays(mesh.bvh, camera.R, camera.t, camera.fx, camera.fy, camera.cx, camera.cy, w, h,
                                     s, min_depth=float(near))
    face = hits["face"].numpy()

    hit = face >= 0
    tri = mesh.vertices[mesh.faces[face[hit]]]  # [hits, 3, 3]: only the faces some ray meets
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)
    d = _sample_directions(camera, s)[hit]
    cos = -np.einsum("ij,ij->i", n, d)  # > 0: the face's normal points towards the camera
    back = cos < 0
    if mode == "colour":
        col = mesh.colours.colour_at(face[hit], hits["bary"].numpy()[hit])
    elif mode == "shaded":
        base = np.where(back[:, None], np.asarray(BACK_COLOR, np.float32), np.asarray(FRONT_COLOR, np.float32))
        col = base * (AMBIENT + (1.0 - AMBIENT) * np.abs(cos))[:, None]
    else:
        facing = np.where(back[:, None], -n, n)
        col = 0.5 * (facing + 1.0)
        col = np.where(back[:, None], 0.5 * col + 0.5 * np.asarray(BACK_COLOR), col)
    samples = np.broadcast_to(bg, face.shape + (3,)).astype(np.float32)
    samples[hit] = col
    img = samples.reshape(h, s, w, s, 3).mean(axis=(1, 3))
    return np.round(np.clip(img, 0.0, 1.0) * 255).astype(np.uint8)


# ------------------------------------------------------------------------------------ Gaussian columns
def colorize_depth(depth: np.ndarray, alpha: np.ndarray, background=BACKGROUND) -> np.ndarray:
    """``[H, W]`` depth → ``[H, W, 3]`` uint8: viridis between the 2nd/98th percentile of the covered
    pixels (``alpha > COVERED_ALPHA`` and depth > 0), near bright; composited on ``background`` by alpha."""
    depth = np.asarray(depth, np.float32)
    alpha = np.clip(np.asarray(alpha, np.float32), 0.0, 1.0)
    valid = (alpha > COVERED_ALPHA) & (depth > 0) & np.isfinite(depth)
    bg = np.asarray(background, np.float32)
    if not valid.any():
        return np.broadcast_to(np.round(bg * 255).astype(np.uint8), depth.shape + (3,)).copy()
    lo, hi = np.percentile(depth[valid], DEPTH_PERCENTILES)
    col = _viridis(1.0 - np.clip((depth - lo) / max(float(hi - lo), 1e-12), 0.0, 1.0))  # 1 = near
    a = np.where(depth > 0, alpha, 0.0)[..., None]
    return np.round(np.clip(col * a + bg * (1 - a), 0, 1) * 255).astype(np.uint8)


def _viridis(x: np.ndarray) -> np.ndarray:
    """``[...]`` values in ``[0, 1]`` → ``[..., 3]`` float colours (the depth map's ramp: 1 = bright yellow)."""
    pos = np.clip(x, 0.0, 1.0) * (len(_DEPTH_ANCHORS) - 1)
    i = np.minimum(pos.astype(np.int64), len(_DEPTH_ANCHORS) - 2)
    t = (pos - i)[..., None]
    return _DEPTH_ANCHORS[i] * (1 - t) + _DEPTH_ANCHORS[i + 1] * t


def colorize_distortion(distortion: np.ndarray) -> np.ndarray:
    """``[H, W]`` per-pixel distortion (≥ 0) → ``[H, W, 3]`` uint8: viridis of ``sqrt(d / max d)`` (an all-zero map
    is dark)."""
    d = np.clip(np.nan_to_num(np.asarray(distortion, np.float64)), 0.0, None)
    top = float(d.max()) if d.size else 0.0
    x = np.sqrt(d / top) if top > 0 else np.zeros_like(d)
    return np.round(np.clip(_viridis(x), 0, 1) * 255).astype(np.uint8)


def colorize_normal(normal_cam: np.ndarray, alpha: np.ndarray, camera: Camera, background=BACKGROUND) -> np.ndarray:
    """Rendered camera-space normals ``[H, W, 3]`` (Σ w n̂, any length) → world ``(n + 1) / 2`` as uint8,
    composited on ``background`` by alpha."""
    n = np.asarray(normal_cam, np.float64) @ camera.R  # camera → world: R^T on row vectors
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(length > 1e-8, n / np.where(length > 1e-8, length, 1.0), 0.0)
    a = np.clip(np.asarray(alpha, np.float64), 0, 1)[..., None] * (length > 1e-8)
    col = 0.5 * (n + 1.0) * a + np.asarray(background) * (1 - a)
    return np.round(np.clip(col, 0, 1) * 255).astype(np.uint8)


def render_columns(gaussians, camera: Camera, render_config=None, distortion: bool = False) -> dict[str, np.ndarray]:
    """``{"render", "depth", "normal"}`` (and ``"distortion"`` when asked) uint8 ``[H, W, 3]`` images of the Gaussians
    seen by ``camera``."""
    import torch

    from ..rendering.render import render

    with torch.no_grad():
        out = render(gaussians, camera, config=render_config)
    rgb = out["rgb"].clamp(0, 1).cpu().numpy()
    alpha = out["alpha"].cpu().numpy()
    tiles = {"render": np.round(rgb * 255).astype(np.uint8),
             "depth": colorize_depth(out["median_depth"].cpu().numpy(), alpha),
             "normal": colorize_normal(out["normal"].cpu().numpy(), alpha, camera)}
    if distortion:
        tiles["distortion"] = colorize_distortion(out["distortion"].cpu().numpy())
    return tiles


# --------------------------------------------------------------------------------------- panel layout
def panel_layout(columns: list[str], sizes: list[tuple[int, int]]) -> tuple[int, int, dict]:
    """Where each tile goes: ``(width, height, boxes)`` with ``boxes[(row, column)] = (x0, y0, x1, y1)``.

    ``sizes``: ``(width, height)`` of each row's tiles. A header strip (``HEADER_H``) names the columns;
    each row has a label strip (``LABEL_H``) above it; ``GAP`` between tiles, ``MARGIN`` around.
    """
    col_w = max(w for w, _ in sizes)
    boxes = {}
    y = MARGIN + HEADER_H
    for r, (w, h) in enumerate(sizes):
        y += LABEL_H
        for c, name in enumerate(columns):
            x = MARGIN + c * (col_w + GAP)
            boxes[(r, name)] = (x, y, x + w, y + h)
        y += h + GAP
    width = 2 * MARGIN + len(columns) * col_w + (len(columns) - 1) * GAP
    return width, y - GAP + MARGIN, boxes


def fit_scale(columns: int, widths: list[int], max_width: int = MAX_WIDTH) -> float:
    """Factor ≤ 1 for the cameras so that :func:`panel_layout` of ``columns`` columns fits ``max_width``."""
    overhead = 2 * MARGIN + (columns - 1) * GAP
    return min(1.0, (max_width - overhead) / float(columns * max(widths)))


def _text_strip(text: str, width: int, height: int) -> np.ndarray:
    """``text`` in Pillow's default font on a ``PANEL_COLOR`` strip, clipped to ``width``."""
    from PIL import Image, ImageDraw

    strip = Image.new("RGB", (max(width, 1), height), PANEL_COLOR)
    ImageDraw.Draw(strip).text((2, 1), text, fill=TEXT_COLOR)
    return np.asarray(strip)


@dataclass
class Panels:
    """A composed picture: ``image`` ``[H, W, 3]`` uint8, its ``columns``, the row ``names`` and the
    tile ``boxes`` of :func:`panel_layout`."""

    image: np.ndarray
    columns: list[str]
    names: list[str]
    boxes: dict


def _resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    if image.shape[:2] == (height, width):
        return image
    from PIL import Image

    return np.asarray(Image.fromarray(image).resize((width, height), Image.BICUBIC))


def view_panels(gaussians, cameras: list[Camera], *, photos: list | None = None, mesh=None, render_config=None,
                path=None, labels: list[str] | None = None, max_width: int = MAX_WIDTH, device=None,
                distortion: bool = False) -> Panels:
    """One row per camera: photo | Gaussian render | median depth | rendered normal | [distortion |] mesh (shaded, or
    in its own colours).

    The mesh is drawn from the same near plane as the render beside it (the larger of ``render_config.near`` and the
    camera's own clip, :attr:`Camera.near`): what lies in front of that plane the photo never showed, and drawing it
    would hide the scene behind surfaces the Gaussian render does not have.

    Args:
        gaussians: :class:`~gof_warp.core.model.Gaussians` (rendered on their own device).
        cameras: the views to show (one row each).
        photos: ``[H, W, 3]`` uint8 per camera (None entries: "no photo"), or None for no photo column.
        mesh: ``(vertices [V, 3], faces [F, 3])``, ``(vertices, faces, vertex colours [V, 3])``, a
            :class:`~gof_warp.viz.mesh_files.MeshFile`, a :class:`CastMesh`, or None for no mesh column. A mesh with
            colours or a texture is drawn in them (the "coloured mesh" / "textured mesh" column), else shaded.
        render_config: :class:`~gof_warp.rendering.render.RenderConfig` (default thresholds if None).
        path: if given, the PNG is written there atomically.
        labels: one text per row (default: the camera names).
        max_width: cameras (and photos) are scaled down so the picture is at most this wide.
        device: Warp device for the mesh ray casting (default: the Gaussians' device).
        distortion: add the distortion map's column.
    Returns:
        :class:`Panels`.
    """
    if not cameras:
        raise GofError("view_panels: no cameras to show")
    if photos is not None and len(photos) != len(cameras):
        raise ValueError(f"view_panels: {len(photos)} photos for {len(cameras)} cameras")
    columns = ["photo"] if photos is not None else []
    columns += ["render", "depth", "normal"] + (["distortion"] if distortion else []) + (["mesh"] if mesh is not None else [])
    scale = fit_scale(len(columns), [c.width for c in cameras], max_width)
    cams = [c if scale == 1.0 else c.scaled(scale) for c in cameras]
    width, height, boxes = panel_layout(columns, [(c.width, c.height) for c in cams])
    mesh_device = device if device is not None else getattr(gaussians, "device", None)
    if mesh is not None:
        mesh = CastMesh.of(mesh, mesh_device)  # once for every row
    titles = dict(COLUMN_TITLES, mesh=MESH_TITLES[mesh.appearance]) if mesh is not None else COLUMN_TITLES
    canvas = np.empty((height, width, 3), np.uint8)
    canvas[:] = PANEL_COLOR
    col_w = max(c.width for c in cams)
    for name in columns:
        x0 = boxes[(0, name)][0]
        canvas[MARGIN:MARGIN + HEADER_H, x0:x0 + col_w] = _text_strip(titles[name], col_w, HEADER_H)
    labels = labels or [c.name for c in cameras]
    clip = render_config or RenderConfig()
    for r, cam in enumerate(cams):
        tiles = render_columns(gaussians, cam, render_config, distortion=distortion)
        if photos is not None:
            p = photos[r]
            tiles["photo"] = (np.full((cam.height, cam.width, 3), np.round(np.asarray(BACKGROUND) * 255), np.uint8)
                              if p is None else _resize(np.asarray(p, np.uint8), cam.width, cam.height))
        if mesh is not None:
            tiles["mesh"] = shade_cast_mesh(mesh, cam, near=clip.clip_near(cam),
                                            mode="shaded" if mesh.colours is None else "colour")
        x0, y0, _, _ = boxes[(r, columns[0])]
        canvas[y0 - LABEL_H:y0, x0:width - MARGIN] = _text_strip(labels[r], width - MARGIN - x0, LABEL_H)
        for name in columns:
            bx0, by0, bx1, by1 = boxes[(r, name)]
            canvas[by0:by1, bx0:bx1] = tiles[name]
    if path is not None:
        write_png(path, canvas)
    return Panels(image=canvas, columns=columns, names=[c.name for c in cameras], boxes=boxes)


def write_png(path, image: np.ndarray) -> None:
    """Write a uint8 RGB image as PNG, atomically."""
    from PIL import Image

    from ..core.io_utils import atomic_path

    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(image)).save(tmp, format="PNG")
