"""Which points lie inside some Gaussian's oriented box: the reach of the Gaussians, on a tetrahedral grid's points.

GOF's Delaunay grid has points only at the Gaussians' centres and the corners of their oriented 3σ boxes, and its
cell filter drops tetrahedra whose edges outrun the Gaussians' extent, so its tetrahedra stay where the Gaussians
reach. A grid that fills whole boxes (the octree) has vertices between and under them too; a tetrahedron none of
whose vertices lies in any box reaches no Gaussian, and the host side (:mod:`gof_warp.mesh.tetra`) leaves it out.

A point ``p`` lies in the box of Gaussian ``k`` (centre ``μ``, rotation ``R`` from the wxyz quaternion, half extents
``e = σ s``) when ``|Rᵀ (p − μ)| ≤ e`` on every axis. The boxes' axis-aligned bounds (:func:`oriented_box_bounds`:
``μ ± |R| e``) go into a ``wp.Bvh``; :func:`points_in_boxes` walks the boxes whose bounds hold each point and stops
at the first that holds it too. Exact over all Gaussians (no nearest-``k`` cut-off); ``O(P log N)`` plus the
candidates each point's bounds query returns. Pure Warp (no torch).
"""

from __future__ import annotations

import warp as wp

from .gaussian_math import quat_to_rotation


@wp.func
def in_oriented_box(p: wp.vec3, mean: wp.vec3, q: wp.vec4, half: wp.vec3) -> bool:
    """``|Rᵀ (p − mean)| <= half`` on each axis, ``R`` the rotation of the unit wxyz quaternion ``q``."""
    d = wp.transpose(quat_to_rotation(q)) @ (p - mean)
    return wp.abs(d[0]) <= half[0] and wp.abs(d[1]) <= half[1] and wp.abs(d[2]) <= half[2]


@wp.kernel
def oriented_box_bounds(
    means: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.vec4),
    half_extents: wp.array(dtype=wp.vec3),
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
):
    """Axis-aligned bounds ``[N]`` of the oriented boxes ``means[k] + R_k diag(half_extents[k]) [-1, 1]³``
    (``rotations`` unit wxyz quaternions): ``means ± |R| half_extents``."""
    k = wp.tid()
    R = quat_to_rotation(rotations[k])
    e = half_extents[k]
    h = wp.vec3(
        wp.abs(R[0, 0]) * e[0] + wp.abs(R[0, 1]) * e[1] + wp.abs(R[0, 2]) * e[2],
        wp.abs(R[1, 0]) * e[0] + wp.abs(R[1, 1]) * e[1] + wp.abs(R[1, 2]) * e[2],
        wp.abs(R[2, 0]) * e[0] + wp.abs(R[2, 1]) * e[1] + wp.abs(R[2, 2]) * e[2],
    )
    lowers[k] = means[k] - h
    uppers[k] = means[k] + h


@wp.kernel
def points_in_boxes(
    bvh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    means: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.vec4),
    half_extents: wp.array(dtype=wp.vec3),
    inside: wp.array(dtype=wp.int8),
):
    """``inside[i] = 1`` when ``points[i]`` lies in the oriented box of some Gaussian, else 0. ``bvh``: the id of a
    ``wp.Bvh`` over :func:`oriented_box_bounds` of the same ``means``, ``rotations``, ``half_extents`` ``[N]``."""
    i = wp.tid()
    p = points[i]
    query = wp.bvh_query_aabb(bvh, p, p)
    k = int(0)
    hit = wp.int8(0)
    while wp.bvh_query_next(query, k):
        if in_oriented_box(p, means[k], rotations[k], half_extents[k]):
            hit = wp.int8(1)
            break
    inside[i] = hit
