"""COLMAP sparse model files (``cameras``, ``images``, ``points3D`` as ``.bin`` or ``.txt``) read with NumPy.

Reading a scene needs no pycolmap (a 38 MB wheel, not built for every platform): only the triangulation from
known poses (:mod:`gof_warp.data.sfm`) does. The formats are COLMAP's documented ones (``src/colmap/scene/
reconstruction_io.cc``): binary little-endian with ``uint64`` counts, text with ``#`` comments. Kept: each camera's
model and parameters; each image's pose, camera, name and the ``points2D`` that name a 3D point, as
``(x, y, point3D_id)`` rows (for checks that reproject them); each 3D point's id, position and colour (not its
track).

Errors (missing, truncated or malformed files; unknown camera models) are :class:`~gof_warp.core.errors.SceneError`
naming the file.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import SceneError

log = logging.getLogger(__name__)

# COLMAP's camera model ids, names and parameter counts (src/colmap/sensor/models.h)
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5), 4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12), 11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}  # fmt: skip
_PARAMS_BY_NAME = dict(CAMERA_MODELS.values())


@dataclass
class ColmapCamera:
    model: str
    width: int
    height: int
    params: np.ndarray  # [num_params] float64, COLMAP's order for the model


@dataclass
class ColmapImage:
    name: str
    camera_id: int
    qvec: np.ndarray  # [4] world-to-camera rotation quaternion (w, x, y, z), as stored (not normalised)
    tvec: np.ndarray  # [3] world-to-camera translation
    observations: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [M, 3] (x, y, point3D_id)


@dataclass
class ColmapModel:
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    point_ids: np.ndarray  # [P] int64
    xyz: np.ndarray  # [P, 3] float64
    rgb: np.ndarray  # [P, 3] uint8
    warnings: list[str] = field(default_factory=list)  # e.g. a .txt file newer than the .bin used


def quaternion_to_rotation(q) -> np.ndarray:
    """``[3, 3]`` rotation of the unit quaternion along ``q = (w, x, y, z)`` (normalised here; COLMAP's convention).

    :func:`gof_warp.core.model.quat_to_rotmat` is the same formula in torch; this NumPy one keeps reading a scene free
    of torch, as the rest of :mod:`gof_warp.data` is."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


class _Bin:
    """Little-endian reads from a whole file in memory; SceneError naming the file when it ends early."""

    def __init__(self, path: Path):
        self.path, self.data, self.pos = path, path.read_bytes(), 0

    def read(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise SceneError(f"{self.path}: truncated at byte {self.pos} (needs {size} more of {len(self.data)})")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def array(self, dtype, count: int) -> np.ndarray:
        dt = np.dtype(dtype).newbyteorder("<")
        size = dt.itemsize * count
        if count < 0 or self.pos + size > len(self.data):
            raise SceneError(f"{self.path}: truncated at byte {self.pos} ({count} items of {dt.itemsize} bytes)")
        out = np.frombuffer(self.data, dt, count, self.pos)
        self.pos += size
        return out

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise SceneError(f"{self.path}: truncated in an image name at byte {self.pos}")
        out = self.data[self.pos : end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return out

    def done(self):
        if self.pos != len(self.data):
            raise SceneError(f"{self.path}: {len(self.data) - self.pos} bytes left after the last record")


def _text_lines(path: Path) -> list[str]:
    return [ln.strip() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines()
            if ln.strip() and not ln.lstrip().startswith("#")]  # fmt: skip


def _bad(path: Path, what: str, line: str) -> SceneError:
    return SceneError(f"{path}: cannot parse {what} from line {line[:120]!r}")


def read_cameras(path: Path) -> dict[int, ColmapCamera]:
    cams = {}
    if path.suffix == ".bin":
        f = _Bin(path)
        for _ in range(f.read("Q")[0]):
            cam_id, model_id, width, height = f.read("iiQQ")
            if model_id not in CAMERA_MODELS:
                raise SceneError(f"{path}: camera {cam_id} has unknown model id {model_id}")
            name, n = CAMERA_MODELS[model_id]
            cams[cam_id] = ColmapCamera(name, int(width), int(height), f.array(np.float64, n).copy())
        f.done()
        return cams
    for line in _text_lines(path):
        parts = line.split()
        try:
            cam_id, model, width, height = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = np.array([float(x) for x in parts[4:]])
        except (IndexError, ValueError):
            raise _bad(path, "a camera", line) from None
        if model not in _PARAMS_BY_NAME:
            raise SceneError(f"{path}: camera {cam_id} has unknown model {model!r}")
        if len(params) != _PARAMS_BY_NAME[model]:
            raise SceneError(f"{path}: camera {cam_id} ({model}) has {len(params)} parameters, "
                             f"expected {_PARAMS_BY_NAME[model]}")  # fmt: skip
        cams[cam_id] = ColmapCamera(model, width, height, params)
    return cams


def read_images(path: Path) -> dict[int, ColmapImage]:
    images = {}
    if path.suffix == ".bin":
        f = _Bin(path)
        for _ in range(f.read("Q")[0]):
            image_id, *pose, cam_id = f.read("i7di")
            name = f.name()
            m = f.read("Q")[0]
            rows = f.array([("x", "f8"), ("y", "f8"), ("id", "i8")], m)
            obs = np.stack([rows["x"], rows["y"], rows["id"].astype(np.float64)], 1) if m else np.zeros((0, 3))
            images[image_id] = ColmapImage(name, cam_id, np.array(pose[:4]), np.array(pose[4:]), obs[obs[:, 2] >= 0])
        f.done()
        return images
    lines = [ln.rstrip("\n") for ln in path.read_text(encoding="utf-8", errors="replace").splitlines()]
    lines = [ln for ln in lines if not ln.lstrip().startswith("#")]
    k = 0
    while k < len(lines):  # an image line, then its (possibly empty) line of points2D
        line = lines[k].strip()
        if not line:
            k += 1
            continue
        parts = line.split(maxsplit=9)
        try:
            image_id, cam_id, name = int(parts[0]), int(parts[8]), parts[9]
            q, t = np.array([float(x) for x in parts[1:5]]), np.array([float(x) for x in parts[5:8]])
        except (IndexError, ValueError):
            raise _bad(path, "an image", line) from None
        pts = lines[k + 1].split() if k + 1 < len(lines) else []
        try:
            obs = np.array([float(x) for x in pts]).reshape(-1, 3)
        except ValueError:
            raise _bad(path, f"the points of image {name}", lines[k + 1]) from None
        images[image_id] = ColmapImage(name, cam_id, q, t, obs[obs[:, 2] >= 0])
        k += 2
    return images


def read_points(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ids [P] int64, xyz [P, 3] float64, rgb [P, 3] uint8)``."""
    ids, xyz, rgb = [], [], []
    if path.suffix == ".bin":
        f = _Bin(path)
        for _ in range(f.read("Q")[0]):
            pid, x, y, z, r, g, b, _err, track = f.read("Q3d3BdQ")
            f.array(np.int32, 2 * track)
            ids.append(pid), xyz.append((x, y, z)), rgb.append((r, g, b))
        f.done()
    else:
        for line in _text_lines(path):
            parts = line.split()
            try:
                ids.append(int(parts[0]))
                xyz.append(tuple(float(v) for v in parts[1:4]))
                rgb.append(tuple(int(v) for v in parts[4:7]))
            except (IndexError, ValueError):
                raise _bad(path, "a 3D point", line) from None
    return (np.array(ids, dtype=np.int64), np.array(xyz, dtype=np.float64).reshape(-1, 3),
            np.array(rgb, dtype=np.uint8).reshape(-1, 3))  # fmt: skip


def read_model(model_dir: Path) -> ColmapModel:
    """The model in ``model_dir`` (binary files first, as COLMAP does); ``points3D`` may be absent (no points).

    Where both ``X.bin`` and ``X.txt`` exist and the text file was modified later, the binary one is still used
    and :attr:`ColmapModel.warnings` says so (an edited or re-exported text model beside a stale binary)."""
    model_dir = Path(model_dir)
    warnings: list[str] = []

    def pick(stem: str, required: bool = True) -> Path | None:
        for ext in (".bin", ".txt"):
            if (model_dir / f"{stem}{ext}").is_file():
                return model_dir / f"{stem}{ext}"
        if required:
            raise SceneError(f"{model_dir}: no {stem}.bin or {stem}.txt")
        return None

    for stem in ("cameras", "images", "points3D"):
        b, t = model_dir / f"{stem}.bin", model_dir / f"{stem}.txt"
        if b.is_file() and t.is_file() and t.stat().st_mtime > b.stat().st_mtime:
            warnings.append(f"{b} is used but {t.name} beside it is newer; remove the stale one "
                            f"(COLMAP reads the .bin first, as gof_warp does)")
            log.warning("warning: %s", warnings[-1])
    cameras, images = read_cameras(pick("cameras")), read_images(pick("images"))
    missing = sorted({im.camera_id for im in images.values()} - set(cameras))
    if missing:
        raise SceneError(f"{pick('images')}: images refer to camera id(s) {missing} that {pick('cameras')} lacks")
    points = pick("points3D", required=False)
    ids, xyz, rgb = read_points(points) if points else (np.zeros(0, np.int64), np.zeros((0, 3)),
                                                         np.zeros((0, 3), np.uint8))  # fmt: skip
    return ColmapModel(cameras, images, ids, xyz, rgb, warnings)


__all__ = ["CAMERA_MODELS", "ColmapCamera", "ColmapImage", "ColmapModel", "quaternion_to_rotation", "read_model"]
