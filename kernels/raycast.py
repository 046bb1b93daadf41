"""Ray casting of textured triangle meshes with pinhole cameras (synthetic scenes with exact ground truth).

Pure Warp (+ numpy on the host side). Two kernels, each with a host function that launches it:

* :func:`cast_pinhole_rays` — one ray per sample of a pinhole camera against a ``wp.Mesh`` (BVH
  query ``wp.mesh_query_ray``). Returns per sample the hit face, barycentrics, camera ``z``-depth and the
  geometric world normal.
* :func:`shade_hits` — albedo (image texture through per-corner UVs, or procedural 3D noise/checker of
  the world position, or a constant) times view-independent Lambertian lighting (directional lights +
  ambient), so that a degree-0 SH colour per surface point can fit it exactly.

Camera conventions are those of ``gof_warp.core.camera`` (OpenCV axes, world-to-camera ``x_c = R x + t``).
With ``s`` samples per pixel axis, sample ``(col, row)`` of the ``[H*s, W*s]`` grid sits at the
continuous pixel coordinate ``((col + 0.5) / s, (row + 0.5) / s)``; ``s = 1`` gives the pixel centres
``(i + 0.5, j + 0.5)``. Its camera-space ray is ``((u - cx) / fx, (v - cy) / fy, 1)``, so the ray
parameter ``t`` is camera-space depth ``z``.

Barycentrics follow Warp: a hit on face ``f`` with vertices ``p0, p1, p2`` is
``p0 * b.x + p1 * b.y + p2 * (1 - b.x - b.y)``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

# Material kinds (``mat_kind`` entries).
MAT_CONSTANT = wp.constant(0)  # albedo = colour_a
MAT_TEXTURE = wp.constant(1)  # albedo = colour_a * texture(uv), bilinear, repeat addressing, OBJ uv (v up)
MAT_PROCEDURAL = wp.constant(2)  # per-channel fBm noise between colour_a and colour_b, times an optional 3D checker

_FBM_OCTAVES = wp.constant(3)


@wp.func
def _fbm(state: wp.uint32, x: wp.vec3) -> float:
    """Fractal Perlin noise (3 octaves), roughly in [-1, 1]."""
    total = float(0.0)
    amp = float(1.0)
    freq = float(1.0)
    for _k in range(_FBM_OCTAVES):
        total += amp * wp.noise(state, x * freq)
        amp *= 0.5
        freq *= 2.0
    return total


@wp.func
def _texel(tex: wp.array3d(dtype=wp.vec3), layer: int, ix: int, iy: int) -> wp.vec3:
    h = tex.shape[1]
    w = tex.shape[2]
    return tex[layer, ((iy % h) + h) % h, ((ix % w) + w) % w]


@wp.func
def sample_texture_bilinear(tex: wp.array3d(dtype=wp.vec3), layer: int, uv: wp.vec2) -> wp.vec3:
    """Bilinear lookup with repeat addressing. ``uv`` in OBJ convention: ``(0, 0)`` is the bottom-left
    corner of the image, texel centres at ``(i + 0.5) / W``."""
    h = float(tex.shape[1])
    w = float(tex.shape[2])
    x = uv[0] * w - 0.5
    y = (1.0 - uv[1]) * h - 0.5
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    ix = int(x0)
    iy = int(y0)
    top = _texel(tex, layer, ix, iy) * (1.0 - fx) + _texel(tex, layer, ix + 1, iy) * fx
    bottom = _texel(tex, layer, ix, iy + 1) * (1.0 - fx) + _texel(tex, layer, ix + 1, iy + 1) * fx
    return top * (1.0 - fy) + bottom * fy


@wp.func
def procedural_albedo(
    seed: int, material: int, x: wp.vec3, color_a: wp.vec3, color_b: wp.vec3, params: wp.vec4
) -> wp.vec3:
    """Per-channel fBm of the world position mixed between two colours, times a 3D checker.

    ``params = (noise_scale, checker_scale, checker_strength, unused)``: noise features per world unit,
    checker squares per world unit (0 = none), and how dark the dark squares are (0..1).
    """
    p = x * params[0]
    mix = wp.vec3(0.0)
    for c in range(3):
        state = wp.rand_init(seed, material * 3 + c)
        mix[c] = wp.clamp(0.5 + 1.8 * _fbm(state, p), 0.0, 1.0)
    albedo = wp.cw_mul(color_a, wp.vec3(1.0) - mix) + wp.cw_mul(color_b, mix)
    if params[1] > 0.0:
        q = x * params[1]
        parity = (int(wp.floor(q[0])) + int(wp.floor(q[1])) + int(wp.floor(q[2]))) % 2
        if parity != 0:
            albedo = albedo * (1.0 - params[2])
    return albedo


@wp.kernel
def cast_pinhole_rays_kernel(
    mesh: wp.uint64,
    rot_c2w: wp.mat33,
    origin: wp.vec3,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    samples: int,
    min_depth: float,
    max_depth: float,
    face: wp.array2d(dtype=wp.int32),
    bary: wp.array2d(dtype=wp.vec2),
    depth: wp.array2d(dtype=float),
    normal: wp.array2d(dtype=wp.vec3),
):
    """Closest hit per sample with depth in ``(min_depth, max_depth)`` (``min_depth``: a near plane, e.g. the
    camera's clip). Outputs ``[H*s, W*s]``: ``face`` (-1 = miss), ``bary``, ``depth`` (camera z, 0 = miss),
    ``normal`` (unit geometric face normal in world space, turned to face the camera; 0 = miss)."""
    row, col = wp.tid()
    inv_s = 1.0 / float(samples)
    u = (float(col) + 0.5) * inv_s
    v = (float(row) + 0.5) * inv_s
    d_cam = wp.vec3((u - cx) / fx, (v - cy) / fy, 1.0)
    d = rot_c2w * d_cam  # camera z of d is 1: the ray parameter is depth
    q = wp.mesh_query_ray(mesh, origin + d * min_depth, d, max_depth - min_depth)  # from the near plane on
    if q.result:
        n = wp.normalize(q.normal)
        if wp.dot(n, d) > 0.0:
            n = -n
        face[row, col] = q.face
        bary[row, col] = wp.vec2(q.u, q.v)
        depth[row, col] = min_depth + q.t
        normal[row, col] = n
    else:
        face[row, col] = -1
        bary[row, col] = wp.vec2(0.0)
        depth[row, col] = 0.0
        normal[row, col] = wp.vec3(0.0)


@wp.kernel
def shade_hits_kernel(
    face: wp.array2d(dtype=wp.int32),
    bary: wp.array2d(dtype=wp.vec2),
    normal: wp.array2d(dtype=wp.vec3),
    points: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    vertex_normals: wp.array(dtype=wp.vec3),
    corner_uvs: wp.array(dtype=wp.vec2),
    face_material: wp.array(dtype=wp.int32),
    mat_kind: wp.array(dtype=wp.int32),
    mat_texture: wp.array(dtype=wp.int32),
    mat_color_a: wp.array(dtype=wp.vec3),
    mat_color_b: wp.array(dtype=wp.vec3),
    mat_params: wp.array(dtype=wp.vec4),
    textures: wp.array3d(dtype=wp.vec3),
    lights: wp.array(dtype=wp.vec3),
    ambient: float,
    seed: int,
    rgb: wp.array2d(dtype=wp.vec3),
):
    """Colour per sample: ``albedo * (ambient + sum_l max(0, n_s . l))``, 0 where ``face < 0``.

    ``lights``: ``[L]`` unit directions towards each light times its intensity. The shading normal
    ``n_s`` interpolates ``vertex_normals`` and is turned to the side of the camera-facing geometric
    ``normal``; ``corner_uvs`` is ``[3F]`` (one uv per face corner, seams allowed).
    """
    row, col = wp.tid()
    f = face[row, col]
    if f < 0:
        rgb[row, col] = wp.vec3(0.0)
        return
    b = bary[row, col]
    w0 = b[0]
    w1 = b[1]
    w2 = 1.0 - w0 - w1
    i0 = indices[3 * f + 0]
    i1 = indices[3 * f + 1]
    i2 = indices[3 * f + 2]
    x = points[i0] * w0 + points[i1] * w1 + points[i2] * w2
    n_s = vertex_normals[i0] * w0 + vertex_normals[i1] * w1 + vertex_normals[i2] * w2
    n_g = normal[row, col]
    if wp.length(n_s) < 1.0e-12:
        n_s = n_g
    n_s = wp.normalize(n_s)
    if wp.dot(n_s, n_g) < 0.0:
        n_s = -n_s

    m = face_material[f]
    kind = mat_kind[m]
    albedo = mat_color_a[m]
    if kind == MAT_TEXTURE:
        uv = corner_uvs[3 * f + 0] * w0 + corner_uvs[3 * f + 1] * w1 + corner_uvs[3 * f + 2] * w2
        albedo = wp.cw_mul(albedo, sample_texture_bilinear(textures, mat_texture[m], uv))
    elif kind == MAT_PROCEDURAL:
        albedo = procedural_albedo(seed, m, x, mat_color_a[m], mat_color_b[m], mat_params[m])

    irradiance = ambient
    for k in range(lights.shape[0]):
        irradiance += wp.max(wp.dot(n_s, lights[k]), 0.0)
    rgb[row, col] = albedo * irradiance


@wp.func
def _unit_clamp(c: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.clamp(c[0], 0.0, 1.0), wp.clamp(c[1], 0.0, 1.0), wp.clamp(c[2], 0.0, 1.0))


@wp.kernel
def resolve_pixels_kernel(
    centre_face: wp.array2d(dtype=wp.int32),
    centre_rgb: wp.array2d(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    rgb: wp.array2d(dtype=wp.vec3),
    samples: int,
    rgba: wp.array2d(dtype=wp.vec4),
):
    """Box-filter the centre sample and the ``samples x samples`` grid of each pixel into ``[H, W]``
    RGBA: alpha = fraction of hits, colour = mean of the hits' colours clamped to [0, 1] (straight
    alpha, 0 where nothing is hit). ``samples = 0`` uses the centre only."""
    row, col = wp.tid()
    hits = float(0.0)
    c = wp.vec3(0.0)
    if centre_face[row, col] >= 0:
        hits += 1.0
        c += _unit_clamp(centre_rgb[row, col])
    for a in range(samples):
        for b in range(samples):
            r = row * samples + a
            k = col * samples + b
            if face[r, k] >= 0:
                hits += 1.0
                c += _unit_clamp(rgb[r, k])
    if hits > 0.0:
        c = c / hits
    alpha = hits / float(1 + samples * samples)
    rgba[row, col] = wp.vec4(c[0], c[1], c[2], alpha)


# ----------------------------------------------------------------------------------------- host side
def cast_pinhole_rays(mesh: wp.Mesh, R, t, fx, fy, cx, cy, width: int, height: int, samples: int = 1,
                      max_depth: float = 1.0e6, min_depth: float = 0.0) -> dict:
    """Launch :func:`cast_pinhole_rays_kernel` for one camera on ``mesh.device``.

    Args:
        mesh: the scene's ``wp.Mesh`` (world coordinates).
        R, t: ``[3, 3]``, ``[3]`` world-to-camera rotation and translation (OpenCV axes).
        fx, fy, cx, cy: intrinsics in pixels (pixel centres at ``i + 0.5``).
        width, height: image size; the sample grid is ``[height * samples, width * samples]``.
        samples: samples per pixel axis (1 = pixel centres).
        max_depth: farthest depth searched.
        min_depth: nearest depth searched (a near plane: surfaces in front of it are not hit; 0: from the centre).

    Returns:
        dict of ``wp.array2d``: ``face`` int32, ``bary`` vec2, ``depth`` float32, ``normal`` vec3.
    """
    if not 0.0 <= min_depth < max_depth:
        raise ValueError(f"cast_pinhole_rays: need 0 <= min_depth < max_depth, got {min_depth} and {max_depth}")
    R = np.asarray(R, dtype=np.float64)
    origin = -R.T @ np.asarray(t, dtype=np.float64)
    shape = (int(height) * samples, int(width) * samples)
    device = mesh.device
    out = {
        "face": wp.empty(shape, dtype=wp.int32, device=device),
        "bary": wp.empty(shape, dtype=wp.vec2, device=device),
        "depth": wp.empty(shape, dtype=wp.float32, device=device),
        "normal": wp.empty(shape, dtype=wp.vec3, device=device),
    }
    wp.launch(
        cast_pinhole_rays_kernel,
        dim=shape,
        inputs=[mesh.id, wp.mat33(*R.T.ravel()), wp.vec3(*origin), float(fx), float(fy), float(cx), float(cy),
                int(samples), float(min_depth), float(max_depth)],
        outputs=[out["face"], out["bary"], out["depth"], out["normal"]],
        device=device,
    )
    return out


def shade_hits(hits: dict, shading: dict, lights: wp.array, ambient: float, seed: int) -> wp.array:
    """Launch :func:`shade_hits_kernel` on the output of :func:`cast_pinhole_rays`.

    ``shading`` holds the device arrays named like the kernel's parameters: ``points``, ``indices``,
    ``vertex_normals``, ``corner_uvs``, ``face_material``, ``mat_kind``, ``mat_texture``,
    ``mat_color_a``, ``mat_color_b``, ``mat_params``, ``textures``. Returns ``rgb`` ``[H*s, W*s]`` vec3
    (linear, unclamped).
    """
    face = hits["face"]
    rgb = wp.empty(face.shape, dtype=wp.vec3, device=face.device)
    names = ("points", "indices", "vertex_normals", "corner_uvs", "face_material", "mat_kind", "mat_texture",
             "mat_color_a", "mat_color_b", "mat_params", "textures")
    wp.launch(
        shade_hits_kernel,
        dim=face.shape,
        inputs=[face, hits["bary"], hits["normal"], *[shading[k] for k in names], lights, float(ambient), int(seed)],
        outputs=[rgb],
        device=face.device,
    )
    return rgb


def resolve_pixels(centre_hits: dict, centre_rgb: wp.array, sub_hits: dict | None = None,
                   sub_rgb: wp.array | None = None) -> wp.array:
    """Launch :func:`resolve_pixels_kernel`; ``sub_*`` None means no supersampling. Returns ``[H, W]`` vec4."""
    face = centre_hits["face"]
    samples = 0 if sub_hits is None else sub_hits["face"].shape[0] // face.shape[0]
    rgba = wp.empty(face.shape, dtype=wp.vec4, device=face.device)
    wp.launch(
        resolve_pixels_kernel,
        dim=face.shape,
        inputs=[face, centre_rgb, face if sub_hits is None else sub_hits["face"],
                centre_rgb if sub_rgb is None else sub_rgb, samples],
        outputs=[rgba],
        device=face.device,
    )
    return rgba
