"""Synthetic scene presets: geometry, materials, camera rig and default resolution, as plain data.

Each preset stresses one way surface reconstruction fails (its ``intent``). Geometry is fixed per preset
(so benchmarks compare like with like); the seed moves the cameras around the object and selects the
procedural noise fields. Defaults are small enough for CPU tests (``DEFAULT_RESOLUTION``); the same
presets render for GPU benchmarks with ``--resolution 800 800`` (``GPU_RESOLUTION``): intrinsics follow
the field of view, so the geometry seen is the same at every resolution.

World space is z up; objects sit inside a ball of radius ~1.3 around the origin. Units are arbitrary
except in ``garden``, whose scene is built in metres (1 unit = 1 m: a 10 m x 10 m lawn, objects of
10-50 cm, rods of 1-2 cm radius) so that absolute tolerances (10 cm ground patches) mean what they say.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..core.camera import look_at
from ..core.errors import SceneError
from . import meshes as M
from .render import Lighting

DEFAULT_RESOLUTION = (128, 128)
GPU_RESOLUTION = (800, 800)
_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
_REPO_ROOT = Path(__file__).resolve().parents[2]
SPOT_RELATIVE = Path("shared") / "data" / "spot"


@dataclass(frozen=True)
class CameraRig:
    """Cameras on a spherical band around ``target``, all looking at it with z up.

    Train and test views lie on two interleaved Fibonacci spirals (uniform in area over the elevation band,
    never coinciding); the seed rotates both about z.

    Attributes:
        n_train, n_test: numbers of views.
        radius: distance of every camera from ``target``.
        fov_x_deg: horizontal field of view; ``fx = fy = (W / 2) / tan(fov_x / 2)``.
        elevation_deg: (lowest, highest) elevation above the target's horizontal plane.
        target: the point every camera looks at.
        principal_offset: principal point offset from the image centre, as fractions of (W, H).
    """

    n_train: int = 40
    n_test: int = 8
    radius: float = 4.0
    fov_x_deg: float = 40.0
    elevation_deg: tuple[float, float] = (-45.0, 70.0)
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    principal_offset: tuple[float, float] = (0.0, 0.0)

    def _spiral(self, n: int, azimuth0: float) -> np.ndarray:
        lo, hi = np.deg2rad(self.elevation_deg)
        k = np.arange(n)
        el = np.arcsin(np.sin(lo) + (np.sin(hi) - np.sin(lo)) * (k + 0.5) / n)
        az = azimuth0 + k * _GOLDEN_ANGLE
        dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
        return np.asarray(self.target, dtype=np.float64) + self.radius * dirs

    def cameras(self, width: int, height: int, n_train: int | None = None, seed: int = 0):
        """``(train, test)`` lists of :class:`~gof_warp.core.camera.Camera` named ``r_000``, ``r_001``, ..."""
        n_train = self.n_train if n_train is None else int(n_train)
        azimuth0 = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi)
        fx = (width / 2.0) / np.tan(np.deg2rad(self.fov_x_deg) / 2.0)
        cx = width / 2.0 + self.principal_offset[0] * width
        cy = height / 2.0 + self.principal_offset[1] * height

        def make(eyes):
            digits = max(3, len(str(len(eyes) - 1)))
            return [look_at(e, self.target, up=(0.0, 0.0, 1.0), fx=fx, fy=fx, cx=cx, cy=cy, width=width,
                            height=height, name=f"r_{k:0{digits}d}") for k, e in enumerate(eyes)]

        # Test spiral: half a golden angle off the train spiral, so no test view repeats a train view.
        return make(self._spiral(n_train, azimuth0)), make(self._spiral(self.n_test, azimuth0 + _GOLDEN_ANGLE / 2))


@dataclass(frozen=True)
class Preset:
    """A synthetic scene recipe.

    Attributes:
        name: CLI name.
        intent: which failure mode of surface reconstruction it stresses.
        build: ``build(mesh_path) -> list[SyntheticMesh]``; ``mesh_path`` is only used by file presets.
        rig: the :class:`CameraRig`.
        resolution: default (CPU-sized) ``(width, height)``.
        supersample: samples per pixel axis for colour/alpha (plus the centre ray).
        lighting: the view-independent :class:`~gof_warp.synthetic.render.Lighting`.
        units: what one scene unit is (``"m"``), or None when the scene has no physical scale.
    """

    name: str
    intent: str
    build: Callable[[Path | None], list]
    rig: CameraRig = field(default_factory=CameraRig)
    resolution: tuple[int, int] = DEFAULT_RESOLUTION
    supersample: int = 2
    lighting: Lighting = field(default_factory=Lighting)
    units: str | None = None


# ----------------------------------------------------------------------------------------- geometry
_KNOT = M.Material(color_a=(0.05, 0.1, 0.4), color_b=(1.0, 0.8, 0.25), noise_scale=4.0)
_SPHERE = M.Material(color_a=(0.6, 0.05, 0.05), color_b=(0.95, 0.95, 0.75), noise_scale=5.0, checker_scale=5.0,
                     checker_strength=0.45)
_BOX = M.Material(color_a=(0.05, 0.3, 0.08), color_b=(0.9, 0.9, 1.0), noise_scale=6.0, checker_scale=6.0,
                  checker_strength=0.5)
_TORUS = M.Material(color_a=(0.35, 0.05, 0.45), color_b=(0.95, 0.9, 0.4), noise_scale=7.0)
_GROUND = M.Material(color_a=(0.25, 0.2, 0.12), color_b=(0.85, 0.8, 0.65), noise_scale=2.0, checker_scale=1.5,
                     checker_strength=0.35)
_SHELL = M.Material(color_a=(0.1, 0.25, 0.45), color_b=(0.9, 0.85, 0.8), noise_scale=0.8)
# A far background with detail at every scale the cameras resolve, as real backgrounds (foliage, facades) have:
# fBm features of ~17, 8 and 4 cm under 33 cm checker squares, about 10-25 px wide at the shell's distance of
# 6-10 units in 400 px views (the plain _SHELL's features are ~70 px wide there: its depth is barely observable).
_SHELL_DETAIL = M.Material(color_a=(0.1, 0.25, 0.45), color_b=(0.9, 0.85, 0.8), noise_scale=6.0, checker_scale=3.0,
                           checker_strength=0.3)
_PLAIN = M.Material(kind="constant", color_a=(0.75, 0.72, 0.68))


def _composition(z0: float = 0.0) -> list[M.SyntheticMesh]:
    """Torus knot above a sphere, a rotated box and a flat torus; disjoint parts (no hidden surfaces).

    The lower three rest on the plane ``z = -0.9 + z0``.
    """
    rz = M.rotation_about((0, 0, 1), np.deg2rad(25.0))
    return [
        M.torus_knot(center=(0, 0, 0.25 + z0), major=0.55, minor=0.22, tube_radius=0.13, material=_KNOT),
        M.sphere(center=(0.5, -0.45, -0.6 + z0), radius=0.3, subdivisions=4, material=_SPHERE),
        M.box(center=(-0.55, -0.3, -0.675 + z0), size=(0.45, 0.45, 0.45), rotation=rz, material=_BOX),
        M.torus(center=(0.0, 0.55, -0.81 + z0), major=0.3, minor=0.09, material=_TORUS),
    ]


def _default(_path):
    return _composition()


def _textureless(_path):
    return [p.with_material(_PLAIN) for p in _composition()]


def _thin(_path):
    """Rods of radius 0.02-0.035 (about 2-3.5 px wide at 128 px, 12-22 px at 800 px), a helical wire, a thin
    ring and a thin base plate."""
    wire = M.Material(color_a=(0.1, 0.1, 0.1), color_b=(0.95, 0.85, 0.4), noise_scale=8.0, checker_scale=8.0,
                      checker_strength=0.4)
    parts = [M.box(center=(0, 0, -0.8), size=(1.7, 1.7, 0.06), material=_BOX, name="plate"),
             M.helix(center=(0, 0, 0), radius=0.45, height=1.2, turns=3.0, wire_radius=0.02, material=wire),
             M.torus(center=(0, 0, 0.72), major=0.7, minor=0.02, sections=(96, 8), material=wire, name="ring")]
    for k in range(6):
        a = 2 * np.pi * k / 6
        r = 0.02 + 0.003 * k
        base = (0.7 * np.cos(a), 0.7 * np.sin(a))
        parts.append(M.cylinder((*base, -0.77), (*base, 0.68), r, sides=10, material=wire, name=f"rod{k}"))
    return parts


def _background(_path, shell=_SHELL, ground_half_size=4.2, cut_ground_to_shell=False):
    """The composition resting on a textured ground plane inside a textured background shell (with
    ``cut_ground_to_shell`` the ground cut to the shell's inside and the shell to above the ground: they meet on
    one polygon)."""
    ground_z = -0.9
    parts = _composition(z0=0.005)  # 5 mm above the ground: touching parts would hide surfaces
    shell_mesh = M.sphere(radius=6.0, subdivisions=3, material=shell, name="shell", inward=True, role="background")
    ground = M.grid_plane(center=(0, 0, ground_z), half_size=ground_half_size, cell=0.1, material=_GROUND)
    if cut_ground_to_shell:  # and the shell to the ground: nothing of either hidden behind the other
        ground = M.clip_to_convex(ground, shell_mesh, center=(0, 0, ground_z))
        shell_mesh = M.cut_below(shell_mesh, ground_z)
    return parts + [ground, shell_mesh]


def _background_detail(path):
    """``background`` with the far shell textured finely enough for the photos to place it."""
    return _background(path, shell=_SHELL_DETAIL)


# The shell (radius 6) crosses the ground's height z = -0.9 at radius 5.93: a ground of half-size 6 cut to the
# shell, and the shell cut at the ground, meet all round with nothing hidden behind either.
GROUND_TO_SHELL_HALF_SIZE = 6.0


def _background_full(path):
    """``background_detail`` with the ground reaching the shell: no gap below the ground's edge."""
    return _background(path, shell=_SHELL_DETAIL, ground_half_size=GROUND_TO_SHELL_HALF_SIZE, cut_ground_to_shell=True)


