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

Coordinates are integers on the lattice of the finest level's half cells: ``2^(depth+1)`` units along the root cube,
21 bits per axis packed in one int64 key (``depth <= 19``: the far corner, ``2^(depth+1)``, must fit). Points are ``lo + key · size / 2^(depth+1)``.

Counts (per leaf): 6 tetrahedra and no extra point for a leaf with no finer neighbour; next to finer leaves one
centre and 12 to 96 tetrahedra. Memory (on the device): the asked-for cells are gathered one box offset at a time
(``N`` int64 candidates and the distinct cells); the tree holds int64 keys per cell (the balance looks at 27
neighbours of each refined node of one level at a time); the tetrahedra are made twice in chunks of ``FACE_CHUNK``
face records — once for the distinct vertex keys, once to write indices — so beyond the output (16 B per
tetrahedron, 12 B per point) one chunk's work is held (~0.7 GB).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import torch

from .errors import GofError

log = logging.getLogger(__name__)

KEY_BITS = 21
KEY_MASK = (1 << KEY_BITS) - 1
MAX_DEPTH = KEY_BITS - 2  # the lattice has 2^(depth+1) units per axis, and its far corner 2^(depth+1) fits the bits
CLAMP_WARN_FRACTION = 0.01  # warn when more Gaussians than this get cells larger than asked (the deepest level)
FACE_CHUNK = 1 << 20  # face records per tetrahedron chunk (~0.7 GB of int64 work at 10 candidate triangles each)

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


@dataclass
class OctreeConfig:
    """Settings of the octree grid (``TetraConfig.grid = "octree"``)."""

    # leaf side <= cell_factor × 2 r over a Gaussian's 3σ box (r = 3 max(s)). 0.5: DTU scan 24 in 4.22M faces (the
    # extraction issue's bar 4.3M; 0.35 gives 7.9M) at the Delaunay grid's accuracy on the garden crop
    # (benchmarks/extract/README.md, session 10)
    cell_factor: float = 0.5
    # deepest level: the root cube's side / 2^depth is the smallest cell. Levels cost only where asked for, so the
    # default is the deepest the keys allow: 5·10^5 cells along the root cube, room for far background Gaussians
    depth: int = MAX_DEPTH
    box_percentile: float = 0.0  # root cube: the box of the 3σ boxes, ignoring this % of the Gaussians per side

    def validate(self):
        if not (self.cell_factor > 0 and math.isfinite(self.cell_factor)):
            raise GofError(f"octree cell_factor must be a positive number, got {self.cell_factor!r}")
        if not (isinstance(self.depth, int) and 1 <= self.depth <= MAX_DEPTH):
            raise GofError(f"octree depth must be an integer in [1, {MAX_DEPTH}], got {self.depth!r}")
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


def _asked_cells(centres: torch.Tensor, radii: torch.Tensor, lo: torch.Tensor, size: float, depth: int,
                 cell_factor: float) -> list[torch.Tensor]:
    """Per level, the sorted keys of the cells some Gaussian asks for: the cells of its level overlapping its box.
    Gathered one box-corner offset at a time, so the work holds ``N`` candidates, not ``27 N``."""
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
    asked = [torch.zeros(0, dtype=torch.int64, device=device) for _ in range(depth + 1)]
    levels_present = torch.unique(level).tolist()
    for off in torch.cartesian_prod(*[torch.arange(span, device=device)] * 3).reshape(-1, 3):
        ijk = first + off
        ok = (ijk <= last).all(dim=1)
        keys, lv = pack(ijk[ok]), level[ok]
        for l in levels_present:
            asked[l] = torch.unique(torch.cat([asked[l], keys[lv == l]]))
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
        parents = [unpack(asked[l]) >> 1] if asked[l].numel() else []
        if refined[l].numel():
            c = unpack(refined[l])
            nb = (c[:, None, :] + _NEIGHBOURS.to(device)[None]).reshape(-1, 3)
            nb = nb[((nb >= 0) & (nb < (1 << l))).all(dim=1)]
            parents.append(nb >> 1)
        if parents:
            refined[l - 1] = torch.unique(torch.cat([refined[l - 1], pack(torch.cat(parents))]))
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
def _corner_keys(tree: Octree) -> torch.Tensor:
    """Sorted lattice keys of every leaf corner (the vertices a face edge can hang)."""
    out = []
    for l, keys in enumerate(tree.leaves):
        if keys.numel():
            u = 1 << (tree.depth + 1 - l)
            out.append(pack(((unpack(keys) * u)[:, None, :] + _CHILDREN.to(keys.device)[None] * u).reshape(-1, 3)))
    return torch.unique(torch.cat(out))


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
    """Kuhn's six tetrahedra of each cell ``keys [L]`` of side ``u`` lattice units, as keys ``[6 L, 4]``."""
    corner = (unpack(keys) * u)[:, None, None, :] + _KUHN.to(keys.device)[None] * u  # [L, 6, 4, 3]
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


