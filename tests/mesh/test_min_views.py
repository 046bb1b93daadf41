"""``min_views``: space fewer than K training views see is left out of the field's meshing (extraction) and of the
scored region (evaluation). Hand-built cases: two cameras whose frusta overlap only around the origin, a Gaussian
seen by both and one seen by a single camera."""

import numpy as np
import pytest

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.cli.evaluate import main as evaluate_main
from gof_warp.mesh.extraction import MeshConfig, extract_mesh
from gof_warp.core.model import Gaussians
from gof_warp.rendering.opacity_field import OpacityFieldConfig, opacity_field
from gof_warp.eval.region_metrics import in_region, observe, scored_region, split_triangles
from gof_warp.synthetic import meshes as M
from gof_warp.mesh.tetra import TetraConfig

BOTH = (0.0, 0.0, 0.0)  # seen by both cameras
ONE = (-1.5, 0.0, 0.0)  # behind the origin for camera 0 only: 27 degrees off camera 1's axis, its half-FOV is 15


def two_cameras(size=48, fov_deg=30.0):
    fx = (size / 2) / np.tan(np.deg2rad(fov_deg) / 2)
    return [look_at(eye, (0.0, 0.0, 0.0), fx=fx, width=size, height=size, name=f"c{k}")
            for k, eye in enumerate([(3.0, 0.0, 0.0), (0.0, 3.0, 0.0)])]


def blobs(device="cpu"):
    means = np.array([BOTH, ONE])
    return Gaussians.from_activated(means, np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)), np.full((2, 3), 0.12),
                                    np.full(2, 0.99), device=device)


def test_the_field_counts_points_fewer_views_see_as_unseen():
    cams, g = two_cameras(), blobs()
    pts = np.array([BOTH, ONE, (0.0, 0.0, 5.0)])
    f1, seen = opacity_field(g, cams, pts, return_seen=True)
    assert seen.tolist() == [2, 1, 0]
    f2 = opacity_field(g, cams, pts, config=OpacityFieldConfig(min_views=2, unseen_value=-1.0))
    assert f2[0] == f1[0] and 0.5 < float(f1[0]) <= 1.0  # seen by both: the same minimum
    assert float(f1[1]) > 0.5 and f2[1:].tolist() == [-1.0, -1.0]  # one view: now unseen, as no view
    for bad in (0, 1.5, True):
        with pytest.raises(GofError, match="min_views"):
            opacity_field(g, cams, pts, config=OpacityFieldConfig(min_views=bad))


@pytest.mark.parametrize("grid", ["octree", "delaunay"])
def test_extraction_leaves_out_the_surface_one_view_alone_sees(grid):
    cams, g = two_cameras(), blobs()

    def mesh(k):
        cfg = MeshConfig(field=OpacityFieldConfig(min_views=k), tetra=TetraConfig(grid=grid))
        (v, f), = extract_mesh(g, cams, cfg)
        return v[np.unique(f)]

    def near(v, c):
        return int((np.linalg.norm(v - np.asarray(c), axis=1) < 0.6).sum())

    v1, v2 = mesh(1), mesh(2)
    assert near(v1, ONE) >= 8 and near(v1, BOTH) >= 8  # GOF's setting meshes both blobs
    assert near(v2, ONE) == 0  # min_views 2: nothing where one view alone looks
    assert near(v2, BOTH) >= 0.8 * near(v1, BOTH)  # the blob both views see stays
    with pytest.raises(GofError, match="min_views"):
        MeshConfig(field=OpacityFieldConfig(min_views=0)).validate()


def test_scored_region_with_min_views():
    ground = M.grid_plane(center=(0, 0, 0), half_size=2.0, cell=0.1)
    fx = 24 / np.tan(np.deg2rad(20))
    # two cameras looking down at x = -0.5 and x = +0.5: their footprints overlap around x = 0 only
    cams = [look_at((x, 0.0, 2.0), (x, 0.0, 0.0), up=(0, 1, 0), fx=fx, width=48, height=48, name=f"c{k}")
            for k, x in enumerate((-0.5, 0.5))]
    tri = split_triangles(ground.vertices[ground.faces], 0.1)
    obs = observe(*(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3)), cams)
    assert obs.views.max() == 2 and (obs.views == 1).any() and np.array_equal(obs.seen, obs.views > 0)
    x, y = tri.mean(1)[:, 0], tri.mean(1)[:, 1]  # each footprint: +-0.73 about its centre
    assert (obs.views[(np.abs(x) < 0.1) & (np.abs(y) < 0.5)] == 2).all() and (obs.views[np.abs(x) > 1.0] < 2).all()
    pts = np.array([[0.0, 0.0, 0.5], [-1.0, 0.0, 0.5]])  # above the overlap; above camera 0's side only
    assert in_region(pts, obs, margin=0.1).tolist() == [True, True]
    assert in_region(pts, obs, margin=0.1, min_views=2).tolist() == [True, False]
    r1, r2 = scored_region(tri, cams), scored_region(tri, cams, min_views=2)
    assert r2.seen.sum() < r1.seen.sum() and not (r2.seen & ~r1.seen).any() and r2.seen_area < r1.seen_area
    low = pts * [1, 1, 0.1]  # inside the default box of interest too (the seen GT's box grown by max_dist)
    assert r1.inside(low).tolist() == [True, True] and r2.inside(low).tolist() == [True, False]
    with pytest.raises(GofError, match="min_views"):
        scored_region(tri, cams, min_views=0)


def test_evaluate_cli_min_views_needs_a_scene(tmp_path, capsys):
    mesh = M.grid_plane(center=(0, 0, 0), half_size=1.0, cell=0.5)
    path = tmp_path / "m.ply"
    import trimesh

    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)
    assert evaluate_main(["--mesh", str(path), "--gt", str(path), "--min-views", "2"]) != 0
    assert "--min-views needs --scene" in capsys.readouterr().err
