"""Vertex colours for an extracted mesh, and the coloured mesh's fidelity to the photos.

Two colour sources (:data:`SOURCES`), one rule (:func:`colours_from_images`): each vertex takes the weighted mean of
the images of the views that see it, sampled (bilinearly) at its projection.

* ``"gaussians"`` (:func:`gaussian_images`): the Gaussians rendered from each training camera (view-dependent SH
  colour at that camera);
* ``"photos"``: the training photos themselves (real appearance; exposure differences are averaged).

A view sees a vertex when the vertex projects into its image in front of the camera and the segment from the camera
centre to the vertex meets no face of the mesh before the last ``depth_tol`` of its length (plus ``depth_tol_px``
pixel footprints): a Warp ray query per vertex and view (:func:`points_unblocked`, the module's own kernel) on the
mesh's BVH. A vertex behind another part of the mesh takes nothing from that view. The weight of a view is
``|cos|`` of the angle between the vertex normal and the ray (grazing views count little). Vertices no view sees take
the colour of the nearest seen vertex (all grey when none is seen).

:func:`render_vertex_colours` renders a vertex-coloured mesh by ray casting (the hit face's barycentric interpolation of
its corners' colours) and :func:`mesh_render_psnr` measures it against photos (PSNR and SSIM, over the pixels the mesh
covers and over the whole image).

Memory: the views are taken one at a time (an iterable of images is consumed lazily): besides the mesh's ``wp.Mesh``
(BVH, ~12 B per face of indices plus the nodes) the working set is one image (``H W`` x 12 B) and
``O(V)`` per-vertex sums (``V`` x 16 B) plus ``O(V)`` temporaries per view.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence

import numpy as np
import warp as wp

from ..core.arrays import check_triangles
from ..core.camera import Camera
from ..core.devices import warp_device
from ..core.errors import GofError

log = logging.getLogger(__name__)

SOURCES = ("gaussians", "photos")
DEPTH_TOL = 0.01  # the last fraction of a vertex's ray where a face does not hide it (its own faces meet it there)
DEPTH_TOL_PX = 2.0  # ... plus this many pixel footprints (d / f)
UNSEEN_GREY = 0.5


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``[V, 3]`` float64 (0 for a vertex of no face with area)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _wp_mesh(vertices, faces, device) -> wp.Mesh:
    pts = wp.array(np.ascontiguousarray(vertices, np.float32), dtype=wp.vec3, device=device)
    idx = wp.array(np.ascontiguousarray(faces, np.int32).ravel(), dtype=wp.int32, device=device)
    return wp.Mesh(points=pts, indices=idx)


def _cast(mesh: wp.Mesh, camera: Camera) -> dict:
    """The mesh's first hits at ``camera``'s pixel centres: numpy ``face [H, W]`` (-1: miss), ``bary [H, W, 2]``,
    ``depth [H, W]`` (camera z, 0: miss)."""
    from ..kernels import raycast

    c = camera
    hits = raycast.cast_pinhole_rays(mesh, c.R, c.t, c.fx, c.fy, c.cx, c.cy, c.width, c.height, 1)
    return {k: hits[k].numpy() for k in ("face", "bary", "depth")}


@wp.func
def segment_unblocked(mesh: wp.uint64, origin: wp.vec3, point: wp.vec3, rel_tol: float) -> bool:
    """The visibility rule of this module (and of :mod:`gof_warp.mesh.texture`): the segment from ``origin`` to
    ``point`` meets no face of ``mesh`` before ``(1 - rel_tol)`` of its length (False for a zero-length one)."""
    d = point - origin
    dist = wp.length(d)
    if dist > 0.0:
        q = wp.mesh_query_ray(mesh, origin, d / dist, dist * (1.0 - rel_tol))
        if not q.result:
            return True
    return False


def visibility_tolerance(camera: Camera, depth_tol: float = DEPTH_TOL, depth_tol_px: float = DEPTH_TOL_PX) -> float:
    """The ``rel_tol`` of :func:`segment_unblocked` for a point seen by ``camera``: ``depth_tol`` plus
    ``depth_tol_px`` pixel footprints (``1 / f``)."""
    return depth_tol + depth_tol_px / min(camera.fx, camera.fy)


@wp.kernel
def _points_unblocked(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), origin: wp.vec3, rel_tol: float,
                      visible: wp.array(dtype=wp.int32)):
    """``visible[i]`` = 1 when :func:`segment_unblocked` from ``origin`` to ``points[i]``, else 0."""
    i = wp.tid()
    visible[i] = 0
    if segment_unblocked(mesh, origin, points[i], rel_tol):
        visible[i] = 1


def points_unblocked(mesh: wp.Mesh, points: np.ndarray, origin: np.ndarray, rel_tol: float) -> np.ndarray:
    """``[N]`` bool: the segment from ``origin`` to each of ``points [N, 3]`` meets no face of ``mesh`` before
    ``(1 - rel_tol)`` of its length (the point is not hidden behind another part of the mesh)."""
    if not len(points):
        return np.zeros(0, bool)
    dev = mesh.device
    pts = wp.array(np.ascontiguousarray(points, np.float32), dtype=wp.vec3, device=dev)
    out = wp.empty(len(points), dtype=wp.int32, device=dev)
    wp.launch(_points_unblocked, dim=len(points), inputs=[mesh.id, pts, wp.vec3(*np.asarray(origin, np.float32)),
                                                          float(rel_tol), out], device=dev)
    return out.numpy().astype(bool)


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``image [H, W, C]`` at continuous pixel coordinates (pixel centres at ``i + 0.5``), clamped at the edges."""
    h, w = image.shape[:2]
    x = np.clip(u - 0.5, 0.0, w - 1.0)
    y = np.clip(v - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 1)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def _as_float_image(image, camera: Camera) -> np.ndarray:
    img = image.detach().cpu().numpy() if hasattr(image, "detach") else np.asarray(image)
    img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)
    if img.ndim != 3 or img.shape[2] < 3 or img.shape[:2] != (camera.height, camera.width):
        raise GofError(f"vertex colours: view {camera.name!r} has an image of shape {img.shape}, expected "
                       f"[{camera.height}, {camera.width}, 3]")
    return img[..., :3]


