"""Which training preset a scene folder needs — bounded object or a capture with a background — and why.

GOF trains objects on a transparent background (NeRF-synthetic: random initial points, white background,
λ_d = 1000) differently from captures whose background is part of the scene (Mip-NeRF 360, Tanks and
Temples: SfM points, λ_d = 100) and from DTU (decoupled appearance, λ_d = 1000). The choice is read from
the files, before any image is decoded:

=====================================================  ==============  ======================================
what the folder holds                                  preset          why
=====================================================  ==============  ======================================
NeuS/IDR ``cameras_sphere.npz`` (DTU)                  ``dtu``         GOF's DTU settings (scan-sized object,
                                                                       exposure changes: appearance model)
images with transparent pixels (alpha < 255 on ≥ 1 %)  ``blender``     an object cut out of its background
anything else (COLMAP, instant-ngp, opaque Blender)    ``unbounded``   the photos show a background, which
                                                                       must be reconstructed as well
=====================================================  ==============  ======================================

Only the first few images' alpha channels are read (:data:`ALPHA_PROBE_VIEWS`).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..core.config import ConfigError, combine_overrides, from_dict, load_yaml, merge

PRESETS = ("auto", "quick", "cpu", "blender", "unbounded", "dtu", "tnt", "mipnerf360")
#: presets whose schedule and image size are derived for the run (:func:`resolve_config`)
SIZED_PRESETS = ("cpu",)


def preset_path(name_or_path: str) -> Path:
    """A preset name (``configs/NAME.yaml``, installed with the package) or a path to a YAML file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise ConfigError(f"config file {p} not found")
        return p
    candidate = Path(str(resources.files("gof_warp.configs") / f"{name_or_path}.yaml"))
    if not candidate.is_file():
        raise ConfigError(f"unknown config preset {name_or_path!r}; presets: {', '.join(PRESETS)} (or a YAML path)")
    return candidate


def resolve_config(config: str, overrides: list[str], iterations: int | None, scene=None):
    """The :class:`~gof_warp.training.trainer.TrainConfig` of preset (or YAML path) ``config`` with the
    ``key=value`` ``overrides`` and ``iterations`` (None: the preset's) applied.

    The ``cpu`` preset (:data:`SIZED_PRESETS`) gets two settings derived for the run, between the YAML and the
    overrides (so an override wins): GOF's schedule compressed to the run's iteration count
    (:func:`~gof_warp.training.schedule.compress_schedule`) and, when the scene folder ``scene`` is given,
    ``data.downscale`` from its largest image (:func:`~gof_warp.training.schedule.cpu_downscale`)."""
    from .trainer import TrainConfig

    cfg = from_dict(TrainConfig, load_yaml(preset_path(config)), f"config {config}")
    combined = combine_overrides(overrides)
    if iterations is not None:
        combined["iterations"] = iterations
    where = "overrides " + " ".join(overrides)
    if config in SIZED_PRESETS:
        user = merge(cfg, combined, where) if combined else cfg  # the overrides checked, and the run's length
        cfg = merge(cfg, sized_settings(user, scene), f"the {config} preset's settings for this run")
    return merge(cfg, combined, where) if combined else cfg


def sized_settings(cfg, scene=None) -> dict:
    """What the ``cpu`` preset derives for a run of ``cfg.iterations`` on the scene folder ``scene`` (None: no
    downscale): the compressed schedule and ``data.downscale``, as a nested override mapping."""
    from .schedule import compress_schedule, cpu_downscale

    out = compress_schedule(cfg.iterations)
    if scene is not None:
        width, height = largest_image(scene, cfg.data)
        out["data"] = {"downscale": cpu_downscale(width, height)}
    return out


def largest_image(scene, data_config) -> tuple[int, int]:
    """``(width, height)`` of the scene folder's image with the most pixels, from the file headers (nothing is
    decoded)."""
    from ..data import read_plan
    from ..data.images import read_header

    sizes = [(h.width, h.height) for h in (read_header(v.image_path) for v in read_plan(scene, data_config).views)]
    if not sizes:
        raise ConfigError(f"{scene}: the scene has no images to size the cpu preset by")
    return max(sizes, key=lambda wh: wh[0] * wh[1])


ALPHA_PROBE_VIEWS = 3
TRANSPARENT_FRACTION = 0.01  # fraction of pixels with alpha < 255 that marks a cut-out object


@dataclass(frozen=True)
class PresetChoice:
    """``preset``: a name in ``configs/``; ``reason``: one sentence for the user; ``format``: the detected format."""

    preset: str
    reason: str
    format: str

    def describe(self) -> str:
        return f"preset {self.preset!r}: {self.reason}"


def transparent_fraction(image_path: Path) -> float:
    """Fraction of pixels whose alpha is below 255 (0 for images without alpha)."""
    from PIL import Image

    with Image.open(image_path) as im:
        if "A" not in im.getbands():
            return 0.0
        alpha = np.asarray(im.getchannel("A"))
    return float((alpha < 255).mean())


def choose_preset(scene_path) -> PresetChoice:
    """The preset for the scene folder ``scene_path`` (see the module docstring)."""
    from ..data import detect_format, read_plan

    fmt = detect_format(scene_path)
    if fmt == "dtu":
        return PresetChoice("dtu", "DTU/NeuS cameras (cameras_sphere.npz): GOF's DTU settings, decoupled appearance, "
                                   "initial points triangulated from the known poses", fmt)
    plan = read_plan(scene_path)
    probe = [v.image_path for v in plan.views[:ALPHA_PROBE_VIEWS]]
    fractions = [transparent_fraction(p) for p in probe]
    if fractions and max(fractions) >= TRANSPARENT_FRACTION:
        return PresetChoice("blender", f"the images are cut out ({max(fractions):.0%} transparent pixels): a bounded "
                                       "object on a plain background, GOF's NeRF-synthetic settings", fmt)
    points = "its SfM points" if plan.points is not None and len(plan.points) else \
        "points triangulated from the known poses"
    return PresetChoice("unbounded", f"opaque {fmt} images: the background is part of the scene; GOF's unbounded "
                                     f"settings (lambda_d = 100) on a random background colour per view, starting "
                                     f"from {points}", fmt)
