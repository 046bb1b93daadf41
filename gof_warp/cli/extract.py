"""``python -m gof_warp.extract RUN [--scene SCENE] [--out MESH.ply] [--method tetra|cubes|tsdf] ...``

Mesh extraction from trained Gaussians (the library: :mod:`gof_warp.mesh.extraction`). Under
``torchrun --nproc_per_node N -m gof_warp.extract RUN ...`` the field's views are shared out among the processes
(one GPU each) and rank 0 triangulates and writes (:mod:`gof_warp.training.distributed`). ``RUN`` is a training output
folder (``point_cloud.ply`` + ``cameras.json``) or any Gaussian PLY in the 3DGS layout together with ``--scene``
for the cameras. Writes the mesh (PLY) and ``<mesh>.json`` with vertex/face counts and per-stage time and peak
memory; ``--color`` adds vertex colours, ``--texture`` bakes a texture (:mod:`gof_warp.mesh.texture`) written as GLB
or OBJ + MTL + PNG. An empty mesh is an error (exit 2) and writes nothing; Gaussians whose scales overflow (see
:func:`gof_warp.mesh.extraction.meshable`) are left out with a warning.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from pathlib import Path

from .common import HelpFormatter, configure_output, run_command
from ..core.errors import GofError
from ..mesh.extraction import (MAX_RESOLUTION, METHODS, MIN_RESOLUTION, MeshConfig, StageTimer,  # noqa: F401
                               empty_mesh_message, extract_mesh, level_name_clash, meshable, save_mesh)
from ..mesh.export import save_mesh_file, save_textured_mesh, textured_companions
from ..core.orientation import UP_CHOICES, parse_up, scene_up
from ..mesh.marching_inputs import MAX_BINARY_STEPS, MAX_STEPS_PER_CALL
from ..core.io_utils import write_json_atomic
from ..mesh.colour import SOURCES as COLOUR_SOURCES
from ..mesh.export import FORMATS as MESH_FORMATS
from ..mesh.export import USD_SUFFIXES, format_of
from ..mesh.texture import MAX_SIDE as TEXTURE_MAX
from ..mesh.texture import MIN_SIDE as TEXTURE_MIN
from ..training.run_folder import cameras_from_json, load_run  # noqa: F401 - re-exported: extract.load_run is public
from ..mesh.collision import MAX_RESOLUTION as MAX_COLLISION_RESOLUTION
from ..mesh.collision import CollisionConfig
from ..mesh.octree_tets import DEFAULT_CELL_FACTOR, SMALL_CELL_FACTOR, OctreeConfig
from ..rendering.opacity_field import OpacityFieldConfig
from ..mesh.tetra import GRIDS, TetraConfig

log = logging.getLogger(__name__)


DESCRIPTION = """\
Extract a mesh from trained Gaussians (Gaussian Opacity Fields): tetra, cubes or tsdf.

RUN is a training output folder (point_cloud.ply and cameras.json), or any Gaussian PLY in the 3DGS
layout together with --scene for the cameras. Writes the mesh (PLY) and <mesh>.json with vertex and
face counts and each stage's time and peak memory."""
EPILOG = """\
An empty mesh is an error (exit code 2) and writes nothing. Gaussians whose scales overflow are left
out with a warning.

Several GPUs: under "torchrun --nproc_per_node N -m gof_warp.extract RUN ..." the field's views are
shared out among the processes (one GPU each), and the first process triangulates and writes."""


