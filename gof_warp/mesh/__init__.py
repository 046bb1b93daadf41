"""Surfaces from trained Gaussians: ``extract_mesh`` and ``MeshConfig`` (GOF Sec. 3.4).

The tetra path builds a tetrahedral grid from the Gaussians (an octree split into tetrahedra, or the
official Delaunay grid of 3σ-box points), evaluates the opacity field at its vertices, marches the
tetrahedra with a binary search on crossing edges and drops faces no training camera sees; ``cubes`` and
``tsdf`` are the baselines; ``decimate`` reduces to a face budget; ``volume`` bakes the field into a
NanoVDB volume for Warp programs; ``collision_mesh`` makes a closed mesh for physics and printing and ``write_usd`` a
USD stage of the mesh, the cameras and the collision mesh.

Memory: grids and fields are made and marched in pieces (``piece_tets``), so peak memory is bounded by a
piece plus the output mesh.
"""

from ..core.lazy import lazy_exports

_PUBLIC = {
    "extract_mesh": "extraction",
    "MeshConfig": "extraction",
    "marching_tetrahedra": "marching",
    "bake_opacity_volume": "volume",
    "save_volume": "volume",
    "collision_mesh": "collision",
    "CollisionConfig": "collision",
    "write_usd": "usd_export",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
