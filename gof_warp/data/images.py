"""Image files: headers, decoding (Pillow), alpha compositing, resizing; errors that name the file.

* Decoded images are ``uint8``: RGB ``[H, W, 3]``, RGBA ``[H, W, 4]``, masks ``[H, W]``.
* Downscaling uses Pillow's ``BICUBIC`` filter, as GOF/3DGS do (``PILtoTorch`` → ``Image.resize`` with
  Pillow's default); Pillow widens the filter by the reduction factor, so it also anti-aliases.
* 16-bit grey images are mapped to 8 bits (``/257``); palette images with transparency become RGBA.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..core.errors import SceneError

# Largest image read, in pixels (100 megapixels: 300 MB decoded as RGB, 1.2 GB as float32 on the device). A header
# that claims more is refused before decoding: such a file is a decompression bomb or not meant for training (the
# project trains at a few megapixels a view); Pillow's own limit would raise an untyped error later.
MAX_IMAGE_PIXELS = 100_000_000
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".JPG", ".JPEG", ".PNG", ".bmp", ".tif", ".tiff", ".webp", ".exr")


@dataclass(frozen=True)
class ImageHeader:
    """What an image file says about itself without decoding the pixels."""

    width: int
    height: int
    mode: str

    @property
    def has_alpha(self) -> bool:
        return self.mode in ("RGBA", "LA", "PA", "RGBa", "La")


def check_regular_file(path: Path, what: str = "image") -> None:
    """Raise :class:`SceneError` unless ``path`` is a regular file (or a link to one): a FIFO, socket or device
    would block or stream forever when opened."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise SceneError(f"{path}: {what} file not found") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read {what}: {e}") from None
    if stat.S_ISDIR(mode):
        raise SceneError(f"{path}: expected an {what} file, found a folder")
    if not stat.S_ISREG(mode):
        raise SceneError(f"{path}: {what} is not a regular file (a FIFO, socket or device); refusing to open it")


def check_inside(path, folder, what: str, allow_outside: bool = False) -> Path:
    """``path`` itself when it resolves (links followed) inside the resolved ``folder``; else :class:`SceneError`
    naming ``what`` (the entry that gave the path), unless ``allow_outside`` (``data.allow_outside_paths``).

    Nothing is opened: the path is only resolved, so a scene file cannot make the readers open (or reveal the
    existence of) files elsewhere on the machine."""
    path = Path(path)
    if allow_outside:
        return path
    base = Path(folder).resolve()
    real = (base / path).resolve() if not path.is_absolute() else path.resolve()
    if real != base and base not in real.parents:
        raise SceneError(f"{what}: path {str(path)!r} points outside the scene folder {base}; "
                         f"set data.allow_outside_paths=true to read files outside it")
    return path


def _open(path: Path, what: str = "image"):
    check_regular_file(path, what)
    try:
        return Image.open(path)
    except Image.DecompressionBombError as e:
        raise SceneError(f"{path}: {what} is too large to decode ({e}); gof_warp reads images of at most "
                         f"{MAX_IMAGE_PIXELS / 1e6:g} megapixels: downscale the file first") from None
    except FileNotFoundError:
        raise SceneError(f"{path}: image file not found") from None
    except IsADirectoryError:
        raise SceneError(f"{path}: expected an image file, found a folder") from None
    except UnidentifiedImageError:
        raise SceneError(f"{path}: not a readable image (unknown or corrupt format)") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot open image: {e}") from None


def read_header(path, what: str = "image") -> ImageHeader:
    """Size and mode of an image file, read from its header only (cheap)."""
    path = Path(path)
    with _open(path, what) as im:
        if im.width * im.height > MAX_IMAGE_PIXELS:
            raise SceneError(f"{path}: image header claims {im.width}x{im.height} pixels, over the limit of "
                             f"{MAX_IMAGE_PIXELS / 1e6:g} megapixels (a corrupt file or a decompression bomb); "
                             f"downscale the file first")
        mode = im.mode
        if mode == "P" and "transparency" in im.info:
            mode = "PA"
        return ImageHeader(width=int(im.width), height=int(im.height), mode=mode)


