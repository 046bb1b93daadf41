"""The Gaussians' reach (gof_warp.mesh.reach, kernels/reach.py): points inside oriented boxes, hand-placed and against the
float64 brute force, and the octree grid's reach filter in the extraction."""

import math

import numpy as np
import pytest
import torch
import trimesh

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.cli.extract import MeshConfig, StageTimer, extract_mesh
from gof_warp.core.model import Gaussians
from gof_warp.mesh.octree_tets import OctreeConfig
from gof_warp.mesh.reach import points_in_boxes, points_in_boxes_reference
from gof_warp.rendering.render import RenderConfig
from gof_warp.mesh.tetra import TetraConfig, octree_tets_from_gaussians


def _quat_z(angle):
    """wxyz quaternion of a rotation by ``angle`` about +z."""
    return [math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)]


def test_a_rotated_box_holds_the_points_placed_by_hand(device):
    """One box rotated 45° about z, half extents (1, 0.1, 0.1): its long axis is the diagonal x = y. A point on that
    diagonal 0.85 from the centre is in; 1.06 along it is out; (0.6, -0.6, 0) lies in the box's axis-aligned bounds
    (±0.78) but 0.85 across the long axis: out. A second, unrotated box given as a non-unit quaternion
    (normalised) holds (5.05, 0, 0.19) and not (5.05, 0, 0.21)."""
    means = torch.tensor([[0.0, 0, 0], [5.0, 0, 0]])
    rotations = torch.tensor([_quat_z(math.pi / 4), [3.0, 0, 0, 0]])
    half = torch.tensor([[1.0, 0.1, 0.1], [0.1, 0.2, 0.2]])
    points = torch.tensor([[0.6, 0.6, 0.0], [0.75, 0.75, 0.0], [0.6, -0.6, 0.0], [0.6, 0.6, 0.09], [0.6, 0.6, 0.11],
                           [5.05, 0.0, 0.19], [5.05, 0.0, 0.21], [2.5, 0.0, 0.0]])
    want = [True, False, False, True, False, True, False, False]
    assert points_in_boxes(points.to(device), means, rotations, half).tolist() == want
    assert points_in_boxes_reference(points, means, rotations, half).tolist() == want


def test_the_kernel_matches_the_float64_brute_force_on_random_boxes(device):
    """300 random boxes (sizes over two decades, every rotation) and 20,000 points: the same answer as the float64
    brute force wherever no face is within float32 rounding of the point (checked: there are fewer than 10 such)."""
    g = torch.Generator().manual_seed(3)
    n, p = 300, 20_000
    means = torch.rand(n, 3, generator=g, dtype=torch.float64) * 4
    rotations = torch.randn(n, 4, generator=g, dtype=torch.float64)
    half = 10 ** (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 2) * 0.6
    points = torch.rand(p, 3, generator=g, dtype=torch.float64) * 4
    got = points_in_boxes(points.to(device), means, rotations, half).cpu()
    want = points_in_boxes_reference(points, means, rotations, half)
    near_face = (points_in_boxes_reference(points, means, rotations, half * (1 + 1e-5))
                 ^ points_in_boxes_reference(points, means, rotations, half * (1 - 1e-5)))
    assert int(near_face.sum()) < 10
    assert 0.05 * p < int(want.sum()) < 0.95 * p  # the test has both kinds of points
    assert torch.equal(got[~near_face], want[~near_face])


def test_degenerate_inputs_give_answers_or_clear_errors():
    """No Gaussians or no points: an empty answer of the right length. A box of zero extent holds its own centre only.
    NaNs, a zero quaternion, negative extents and mismatched shapes are named."""
    pts = torch.tensor([[0.0, 0, 0], [0.01, 0, 0]])
    assert points_in_boxes(pts, torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3)).tolist() == [False, False]
    assert points_in_boxes(torch.zeros(0, 3), torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]),
                           torch.ones(1, 3)).shape == (0,)
    assert points_in_boxes(pts, torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.zeros(1, 3)).tolist() == [
        True, False]
    one = (torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1, 3))
    with pytest.raises(GofError, match="points has NaN"):
        points_in_boxes(torch.tensor([[math.nan, 0, 0]]), *one)
    with pytest.raises(GofError, match="zero quaternions"):
        points_in_boxes(pts, one[0], torch.zeros(1, 4), one[2])
    with pytest.raises(GofError, match="half_extents must be >= 0"):
        points_in_boxes(pts, one[0], one[1], -torch.ones(1, 3))
    with pytest.raises(GofError, match="one row per Gaussian"):
        points_in_boxes(pts, torch.zeros(2, 3), one[1], one[2])
    with pytest.raises(GofError, match=r"rotations must be a \[\*, 4\]"):
        points_in_boxes(pts, one[0], torch.ones(1, 3), one[2])


