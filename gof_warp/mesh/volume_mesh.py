"""A level-set mesh of a baked opacity volume (:mod:`gof_warp.mesh.volume`): marching cubes on the volume's own voxel
lattice, refined by bisection on the volume's trilinear field.

Lattice: grid node ``n`` (``0 ≤ n < resolution`` per axis) is voxel ``lo + n`` of the volume, at world
``origin + h · (lo + n)`` (``info["origin"]``, ``info["voxel_size"]``), where ``[lo, hi]`` is the index box
of the stored (active) voxels. The node values are the stored voxel values, so marching cubes sees exactly
the samples the bake computed.

Field: ``f(x) = wp.volume_sample_f(volume, world_to_index(x), LINEAR)`` — the trilinear field any Warp
kernel reads from the ``.nvdb`` — wherever the 8 voxels of ``x``'s trilinear stencil are all stored. A
volume stores only a band around the level set and reads the background 0 elsewhere, *including the deep
inside of solids*; marching that raw field would add a false shell where the band ends inside each solid.
So a voxel that is not stored takes the value of the nearest stored voxel (Euclidean, on the lattice), and
stencils that touch one interpolate those filled values instead: inside solids it is ~1, outside ~0, and no
level crossing appears where the band ends. (The bake keeps every point within ``band`` voxels of a
crossing on a fully stored stencil, so real crossings are on the volume's own trilinear field.)

Bisection: on a lattice edge the trilinear field is the linear interpolation of the edge's two voxels, so the
binary search converges to marching cubes' linear vertex; ``binary_steps`` is kept for the same call
signature as :mod:`gof_warp.mesh.marching` (and costs one field launch per step on the crossing edges).

Memory (host, ``N`` lattice nodes): 4 B/node values + 1 B/node stored mask + 12 B/node nearest-voxel
indices (``scipy.ndimage.distance_transform_edt``) while filling, then marching cubes' ~52 B/node
(:mod:`gof_warp.mesh.marching`); ``max_nodes`` bounds ``N``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core.errors import GofError
from ..kernels import volume as vk
from .marching import marching_cubes

DEFAULT_MAX_NODES = 1 << 27  # ~8 GB of host working memory at ~60 B per lattice node


@wp.struct
class VolumeLattice:
    """The field's parameters: the volume, the filled node values and the stored-voxel mask on its index box."""

    volume: wp.uint64
    filled: wp.array3d(dtype=wp.float32)  # [nx, ny, nz] node values, unstored voxels = nearest stored value
    stored: wp.array3d(dtype=wp.uint8)  # [nx, ny, nz] 1 where the volume stores the voxel
    lo: wp.vec3i  # index of lattice node (0, 0, 0)


@wp.func
def _node(p: VolumeLattice, i: int, j: int, k: int) -> float:
    """Filled value at lattice node ``(i, j, k)``, clamped to the lattice."""
    i = wp.clamp(i, 0, p.filled.shape[0] - 1)
    j = wp.clamp(j, 0, p.filled.shape[1] - 1)
    k = wp.clamp(k, 0, p.filled.shape[2] - 1)
    return p.filled[i, j, k]


@wp.func
def _is_stored(p: VolumeLattice, i: int, j: int, k: int) -> int:
    if i < 0 or j < 0 or k < 0 or i >= p.stored.shape[0] or j >= p.stored.shape[1] or k >= p.stored.shape[2]:
        return 0
    return int(p.stored[i, j, k])


@wp.func
def volume_lattice_field(x: wp.vec3, p: VolumeLattice) -> float:
    """Trilinear field of the volume at world ``x``; stencils touching an unstored voxel use the filled values."""
    uvw = wp.volume_world_to_index(p.volume, x)
    b = wp.vec3(wp.floor(uvw[0]), wp.floor(uvw[1]), wp.floor(uvw[2]))
    t = uvw - b
    i0 = int(b[0]) - p.lo[0]
    j0 = int(b[1]) - p.lo[1]
    k0 = int(b[2]) - p.lo[2]
    n = int(0)
    for c in range(8):
        n += _is_stored(p, i0 + (c & 1), j0 + ((c >> 1) & 1), k0 + ((c >> 2) & 1))
    if n == 8:
        return wp.volume_sample_f(p.volume, uvw, wp.Volume.LINEAR)
    v = float(0.0)
    for c in range(8):
        di = c & 1
        dj = (c >> 1) & 1
        dk = (c >> 2) & 1
        w = wp.where(di == 1, t[0], 1.0 - t[0]) * wp.where(dj == 1, t[1], 1.0 - t[1])
        w = w * wp.where(dk == 1, t[2], 1.0 - t[2])
        v += w * _node(p, i0 + di, j0 + dj, k0 + dk)
    return v