def _to_uint8(im: Image.Image) -> np.ndarray:
    """Decoded Pillow image → uint8 array: RGB(A) ``[H, W, 3|4]`` or grey ``[H, W]``."""
    if im.mode in ("I;16", "I;16B", "I;16L", "I"):
        a = np.asarray(im, dtype=np.float64)
        scale = 257.0 if a.max(initial=0) > 255 else 1.0
        return np.clip(np.rint(a / scale), 0, 255).astype(np.uint8)
    if im.mode == "F":
        a = np.asarray(im, dtype=np.float64)
        return np.clip(np.rint(a * (255.0 if a.max(initial=0) <= 1.0 else 1.0)), 0, 255).astype(np.uint8)
    if im.mode in ("1", "L"):
        return np.asarray(im.convert("L"), dtype=np.uint8)
    has_alpha = im.mode in ("RGBA", "LA", "PA", "RGBa", "La") or (im.mode == "P" and "transparency" in im.info)
    return np.asarray(im.convert("RGBA" if has_alpha else "RGB"), dtype=np.uint8)


def _load_pixels(path: Path, what: str) -> np.ndarray:
    with _open(path, what) as im:
        if im.width * im.height > MAX_IMAGE_PIXELS:
            raise SceneError(f"{path}: {what} is {im.width}x{im.height} pixels, over the limit of "
                             f"{MAX_IMAGE_PIXELS / 1e6:g} megapixels")
        try:
            im.load()
            return _to_uint8(im)
        except (OSError, SyntaxError, ValueError) as e:
            raise SceneError(f"{path}: {what} data is truncated or corrupt ({e})") from None


def decode(path) -> np.ndarray:
    """Decode an image file: ``[H, W, 3]`` RGB or ``[H, W, 4]`` RGBA uint8 (grey is expanded to RGB).

    Raises :class:`SceneError` naming the file when it is missing, not an image, or truncated.
    """
    a = _load_pixels(Path(path), "image")
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    return np.ascontiguousarray(a)


def decode_mask(path, threshold: int | None = 127) -> np.ndarray:
    """Decode a mask file to ``[H, W]`` uint8. With ``threshold``, values ``> threshold`` become 255, others 0.

    Colour masks use their grey value (``L``); a mask with alpha uses the alpha channel.
    """
    a = _load_pixels(Path(path), "mask")
    if a.ndim == 3:
        a = a[:, :, 3] if a.shape[2] == 4 else np.asarray(Image.fromarray(a[:, :, :3]).convert("L"))
    if threshold is not None:
        a = np.where(a > threshold, 255, 0).astype(np.uint8)
    return np.ascontiguousarray(a)


def composite(rgba: np.ndarray, background) -> tuple[np.ndarray, np.ndarray]:
    """Blend ``[H, W, 4]`` RGBA over a background colour (RGB in ``[0, 1]``).

    Returns ``(rgb [H, W, 3] uint8, alpha [H, W] uint8)``: ``rgb = c·a + bg·(1 − a)`` rounded.
    """
    a = rgba[:, :, 3:4].astype(np.float32) / 255.0
    bg = np.asarray(background, dtype=np.float32).reshape(1, 1, 3) * 255.0
    rgb = rgba[:, :, :3].astype(np.float32) * a + bg * (1.0 - a)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8), np.ascontiguousarray(rgba[:, :, 3])


def resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize a uint8 ``[H, W]`` or ``[H, W, C]`` array with Pillow's BICUBIC filter (GOF's choice)."""
    if image.shape[1] == width and image.shape[0] == height:
        return image
    if image.ndim == 3 and image.shape[2] not in (3, 4):
        raise ValueError(f"resize: unsupported channel count {image.shape[2]}")
    out = Image.fromarray(image).resize((int(width), int(height)), Image.Resampling.BICUBIC)
    return np.asarray(out, dtype=np.uint8)


def find_image(base: Path, rel: str) -> Path:
    """``base / rel``; when ``rel`` has no image suffix and does not exist, try ``.png`` then other suffixes.

    NeRF-synthetic ``file_path`` values omit the extension (``./train/r_0``). Returns the first existing
    candidate, else ``base / rel`` (so the error names the path the file says).
    """
    p = (base / rel).resolve() if not Path(rel).is_absolute() else Path(rel)
    if p.is_file() or p.suffix in IMAGE_SUFFIXES:
        return p
    for suffix in (".png", ".jpg", ".jpeg", ".JPG", ".PNG"):
        q = p.with_name(p.name + suffix)
        if q.is_file():
            return q
    return p


def list_images(folder: Path) -> list[Path]:
    """Image files directly in ``folder``, sorted by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix in IMAGE_SUFFIXES)