def _oriented_chunks(tree: Octree, corners: torch.Tensor, chunk: int):
    """The occupied leaves' tetrahedra as lattice keys ``[T_c, 4]``, positively oriented, a chunk of face records
    at a time (same chunks, same order, on every call)."""
    def oriented(t):
        flip = _orient(unpack(t))
        t[flip] = t[flip][:, [0, 2, 1, 3]]
        return t

    for level in range(tree.depth + 1):
        keys = tree.leaves[level][tree.occupied[level]]
        if keys.numel() == 0:
            continue
        plain = _plain(tree, level, keys, corners)
        cubes, cones = keys[plain], keys[~plain]
        u = 1 << (tree.depth + 1 - level)
        for s in range(0, cubes.shape[0], chunk):
            yield oriented(_kuhn_tets(cubes[s:s + chunk], u))
        if cones.numel():
            rec = _face_records(tree, level, cones)
            for s in range(0, rec[0].shape[0], chunk):
                yield oriented(_face_tets(*(r[s:s + chunk] for r in rec), corners))


def octree_tetrahedra(tree: Octree, *, chunk: int = FACE_CHUNK, return_keys: bool = False):
    """Tetrahedralise the occupied leaves: ``(points [P, 3] float32 world, tets [T, 4] int32)``, positively
    oriented, on the tree's device. Two passes over the chunks (the first collects the distinct vertex keys, the
    second writes point indices), so the int64 keys of one chunk only are held beside the int32 output."""
    device = tree.lo.device
    corners = _corner_keys(tree)
    found, count = [], 0
    for t in _oriented_chunks(tree, corners, chunk):
        found.append(torch.unique(t))
        count += t.shape[0]
    if not count:
        empty = (torch.zeros(0, 3, dtype=torch.float32, device=device),
                 torch.zeros(0, 4, dtype=torch.int32, device=device))
        return (*empty, torch.zeros(0, dtype=torch.int64, device=device)) if return_keys else empty
    keys = torch.unique(torch.cat(found))
    del found
    if keys.numel() >= 2**31:
        raise GofError(f"octree grid has {keys.numel()} points: more than int32 tetrahedra can index")
    tets = torch.empty(count, 4, dtype=torch.int32, device=device)
    at = 0
    for t in _oriented_chunks(tree, corners, chunk):
        tets[at:at + t.shape[0]] = torch.searchsorted(keys, t).to(torch.int32)
        at += t.shape[0]
    points = (tree.lo + unpack(keys).to(torch.float64) * tree.unit()).to(torch.float32)
    return (points, tets, keys) if return_keys else (points, tets)


def octree_grid(centres, radii, config: OctreeConfig | None = None, stats: dict | None = None
                ) -> tuple[torch.Tensor, torch.Tensor, Octree]:
    """Boxes ``centres [N, 3] ± radii [N]`` → ``(points [P, 3] float32, tets [T, 4] int32, tree)`` on their
    device (see the module docstring); ``stats`` gets the counts."""
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
    tree = build_octree(centres, radii, depth=cfg.depth, cell_factor=cfg.cell_factor, lo=lo, size=size)
    points, tets = octree_tetrahedra(tree)
    if stats is not None:
        stats.update(octree_leaves=tree.n_leaves,
                     octree_occupied=sum(int(o.sum()) for o in tree.occupied),
                     octree_levels={l: int(k.numel()) for l, k in enumerate(tree.leaves) if k.numel()})
    log.info("octree grid: %d leaves, %d points, %d tetrahedra", tree.n_leaves, points.shape[0], tets.shape[0])
    return points, tets, tree
