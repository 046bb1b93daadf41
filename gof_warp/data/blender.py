"""Blender / NeRF-synthetic scenes: ``transforms_train.json`` + ``transforms_test.json``.

* Intrinsics: ``camera_angle_x`` with the principal point at the image centre and ``fy = fx`` (3DGS/GOF),
  or explicit ``fl_x, fl_y, cx, cy, w, h`` at the top level or per frame (the project's synthetic
  generator writes those); the frame parsing is shared with :mod:`gof_warp.data.ingp`.
* ``file_path`` may omit the extension (``./train/r_0`` → ``.png``).
* ``transform_matrix``: camera-to-world with OpenGL/Blender camera axes → ``Camera.from_c2w(opengl=True)``.
* RGBA images are composited on the chosen background (GOF: black, or white with ``--white_background``);
  alpha is kept as the view's mask. A per-frame ``mask_path`` replaces alpha as the mask. Per-frame
  ``depth_path`` / ``normal_path`` (synthetic ground truth) are not read here.
* Split: the test views are those of ``transforms_test.json``; ``test_every = 0`` merges them into
  training (GOF without ``--eval``). Without a test file, the every-N-th split applies.
  ``transforms_val.json`` is ignored, as in GOF. Frames keep their file order.
* Initial points: none (3DGS initialises Blender scenes randomly), unless ``points3d.ply`` lies next to
  the json files.
"""

from __future__ import annotations

from pathlib import Path

from ..core.errors import SceneError
from .ingp import frames_to_views, load_points_ply, read_json
from .plan import ScenePlan


def read_blender(root: Path, config) -> ScenePlan:
    """Parse ``root/transforms_{train,test}.json`` (see the module docstring)."""
    views, models = [], []
    test_json = root / "transforms_test.json"
    splits = [("train", root / "transforms_train.json")] + ([("test", test_json)] if test_json.is_file() else [])
    for split, path in splits:
        v, m = frames_to_views(path, read_json(path), config, split=split if test_json.is_file() else None)
        views += v
        models += m
    names = [v.name for v in views]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise SceneError(f"{root}: the train and test files list the same image(s): {sorted(dup)[:3]}")
    plan = ScenePlan(format="blender", source=root, views=views, camera_models=sorted(set(models)))
    if not test_json.is_file():
        plan.warnings.append(f"{test_json.name} not found: test views are every N-th training view")
    ply = root / "points3d.ply"
    if ply.is_file():
        plan.points, plan.point_colors = load_points_ply(ply)
    return plan