def parse_args(argv=None) -> argparse.Namespace:
    """The command's arguments (``argv``: a list, or None for ``sys.argv``), for :func:`main` and
    :func:`extract_run`."""
    ap = argparse.ArgumentParser(prog="python -m gof_warp.extract", description=DESCRIPTION, epilog=EPILOG,
                                 formatter_class=HelpFormatter)
    ap.add_argument("run", help="training output folder, or a 3DGS-layout Gaussian PLY (with --scene)")
    common = ap.add_argument_group("common options")
    common.add_argument("--out", default=None, help="mesh path (default: RUN/mesh_<method>.ply)")
    common.add_argument("--method", default="tetra", choices=METHODS,
                        help="tetra (GOF's tetrahedral grid), cubes (marching cubes) or tsdf (fused depth maps)")
    common.add_argument("--max-faces", type=int, default=None,
                        help="decimate each mesh to at most this many faces (default: no decimation)")
    common.add_argument("--max-error", type=float, default=None,
                        help="decimate to the fewest faces whose input vertices stay within this distance, in world "
                             "units (default: no decimation)")
    common.add_argument("--levels", type=float, nargs="+", default=[0.5],
                        help="opacity levels to mesh, one mesh each (tetra, cubes)")
    common.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto")
    common.add_argument("--quiet", action="store_true", help="no progress lines (errors and warnings still shown)")
    common.add_argument("--keep-hidden", action="store_true",
                        help="keep the faces no training camera sees (by default they are dropped: level crossings "
                             "under a ground, inside objects or behind walls that no photo supports)")
    common.add_argument("--min-views", type=int, default=OpacityFieldConfig.min_views,
                        help="mesh only space that at least this many training views see (default %(default)s, GOF's; "
                             "2 leaves out what a single photo alone sees, where nothing places the surface's "
                             "depth)")
    common.add_argument("--scene", default=None,
                        help="scene folder for the cameras, and the photos and masks for tsdf (default: none; the "
                             "cameras come from RUN/cameras.json)")
    common.add_argument("--no-pictures", action="store_true",
                        help="do not write RUN/pictures/mesh_<stem>.png (views of the model and the shaded mesh)")
    grid = ap.add_argument_group("grid and search")
    grid.add_argument("--grid", default=TetraConfig.grid, choices=GRIDS,
                      help="tetra: the tetrahedral grid: 'delaunay' (GOF's: Delaunay of the 3-sigma box corners and "
                           "centres, on the CPU), 'octree' (a balanced octree sized by the Gaussians, on the "
                           "model's device; no Delaunay) or 'auto' (the default: the octree, but the Delaunay grid "
                           f"for a small model, whose octree at cell factor {DEFAULT_CELL_FACTOR} has fewer than "
                           f"{OctreeConfig.small_leaves:,} leaves, unless --cell-factor is given)")
    grid.add_argument("--cell-factor", type=float, default=None,
                      help="octree grid: leaf side at most this times a Gaussian's 3-sigma box width (smaller: "
                           f"finer; default {DEFAULT_CELL_FACTOR}, or with --grid octree {SMALL_CELL_FACTOR} for a "
                           f"grid of fewer than {OctreeConfig.small_leaves:,} leaves at {DEFAULT_CELL_FACTOR}; "
                           "given, it is used as it is, and --grid auto keeps the octree)")
    grid.add_argument("--binary-steps", type=int, default=8,
                      help="tetra: bisection steps that place each vertex on the level")
    grid.add_argument("--resolution", type=int, default=None,
                      help="cubes and tsdf: grid nodes along the longest side (default: "
                           f"{MeshConfig.cubes_resolution} for cubes, {MeshConfig().tsdf.resolution} for tsdf)")
    grid.add_argument("--opacity-min", type=float, default=None,
                      help="tetra: leave out the Gaussians below this opacity first (default: none left out)")
    grid.add_argument("--corner-min-extent", type=float, default=None,
                      help="delaunay grid: only the centre point for Gaussians whose 3-sigma extent is below this, "
                           "in world units (default: box corners for every Gaussian)")
    grid.add_argument("--min-component-faces", type=int, default=0,
                      help="drop connected pieces of the mesh with fewer faces than this (0: keep all)")
    grid.add_argument("--reach-filter", action=argparse.BooleanOptionalAction, default=None,
                      help="octree grid: keep only the tetrahedra with a vertex inside some Gaussian's oriented "
                           "3-sigma box, where the Delaunay grid reaches (default: off; it can cut a surface of "
                           "flat Gaussians that no grid vertex falls in: benchmarks/extract/README.md)")
    perf = ap.add_argument_group("advanced and performance (the mesh is the same unless said)")
    perf.add_argument("--band", action="store_true",
                      help="delaunay grid: triangulate only the points near a level crossing (faster, not the same "
                           "mesh: benchmarks/extract/README.md)")
    perf.add_argument("--search-steps-per-call", type=int, default=MeshConfig.search_steps_per_call,
                      help="tetra: bisection steps served by one opacity-field call (0, the default: on a GPU chosen "
                           "from the field's measured cost, on the CPU one)")
    perf.add_argument("--piece-tets", type=int, default=None,
                      help="octree grid: make and march the grid's tetrahedra in pieces of at most this many, so "
                           f"they are never held whole (default {OctreeConfig.piece_tets})")
    perf.add_argument("--delaunay", default="scipy", choices=("scipy", "cgal", "auto"),
                      help="delaunay grid: the Delaunay library (cgal: the optional gof_warp[cgal] extra)")
    perf.add_argument("--delaunay-workers", type=int, default=TetraConfig.delaunay_workers,
                      help="delaunay grid: threads for scipy's Delaunay in chunks (0, the default: every CPU; 1: "
                           "one Qhull call)")
    perf.add_argument("--delaunay-processes", action=argparse.BooleanOptionalAction,
                      default=TetraConfig.delaunay_processes,
                      help="delaunay grid: run the Delaunay chunks in forked processes (the default, where the OS "
                           "can fork: Linux) or, with --no-delaunay-processes, in threads")
    colour = ap.add_argument_group("colour and file format")
    colour.add_argument("--color", default="none", choices=("none",) + COLOUR_SOURCES,
                        help="vertex colours: none (the default), gaussians (the Gaussians rendered from the training "
                             "cameras that see each vertex) or photos (the training photos, from --scene or the "
                             "scene the run names; on the built-in scene 1.6 dB closer to the held-out photos than gaussians: "
                             "benchmarks/extract/results/mesh_colour_fidelity_default_scene_cpu.json)")
    colour.add_argument("--format", default=None, choices=MESH_FORMATS,
                        help="mesh file format: ply, glb (one binary glTF file), obj (vertex colours as 'v x y z r "
                             "g b'; with --texture, OBJ + MTL + PNG side by side) or usd (a stage with the mesh, the "
                             "training cameras and, with --collision, the collision mesh; needs gof_warp[usd]) "
                             "(default: from --out's suffix, .glb, .obj, .usd, .usda or .usdc, else ply; with "
                             "--texture, glb)")
    colour.add_argument("--up", default="auto", choices=UP_CHOICES,
                        help="the scene's up direction, so that glb and obj (+Y up) and usd (Z up) assets stand "
                             "upright: auto (the default: the mean up direction of the training cameras' images, "
                             "snapped to a world axis within 10 degrees) or an axis; ply stays in the scene's frame "
                             "(the file records the rotation: gof_warp reads it back in the scene's frame)")
    colour.add_argument("--texture", action="store_true",
                        help="bake a colour texture on a UV atlas (the optional gof_warp[texture] extra: xatlas) from "
                             "--color's source (default with --texture: photos), after any --max-faces decimation; "
                             "glb embeds it, obj writes <mesh>.mtl and <mesh>.png beside it, ply takes vertex colours "
                             "sampled from it (default: off)")
    colour.add_argument("--texture-size", type=int, default=None,
                        help="--texture: the texture's side in texels (default: from the face count, 16 texels per "
                             f"face at 60%% atlas fill, a multiple of 4 in [{TEXTURE_MIN}, {TEXTURE_MAX}])")
    collision = ap.add_argument_group("collision mesh")
    collision.add_argument("--collision", action="store_true",
                           help="also write a closed (watertight) mesh of the opacity field for physics or printing: "
                                "RUN/mesh_collision.ply, or <out stem>_collision.ply beside --out, and "
                                "/World/collision in a USD stage. Space fewer than --min-views training views see is empty; what the "
                                "views see only through the object is solid (gof_warp.mesh.collision)")
    collision.add_argument("--collision-faces", type=int, default=CollisionConfig.max_faces,
                           help="--collision: face budget of the collision mesh (default %(default)s)")
    collision.add_argument("--collision-resolution", type=int, default=CollisionConfig.resolution,
                           help="--collision: grid cells along the longest side of the Gaussians' box (default "
                                "%(default)s)")
    collision.add_argument("--collision-bounds", type=float, nargs=6, default=None,
                           metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                           help="--collision: the box to make solid, in world units (default: the box of the "
                                "Gaussians the cameras see; give it for a scene with a background, whose space seen "
                                "only through the walls would otherwise be solid)")
    volume = ap.add_argument_group("other outputs")
    volume.add_argument("--volume", action="store_true",
                        help="bake the opacity field into a sparse NanoVDB volume (RUN/opacity_volume.nvdb and "
                             ".json) for Warp kernels instead of a mesh (docs/warp_volume.md)")
    volume.add_argument("--voxel-size", type=float, default=None,
                        help="--volume: voxel edge in world units (default: the median 3-sigma extent of the opaque "
                             "Gaussians / 4)")
    volume.add_argument("--volume-band", type=int, default=4,
                        help="--volume: voxels kept on each side of the 0.5 level")
    a = ap.parse_args(argv)
    a.given = given_options(ap, argv)
    if a.texture and not a.volume:  # --texture's defaults: photos, and a GLB unless --out or --format says otherwise
        if "color" not in a.given:
            a.color = "photos"
        suffix = "" if a.out is None else Path(a.out).suffix.lower()
        if a.format is None and suffix.lstrip(".") not in MESH_FORMATS and suffix not in USD_SUFFIXES:
            a.format = "glb"
    return a


