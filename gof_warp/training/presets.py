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

PRESETS = ("auto", "quick", "blender", "unbounded", "dtu", "tnt", "mipnerf360")


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


def resolve_config(config: str, overrides: list[str], iterations: int | None):
    from .trainer import TrainConfig

    cfg = from_dict(TrainConfig, load_yaml(preset_path(config)), f"config {config}")
    combined = combine_overrides(overrides)
    if iterations is not None:
        combined["iterations"] = iterations
    return merge(cfg, combined, "overrides " + " ".join(overrides)) if combined else cfg


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
