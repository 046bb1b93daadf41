"""Textured meshes: a UV atlas (xatlas), a colour texture baked from the training photos or the Gaussians' renders,
and the textured mesh's fidelity to photos.

Data flow (``V``/``F``: the mesh's vertices/faces; ``S``: the texture side; ``N``: texels baked; ``K``: views kept
per texel):

1. :func:`make_atlas` (``vertices [V, 3]``, ``faces [F, 3]``, ``size``) → :class:`Atlas`: ``vmap [V']`` (atlas vertex
   → mesh vertex: xatlas splits vertices along chart seams), ``faces [F, 3]`` (atlas vertices, the mesh's faces in
   their order) and ``uv [V', 2]`` in ``[0, 1]``, glTF's convention (``u`` right, ``v`` down: texel ``(x, y)`` of
   the image's row ``y`` has its centre at ``((x + 0.5) / S, (y + 0.5) / S)``). xatlas runs in a child process
   where the OS can fork (a crash inside it becomes a :class:`GofError`).
2. :func:`rasterise_atlas` (Warp kernels): each face's UV triangle in texel space marks the texels whose centres it
   covers (``face [S, S]``, -1: none; a texel on a shared edge takes the largest face index); the ring of texels
   within :data:`RING` texels of a chart takes its nearest covered texel's face, so bilinear lookups at chart
   borders read colours of the surface, not of the background. Each baked texel gets the barycentrics of its
   centre in its face's UV triangle (extrapolated in the ring) → a 3D point and an interpolated vertex normal.
3. :func:`bake_texture`: per view (one image at a time), a Warp kernel projects the ``N`` texel points, keeps those
   :func:`gof_warp.mesh.colour.segment_unblocked` sees (the vertex colours' visibility rule: nothing of the mesh
   on the segment from the camera before its last ``depth_tol`` + ``depth_tol_px`` pixel footprints), weighs each
   by the view's sampling density there, ``|cos| (f / z)^2`` (frontal and close views first), samples the image
   bilinearly (only where its four pixels see the mesh at about its depth: no sample straddles a silhouette and
   takes in the background or another surface) and keeps the ``K`` heaviest views per texel (``[N, K]`` weights,
   views and colours). The same kernel on up to :data:`GAIN_PROBES` texels inside faces (:func:`gain_probes`) gives the exposure solve's
   samples.
4. Exposure (:func:`exposure_gains`): a gain per view and channel, ``c_iv ≈ g_v a_i`` by least squares over the
   probes seen by two or more views (in the logarithm, the ``a_i`` eliminated), normalised to median 1;
   each kept sample is divided by its view's gain before the weighted blend.
5. Fill: a baked texel no view sees takes the nearest seen texel's colour (in 3D); every other texel (the gutters
   and the unused atlas) takes the nearest baked texel's colour in texture space, so mipmaps do not bleed the
   background into the charts.

:func:`render_textured` ray casts the textured mesh (hit face + barycentrics → UV → bilinear texel lookup, a Warp
kernel) and :func:`textured_render_psnr` measures it against photos like
:func:`gof_warp.mesh.colour.mesh_render_psnr` (the same :func:`~gof_warp.mesh.colour.render_fidelity`).

Texture size (:func:`texture_side`): ``S = 4 ceil(sqrt(F * texels_per_face / ATLAS_FILL) / 4)`` clamped to
``[512, 8192]``: :data:`TEXELS_PER_FACE` texels per face once xatlas has filled about :data:`ATLAS_FILL` of the
square, a multiple of 4 (block-compressible). (xatlas's charts with their padding, scaled into the square, covered
38-47% of it on the built-in scene's meshes: about 10-12 texels per face in practice.)

Memory: the texture ``S^2 x 12`` B, the texel map ``S^2 x 4`` B and the fills' nearest-texel maps (scipy's
distance transform, ``S^2 x 16`` B while it runs); per baked texel ``K x 20 + 40`` B (kept views,
point, normal); per view one image (``H W x 12`` B) and ``N x 16`` B of samples; the mesh's ``wp.Mesh``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.arrays import check_triangles
from ..core.camera import Camera
from ..core.devices import warp_device
from ..core.errors import GofError
from .colour import (DEPTH_TOL, DEPTH_TOL_PX, UNSEEN_GREY, _as_float_image, _wp_mesh, render_fidelity,
                     render_surface, segment_unblocked, source_images, vertex_normals, visibility_tolerance)

log = logging.getLogger(__name__)

TEXELS_PER_FACE = 16
ATLAS_FILL = 0.6  # the fraction of the square xatlas's charts typically cover
MIN_SIDE = 512
MAX_SIDE = 8192
PADDING = 4  # texels between xatlas's charts
RING = 2.0  # texels around each chart baked from the surface (extrapolated barycentrics)
BEST_VIEWS = 4
EDGE_TOL_PX = 8.0  # silhouette test: pixel footprints of depth change allowed between a sample and its pixels
GAIN_RANGE = (0.25, 4.0)
GAIN_PROBES = 20_000  # texels whose samples solve the exposure gains
INSTALL_HINT = "pip install gof-warp[texture]"


def _xatlas():
    try:
        import xatlas
    except ImportError as e:
        raise GofError(f"textured meshes need xatlas for the UV atlas: {INSTALL_HINT} (or pip install xatlas)") from e
    return xatlas


def texture_side(n_faces: int, texels_per_face: float = TEXELS_PER_FACE) -> int:
    """The texture side for a mesh of ``n_faces`` faces (module docstring): a multiple of 4 in
    ``[MIN_SIDE, MAX_SIDE]``."""
    side = 4 * int(np.ceil(np.sqrt(max(int(n_faces), 1) * float(texels_per_face) / ATLAS_FILL) / 4.0))
    return int(min(max(side, MIN_SIDE), MAX_SIDE))


def check_side(size: int) -> int:
    """``size`` as a texture side: an integer in ``[16, MAX_SIDE]``, else a :class:`GofError`."""
    if int(size) != size or not 16 <= int(size) <= MAX_SIDE:
        raise GofError(f"texture size must be an integer in [16, {MAX_SIDE}], got {size}")
    return int(size)


@dataclass
class Atlas:
    """A mesh's UV atlas: ``vmap [V']`` int64 (atlas vertex → mesh vertex), ``faces [F, 3]`` int64 (atlas vertex
    indices, face ``i`` is the mesh's face ``i``), ``uv [V', 2]`` float32 in ``[0, 1]`` (glTF convention, module
    docstring), ``size`` (the texture side it was packed for)."""

    vmap: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    size: int


@dataclass
class TexturedMesh:
    """A textured mesh: ``vertices [V', 3]`` float32 (the atlas's: mesh vertices split at seams), ``faces [F, 3]``
    int64, ``uv [V', 2]`` float32 (glTF convention: ``v`` down, row 0 at the top), ``texture [S, S, 3]`` float32 in
    ``[0, 1]``, ``vmap [V']`` (atlas vertex → input mesh vertex) and ``info`` (what the bake measured)."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    vmap: np.ndarray
    info: dict

    def uv_up(self) -> np.ndarray:
        """``uv`` in the OpenGL / OBJ / USD convention, ``v`` up (``(0, 0)`` at the image's bottom-left): ``[V', 2]``
        float64."""
        uv = np.asarray(self.uv, np.float64)
        return np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1)

    def texture_uint8(self) -> np.ndarray:
        """The texture as ``[S, S, 3]`` uint8 (rounded)."""
        return np.round(np.clip(self.texture, 0.0, 1.0) * 255.0).astype(np.uint8)

    def vertex_colours(self) -> np.ndarray:
        """The texture sampled at each input mesh vertex ``[V, 3]`` float32 (a vertex split at a seam: its
        first atlas copy)."""
        n = int(self.vmap.max()) + 1 if len(self.vmap) else 0
        first = np.full(n, -1, np.int64)
        first[self.vmap[::-1]] = np.arange(len(self.vmap))[::-1]
        return sample_texture_np(self.texture, self.uv[first]).astype(np.float32)


def _run_xatlas(vertices: np.ndarray, faces: np.ndarray, size: int, padding: int):
    xatlas = _xatlas()
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = int(size)
    pack.padding = int(padding)
    pack.bilinear = True
    atlas.generate(xatlas.ChartOptions(), pack)
    vmap, idx, uv = atlas.get_mesh(0)
    return (np.asarray(vmap, np.int64), np.asarray(idx, np.int64).reshape(-1, 3), np.asarray(uv, np.float64),
            int(atlas.width), int(atlas.height), int(atlas.atlas_count), int(atlas.chart_count))


def _xatlas_child(conn, vertices, faces, size, padding):
    try:
        conn.send(("ok", _run_xatlas(vertices, faces, size, padding)))
    except BaseException as e:  # noqa: BLE001 - handed to the parent, which raises it as a GofError
        conn.send(("error", f"{type(e).__name__}: {e}"))
    finally:
        conn.close()


def _xatlas_isolated(vertices, faces, size, padding):
    """:func:`_run_xatlas` in a forked child where the OS can fork (xatlas can crash on some meshes: the crash is
    a :class:`GofError` here, not the end of the process), else in this process."""
    import multiprocessing as mp

    _xatlas()  # a missing package: the clear error, here
    if "fork" not in mp.get_all_start_methods():
        return _run_xatlas(vertices, faces, size, padding)
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_xatlas_child, args=(child, vertices, faces, size, padding), daemon=True)
    proc.start()
    child.close()
    try:
        status, payload = parent.recv()
    except EOFError:
        status, payload = "crash", None
    proc.join()
    if status == "ok":
        return payload
    why = payload if status == "error" else f"the xatlas process ended with exit code {proc.exitcode}"
    raise GofError(f"UV atlas of a mesh of {len(faces)} faces failed ({why}); a decimated mesh (--max-faces) may "
                   "unwrap")


