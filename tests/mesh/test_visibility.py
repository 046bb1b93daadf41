"""The faces some camera sees (gof_warp.mesh.visibility, kernels/visibility.py): a hand-built floor with a pocket under it,
random triangle soups against the float64 brute force, and the extraction dropping what no camera sees."""

import dataclasses

import numpy as np
import pytest

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.cli.extract import MeshConfig, StageTimer, extract_mesh
from gof_warp.core.model import Gaussians
from gof_warp.mesh.octree_tets import OctreeConfig
from gof_warp.rendering.render import RenderConfig
from gof_warp.mesh.tetra import TetraConfig
from gof_warp.mesh.visibility import faces_seen, faces_seen_reference


def _square(z, half, lo=0):
    """Two triangles of the square ``[-half, half]² × {z}``: vertices, faces (indices from ``lo``)."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]]) + lo


def _floor_and_pocket():
    """A 2 × 2 floor at z = 0 and a 0.4 × 0.4 square 0.1 under its middle (a skirt under a ground)."""
    v0, f0 = _square(0.0, 1.0)
    v1, f1 = _square(-0.1, 0.2, lo=4)
    return np.vstack([v0, v1]), np.vstack([f0, f1])


def test_a_pocket_under_the_floor_is_hidden_from_above_and_seen_from_below(device):
    """Cameras above the floor see its two triangles and not the square under it; a camera under the floor sees the
    square (and the floor's underside); a camera whose image the square falls outside of sees nothing of it, nor does
    one whose near plane (its own or the one given) lies beyond the floor."""
    v, f = _floor_and_pocket()
    above = [look_at([0.3, 0.2, 3.0], [0, 0, 0], fx=100, width=96, height=96, name="a"),
             look_at([-2.0, 0.5, 1.5], [0, 0, 0], fx=100, width=96, height=96, name="b")]
    below = look_at([0.1, 0.0, -2.0], [0, 0, -0.1], fx=100, width=96, height=96, name="c")
    away = look_at([0.0, 0.0, -2.0], [0, 0, -5.0], fx=100, width=96, height=96, name="d")
    assert faces_seen(v, f, above, device=device).tolist() == [True, True, False, False]
    assert faces_seen(v, f, above + [below], device=device).tolist() == [True, True, True, True]
    assert faces_seen(v, f, [away], device=device).tolist() == [False, False, False, False]
    clipped = dataclasses.replace(above[0], near=3.5)  # its own near plane lies beyond the floor: sees nothing
    assert faces_seen(v, f, [clipped], device=device).tolist() == [False] * 4
    assert faces_seen(v, f, [above[0]], near=3.5, device=device).tolist() == [False] * 4
    for cams in (above, above + [below], [away], [clipped]):
        assert faces_seen(v, f, cams, device=device).tolist() == faces_seen_reference(v, f, cams).tolist()


def test_a_large_face_whose_centre_is_covered_is_seen_by_its_corners(device):
    """The 2 × 2 floor's two triangles under a 1 × 1 lid at z = 0.3, one camera straight above: the lid hides both
    triangles' centroids (±1/3, ∓1/3) but not their outer corners, so the corner probes of these large faces (many
    pixels across) find them seen; the lid is seen too."""
    v0, f0 = _square(0.0, 1.0)
    v1, f1 = _square(0.3, 0.5, lo=4)
    v, f = np.vstack([v0, v1]), np.vstack([f0, f1])
    cam = [look_at([0.0, 0.0, 3.0], [0, 0, 0], up=[0, 1, 0], fx=100, width=200, height=200, name="top")]
    assert faces_seen(v, f, cam, device=device).tolist() == [True] * 4
    assert faces_seen_reference(v, f, cam).tolist() == [True] * 4


def test_the_kernel_matches_the_float64_brute_force_on_triangle_soups(device):
    """400 random triangles in a box seen by 3 cameras around it: the same faces seen as the float64 brute force,
    and both kinds present (301 of 400 seen)."""
    rng = np.random.default_rng(5)
    centres = rng.uniform(-1, 1, (400, 3))
    v = (centres[:, None, :] + rng.normal(0, 0.3, (400, 3, 3))).reshape(-1, 3)
    f = np.arange(1200).reshape(400, 3)
    cams = [look_at([3 * np.cos(a), 3 * np.sin(a), 0.8 * np.cos(3 * a)], [0, 0, 0], fx=60, width=64, height=64,
                    name=f"c{k}") for k, a in enumerate(np.linspace(0, 2 * np.pi, 3, endpoint=False))]
    got = faces_seen(v, f, cams, device=device)
    want = faces_seen_reference(v, f, cams)
    assert 100 < want.sum() < 350
    assert (got != want).sum() <= 2  # a ray that grazes an edge within float32 rounding may go either way


def test_bad_inputs_are_named():
    v, f = _floor_and_pocket()
    cam = [look_at([0, 0, 3.0], [0, 0, 0], fx=100, width=96, height=96, name="a")]
    assert faces_seen(v, np.zeros((0, 3), int), cam).shape == (0,)
    with pytest.raises(GofError, match="at least one camera"):
        faces_seen(v, f, [])
    with pytest.raises(GofError, match="face indices"):
        faces_seen(v, f + 10, cam)
    with pytest.raises(GofError, match="NaN"):
        faces_seen(np.full_like(v, np.nan), f, cam)
    with pytest.raises(GofError, match="eps_px"):
        faces_seen(v, f, cam, eps_px=-1.0)


def test_extraction_keeps_the_faces_the_training_cameras_see():
    """One Gaussian seen by cameras on one side only (x > 0): dropping hidden faces removes the far side's faces and
    keeps exactly the faces the float64 reference says these cameras see; the stage counts the dropped ones. A ring
    of cameras all around sees every face of the closed sphere (nothing dropped)."""
    g = Gaussians.from_activated(np.zeros((1, 3)), [[1.0, 0, 0, 0]], [[0.2] * 3], [0.9], device="cpu")
    ring = [look_at([2.0 * np.cos(a), 2.0 * np.sin(a), 0.9 * np.sin(3 * a)], [0, 0, 0], fx=80, width=64, height=64,
                    name=f"c{k}") for k, a in enumerate(np.linspace(0, 2 * np.pi, 16, endpoint=False))]
    half = [c for c in ring if c.center[0] > 0.5]

    def mesh(cams, drop):
        timer = StageTimer("cpu")
        cfg = MeshConfig(binary_steps=4, drop_hidden=drop,  # the octree's finer mesh: faces on the far side
                         tetra=TetraConfig(grid="octree", octree=OctreeConfig(cell_factor=0.25)))
        (m,) = extract_mesh(g, cams, cfg,
                            render_config=RenderConfig(alpha_min=0.0, k_max=10.0), timer=timer)
        return m, timer.stages.get("hidden_faces")

    (v0, f0), none = mesh(half, False)
    (v1, f1), stage = mesh(half, True)
    assert none is None and stage["dropped"] == [len(f0) - len(f1)] and 0 < len(f1) < len(f0)
    kept = faces_seen_reference(v0, f0, half)
    triangles = lambda v, f: sorted(map(tuple, v[f].reshape(-1, 9).round(6)))  # noqa: E731
    assert triangles(v0, f0[kept]) == triangles(v1, f1)
    (_, f_all), stage_all = mesh(ring, True)
    assert stage_all["dropped"] == [0] and len(f_all) > 0