def colours_from_images(vertices: np.ndarray, faces: np.ndarray, cameras: Sequence[Camera], images: Iterable, *,
                        depth_tol: float = DEPTH_TOL, depth_tol_px: float = DEPTH_TOL_PX, device=None,
                        return_seen: bool = False):
    """Vertex colours ``[V, 3]`` float32 in ``[0, 1]`` from ``images`` seen by ``cameras`` (module docstring).

    Args:
        vertices: ``[V, 3]`` world positions; faces: ``[F, 3]`` vertex indices (the occluders).
        cameras: one :class:`Camera` per image.
        images: an iterable of ``[H, W, 3]`` images (uint8, or float in ``[0, 1]``; numpy or torch), one per camera,
            at the camera's size; consumed one at a time.
        depth_tol, depth_tol_px: the vertex at distance ``d`` is seen when nothing of the mesh lies on its ray
            before ``d (1 - depth_tol - depth_tol_px / f)``.
        device: Warp device for the ray casting (default: CUDA if present, else the CPU).
        return_seen: also return the number of views that saw each vertex ``[V]`` int32.
    """
    v, f = check_triangles(vertices, np.asarray(faces, np.int64), "vertex colours", GofError)
    v = np.asarray(v, np.float64)
    cams = list(cameras)
    sums = np.zeros((len(v), 3), np.float64)
    weights = np.zeros(len(v), np.float64)
    seen = np.zeros(len(v), np.int32)
    if len(v) and len(f):
        mesh = _wp_mesh(v, f, warp_device(device))
        normals = vertex_normals(v, f)
        n_images = 0
        for cam, image in zip(cams, images):
            n_images += 1
            img = _as_float_image(image, cam)
            uv, z, inside = cam.in_image(v)
            idx = np.flatnonzero(inside)
            if not len(idx):
                continue
            ok = points_unblocked(mesh, v[idx], cam.center, visibility_tolerance(cam, depth_tol, depth_tol_px))
            idx = idx[ok]
            u, vv = uv[idx, 0], uv[idx, 1]
            ray = v[idx] - cam.center
            ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-30)
            w = np.abs(np.einsum("ij,ij->i", ray, normals[idx]))
            w = np.where(np.linalg.norm(normals[idx], axis=1) > 0, w, 1.0)  # a vertex of no area: equal weights
            sums[idx] += w[:, None] * _bilinear(img, u, vv)
            weights[idx] += w
            seen[idx] += 1
        if n_images != len(cams):
            raise GofError(f"vertex colours: {len(cams)} cameras but {n_images} images")
    colours = np.full((len(v), 3), UNSEEN_GREY, np.float64)
    have = weights > 0
    colours[have] = sums[have] / weights[have, None]
    if have.any() and not have.all():
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(v[have]).query(v[~have])
        colours[~have] = colours[have][nearest]
    if (~have).any():
        log.info("vertex colours: %d of %d vertices seen by no view take the nearest seen vertex's colour",
                 int((~have).sum()), len(v))
    out = np.clip(colours, 0.0, 1.0).astype(np.float32)
    return (out, seen) if return_seen else out