class _Unset:
    """The value every option starts from in :func:`given_options`' second parse."""


def given_options(ap: argparse.ArgumentParser, argv=None) -> frozenset[str]:
    """The ``dest`` of every option the command line sets (abbreviated or not), whatever its value: argparse fills
    in a default only where the namespace has none, so what still holds the marker was not given."""
    unset = _Unset()
    seen = ap.parse_args(argv, namespace=argparse.Namespace(
        **{act.dest: unset for act in ap._actions if act.dest is not argparse.SUPPRESS}))
    return frozenset(k for k, v in vars(seen).items() if v is not unset)


INT_LIMIT = 2**31 - 1  # the largest count a flag takes: beyond it no mesh's faces or tetrahedra reach
MAX_VOLUME_BAND = 64  # voxels on each side of the level: eight bricks
MAX_DELAUNAY_WORKERS = 1024
# flags that only a mesh uses, and those only the tetra method uses: given where they do nothing, a warning
MESH_ONLY = ("color", "format", "texture", "texture_size", "method", "max_faces", "max_error", "levels", "keep_hidden", "min_views", "grid", "cell_factor",
             "binary_steps", "resolution", "opacity_min", "corner_min_extent", "min_component_faces", "reach_filter",
             "band", "search_steps_per_call", "piece_tets", "delaunay", "delaunay_workers", "delaunay_processes",
             "collision_faces", "collision_resolution", "collision_bounds")
