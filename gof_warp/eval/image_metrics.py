"""Image metrics in torch: PSNR, SSIM (also the training loss), LPIPS-VGG from local weights.

Shapes and ranges (all functions): images are float tensors ``[3, H, W]`` or ``[B, 3, H, W]`` (any
channel count ``C`` works) with values in ``[0, 1]``; prediction and ground truth have the same shape,
dtype and device. Everything runs on the tensors' device and is differentiable (PSNR, SSIM, LPIPS).

SSIM is the one 3DGS and GOF train and evaluate with (``utils/loss_utils.py::ssim``): an 11x11
Gaussian window with sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, zero padding (``conv2d(padding=5,
groups=C)``), mean of the SSIM map over channels and pixels. We convolve separably (one 1-D pass
along each axis); with zero padding this is the same sum as the 2-D window, up to float rounding.

LPIPS needs VGG-16 + LPIPS linear-layer weights on disk; nothing is ever downloaded. See
:func:`load_lpips`.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import torch
import torch.nn.functional as F

from ..core.errors import GofError

log = logging.getLogger(__name__)

SSIM_C1 = 0.01**2  # (K1 * L)^2 with K1 = 0.01, data range L = 1 (Wang et al. 2004; 3DGS)
SSIM_C2 = 0.03**2  # (K2 * L)^2 with K2 = 0.03
LPIPS_WEIGHTS_ENV = "GOF_WARP_LPIPS_WEIGHTS"


def _as_batch(img: torch.Tensor, gt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Check a prediction/ground-truth pair; return both as ``[B, C, H, W]`` and whether a batch was given."""
    if not isinstance(img, torch.Tensor) or not isinstance(gt, torch.Tensor):
        raise GofError(f"images must be torch tensors, got {type(img).__name__} and {type(gt).__name__}")
    if img.shape != gt.shape:
        raise GofError(f"image shapes differ: prediction {tuple(img.shape)} vs ground truth {tuple(gt.shape)}")
    if img.dim() not in (3, 4):
        raise GofError(f"images must be [C, H, W] or [B, C, H, W], got shape {tuple(img.shape)}")
    if not img.is_floating_point() or img.dtype != gt.dtype:
        raise GofError(f"images must share one floating dtype, got {img.dtype} and {gt.dtype}")
    if img.dim() == 3:
        return img[None], gt[None], False
    return img, gt, True


def _reduce(per_image: torch.Tensor, batched: bool, reduction: str) -> torch.Tensor:
    if reduction == "mean":
        return per_image.mean()
    if reduction == "none":
        return per_image if batched else per_image[0]
    raise GofError(f"reduction must be 'mean' or 'none', got {reduction!r}")


def _mask_batch(mask, like: torch.Tensor) -> torch.Tensor:
    """A mask ``[H, W]``, ``[1, H, W]`` or ``[B, 1, H, W]`` (bool or float) as a float ``[B, 1, H, W]``."""
    m = torch.as_tensor(mask, device=like.device).to(like.dtype)
    B, _, H, W = like.shape
    if m.shape[-2:] != (H, W) or m.dim() > 4:
        raise GofError(f"mask shape {tuple(m.shape)} does not match images {tuple(like.shape)}")
    while m.dim() < 4:
        m = m[None]
    if m.shape[1] != 1 or m.shape[0] not in (1, B):
        raise GofError(f"mask shape {tuple(m.shape)} does not match images {tuple(like.shape)}")
    return m.expand(B, 1, H, W)


def psnr(img: torch.Tensor, gt: torch.Tensor, mask=None, *, data_range: float = 1.0,
         reduction: str = "mean") -> torch.Tensor:
    """Peak signal-to-noise ratio ``10 log10(data_range^2 / MSE)`` in dB, per image.

    Args:
        img, gt: ``[C, H, W]`` or ``[B, C, H, W]``, values in ``[0, data_range]``.
        mask: optional ``[H, W]``, ``[1, H, W]`` or ``[B, 1, H, W]``; the MSE is averaged over masked
            pixels (and all channels) only. An all-zero mask gives NaN for that image.
        reduction: ``"mean"`` = mean of the per-image PSNRs (as 3DGS/GOF report), a scalar;
            ``"none"`` = per image, ``[B]`` (or a scalar for one ``[C, H, W]`` image).
    Identical images give ``inf``.
    """
    x, y, batched = _as_batch(img, gt)
    sq = (x - y) ** 2
    if mask is None:
        mse = sq.flatten(1).mean(1)
    else:
        m = _mask_batch(mask, x)
        mse = (sq * m).flatten(1).sum(1) / (m.flatten(1).sum(1) * x.shape[1])
    return _reduce(10.0 * torch.log10(data_range**2 / mse), batched, reduction)