def _ring_cameras(n=16, size=64):
    return [look_at([2.0 * np.cos(2 * np.pi * a / n), 2.0 * np.sin(2 * np.pi * a / n), 0.9 * np.sin(6 * np.pi * a / n)],
                    [0, 0, 0], fx=80, width=size, height=size, name=f"c{a:02d}") for a in range(n)]


def _disc():
    """A flat, tilted Gaussian (3σ box 0.9 × 0.9 × 0.06): its octree cells reach far above and below it."""
    return Gaussians.from_activated(np.zeros((1, 3)), [_quat_z(0.3)], [[0.3, 0.3, 0.02]], [0.9], device="cpu")


def test_the_octree_grid_marks_the_points_in_reach():
    """octree_tets_from_gaussians with the reach filter: ``grid.reach`` is the brute force's answer for the grid's
    points and the Gaussian's 3σ box; off (the default), it is not computed."""
    g = _disc()
    stats = {}
    assert not OctreeConfig().reach_filter
    cfg = TetraConfig(grid="octree", octree=OctreeConfig(cell_factor=0.25, reach_filter=True))
    grid = octree_tets_from_gaussians(g.means, g.rotations, g.scales, g.opacities, None, cfg, stats=stats)
    want = points_in_boxes_reference(grid.points, g.means, g.rotations, 3.0 * g.scales)
    assert torch.equal(grid.reach, want) and 0 < stats["octree_points_in_reach"] == int(want.sum()) < len(want)
    cfg.octree.reach_filter = False
    assert octree_tets_from_gaussians(g.means, g.rotations, g.scales, g.opacities, None, cfg).reach is None


def test_reach_filter_drops_tetrahedra_but_not_the_surface_of_one_gaussian():
    """One flat Gaussian: its 0.5 level lies inside its 3σ box, so every tetrahedron the level crosses has a vertex in
    reach and the filter leaves the mesh as it was, bit for bit (closed), while it leaves out most of the octree's
    tetrahedra; every tetrahedron is counted once (marched, out of view or out of reach)."""
    cams = _ring_cameras()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    meshes, counts = {}, {}
    for on in (True, False):
        timer = StageTimer("cpu")
        cfg = MeshConfig(binary_steps=4, tetra=TetraConfig(octree=OctreeConfig(cell_factor=0.25, reach_filter=on)))
        (meshes[on],) = extract_mesh(_disc(), cams, cfg, render_config=cfg_render, timer=timer)
        counts[on] = timer.stages["counts"]
    on, off = counts[True], counts[False]
    assert on["tetrahedra_made"] == off["tetrahedra_made"]
    assert on["tetrahedra"] + on["tetrahedra_out_of_view"] + on["tetrahedra_out_of_reach"] == on["tetrahedra_made"]
    assert on["tetrahedra_out_of_reach"] > 0.3 * on["tetrahedra_made"] and "tetrahedra_out_of_reach" not in off
    (v1, f1), (v2, f2) = meshes[True], meshes[False]
    assert len(f1) >= 8 and np.array_equal(v1, v2) and np.array_equal(f1, f2)
    assert trimesh.Trimesh(v1, f1).is_watertight
    with pytest.raises(ValueError, match="--grid octree"):  # an octree setting on the Delaunay grid: not ignored
        MeshConfig(tetra=TetraConfig(grid="delaunay", octree=OctreeConfig(reach_filter=True))).validate()
