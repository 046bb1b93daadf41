"""The public Warp surface: ``gof_warp.kernels.__all__`` (documented, torch-free) and marching tetrahedra on a
user's ``@wp.func`` field (``make_field_kernel``), which must give what the host-callback path gives.

Float64 references: the fields below in numpy float64.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import gof_warp.kernels as K
from gof_warp.core.errors import GofError
from gof_warp.kernels import marching_tets as mt
from gof_warp.mesh.marching import marching_cubes, marching_tetrahedra

FIELD_TOL = 1e-6  # float32 field vs float64 reference, values of order 1
SAME_PATH_TOL = 1e-5  # wp.func vs numpy callback of the same float32 field: bisection ends agree to float32 rounding
RADIUS = 0.7


@wp.func
def sphere_field(x: wp.vec3) -> float:
    """``r² − |x|²`` (inside the ball of radius ``RADIUS``)."""
    return RADIUS * RADIUS - wp.dot(x, x)


def sphere_field_np(x):
    x = np.asarray(x, np.float64)
    return RADIUS**2 - (x**2).sum(1)


@wp.struct
class Blobs:
    centres: wp.array(dtype=wp.vec3)
    weight: float


@wp.func
def blob_field(x: wp.vec3, p: Blobs) -> float:
    """Sum of Gaussians ``weight · exp(−|x − c|²)`` over the centres."""
    s = float(0.0)
    for k in range(p.centres.shape[0]):
        d = x - p.centres[k]
        s += p.weight * wp.exp(-wp.dot(d, d))
    return s


def grid_tets(n=9, half=1.0):
    """A regular grid ``[n³, 3]`` split into Kuhn tetrahedra (6 per cube)."""
    axis = np.linspace(-half, half, n)
    pts = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    c = np.stack(np.meshgrid(*[np.arange(n - 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    e = np.eye(3, dtype=np.int64)
    idx = lambda ijk: (ijk[:, 0] * n + ijk[:, 1]) * n + ijk[:, 2]  # noqa: E731
    tets = [np.stack([idx(c), idx(c + e[a]), idx(c + e[a] + e[b]), idx(c + 1)], 1)
            for a, b in [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]]
    return pts, np.concatenate(tets).astype(np.int32)


# ---------------------------------------------------------------------------------------------- __all__
def test_every_public_name_exists_and_is_documented():
    assert len(K.__all__) == len(set(K.__all__)) >= 40
    modules = {p.stem for p in Path(K.__file__).parent.glob("*.py")}
    assert not set(K.__all__) & modules, "a submodule import would shadow a public name"
    for name in K.__all__:
        value = getattr(K, name)
        doc = getattr(value, "__doc__", None)
        assert doc and doc.strip(), f"gof_warp.kernels.{name} has no docstring"
        assert name in dir(K)
    with pytest.raises(AttributeError):
        K.not_a_kernel  # noqa: B018


def test_public_names_cover_what_a_warp_user_needs():
    kinds = {name: type(getattr(K, name)) for name in K.__all__}
    for name in ("preprocess_gaussians", "screen_bounds", "opacity_min_over_view", "count_triangles",
                 "update_brackets", "integrate_tsdf"):
        assert kinds[name] is wp.Kernel, name
    for name in ("ray_gaussian", "opacity_along_ray", "tet_case", "quat_to_rotation"):
        assert kinds[name] is wp.Function, name
    for name in ("render_gaussians", "render_forward", "render_backward", "make_field_kernel", "cast_pinhole_rays"):
        assert callable(getattr(K, name)), name


@pytest.mark.slow
def test_importing_kernels_and_marching_does_not_import_torch(tmp_path):
    code = ("import sys, gof_warp.kernels as K\n"
            "[getattr(K, n) for n in K.__all__]\n"
            "import gof_warp.mesh.marching\n"
            "assert 'torch' not in sys.modules, 'torch was imported'\n"
            "print('ok', len(K.__all__))\n")
    env = dict(os.environ, WARP_CACHE_PATH=os.environ.get("WARP_CACHE_PATH", ""))
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.startswith("ok")


# ---------------------------------------------------------------------------------------------- field kernels
@pytest.mark.slow
def test_make_field_kernel_matches_float64(device):
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (257, 3)).astype(np.float32)
    points = wp.array(x, dtype=wp.vec3, device=device)
    values = wp.empty(257, dtype=wp.float32, device=device)
    wp.launch(mt.make_field_kernel(sphere_field), dim=257, inputs=[points], outputs=[values], device=device)
    assert np.abs(values.numpy() - sphere_field_np(x)).max() < FIELD_TOL

    params = Blobs()
    centres = np.array([[0.3, 0.0, 0.0], [-0.3, 0.1, 0.2]], np.float32)
    params.centres, params.weight = wp.array(centres, dtype=wp.vec3, device=device), 0.8
    wp.launch(mt.make_field_kernel(blob_field), dim=257, inputs=[points, params], outputs=[values], device=device)
    ref = 0.8 * np.exp(-((x[:, None, :].astype(np.float64) - centres[None]) ** 2).sum(2)).sum(1)
    assert np.abs(values.numpy() - ref).max() < FIELD_TOL


def test_field_signatures_are_checked():
    assert mt.field_params_type(sphere_field) is None
    assert mt.field_params_type(blob_field) is Blobs
    with pytest.raises(TypeError, match="it takes 3 arguments"):
        mt.field_params_type(mt.edge_key)
    with pytest.raises(TypeError, match="first argument must be wp.vec3"):
        mt.field_params_type(mt.starts_run)
    with pytest.raises(TypeError, match="@wp.func"):
        mt.field_params_type(sphere_field_np)
    pts, tets = grid_tets(4)
    with pytest.raises(GofError, match="needs field_params"):
        marching_tetrahedra(pts, tets, None, blob_field, device="cpu")
    with pytest.raises(GofError, match="takes no params"):
        marching_tetrahedra(pts, tets, None, sphere_field, field_params=Blobs(), device="cpu")
    with pytest.raises(GofError, match="only for a Warp field"):
        marching_tetrahedra(pts, tets, sphere_field_np(pts), sphere_field_np, field_params=Blobs(), device="cpu")
    with pytest.raises(GofError, match="values may be None only"):
        marching_tetrahedra(pts, tets, None, sphere_field_np, device="cpu")
    with pytest.raises(GofError, match="first argument must be wp.vec3"):
        marching_tetrahedra(pts, tets, None, mt.starts_run, device="cpu")


@pytest.mark.parametrize("steps", [0, 6])
def test_warp_field_and_callback_give_the_same_mesh(device, steps):
    """One marching and one bisection: only how the batch of values is filled differs."""
    pts, tets = grid_tets(9)
    f32 = lambda x: np.float32(RADIUS * RADIUS) - (np.asarray(x, np.float32) ** 2).sum(1, dtype=np.float32)  # noqa: E731
    (v_host, f_host), = marching_tetrahedra(pts, tets, f32(pts), f32, levels=[0.0], binary_steps=steps, device=device)
    (v_warp, f_warp), = marching_tetrahedra(pts, tets, None, sphere_field, levels=[0.0], binary_steps=steps, device=device)
    assert f_host.shape[0] > 100
    np.testing.assert_array_equal(f_host, f_warp)
    assert np.abs(v_host - v_warp).max() < SAME_PATH_TOL
    radial = np.abs(np.linalg.norm(v_warp.astype(np.float64), axis=1) - RADIUS)
    if steps:  # 6 bisections of a cube diagonal (0.25·√3) → bracket < 7e-3, then the linear zero of a smooth field
        assert radial.max() < 1e-3
    else:
        assert radial.max() > 1e-3  # plain interpolation of a quadratic is visibly off: the search matters


def test_warp_field_with_params_and_several_levels(device):
    pts, tets = grid_tets(11, 1.6)
    params = Blobs()
    centres = np.array([[0.35, 0.0, 0.0], [-0.35, 0.0, 0.0]], np.float32)
    params.centres, params.weight = wp.array(centres, dtype=wp.vec3, device=device), 1.0
    levels = [0.5, 1.0]
    meshes = marching_tetrahedra(pts, tets, None, blob_field, field_params=params, levels=levels, binary_steps=8,
                                 device=device)
    for (v, f), level in zip(meshes, levels):
        x = v.astype(np.float64)
        value = np.exp(-((x[:, None, :] - centres[None]) ** 2).sum(2)).sum(1)
        assert f.shape[0] > 50 and np.abs(value - level).max() < 2e-4, level
        _, uses = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), 1), axis=0,
                            return_counts=True)
        assert np.all(uses == 2), "a closed level set inside the grid gives a watertight mesh"


def test_marching_cubes_takes_a_warp_field(device):
    v, f = marching_cubes(sphere_field, [[-1, -1, -1], [1, 1, 1]], 17, level=0.0, binary_steps=6, device=device)
    assert f.shape[0] > 100
    assert np.abs(np.linalg.norm(v.astype(np.float64), axis=1) - RADIUS).max() < 1e-3


@pytest.mark.slow
def test_pure_warp_caller_gets_warp_device_rules(tmp_path):
    """Without torch: device=None follows wp.ScopedDevice, and the search runs with no torch loaded."""
    code = ("import sys, numpy as np, warp as wp\n"
            "from gof_warp.mesh.marching import marching_tetrahedra, resolve_device\n"
            "@wp.func\n"
            "def f(x: wp.vec3) -> float:\n"
            "    return 0.25 - wp.dot(x, x)\n"
            "with wp.ScopedDevice('cpu'):\n"
            "    assert resolve_device(None) == 'cpu'\n"
            "    pts = np.array([[0,0,0],[1,0,0],[0,1,0],[0,0,1]], np.float32)\n"
            "    (v, faces), = marching_tetrahedra(pts, np.array([[0,1,2,3]]), None, f, levels=[0.0])\n"
            "assert faces.shape == (1, 3) and abs(np.linalg.norm(v, axis=1) - 0.5).max() < 1e-4, v\n"
            "assert 'torch' not in sys.modules\n"
            "print('ok')\n")
    script = tmp_path / "pure_warp.py"  # Warp reads a wp.func's source from its file
    script.write_text(code)
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("ok")
