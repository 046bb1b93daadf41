"""Blender / NeRF-synthetic output of synthetic scenes, plus exact depth/normal maps and the GT mesh.

Layout written into a scene folder::

    transforms_train.json, transforms_test.json   camera_angle_x/y, fl_x, fl_y, cx, cy, w, h, frames[]
    train/r_000.png ...                            RGBA, alpha = coverage
    train/depth/r_000.npy                          float32 [H, W] camera z-depth, 0 = no hit
    train/normal/r_000.npy                         float32 [H, W, 3] unit world normal facing the camera, 0 = no hit
    test/...                                       the same for the test views
    gt_mesh.ply                                    all geometry (world coordinates)
    gt_object.ply                                  only the parts with role "object" (when there is background)
    scene.json                                     preset, seed, resolution, bounding boxes, ...

Each frame's ``transform_matrix`` is camera-to-world in OpenGL/Blender axes (x right, y up, z backward),
i.e. the OpenCV camera-to-world with its y and z columns negated; ``file_path`` has no extension (as in
the original NeRF-synthetic files).
"""

from __future__ import annotations

import io

import numpy as np

from ..core.camera import Camera
from ..core.io_utils import write_bytes_atomic


def png_bytes(rgba: np.ndarray) -> bytes:
    """Encode ``[H, W, 4]`` float in ``[0, 1]`` as an 8-bit RGBA PNG (deterministic bytes)."""
    from PIL import Image

    q = np.round(np.clip(rgba, 0.0, 1.0) * 255.0).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(q, mode="RGBA").save(buf, format="PNG")
    return buf.getvalue()


def npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a, dtype=np.float32), allow_pickle=False)
    return buf.getvalue()


def opengl_c2w(camera: Camera) -> np.ndarray:
    """``[4, 4]`` camera-to-world with OpenGL/Blender camera axes."""
    m = camera.c2w.copy()
    m[:3, 1:3] *= -1.0
    return m


def intrinsics_json(camera: Camera) -> dict:
    """The top-level intrinsics shared by every frame of a split."""
    fov_x, fov_y = camera.fov()
    return {"camera_angle_x": float(fov_x), "camera_angle_y": float(fov_y), "fl_x": camera.fx, "fl_y": camera.fy,
            "cx": camera.cx, "cy": camera.cy, "w": camera.width, "h": camera.height}


def frame_paths(split: str, name: str) -> dict:
    """Relative paths of one frame's files (image without extension, as NeRF-synthetic writes it)."""
    return {"file_path": f"{split}/{name}", "depth_path": f"{split}/depth/{name}.npy",
            "normal_path": f"{split}/normal/{name}.npy"}


def write_view(folder, split: str, camera: Camera, view) -> dict:
    """Write one rendered view (a :class:`~gof_warp.synthetic.render.RenderedView`); return its frame."""
    paths = frame_paths(split, camera.name)
    write_bytes_atomic(folder / (paths["file_path"] + ".png"), png_bytes(view.rgba))
    write_bytes_atomic(folder / paths["depth_path"], npy_bytes(view.depth))
    write_bytes_atomic(folder / paths["normal_path"], npy_bytes(view.normal))
    return {"file_path": paths["file_path"],
            "transform_matrix": [[float(x) for x in row] for row in opengl_c2w(camera)],
            "depth_path": paths["depth_path"], "normal_path": paths["normal_path"]}


def ply_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary PLY of a triangle mesh (float32 vertices, coincident vertices welded) via trimesh."""
    import trimesh

    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, dtype=np.float32).astype(np.float64),
                           faces=np.asarray(faces, dtype=np.int64), process=False)
    mesh.merge_vertices()
    return mesh.export(file_type="ply")
