"""The Gaussian opacity field at 3D points (GOF Sec. 3.2, appendix Algorithm 2), tile-binned.

For a view and a point ``x`` with camera-space position ``x_v`` (depth ``z = x_v.z``), the ray through
``x``'s projection is ``t · r`` with ``r = x_v / z``; each Gaussian on the point's tile list (depth-sorted,
shared with rendering) contributes ``α = min(alpha_max, opacity · G(min(t*, z)))`` where
``G(t) = exp(−½ ‖o_g + t r_g‖²)`` — it rises along the ray until its maximum at ``t*`` and then stays
flat — composited front to back like colour: ``O += α T``, ``T ← T (1 − α)``. The same per-pair rules
as rendering apply (skip ``t* ≤ near``, ``d² > k_max²``, ``α < alpha_min``), so far along a pixel's ray
the field equals that pixel's rendered alpha; and the same early reject (``rasterize.ray_outside``: a ray outside the
Gaussian's silhouette at its cutoff has ``α(t*) < alpha_min``, so ``α(min(t*, z))`` is too) skips those pairs first.
Compositing stops once ``T < transmittance_min`` (the remaining contribution is below that bound; GOF composites to
the end).

The field of a point over several views is the minimum over the views in whose image it projects (in
front of the near plane; for a camera with its own, farther clip, see :func:`point_view_tile`):
:func:`opacity_min_over_view` lowers a running minimum, one launch per view. The
running minimum bounds each walk (:func:`opacity_along_ray_bounded`): a view stops compositing once its opacity
reaches the minimum of the views before it, which cannot change the result.
"""

from __future__ import annotations

import warp as wp

from .rasterize import ray_outside
from .render_types import CameraParams, RasterSettings, Splats, TileLists


@wp.func
def opacity_along_ray_bounded(lists: TileLists, splats: Splats, tile: int, r: wp.vec3, z: float, settings: RasterSettings,
                              bound: float) -> float:
    """``min(bound, O)`` where ``O`` is the composited opacity at depth ``z`` on the camera-space ray ``t · r``
    (``r.z = 1``) of ``tile``: ``O`` never decreases along the walk, so it stops as soon as ``O ≥ bound`` (and
    returns that partial ``O``, itself ``≥ bound``). The caller's ``min(bound, ·)`` is then exactly what the full
    walk gives, bit for bit. With ``bound > 1`` it is the full walk."""
    T = float(1.0)
    O = float(0.0)
    if O >= bound:
        return O
    k_max2 = settings.k_max * settings.k_max
    for e in range(lists.range_start[tile], lists.range_end[tile]):
        k = lists.values[e]
        if ray_outside(splats.conic[k], splats.centre[k], r):  # d² > k² on the whole line: skipped below anyway
            continue
        og = splats.o_g[k]
        rg = splats.P[k] * r
        A = wp.dot(rg, rg)
        B = wp.dot(og, rg)
        C = wp.dot(og, og)
        t_star = -B / A
        if t_star <= settings.near:
            continue
        if C - B * B / A > k_max2:
            continue
        t = wp.min(t_star, z)
        x_g = og + t * rg
        alpha = wp.min(settings.alpha_max, splats.opacity[k] * wp.exp(-0.5 * wp.dot(x_g, x_g)))
        if alpha < settings.alpha_min:
            continue
        O += alpha * T
        T *= 1.0 - alpha
        if T < settings.transmittance_min or O >= bound:
            break
    return O


@wp.func
def opacity_along_ray(lists: TileLists, splats: Splats, tile: int, r: wp.vec3, z: float, settings: RasterSettings) -> float:
    """Composited opacity at depth ``z`` on the camera-space ray ``t · r`` (``r.z = 1``) of ``tile`` (the whole walk)."""
    return opacity_along_ray_bounded(lists, splats, tile, r, z, settings, 2.0)


@wp.func
def point_view_tile(x_v: wp.vec3, cam: CameraParams, settings: RasterSettings) -> int:
    """The tile of camera-space point ``x_v``'s projection, or −1 when the view does not see it (outside the image,
    or not beyond the scene's near plane ``settings.ndc_near``, i.e. ``render.near``).

    A camera with its own clip (``settings.near`` > ``ndc_near``: the trainer's near planes from the SfM points) still
    sees the points between the scene's near plane and that clip: the clip keeps Gaussians out of its renders, but the
    space in front of it is space the camera looked through, where its opacity (the tails of the Gaussians beyond the
    clip) is low. Counting it as unseen by that camera left the field there to the cameras across the scene, which
    see it behind the objects (opacity ~1), and the mesh closed around the cameras (seen on colmap_can).
    """
    z = x_v[2]
    if z <= settings.ndc_near:
        return -1
    u = cam.fx * x_v[0] / z + cam.cx
    v = cam.fy * x_v[1] / z + cam.cy
    if u < 0.0 or v < 0.0 or u >= float(cam.width) or v >= float(cam.height):
        return -1
    return (int(v) // settings.tile_size) * settings.tiles_x + int(u) // settings.tile_size


@wp.kernel
def opacity_min_over_view(
    points: wp.array(dtype=wp.vec3),
    lists: TileLists,
    splats: Splats,
    cam: CameraParams,
    settings: RasterSettings,
    field: wp.array(dtype=float),
    seen: wp.array(dtype=wp.int32),
):
    """``field[i] ← min(field[i], O_view(points[i]))`` for points this view sees; ``seen[i] += 1`` then.

    Inputs: ``points [M] vec3`` world space, the view's tile lists and splats (from the renderer's
    preprocessing and binning, with ``settings.pixel_pad ≥ 0.5`` so off-centre rays are covered). The running
    minimum bounds the walk: once this view's opacity reaches it, the view cannot lower it.
    """
    i = wp.tid()
    x_v = cam.R * points[i] + cam.t
    tile = point_view_tile(x_v, cam, settings)
    if tile < 0:
        return
    field[i] = wp.min(field[i], opacity_along_ray_bounded(lists, splats, tile, x_v / x_v[2], x_v[2], settings, field[i]))
    seen[i] = seen[i] + 1


@wp.kernel
def opacity_min_over_view_whole(
    points: wp.array(dtype=wp.vec3),
    lists: TileLists,
    splats: Splats,
    cam: CameraParams,
    settings: RasterSettings,
    field: wp.array(dtype=float),
    seen: wp.array(dtype=wp.int32),
):
    """:func:`opacity_min_over_view` with every view walking its whole list: the reference the bounded kernel
    equals bit for bit (``tests/rendering/test_opacity_field.py``)."""
    i = wp.tid()
    x_v = cam.R * points[i] + cam.t
    tile = point_view_tile(x_v, cam, settings)
    if tile < 0:
        return
    field[i] = wp.min(field[i], opacity_along_ray(lists, splats, tile, x_v / x_v[2], x_v[2], settings))
    seen[i] = seen[i] + 1
