"""DTU in NeuS/IDR form: ``cameras_sphere.npz``, ``image/*.png|jpg``, ``mask/*.png``.

``cameras_sphere.npz`` holds, per view ``i``, ``world_mat_i`` (``K [R | t]`` of DTU's world frame, 4x4) and
``scale_mat_i`` (the similarity that maps the unit sphere onto the object's bounding sphere). As
NeuS/2DGS/GOF do, the projection ``P = world_mat_i @ scale_mat_i`` is decomposed, so the cameras live in
the **normalised frame** where the object is inside the unit sphere at the origin.

Decomposition (no OpenCV): ``P[:3, :3] = K R`` by RQ decomposition (``scipy.linalg.rq``), signs fixed so
that ``K`` has a positive diagonal and ``det R = +1`` (``P`` is defined up to a scale of either sign);
``t = K⁻¹ P[:3, 3]`` before ``K`` is normalised to ``K[2, 2] = 1``. The skew ``K[0, 1]`` is dropped (a
warning says so when it moves pixels by more than 0.1 px).

Pixel convention: NeuS/IDR cast the ray of pixel index ``i`` through coordinate ``i`` (pixel centres at
integers); ours puts pixel centres at ``i + 0.5``, so ``cx = K[0, 2] + 0.5`` and ``cy = K[1, 2] + 0.5``.

Images and masks are matched to cameras by sorted order (IDR names them ``000000.png`` and ``000.png``);
masks are binarised at ``> 127``. Initial points: none (training initialises them).
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np
import scipy.linalg

from ..core.camera import Camera
from ..core.errors import SceneError
from . import images as imio
from .plan import ScenePlan, ViewPlan

_SKEW_WARN_PX = 0.1  # dropping the skew shifts the image edge by |skew| * (H/2) / fy pixels
MASK_THRESHOLD = 127


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P [3, 4] = λ K [R | t]`` → ``(K [3, 3] with K[2,2] = 1 and positive diagonal, R [3, 3], t [3])``."""
    P = np.asarray(P, dtype=np.float64)[:3, :4]
    if np.linalg.det(P[:, :3]) < 0:
        P = -P
    K, R = scipy.linalg.rq(P[:, :3])
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R  # D = D⁻¹: K R unchanged
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def _load_npz(path: Path) -> dict:
    """The arrays of an ``.npz`` file (no pickles); SceneError naming the file for anything else (an ``.npy`` or a
    pickle renamed ``.npz``, a corrupt archive, arrays that are not numbers)."""
    try:
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            kind = f"a single array {getattr(z, 'shape', '')}" if isinstance(z, np.ndarray) else type(z).__name__
            raise SceneError(f"{path}: expected an .npz archive of world_mat_<i> / scale_mat_<i> arrays, found {kind} "
                             f"(an .npy file?)")
        with z:
            out = {k: z[k] for k in z.files}
    except SceneError:
        raise
    except FileNotFoundError:
        raise SceneError(f"{path}: file not found") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise SceneError(f"{path}: cannot read camera file: {e}") from None
    for k, v in out.items():
        if v.dtype.kind not in "biuf":
            raise SceneError(f"{path}: entry {k!r} holds {v.dtype} values, expected numbers")
    return out


def read_dtu(root: Path, config) -> ScenePlan:
    """Parse a NeuS/IDR DTU folder (see the module docstring)."""
    npz_path = root / "cameras_sphere.npz"
    mats = _load_npz(npz_path)
    ids = sorted(int(m.group(1)) for k in mats if (m := re.fullmatch(r"world_mat_(\d+)", k)))
    if not ids:
        raise SceneError(f"{npz_path}: no world_mat_<i> entries")
    if ids != list(range(len(ids))):
        raise SceneError(f"{npz_path}: world_mat indices are not 0..{len(ids) - 1}")
    image_dir = root / "image"
    if not image_dir.is_dir():
        raise SceneError(f"{image_dir}: image folder not found")
    image_paths = imio.list_images(image_dir)
    if len(image_paths) != len(ids):
        raise SceneError(f"{npz_path} has {len(ids)} cameras but {image_dir} has {len(image_paths)} images")
    mask_dir = root / "mask"
    mask_paths = imio.list_images(mask_dir) if mask_dir.is_dir() else []
    if mask_paths and len(mask_paths) != len(ids):
        raise SceneError(f"{npz_path} has {len(ids)} cameras but {mask_dir} has {len(mask_paths)} masks")

    warnings, views, max_skew_px = [], [], 0.0
    for i, image_path in zip(ids, image_paths):
        where = f"{npz_path} (view {i})"
        world = np.asarray(mats[f"world_mat_{i}"], dtype=np.float64)
        scale = np.asarray(mats.get(f"scale_mat_{i}", np.eye(4)), dtype=np.float64)
        if world.shape not in ((4, 4), (3, 4)) or scale.shape != (4, 4):
            raise SceneError(f"{where}: world_mat must be 4x4 or 3x4 and scale_mat 4x4")
        P = world[:3, :4] @ scale
        if not np.all(np.isfinite(P)) or abs(np.linalg.det(P[:, :3])) < 1e-12:
            raise SceneError(f"{where}: degenerate projection matrix: world_mat_{i} @ scale_mat_{i} is singular "
                             f"or not finite (e.g. an all-zero world_mat)")
        K, R, t = decompose_projection(P)
        header = imio.read_header(image_path)
        max_skew_px = max(max_skew_px, abs(K[0, 1]) * 0.5 * header.height / K[1, 1])
        name = image_path.stem
        try:
            cam = Camera(R=R, t=t, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] + 0.5, cy=K[1, 2] + 0.5,
                         width=header.width, height=header.height, name=name)  # fmt: skip
        except SceneError as e:
            raise SceneError(f"{where}: {e}") from None
        mask_path = mask_paths[i] if mask_paths else None
        views.append(ViewPlan(name=name, camera=cam, image_path=image_path, mask_path=mask_path,
                              mask_threshold=MASK_THRESHOLD, composite_alpha=False))  # fmt: skip
    if max_skew_px > _SKEW_WARN_PX:
        warnings.append(f"{npz_path}: camera skew dropped (moves pixels by up to {max_skew_px:.2f} px)")
    if not mask_paths:
        warnings.append(f"{mask_dir}: no masks")
    if "scale_mat_0" not in mats:
        warnings.append(f"{npz_path}: no scale_mat_<i>: cameras are in DTU's world frame, not the unit sphere")
    return ScenePlan(format="dtu", source=root, views=views, camera_models=["PINHOLE"], warnings=warnings)
