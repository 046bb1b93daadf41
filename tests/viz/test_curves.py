"""Training curves picture: the lines go through the history's points, axes carry tick labels; the train CLI
writes RUN/pictures/curves.png and prints progress (not with --quiet)."""

import json
import logging
import re

import numpy as np
import pytest
from PIL import Image

from gof_warp.viz.curves import (
    BACKGROUND,
    PANEL_H,
    PANEL_W,
    PLOT_BACKGROUND,
    SERIES,
    curves_or_warning,
    curves_picture,
    nice_ticks,
    panel_axes,
    write_curves,
)
from gof_warp.core.errors import GofError


def _history(n=12, psnr=True):
    out = []
    for k in range(1, n + 1):
        h = {"iteration": 50 * k, "total": 0.3 * np.exp(-k / 3) + 0.02, "num_gaussians": 1000 + 400 * k}
        if psnr:
            h["psnr"] = 12 + 1.5 * k
        out.append(h)
    return out


def _near(img, x, y, colour, r=2):
    """Whether some pixel within ``r`` of (x, y) has exactly ``colour``."""
    x, y = int(round(float(x))), int(round(float(y)))
    patch = img[max(y - r, 0): y + r + 1, max(x - r, 0): x + r + 1].reshape(-1, 3)
    return bool((patch == np.asarray(colour, np.uint8)).all(axis=1).any())


def test_lines_pass_through_every_point_of_every_series():
    history = _history()
    img = curves_picture(history)
    assert img.shape == (PANEL_H, PANEL_W * len(SERIES), 3) and img.dtype == np.uint8
    for i, (key, _, colour) in enumerate(SERIES):
        axes = panel_axes(history, i)
        for h in history:
            px, py = axes.to_pixel(h["iteration"], h[key])
            assert _near(img, px, py, colour), f"{key} at iteration {h['iteration']}: no line pixel near ({px}, {py})"
        x0, y0, x1, y1 = axes.box
        area = img[y0 + 2:y1 - 1, x0 + 2:x1 - 1].reshape(-1, 3)
        line = (area == np.asarray(colour, np.uint8)).all(axis=1).mean()
        assert 0.002 < line < 0.2, f"{key}: the line covers {line:.1%} of the plot area"
        others = [c for j, (_, _, c) in enumerate(SERIES) if j != i]
        assert not any((area == np.asarray(c, np.uint8)).all(axis=1).any() for c in others), "colours leak across panels"
        assert (area == np.asarray(PLOT_BACKGROUND, np.uint8)).all(axis=1).mean() > 0.5
        # tick labels: text pixels left of the plot area (y ticks) and under it (x ticks)
        left = img[y0:y1, i * PANEL_W: x0 - 3]
        below = img[y1 + 4: y1 + 17, x0:x1]
        for region in (left, below):
            assert (np.abs(region.astype(int) - BACKGROUND).sum(-1) > 100).sum() > 20, "no tick labels drawn"


def test_loss_line_falls_and_psnr_line_rises_in_pixels():
    history = _history()
    img = curves_picture(history)
    for i, falls in ((0, True), (1, False)):
        key, _, colour = SERIES[i]
        axes = panel_axes(history, i)
        _, y_first = axes.to_pixel(history[0]["iteration"], history[0][key])
        _, y_last = axes.to_pixel(history[-1]["iteration"], history[-1][key])
        assert (y_last > y_first) == falls  # image rows grow downwards
        assert _near(img, *axes.to_pixel(history[-1]["iteration"], history[-1][key]), colour)


def test_a_series_missing_from_the_history_gets_an_empty_panel():
    img = curves_picture(_history(psnr=False))
    psnr_panel = img[:, PANEL_W:2 * PANEL_W]
    assert not (psnr_panel == np.asarray(SERIES[1][2], np.uint8)).all(-1).any()
    assert (np.abs(psnr_panel.astype(int) - BACKGROUND).sum(-1) > 100).any(), "the panel says 'no data'"


def test_a_single_entry_and_bad_histories():
    img = curves_picture([{"iteration": 10, "total": 0.5, "psnr": 20.0, "num_gaussians": 100}])
    assert _near(img, *panel_axes([{"iteration": 10, "total": 0.5}], 0).to_pixel(10, 0.5), SERIES[0][2])
    for bad in ([], [{"total": 1.0}], None):
        with pytest.raises(GofError, match="history is empty"):
            curves_picture(bad)


def test_nice_ticks():
    assert nice_ticks(0, 1200, 4) == [0, 500, 1000]
    assert nice_ticks(1500, 9500) == [2000, 4000, 6000, 8000]
    assert nice_ticks(14.2, 33.1) == [15, 20, 25, 30]
    ticks = nice_ticks(0.013, 0.29)
    assert 3 <= len(ticks) <= 7 and all(0.013 <= t <= 0.29 for t in ticks)


def test_write_curves_from_metrics_json(tmp_path, caplog):
    (tmp_path / "metrics.json").write_text(json.dumps({"history": _history()}))
    path = write_curves(tmp_path)
    assert path == tmp_path / "pictures" / "curves.png"
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size == (PANEL_W * len(SERIES), PANEL_H)
    (tmp_path / "metrics.json").write_text("{not json")
    with pytest.raises(GofError, match="metrics.json"):
        write_curves(tmp_path)
    with caplog.at_level(logging.WARNING):
        assert curves_or_warning(tmp_path) == []
    assert "could not write the training curves" in caplog.text


# ------------------------------------------------------------------------------- the train command


@pytest.mark.slow
def test_train_writes_the_curves_and_prints_progress_unless_quiet(tiny_train_scene, tiny_train_overrides, tmp_path,
                                                                  capsys):
    from gof_warp.cli import train

    run = tmp_path / "run"
    assert train.main([str(tiny_train_scene), "--out", str(run), "--config", "quick", "--iterations", "6",
                       "--device", "cpu", *tiny_train_overrides]) == 0
    err = capsys.readouterr().err
    assert re.search(r"^it 6/6 loss \d\.\d{4} psnr [\d.]+ N 300 [\d.]+ it/s elapsed \d:\d\d ETA 0:00$", err, re.M), err
    assert "\r" not in err
    with Image.open(run / "pictures" / "curves.png") as im:
        assert im.size == (PANEL_W * len(SERIES), PANEL_H)
    assert (run / "pictures" / "views.png").is_file()

    quiet = tmp_path / "quiet"
    assert train.main([str(tiny_train_scene), "--out", str(quiet), "--config", "quick", "--iterations", "6", "--device",
                       "cpu", "--quiet", "--no-pictures", *tiny_train_overrides]) == 0
    out = capsys.readouterr()
    assert not re.search(r"^it \d", out.err, re.M), out.err
    assert "done: 6 iterations" in out.out
    assert not (quiet / "pictures").exists()