def make_atlas(vertices, faces, size: int, *, padding: int = PADDING) -> Atlas:
    """The UV atlas of ``vertices [V, 3]``, ``faces [F, 3]`` packed by xatlas for a ``size`` x ``size`` texture
    with ``padding`` texels between charts. xatlas's own atlas may come out a little larger or smaller than asked:
    its pixel coordinates are scaled by ``size / max(width, height)`` so the charts fill the square (their shapes
    kept)."""
    size = check_side(size)
    v, f = check_triangles(vertices, np.asarray(faces, np.int64), "UV atlas", GofError)
    if not len(f):
        raise GofError("UV atlas: the mesh has no faces")
    vmap, idx, uv, width, height, n_atlases, n_charts = _xatlas_isolated(np.asarray(v, np.float32), f, size, padding)
    if n_atlases != 1 or len(idx) != len(f) or not np.array_equal(vmap[idx], f):
        raise GofError(f"UV atlas: xatlas made {n_atlases} atlases and {len(idx)} faces for {len(f)} faces (expected "
                       "one atlas, the faces in order)")
    px = uv * np.array([width, height], np.float64)
    scale = 1.0 / max(width, height)
    log.info("UV atlas: %d charts, xatlas %d x %d for %d x %d", n_charts, width, height, size, size)
    return Atlas(vmap=vmap, faces=idx, uv=(px * scale).astype(np.float32), size=size)


