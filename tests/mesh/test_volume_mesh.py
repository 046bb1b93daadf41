"""A mesh extracted from the baked opacity volume (gof_warp.mesh.volume_mesh) is as good as the tetra mesh of the
same Gaussians (issue 16: "within 2 % Chamfer of the tetra mesh").

Asserted interpretation, on the analytic ground-and-sphere scene of tests/mesh/test_volume.py (GT: the plane z = 0
and the sphere of radius 0.3, scored where the GT is unambiguous — the sphere's upper cap and the ground away
from its edges and from the sphere's foot — with exact point-to-triangle distances):

    Chamfer(volume mesh, GT) ≤ 1.02 · Chamfer(tetra mesh, GT)

i.e. *no more than 2 % worse*. The two-sided reading |C_vol − C_tetra| ≤ 0.02 · C_tetra is not asserted: at the
derived voxel size the volume mesh is ~45 % *closer* to the GT than the tetra mesh (its ground sits nearer
z = 0), which that reading would count as a failure. The direct Chamfer between the two meshes is also
asserted small in the scored region (≤ 0.1 voxel, ≤ 0.1 % of the scene diagonal) and all numbers are printed
(pytest -s). Measured on the 2-core CPU: C_vol = 0.00229, C_tetra = 0.00413 (gap −45 %), between = 0.00222
(0.06 h, 0.08 % of the diagonal); between the whole meshes 0.0059 (0.16 h, 0.2 %): the volume also meshes the
field's 0.5 level below the ground and beyond its edges, where the tetra grid (the Gaussians' 3σ boxes) has no
points.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import warp as wp

from gof_warp.core.errors import GofError
from gof_warp.mesh.extraction import MeshConfig, extract_mesh
from gof_warp.eval.geometry_metrics import evaluate_mesh, mesh_statistics
from gof_warp.mesh.tetra import TetraConfig
from gof_warp.mesh.volume import bake_opacity_volume, sample_volume
from gof_warp.mesh.volume_mesh import volume_mesh
from test_volume import SPHERE_C, SPHERE_R, ground_and_sphere, scene_cameras

CHAMFER_RATIO_MAX = 1.02  # issue 16: the volume mesh within 2 % of the tetra mesh's Chamfer to the GT
BETWEEN_MAX_VOXELS = 0.1  # Chamfer(volume mesh, tetra mesh) in voxels (measured 0.06)


def _gt_mesh() -> trimesh.Trimesh:
    """The scene's ground truth: the plane z = 0 over [−1, 1]² (0.02 triangles) and the sphere (icosphere)."""
    xs = np.linspace(-1.0, 1.0, 101)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    plane = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = np.arange(xs.size ** 2).reshape(xs.size, xs.size)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    sph = trimesh.creation.icosphere(subdivisions=5, radius=SPHERE_R)
    return trimesh.Trimesh(np.concatenate([plane, sph.vertices + SPHERE_C]),
                           np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1), sph.faces + len(plane)]),
                           process=False)


def _scored(p: np.ndarray) -> np.ndarray:
    """Where the GT is unambiguous: the sphere's upper cap, the ground inside [−0.8, 0.8]² away from the sphere's
    foot (the field's level below the ground and under the sphere is not the scene's surface)."""
    r, rxy = np.linalg.norm(p - SPHERE_C, axis=1), np.linalg.norm(p[:, :2], axis=1)
    cap = (np.abs(r - SPHERE_R) < 0.1) & (p[:, 2] > 0.3)
    ground = (np.abs(p[:, :2]) < 0.8).all(axis=1) & (np.abs(p[:, 2]) < 0.1) & (rxy > 0.5)
    return cap | ground


@pytest.fixture(scope="module")
def scene_meshes():
    g, cams = ground_and_sphere(), scene_cameras()
    vol, info = bake_opacity_volume(g, cams)  # the derived voxel size, h = 0.0375
    verts, faces = volume_mesh(vol, info)
    # the reference: the official GOF mesh (Delaunay grid); the default octree grid's mesh is coarser here (0.12 % of
    # the diagonal from the volume mesh against the 0.1 % this test allows the Delaunay one)
    (tv, tf), = extract_mesh(g, cams, MeshConfig(method="tetra", binary_steps=8, tetra=TetraConfig(grid="delaunay")))
    return vol, info, (verts, faces), (tv, tf)


