"""``python -m gof_warp.evaluate`` prints an aligned table: one row per tau, with tau as a fraction of the diagonal."""

import json
import re

import numpy as np
import pytest
import trimesh

from gof_warp.cli.evaluate import main as evaluate_main

HEADER = ("tau", "tau / diagonal", "precision", "recall", "F-score")


@pytest.fixture
def mesh_pair(tmp_path):
    """An icosphere (GT) and a copy with its vertices moved by ~1 % of its radius (prediction), as PLYs."""
    gt = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    pred = gt.copy()
    pred.vertices = pred.vertices + np.random.default_rng(0).normal(0.0, 0.01, pred.vertices.shape)
    gt.export(tmp_path / "gt.ply")
    pred.export(tmp_path / "pred.ply")
    diagonal = float(np.linalg.norm(gt.vertices.max(0) - gt.vertices.min(0)))
    return tmp_path / "pred.ply", tmp_path / "gt.ply", diagonal


def _tau_table(out: str) -> tuple[str, list[str]]:
    """The tau table's header line and its rows (the lines up to the next blank one)."""
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split()[:1] == ["tau"])
    rows = []
    for line in lines[start + 1:]:
        if not line.strip():
            break
        rows.append(line)
    return lines[start], rows


def _columns(header: str) -> list[tuple[int, int]]:
    """(start, end) of each header label, labels two or more spaces apart."""
    return [m.span() for m in re.finditer(r"\S+(?: \S+)*", header)]


@pytest.mark.parametrize("taus", [None, (0.005, 0.02, 0.1)])
def test_tau_rows_aligned_with_fraction_of_diagonal(mesh_pair, taus, tmp_path, capsys):
    pred, gt, diagonal = mesh_pair
    js = tmp_path / "eval.json"
    args = ["--mesh", str(pred), "--gt", str(gt), "--density", "0.02", "--json", str(js)]
    assert evaluate_main(args + (["--tau", *map(str, taus)] if taus else [])) == 0
    out = capsys.readouterr().out
    header, rows = _tau_table(out)
    spans = _columns(header)
    assert [header[a:b] for a, b in spans] == list(HEADER)
    metrics = json.loads(js.read_text())["metrics"]
    expected_taus = list(taus) if taus else [0.005 * diagonal, 0.01 * diagonal]
    assert metrics["tau"] == pytest.approx(expected_taus)
    assert len(rows) == len(expected_taus)
    for row, tau, p, r, f in zip(rows, expected_taus, metrics["precision"], metrics["recall"], metrics["fscore"]):
        cells = list(re.finditer(r"\S+(?: %)?", row))  # "0.50 %" is one cell
        assert [c.end() for c in cells] == [end for _, end in spans]  # each cell right-aligned under its label
        tau_cell, pct, p_cell, r_cell, f_cell = (c.group() for c in cells)
        assert float(tau_cell) == pytest.approx(tau, rel=1e-5)
        assert pct.endswith(" %") and float(pct[:-2]) == pytest.approx(100 * tau / diagonal, abs=0.006)
        for cell, value in zip((p_cell, r_cell, f_cell), (p, r, f)):
            assert float(cell) == pytest.approx(value, abs=6e-5)
    if taus is None:  # the defaults are 0.5 % and 1 % of the GT's bounding-box diagonal
        assert [r.split()[1:3] for r in rows] == [["0.50", "%"], ["1.00", "%"]]
    assert metrics["tau_fraction_of_diagonal"] == pytest.approx([t / diagonal for t in expected_taus])


def test_scores_block_above_the_tau_table(mesh_pair, capsys):
    pred, gt, diagonal = mesh_pair
    assert evaluate_main(["--mesh", str(pred), "--gt", str(gt), "--density", "0.02"]) == 0
    lines = capsys.readouterr().out.splitlines()
    tau_line = next(i for i, line in enumerate(lines) if line.split()[:1] == ["tau"])
    keyed = {line.split("  ")[0].strip(): line for line in lines[:tau_line] if line.strip()}
    for key in ("accuracy", "completeness", "chamfer", "vertices", "faces", "diagonal"):
        assert key in keyed, key
    assert float(keyed["diagonal"].split()[1]) == pytest.approx(diagonal, rel=1e-5)
    assert keyed["faces"].split()[1:] == ["320", "320"]
    # the score column: the values' last characters share one column
    ends = {len(keyed[k].rstrip()) for k in ("accuracy", "completeness", "chamfer")}
    assert len(ends) == 1