_LAWN = M.Material(color_a=(0.12, 0.22, 0.06), color_b=(0.8, 0.75, 0.45), noise_scale=3.0, checker_scale=2.0,
                   checker_strength=0.3)  # fBm features of ~33, 17 and 8 cm under 50 cm checker squares
_WIRE = M.Material(color_a=(0.1, 0.1, 0.1), color_b=(0.95, 0.85, 0.4), noise_scale=30.0, checker_scale=20.0,
                   checker_strength=0.4)
GARDEN_GROUND_Z = 0.0
GARDEN_LIFT = 0.005  # objects float 5 mm above the ground: touching parts would hide surfaces


def _garden(_path):
    """In metres. A 10 m x 10 m textured lawn (10 cm cells, so per-face visibility resolves what is seen) at
    ``z = 0``; 5 mm above it a rotated 40 cm box, a 25 cm sphere, a flat torus, a ring (1.2 cm wire) on a
    stand (1.5 cm post on a base disc) and three posts of radius 1, 1.5 and 2 cm; all inside a textured
    background sphere of radius 8 m (only its upper half is ever seen)."""
    z = GARDEN_GROUND_Z + GARDEN_LIFT
    rz = M.rotation_about((0, 0, 1), np.deg2rad(30.0))
    ring_rot = M.rotation_about((1, 0, 0), np.pi / 2) @ M.rotation_about((0, 0, 1), np.deg2rad(20.0))
    parts = [
        M.box(center=(-0.7, -0.5, z + 0.2), size=(0.4, 0.4, 0.4), rotation=rz, material=_BOX),
        M.sphere(center=(0.7, -0.6, z + 0.25), radius=0.25, subdivisions=4, material=_SPHERE),
        M.torus(center=(0.0, 0.85, z + 0.08), major=0.25, minor=0.08, material=_TORUS),
        M.cylinder((0.65, 0.55, z), (0.65, 0.55, z + 0.02), 0.12, sides=32, material=_WIRE, name="stand_base"),
        M.cylinder((0.65, 0.55, z + 0.025), (0.65, 0.55, z + 0.45), 0.015, sides=12, material=_WIRE,
                   name="stand_post"),
        M.torus(center=(0.65, 0.55, z + 0.45 + 0.005 + 0.18 + 0.012), major=0.18, minor=0.012, sections=(96, 8),
                rotation=ring_rot, material=_WIRE, name="ring"),
    ]
    for k, (r, h) in enumerate(((0.01, 0.6), (0.015, 0.5), (0.02, 0.4))):
        base = (-0.75 + 0.18 * k, 0.45 - 0.1 * k)
        parts.append(M.cylinder((*base, z), (*base, z + h), r, sides=12, material=_WIRE, name=f"post{k}"))
    return parts + [
        M.grid_plane(center=(0, 0, GARDEN_GROUND_Z), half_size=5.0, cell=0.1, material=_LAWN),
        M.sphere(radius=8.0, subdivisions=4, material=_SHELL, name="shell", inward=True, role="background"),
    ]


