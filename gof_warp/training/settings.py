"""The two sections of :class:`~gof_warp.training.trainer.TrainConfig` that are not a stage's: ``experimental`` and
``performance``, and the map from the keys they replace.

``experimental``: settings that no preset turns on — alternatives to GOF's choices kept for comparisons and
measurements (a different distortion or normal-consistency form, another densification metric, 3DGS's screen-size
prune and learning-rate delay, the multi-view photometric term, …). They act as before when set; they are grouped
here so that the stage sections hold what a user of GOF adjusts. Each is copied into its stage's config (the
stage's field is marked ``set_by``), where the stage code reads it.

``performance``: how fast, never what: each setting's default is decided for the device and the run length, and a
setting here only overrides that decision (for debugging or measuring). The training result does not depend on
them beyond float summation order, except ``adam`` on the CPU (see :class:`PerformanceConfig`).

Old keys (a run folder's ``config.yaml`` or a checkpoint written before these sections existed, or an override
such as ``loss.multiview.weight=0.2``) are moved to their new place with a :class:`ConfigDeprecationWarning`;
``cudnn_benchmark`` is dropped (always on while training).
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from dataclasses import dataclass, field

from ..core.config import ConfigError
from .losses import COMPILE_MODES
from .multiview import MultiViewConfig

ADAM_CHOICES = ("auto", "warp", "torch", "torch-fused", "torch-loop")


class ConfigDeprecationWarning(FutureWarning):
    """An old config key that was moved (shown by default, unlike DeprecationWarning)."""


@dataclass
class ExperimentalConfig:
    """Alternatives to GOF's choices that no preset turns on, kept for comparisons (module docstring).

    Attributes:
        multiview: the multi-view photometric term (:class:`~gof_warp.training.multiview.MultiViewConfig`;
            not GOF's; ``multiview.weight`` 0 = off).
        normal_form: depth–normal consistency form: ``"paper"`` Σ ω_i(1 − n_iᵀN) (GOF's), ``"gof"``
            1 − normalize(Σ ω_i n_i)ᵀN.
        distortion: ``"gof"`` (GOF/2DGS's NDC-depth form) or ``"paper"`` (paper Eq. 13 on raw depth; λ_d must be
            scaled down ~10⁴). See :class:`~gof_warp.rendering.render.RenderConfig`.
        distortion_linear_from: 0 = off (GOF); a depth L > render.near continues the NDC depth by its tangent
            beyond L, so far layers cost as much as layers at L.
        tile_cull: bin each Gaussian only into the tiles its ellipse meets (true, same images, fewer list
            entries); false = every tile of its bounding rectangle, as 3DGS/GOF.
        densify_metric: ``"gof"`` | ``"paper"`` | ``"standard"`` densification gradient statistic
            (:mod:`gof_warp.training.densify`).
        abs_grad_threshold: τ_M on M̄ (NDC units), ``densify_metric="paper"`` only.
        prune_screen_size: 3DGS's screen-size prune (dead in GOF's code, so off).
        max_screen_radius: that prune's radius in pixels.
        means_lr_delay_steps: 3DGS's learning-rate delay of the means, in iterations (0 = none, as GOF).
        means_lr_delay_mult: the delay's starting factor.
        background_points: extra initial points on a sphere around the scene (0 = none).
    """

    multiview: MultiViewConfig = field(default_factory=MultiViewConfig)
    normal_form: str = "paper"
    distortion: str = "gof"
    distortion_linear_from: float = 0.0
    tile_cull: bool = True
    densify_metric: str = "gof"
    abs_grad_threshold: float = 2e-4
    prune_screen_size: bool = False
    max_screen_radius: float = 20.0
    means_lr_delay_steps: int = 0
    means_lr_delay_mult: float = 0.01
    background_points: int = 0


#: experimental key → (stage section, field of the stage's config it sets)
EXPERIMENTAL_TARGETS = {
    "multiview": ("loss", "multiview"),
    "normal_form": ("loss", "normal_form"),
    "distortion": ("render", "distortion"),
    "distortion_linear_from": ("render", "distortion_linear_from"),
    "tile_cull": ("render", "tile_cull"),
    "densify_metric": ("densify", "metric"),
    "abs_grad_threshold": ("densify", "abs_grad_threshold"),
    "prune_screen_size": ("densify", "prune_screen_size"),
    "max_screen_radius": ("densify", "max_screen_radius"),
    "means_lr_delay_steps": ("optim", "means_lr_delay_steps"),
    "means_lr_delay_mult": ("optim", "means_lr_delay_mult"),
    "background_points": ("model", "background_points"),
}


@dataclass
class PerformanceConfig:
    """Overrides of decisions that change speed, not results (module docstring); the defaults decide by device
    and run length.

    Attributes:
        compile_loss: the loss through ``torch.compile``: ``"auto"`` compiles on CUDA for runs of at least
            ``AUTO_COMPILE_MIN_ITERATIONS`` iterations (eager below, on the CPU, or if compiling fails); ``"on"``;
            ``"off"`` (eager: for debugging). Where the loss is compiled on CUDA, the Gaussians' activations are too.
            YAML's bare on/off (true/false) are taken as "on"/"off".
        loss_cuda_graphs: a loss compiled on CUDA is replayed as CUDA graphs (one launch for the loss and the
            appearance network, forward and backward); false = its kernels launched one by one.
        tile_list_margin: on CUDA, tile lists are sized at this factor over earlier renders' counts, without a
            host–device synchronisation per iteration (``kernels.binning.TileListSizer``); 0 = exact sizing.
            Raise it if the log reports overflowing renders.
        checksum_every: with several processes, compare the ranks' models every this many iterations
            (0 = never).
        adam: the Gaussians' Adam: ``"auto"`` = ``"warp"`` on CUDA, ``"torch"`` on the CPU; ``"warp"`` (WarpAdam, the
            bits of torch's fused CUDA Adam); ``"torch"`` (torch's Adam, fused on CUDA, its loop version on the CPU);
            ``"torch-fused"`` / ``"torch-loop"`` (torch's, fused or loop on any device). The fused/loop choice also
            applies to the appearance network's Adam (always torch's). On the CPU, fused and loop versions differ
            in the last bits.
    """

    compile_loss: str | bool = "auto"
    loss_cuda_graphs: bool = True
    tile_list_margin: float = 1.25
    checksum_every: int = 1000
    adam: str = "auto"

    def __post_init__(self):
        if isinstance(self.compile_loss, bool):
            self.compile_loss = "on" if self.compile_loss else "off"
        if self.compile_loss not in COMPILE_MODES:
            raise ConfigError(f"performance.compile_loss must be one of {COMPILE_MODES}, got {self.compile_loss!r}")
        m = self.tile_list_margin
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not (m == 0 or m >= 1):
            raise ConfigError(f"performance.tile_list_margin must be 0 (exact sizing) or a number >= 1, got {m!r}")
        v = self.checksum_every
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ConfigError(f"performance.checksum_every must be an integer >= 0, got {v!r}")
        if self.adam not in ADAM_CHOICES:
            raise ConfigError(f"performance.adam must be one of {ADAM_CHOICES}, got {self.adam!r}")

    def optim_fields(self) -> dict:
        """``OptimConfig``'s ``adam`` and ``fused`` for :attr:`adam`."""
        return {"auto": {"adam": "auto", "fused": None}, "warp": {"adam": "warp", "fused": None},
                "torch": {"adam": "torch", "fused": None}, "torch-fused": {"adam": "torch", "fused": True},
                "torch-loop": {"adam": "torch", "fused": False}}[self.adam]


