"""A tetrahedral grid without Delaunay: a 2:1-balanced octree sized by the Gaussians, split into tetrahedra.

GOF meshes the opacity field by marching tetrahedra on *a* tetrahedralisation whose vertices carry the field; the
official code takes the Delaunay of the Gaussians' 3σ-box corners and centres. That Delaunay is the extraction's wall
on a CPU (Qhull: ~50 core-seconds per million points). This module builds the grid from integer arithmetic alone, on
the Gaussians' device (torch; CUDA or CPU):

1. **Octree.** Each Gaussian asks for cells no larger than ``cell_factor × 2r`` over its 3σ box (``r = 3 max(s)``, the
   radius the Delaunay grid's points span) at the level ``l`` with ``root / 2^l <= cell_factor · 2r``. Every asked-for
   cell's ancestors are refined, then the tree is **2:1 balanced** over faces, edges and corners (a refined node's 26
   neighbours have refined parents), so leaves that touch differ by at most one level.
2. **Tetrahedra.** A face is triangulated as a function of the face alone, so both leaves that share it agree: a face
   none of whose edges holds a hanging vertex (the corner of a finer leaf at its midpoint) is split along its
   ``q0–q2`` diagonal; otherwise it is a fan from the face's centre over its boundary, hanging vertices included. A
   leaf next to finer leaves is a cone from its centre over its faces' triangles (a side next to a refined neighbour
   as the neighbour's four sub-faces). A leaf with no finer neighbour and no hanging vertex — most of them — is
   Kuhn's six tetrahedra around its main diagonal, which split every face along that same ``q0–q2`` diagonal: no
   centre point and half the tetrahedra of a cone. The result is conforming (every inner triangle belongs to exactly
   two tetrahedra; tested), so marching tetrahedra on it gives watertight meshes.
3. **Occupancy.** Only leaves inside an asked-for cell (some Gaussian's box) get tetrahedra. The empty space between
   boxes is left out, as the paper's cell filter leaves out Delaunay cells with edges longer than the Gaussians'
   reach: there the field only changes at the shadow boundaries behind objects, which are not surfaces.
4. **Reach** (optional, off by default: ``OctreeConfig.reach_filter``, applied by the caller that has the rotations:
   :func:`gof_warp.mesh.tetra.octree_tets_from_gaussians`). An occupied leaf fills the whole cube around a box, also where
   no Gaussian is (under a ground, between objects); :attr:`OctreeTets.reach` marks the points inside some
   Gaussian's oriented 3σ box (:mod:`gof_warp.mesh.reach`), and the extraction keeps only the tetrahedra with such a
   vertex: where the Delaunay grid's points and cell filter reach.

Coordinates are integers on the lattice of the finest level's half cells: ``2^(depth+1)`` units along the root cube,
21 bits per axis packed in one int64 key (``depth <= 19``: the far corner, ``2^(depth+1)``, must fit). Points are ``lo + key · size / 2^(depth+1)``.

Counts (per leaf): 6 tetrahedra and no extra point for a leaf with no finer neighbour; next to finer leaves one
centre and 12 to 96 tetrahedra. Memory (on the device): the asked-for cells are gathered one box offset at a time
(``N`` int64 candidates and the distinct cells); the tree holds int64 keys per cell (the balance looks at 27
neighbours of each refined node of one level at a time). The tetrahedra are made ``LEAF_CHUNK`` leaves (and face
records) at a time, twice: once to collect the distinct vertex keys (the grid's points, 8 B each, plus 12 B each for
their positions), and again, on demand, as **pieces** (:class:`OctreeTets`): consecutive ranges of the one order in
which the chunks come, written as int32 point indices. The tetrahedra need never be held whole: a caller that marches
piece by piece (``gof_warp.mesh.extraction``) holds one piece (16 B per tetrahedron) and one chunk's int64 work
(~0.25 GB) beyond the points.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import torch

from ..core.arrays import even_split
from ..core.errors import GofError

log = logging.getLogger(__name__)

KEY_BITS = 21
KEY_MASK = (1 << KEY_BITS) - 1
MAX_DEPTH = KEY_BITS - 2  # the lattice has 2^(depth+1) units per axis, and its far corner 2^(depth+1) fits the bits
CLAMP_WARN_FRACTION = 0.01  # warn when more Gaussians than this get cells larger than asked (the deepest level)
KEYSET_MERGE_MIN = 1 << 22  # keys a _KeySet lets wait before merging them into its sorted set
LEVEL_BITS = MAX_DEPTH  # bits per axis of a cell of any level (coordinates < 2^depth)
LEVEL_SHIFT = 3 * LEVEL_BITS  # an asked-for cell's level above its three coordinates: 5 + 57 bits
POINT_CHUNK = 1 << 24  # points whose world positions are computed at once (1.2 GB of float64 work)
LEAF_CHUNK = 1 << 18  # leaves (and face records of cone leaves) per tetrahedron chunk: ~0.25 GB of int64 work

# the 26 neighbours and the cell itself
_NEIGHBOURS = torch.tensor([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=torch.int64)
_CHILDREN = torch.tensor([(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=torch.int64)


def _edge_midpoints() -> torch.Tensor:
    """The 12 edge midpoints of a cube of side 2: one coordinate 1 (along the edge), the other two 0 or 2."""
    out = []
    for axis in range(3):
        for p in (0, 2):
            for q in (0, 2):
                m = [0, 0, 0]
                m[axis], m[(axis + 1) % 3], m[(axis + 2) % 3] = 1, p, q
                out.append(m)
    return torch.tensor(out, dtype=torch.int64)


_EDGE_MIDPOINTS = _edge_midpoints()
# Kuhn's six tetrahedra of the unit cube around its main diagonal: corners 0 → +e_i → +e_j → (1, 1, 1)
_KUHN = torch.tensor([[[0, 0, 0], list(map(int, [a == 0, a == 1, a == 2])),
                       list(map(int, [a == 0 or b == 0, a == 1 or b == 1, a == 2 or b == 2])), [1, 1, 1]]
                      for a in range(3) for b in range(3) if a != b], dtype=torch.int64)  # [6, 4, 3]


# the octree's cell factor when none is given: 0.5 meshes DTU scan 24 in ~4.2M faces (under the 4.3M-face target;
# 0.35 gives 7.9M) at the Delaunay grid's accuracy on the synthetic garden's ground-and-objects crop
DEFAULT_CELL_FACTOR = 0.5
# ... and, with TetraConfig.grid = "octree" (the default "auto" takes the Delaunay grid there: gof_warp.mesh.tetra), for a
# grid of fewer than OctreeConfig.small_leaves leaves at 0.5, where the finer grid costs a second or two.
# On the README job's model (40k leaves) 0.35 gives a Chamfer +1.7 % of the Delaunay grid's over five seeds, 0.5
# +3.2 % (benchmarks/RESULTS.md). colmap_can, fox, background_full (1.0–2.0M leaves at 0.5) and the 400×400 default
# scene (242k) keep 0.5, as does DTU (800k Gaussians, more than background_full's 360k)
SMALL_CELL_FACTOR = 0.35


@dataclass
class OctreeConfig:
    """Settings of the octree grid (``TetraConfig.grid = "octree"``)."""

    # leaf side <= cell_factor × 2 r over a Gaussian's 3σ box (r = 3 max(s)). None (the default): DEFAULT_CELL_FACTOR,
    # or SMALL_CELL_FACTOR for a grid of fewer than small_leaves leaves at the default; a number is used as it is
    cell_factor: float | None = None
    small_leaves: int = 100_000
    # deepest level: the root cube's side / 2^depth is the smallest cell. Levels cost only where asked for, so the
    # default is the deepest the keys allow: 5·10^5 cells along the root cube, room for far background Gaussians
    depth: int = MAX_DEPTH
    box_percentile: float = 0.0  # root cube: the box of the 3σ boxes, ignoring this % of the Gaussians per side
    # tetrahedra made and marched at once: extraction takes the grid in consecutive pieces of at most this many
    # (OctreeTets.pieces), so the tetrahedra are never held whole; the mesh is the same for any value. 2^24: 0.27 GB of
    # indices and the marching's 24 B per tetrahedron (DTU scan 24's 35.7M tetrahedra: three pieces)
    piece_tets: int = 1 << 24
    # keep only the tetrahedra with a vertex inside some Gaussian's oriented 3σ box (gof_warp.mesh.reach). Off by default:
    # where a surface is made of flat Gaussians, whether any octree vertex falls inside their thin boxes depends on how
    # the lattice happens to lie. Measured: the background model's crop
    # Chamfer +5.5 % of the Delaunay grid's without it, +1.7 % / +5.2 % with unfiltered / 3D-filtered boxes; on
    # background_full 12 % of the ground lost (264 of 1,324 ground patches); colmap_can loses a floater but gets holes
    reach_filter: bool = False

    def validate(self):
        if self.cell_factor is not None and not (self.cell_factor > 0 and math.isfinite(self.cell_factor)):
            raise GofError(f"octree cell_factor must be a positive number or None (auto), got {self.cell_factor!r}")
        if isinstance(self.small_leaves, bool) or not isinstance(self.small_leaves, int) or self.small_leaves < 0:
            raise GofError(f"octree small_leaves must be an integer >= 0, got {self.small_leaves!r}")
        if not (isinstance(self.depth, int) and 1 <= self.depth <= MAX_DEPTH):
            raise GofError(f"octree depth must be an integer in [1, {MAX_DEPTH}], got {self.depth!r}")
        if isinstance(self.piece_tets, bool) or not isinstance(self.piece_tets, int) or self.piece_tets < 1:
            raise GofError(f"octree piece_tets must be a positive integer, got {self.piece_tets!r}")
        if not isinstance(self.reach_filter, bool):
            raise GofError(f"octree reach_filter must be true or false, got {self.reach_filter!r}")
        if not 0.0 <= self.box_percentile < 50.0:
            raise GofError(f"octree box_percentile must be in [0, 50), got {self.box_percentile!r}")


# ---------------------------------------------------------------------------------------------- keys
def pack(ijk: torch.Tensor) -> torch.Tensor:
    """``[..., 3]`` int64 lattice coordinates (each in ``[0, 2^21)``) → ``[...]`` int64 keys."""
    return ijk[..., 0] | (ijk[..., 1] << KEY_BITS) | (ijk[..., 2] << (2 * KEY_BITS))


def unpack(key: torch.Tensor) -> torch.Tensor:
    """``[...]`` int64 keys → ``[..., 3]`` int64 coordinates."""
    return torch.stack([key & KEY_MASK, (key >> KEY_BITS) & KEY_MASK, (key >> (2 * KEY_BITS)) & KEY_MASK], -1)


def contains(sorted_keys: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
    """``query`` (any shape) in the sorted 1-D ``sorted_keys``: bool, same shape."""
    if sorted_keys.numel() == 0:
        return torch.zeros_like(query, dtype=torch.bool)
    i = torch.searchsorted(sorted_keys, query).clamp_(max=sorted_keys.numel() - 1)
    return sorted_keys[i] == query


# ---------------------------------------------------------------------------------------------- octree
@dataclass
class Octree:
    """A 2:1-balanced octree over the cube ``lo + [0, size]^3``.

    ``refined[l]``: sorted keys (cell coordinates at level ``l``) of the nodes with children; ``leaves[l]``: the
    leaves at level ``l`` (in parent order) and ``occupied[l]`` which of them lie in some Gaussian's asked-for cell.
    """

    lo: torch.Tensor  # [3] float64
    size: float
    depth: int
    refined: list = field(default_factory=list)
    leaves: list = field(default_factory=list)
    occupied: list = field(default_factory=list)

    @property
    def n_leaves(self) -> int:
        return sum(int(x.numel()) for x in self.leaves)

    def unit(self) -> float:
        """World length of one lattice unit (half the finest cell)."""
        return self.size / float(1 << (self.depth + 1))


class _KeySet:
    """Sorted distinct int64 keys gathered from many batches: the batches wait in a list and are merged
    (``torch.unique``) once they hold as many keys as the set (and at least ``KEYSET_MERGE_MIN``), so ``n`` keys
    cost ``O(n log n)`` work and the memory of a few times the set, whatever the number of batches."""

    def __init__(self, device):
        self.keys = torch.zeros(0, dtype=torch.int64, device=device)
        self.pending: list = []
        self.waiting = 0

    def add(self, keys: torch.Tensor) -> None:
        self.pending.append(keys)
        self.waiting += keys.numel()
        if self.waiting > max(KEYSET_MERGE_MIN, self.keys.numel()):
            self.sorted()

    def sorted(self) -> torch.Tensor:
        if self.pending:
            merged = torch.cat([self.keys, *self.pending])
            self.keys, self.pending, self.waiting = None, [], 0  # the parts are freed before the sort, not after
            self.keys = torch.unique(merged)
        return self.keys


def _asked_cells(centres: torch.Tensor, radii: torch.Tensor, lo: torch.Tensor, size: float, depth: int,
                 cell_factor: float) -> list[torch.Tensor]:
    """Per level, the sorted keys of the cells some Gaussian asks for: the cells of its level overlapping its box.
    Gathered one box-corner offset at a time (``N`` candidates at once, not ``span³ N``), each candidate keyed by its
    level and cell together (``LEVEL_SHIFT``) in one :class:`_KeySet`."""
    device = centres.device
    want = (size / (cell_factor * 2.0 * radii)).clamp(min=1.0)
    level = torch.ceil(torch.log2(want)).to(torch.int64)
    clamped = int((level > depth).sum())
    if clamped > CLAMP_WARN_FRACTION * max(1, level.numel()):
        log.warning("warning: %d of %d Gaussians ask for cells finer than the octree's deepest level %d (root cube %.4g): "
                    "their part of the mesh is coarser than asked; a few far Gaussians can widen the root cube "
                    "(OctreeConfig.box_percentile drops them)", clamped, level.numel(), depth, size)
    level = level.clamp_(1, depth)
    h = size / (2.0 ** level.to(torch.float64))  # [N]
    rel = centres - lo
    first = torch.floor((rel - radii[:, None]) / h[:, None]).to(torch.int64)
    last = torch.floor((rel + radii[:, None]) / h[:, None]).to(torch.int64)
    top = (1 << level)[:, None] - 1
    first, last = first.clamp(min=0).minimum(top), last.clamp(min=0).minimum(top)
    span = int((last - first).max()) + 1 if centres.shape[0] else 0
    cells = _KeySet(device)
    for off in torch.cartesian_prod(*[torch.arange(span, device=device)] * 3).reshape(-1, 3):
        ijk = first + off
        ok = (ijk <= last).all(dim=1)
        c = ijk[ok]  # a cell of level l has coordinates < 2^l <= 2^depth: LEVEL_BITS each
        cells.add(c[:, 0] | (c[:, 1] << LEVEL_BITS) | (c[:, 2] << (2 * LEVEL_BITS)) | (level[ok] << LEVEL_SHIFT))
    found = cells.sorted()
    lv, mask = found >> LEVEL_SHIFT, (1 << LEVEL_BITS) - 1
    keys = pack(torch.stack([found & mask, (found >> LEVEL_BITS) & mask, (found >> (2 * LEVEL_BITS)) & mask], -1))
    asked = [torch.zeros(0, dtype=torch.int64, device=device) for _ in range(depth + 1)]
    for l in torch.unique(lv).tolist():  # sorted already: a level's combined keys order its cells as pack() does
        asked[l] = keys[lv == l]
    return asked


def root_cube(centres: torch.Tensor, radii: torch.Tensor) -> tuple[torch.Tensor, float]:
    """``(lo [3], size)``: the cube around the boxes ``centres [N, 3] ± radii [N]`` (their bounding cube, 1 % larger)."""
    if centres.shape[0] == 0:
        raise GofError("no Gaussians to build the octree from")
    bmin = (centres - radii[:, None]).min(dim=0).values
    bmax = (centres + radii[:, None]).max(dim=0).values
    size = float((bmax - bmin).max()) * 1.01
    return (bmin + bmax) / 2 - size / 2, size


def build_octree(centres, radii, *, depth: int, cell_factor: float = 1.0, lo=None, size: float | None = None
                 ) -> Octree:
    """The balanced octree asked for by boxes ``centres [N, 3] ± radii [N]`` (float64 tensors on one device).

    ``lo``/``size``: the root cube (default: the boxes' bounding cube, 1 % larger)."""
    device = centres.device
    centres = centres.to(torch.float64)
    radii = radii.to(torch.float64)
    if lo is None or size is None:
        lo, size = root_cube(centres, radii)
    lo = torch.as_tensor(lo, dtype=torch.float64, device=device)
    if not (size > 0 and math.isfinite(size)):
        raise GofError(f"octree root cube must have a positive finite size, got {size!r}")
    return tree_from_asked(_asked_cells(centres, radii, lo, float(size), depth, cell_factor), lo, float(size), depth)


def tree_from_asked(asked: list, lo: torch.Tensor, size: float, depth: int) -> Octree:
    """The balanced octree whose leaves are no larger than the asked-for cells: ``asked[l]`` the sorted keys of the
    cells wanted at level ``l`` (``depth + 1`` lists), over the cube ``lo [3] + [0, size]^3``."""
    device = lo.device
    # refined[l]: parents of asked-for cells, then closed under ancestors and balanced, deepest level first
    refined = [torch.zeros(0, dtype=torch.int64, device=device) for _ in range(depth + 1)]
    for l in range(depth, 0, -1):
        parents = _KeySet(device)
        if asked[l].numel():
            parents.add(pack(unpack(asked[l]) >> 1))
        for s in range(0, refined[l].numel(), LEAF_CHUNK):  # the 27 neighbours of a chunk of refined nodes at once
            nb = (unpack(refined[l][s:s + LEAF_CHUNK])[:, None, :] + _NEIGHBOURS.to(device)[None]).reshape(-1, 3)
            nb = nb[((nb >= 0) & (nb < (1 << l))).all(dim=1)]
            parents.add(torch.unique(pack(nb >> 1)))
        refined[l - 1] = parents.sorted()
    tree = Octree(lo=lo, size=float(size), depth=depth, refined=refined)
    # leaves: children of refined nodes that are not refined; the root alone when nothing is refined
    children_of = _CHILDREN.to(device)
    tree.leaves = [torch.zeros(0, dtype=torch.int64, device=device) for _ in range(depth + 1)]
    tree.occupied = [torch.zeros(0, dtype=torch.bool, device=device) for _ in range(depth + 1)]
    if refined[0].numel() == 0:
        tree.leaves[0] = torch.zeros(1, dtype=torch.int64, device=device)
        tree.occupied[0] = torch.ones(1, dtype=torch.bool, device=device)
        return tree
    occ_refined = contains(asked[0], refined[0])
    for l in range(depth):
        if refined[l].numel() == 0:
            break
        ch = pack((unpack(refined[l])[:, None, :] * 2 + children_of[None]).reshape(-1, 3))
        occ_parent = occ_refined.repeat_interleave(8)
        is_ref = contains(refined[l + 1], ch)
        occ_ch = occ_parent | contains(asked[l + 1], ch)
        tree.leaves[l + 1] = ch[~is_ref]
        tree.occupied[l + 1] = occ_ch[~is_ref]
        if l + 1 < depth:
            order = torch.argsort(ch[is_ref])
            occ_refined = occ_ch[is_ref][order]  # aligned with refined[l + 1] (sorted keys)
    return tree


# ---------------------------------------------------------------------------------------------- tetrahedra
def _corner_keys(tree: Octree, chunk: int = LEAF_CHUNK) -> torch.Tensor:
    """Sorted lattice keys of every leaf corner (the vertices a face edge can hang), ``chunk`` leaves at a time."""
    out = _KeySet(tree.lo.device)
    for l, keys in enumerate(tree.leaves):
        u = 1 << (tree.depth + 1 - l)
        for s in range(0, keys.numel(), chunk):
            c = unpack(keys[s:s + chunk]) * u
            out.add(torch.unique(pack((c[:, None, :] + _CHILDREN.to(keys.device)[None] * u).reshape(-1, 3))))
    return out.sorted()


def _plain(tree: Octree, level: int, keys: torch.Tensor, corners: torch.Tensor) -> torch.Tensor:
    """``[L]`` bool: the leaf has no refined face neighbour and no hanging vertex on its 12 edges. Every face of such
    a leaf is split along its ``q0–q2`` diagonal by both leaves that share it, which is how Kuhn's six tetrahedra
    around the main diagonal split a cube's faces: such a leaf needs no centre and half the tetrahedra."""
    c = unpack(keys)
    u = 1 << (tree.depth + 1 - level)
    mids = (c * u)[:, None, :] + _EDGE_MIDPOINTS.to(keys.device)[None] * (u // 2)
    plain = ~contains(corners, pack(mids)).any(dim=1)
    for off in torch.cat([torch.eye(3, dtype=torch.int64), -torch.eye(3, dtype=torch.int64)]).to(keys.device):
        plain &= ~_refined_neighbour(tree, level, c, off)
    return plain


def _refined_neighbour(tree: Octree, level: int, c: torch.Tensor, off: torch.Tensor) -> torch.Tensor:
    """``[L]`` bool: the cell ``c + off`` next to each cell ``c [L, 3]`` of ``level`` lies in the root cube and has
    children (the side of ``c`` facing it is then its four sub-faces)."""
    nb = c + off
    inside = ((nb >= 0) & (nb < (1 << level))).all(dim=1)
    return inside & contains(tree.refined[level], pack(nb.clamp(min=0)))


def _kuhn_tets(keys: torch.Tensor, u: int) -> torch.Tensor:
    """Kuhn's six tetrahedra of each cell ``keys [L]`` of side ``u`` lattice units, as keys ``[6 L, 4]``, positively
    oriented (the templates are)."""
    corner = (unpack(keys) * u)[:, None, None, :] + _KUHN_ORIENTED.to(keys.device)[None] * u  # [L, 6, 4, 3]
    return pack(corner).reshape(-1, 4)


def _face_records(tree: Octree, level: int, keys: torch.Tensor
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The faces of the leaves ``keys`` at ``level`` to triangulate: ``(origin [F, 3], axis [F], width [F],
    centre [F, 3])`` in lattice units; a side next to a refined neighbour gives its four sub-faces."""
    device = keys.device
    c = unpack(keys)
    u = 1 << (tree.depth + 1 - level)
    origin, centre = c * u, c * u + u // 2
    outs = []
    for axis in range(3):
        e = torch.zeros(3, dtype=torch.int64, device=device)
        e[axis] = 1
        b, cc = [(axis + 1) % 3, (axis + 2) % 3]
        eb = torch.zeros(3, dtype=torch.int64, device=device)
        ec = torch.zeros(3, dtype=torch.int64, device=device)
        eb[b], ec[cc] = 1, 1
        for side in (0, 1):
            split = _refined_neighbour(tree, level, c, e if side else -e)
            plane = origin + e * (u * side)
            whole = ~split
            outs.append((plane[whole], torch.full((int(whole.sum()),), axis, device=device), u, centre[whole]))
            if bool(split.any()):
                p, h = plane[split], u // 2
                for db, dc in ((0, 0), (1, 0), (0, 1), (1, 1)):
                    outs.append((p + eb * (h * db) + ec * (h * dc), torch.full((p.shape[0],), axis, device=device),
                                 h, centre[split]))
    origin = torch.cat([o[0] for o in outs])
    axis = torch.cat([o[1] for o in outs])
    width = torch.cat([torch.full((o[0].shape[0],), o[2], dtype=torch.int64, device=device) for o in outs])
    centres = torch.cat([o[3] for o in outs])
    return origin, axis, width, centres


def _face_tets(origin, axis, width, centre, corners: torch.Tensor) -> torch.Tensor:
    """Tetrahedra (cell centre + one triangle of a face) as lattice keys ``[T, 4]`` for the given face records."""
    device = origin.device
    n = origin.shape[0]
    eye = torch.eye(3, dtype=torch.int64, device=device)
    eb, ec = eye[(axis + 1) % 3], eye[(axis + 2) % 3]  # [F, 3]
    w = width[:, None]
    q = torch.stack([origin, origin + eb * w, origin + (eb + ec) * w, origin + ec * w], 1)  # [F, 4, 3] around
    m = (q + q.roll(-1, dims=1)) // 2  # [F, 4, 3] edge midpoints (q_e + q_{e+1}) / 2
    qk, mk = pack(q), pack(m)
    hang = contains(corners, mk)  # [F, 4]
    fan = hang.any(dim=1)
    fc = pack(origin + (eb + ec) * (w // 2))  # [F]
    ck = pack(centre)
    # candidate triangles: 8 fan slots (per edge: q_e→m_e and m_e→q_{e+1}, or q_e→q_{e+1}) + 2 diagonal slots
    q_next = qk.roll(-1, dims=1)
    a = torch.stack([qk, mk], 2).reshape(n, 8)
    b = torch.stack([torch.where(hang, mk, q_next), q_next], 2).reshape(n, 8)
    ok_fan = torch.stack([torch.ones_like(hang), hang], 2).reshape(n, 8) & fan[:, None]
    tri_fan = torch.stack([fc[:, None].expand(n, 8), a, b], 2)  # [F, 8, 3]
    tri_diag = torch.stack([qk[:, [0, 0]], qk[:, [1, 2]], qk[:, [2, 3]]], 2)  # [F, 2, 3]
    ok_diag = (~fan)[:, None].expand(n, 2)
    tri = torch.cat([tri_fan, tri_diag], 1)[torch.cat([ok_fan, ok_diag], 1)]  # [T, 3]
    owner = torch.arange(n, device=device)[:, None].expand(n, 10)[torch.cat([ok_fan, ok_diag], 1)]
    return torch.cat([ck[owner][:, None], tri], 1)


def _orient(tets_xyz: torch.Tensor) -> torch.Tensor:
    """``[T]`` bool: the tetrahedron ``[T, 4, 3]`` (lattice coordinates) has negative volume."""
    d = (tets_xyz[:, 1:] - tets_xyz[:, :1]).to(torch.float64)  # [T, 3, 3]
    return (d[:, 0] * torch.linalg.cross(d[:, 1], d[:, 2])).sum(dim=1) < 0


def _oriented(tets: torch.Tensor, xyz: torch.Tensor) -> torch.Tensor:
    """``tets [T, 4]`` (any dtype) with corners 1 and 2 swapped where ``xyz [T, 4, 3]`` (their lattice coordinates)
    has negative volume, in place."""
    flip = _orient(xyz)
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return tets


# Kuhn's tetrahedra positively oriented once, so the cubes' tetrahedra need no volume test
_KUHN_ORIENTED = _oriented(_KUHN.clone(), _KUHN)


def _oriented_chunks(tree: Octree, corners: torch.Tensor, chunk: int):
    """The occupied leaves' tetrahedra as lattice keys ``[T_c, 4]``, positively oriented: level by level, ``chunk``
    leaves at a time (their Kuhn cubes, then their cones' face records ``chunk`` at a time). The same chunks in the
    same order on every call: the order of :class:`OctreeTets`' tetrahedra."""
    for level in range(tree.depth + 1):
        keys = tree.leaves[level][tree.occupied[level]]
        u = 1 << (tree.depth + 1 - level)
        for s in range(0, keys.numel(), chunk):
            part = keys[s:s + chunk]
            plain = _plain(tree, level, part, corners)
            cubes, cones = part[plain], part[~plain]
            if cubes.numel():
                yield _kuhn_tets(cubes, u)
            if cones.numel():
                rec = _face_records(tree, level, cones)
                for f in range(0, rec[0].shape[0], chunk):
                    t = _face_tets(*(r[f:f + chunk] for r in rec), corners)
                    yield _oriented(t, unpack(t))


@dataclass
class OctreeTets:
    """The occupied leaves' tetrahedra, made on demand: ``points [P, 3]`` float32 (world) and their sorted lattice
    ``keys [P]`` int64 are held; the ``count`` tetrahedra are written as int32 indices into ``points``, positively
    oriented, in **pieces**: :meth:`pieces` cuts the one order of the chunks into consecutive ranges, so pieces
    ``0 … n-1`` concatenated are :meth:`all` and a caller (or a process of several) can take any of them alone."""

    tree: Octree
    corners: torch.Tensor  # sorted keys of the leaves' corners (where a face edge can hang a vertex)
    keys: torch.Tensor  # [P] int64, sorted: point i has lattice key keys[i]
    points: torch.Tensor  # [P, 3] float32 world positions
    count: int  # tetrahedra
    chunk: int = LEAF_CHUNK
    # [P] bool: the point lies in some Gaussian's oriented 3σ box (gof_warp.mesh.reach), set by the caller that has the
    # Gaussians' rotations (gof_warp.mesh.tetra.octree_tets_from_gaussians with OctreeConfig.reach_filter); None: not asked
    reach: torch.Tensor | None = None

    def pieces(self, n_pieces: int, first: int = 0, last: int | None = None):
        """Yield ``(k, tets [T_k, 4] int32)`` for the pieces ``first <= k < last`` of ``n_pieces`` (the ranges of
        :func:`~gof_warp.core.arrays.even_split`: sizes differ by at most one tetrahedron). Every chunk is made (to know
        where each piece starts) but only the wanted pieces' tetrahedra are written as indices, and one piece is held
        at a time."""
        if n_pieces < 1:
            raise GofError(f"n_pieces must be >= 1, got {n_pieces!r}")
        last = n_pieces if last is None else last
        if not 0 <= first <= last <= n_pieces:
            raise GofError(f"pieces [{first}, {last}) do not lie in [0, {n_pieces})")
        bounds, k, parts, at = even_split(self.count, n_pieces), first, [], 0

        def piece():
            out = torch.cat(parts) if parts else torch.zeros(0, 4, dtype=torch.int32, device=self.keys.device)
            parts.clear()
            return out

        if k < last:
            for t in _oriented_chunks(self.tree, self.corners, self.chunk):
                end = at + t.shape[0]
                while k < last:
                    lo, hi = max(bounds[k], at), min(bounds[k + 1], end)
                    if lo < hi:
                        parts.append(torch.searchsorted(self.keys, t[lo - at:hi - at]).to(torch.int32))
                    if bounds[k + 1] > end:
                        break
                    yield k, piece()
                    k += 1
                at = end
                if k >= last:
                    return
        while k < last:  # pieces that end where the tetrahedra do (or none at all)
            yield k, piece()
            k += 1

    def all(self) -> torch.Tensor:
        """Every tetrahedron, ``[count, 4]`` int32 (one piece)."""
        return next(self.pieces(1))[1]


def octree_tets(tree: Octree, *, chunk: int = LEAF_CHUNK) -> OctreeTets:
    """The grid's points and how to make its tetrahedra (:class:`OctreeTets`): one pass over the chunks collects the
    distinct vertex keys and counts the tetrahedra; none is kept."""
    device = tree.lo.device
    corners = _corner_keys(tree, chunk)
    found, count = _KeySet(device), 0
    for t in _oriented_chunks(tree, corners, chunk):
        found.add(torch.unique(t))
        count += t.shape[0]
    keys = found.sorted()
    del found
    if keys.numel() >= 2**31:
        raise GofError(f"octree grid has {keys.numel()} points: more than int32 tetrahedra can index")
    points = torch.empty(keys.numel(), 3, dtype=torch.float32, device=device)
    for s in range(0, keys.numel(), POINT_CHUNK):
        points[s:s + POINT_CHUNK] = (tree.lo + unpack(keys[s:s + POINT_CHUNK]).to(torch.float64) * tree.unit()
                                     ).to(torch.float32)
    return OctreeTets(tree=tree, corners=corners, keys=keys, points=points, count=count, chunk=chunk)


def octree_tetrahedra(tree: Octree, *, chunk: int = LEAF_CHUNK, return_keys: bool = False):
    """Tetrahedralise the occupied leaves: ``(points [P, 3] float32 world, tets [T, 4] int32)``, positively
    oriented, on the tree's device (:func:`octree_tets`, all of it at once); with ``return_keys`` also the points'
    lattice keys ``[P]``."""
    grid = octree_tets(tree, chunk=chunk)
    return (grid.points, grid.all(), grid.keys) if return_keys else (grid.points, grid.all())


def octree_grid_tets(centres, radii, config: OctreeConfig | None = None, stats: dict | None = None,
                     small_grid: str = "finer") -> OctreeTets | None:
    """Boxes ``centres [N, 3] ± radii [N]`` → the grid (:class:`OctreeTets`: points held, tetrahedra made on demand)
    on their device (see the module docstring); ``stats`` gets the counts.

    ``small_grid``: what a small grid gets (``config.cell_factor`` None and fewer than ``config.small_leaves`` leaves at
    ``DEFAULT_CELL_FACTOR``): ``"finer"`` the grid at ``SMALL_CELL_FACTOR``; ``"none"`` nothing: None is returned (the
    caller meshes it on another grid; ``stats`` still gets ``octree_leaves`` at the default factor)."""
    if small_grid not in ("finer", "none"):
        raise GofError(f"octree small_grid must be 'finer' or 'none', got {small_grid!r}")
    cfg = config or OctreeConfig()
    cfg.validate()
    centres = torch.as_tensor(centres).to(torch.float64)
    radii = torch.as_tensor(radii, device=centres.device).to(torch.float64).reshape(-1)
    if centres.ndim != 2 or centres.shape[1] != 3 or radii.shape[0] != centres.shape[0]:
        raise GofError(f"centres [N, 3] and radii [N] disagree: {tuple(centres.shape)}, {tuple(radii.shape)}")
    if not bool(torch.isfinite(centres).all() and torch.isfinite(radii).all()) or bool((radii <= 0).any()):
        raise GofError("octree boxes need finite centres and positive finite radii")
    lo = size = None
    if cfg.box_percentile > 0 and centres.shape[0]:
        q = torch.tensor([cfg.box_percentile / 100, 1 - cfg.box_percentile / 100], dtype=torch.float64,
                         device=centres.device)
        lo_b = torch.quantile(centres - radii[:, None], q[0], dim=0)
        hi_b = torch.quantile(centres + radii[:, None], q[1], dim=0)
        size = float((hi_b - lo_b).max()) * 1.01
        lo = (lo_b + hi_b) / 2 - size / 2
        inside = ((centres >= lo) & (centres <= lo + size)).all(dim=1)
        centres, radii = centres[inside], radii[inside]
    factor = DEFAULT_CELL_FACTOR if cfg.cell_factor is None else cfg.cell_factor
    tree = build_octree(centres, radii, depth=cfg.depth, cell_factor=factor, lo=lo, size=size)
    if cfg.cell_factor is None and tree.n_leaves < cfg.small_leaves:
        if small_grid == "none":
            if stats is not None:
                stats.update(octree_cell_factor=factor, octree_leaves=tree.n_leaves)
            log.info("octree grid: %d leaves at cell factor %g, fewer than %d: a small grid", tree.n_leaves, factor,
                     cfg.small_leaves)
            return None
        factor = SMALL_CELL_FACTOR  # a small grid: the finer one costs a second or two
        tree = build_octree(centres, radii, depth=cfg.depth, cell_factor=factor, lo=lo, size=size)
    grid = octree_tets(tree)
    if stats is not None:
        stats.update(octree_cell_factor=factor, octree_leaves=tree.n_leaves,
                     octree_occupied=sum(int(o.sum()) for o in tree.occupied),
                     octree_levels={l: int(k.numel()) for l, k in enumerate(tree.leaves) if k.numel()})
    log.info("octree grid: %d leaves, %d points, %d tetrahedra", tree.n_leaves, grid.points.shape[0], grid.count)
    return grid


def octree_grid(centres, radii, config: OctreeConfig | None = None, stats: dict | None = None
                ) -> tuple[torch.Tensor, torch.Tensor, Octree]:
    """:func:`octree_grid_tets` with the tetrahedra made at once: ``(points [P, 3] float32, tets [T, 4] int32,
    tree)``."""
    grid = octree_grid_tets(centres, radii, config, stats)
    return grid.points, grid.all(), grid.tree