def _sphere(_path):
    return [M.sphere(radius=1.0, subdivisions=5, material=_SPHERE)]


def find_mesh_file(path=None) -> tuple[Path, Path | None]:
    """Locate a textured OBJ: ``path`` (an ``.obj`` or a folder holding one), else the Spot cow in
    ``../shared/data/spot`` (next to the repository, or next to the working directory).

    Returns ``(obj, texture or None)``; the texture is the folder's only PNG (or its ``*texture*.png``).
    """
    tried = []
    candidates = [Path(path)] if path else [_REPO_ROOT.parent / SPOT_RELATIVE, Path.cwd().parent / SPOT_RELATIVE]
    env = os.environ.get("GOF_WARP_DATA")
    if env and not path:
        candidates.insert(0, Path(env) / "spot")
    for c in candidates:
        tried.append(str(c))
        objs = sorted(c.glob("*.obj")) if c.is_dir() else ([c] if c.is_file() else [])
        if objs:
            obj = objs[0]
            pngs = sorted(obj.parent.glob("*texture*.png")) or sorted(obj.parent.glob("*.png"))
            return obj, (pngs[0] if len(pngs) >= 1 else None)
    raise SceneError(
        "preset 'spot' needs a textured OBJ mesh; none found in " + ", ".join(tried)
        + " (pass --mesh PATH, or use a procedural preset such as 'default')"
    )