_PERFORMANCE_TOP = ("compile_loss", "loss_cuda_graphs", "tile_list_margin", "checksum_every")


def _adam_choice(adam, fused) -> str:
    """The one ``performance.adam`` for the old pair ``optim.adam`` / ``optim.fused``."""
    adam = "auto" if adam is None else adam
    if fused is None or adam == "warp":
        return adam
    return "torch-fused" if fused else "torch-loop"


def upgrade_keys(data: dict, where: str) -> dict:
    """``data`` (a TrainConfig mapping, possibly partial) with old keys moved to ``experimental``/``performance``,
    each move warned about (:class:`ConfigDeprecationWarning`). ``data`` itself is left as it is."""
    if not isinstance(data, dict):
        return data
    data = copy.deepcopy(data)
    moved: list[str] = []

    def put(section: str, key: str, value, old: str):
        target = data.setdefault(section, {})
        if not isinstance(target, dict):
            raise ConfigError(f"{where}.{section}: expected a mapping, got {target!r}")
        if key not in target:  # the new key, when both are given, wins
            target[key] = value
        moved.append(f"{old} -> {section}.{key}")

    for new, (section, old) in EXPERIMENTAL_TARGETS.items():
        sec = data.get(section)
        if isinstance(sec, dict) and old in sec:
            put("experimental", new, sec.pop(old), f"{section}.{old}")
    for key in _PERFORMANCE_TOP:
        if key in data:
            put("performance", key, data.pop(key), key)
    optim = data.get("optim")
    if isinstance(optim, dict) and ("adam" in optim or "fused" in optim):
        had = [k for k in ("adam", "fused") if k in optim]
        choice = _adam_choice(optim.pop("adam", None), optim.pop("fused", None))
        put("performance", "adam", choice, " and ".join(f"optim.{k}" for k in had))
    if "cudnn_benchmark" in data:
        data.pop("cudnn_benchmark")
        moved.append("cudnn_benchmark (removed: cuDNN's autotuner is always on while training)")
    dens = data.get("densify")
    if isinstance(dens, dict) and "seed" in dens:
        old = dens.pop("seed")
        note = "" if old == data.get("seed", 0) else f" (its value {old} is not used: densification follows seed)"
        moved.append(f"densify.seed (removed: densification is seeded by seed{note})")
    if moved:
        warnings.warn(f"{where}: old config key(s) moved: {'; '.join(moved)}. Write the new keys to silence this.",
                      ConfigDeprecationWarning, stacklevel=3)
    return data


def run_render_config(data: dict, where: str):
    """The :class:`~gof_warp.rendering.render.RenderConfig` of a run's resolved config (``RUN/config.yaml`` as a
    mapping, old or new keys): its ``render`` section with the ``experimental`` render settings copied in."""
    from ..core.config import from_dict
    from ..rendering.render import RenderConfig

    data = upgrade_keys({k: data.get(k) for k in ("render", "experimental") if data.get(k)}, where)
    render = from_dict(RenderConfig, data.get("render", {}), f"{where}: render")
    exp = from_dict(ExperimentalConfig, data.get("experimental", {}), f"{where}: experimental")
    values = {name: getattr(exp, key) for key, (section, name) in EXPERIMENTAL_TARGETS.items() if section == "render"}
    return dataclasses.replace(render, **values)