def lattice_of(volume: wp.Volume, info: dict, max_nodes: int = DEFAULT_MAX_NODES):
    """The volume's lattice: ``(params VolumeLattice, lower [3] world, resolution (nx, ny, nz), stored count)``.

    Raises:
        GofError: not a ``wp.Volume``, ``info`` without ``origin``/``voxel_size`` or disagreeing with the
            volume's transform, no stored voxel, or more than ``max_nodes`` lattice nodes.
    """
    if not isinstance(volume, wp.Volume):
        raise GofError(f"volume_mesh needs a wp.Volume, got {type(volume).__name__}")
    if not isinstance(info, dict) or "origin" not in info or "voxel_size" not in info:
        raise GofError("volume_mesh needs the bake's info dict (with 'origin' and 'voxel_size', "
                       "as written beside the .nvdb)")
    h = float(info["voxel_size"])
    origin = np.asarray(info["origin"], np.float64)
    if not (np.isfinite(h) and h > 0) or origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise GofError(f"info has no usable voxel_size/origin: {info['voxel_size']!r}, {info['origin']!r}")
    vs = np.asarray(volume.get_voxel_size(), np.float64)
    if not np.allclose(vs, h, rtol=1e-5):
        raise GofError(f"info's voxel_size {h:g} is not the volume's {vs.tolist()}: info of another volume?")
    ijk = volume.get_voxels().numpy().astype(np.int64).reshape(-1, 3)
    if len(ijk) == 0:
        raise GofError("the volume stores no voxel: nothing to mesh")
    lo, hi = ijk.min(axis=0), ijk.max(axis=0)
    res = tuple(int(r) for r in hi - lo + 1)
    n_nodes = int(np.prod(res))
    if n_nodes > max_nodes:
        raise GofError(f"the volume's lattice has {n_nodes:,} nodes {res} (max_nodes {max_nodes:,}): crop or "
                       "bake with a larger voxel size")
    if min(res) < 2:
        raise GofError(f"the volume's lattice {res} is flat: marching cubes needs >= 2 nodes per axis")
    dev = volume.device
    vals = wp.empty(len(ijk), dtype=wp.float32, device=dev)
    wp.launch(vk.lookup_stored_voxels, dim=len(ijk), device=dev,
              inputs=[volume.id, wp.array(ijk.astype(np.int32), dtype=wp.vec3i, device=dev)], outputs=[vals])
    rel = tuple((ijk - lo).T)
    stored = np.zeros(res, np.uint8)
    stored[rel] = 1
    filled = np.zeros(res, np.float32)
    filled[rel] = vals.numpy()
    if len(ijk) < n_nodes:
        from scipy.ndimage import distance_transform_edt

        nearest = distance_transform_edt(stored == 0, return_distances=False, return_indices=True)
        filled = filled[tuple(nearest)]
    p = VolumeLattice()
    p.volume = volume.id
    p.filled = wp.array(filled, dtype=wp.float32, device=dev)
    p.stored = wp.array(stored, dtype=wp.uint8, device=dev)
    p.lo = wp.vec3i(*(int(v) for v in lo))
    return p, origin + h * lo, res, len(ijk)


def volume_mesh(volume: wp.Volume, info: dict, *, level: float = 0.5, binary_steps: int = 4,
                max_nodes: int = DEFAULT_MAX_NODES, exact_field=None) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of a baked opacity volume on its own voxel lattice (see the module docstring).

    Args:
        volume: a float ``wp.Volume`` from :func:`gof_warp.mesh.volume.bake_opacity_volume` or
            :func:`gof_warp.mesh.volume.load_volume`; the work runs on its device.
        info: the bake's info dict (``bake_opacity_volume``'s second result, or the ``.json`` beside the
            ``.nvdb``): ``origin`` (world position of voxel (0, 0, 0)) and ``voxel_size`` ``h`` (world units).
        level: the level set, in (0, 1) (inside = ``value >= level``; GOF: 0.5).
        binary_steps: bisection steps per vertex on the trilinear field (0 = linear interpolation).
        max_nodes: the most lattice nodes (index box of the stored voxels) to allocate.
        exact_field: optional callable, world points ``[M, 3]`` (numpy) → values ``[M]``, for the bisection
            instead of the trilinear field (e.g. :func:`gof_warp.rendering.opacity_field.opacity_field` of the baked
            Gaussians): the lattice's crossings, refined on the field the volume was baked from.

    Returns:
        ``(vertices [V, 3] float32 world units, faces [F, 3] int32)``, normals from high to low opacity
        (outwards). Vertices lie on lattice edges (spacing ``h``).

    Raises:
        GofError: bad ``volume``/``info``/``level``/``binary_steps`` (see :func:`lattice_of`).
    """
    if not isinstance(level, (int, float, np.floating)) or not 0.0 < float(level) < 1.0:
        raise GofError(f"level must be an opacity in (0, 1), got {level!r}")
    if not isinstance(binary_steps, (int, np.integer)) or binary_steps < 0:
        raise GofError(f"binary_steps must be a non-negative integer, got {binary_steps!r}")
    params, lower, res, _ = lattice_of(volume, info, max_nodes)
    h = float(info["voxel_size"])
    upper = lower + h * (np.asarray(res, np.float64) - 1)
    return marching_cubes(volume_lattice_field, np.stack([lower, upper]), res, level=float(level),
                          binary_steps=int(binary_steps), device=str(volume.device), field_params=params,
                          search_field=exact_field)