# --------------------------------------------------------------------------------------------------------------
# Warp kernels


@wp.func
def bilinear(image: wp.array2d(dtype=wp.vec3), x: float, y: float) -> wp.vec3:
    """``image [H, W]`` at continuous pixel coordinates ``(x, y)`` (pixel ``(i, j)``'s centre at
    ``(i + 0.5, j + 0.5)``), clamped at the edges: the rule of :func:`gof_warp.mesh.colour._bilinear`."""
    h = image.shape[0]
    w = image.shape[1]
    xf = wp.clamp(x - 0.5, 0.0, float(w - 1))
    yf = wp.clamp(y - 0.5, 0.0, float(h - 1))
    x0 = wp.min(int(wp.floor(xf)), w - 1)
    y0 = wp.min(int(wp.floor(yf)), h - 1)
    x1 = wp.min(x0 + 1, w - 1)
    y1 = wp.min(y0 + 1, h - 1)
    fx = xf - float(x0)
    fy = yf - float(y0)
    top = image[y0, x0] * (1.0 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1.0 - fx) + image[y1, x1] * fx
    return top * (1.0 - fy) + bottom * fy


@wp.func
def _uv_barycentric(p: wp.vec2, a: wp.vec2, b: wp.vec2, c: wp.vec2) -> wp.vec3:
    """Barycentrics of ``p`` in the triangle ``a b c`` (``(0, 0, 0)`` when it has no area)."""
    e1 = b - a
    e2 = c - a
    q = p - a
    det = e1[0] * e2[1] - e1[1] * e2[0]
    if det == 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    l1 = (q[0] * e2[1] - q[1] * e2[0]) / det
    l2 = (e1[0] * q[1] - e1[1] * q[0]) / det
    return wp.vec3(1.0 - l1 - l2, l1, l2)


@wp.kernel
def _rasterise_faces(uv_px: wp.array(dtype=wp.vec2), faces: wp.array2d(dtype=wp.int32),
                     face_map: wp.array2d(dtype=wp.int32)):
    """Face ``f`` writes itself (atomic max: the largest index wins a shared texel) into every texel of
    ``face_map [S, S]`` whose centre its texel-space triangle covers (barycentrics ``>= -1e-6``)."""
    f = wp.tid()
    a = uv_px[faces[f, 0]]
    b = uv_px[faces[f, 1]]
    c = uv_px[faces[f, 2]]
    h = face_map.shape[0]
    w = face_map.shape[1]
    x_lo = wp.max(int(wp.floor(wp.min(wp.min(a[0], b[0]), c[0]) - 0.5)), 0)
    x_hi = wp.min(int(wp.ceil(wp.max(wp.max(a[0], b[0]), c[0]) - 0.5)), w - 1)
    y_lo = wp.max(int(wp.floor(wp.min(wp.min(a[1], b[1]), c[1]) - 0.5)), 0)
    y_hi = wp.min(int(wp.ceil(wp.max(wp.max(a[1], b[1]), c[1]) - 0.5)), h - 1)
    for y in range(y_lo, y_hi + 1):
        for x in range(x_lo, x_hi + 1):
            lam = _uv_barycentric(wp.vec2(float(x) + 0.5, float(y) + 0.5), a, b, c)
            if lam[0] + lam[1] + lam[2] > 0.5 and lam[0] >= -1.0e-6 and lam[1] >= -1.0e-6 and lam[2] >= -1.0e-6:
                wp.atomic_max(face_map, y, x, f)


