"""Tiny scene folders of every supported format, written by the tests themselves (in ``tmp_path``).

All share one small world: cameras on a circle looking at the origin (``ring_cameras``) and random points
in the unit cube; images are small random ``uint8`` arrays so that every test stays fast.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from gof_warp.core.camera import Camera, look_at
from gof_warp.data.undistort import LensCamera, distort_normalized

W, H = 48, 36  # tiny images: the readers' logic, not decoding speed, is under test


def ring_cameras(n=10, width=W, height=H, fx=40.0, fy=42.0, cx=None, cy=None, radius=3.0) -> list[Camera]:
    """``n`` cameras on a circle of ``radius`` at height 1 looking at the origin (z up)."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = [radius * np.cos(a), radius * np.sin(a), 1.0]
        cams.append(look_at(eye, [0, 0, 0], fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, name=f"{i:04d}"))
    return cams


def random_points(n=50, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-0.5, 0.5, (n, 3))


def random_image(h=H, w=W, channels=3, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, channels), dtype=np.uint8)


def save_image(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)
    return path


def project_distorted(cam: Camera, lens: LensCamera | None, X: np.ndarray) -> np.ndarray:
    """Pixel coordinates of world points seen by ``cam``'s pose through ``lens`` (or ``cam``'s K if None)."""
    pc = cam.to_camera(X)
    xy = pc[:, :2] / pc[:, 2:3]
    if lens is None:
        return np.stack([cam.fx * xy[:, 0] + cam.cx, cam.fy * xy[:, 1] + cam.cy], axis=1)
    xy = distort_normalized(xy, lens)
    return np.stack([lens.fx * xy[:, 0] + lens.cx, lens.fy * xy[:, 1] + lens.cy], axis=1)


# ---------------------------------------------------------------------------------------------- COLMAP
def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def _nums(values) -> str:
    return " ".join(f"{float(v):.17g}" for v in values)