def gaussian_window_1d(window_size: int, sigma: float, dtype=torch.float32, device=None) -> torch.Tensor:
    """``[window_size]`` normalised Gaussian ``exp(-(i - window_size//2)^2 / (2 sigma^2))``."""
    i = torch.arange(window_size, dtype=torch.float64, device=device) - window_size // 2  # built where it is used:
    g = torch.exp(-(i**2) / (2.0 * sigma**2))  # a host-to-device copy per call would synchronise the GPU
    return (g / g.sum()).to(dtype=dtype)


def gaussian_weights(window_size: int, sigma: float) -> tuple[float, ...]:
    """:func:`gaussian_window_1d` as Python floats (float64), constants that a compiled graph inlines; a float32 image
    rounds them to float32, as the window tensor is."""
    g = [math.exp(-((i - window_size // 2) ** 2) / (2.0 * sigma**2)) for i in range(window_size)]
    total = sum(g)
    return tuple(v / total for v in g)


def _correlate_axis(x: torch.Tensor, weights: tuple[float, ...], dim: int) -> torch.Tensor:
    """Zero-padded 1-D correlation of ``x`` along ``dim`` (``-1`` or ``-2``) with an odd-length ``weights``, written as
    a sum of shifted copies: ``out[i] = Σ_k weights[k] · x[i + k − len // 2]`` (``x`` outside the tensor is 0)."""
    pad, n = len(weights) // 2, x.shape[dim]
    padded = F.pad(x, (pad, pad) if dim == -1 else (0, 0, pad, pad))
    out = weights[0] * padded.narrow(dim, 0, n)
    for k in range(1, len(weights)):
        out = out + weights[k] * padded.narrow(dim, k, n)
    return out


def ssim(img: torch.Tensor, gt: torch.Tensor, window_size: int = 11, sigma: float = 1.5, *,
         reduction: str = "mean", return_map: bool = False, mask=None) -> torch.Tensor:
    """Structural similarity with a Gaussian window and zero padding (the 3DGS/GOF definition).

    ``SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2))`` per pixel
    and channel, where the local moments are Gaussian-weighted over the window (pixels outside the
    image count as 0). Differentiable; training uses ``1 - ssim(render, gt)``.

    Args:
        img, gt: ``[C, H, W]`` or ``[B, C, H, W]``, values in ``[0, 1]``.
        window_size: odd window width (11); sigma: its standard deviation in pixels (1.5).
        reduction: ``"mean"`` = mean over everything (scalar, the loss); ``"none"`` = mean per image.
        return_map: return the SSIM map (same shape as ``img``) instead.
        mask: optional mask as in :func:`psnr`: the map is averaged over masked pixels only (the
            window still reads unmasked neighbours).
    """
    if window_size % 2 != 1 or window_size < 1:
        raise GofError(f"ssim window_size must be a positive odd number, got {window_size}")
    x, y, batched = _as_batch(img, gt)
    B, C, H, W = x.shape
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)  # [B, 5C, H, W]
    if torch.compiler.is_compiling():  # shifted sums: the compiler fuses each pass (and its backward) into one kernel
        weights = gaussian_weights(window_size, sigma)
        stack = _correlate_axis(_correlate_axis(stack, weights, -1), weights, -2)
    else:  # eager: two depthwise convolutions are fewer launches than 2 × 11 shifted products
        g = gaussian_window_1d(window_size, sigma, x.dtype, x.device)
        pad = window_size // 2
        stack = F.conv2d(stack, g.view(1, 1, 1, -1).expand(5 * C, 1, 1, window_size), padding=(0, pad), groups=5 * C)
        stack = F.conv2d(stack, g.view(1, 1, -1, 1).expand(5 * C, 1, window_size, 1), padding=(pad, 0), groups=5 * C)
    mu_x, mu_y, e_xx, e_yy, e_xy = stack.split(C, dim=1)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    num = (2.0 * mu_xy + SSIM_C1) * (2.0 * (e_xy - mu_xy) + SSIM_C2)
    den = (mu_xx + mu_yy + SSIM_C1) * ((e_xx - mu_xx) + (e_yy - mu_yy) + SSIM_C2)
    smap = num / den
    if return_map:
        return smap if batched else smap[0]
    if mask is None:
        per_image = smap.flatten(1).mean(1)
    else:
        m = _mask_batch(mask, x)
        per_image = (smap * m).flatten(1).sum(1) / (m.flatten(1).sum(1) * C)
    return _reduce(per_image, batched, reduction)


def quantize_8bit(img: torch.Tensor) -> torch.Tensor:
    """Round to the 8-bit grid (``round(clamp(x, 0, 1) * 255) / 255``), as saving PNGs and re-reading does
    in GOF's ``render.py`` + ``metrics.py``; apply before the metrics to reproduce their numbers."""
    return torch.round(img.clamp(0.0, 1.0) * 255.0) / 255.0


# ----------------------------------------------------------------------------- LPIPS (VGG-16)
# torchvision's vgg16().features layout: ("C", cin, cout) = conv3x3 + ReLU, "M" = max-pool 2x2.
# Module indices follow torchvision, so its state-dict keys ("features.{i}.weight") load directly.
_VGG16_LAYOUT = [(3, 64), (64, 64), "M", (64, 128), (128, 128), "M", (128, 256), (256, 256), (256, 256), "M",
                 (256, 512), (512, 512), (512, 512), "M", (512, 512), (512, 512), (512, 512)]
_LPIPS_TAPS = (3, 8, 15, 22, 29)  # relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 in torchvision indices
_LPIPS_CHANNELS = (64, 128, 256, 512, 512)
_LPIPS_SHIFT = (-0.030, -0.088, -0.188)  # LPIPS v0.1 ScalingLayer (inputs in [-1, 1])
_LPIPS_SCALE = (0.458, 0.448, 0.450)


class LpipsVgg(torch.nn.Module):
    """LPIPS v0.1 with a VGG-16 trunk (Zhang et al. 2018): a fixed network, built from a state dict.

    ``d(x, y) = sum_l mean_hw( w_l . (f_l(x)/|f_l(x)| - f_l(y)/|f_l(y)|)^2 )`` over the 5 taps ``l``.
    """

    def __init__(self):
        super().__init__()
        layers: list[torch.nn.Module] = []
        for item in _VGG16_LAYOUT:
            if item == "M":
                layers.append(torch.nn.MaxPool2d(2, 2))
            else:
                layers += [torch.nn.Conv2d(item[0], item[1], 3, padding=1), torch.nn.ReLU()]
        self.features = torch.nn.Sequential(*layers)
        self.lins = torch.nn.ModuleList(torch.nn.Conv2d(c, 1, 1, bias=False) for c in _LPIPS_CHANNELS)
        self.register_buffer("shift", torch.tensor(_LPIPS_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_LPIPS_SCALE).view(1, 3, 1, 1))

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        out, h = [], (x - self.shift) / self.scale
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i in _LPIPS_TAPS:
                out.append(h / (torch.sqrt((h * h).sum(1, keepdim=True)) + 1e-10))
            if i == _LPIPS_TAPS[-1]:
                break
        return out

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """``x, y``: ``[B, 3, H, W]`` in ``[-1, 1]`` -> ``[B]`` distances."""
        return sum(lin((fx - fy) ** 2).mean((2, 3))[:, 0] for lin, fx, fy in zip(self.lins, self._taps(x), self._taps(y)))


def _lpips_key(key: str) -> str | None:
    """Map a key of torchvision vgg16, ``lpips.LPIPS(net='vgg')`` or the lpips ``vgg.pth`` to ours."""
    parts = key.split(".")
    if parts[0] == "features" and len(parts) == 3:
        return key
    if parts[0] == "net" and len(parts) == 4 and parts[1].startswith("slice"):
        return f"features.{parts[2]}.{parts[3]}"  # lpips slices keep torchvision's indices
    if parts[0].startswith("lin") and parts[0][3:].isdigit() and parts[-1] == "weight":
        return f"lins.{parts[0][3:]}.weight"
    if parts[0] == "lins" and parts[-1] == "weight":
        return f"lins.{parts[1]}.weight"
    return None  # classifier, scaling-layer buffers (we hold the constants), ...


def _lpips_paths(weights) -> list[Path]:
    if weights is None:
        weights = os.environ.get(LPIPS_WEIGHTS_ENV, "")
        weights = [w for w in weights.split(os.pathsep) if w]
    elif isinstance(weights, (str, os.PathLike)):
        weights = [weights]
    return [Path(w) for w in weights]


def lpips_available(weights=None) -> bool:
    """Whether LPIPS weight files are named (argument, else ``$GOF_WARP_LPIPS_WEIGHTS``) and exist."""
    paths = _lpips_paths(weights)
    return bool(paths) and all(p.is_file() for p in paths)


def load_lpips(weights=None, device=None) -> LpipsVgg:
    """Build :class:`LpipsVgg` from local torch state dicts; never downloads.

    Args:
        weights: a path or a list of paths (default: ``$GOF_WARP_LPIPS_WEIGHTS``, several joined with
            ``os.pathsep``). Together they must hold the 13 VGG-16 conv layers and the 5 linear layers,
            e.g. ``torch.save(lpips.LPIPS(net='vgg').state_dict(), f)``, or torchvision's
            ``vgg16-397923af.pth`` plus lpips' ``weights/v0.1/vgg.pth``.
        device: where to put the network (default CPU).
    Raises:
        GofError: no file named, a file missing/unreadable, or required weights missing.
    """
    paths = _lpips_paths(weights)
    if not paths:
        raise GofError(f"LPIPS needs local weights: pass weights= or set ${LPIPS_WEIGHTS_ENV} (nothing is downloaded)")
    state = {}
    for p in paths:
        if not p.is_file():
            raise GofError(f"LPIPS weight file {p} does not exist")
        try:
            sd = torch.load(p, map_location="cpu", weights_only=True)
        except Exception as e:  # torch raises many types for corrupt files
            raise GofError(f"cannot read LPIPS weight file {p}: {e}") from None
        if not isinstance(sd, dict):
            raise GofError(f"LPIPS weight file {p} does not hold a state dict")
        state.update({k2: v for k, v in sd.items() if (k2 := _lpips_key(k)) is not None})
    model = LpipsVgg()
    wanted = {k for k in model.state_dict() if k not in ("shift", "scale")}
    missing = sorted(wanted - state.keys())
    if missing:
        raise GofError(f"LPIPS weights {', '.join(map(str, paths))} lack {len(missing)} tensors, e.g. {missing[:3]}")
    try:
        model.load_state_dict(state, strict=False)
    except RuntimeError as e:
        raise GofError(f"LPIPS weights {', '.join(map(str, paths))} do not fit VGG-16: {e}") from None
    return model.eval().requires_grad_(False).to(device or "cpu")


def lpips(img: torch.Tensor, gt: torch.Tensor, model: LpipsVgg | None = None, *, weights=None,
          rescale_input: bool = True, reduction: str = "mean") -> torch.Tensor:
    """LPIPS-VGG distance (lower is better).

    Args:
        img, gt: ``[3, H, W]`` or ``[B, 3, H, W]`` in ``[0, 1]``.
        model: a loaded :func:`load_lpips` network (load once, reuse); else loaded from ``weights``.
        rescale_input: map ``[0, 1]`` to ``[-1, 1]`` first, as LPIPS expects (``normalize=True``).
            ``False`` feeds ``[0, 1]`` directly, which is what the lpipsPyTorch wrapper used by
            3DGS/GOF's ``metrics.py`` does; use it only to reproduce their numbers.
    Raises:
        GofError: no model and no local weights.
    """
    x, y, batched = _as_batch(img, gt)
    if model is None:
        model = load_lpips(weights, x.device)
    model = model.to(x.device)  # in place, a no-op when already there
    x, y = x.to(model.shift.dtype), y.to(model.shift.dtype)
    if rescale_input:
        x, y = 2.0 * x - 1.0, 2.0 * y - 1.0
    return _reduce(model(x, y), batched, reduction)


def image_metrics(pred_images, gt_images, masks=None, *, lpips_weights=None, lpips_rescale: bool = True) -> dict:
    """Mean PSNR / SSIM (and LPIPS when its weights are present locally) over a list of test views.

    Args:
        pred_images, gt_images: sequences of ``[3, H, W]`` tensors in ``[0, 1]`` (or ``[B, 3, H, W]``
            tensors), pairwise the same shape; sizes may differ between views.
        masks: optional sequence of ``[H, W]`` masks (PSNR and SSIM are averaged inside them).
        lpips_weights: see :func:`load_lpips`; without weights LPIPS is reported as ``None``.
    Returns:
        ``{"num_images", "psnr", "ssim", "lpips", "lpips_note", "per_image": [{"psnr", "ssim", "lpips"}]}``,
        means over images (like 3DGS/GOF's ``metrics.py``).
    """
    pred_images, gt_images = list(pred_images), list(gt_images)
    if len(pred_images) != len(gt_images) or not pred_images:
        raise GofError(f"need equally many predicted and ground-truth images, got {len(pred_images)} and {len(gt_images)}")
    masks = [None] * len(pred_images) if masks is None else list(masks)
    if len(masks) != len(pred_images):
        raise GofError(f"got {len(masks)} masks for {len(pred_images)} images")
    model, note = None, None
    if lpips_available(lpips_weights):
        model = load_lpips(lpips_weights)
    else:
        note = f"not computed: no local LPIPS weights (set ${LPIPS_WEIGHTS_ENV})"
        log.info("LPIPS %s", note)
    rows = []
    with torch.no_grad():
        for p, g, m in zip(pred_images, gt_images, masks):
            row = {"psnr": psnr(p, g, m).item(), "ssim": ssim(p, g, mask=m).item(), "lpips": None}
            if model is not None:
                row["lpips"] = lpips(p, g, model, rescale_input=lpips_rescale).item()
            rows.append(row)
    mean = {k: (None if rows[0][k] is None else math.fsum(r[k] for r in rows) / len(rows)) for k in rows[0]}
    return {"num_images": len(rows), **mean, "lpips_note": note, "per_image": rows}