def test_volume_mesh_is_within_2_percent_chamfer_of_the_tetra_mesh(scene_meshes):
    vol, info, (verts, faces), (tv, tf) = scene_meshes
    h = info["voxel_size"]
    assert verts.dtype == np.float32 and faces.dtype == np.int32 and verts.shape[1] == faces.shape[1] == 3
    assert len(faces) > 1000 and faces.min() >= 0 and faces.max() < len(verts)
    assert mesh_statistics((verts, faces))["winding_consistent"]
    gt = _gt_mesh()
    # sample spacing 0.016 (~10k scored samples a side, ~2 a voxel): the Chamfers match the 0.008 spacing's to 1e-5
    # (0.00229, 0.00413, 0.00221; seeds 0 and 1) at a quarter of the exact-distance work (27 -> 7 s on the 2-core box)
    kw = dict(density=0.016, max_dist=0.1, tau=[0.01, 0.02], crop=_scored, method="triangles")
    vmesh, tmesh = trimesh.Trimesh(verts, faces, process=False), trimesh.Trimesh(tv, tf, process=False)
    ev, et = evaluate_mesh(vmesh, gt, **kw)["metrics"], evaluate_mesh(tmesh, gt, **kw)["metrics"]
    between = evaluate_mesh(vmesh, tmesh, **kw)["metrics"]["chamfer"]  # where the GT is scored
    diag = float(np.linalg.norm(gt.vertices.max(0) - gt.vertices.min(0)))
    gap = (ev["chamfer"] - et["chamfer"]) / et["chamfer"]
    print(f"\nh={h:.4f} ({info['bytes'] / 1e6:.2f} MB): Chamfer to GT volume {ev['chamfer']:.5f} "
          f"(F@1cm {ev['fscore'][0]:.3f}), tetra {et['chamfer']:.5f} (F {et['fscore'][0]:.3f}), gap {gap:+.1%}; "
          f"volume↔tetra {between:.5f} = {between / h:.3f} h = {between / diag:.2e} of the diagonal")
    assert ev["chamfer"] <= CHAMFER_RATIO_MAX * et["chamfer"], (ev["chamfer"], et["chamfer"])
    assert between <= BETWEEN_MAX_VOXELS * h and between <= 1e-3 * diag, (between, h, diag)


def test_vertices_are_on_the_volume_level_set_and_no_false_shell(scene_meshes):
    vol, info, (verts, faces), _ = scene_meshes
    h = info["voxel_size"]
    # bisection on the trilinear field: the volume reads the level at every vertex (unstored stencils aside)
    val = sample_volume(vol, verts)
    assert np.percentile(np.abs(val - 0.5), 99) < 1e-3, np.percentile(np.abs(val - 0.5), [50, 99, 100])
    lin, _ = volume_mesh(vol, info, binary_steps=0)  # on lattice edges the trilinear field is linear
    assert np.abs(lin - verts).max() < 1e-3 * h
    # the band ends inside the sphere (background 0 there): no shell may appear inside it
    r = np.linalg.norm(verts - SPHERE_C, axis=1)
    assert not np.any(r < SPHERE_R - 3 * h), np.sort(r)[:5]
    # lattice: every vertex within the stored voxels' index box
    assert np.all(verts >= np.asarray(info["bounds_min"]) - 1e-4) and np.all(verts <= np.asarray(info["bounds_max"]) + 1e-4)


def test_bisection_on_the_exact_field_puts_vertices_on_its_level_set(scene_meshes):
    """``exact_field``: the lattice's crossings refined on the field the volume was baked from (its samples at
    the lattice nodes are exact), so the vertices read 0.5 on the exact field, not only on the trilinear one."""
    from gof_warp.rendering.opacity_field import opacity_field

    vol, info, (verts, faces), _ = scene_meshes
    g, cams = ground_and_sphere(), scene_cameras()
    exact = lambda x: opacity_field(g, cams, x).cpu().numpy()  # noqa: E731
    ev, ef = volume_mesh(vol, info, binary_steps=10, exact_field=exact)
    assert ef.shape == faces.shape and np.array_equal(ef, faces)  # the same lattice crossings, moved along their edges
    on_exact, on_trilinear = np.abs(exact(ev) - 0.5), np.abs(exact(verts) - 0.5)
    # where the band's filled (not baked) nodes make a crossing, the exact field has none on that edge: those
    # vertices end at an edge end; everywhere else they sit on the exact level
    close_exact, close_trilinear = np.mean(on_exact < 1e-3), np.mean(on_trilinear < 1e-3)
    print(f"vertices within 1e-3 of the exact level: {close_exact:.3f} (exact search) vs {close_trilinear:.3f} "
          f"(trilinear); medians {np.median(on_exact):.2e} vs {np.median(on_trilinear):.2e}")
    assert close_exact > 0.9 and close_exact > close_trilinear + 0.2 and np.median(on_exact) < 1e-4
    assert np.abs(ev - verts).max() <= info["voxel_size"] * (1 + 1e-4)  # still on their lattice edges


def test_bad_inputs_are_clear_errors(scene_meshes):
    vol, info, _, _ = scene_meshes
    with pytest.raises(GofError, match="wp.Volume"):
        volume_mesh(np.zeros((4, 4, 4)), info)
    with pytest.raises(GofError, match="info"):
        volume_mesh(vol, {"voxel_size": 0.1})
    with pytest.raises(GofError, match="another volume"):
        volume_mesh(vol, info | {"voxel_size": 2 * info["voxel_size"]})
    with pytest.raises(GofError, match="level"):
        volume_mesh(vol, info, level=1.0)
    with pytest.raises(GofError, match="binary_steps"):
        volume_mesh(vol, info, binary_steps=-1)
    with pytest.raises(GofError, match="max_nodes"):
        volume_mesh(vol, info, max_nodes=1000)
    zeros = wp.Volume.allocate(min=[0, 0, 0], max=[7, 7, 7], voxel_size=0.1, bg_value=0.0, device="cpu")
    v, f = volume_mesh(zeros, {"origin": [0, 0, 0], "voxel_size": 0.1})  # stored, but nothing crosses 0.5
    assert v.shape == (0, 3) and f.shape == (0, 3)
