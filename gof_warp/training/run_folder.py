"""Reading a training run folder: its Gaussians, cameras and render settings (library code for the CLIs
``extract`` and ``pictures`` and for Python users).

``RUN/point_cloud.ply`` (3DGS layout), ``RUN/cameras.json`` (:meth:`~gof_warp.camera.Camera.to_dict` per
train/test view, written by the trainer) and ``RUN/config.yaml`` (its ``render`` section) — or any Gaussian PLY
together with the scene folder it was trained on.
"""

from __future__ import annotations

import json
from pathlib import Path

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
            from ..core.config import load_yaml
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


def cameras_from_json(path: Path) -> list[Camera]:
    try:
        data = json.loads(path.read_text())
        return [Camera.from_dict(c) for c in data["train"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise GofError(f"{path}: cannot read cameras: {e}") from None
