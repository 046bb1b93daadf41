"""Pictures of a run: see what training and extraction produced without writing code.

``python -m gof_warp.pictures RUN [--mesh MESH.ply] [--views K] [--out DIR] [--device D]`` writes one PNG,
``RUN/pictures/views.png`` (no mesh) or ``RUN/pictures/mesh_<stem>.png`` (``mesh_tetra.ply`` → ``mesh_tetra.png``).
It holds one row per chosen view (the test views if the run has any, else train views spread over the
list), with the columns

    photo | Gaussian render | median depth | rendered normal | mesh

* **photo**: the training image, when the scene folder can be found (``--scene``, a ``scene`` entry in
  ``cameras.json``/``config.yaml``, or ``RUN/scene`` as the built-in default run writes it); the column
  is left out, with a log line, when it cannot.
* **mesh** (with ``--mesh``: PLY, OBJ or GLB): the mesh in its own colours, unlit, when the file carries vertex
  colours or a texture (``extract --color``; column "coloured mesh" / "textured mesh"), else shaded ("shaded mesh").
* **Gaussian render**, **median depth**, **rendered normal**, **mesh**: drawn by
  :mod:`gof_warp.viz.panels` (:func:`view_panels`, :func:`shade_mesh`, …; those names are importable from here
  too) with the run's render settings.

Training also writes ``RUN/pictures/views_it<N>.png`` (the same panels and views) for the model at each of
its ``snapshot_iterations`` (:func:`snapshot_pictures_or_warning`), and for each loss spike it lists (a view's loss
more than 10× that view's own median, ``metrics.json`` ``loss_spikes.view_spikes``) ``RUN/pictures/spike_it<N>_<view>.png``:
that view's photo, render, depth, normal and distortion map when the spike was read back
(:func:`spike_picture_or_warning`).

This module finds what to draw — the run's Gaussians, cameras, render settings, the views to show and their
photos. The command is :mod:`gof_warp.cli.common.pictures`; library code (``train`` and ``extract``) calls
:func:`pictures_or_warning`.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from ..core.camera import Camera
from ..core.devices import resolve_device
from ..core.errors import GofError
from .panels import (  # noqa: F401 - the drawing lives in panels; re-exported for callers of gof_warp.viz.pictures
    AMBIENT,
    BACK_COLOR,
    BACKGROUND,
    COLUMN_TITLES,
    COVERED_ALPHA,
    DEPTH_PERCENTILES,
    FRONT_COLOR,
    GAP,
    HEADER_H,
    LABEL_H,
    MARGIN,
    MAX_WIDTH,
    PANEL_COLOR,
    TEXT_COLOR,
    CastMesh,
    Panels,
    _resize,
    _warp_device,
    colorize_depth,
    colorize_distortion,
    colorize_normal,
    fit_scale,
    panel_layout,
    render_columns,
    shade_cast_mesh,
    shade_mesh,
    view_panels,
    write_png,
)

log = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------------ run folder
def choose_views(train: list[Camera], test: list[Camera], k: int) -> list[tuple[Camera, str]]:
    """``k`` views: the first ``k`` test views spread over the list if any, else train views spread over it.
    Returns ``(camera, split)`` pairs."""
    if k < 1:
        raise GofError(f"the number of views must be >= 1, got {k}")
    pool, split = (test, "test") if test else (train, "train")
    if not pool:
        raise GofError("the run has no cameras")
    idx = sorted(set(np.round(np.linspace(0, len(pool) - 1, min(k, len(pool)))).astype(int).tolist()))
    return [(pool[i], split) for i in idx]


def find_photos(cameras: list[Camera], candidates: list[Path], data_config, device=None) -> list | None:
    """Decode the images of ``cameras`` (matched by name) from the first candidate scene folder that has
    them all, following the run's ``data_config`` (downscale, background). Only these views are decoded.
    Returns one ``uint8 [H, W, 3]`` per camera (resized to the camera's size if the scene's differs), or None."""
    from ..data import detect_format, read_plan
    from ..core.scene import pose_warnings
    from ..data.plan import build_scene, unique_names

    wanted = [c.name for c in cameras]
    for folder in candidates:
        if not folder.is_dir():
            continue
        try:
            detect_format(folder)
            plan = read_plan(folder, data_config)
            names = unique_names([v.name for v in plan.views])
            index = {n: i for i, n in enumerate(names)}
            if not all(n in index for n in wanted):
                missing = ", ".join(n for n in wanted if n not in index)
                log.info("%s does not hold every view shown (%s)", folder, missing)
                continue
            # a subset of the views, decoded for their photos: its pose warnings ("only 1 training view") are not
            # the scene's, so they count as said already
            chosen = [plan.views[index[n]] for n in wanted]
            sub = dataclasses.replace(plan, views=chosen, warnings=pose_warnings([v.camera for v in chosen]))
            scene = build_scene(sub, dataclasses.replace(data_config, test_every=0), device=device)
        except GofError as e:
            log.info("no photos from %s: %s", folder, e)
            continue
        photos = []
        for cam, view in zip(cameras, scene.train):
            if view.image.shape[:2] != (cam.height, cam.width):
                log.info("photo %s is %dx%d, the run's camera %dx%d: resized", cam.name, view.image.shape[1],
                         view.image.shape[0], cam.width, cam.height)
            photos.append(_resize(view.image, cam.width, cam.height))
        log.info("photos from %s", folder)
        return photos
    return None


def run_photos(run: Path, cameras, device):
    """The training photos of ``cameras`` from the scene folder a run names, or ``RUN/scene`` (uint8 ``[H, W, 3]``
    each), or None when none is found."""
    import json

    from ..core.config import from_dict
    from ..core.devices import warp_device
    from ..data import DataConfig
    from ..training.run_folder import read_run_config, scene_candidates

    run = Path(run)
    base = run if run.is_dir() else run.parent
    config = read_run_config(base / "config.yaml") if run.is_dir() else {}
    cams_file = base / "cameras.json"
    cams_json = json.loads(cams_file.read_text()) if run.is_dir() and cams_file.is_file() else {}
    data_config = from_dict(DataConfig, (config or {}).get("data", {}) or {}, "config.yaml: data")
    return find_photos(list(cameras), scene_candidates(base, cams_json, config or {}, None), data_config,
                       device=warp_device(device))


def run_views(run, split: str, device) -> tuple[list[Camera], list]:
    """The ``split`` (``"train"`` or ``"test"``) cameras of run folder ``run`` (``RUN/cameras.json``, at the training
    resolution) and their photos (:func:`run_photos`, uint8 ``[H, W, 3]`` each); :class:`GofError` when the run holds no
    such views or their photos are not found."""
    from ..training.run_folder import cameras_from_json

    run = Path(run)
    cameras = cameras_from_json(run / "cameras.json", split)
    if not cameras:
        raise GofError(f"{run} has no {split} views" + (" (the run held none out: use its train views)"
                                                         if split == "test" else ""))
    photos = run_photos(run, cameras, device)
    if photos is None:
        raise GofError(f"{run}: the photos of its {split} views were not found (the scene folder it names, or "
                       "RUN/scene)")
    return cameras, photos


def mesh_picture_stem(mesh_path) -> str:
    """``mesh_<stem>`` for a mesh file, without doubling the prefix (``mesh_tetra.ply`` → ``mesh_tetra``)."""
    stem = Path(mesh_path).stem
    return stem if stem.startswith("mesh_") else f"mesh_{stem}"


def write_run_pictures(run_dir, *, mesh_path=None, views: int = 3, out_dir=None, device=None, scene=None,
                       max_width: int = MAX_WIDTH, gaussians=None, mesh=None) -> list[Path]:
    """Write the picture of a run (module docstring) and return its path(s).

    Args:
        run_dir: training output folder (``point_cloud.ply`` + ``cameras.json``), or a Gaussian PLY
            together with ``scene``.
        mesh_path: a mesh file (PLY, OBJ, GLB) to show in the last column (``mesh_<stem>.png``, see
            :func:`mesh_picture_stem`), in its colours or texture when it has them, else shaded; None: ``views.png``.
        views: number of views (rows).
        out_dir: where to write (default ``RUN/pictures``).
        device: torch device for the Gaussians and the ray casting (default: CUDA if available, else CPU).
        scene: scene folder for cameras and photos (default: what the run names, else ``RUN/scene``).
        gaussians: the run's :class:`~gof_warp.core.model.Gaussians` already in memory (``extract`` passes its own),
            used instead of reading ``point_cloud.ply`` again.
        mesh: the mesh at ``mesh_path`` already in memory, ``(vertices [V, 3], faces [F, 3])`` or with its vertex
            colours ``(vertices, faces, colours [V, 3])``, used instead of reading the file again (``mesh_path`` still
            names the picture).
    """
    from ..core.config import from_dict
    from ..data import DataConfig
    from ..training.run_folder import cameras_from_json, read_run_config, scene_candidates
    from ..core.model import Gaussians
    from ..training.settings import run_render_config

    run = Path(run_dir)
    if run.is_dir():
        base, ply = run, run / "point_cloud.ply"
        if not ply.is_file():
            raise GofError(f"{run} has no point_cloud.ply (is it a training output folder?)")
    elif run.is_file() and run.suffix.lower() == ".ply":
        base, ply = run.parent, run
    else:
        raise GofError(f"{run} is neither a run folder nor a .ply file")
    device = resolve_device(device)
    config = read_run_config(base / "config.yaml") if run.is_dir() else {}
    render_config = run_render_config(config or {}, "config.yaml")
    data_config = from_dict(DataConfig, config.get("data", {}) or {}, "config.yaml: data")
    render_config = dataclasses.replace(render_config, background=tuple(data_config.background))
    if mesh is not None and mesh_path is None:
        raise GofError("write_run_pictures: a mesh in memory needs mesh_path too (it names the picture)")
    if gaussians is None:
        gaussians = Gaussians.load_ply(ply, device=device)
    if mesh is None and mesh_path is not None:
        from .mesh_files import load_mesh_file

        mesh = load_mesh_file(mesh_path)

    cams_file = base / "cameras.json"
    cams_json: dict = {}
    if scene is not None:
        from ..data import load_scene

        s = load_scene(scene, data_config)
        chosen = choose_views([v.camera for v in s.train], [v.camera for v in s.test], views)
        by_name = {v.camera.name: v.image for v in s.all_views}
        photos = [by_name.get(c.name) for c, _ in chosen]
    elif run.is_dir() and cams_file.is_file():
        cams_json = json.loads(cams_file.read_text())
        train = cameras_from_json(cams_file)
        test = [Camera.from_dict(c) for c in cams_json.get("test", [])]
        chosen = choose_views(train, test, views)
        photos = find_photos([c for c, _ in chosen], scene_candidates(base, cams_json, config, None), data_config,
                             device=_warp_device(device))
    else:
        raise GofError(f"no cameras for {run}: pass a scene folder (the scene the model was trained on)")
    if photos is None:
        log.info("photos not found (looked in the scene the run names and %s): the photo column is left out",
                 base / "scene")
    out = Path(out_dir) if out_dir is not None else base / "pictures"
    path = out / ("views.png" if mesh is None else f"{mesh_picture_stem(mesh_path)}.png")
    return [draw_views(gaussians, chosen, path, photos=photos, mesh=mesh, render_config=render_config,
                       max_width=max_width)]


def draw_views(gaussians, chosen: list[tuple[Camera, str]], path, *, photos=None, mesh=None, render_config=None,
               max_width: int = MAX_WIDTH) -> Path:
    """The views picture of ``gaussians`` (module docstring) for ``chosen`` ``(camera, split)`` pairs (see
    :func:`choose_views`), rows labelled ``name (split)``, written to ``path``; returns ``path``. The one
    drawing path of ``views.png`` (:func:`write_run_pictures`) and of training snapshots
    (:func:`write_model_views`)."""
    path = Path(path)
    labels = [f"{c.name} ({split})" for c, split in chosen]
    view_panels(gaussians, [c for c, _ in chosen], photos=photos, mesh=mesh, render_config=render_config, path=path,
                labels=labels, max_width=max_width)
    log.debug("wrote %s", path)
    return path


def write_model_views(gaussians, scene, path, *, render_config=None, views: int = 3,
                      max_width: int = MAX_WIDTH) -> Path:
    """The views picture of an in-memory model (``views.png``'s panels, the same views: the run's test views
    if any, else train views) over a loaded :class:`~gof_warp.core.scene.Scene`, whose images are the photos:
    what training writes at each snapshot (``RUN/pictures/views_it<N>.png``) without reloading the run."""
    chosen = choose_views(scene.train_cameras, [v.camera for v in scene.test], views)
    by_name = {v.camera.name: v.image for v in scene.all_views}
    photos = [by_name.get(c.name) for c, _ in chosen]
    return draw_views(gaussians, chosen, path, photos=photos, render_config=render_config, max_width=max_width)


def snapshot_picture_name(iteration: int) -> str:
    """``views_it<N>.png``: the picture of the snapshot at iteration ``N`` in ``RUN/pictures``."""
    return f"views_it{int(iteration)}.png"


def snapshot_pictures_or_warning(trainer, record: dict | None = None, *, views: int = 3) -> list[Path]:
    """``RUN/pictures/views_it<N>.png`` for a :class:`~gof_warp.training.trainer.Trainer` at a snapshot (its current
    model, scene and render settings; ``record`` is the snapshot's record, unused beyond its iteration). Like
    :func:`pictures_or_warning`, a failure only logs a warning and returns ``[]``: training goes on."""
    iteration = record["iteration"] if record else trainer.iteration
    path = Path(trainer.out_dir) / "pictures" / snapshot_picture_name(iteration)
    try:
        return [write_model_views(trainer.gaussians, trainer.scene, path, render_config=trainer.render_config,
                                  views=views)]
    except Exception as e:  # noqa: BLE001 - any failure of a convenience output
        log.warning("could not write the picture of the snapshot at iteration %d: %s", iteration, e)
        return []


def spike_picture_name(iteration: int, view: str) -> str:
    """``spike_it<N>_<view>.png``: the picture of the loss spike of ``view`` at iteration ``N`` in ``RUN/pictures``
    (characters other than letters, digits, ``-``, ``_`` and ``.`` in the view's name become ``_``)."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(view))
    return f"spike_it{int(iteration)}_{safe}.png"


def spike_picture_or_warning(trainer, event: dict) -> list[Path]:
    """``RUN/pictures/spike_it<N>_<view>.png`` for one listed loss spike of a :class:`~gof_warp.training.trainer.Trainer`
    (``event``: an entry of ``loss_spikes.view_spikes``): one row, photo | render | median depth | rendered normal |
    distortion, of the trainer's current model (drawn when the spike was read back, a few iterations after it).
    Records the picture's name in ``event["picture"]``. A failure only logs a warning and returns ``[]``."""
    view, iteration = str(event.get("view", "")), int(event.get("iteration", trainer.iteration))
    path = Path(trainer.out_dir) / "pictures" / spike_picture_name(iteration, view)
    try:
        idx = trainer.view_index(view)
        if idx is None:
            raise GofError(f"no training view is called {view!r}")
        photo = np.round(trainer.images[idx].detach().clamp(0, 1).cpu().numpy() * 255).astype(np.uint8)
        label = (f"{view} (train): loss {event.get('ratio')}x its median at iteration {iteration}, drawn at "
                 f"{trainer.iteration}")
        view_panels(trainer.gaussians, [trainer.cameras[idx]], photos=[photo], render_config=trainer.render_config,
                    path=path, labels=[label], distortion=True)
    except Exception as e:  # noqa: BLE001 - any failure of a convenience output
        log.warning("could not write the picture of the loss spike of view %r at iteration %d: %s", view, iteration, e)
        return []
    event["picture"] = f"pictures/{path.name}"
    return [path]


def pictures_or_warning(run_dir, **kwargs) -> list[Path]:
    """:func:`write_run_pictures`, but a failure only logs a warning and returns ``[]``: the commands that call
    it (train, extract) have already written their real outputs, which a picture is never worth losing."""
    try:
        return write_run_pictures(run_dir, **kwargs)
    except Exception as e:  # noqa: BLE001 - any failure of a convenience output
        log.warning("could not write the pictures of %s: %s", run_dir, e)
        return []