TETRA_ONLY = ("grid", "cell_factor", "opacity_min", "corner_min_extent", "reach_filter", "band",
              "search_steps_per_call", "piece_tets", "delaunay", "delaunay_workers", "delaunay_processes")


def _flag(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _check_range(dest: str, value, lo=None, hi=None, *, above: bool = False, why: str = "") -> None:
    """``value`` (None: not set) is finite, ``>= lo`` (``> lo`` when ``above``) and ``<= hi``, else a
    :class:`GofError` naming the flag."""
    if value is None:
        return
    if math.isfinite(value) and (lo is None or (value > lo if above else value >= lo)) and (hi is None or value <= hi):
        return
    kind = "an integer" if isinstance(value, int) else "a number"

    def num(x):
        return str(x) if isinstance(x, int) else f"{x:g}"

    if lo is not None and hi is not None:
        bound = f"in {'(' if above else '['}{num(lo)}, {num(hi)}]"
    elif lo is not None:
        bound = f"{'>' if above else '>='} {num(lo)}"
    else:
        bound = f"<= {num(hi)}"
    raise GofError(f"{_flag(dest)} must be {kind} {bound}{why}, got {num(value)}")


def check_args(a: argparse.Namespace) -> None:
    """Every option's value and the options' combination, before any work: a value that means nothing is a
    :class:`GofError` naming its flag; a flag the chosen output or method does not use, a warning naming it (a
    script may pass one set of flags to every method). ``a.given``: the options the command line set
    (:func:`given_options`; all of them when absent)."""
    given = getattr(a, "given", None)
    given = set(vars(a)) if given is None else set(given)
    _check_range("binary_steps", a.binary_steps, 0, MAX_BINARY_STEPS,
                 why=f": each step halves the bracket around a vertex, and after {MAX_BINARY_STEPS} (float32's "
                     "significand bits) it is below the coordinates' precision")
    _check_range("resolution", a.resolution, MIN_RESOLUTION, MAX_RESOLUTION,
                 why=f": grid nodes along the longest side; marching cubes needs {MIN_RESOLUTION}, and "
                     f"{MAX_RESOLUTION}^3 dense nodes are already 8.6e9 values")
    for level in a.levels:
        if not 0.0 < level < 1.0:
            raise GofError(f"--levels must be opacities in (0, 1), got {level:g}")
    twice = level_name_clash(a.levels)
    if twice:
        same = f"{twice[0]:g} twice" if twice[0] == twice[1] else f"{twice[0]!r} and {twice[1]!r} (one file name)"
        raise GofError(f"--levels has {same}: each level writes one mesh file, give each once")
    _check_range("max_faces", a.max_faces, 4, INT_LIMIT)
    _check_range("max_error", a.max_error, 0.0, above=True, why=" (world units)")
    _check_range("min_views", a.min_views, 1, INT_LIMIT)
    _check_range("cell_factor", a.cell_factor, 0.0, above=True)
    _check_range("piece_tets", a.piece_tets, 1, INT_LIMIT)
    _check_range("opacity_min", a.opacity_min, 0.0, 1.0, why=" (1 would leave out every Gaussian)")
    if a.opacity_min is not None and a.opacity_min == 1.0:
        raise GofError("--opacity-min must be below 1: opacities lie in (0, 1), so 1 leaves out every Gaussian")
    _check_range("corner_min_extent", a.corner_min_extent, 0.0, why=" (world units)")
    _check_range("min_component_faces", a.min_component_faces, 0, INT_LIMIT)
    _check_range("search_steps_per_call", a.search_steps_per_call, 0, MAX_STEPS_PER_CALL, why=" (0: automatic)")
    _check_range("delaunay_workers", a.delaunay_workers, 0, MAX_DELAUNAY_WORKERS, why=" (0: every CPU)")
    _check_range("voxel_size", a.voxel_size, 0.0, above=True, why=" (world units)")
    _check_range("volume_band", a.volume_band, 0, MAX_VOLUME_BAND, why=" (voxels on each side of the level)")
    _check_range("collision_faces", a.collision_faces, 4, INT_LIMIT)
    _check_range("collision_resolution", a.collision_resolution, 2, MAX_COLLISION_RESOLUTION,
                 why=" (grid cells along the longest side)")
    if a.collision_bounds is not None:
        b = a.collision_bounds
        if not all(math.isfinite(x) for x in b) or not all(b[i + 3] > b[i] for i in range(3)):
            raise GofError(f"--collision-bounds must be 6 finite numbers XMIN YMIN ZMIN XMAX YMAX ZMAX with each max "
                           f"above its min, got {' '.join(f'{x:g}' for x in b)}")

    def ignored(dests, why):
        names = [_flag(d) for d in dests if d in given]
        if names:
            log.warning("warning: %s ignored: %s", ", ".join(names), why)

    if a.volume:
        if "method" in given:
            raise GofError(f"--volume writes a NanoVDB opacity volume (.nvdb), not a mesh: it takes no --method "
                           f"(got --method {a.method})")
        for dest in ("color", "format", "texture", "texture_size", "collision"):
            if dest in given:
                raise GofError(f"--volume writes a NanoVDB opacity volume (.nvdb), not a mesh: it takes no "
                               f"{_flag(dest)}")
        if a.out is not None and Path(a.out).suffix.lower() != ".nvdb":
            raise GofError(f"--volume writes a NanoVDB volume: --out must end in .nvdb, got {a.out}")
        ignored(MESH_ONLY, "--volume bakes the opacity field, and these are mesh settings")
        return
    ignored(("voxel_size", "volume_band"), "they are --volume settings, and no --volume was given")
    _check_range("texture_size", a.texture_size, 16, TEXTURE_MAX, why=" (texels along the texture's side)")
    if a.texture and a.color == "none":
        raise GofError("--texture bakes colours: it needs a colour source (--color photos or gaussians), not --color "
                       "none")
    if not a.texture:
        ignored(("texture_size",), "it is a --texture setting, and no --texture was given")
    if not a.collision:
        ignored(("collision_faces", "collision_resolution", "collision_bounds"),
                "they are --collision settings, and no --collision was given")
    if a.out is not None and a.format is not None:
        suffix = Path(a.out).suffix.lower().lstrip(".")
        named = format_of(a.out) if f".{suffix}" in USD_SUFFIXES else suffix
        if named in MESH_FORMATS and named != a.format:
            raise GofError(f"--format {a.format}, but --out {a.out} ends in .{suffix}: give one format")
    if a.method != "tetra":
        ignored(TETRA_ONLY, f"tetra settings, and the method is {a.method}")
    if a.method == "tetra":
        ignored(("resolution",), "--method tetra has no dense grid (its grid: --grid, --cell-factor)")
    if a.method == "tsdf":
        ignored(("levels",), "--method tsdf meshes the fused depths' zero distance, not an opacity level")
        ignored(("min_views",), "--method tsdf fuses depth maps and evaluates no opacity field")


def main(argv=None) -> int:
    a = parse_args(argv)
    configure_output(a.quiet)

    def body():
        check_args(a)  # before the device, the ranks and the model: a bad flag costs no time
        from ..core.devices import resolve_device as pick_device
        from ..training.distributed import rank_device, ranks_from_environment

        ranks = ranks_from_environment()  # several processes under torchrun: views shared out (gof_warp.training.distributed)
        try:
            extract_run(a, ranks, rank_device(pick_device(a.device), ranks))
            ranks.barrier()
        finally:
            ranks.close()

    return run_command(body)


def extract_run(a, ranks, device) -> None:
    """The command's work for parsed arguments ``a`` on ``device``; rank 0 alone writes."""
    run = Path(a.run)
    check_outputs(a, run)
    if a.volume:
        if ranks.active:
            raise GofError("--volume runs in one process (launch without torchrun)")
        from ..mesh.volume import bake_run

        info = bake_run(run, scene=a.scene, out_path=a.out, voxel_size=a.voxel_size, band=a.volume_band,
                        device=device)
        print(f"wrote {info['nvdb']}: {info['active_voxels']} voxels of {info['voxel_size']:.4g}, "
              f"{info['bytes'] / 2**20:.1f} MiB, {info['time_s']['total']:.1f} s")
        return
    if format_of(mesh_base(a, run), a.format) == "usd":  # usd-core missing: said before the extraction's work
        from ..mesh.usd_export import pxr

        pxr()
    cfg = MeshConfig(method=a.method, levels=tuple(a.levels), binary_steps=a.binary_steps,
                     drop_hidden=not a.keep_hidden,
                     min_component_faces=a.min_component_faces, max_faces=a.max_faces, max_error=a.max_error,
                     search_steps_per_call=a.search_steps_per_call, field=OpacityFieldConfig(min_views=a.min_views),
                     tetra=TetraConfig(backend=a.delaunay, opacity_min=a.opacity_min,
                                       corner_min_extent=a.corner_min_extent,
                                       delaunay_workers=a.delaunay_workers, band=a.band,
                                       delaunay_processes=a.delaunay_processes, grid=a.grid,
                                       octree=OctreeConfig(**{k: v for k, v in (("cell_factor", a.cell_factor),
                                                                                ("piece_tets", a.piece_tets),
                                                                                ("reach_filter", a.reach_filter))
                                                              if v is not None})))
    if a.resolution is not None:
        cfg.cubes_resolution = a.resolution
        cfg.tsdf.resolution = a.resolution
    cfg.validate()
    t_load = time.perf_counter()
    gaussians, cameras, views, render_config = load_run(run, a.scene, device)
    if a.method != "tsdf" and a.min_views > len(cameras):
        raise GofError(f"--min-views {a.min_views}, but the run has {len(cameras)} training views: no space would be "
                       "meshed")
    if a.color == "photos":  # found before the extraction's work; decoded again when the colours are made
        training_photos(a, run, cameras[:1], views[:1] if views is not None else None, device)
    if a.texture:  # the optional package, before the extraction's work
        from ..mesh.texture import _xatlas

        _xatlas()
    command = {"load_s": round(time.perf_counter() - t_load, 3)}
    from ..core.progress import Stages

    timer = StageTimer(device, progress=Stages(quiet=a.quiet or not ranks.is_main))
    t0 = time.perf_counter()
    meshes = extract_mesh(gaussians, cameras, cfg, render_config=render_config, views=views, timer=timer,
                          ranks=ranks)
    total = time.perf_counter() - t0
    per_rank = ranks.gather_to_main(rank_summary(ranks, device, timer.stages, total))  # every rank calls it
    if not ranks.is_main:
        return
    levels = cfg.levels if a.method != "tsdf" else (0.0,)
    empty = [level for level, (_, f) in zip(levels, meshes) if len(f) == 0]
    if empty:  # before anything is written: an existing mesh of that name stays as it is
        raise GofError(empty_mesh_message(gaussians, a.method, empty, cfg))
    base = mesh_base(a, run)
    fmt = format_of(base, a.format)
    colours = [None] * len(meshes)
    textures = [None] * len(meshes)
    if a.texture:
        t_colour = time.perf_counter()
        textures = mesh_textures(a, run, meshes, gaussians, cameras, views, render_config, device)
        command["texture_s"] = round(time.perf_counter() - t_colour, 3)
    elif a.color != "none":
        t_colour = time.perf_counter()
        colours = mesh_vertex_colours(a, run, meshes, gaussians, cameras, views, render_config, device)
        command["colour_s"] = round(time.perf_counter() - t_colour, 3)
    collision = None
    if a.collision:
        with timer("collision_mesh"):
            collision = make_collision_mesh(a, gaussians, cameras, render_config)
    up = asset_up(a, cameras, fmt)
    if up is not None:
        command["up"] = [float(x) for x in up]
    outputs = []
    t_save = time.perf_counter()
    for level, (v, f), c, tex in zip(levels, meshes, colours, textures):
        path = mesh_path(base, level, len(meshes))
        if fmt == "usd":
            from ..mesh.usd_export import write_usd

            solid = None if collision is None else collision[:2]
            if tex is not None:  # the atlas's vertices; USD's UVs have v up
                write_usd(path, tex.vertices, tex.faces, cameras=cameras, collision=solid,
                          texture=tex.texture_uint8(), uvs=tex.uv_up(), up=up)
            else:
                write_usd(path, v, f, colours=c, cameras=cameras, collision=solid, up=up)
        elif tex is not None:
            save_textured_mesh(path, tex, fmt, up=up)
        elif fmt == "ply" and c is None:
            save_mesh(path, v, f)
        else:
            save_mesh_file(path, v, f, c, fmt, up=up)
        outputs.append({"path": str(path), "level": level, "vertices": int(len(v)), "faces": int(len(f)),
                        "format": fmt, "color": a.color,
                        **({"texture": {k: tex.info[k] for k in ("size", "atlas_vertices", "texels", "unseen_texels",
                                                                 "charts_fill", "best_views", "exposure", "gains")},
                            "files": [str(p) for p in textured_companions(path, fmt)]} if tex is not None else {})})
        print(f"wrote {path}: {len(v)} vertices, {len(f)} faces")
    if collision is not None:
        cv, cf, cinfo = collision
        cpath = collision_path(a, run)
        save_mesh(cpath, cv, cf)
        check = cinfo["check"]
        print(f"wrote {cpath}: {len(cv)} vertices, {len(cf)} faces, watertight {'yes' if check['watertight'] else 'NO'}"
              f", winding consistent {'yes' if check['winding_consistent'] else 'NO'}, volume {check['volume']:.4g}"
              f" ({check['components']} pieces; {cinfo['route']})")
        outputs.append({"path": str(cpath), "collision": True, "vertices": int(len(cv)), "faces": int(len(cf)),
                        "format": "ply"})
    command["save_s"] = round(time.perf_counter() - t_save, 3)
    summary = {
        "method": a.method, "binary_steps": a.binary_steps, "min_views": a.min_views, "num_gaussians": len(gaussians),
        "num_views": len(cameras), "device": device, "processes": ranks.world, "total_time_s": round(total, 3),
        "command": command, "stages": timer.stages, "meshes": outputs, **({"ranks": per_rank} if ranks.active else {}),
        **({"collision": {k: v for k, v in collision[2].items() if k != "config"}} if collision is not None else {})}
    write_json_atomic(base.with_suffix(".json"), summary)
    if not a.no_pictures:  # a picture per mesh; a failure only warns: the mesh is already written
        from ..viz.pictures import pictures_or_warning

        t_pictures = time.perf_counter()
        for o, m, c in zip(outputs, meshes, colours):  # the model and meshes in memory: no second read of the files
            for p in pictures_or_warning(run, mesh_path=o["path"], device=device, scene=a.scene, gaussians=gaussians,
                                         mesh=m if c is None else (*m, c)):
                print(f"wrote {p}")
        command["pictures_s"] = round(time.perf_counter() - t_pictures, 3)
        write_json_atomic(base.with_suffix(".json"), summary)  # again, with the pictures' time


def make_collision_mesh(a, gaussians, cameras, render_config):
    """``(vertices, faces, info)`` of the closed collision mesh (:func:`gof_warp.mesh.collision.collision_mesh`) for
    ``--collision``."""
    from ..mesh.collision import collision_mesh

    config = CollisionConfig(resolution=a.collision_resolution, max_faces=a.collision_faces, min_views=a.min_views,
                             bounds=None if a.collision_bounds is None else tuple(a.collision_bounds))
    return collision_mesh(gaussians, cameras, config, render_config=render_config)


def collision_path(a, run: Path) -> Path:
    """Where ``--collision`` writes its PLY: ``<out stem>_collision.ply`` beside ``--out``, else
    ``RUN/mesh_collision.ply`` (beside a PLY given as RUN)."""
    if a.out:
        out = Path(a.out)
        return out.with_name(f"{out.stem}_collision.ply")
    return (run if run.is_dir() else run.parent) / "mesh_collision.ply"


def mesh_vertex_colours(a, run: Path, meshes, gaussians, cameras, views, render_config, device) -> list:
    """Vertex colours ``[V, 3]`` float32 of each mesh from ``a.color`` (:func:`gof_warp.mesh.colour.mesh_colours`);
    the photos come from ``views`` (``--scene``) or the scene folder the run names (else ``RUN/scene``)."""
    from ..core.devices import warp_device
    from ..mesh.colour import mesh_colours

    photos = training_photos(a, run, cameras, views, device) if a.color == "photos" else None
    return [mesh_colours(a.color, v, f, cameras, gaussians=gaussians, photos=photos, render_config=render_config,
                         device=warp_device(device)) for v, f in meshes]


def mesh_textures(a, run: Path, meshes, gaussians, cameras, views, render_config, device) -> list:
    """``--texture``: the :class:`~gof_warp.mesh.texture.TexturedMesh` of each mesh from ``a.color``
    (:func:`gof_warp.mesh.texture.mesh_texture`), at ``--texture-size`` or the size its face count gives."""
    from ..core.devices import warp_device
    from ..mesh.texture import mesh_texture

    photos = training_photos(a, run, cameras, views, device) if a.color == "photos" else None
    return [mesh_texture(a.color, v, f, cameras, gaussians=gaussians, photos=photos, render_config=render_config,
                         size=a.texture_size, device=warp_device(device)) for v, f in meshes]


def training_photos(a, run: Path, cameras, views, device) -> list:
    """``--color photos``: the training photos, one uint8 ``[H, W, 3]`` per camera, from ``--scene``'s views or the
    scene folder the run names; a :class:`GofError` when there are none."""
    from ..viz.pictures import run_photos

    photos = [v.image for v in views] if views is not None else run_photos(run, cameras, device)
    if photos is None:
        raise GofError(f"--color photos: no photos found for {run} (pass --scene SCENE, the scene the model was "
                       "trained on)")
    return photos


def asset_up(a, cameras, fmt: str):
    """The scene's up for an upright GLB, OBJ or USD (``--up``; None for PLY, or when ``auto`` finds the training
    cameras' image-up directions cancel out, which is warned about)."""
    if fmt == "ply":
        return None
    up = parse_up(a.up)
    if up is None:
        up = scene_up(cameras)
        if up is None:
            print("warning: the training cameras do not agree on an up direction (--up auto): the mesh is written in "
                  "the scene's frame; pass --up +z (or the axis that is up) to stand it upright", file=sys.stderr)
            return None
        print(f"up: {_axis_name(up)} (from the training cameras; --up to choose)")
    return up


def _axis_name(up) -> str:
    k = max(range(3), key=lambda i: abs(float(up[i])))
    if abs(float(up[k])) == 1.0:
        return ("+" if up[k] > 0 else "-") + "xyz"[k]
    return "(" + ", ".join(f"{float(x):.3f}" for x in up) + ")"


def mesh_base(a, run: Path) -> Path:
    """The mesh path ``--out`` names, or ``RUN/mesh_<method>.<format>`` (beside a PLY given as RUN; the format
    ``--format``'s, else ply)."""
    ext = getattr(a, "format", None) or "ply"
    return Path(a.out) if a.out else (run if run.is_dir() else run.parent) / f"mesh_{a.method}.{ext}"


def mesh_path(base: Path, level: float, count: int) -> Path:
    """The file of the mesh at ``level``: ``base`` for one mesh, ``<stem>_<level><suffix>`` for each of several."""
    return base if count == 1 else base.with_name(f"{base.stem}_{level:g}{base.suffix}")


def check_outputs(a, run: Path) -> None:
    """Every path the command will write, checked before any work (:func:`check_output_path`): none may be a
    folder or another non-regular file, nor one of the run's inputs (:func:`run_inputs`)."""
    from ..core.io_utils import check_output_path
    from ..training.run_folder import run_inputs

    protected = run_inputs(run, a.scene)
    if a.volume:
        nvdb = Path(a.out) if a.out else run / "opacity_volume.nvdb" if run.is_dir() else run.with_suffix(".nvdb")
        paths = [nvdb, nvdb.with_suffix(".json")]
    else:
        base = mesh_base(a, run)
        levels = tuple(a.levels) if a.method != "tsdf" else (0.0,)
        paths = [mesh_path(base, level, len(levels)) for level in levels] + [base.with_suffix(".json")]
        if a.texture:
            paths += [p for mesh in paths[:-1] for p in textured_companions(mesh, a.format)]
        if a.collision:
            paths.append(collision_path(a, run))
    for path in paths:
        check_output_path(path, protected=protected)


def rank_summary(ranks, device, stages: dict, total_s: float) -> dict:
    """One rank's figures for ``<mesh>.json``: its device, wall time, and the peaks over its stages (host RSS; on
    CUDA torch's allocation and Warp's pool) — each GPU's own memory, which rank 0's stages alone do not show."""
    peaks = {}
    for entry in (e for e in stages.values() if isinstance(e, dict)):
        for key in ("host_peak_rss_mb", "gpu_peak_allocated_mb", "gpu_warp_pool_high_mb"):
            if key in entry:
                peaks[key] = max(peaks.get(key, 0.0), entry[key])
    return {"rank": ranks.rank, "device": str(device), "total_time_s": round(total_s, 3), **peaks}


if __name__ == "__main__":
    sys.exit(main())
