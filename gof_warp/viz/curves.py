"""The training curves of a run as one picture: loss, train PSNR and Gaussian count against the iteration.

``RUN/pictures/curves.png`` is drawn at the end of training (``python -m gof_warp.train``, unless
``--no-pictures``) from the history the trainer already keeps in ``RUN/metrics.json`` (``history``: one entry
every ``log_every`` iterations with ``iteration``, ``total`` (the loss), ``psnr`` of the training view and
``num_gaussians``). Three panels side by side, each with its title, y tick labels, x tick labels
(iterations) and a light grid, in the dark theme of the run's other pictures. Drawn with Pillow only (no
matplotlib). Memory: the picture itself (``[H, W, 3]`` uint8).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import GofError

log = logging.getLogger(__name__)

#: (history key, panel title, line colour): the panels, left to right.
SERIES = (("total", "loss", (255, 160, 60)), ("psnr", "train PSNR (dB)", (80, 200, 255)),
          ("num_gaussians", "Gaussians", (120, 220, 120)))
PANEL_W, PANEL_H = 320, 240  # one panel, pixels
MARGIN_LEFT, MARGIN_RIGHT, MARGIN_TOP, MARGIN_BOTTOM = 56, 14, 24, 34  # plot area inside a panel
BACKGROUND = (24, 24, 24)  # the run pictures' panel colour
PLOT_BACKGROUND = (36, 36, 36)
GRID = (62, 62, 62)
AXIS = (150, 150, 150)
TEXT = (225, 225, 225)
LINE_WIDTH = 2
FONT_SIZE = 12
MARKERS_UP_TO = 40  # points are marked with dots when a series has at most this many


@dataclass(frozen=True)
class Axes:
    """Where one panel's plot area is and how data maps onto it.

    Attributes:
        box: ``(x0, y0, x1, y1)`` pixel corners of the plot area in the whole picture.
        x_range, y_range: ``(lo, hi)`` data values at the left/right and bottom/top edges.
    """

    box: tuple[int, int, int, int]
    x_range: tuple[float, float]
    y_range: tuple[float, float]

    def to_pixel(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Data ``(x, y)`` (scalars or arrays) → pixel ``(column, row)`` as float arrays."""
        x0, y0, x1, y1 = self.box
        (xa, xb), (ya, yb) = self.x_range, self.y_range
        px = x0 + (np.asarray(x, np.float64) - xa) / (xb - xa) * (x1 - x0)
        py = y1 - (np.asarray(y, np.float64) - ya) / (yb - ya) * (y1 - y0)
        return px, py


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """Round tick values (steps 1, 2 or 5 × 10^k) inside ``[lo, hi]``: the step whose tick count is closest to
    ``count`` (at least 2 ticks where the range allows)."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    e = math.floor(math.log10((hi - lo) / max(count - 1, 1)))

    def ticks(step):
        first = math.ceil(lo / step - 1e-9) * step
        n = int(math.floor((hi - first) / step + 1e-9)) + 1
        return [round(first + k * step, 12) for k in range(max(n, 0))]

    options = [ticks(m * 10.0 ** k) for k in (e - 1, e, e + 1) for m in (1, 2, 5)]
    return min(options, key=lambda t: (abs(len(t) - count) + (10 if len(t) < 2 else 0), -len(t)))


def tick_label(value: float) -> str:
    """Short labels: ``12000`` → ``12k``, ``1.5e6`` → ``1.5M``, ``0.0412`` → ``0.0412``, ``27.5`` → ``27.5``."""
    a = abs(value)
    if a >= 1e6:
        return f"{value / 1e6:g}M"
    if a >= 1e4:
        return f"{value / 1e3:g}k"
    return f"{value:.4g}"


def _padded_range(values: np.ndarray) -> tuple[float, float]:
    lo, hi = float(values.min()), float(values.max())
    if hi - lo < 1e-12 * max(1.0, abs(hi)):
        pad = 0.5 * abs(hi) if hi else 1.0
        return lo - pad, hi + pad
    pad = 0.06 * (hi - lo)
    return lo - pad, hi + pad


def _series(history: list[dict], key: str) -> tuple[np.ndarray, np.ndarray]:
    """``(iterations, values)`` of the entries that have a finite ``key``."""
    pts = [(float(h["iteration"]), float(h[key])) for h in history
           if "iteration" in h and h.get(key) is not None and math.isfinite(float(h[key]))]
    arr = np.asarray(pts, np.float64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def panel_axes(history: list[dict], index: int) -> Axes | None:
    """The axes of panel ``index`` of :data:`SERIES` for ``history`` (None when the series has no data)."""
    key = SERIES[index][0]
    its, values = _series(history, key)
    if len(its) == 0:
        return None
    all_its = np.asarray([float(h["iteration"]) for h in history if "iteration" in h])
    x_lo, x_hi = 0.0, float(all_its.max()) if len(all_its) else 1.0
    if x_hi <= x_lo:
        x_hi = x_lo + 1.0
    left = index * PANEL_W
    box = (left + MARGIN_LEFT, MARGIN_TOP, left + PANEL_W - MARGIN_RIGHT, PANEL_H - MARGIN_BOTTOM)
    return Axes(box, (x_lo, x_hi), _padded_range(values))


def curves_picture(history: list[dict]) -> np.ndarray:
    """The three panels of :data:`SERIES` for a trainer history → ``[PANEL_H, 3 * PANEL_W, 3]`` uint8.

    ``history``: a list of dicts with ``iteration`` and any of ``total``, ``psnr``, ``num_gaussians``
    (``RUN/metrics.json``'s ``history``); entries lacking a key are skipped in that panel, and a panel with
    no data says so. Raises :class:`GofError` when no entry has an ``iteration``.
    """
    from PIL import Image, ImageDraw

    if not isinstance(history, list) or not any(isinstance(h, dict) and "iteration" in h for h in history):
        raise GofError("the training history is empty: no curves to draw (metrics.json has no 'history' entries)")
    history = [h for h in history if isinstance(h, dict) and "iteration" in h]
    img = Image.new("RGB", (PANEL_W * len(SERIES), PANEL_H), BACKGROUND)
    draw = ImageDraw.Draw(img)
    draw.font = _font()
    for i, (key, title, colour) in enumerate(SERIES):
        left = i * PANEL_W
        draw.text((left + MARGIN_LEFT, 5), title, fill=TEXT)
        axes = panel_axes(history, i)
        if axes is None:
            draw.text((left + MARGIN_LEFT + 10, PANEL_H // 2), "no data", fill=AXIS)
            continue
        _draw_axes(draw, axes)
        its, values = _series(history, key)
        px, py = axes.to_pixel(its, values)
        pts = [(float(a), float(b)) for a, b in zip(px, py)]
        if len(pts) > 1:
            draw.line(pts, fill=colour, width=LINE_WIDTH, joint="curve")
        if len(pts) <= MARKERS_UP_TO:
            for a, b in pts:
                draw.ellipse((a - 2, b - 2, a + 2, b + 2), fill=colour)
    return np.asarray(img)


def _font():
    """Pillow's default font at :data:`FONT_SIZE` (its bitmap font where Pillow has no FreeType)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=FONT_SIZE)
    except (TypeError, ImportError, OSError, AttributeError):  # an old Pillow, or no FreeType
        return ImageFont.load_default()


def _draw_axes(draw, axes: Axes) -> None:
    x0, y0, x1, y1 = axes.box
    draw.rectangle(axes.box, fill=PLOT_BACKGROUND)
    for t in nice_ticks(*axes.y_range):
        _, py = axes.to_pixel(axes.x_range[0], t)
        py = float(py)
        draw.line([(x0, py), (x1, py)], fill=GRID)
        label = tick_label(t)
        w = draw.textlength(label)
        draw.text((x0 - 5 - w, py - FONT_SIZE // 2 - 1), label, fill=TEXT)
    for t in nice_ticks(*axes.x_range, count=4):
        px, _ = axes.to_pixel(t, axes.y_range[0])
        px = float(px)
        draw.line([(px, y0), (px, y1)], fill=GRID)
        draw.line([(px, y1), (px, y1 + 3)], fill=AXIS)
        label = tick_label(t)
        draw.text((px - draw.textlength(label) / 2, y1 + 4), label, fill=TEXT)
    draw.rectangle(axes.box, outline=AXIS)
    label = "iteration"
    draw.text(((x0 + x1) / 2 - draw.textlength(label) / 2, y1 + 18), label, fill=AXIS)


def write_curves(run_dir, out_path=None) -> Path:
    """Draw ``RUN/metrics.json``'s history into ``out_path`` (default ``RUN/pictures/curves.png``), atomically."""
    from .pictures import write_png

    run = Path(run_dir)
    metrics_file = run / "metrics.json"
    try:
        history = json.loads(metrics_file.read_text()).get("history")
    except (OSError, ValueError, AttributeError) as e:
        raise GofError(f"{metrics_file}: cannot read the training history: {e}") from None
    path = Path(out_path) if out_path is not None else run / "pictures" / "curves.png"
    write_png(path, curves_picture(history or []))
    return path


def curves_or_warning(run_dir) -> list[Path]:
    """:func:`write_curves`, but a failure only logs a warning and returns ``[]`` (a picture is a convenience)."""
    try:
        return [write_curves(run_dir)]
    except Exception as e:  # noqa: BLE001 - any failure of a convenience output
        log.warning("could not write the training curves of %s: %s", run_dir, e)
        return []