def _spot(path):
    obj, texture = find_mesh_file(path)
    mesh = M.load_textured_obj(obj, texture, name="spot")
    y_up_to_z_up = M.rotation_about((1, 0, 0), np.pi / 2)
    return [M.fit_to_box(mesh.transformed(y_up_to_z_up), size=2.0)]


_PRESETS = {
    p.name: p
    for p in [
        Preset("default", "Rich procedural texture on several disjoint objects (knot, sphere, box, torus), 360 "
               "degree views: the well-posed baseline, generated in seconds on a CPU.", _default,
               rig=CameraRig(target=(0.0, 0.0, -0.15))),
        Preset("spot", "A textured mesh from a file (the Spot cow, or --mesh): real UV texture, smooth organic "
               "shape, thin legs, ears and horns.", _spot, rig=CameraRig(elevation_deg=(-30.0, 70.0))),
        Preset("thin", "Thin structures a few pixels wide (rods, a helical wire, a thin ring and plate): where "
               "Gaussians smear and opacity/TSDF fusion erodes.", _thin, rig=CameraRig(elevation_deg=(-20.0, 70.0))),
        Preset("background", "Objects on a textured ground plane inside a textured background shell: the "
               "background is part of the reconstruction (GOF's claim over 2DGS/TSDF).", _background,
               rig=CameraRig(radius=4.0, elevation_deg=(8.0, 55.0), target=(0.0, 0.0, -0.35))),
        Preset("background_detail", "The background scene with a far shell textured at every scale the views "
               "resolve (as foliage or facades are): its depth is observable, so the whole seen region can be "
               "scored; the plain shell's smooth texture barely places it.", _background_detail,
               rig=CameraRig(radius=4.0, elevation_deg=(8.0, 55.0), target=(0.0, 0.0, -0.35))),
        Preset("background_full", "background_detail with the ground reaching the shell all round, as a real "
               "ground meets its background: no gap under the ground's edge that the cameras see into at grazing "
               "angles.", _background_full,
               rig=CameraRig(radius=4.0, elevation_deg=(8.0, 55.0), target=(0.0, 0.0, -0.35))),
        Preset("garden", "A whole outdoor scene in metres, as GOF meshes it: a textured lawn (10 m), objects of "
               "different kinds on it (box, sphere, torus, a ring on a stand, posts of 1-2 cm radius) and a far "
               "textured background 8 m away, seen by 100 cameras 10-50 degrees above the ground.", _garden,
               rig=CameraRig(n_train=100, n_test=10, radius=3.5, fov_x_deg=50.0, elevation_deg=(10.0, 50.0),
                             target=(0.0, 0.0, 0.25)), resolution=(128, 96), units="m"),
        Preset("textureless", "The default geometry with one uniform albedo: only shading constrains depth, "
               "photometric matching is ill-posed.", _textureless, rig=CameraRig(target=(0.0, 0.0, -0.15))),
        Preset("sparse", "The default scene seen from only 8 training views: overfitting and floaters.",
               _default, rig=CameraRig(n_train=8, target=(0.0, 0.0, -0.15))),
        Preset("sphere", "An analytic unit sphere (geodesic mesh, 20,480 faces) for exact depth/normal tests.",
               _sphere, rig=CameraRig(n_train=16, n_test=4), resolution=(64, 64)),
    ]
}


def list_presets() -> list[str]:
    """Names of the built-in presets."""
    return list(_PRESETS)


def get_preset(name: str) -> Preset:
    """The preset called ``name`` (a :class:`~gof_warp.core.errors.SceneError` naming the choices if unknown)."""
    if name not in _PRESETS:
        raise SceneError(f"unknown synthetic preset {name!r}; choose one of: {', '.join(_PRESETS)}")
    return _PRESETS[name]


def with_rig(preset: Preset, **changes) -> Preset:
    """A copy of ``preset`` whose camera rig has ``changes`` (e.g. ``principal_offset=(0.1, 0)``)."""
    return replace(preset, rig=replace(preset.rig, **changes))


__all__ = ["CameraRig", "Preset", "DEFAULT_RESOLUTION", "GPU_RESOLUTION", "find_mesh_file", "get_preset",
           "list_presets", "with_rig"]
