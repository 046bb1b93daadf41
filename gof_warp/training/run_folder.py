"""A training run folder: reading its Gaussians, cameras and render settings (library code for the CLIs
``extract`` and ``pictures`` and for Python users), and guarding it: its lock, its inputs, its outputs.

``RUN/point_cloud.ply`` (3DGS layout), ``RUN/cameras.json`` (:meth:`~gof_warp.core.camera.Camera.to_dict` per
train/test view, written by the trainer) and ``RUN/config.yaml`` (its ``render`` section) — or any Gaussian PLY
together with the scene folder it was trained on.

Guards. :func:`lock_run_folder`: one training at a time per run folder (an OS lock, ``fcntl.flock`` on
``RUN/.lock``, released when the process ends, however it ends). :func:`run_inputs`: the paths another command
must not write over (the model, its cameras and config, the checkpoints, the scene). :func:`remove_run_outputs`:
what ``train --overwrite`` clears, by name (files of the run, never the scene nor anything it does not know).
:func:`remove_if_empty`: a run folder a failed command created and left empty.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
from pathlib import Path

from ..core.config import load_yaml
from ..core.camera import Camera
from ..core.errors import GofError
from ..rendering.render import RenderConfig


def load_run(run: Path, scene: str | None, device: str):
    """``(gaussians, cameras, views, render_config)`` from a run folder or a PLY (+ ``--scene``)."""
    from ..core.model import Gaussians

    views = None
    render_config = RenderConfig()
    if run.is_dir():
        ply = run / "point_cloud.ply"
        if not ply.is_file():
            raise GofError(f"{run} has no point_cloud.ply (is it a training output folder?)")
        cfg_file = run / "config.yaml"
        if cfg_file.is_file():
            from .settings import run_render_config

            render_config = run_render_config(load_yaml(cfg_file), str(cfg_file))
    elif run.suffix.lower() == ".ply" and run.is_file():
        ply = run
    else:
        raise GofError(f"{run} is neither a run folder nor a .ply file")
    gaussians = Gaussians.load_ply(ply, device=device)
    if scene is not None:
        from ..data import load_scene

        s = load_scene(scene)
        views = s.train
        cameras = s.train_cameras
    elif run.is_dir() and (run / "cameras.json").is_file():
        cameras = cameras_from_json(run / "cameras.json")
    else:
        raise GofError(f"no cameras for {run}: pass --scene SCENE (the scene the model was trained on)")
    return gaussians, cameras, views, render_config


def cameras_from_json(path: Path, split: str = "train") -> list[Camera]:
    """The ``split`` (``"train"`` or ``"test"``) cameras of a run's ``cameras.json``; :class:`GofError` when unreadable."""
    try:
        data = json.loads(path.read_text())
        return [Camera.from_dict(c) for c in data[split]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise GofError(f"{path}: cannot read cameras: {e}") from None


LOCK_NAME = ".lock"

#: what a training run and the commands run on it write into ``RUN/`` (removed by :func:`remove_run_outputs`)
_OUTPUT_FILES = ("config.yaml", "cameras.json", "point_cloud.ply", "metrics.json", "opacity_volume.nvdb",
                 "opacity_volume.json")
_OUTPUT_PATTERNS = (re.compile(r"^mesh_.*\.(ply|glb|obj|json)$"),)
_OUTPUT_FOLDERS = {"checkpoints": re.compile(r"^(ckpt_\d+\.pt(\.corrupt(\.\d+)?)?|\.ckpt_.*\.tmp)$"),
                   "pictures": re.compile(r"^.*\.png$"),
                   "snapshots": None}  # snapshots/iter_<k>/{point_cloud.ply, snapshot.json}


@contextlib.contextmanager
def lock_run_folder(run):
    """Hold the run folder's lock (``RUN/.lock``, ``fcntl.flock``) while within; :class:`GofError` at once when
    another process holds it. The OS releases it when the process ends, also on a crash or ``kill -9``."""
    import fcntl

    path = Path(run) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as e:
        raise GofError(f"cannot create the run folder's lock {path}: {e.strerror or e}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise GofError(f"{run} is in use by another training (it holds {path}): wait for it to end, or choose "
                           "another --out") from None
        yield path
    finally:
        os.close(fd)  # releases the lock


def is_finished_run(run) -> bool:
    """Whether ``run`` holds a trained model or checkpoints (what ``train --out`` must not start over silently)."""
    from .checkpoint import list_checkpoints

    run = Path(run)
    return (run / "point_cloud.ply").exists() or bool(list_checkpoints(run))


def run_inputs(run, scene=None) -> list[Path]:
    """The paths that a command reading the run folder ``run`` (or a Gaussian PLY) must not write over: the PLY,
    ``cameras.json``, ``config.yaml``, the checkpoints, snapshots and lock, the built-in scene ``RUN/scene``,
    the scene folder ``cameras.json`` names, and ``scene`` (a ``--scene`` argument)."""
    run = Path(run)
    found: list[Path] = []
    if run.is_dir():
        found += [run / name for name in ("point_cloud.ply", "cameras.json", "config.yaml", "checkpoints",
                                          "snapshots", "scene", LOCK_NAME)]
        with contextlib.suppress(OSError, ValueError, TypeError, AttributeError):
            named = json.loads((run / "cameras.json").read_text()).get("scene")
            if named:
                found.append(Path(named))
    else:
        found.append(run)
    if scene is not None:
        found.append(Path(scene))
    return found


def remove_run_outputs(run) -> list[Path]:
    """Remove what a training run and the commands on it wrote into ``run`` (model, config, cameras, metrics,
    checkpoints, snapshots, pictures, meshes, volumes), by name; the scene and unknown files stay. Returns the
    paths removed."""
    run = Path(run)
    removed = []
    for p in sorted(run.iterdir()) if run.is_dir() else []:
        if p.is_symlink() or not (p.is_file() or p.is_dir()):
            continue
        if p.is_file() and (p.name in _OUTPUT_FILES or any(r.match(p.name) for r in _OUTPUT_PATTERNS)):
            p.unlink()
            removed.append(p)
        elif p.is_dir() and p.name in _OUTPUT_FOLDERS:
            pattern = _OUTPUT_FOLDERS[p.name]
            if pattern is None:  # snapshots: its iter_<k> folders
                for q in p.iterdir():
                    if q.is_dir() and not q.is_symlink() and re.match(r"^iter_\d+$", q.name):
                        shutil.rmtree(q)
                        removed.append(q)
            else:
                for q in p.iterdir():
                    if q.is_file() and not q.is_symlink() and pattern.match(q.name):
                        q.unlink()
                        removed.append(q)
            with contextlib.suppress(OSError):
                p.rmdir()  # only when nothing else is left in it
    return removed


def remove_if_empty(run) -> bool:
    """Remove the folder ``run`` when it holds nothing but its lock file; whether it was removed."""
    run = Path(run)
    try:
        if any(p.name != LOCK_NAME for p in run.iterdir()):
            return False
        (run / LOCK_NAME).unlink(missing_ok=True)
        run.rmdir()
    except OSError:
        return False
    return True


def read_run_config(path: Path) -> dict:
    """A run's ``config.yaml`` as a mapping ({} when there is none)."""
    if not path.is_file():
        return {}
    data = load_yaml(path)
    return data if isinstance(data, dict) else {}


def scene_candidates(base: Path, cameras_json: dict, config: dict, scene) -> list[Path]:
    """Scene folders to try for a run's photos, most explicit first: ``scene``, the folder ``cameras.json`` or
    ``config.yaml`` names (as given and relative to the run), then ``RUN/scene``."""
    named = [scene] if scene is not None else []
    for d in (cameras_json, config, config.get("data", {}) if isinstance(config.get("data"), dict) else {}):
        for key in ("scene", "scene_dir", "source", "path"):
            if isinstance(d.get(key), str) and d[key]:
                named.append(d[key])
    out = []
    for n in named:
        p = Path(n).expanduser()
        out += [p] if p.is_absolute() else [p, base / p]
    out.append(base / "scene")  # the built-in default run generates its scene there
    return out