def write_colmap_text(model_dir: Path, cams, points, model="PINHOLE", params=None, colors=None) -> Path:
    """A COLMAP text model (cameras/images/points3D.txt), one camera per image, full observations.

    ``params``: the camera's parameter list for ``model`` (default: the pinhole ``fx fy cx cy`` of each camera).
    Observations are the points' projections through the model (via :func:`lens_from_colmap`).
    """
    from gof_warp.data.colmap import lens_from_colmap

    model_dir.mkdir(parents=True, exist_ok=True)
    colors = np.full((len(points), 3), 128, np.uint8) if colors is None else colors
    cam_lines, image_lines, tracks = [], [], {j: [] for j in range(len(points))}
    for i, cam in enumerate(cams, start=1):
        p = params if params is not None else [cam.fx, cam.fy, cam.cx, cam.cy]
        cam_lines.append(f"{i} {model} {cam.width} {cam.height} " + _nums(p))
        lens = lens_from_colmap(model, p, cam.width, cam.height, "test")
        uv = project_distorted(cam, lens, points)
        q, t = _quat_wxyz(cam.R), cam.t
        image_lines.append(f"{i} " + _nums([*q, *t]) + f" {i} {cam.name}.png")
        image_lines.append(" ".join(f"{_nums((u, v))} {j + 1}" for j, (u, v) in enumerate(uv)))
        for j in range(len(points)):
            tracks[j].append(f"{i} {j}")
    (model_dir / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    (model_dir / "images.txt").write_text("\n".join(image_lines) + "\n")
    pts = [
        f"{j + 1} {_nums(X)} {c[0]} {c[1]} {c[2]} 0.5 " + " ".join(tracks[j])
        for j, (X, c) in enumerate(zip(points, colors))
    ]
    (model_dir / "points3D.txt").write_text("\n".join(pts) + "\n")
    return model_dir


def make_colmap_scene(root: Path, n=10, model="PINHOLE", params=None, binary=False, images="images") -> Path:
    cams = ring_cameras(n)
    pts = random_points()
    model_dir = root / "sparse" / "0"
    if binary:
        import pycolmap

        txt = write_colmap_text(root / "text_model", cams, pts, model, params)
        model_dir.mkdir(parents=True)
        pycolmap.Reconstruction(str(txt)).write_binary(str(model_dir))
    else:
        write_colmap_text(model_dir, cams, pts, model, params)
    for i, cam in enumerate(cams):
        save_image(root / images / f"{cam.name}.png", random_image(seed=i))
    return root


# ------------------------------------------------------------------------------------- NeRF transforms
def opengl_c2w(cam: Camera) -> list:
    m = cam.c2w.copy()
    m[:3, 1:3] *= -1.0
    return m.tolist()


def make_blender_scene(root: Path, n_train=6, n_test=2, angle_x=1.0, alpha=True, size=(W, H), top=None) -> Path:
    """NeRF-synthetic layout: extension-less ``./train/r_i`` paths, RGBA images, ``camera_angle_x``."""
    w, h = size
    fx = 0.5 * w / np.tan(0.5 * angle_x)
    cams = ring_cameras(n_train + n_test, width=w, height=h, fx=fx, fy=fx)
    for split, sel in (("train", cams[:n_train]), ("test", cams[n_train:])):
        frames = []
        for i, cam in enumerate(sel):
            img = random_image(h, w, 4 if alpha else 3, seed=100 * (split == "test") + i)
            save_image(root / split / f"r_{i}.png", img)
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": opengl_c2w(cam)})
        data = {"camera_angle_x": angle_x, **(top or {}), "frames": frames}
        (root / f"transforms_{split}.json").write_text(json.dumps(data))
    return root


def make_ingp_scene(root: Path, n=9, dist=None, size=(W, H)) -> Path:
    """instant-ngp ``transforms.json`` with ``fl_x fl_y cx cy w h`` and OpenCV distortion ``dist``."""
    w, h = size
    cams = ring_cameras(n, width=w, height=h, fx=40.0, fy=41.0, cx=23.1, cy=18.7)
    frames = []
    for i, cam in enumerate(cams):
        save_image(root / "images" / f"{cam.name}.jpg", random_image(h, w, seed=i))
        frames.append({"file_path": f"images/{cam.name}.jpg", "transform_matrix": opengl_c2w(cam)})
    c = cams[0]
    data = {"fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": w, "h": h, **(dist or {}), "frames": frames[::-1]}
    (root / "transforms.json").write_text(json.dumps(data))
    return root


# ------------------------------------------------------------------------------------------------- DTU
SCALE_CENTER = np.array([0.3, -0.2, 5.0])
SCALE_RADIUS = 2.5


def make_dtu_scene(root: Path, n=5, masks=True, negate=(1,)) -> tuple[Path, list[Camera]]:
    """NeuS/IDR layout. Returns the folder and the expected cameras in the unit-sphere frame.

    ``world_mat`` uses IDR's pixel convention (pixel centres at integers: ``cx_file = cx - 0.5``);
    views listed in ``negate`` store ``-world_mat`` (a projection is defined up to sign).
    """
    cams = ring_cameras(n, fx=40.0, fy=41.0, cx=23.1, cy=18.7)
    S = np.eye(4)
    S[:3, :3] *= SCALE_RADIUS
    S[:3, 3] = SCALE_CENTER
    mats = {}
    for i, cam in enumerate(cams):
        K = cam.K.copy()
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        world = np.eye(4)
        world[:3] = K @ np.hstack([cam.R, (SCALE_RADIUS * cam.t - cam.R @ SCALE_CENTER)[:, None]])
        mats[f"world_mat_{i}"] = -world if i in negate else world
        mats[f"scale_mat_{i}"] = S
        save_image(root / "image" / f"{i:06d}.png", random_image(seed=i))
        if masks:
            m = np.zeros((H, W), np.uint8)
            m[H // 4 : 3 * H // 4, W // 4 : 3 * W // 4] = 200
            m[0, 0] = 100  # below the 127 threshold
            save_image(root / "mask" / f"{i:03d}.png", m)
    np.savez(root / "cameras_sphere.npz", **mats)
    return root, cams