@wp.kernel
def _texel_points(texel_xy: wp.array(dtype=wp.vec2i), texel_face: wp.array(dtype=wp.int32),
                  uv_px: wp.array(dtype=wp.vec2), faces: wp.array2d(dtype=wp.int32),
                  positions: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                  bary: wp.array(dtype=wp.vec3), points: wp.array(dtype=wp.vec3), texel_normals: wp.array(dtype=wp.vec3)):
    """Texel ``i`` at ``texel_xy[i]`` (column, row) of face ``texel_face[i]``: its centre's barycentrics in the face's
    texel-space triangle (extrapolated outside it), the 3D point and the interpolated normal there."""
    i = wp.tid()
    f = texel_face[i]
    xy = texel_xy[i]
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    lam = _uv_barycentric(wp.vec2(float(xy[0]) + 0.5, float(xy[1]) + 0.5), uv_px[i0], uv_px[i1], uv_px[i2])
    if lam[0] + lam[1] + lam[2] < 0.5:  # a face of no area in the atlas: its centroid
        lam = wp.vec3(1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)
    bary[i] = lam
    points[i] = positions[i0] * lam[0] + positions[i1] * lam[1] + positions[i2] * lam[2]
    texel_normals[i] = normals[i0] * lam[0] + normals[i1] * lam[1] + normals[i2] * lam[2]


@wp.kernel
def _view_samples(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                  rot: wp.mat33, trans: wp.vec3, origin: wp.vec3, fx: float, fy: float, cx: float, cy: float,
                  rel_tol: float, image: wp.array2d(dtype=wp.vec3), depth: wp.array2d(dtype=float), edge_tol: float,
                  weight: wp.array(dtype=float), colour: wp.array(dtype=wp.vec3)):
    """Point ``i`` in one view: ``weight[i] = |cos| (f / z)^2`` (cosine between its normal and the ray, 1 for a zero
    normal; ``f = sqrt(fx fy)``) and ``colour[i]`` = the image there, when the point projects into the image in
    front of the camera, :func:`segment_unblocked` from the camera, and the four pixels its bilinear sample reads
    all see the mesh at a depth within ``edge_tol z`` of its own (``depth [H, W]``: the mesh's ray-cast depth at the
    pixel centres, 0: none), so no sample straddles a silhouette; else weight 0."""
    i = wp.tid()
    weight[i] = 0.0
    colour[i] = wp.vec3(0.0, 0.0, 0.0)
    p = points[i]
    q = rot * p + trans
    if q[2] <= 0.0:
        return
    u = fx * q[0] / q[2] + cx
    v = fy * q[1] / q[2] + cy
    if u < 0.0 or v < 0.0 or u >= float(image.shape[1]) or v >= float(image.shape[0]):
        return
    if not segment_unblocked(mesh, origin, p, rel_tol):
        return
    h = depth.shape[0]
    w = depth.shape[1]
    x0 = wp.min(int(wp.floor(wp.clamp(u - 0.5, 0.0, float(w - 1)))), w - 1)
    y0 = wp.min(int(wp.floor(wp.clamp(v - 0.5, 0.0, float(h - 1)))), h - 1)
    x1 = wp.min(x0 + 1, w - 1)
    y1 = wp.min(y0 + 1, h - 1)
    tol = edge_tol * q[2]
    if wp.abs(depth[y0, x0] - q[2]) > tol or wp.abs(depth[y0, x1] - q[2]) > tol:
        return
    if wp.abs(depth[y1, x0] - q[2]) > tol or wp.abs(depth[y1, x1] - q[2]) > tol:
        return
    n = normals[i]
    cos = float(1.0)
    if wp.length(n) > 0.0:
        cos = wp.abs(wp.dot(wp.normalize(p - origin), wp.normalize(n)))
    density = wp.sqrt(fx * fy) / q[2]
    weight[i] = cos * density * density
    colour[i] = bilinear(image, u, v)


@wp.kernel
def _keep_best(weight: wp.array(dtype=float), colour: wp.array(dtype=wp.vec3), view: int,
               best_w: wp.array2d(dtype=float), best_c: wp.array2d(dtype=wp.vec3), best_v: wp.array2d(dtype=wp.int32)):
    """Texel ``i`` keeps view ``view``'s sample when it outweighs the lightest of the ``K`` kept (ties: the earlier
    view stays)."""
    i = wp.tid()
    w = weight[i]
    if w <= 0.0:
        return
    k = best_w.shape[1]
    slot = int(0)
    lightest = best_w[i, 0]
    for s in range(1, k):
        if best_w[i, s] < lightest:
            lightest = best_w[i, s]
            slot = s
    if w > lightest:
        best_w[i, slot] = w
        best_c[i, slot] = colour[i]
        best_v[i, slot] = view