def gaussian_images(gaussians, cameras: Sequence[Camera], render_config=None):
    """The Gaussians' rendered colour ``[H, W, 3]`` float32 numpy from each of ``cameras``, one at a time (a
    generator: one render held at once)."""
    import torch

    from ..rendering.render import render

    for cam in cameras:
        with torch.no_grad():
            out = render(gaussians, cam, config=render_config)
        yield out["rgb"].clamp(0, 1).detach().cpu().numpy()


def source_images(source: str, cameras: Sequence[Camera], *, gaussians=None, photos=None, render_config=None,
                  what: str = "vertex colours"):
    """The images a colour ``source`` (:data:`SOURCES`) gives for ``cameras``, one per camera: ``"gaussians"``
    renders ``gaussians`` (a generator, one render at a time); ``"photos"`` is ``photos``."""
    if source == "gaussians":
        if gaussians is None:
            raise GofError(f"{what} from the Gaussians need the Gaussians")
        return gaussian_images(gaussians, cameras, render_config)
    if source == "photos":
        if photos is None:
            raise GofError(f"{what} from the photos need the training photos (the scene folder)")
        return photos
    raise GofError(f"{what}: the colour source must be one of {SOURCES}, got {source!r}")


def mesh_colours(source: str, vertices, faces, cameras: Sequence[Camera], *, gaussians=None, photos=None,
                 render_config=None, device=None) -> np.ndarray:
    """Vertex colours ``[V, 3]`` float32 from ``source`` (:data:`SOURCES`): ``"gaussians"`` renders ``gaussians``
    from ``cameras``; ``"photos"`` samples ``photos`` (one image per camera)."""
    images = source_images(source, cameras, gaussians=gaussians, photos=photos, render_config=render_config)
    return colours_from_images(vertices, faces, cameras, images, device=device)


