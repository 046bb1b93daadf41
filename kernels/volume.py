"""Kernels for the baked opacity volume (a sparse ``wp.Volume`` of float voxels; see ``docs/warp_volume.md``).

Pure Warp. Voxel ``(i, j, k)`` of a baked volume sits at ``origin + h (i, j, k)`` in world units; empty space
reads the background value 0.
"""

import warp as wp


@wp.kernel
def store_voxels(volume: wp.uint64, ijk: wp.array(dtype=wp.vec3i), values: wp.array(dtype=wp.float32)):
    """Write ``values[t]`` (float32) at voxel index ``ijk[t]`` (vec3i) of ``volume`` (``wp.Volume.id``); the
    voxel's brick must be allocated (``wp.Volume.allocate_by_tiles``). Launch with ``dim = len(ijk)``."""
    t = wp.tid()
    c = ijk[t]
    wp.volume_store_f(volume, c[0], c[1], c[2], values[t])


@wp.kernel
def sample_volume_world(volume: wp.uint64, points: wp.array(dtype=wp.vec3), values: wp.array(dtype=wp.float32)):
    """``values[t]`` (float32): the trilinear sample of ``volume`` at world point ``points[t]`` (vec3, world
    units). Launch with ``dim = len(points)``."""
    t = wp.tid()
    uvw = wp.volume_world_to_index(volume, points[t])
    values[t] = wp.volume_sample_f(volume, uvw, wp.Volume.LINEAR)


@wp.kernel
def lookup_stored_voxels(volume: wp.uint64, ijk: wp.array(dtype=wp.vec3i), values: wp.array(dtype=wp.float32)):
    """``values[t]`` (float32): the value stored at voxel index ``ijk[t]`` (vec3i), no interpolation (the
    background value where no voxel is stored). Launch with ``dim = len(ijk)``."""
    t = wp.tid()
    c = ijk[t]
    values[t] = wp.volume_lookup_f(volume, c[0], c[1], c[2])