@wp.kernel
def _blend(best_w: wp.array2d(dtype=float), best_c: wp.array2d(dtype=wp.vec3), best_v: wp.array2d(dtype=wp.int32),
           gains: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3), total: wp.array(dtype=float)):
    """``out[i]`` = the weighted mean of texel ``i``'s kept samples, each divided (per channel) by its view's gain;
    ``total[i]`` = their weight (0: no view saw it)."""
    i = wp.tid()
    acc = wp.vec3(0.0, 0.0, 0.0)
    wsum = float(0.0)
    for s in range(best_w.shape[1]):
        w = best_w[i, s]
        if w > 0.0:
            g = gains[best_v[i, s]]
            c = best_c[i, s]
            acc = acc + w * wp.vec3(c[0] / g[0], c[1] / g[1], c[2] / g[2])
            wsum = wsum + w
    total[i] = wsum
    if wsum > 0.0:
        out[i] = acc / wsum
    else:
        out[i] = wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def _lookup(face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec2), faces: wp.array2d(dtype=wp.int32),
            uv: wp.array(dtype=wp.vec2), texture: wp.array2d(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    """Hit ``i`` on face ``face[i]`` at Warp's barycentrics ``bary[i] = (b0, b1)`` (corner 2: ``1 - b0 - b1``): the
    interpolated UV (glTF convention) looked up bilinearly in ``texture [S, S]``."""
    i = wp.tid()
    f = face[i]
    b = bary[i]
    t = uv[faces[f, 0]] * b[0] + uv[faces[f, 1]] * b[1] + uv[faces[f, 2]] * (1.0 - b[0] - b[1])
    out[i] = bilinear(texture, t[0] * float(texture.shape[1]), t[1] * float(texture.shape[0]))


# --------------------------------------------------------------------------------------------------------------
# numpy references of the lookups (also used on the host)


def sample_texture_np(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``texture [S, S, C]`` at ``uv [N, 2]`` (glTF convention), bilinear with clamped edges, float64 ``[N, C]``."""
    from .colour import _bilinear

    t = np.asarray(texture, np.float64)
    uv = np.asarray(uv, np.float64)
    return _bilinear(t, uv[:, 0] * t.shape[1], uv[:, 1] * t.shape[0])


# --------------------------------------------------------------------------------------------------------------
# atlas rasterisation and baking


@dataclass
class Texels:
    """The texels :func:`rasterise_atlas` bakes: ``xy [N, 2]`` int32 (column, row), ``face [N]`` int32, ``bary [N, 3]``
    float32, ``points [N, 3]`` and ``normals [N, 3]`` float32; ``covered [N]`` bool (the centre lies on its face,
    not in the ring); ``face_map [S, S]`` int32 (-1: no face covers the texel's centre)."""

    xy: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    covered: np.ndarray
    face_map: np.ndarray


def rasterise_atlas(vertices, faces, atlas: Atlas, *, ring: float = RING, device=None) -> Texels:
    """The texels of ``atlas`` to bake (module docstring, step 2) for the mesh ``vertices [V, 3]``, ``faces [F, 3]``
    (the mesh the atlas was made of)."""
    from scipy.ndimage import distance_transform_edt

    dev = warp_device(device)
    size = atlas.size
    v = np.asarray(vertices, np.float64)
    f_mesh = np.asarray(faces, np.int64)
    uv_px = wp.array((atlas.uv * size).astype(np.float32), dtype=wp.vec2, device=dev)
    f_atlas = wp.array(atlas.faces.astype(np.int32), dtype=wp.int32, device=dev)
    face_map = wp.full((size, size), -1, dtype=wp.int32, device=dev)
    wp.launch(_rasterise_faces, dim=len(atlas.faces), inputs=[uv_px, f_atlas, face_map], device=dev)
    fmap = face_map.numpy()
    covered_map = fmap >= 0
    if not covered_map.any():
        raise GofError("texture: no texel centre falls inside any face of the atlas (texture too small?)")
    dist, (iy, ix) = distance_transform_edt(~covered_map, return_indices=True)
    bake_map = covered_map | (dist <= ring)
    ys, xs = np.nonzero(bake_map)
    face = fmap[iy[ys, xs], ix[ys, xs]]
    n = len(ys)
    pos = v[atlas.vmap].astype(np.float32)
    nrm = vertex_normals(v, f_mesh)[atlas.vmap].astype(np.float32)
    out_b = wp.empty(n, dtype=wp.vec3, device=dev)
    out_p = wp.empty(n, dtype=wp.vec3, device=dev)
    out_n = wp.empty(n, dtype=wp.vec3, device=dev)
    xy = np.stack([xs, ys], 1).astype(np.int32)
    wp.launch(_texel_points, dim=n, inputs=[wp.array(xy, dtype=wp.vec2i, device=dev),
                                            wp.array(face.astype(np.int32), dtype=wp.int32, device=dev), uv_px,
                                            f_atlas, wp.array(pos, dtype=wp.vec3, device=dev),
                                            wp.array(nrm, dtype=wp.vec3, device=dev), out_b, out_p, out_n], device=dev)
    return Texels(xy=xy, face=face.astype(np.int32), bary=out_b.numpy(), points=out_p.numpy(), normals=out_n.numpy(),
                  covered=covered_map[ys, xs], face_map=fmap)


def exposure_gains(samples: list, n_views: int, *, rounds: int = 3, min_views: int = 2) -> np.ndarray:
    """Per-view, per-channel gains ``[n_views, 3]`` float64 (median 1 over the views with samples, so the majority's
    exposure sets the scale; 1 for the others) that best explain ``c_iv = g_v a_i`` over the points seen by at least
    ``min_views`` views: weighted least squares in the logarithm, ``log c_iv = log g_v + log a_i``, solved exactly by
    eliminating the ``a_i`` (an ``n_views x n_views`` system per channel). Samples that fit badly (a point on a
    silhouette whose sample takes in the background; a highlight) are left out of the next of ``rounds`` solves:
    a relative residual above ``max(0.05, 3 x`` the median one).

    Args:
        samples: one ``(view, point_index [M] int, colour [M, 3], weight [M])`` per view that saw points.
        n_views: the number of views.
    """
    from scipy.sparse import csr_matrix

    gains = np.ones((n_views, 3), np.float64)
    if not samples:
        return gains
    view = np.concatenate([np.full(len(s[1]), s[0], np.int64) for s in samples])
    point = np.concatenate([np.asarray(s[1], np.int64) for s in samples])
    colour = np.concatenate([np.asarray(s[2], np.float64) for s in samples])
    weight = np.concatenate([np.asarray(s[3], np.float64) for s in samples])
    keep = (colour.min(1) > 1.0 / 255.0) & (colour.max(1) < 254.0 / 255.0)  # clipped samples say nothing of gain
    view, point, colour, weight = view[keep], point[keep], colour[keep], weight[keep]
    if not len(view):
        return gains
    weight = weight / weight.mean()
    y = np.log(colour)
    n_points = int(point.max()) + 1
    inlier = np.ones(len(view), bool)
    for _ in range(rounds):
        inlier &= np.bincount(point[inlier], minlength=n_points)[point] >= min_views
        if not inlier.any():
            break
        vi, pi, wi = view[inlier], point[inlier], weight[inlier]
        w_pt = np.bincount(pi, wi, n_points)
        a_mat = csr_matrix((wi, (pi, vi)), shape=(n_points, n_views))  # w_iv
        scaled = csr_matrix((wi / w_pt[pi], (pi, vi)), shape=(n_points, n_views))
        lap = np.diag(np.bincount(vi, wi, n_views)) - (a_mat.T @ scaled).toarray()
        has = np.bincount(vi, minlength=n_views) > 0
        log_g = np.zeros((n_views, 3))
        for ch in range(3):
            yc = y[inlier, ch]
            ybar = np.bincount(pi, wi * yc, n_points) / np.maximum(w_pt, 1e-30)
            rhs = np.bincount(vi, wi * (yc - ybar[pi]), n_views)
            log_g[:, ch] = np.linalg.lstsq(lap, rhs, rcond=None)[0]
        log_g[has] -= np.median(log_g[has], axis=0)
        log_g[~has] = 0.0
        gains = np.exp(np.clip(log_g, *np.log(GAIN_RANGE)))
        log_a = np.zeros((n_points, 3))
        for ch in range(3):
            log_a[:, ch] = np.bincount(pi, wi * (y[inlier, ch] - np.log(gains[vi, ch])), n_points) / np.maximum(
                w_pt, 1e-30)
        model = gains[view] * np.exp(log_a[point])
        resid = (np.abs(colour - model) / np.maximum(model, 1e-3)).max(1)
        inlier = resid <= max(0.05, 3.0 * float(np.median(resid[inlier])))
    return gains


def edge_tolerance(camera: Camera, depth_tol: float = DEPTH_TOL, edge_tol_px: float = EDGE_TOL_PX) -> float:
    """The silhouette test's relative depth tolerance for ``camera``: ``depth_tol`` plus ``edge_tol_px`` pixel
    footprints (``1 / f``): a sloped surface's depth changes by ``tan(angle) / f`` of itself per pixel."""
    return depth_tol + edge_tol_px / min(camera.fx, camera.fy)


def gain_probes(texels: Texels, count: int = GAIN_PROBES, margin: float = 0.1) -> np.ndarray:
    """Indices of the texels whose samples solve the exposure gains: covered texels whose centre lies at least
    ``margin`` (barycentric) inside its face, so off the mesh's edges (where a silhouette's bilinear sample takes in
    the background), evenly strided down to at most ``count``."""
    idx = np.flatnonzero(texels.covered & (texels.bary.min(1) >= margin))
    if not len(idx):
        idx = np.flatnonzero(texels.covered)
    return idx[:: max(1, -(-len(idx) // int(count)))]


def bake_texture(vertices, faces, cameras: Sequence[Camera], images: Iterable, *, size: int | None = None,
                 atlas: Atlas | None = None, best_views: int = BEST_VIEWS, exposure: bool = True,
                 depth_tol: float = DEPTH_TOL, depth_tol_px: float = DEPTH_TOL_PX, edge_tol_px: float = EDGE_TOL_PX,
                 device=None) -> TexturedMesh:
    """The textured mesh of ``vertices [V, 3]``, ``faces [F, 3]`` from ``images`` seen by ``cameras`` (module
    docstring).

    Args:
        cameras: one :class:`Camera` per image.
        images: an iterable of ``[H, W, 3]`` images (uint8, or float in ``[0, 1]``; numpy or torch), one per camera,
            consumed one at a time.
        size: the texture side (default :func:`texture_side` of the face count); ignored when ``atlas`` is given.
        atlas: a ready :class:`Atlas` of this mesh (default: :func:`make_atlas`).
        best_views: ``K``, the heaviest views blended per texel.
        exposure: divide each view's samples by its :func:`exposure_gains` (False: gains of 1).
        depth_tol, depth_tol_px: the visibility rule's tolerances (:mod:`gof_warp.mesh.colour`).
        edge_tol_px: the silhouette test's depth tolerance (:func:`edge_tolerance`).
        device: Warp device (default: CUDA if present, else the CPU).

    ``info`` of the result: ``size``, ``atlas_vertices`` (``V'``), ``texels`` (covered by a face), ``ring_texels``,
    ``unseen_texels``, ``charts_fill`` (covered fraction of the square), ``views``, ``best_views``, ``exposure``,
    ``gains [n_views, 3]`` (a list).
    """
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial import cKDTree

    from ..kernels import raycast

    v, f = check_triangles(vertices, np.asarray(faces, np.int64), "texture", GofError)
    v = np.asarray(v, np.float64)
    if not len(f):
        raise GofError("texture: the mesh has no faces")
    if int(best_views) < 1:
        raise GofError(f"texture: best_views must be >= 1, got {best_views}")
    cams = list(cameras)
    dev = warp_device(device)
    if atlas is None:
        atlas = make_atlas(v, f, texture_side(len(f)) if size is None else size)
    texels = rasterise_atlas(v, f, atlas, device=dev)
    n = len(texels.xy)
    k = int(best_views)
    mesh = _wp_mesh(v, f, dev)
    t_points = wp.array(texels.points, dtype=wp.vec3, device=dev)
    t_normals = wp.array(texels.normals, dtype=wp.vec3, device=dev)
    probe = gain_probes(texels)
    v_points = wp.array(texels.points[probe], dtype=wp.vec3, device=dev)
    v_normals = wp.array(texels.normals[probe], dtype=wp.vec3, device=dev)
    best_w = wp.zeros((n, k), dtype=float, device=dev)
    best_c = wp.zeros((n, k), dtype=wp.vec3, device=dev)
    best_v = wp.zeros((n, k), dtype=wp.int32, device=dev)
    weight = wp.empty(n, dtype=float, device=dev)
    colour = wp.empty(n, dtype=wp.vec3, device=dev)
    v_weight = wp.empty(len(probe), dtype=float, device=dev)
    v_colour = wp.empty(len(probe), dtype=wp.vec3, device=dev)
    samples = []
    n_images = 0
    for view, (cam, image) in enumerate(zip(cams, images)):
        n_images += 1
        img = wp.array(np.ascontiguousarray(_as_float_image(image, cam)), dtype=wp.vec3, device=dev)
        zmap = raycast.cast_pinhole_rays(mesh, cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                                         1)["depth"]
        args = [wp.mat33(*np.asarray(cam.R, np.float32).ravel()), wp.vec3(*np.asarray(cam.t, np.float32)),
                wp.vec3(*np.asarray(cam.center, np.float32)), float(cam.fx), float(cam.fy), float(cam.cx),
                float(cam.cy), float(visibility_tolerance(cam, depth_tol, depth_tol_px)), img, zmap,
                float(edge_tolerance(cam, depth_tol, edge_tol_px))]
        wp.launch(_view_samples, dim=n, inputs=[mesh.id, t_points, t_normals, *args, weight, colour], device=dev)
        wp.launch(_keep_best, dim=n, inputs=[weight, colour, view, best_w, best_c, best_v], device=dev)
        if exposure:
            wp.launch(_view_samples, dim=len(probe), inputs=[mesh.id, v_points, v_normals, *args, v_weight, v_colour],
                      device=dev)
            w_np = v_weight.numpy()
            idx = np.flatnonzero(w_np > 0)
            if len(idx):
                samples.append((view, idx, v_colour.numpy()[idx], w_np[idx]))
    if n_images != len(cams):
        raise GofError(f"texture: {len(cams)} cameras but {n_images} images")
    gains = exposure_gains(samples, len(cams)) if exposure else np.ones((len(cams), 3))
    out = wp.empty(n, dtype=wp.vec3, device=dev)
    total = wp.empty(n, dtype=float, device=dev)
    wp.launch(_blend, dim=n, inputs=[best_w, best_c, best_v,
                                     wp.array(np.maximum(gains, 1e-6).astype(np.float32), dtype=wp.vec3, device=dev),
                                     out, total], device=dev)
    rgb = out.numpy().astype(np.float64)
    seen = total.numpy() > 0
    if seen.any() and not seen.all():
        _, nearest = cKDTree(texels.points[seen]).query(texels.points[~seen])
        rgb[~seen] = rgb[seen][nearest]
    elif not seen.any():
        rgb[:] = UNSEEN_GREY
    size = atlas.size
    tex = np.zeros((size, size, 3), np.float32)
    baked = np.zeros((size, size), bool)
    tex[texels.xy[:, 1], texels.xy[:, 0]] = rgb
    baked[texels.xy[:, 1], texels.xy[:, 0]] = True
    _, (iy, ix) = distance_transform_edt(~baked, return_indices=True)
    tex = tex[iy, ix]  # every texel off the charts: its nearest baked texel's colour
    n_unseen = int((~seen & texels.covered).sum())
    if n_unseen:
        log.info("texture: %d of %d texels seen by no view take the nearest seen texel's colour", n_unseen,
                 int(texels.covered.sum()))
    info = {"size": size, "atlas_vertices": int(len(atlas.vmap)), "texels": int(texels.covered.sum()), "ring_texels": int((~texels.covered).sum()),
            "unseen_texels": n_unseen, "charts_fill": round(float(texels.covered.sum()) / size**2, 4),
            "views": len(cams), "best_views": k, "exposure": bool(exposure), "gains": gains.round(5).tolist()}
    return TexturedMesh(vertices=v[atlas.vmap].astype(np.float32), faces=atlas.faces, uv=atlas.uv,
                        texture=np.clip(tex, 0.0, 1.0).astype(np.float32), vmap=atlas.vmap, info=info)


def mesh_texture(source: str, vertices, faces, cameras: Sequence[Camera], *, gaussians=None, photos=None,
                 render_config=None, size: int | None = None, device=None, **kwargs) -> TexturedMesh:
    """:func:`bake_texture` from a colour ``source`` (:data:`gof_warp.mesh.colour.SOURCES`): ``"gaussians"`` renders
    ``gaussians`` from ``cameras``, ``"photos"`` takes ``photos`` (one image per camera)."""
    images = source_images(source, cameras, gaussians=gaussians, photos=photos, render_config=render_config,
                           what="texture")
    return bake_texture(vertices, faces, cameras, images, size=size, device=device, **kwargs)


# --------------------------------------------------------------------------------------------------------------
# rendering and fidelity


def render_textured(textured: TexturedMesh, camera: Camera, *, background=(0.0, 0.0, 0.0), device=None,
                    mesh: wp.Mesh | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Render ``textured`` at ``camera``'s pixel centres: ``(rgb [H, W, 3] float32, hit [H, W] bool)``; a hit pixel
    interpolates its face's corner UVs by the hit's barycentrics and looks the texture up bilinearly, a missed one
    is ``background``. ``mesh``: a ``wp.Mesh`` of ``textured``'s vertices and faces, to reuse over views."""
    dev = mesh.device if mesh is not None else warp_device(device)
    mesh = mesh if mesh is not None else _wp_mesh(textured.vertices, textured.faces, dev)

    def colour_at(face, bary):  # the texture's bilinear lookup at the hits' interpolated UVs, in a Warp kernel
        out = wp.empty(len(face), dtype=wp.vec3, device=dev)
        wp.launch(_lookup, dim=len(face), inputs=[
            wp.array(np.asarray(face, np.int32), dtype=wp.int32, device=dev),
            wp.array(np.asarray(bary, np.float32), dtype=wp.vec2, device=dev),
            wp.array(np.asarray(textured.faces, np.int32), dtype=wp.int32, device=dev),
            wp.array(np.asarray(textured.uv, np.float32), dtype=wp.vec2, device=dev),
            wp.array(np.ascontiguousarray(textured.texture, np.float32), dtype=wp.vec3, device=dev), out], device=dev)
        return out.numpy()

    return render_surface(textured.vertices, textured.faces, colour_at, camera, background=background, mesh=mesh)


def textured_render_psnr(textured: TexturedMesh, cameras: Sequence[Camera], photos: Iterable, *,
                         background=(0.0, 0.0, 0.0), device=None) -> dict:
    """PSNR and SSIM of the textured mesh (:func:`render_textured`) against ``photos`` from ``cameras``:
    :func:`gof_warp.mesh.colour.render_fidelity` (whole image and covered pixels, coverage, views)."""
    mesh = _wp_mesh(textured.vertices, textured.faces, warp_device(device))
    return render_fidelity(lambda cam: render_textured(textured, cam, background=background, mesh=mesh), cameras,
                           photos)
