"""GOF's training loss ``L = L_c + λ_d L_d + λ_n L_n`` (paper Eq. 12; GOF_REFERENCE §4, §9).

* Colour: ``L_c = (1 − λ_dssim)·L1 + λ_dssim·(1 − SSIM)``, SSIM with an 11×11 Gaussian window,
  σ = 1.5 (:func:`gof_warp.eval.image_metrics.ssim`), λ_dssim = 0.2.
* Depth distortion: ``L_d = mean over pixels`` of the renderer's distortion map (GOF's code squares
  NDC-depth differences; the paper writes ``Σ w_i w_j |t_i − t_j|``; the map is the renderer's job).
* Depth–normal consistency, with ``N`` the normal of the rendered median-depth map
  (:func:`depth_to_normal`):

  - ``form="paper"`` (default): ``Σ_i ω_i (1 − n_iᵀN)`` per pixel (paper Eq. 11). Because the
    renderer's normal channel is the *un-normalised* ``Σ_i ω_i n_i`` and its alpha is ``Σ_i ω_i``, this
    is exactly ``alpha − normalᵀN`` — no approximation. Pixels seen by nothing cost nothing.
  - ``form="gof"``: ``1 − normalize(Σ_i ω_i n_i)ᵀN`` per pixel, as GOF's ``train.py`` computes it
    (every pixel weighs the same whatever its opacity).

  Both are averaged over all ``H·W`` pixels; where ``N`` is undefined (1-px border, degenerate
  neighbourhoods) it is 0, as GOF's ``depth_to_normal`` leaves the border: the GOF form then costs 1
  there (GOF's value exactly) and the paper form 0. Gradients reach both the depth and the normals.

The regularisers start at ``regularization_from_iter`` (GOF: 15 000, ``>=``). Setting a λ to 0
switches a term off (and skips its computation) for ablations.

Images are channel-last ``[H, W, 3]`` floats in ``[0, 1]``, like the renderer's ``rgb``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import torch

from .appearance import DOWNSAMPLE
from ..core.camera import Camera
from ..core.config import ConfigError
from ..core.errors import GofError, error_summary
from ..eval.image_metrics import ssim
from .multiview import MultiViewConfig

log = logging.getLogger(__name__)

NORMAL_FORMS = ("paper", "gof")
# A central-difference cross product this much smaller than |dv|·|du| (sine of the angle between the
# two tangents) is treated as degenerate: N is left 0 there instead of dividing by ~0 (which gives
# ~1e12 gradients through torch's normalize at depth edges).
DEGENERATE_SINE = 1e-6


@dataclass
class LossConfig:
    """Weights of GOF's loss terms. λ = 0 switches a term off.

    Defaults: GOF ``arguments/__init__.py`` and its scripts, with the bounded/object-scene distortion
    weight (1000, GOF's DTU script); unbounded-scene presets use ``lambda_distortion = 100``.
    """

    lambda_dssim: float = 0.2  # weight of D-SSIM in the colour loss, (1 − λ)·L1 + λ·D-SSIM; in [0, 1]
    lambda_distortion: float = 1000.0  # λ_d of the depth-distortion term (unbounded presets: 100)
    lambda_normal: float = 0.05  # λ_n of the depth–normal consistency term
    regularization_from_iter: int = 15_000  # the distortion and normal terms act from this iteration
    # "paper": Σ ω_i(1 − n_iᵀN); "gof": 1 − normalize(Σ ω_i n_i)ᵀN
    normal_form: str = field(default="paper", metadata={"set_by": "experimental.normal_form"})
    # a neighbouring photo's patches through the rendered planes (not GOF's; off unless multiview.weight > 0):
    # gof_warp.training.multiview, added by the trainer outside the (compiled) terms above
    multiview: MultiViewConfig = field(default_factory=MultiViewConfig, metadata={"set_by": "experimental.multiview"})

    def __post_init__(self):
        if self.normal_form not in NORMAL_FORMS:
            raise ConfigError(f"experimental.normal_form must be one of {NORMAL_FORMS}, got {self.normal_form!r}")
        if not 0.0 <= self.lambda_dssim <= 1.0:
            raise ConfigError(f"loss.lambda_dssim must be in [0, 1], got {self.lambda_dssim}")
        if self.lambda_distortion < 0 or self.lambda_normal < 0:
            raise ConfigError("loss.lambda_distortion and loss.lambda_normal must be >= 0")


def l1(img: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference (scalar)."""
    return (img - gt).abs().mean()


def dssim(img: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """``1 − SSIM`` of two channel-last images ``[H, W, C]`` (11×11 Gaussian window, σ = 1.5)."""
    return 1.0 - ssim(img.permute(2, 0, 1), gt.permute(2, 0, 1), window_size=11, sigma=1.5)


def distortion_loss(distortion: torch.Tensor) -> torch.Tensor:
    """Mean of the renderer's per-pixel depth-distortion map ``[H, W]``."""
    return distortion.mean()


def depth_to_points(depth: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Camera-space points ``[H, W, 3]`` of a z-depth map ``[H, W]`` through the pixel centres
    ``((i + ½ − cx)/fx, (j + ½ − cy)/fy, 1)·depth`` (any principal point)."""
    return _points(depth, camera.pinhole)


def _points(depth: torch.Tensor, intr) -> torch.Tensor:
    """:func:`depth_to_points` for ``intr = (fx, fy, cx, cy)``: floats, or a ``[4]`` tensor (no constants to
    specialise on in a compiled graph)."""
    h, w = depth.shape
    kw = {"dtype": depth.dtype, "device": depth.device}
    if isinstance(intr, torch.Tensor):  # float64 on the device: rounded to the depth's dtype, as a float would be
        intr = intr.to(depth.dtype)
    x = (torch.arange(w, **kw) + 0.5 - intr[2]) / intr[0]
    y = (torch.arange(h, **kw) + 0.5 - intr[3]) / intr[1]
    rays = torch.stack(torch.broadcast_tensors(x[None, :], y[:, None], torch.ones((), **kw)), dim=-1)
    return depth[..., None] * rays


def depth_to_normal(depth: torch.Tensor, camera: Camera, *, return_valid: bool = False):
    """Normals of a depth map by central differences (GOF ``utils/depth_utils.py``), camera space.

    ``N[v, u] = normalize((P[v+1, u] − P[v−1, u]) × (P[v, u+1] − P[v, u−1]))`` with ``P`` from
    :func:`depth_to_points`. With OpenCV axes (x right, y down, z forward) this order makes ``N``
    face the camera for any depth map: ``Nᵀr ∝ −z²/(fx fy) < 0`` along the pixel ray ``r``, so no
    per-pixel sign flip is needed.

    Args:
        depth: ``[H, W]`` z-depth (the renderer's median depth), differentiable.
        camera: the view's :class:`~gof_warp.core.camera.Camera` (intrinsics only are used).
        return_valid: also return the ``[H, W]`` bool mask where ``N`` is defined.
    Returns:
        ``[H, W, 3]`` unit normals; 0 on the 1-pixel border and where the two tangents are (nearly)
        parallel or zero (see ``DEGENERATE_SINE``).
    """
    _check_depth_map(depth)
    normals, valid = _normals(depth, camera.pinhole)
    return (normals, valid) if return_valid else normals


def _check_depth_map(depth: torch.Tensor) -> None:
    if depth.ndim != 2 or depth.shape[0] < 3 or depth.shape[1] < 3:
        raise GofError(f"depth_to_normal: depth must be [H, W] with H, W >= 3, got {list(depth.shape)}")


def _normals(depth: torch.Tensor, intr) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`depth_to_normal` (unchecked) for ``intr`` as in :func:`_points`: ``(normals, valid)``."""
    p = _points(depth, intr)
    dv = p[2:, 1:-1] - p[:-2, 1:-1]
    du = p[1:-1, 2:] - p[1:-1, :-2]
    n = torch.linalg.cross(dv, du, dim=-1)
    norm = n.norm(dim=-1)
    valid = norm > DEGENERATE_SINE * dv.norm(dim=-1) * du.norm(dim=-1)
    inner = torch.where(valid[..., None], n / torch.where(valid, norm, torch.ones_like(norm))[..., None],
                        torch.zeros_like(n))
    return torch.nn.functional.pad(inner, (0, 0, 1, 1, 1, 1)), torch.nn.functional.pad(valid, (1, 1, 1, 1))


def depth_normal_consistency(median_depth: torch.Tensor, normal: torch.Tensor, camera: Camera,
                             alpha: torch.Tensor | None = None, *, form: str = "paper") -> torch.Tensor:
    """Depth–normal consistency loss (scalar, mean over all pixels; see the module docstring).

    Args:
        median_depth: ``[H, W]`` rendered median depth.
        normal: ``[H, W, 3]`` rendered camera-space normal ``Σ_i ω_i n_i`` (not renormalised).
        camera: the view's camera.
        alpha: ``[H, W]`` rendered ``Σ_i ω_i``; required for ``form="paper"``.
        form: ``"paper"`` (``alpha − normalᵀN``) or ``"gof"`` (``1 − normalize(normal)ᵀN``).
    """
    _check_consistency_inputs(median_depth, normal, alpha, form)
    return _consistency(median_depth, normal, camera.pinhole, alpha, form)


def _check_consistency_inputs(median_depth, normal, alpha, form: str) -> None:
    if form not in NORMAL_FORMS:
        raise GofError(f"depth_normal_consistency: form must be one of {NORMAL_FORMS}, got {form!r}")
    if normal.shape != (*median_depth.shape, 3):
        raise GofError(f"depth_normal_consistency: normal {list(normal.shape)} does not match "
                       f"depth {list(median_depth.shape)}")
    _check_depth_map(median_depth)
    if form == "paper" and alpha is None:
        raise GofError("depth_normal_consistency: form='paper' needs the rendered alpha (Σ ω_i)")
    if alpha is not None and alpha.shape != median_depth.shape:
        raise GofError(f"depth_normal_consistency: alpha {list(alpha.shape)} does not match "
                       f"depth {list(median_depth.shape)}")


def _consistency(median_depth, normal, intr, alpha, form: str) -> torch.Tensor:
    """:func:`depth_normal_consistency` (unchecked) for ``intr`` as in :func:`_points`."""
    n_depth, valid = _normals(median_depth, intr)
    if form == "gof":
        return (1.0 - (torch.nn.functional.normalize(normal, dim=-1) * n_depth).sum(-1)).mean()
    per_pixel = alpha - (normal * n_depth).sum(-1)
    return torch.where(valid, per_pixel, torch.zeros_like(per_pixel)).mean()


def total_loss(out: dict, gt_image: torch.Tensor, camera: Camera, config: LossConfig, iteration: int, *,
               l1_pair: tuple[torch.Tensor, torch.Tensor] | None = None) -> tuple[torch.Tensor, dict]:
    """GOF's training loss for one view.

    Args:
        out: the renderer's dict: ``rgb [H, W, 3]``, ``alpha [H, W]``, ``median_depth [H, W]``,
            ``normal [H, W, 3]`` (camera space), ``distortion [H, W]``.
        gt_image: ``[H, W, 3]`` in ``[0, 1]``, same device/dtype as ``out["rgb"]``.
        camera: the view's camera.
        iteration: current iteration (GOF counts from 1); regularisers act from
            ``config.regularization_from_iter`` on.
        l1_pair: optional ``(prediction, target)`` that replaces ``(rgb, gt_image)`` in the L1 term
            only — GOF's decoupled appearance puts the appearance-corrected crop there while SSIM
            stays on the raw render.
    Returns:
        ``(loss, terms)``: the scalar loss and detached scalars ``l1, dssim, distortion, normal,
        total`` (terms that were off or inactive are absent).
    """
    args, regularise = _loss_inputs(out, gt_image, config, iteration, l1_pair)
    loss, terms = loss_terms(*args, camera.pinhole, config, regularise)
    return loss, {k: v.detach() for k, v in terms.items()}


def _loss_inputs(out: dict, gt_image, config: LossConfig, iteration: int, l1_pair) -> tuple[tuple, bool]:
    """The checked tensor arguments of :func:`loss_terms` (up to ``intr``) and ``regularise``."""
    rgb = out["rgb"]
    if gt_image.shape != rgb.shape:
        raise GofError(f"total_loss: gt_image {list(gt_image.shape)} does not match rendered rgb {list(rgb.shape)} "
                       "(both channel-last [H, W, 3])")
    regularise = iteration >= config.regularization_from_iter
    if regularise and config.lambda_normal > 0:
        _check_consistency_inputs(out["median_depth"], out["normal"], out.get("alpha"), config.normal_form)
    pred, target = (rgb, gt_image) if l1_pair is None else l1_pair
    return (rgb, gt_image, pred, target, out.get("alpha"), out["median_depth"], out["normal"], out["distortion"]), regularise


def loss_terms(rgb, gt_image, l1_pred, l1_target, alpha, median_depth, normal, distortion, intr, config: LossConfig,
               regularise: bool) -> tuple[torch.Tensor, dict]:
    """The core of :func:`total_loss` on plain tensors, unchecked: ``(loss, terms)`` (terms not detached).

    ``intr = (fx, fy, cx, cy)`` as floats or a ``[4]`` tensor on the images' device; ``regularise``: the
    distortion and normal terms are on. Tensors and one flag only, so that ``torch.compile`` can fuse it into a
    few kernels (one graph per value of ``regularise``: the trainer's ``compile_loss``)."""
    terms: dict[str, torch.Tensor] = {}
    terms["l1"] = l1(l1_pred, l1_target)
    loss = (1.0 - config.lambda_dssim) * terms["l1"]
    if config.lambda_dssim > 0:
        terms["dssim"] = dssim(rgb, gt_image)
        loss = loss + config.lambda_dssim * terms["dssim"]
    if regularise:
        if config.lambda_distortion > 0:
            terms["distortion"] = distortion_loss(distortion)
            loss = loss + config.lambda_distortion * terms["distortion"]
        if config.lambda_normal > 0:
            terms["normal"] = _consistency(median_depth, normal, intr, alpha, config.normal_form)
            loss = loss + config.lambda_normal * terms["normal"]
    terms["total"] = loss
    return loss, terms


def appearance_l1_pair(appearance, rgb: torch.Tensor, gt_image: torch.Tensor,
                       embedding: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """GOF's decoupled-appearance L1 pair ``(gain ⊙ crop(rgb), crop(gt))``, channel-last ``[H', W', 3]`` each, for an
    :class:`~gof_warp.training.appearance.AppearanceModel` and the image's embedding row ``[D]``."""
    corrected = appearance.apply_for(rgb.permute(2, 0, 1), embedding)
    return corrected.permute(1, 2, 0), appearance.crop(gt_image.permute(2, 0, 1)).permute(1, 2, 0)


def appearance_loss_terms(appearance, view_index, rgb, gt_image, alpha, median_depth, normal, distortion, intr,
                          config: LossConfig, regularise: bool) -> tuple[torch.Tensor, dict]:
    """:func:`loss_terms` with the appearance-corrected L1 pair of the image ``view_index`` (a 0-d integer tensor on
    the images' device, so that a compiled graph serves every view)."""
    pred, target = appearance_l1_pair(appearance, rgb, gt_image, appearance.embedding(view_index))
    return loss_terms(rgb, gt_image, pred, target, alpha, median_depth, normal, distortion, intr, config, regularise)


COMPILE_MODES = ("auto", "on", "off")


class TrainingLoss:
    """:func:`total_loss` over a fixed list of cameras, through ``torch.compile`` where asked, with GOF's decoupled
    appearance in the L1 term when given an ``appearance`` model.

    The loss is some 60 small tensor operations (SSIM's moments, the normals of the depth map, the products
    of the consistency term) and as many in its backward, and the appearance network a dozen layers more: on a GPU
    the host spends longer issuing them than the GPU takes to run them, and training steps are host-bound
    (``benchmarks/RESULTS.md``, section 2). Compiled, the forward and the backward are a few fused kernels each. The
    compiled graph takes the intrinsics as a ``[4]`` tensor per camera and the appearance embedding's row as a device
    index, so that views do not trigger recompilation; there is one graph per value of ``regularise``.

    ``mode``: ``"auto"`` compiles on CUDA and falls back to the eager loss (with a warning) if compiling fails;
    ``"on"`` compiles on any device and raises if it fails; ``"off"`` never compiles. ``backend``: passed to
    ``torch.compile`` (tests use ``"aot_eager"``, which traces without generating code). ``cuda_graphs``: on CUDA,
    compile with ``mode="reduce-overhead"``, which replays the compiled forward and backward as CUDA graphs (one launch
    each instead of one per kernel); the terms are then copied out of the graph's memory, which the next replay reuses.
    ``appearance``: an :class:`~gof_warp.training.appearance.AppearanceModel` whose embedding ``i`` belongs to camera ``i``;
    views smaller than its 32-pixel crop get the plain L1."""

    def __init__(self, config: LossConfig, cameras, device, mode: str = "auto", backend: str = "inductor",
                 cuda_graphs: bool = False, appearance=None):
        if mode not in COMPILE_MODES:
            raise GofError(f"compile_loss must be one of {COMPILE_MODES}, got {mode!r}")
        if appearance is not None and appearance.embedding.num_embeddings < len(cameras):
            raise GofError(f"TrainingLoss: the appearance model has {appearance.embedding.num_embeddings} embeddings "
                           f"for {len(cameras)} cameras (camera i uses embedding i)")
        self.config, self.mode, self.appearance = config, mode, appearance
        device = torch.device(device)
        self.corrected = [appearance is not None and min(c.width, c.height) >= DOWNSAMPLE for c in cameras]
        self.compiled = self.compiled_appearance = None
        self.fallback_reason: str | None = None
        self.cuda_graphs = False
        if mode == "on" or (mode == "auto" and device.type == "cuda"):
            self.intr = [torch.tensor(c.pinhole, dtype=torch.float64, device=device) for c in cameras]
            self.view_index = [torch.tensor(i, dtype=torch.int64, device=device) for i in range(len(cameras))]
            self.cuda_graphs = cuda_graphs and device.type == "cuda"
            options = dict(dynamic=False, fullgraph=True, backend=backend)
            if self.cuda_graphs:
                options["mode"] = "reduce-overhead"
            self.compiled = torch.compile(loss_terms, **options)
            if appearance is not None:
                self.compiled_appearance = torch.compile(appearance_loss_terms, **options)

    def __call__(self, out: dict, gt_image, camera: Camera, view: int, iteration: int, *, l1_pair=None):
        """``total_loss(out, gt_image, camera, config, iteration, l1_pair=l1_pair)``, with the appearance's L1 pair
        when the loss has an appearance model and no ``l1_pair`` is given; ``view``: ``camera``'s index in the list
        given at construction."""
        corrected = l1_pair is None and self.corrected[view]
        if self.compiled is not None:
            args, regularise = _loss_inputs(out, gt_image, self.config, iteration, l1_pair)
            try:
                if self.cuda_graphs:
                    torch.compiler.cudagraph_mark_step_begin()
                if corrected:
                    loss, terms = self.compiled_appearance(self.appearance, self.view_index[view], *args[:2], *args[4:],
                                                           self.intr[view], self.config, regularise)
                else:
                    loss, terms = self.compiled(*args, self.intr[view], self.config, regularise)
                if self.cuda_graphs:  # one copy out of the graph's memory; the terms are views of it
                    copied = torch.stack([v.detach() for v in terms.values()])
                    return loss, dict(zip(terms, copied.unbind()))
                return loss, {k: v.detach() for k, v in terms.items()}
            except Exception as e:  # noqa: BLE001 - any compiler failure: the eager loss computes the same
                if self.mode != "auto":
                    raise
                self.give_up(e)
        if corrected:
            l1_pair = appearance_l1_pair(self.appearance, out["rgb"], gt_image, self.appearance.embedding.weight[view])
        return total_loss(out, gt_image, camera, self.config, iteration, l1_pair=l1_pair)

    def give_up(self, error: Exception) -> None:
        """Use the eager loss from now on (``mode="auto"`` after ``error`` from the compiler), with a warning."""
        self.fallback_reason = error_summary(error)
        log.warning("torch.compile of the loss failed (%s); using the eager loss", self.fallback_reason)
        self.compiled = self.compiled_appearance = None
        self.cuda_graphs = False
