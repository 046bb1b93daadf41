"""CGAL's Delaunay tetrahedralisation (optional extra ``gof_warp[cgal]``, GPLv3), for :func:`gof_warp.mesh.delaunay.delaunay`.

Its Python bindings (pip ``cgal``, SWIG) expose no vertex ids or arrays: the triangulation is written as text at
full precision and read back, and CGAL's vertices are matched to the input points by their exact coordinates.
"""

from __future__ import annotations

import itertools
import os
import tempfile

import numpy as np

from ..core.errors import GofError

CGAL_FILE_PRECISION = 17  # digits: doubles round-trip exactly through CGAL's text output


def _read_numbers(f, n_lines: int, dtype, block: int = 1 << 20) -> np.ndarray:
    """Next ``n_lines`` whitespace-separated number lines of a text file, in blocks."""
    parts = []
    for start in range(0, n_lines, block):
        text = b"".join(itertools.islice(f, min(block, n_lines - start))).decode()
        parts.append(np.fromstring(text, dtype=dtype, sep=" "))  # text mode (not deprecated), 4x split()
    return np.concatenate(parts) if parts else np.zeros(0, dtype)


def delaunay_cgal(p: np.ndarray) -> np.ndarray:
    """CGAL's ``Delaunay_triangulation_3`` (pip ``cgal``, SWIG bindings, GPLv3): insert all points, write
    the triangulation as text (full precision), read finite cells, map CGAL's vertices back to our indices
    by their exact coordinates (duplicates map to their first copy)."""
    try:
        from CGAL.CGAL_Kernel import Point_3
        from CGAL.CGAL_Triangulation_3 import Delaunay_triangulation_3
    except ImportError as e:
        raise GofError("backend='cgal' needs the optional CGAL bindings (GPLv3): pip install 'gof_warp[cgal]'") from e
    tri = Delaunay_triangulation_3()
    tri.insert([Point_3(x, y, z) for x, y, z in p.tolist()])
    if tri.dimension() < 3:
        raise GofError(f"Delaunay failed: the {p.shape[0]} points are degenerate (dimension {tri.dimension()})")
    with tempfile.TemporaryDirectory(prefix="gof_cgal_") as tmp:
        path = os.path.join(tmp, "triangulation.txt")
        tri.write_to_file(path, CGAL_FILE_PRECISION)
        del tri
        with open(path, "rb") as f:  # dimension, n, n vertex lines, n_cells, n_cells cell lines, neighbours
            int(f.readline())
            n = int(f.readline())
            xyz = _read_numbers(f, n, np.float64).reshape(n, 3)
            n_cells = int(f.readline())
            cells = _read_numbers(f, n_cells, np.int64).reshape(n_cells, 4)
    cells = cells[(cells != 0).all(axis=1)] - 1  # index 0 is the infinite vertex
    unique, first = np.unique(p, axis=0, return_index=True)
    order = np.lexsort(xyz.T[::-1])
    if unique.shape != xyz.shape or not np.array_equal(unique, xyz[order]):
        raise RuntimeError("CGAL's vertices do not match the input points")
    to_input = np.empty(n, np.int64)
    to_input[order] = first
    return to_input[cells]