def to_uint8(colours: np.ndarray) -> np.ndarray:
    """Colours in ``[0, 1]`` → ``uint8`` (rounded)."""
    return np.round(np.clip(np.asarray(colours, np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def render_surface(vertices, faces, colour_at, camera: Camera, *, background=(0.0, 0.0, 0.0), device=None,
                   mesh: wp.Mesh | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Render a mesh whose colour ``colour_at(face [N], bary [N, 2]) -> [N, 3]`` (floats in ``[0, 1]``; Warp's
    barycentrics: the hit is ``u p0 + v p1 + (1 - u - v) p2``) gives at its first hits through ``camera``'s pixel
    centres: ``(rgb [H, W, 3] float32, hit [H, W] bool)``, missed pixels ``background``. ``mesh``: a ``wp.Mesh`` of
    the same vertices and faces, to reuse over views."""
    mesh = mesh if mesh is not None else _wp_mesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64),
                                                  warp_device(device))
    hits = _cast(mesh, camera)
    hit = hits["face"] >= 0
    rgb = np.empty((camera.height, camera.width, 3), np.float32)
    rgb[:] = np.asarray(background, np.float32)
    if hit.any():
        rgb[hit] = colour_at(hits["face"][hit], hits["bary"][hit])
    return rgb, hit


def render_vertex_colours(vertices, faces, colours, camera: Camera, *, background=(0.0, 0.0, 0.0), device=None,
                          mesh: wp.Mesh | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Render the vertex-coloured mesh at ``camera``'s pixel centres (:func:`render_surface`): a hit pixel
    interpolates its face's corner colours by the barycentrics of the hit."""
    f = np.asarray(faces, np.int64)
    c = np.asarray(colours)
    c = c.astype(np.float32) / 255.0 if c.dtype == np.uint8 else c.astype(np.float32)

    def colour_at(face, bary):
        fi = f[face]
        w0, w1 = bary[:, :1], bary[:, 1:2]
        return c[fi[:, 0]] * w0 + c[fi[:, 1]] * w1 + c[fi[:, 2]] * (1.0 - w0 - w1)

    return render_surface(vertices, f, colour_at, camera, background=background, device=device, mesh=mesh)


def mesh_render_psnr(vertices, faces, colours, cameras: Sequence[Camera], photos: Iterable, *,
                     background=(0.0, 0.0, 0.0), device=None) -> dict:
    """PSNR and SSIM of the vertex-coloured mesh (:func:`render_vertex_colours`) against ``photos`` (one
    ``[H, W, 3]`` image per camera, uint8 or float in ``[0, 1]``) from ``cameras``: :func:`render_fidelity`."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    mesh = _wp_mesh(v, f, warp_device(device))
    return render_fidelity(lambda cam: render_vertex_colours(v, f, colours, cam, background=background, mesh=mesh),
                           cameras, photos)


def render_fidelity(render_view, cameras: Sequence[Camera], photos: Iterable) -> dict:
    """PSNR and SSIM of ``render_view(camera) -> (rgb [H, W, 3] float32, hit [H, W] bool)`` against ``photos`` (one
    ``[H, W, 3]`` image per camera, uint8 or float in ``[0, 1]``), means over the views: ``{"psnr", "ssim"}`` over
    the whole image (missed pixels as rendered), ``{"psnr_masked", "ssim_masked"}`` over the hit pixels,
    ``"coverage"`` (hit fraction), ``"views"``."""
    import torch

    from ..eval.image_metrics import psnr, ssim

    rows = []
    for cam, photo in zip(cameras, photos):
        gt = _as_float_image(photo, cam)
        rgb, hit = render_view(cam)
        x = torch.from_numpy(np.ascontiguousarray(rgb, np.float32)).permute(2, 0, 1)
        y = torch.from_numpy(np.ascontiguousarray(gt)).permute(2, 0, 1)
        m = torch.from_numpy(hit.astype(np.float32))
        rows.append({"psnr": float(psnr(x, y)), "ssim": float(ssim(x, y)),
                     "psnr_masked": float(psnr(x, y, mask=m)) if hit.any() else float("nan"),
                     "ssim_masked": float(ssim(x, y, mask=m)) if hit.any() else float("nan"),
                     "coverage": float(hit.mean())})
    if not rows:
        raise GofError("mesh_render_psnr: no views")
    return {**{k: float(np.mean([r[k] for r in rows])) for k in rows[0]}, "views": len(rows)}
