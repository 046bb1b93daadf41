"""Which way is up in a scene, and the rotation that stands an exported asset upright in its format.

A capture's world frame has whatever up its poses came with (COLMAP: the first camera's; DTU: the calibration's;
gof_warp's built-in scenes: +z). Asset formats state theirs: glTF is +Y up (its specification), OBJ is read as +Y up
by Blender's and most tools' importers, and a USD stage states its up axis (``upAxis``; Isaac Sim and Omniverse
physics: Z). An asset written in the capture's frame lies on its side or upside down in them.

* :func:`scene_up` — the up of a capture from its cameras, as nerfstudio's ``orientation_method="up"`` does: the
  mean of the cameras' image-up directions (OpenCV cameras: ``-R[1]``, the world direction of the image's ``-y``),
  normalised; within :data:`SNAP_DEGREES` of a world axis it is that axis exactly (a built-in scene stays as it is).
  Photos are taken upright, so the mean is the world's up; cameras whose up directions cancel (rolled every way) give
  no answer.
* :func:`parse_up` — ``"auto"`` or a signed axis (``"+z"``, ``"-y"``, ...), as the command line takes it.
* :func:`rotation_taking` — the smallest rotation taking one direction to another (Rodrigues); a half turn about an
  axis perpendicular to both when they are opposite.
* :func:`world_from_file` — the rotation back to the scene's frame that a GLB or OBJ written upright records
  (:mod:`gof_warp.mesh.export`), for every reader of mesh files (scoring, viewer, pictures).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .errors import GofError

SNAP_DEGREES = 10.0  # a scene up this close to a world axis is that axis
UP_CHOICES = ("auto", "+x", "-x", "+y", "-y", "+z", "-z")
MIN_AGREEMENT = 0.3  # |mean of the cameras' unit up directions| below this: they do not agree on an up
Y_UP = np.array([0.0, 1.0, 0.0])  # glTF's up, and OBJ importers'
OBJ_ROTATION_TAG = "# gof_warp file_from_world"  # an upright OBJ's comment line: the nine numbers of its rotation
GLB_MAGIC, GLB_JSON = 0x46546C67, 0x4E4F534A  # the GLB header's magic and its JSON chunk's type


def parse_up(text: str) -> np.ndarray | None:
    """``"auto"`` → None (:func:`scene_up` decides); ``"+x"`` … ``"-z"`` (or without the ``+``) → that unit axis."""
    t = str(text).strip().lower()
    if t == "auto":
        return None
    if t in ("x", "y", "z"):
        t = "+" + t
    if t not in UP_CHOICES:
        raise GofError(f"up must be one of {', '.join(UP_CHOICES)}, got {text!r}")
    axis = np.zeros(3)
    axis["xyz".index(t[1])] = 1.0 if t[0] == "+" else -1.0
    return axis


def scene_up(cameras) -> np.ndarray | None:
    """``[3]`` unit up direction of the world the ``cameras`` (OpenCV, :class:`~gof_warp.core.camera.Camera`) look at:
    the normalised mean of their image-up directions ``-R[1]``, snapped to a world axis within :data:`SNAP_DEGREES`.
    None when there are no cameras or their up directions cancel (mean length below :data:`MIN_AGREEMENT`)."""
    if not len(cameras):
        return None
    ups = np.stack([-np.asarray(c.R, np.float64)[1] for c in cameras])
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    mean = ups.mean(0)
    n = float(np.linalg.norm(mean))
    if n < MIN_AGREEMENT:
        return None
    up = mean / n
    k = int(np.argmax(np.abs(up)))
    if abs(up[k]) >= math.cos(math.radians(SNAP_DEGREES)):
        up = np.zeros(3)
        up[k] = math.copysign(1.0, mean[k])
    return up


def rotation_taking(a, b) -> np.ndarray:
    """``[3, 3]`` the smallest rotation ``R`` with ``R a = b`` for directions ``a``, ``b`` (normalised here); the
    identity when they agree, a half turn about an axis perpendicular to ``a`` when they are opposite."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        p = np.eye(3)[int(np.argmin(np.abs(a)))]  # the world axis least along a
        k = np.cross(a, p)
        k /= np.linalg.norm(k)
        return 2.0 * np.outer(k, k) - np.eye(3)  # half turn about k
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def read_glb_json(glb: bytes) -> tuple[dict, int]:
    """``(the JSON chunk of a GLB as a dict, its length in bytes)``; :class:`GofError` when the header is not glTF's."""
    import json
    import struct

    if len(glb) < 20:
        raise GofError("not a GLB file (shorter than its header)")
    magic, _, _ = struct.unpack_from("<III", glb, 0)
    json_len, json_type = struct.unpack_from("<II", glb, 12)
    if magic != GLB_MAGIC or json_type != GLB_JSON:
        raise GofError("not a GLB file (its header is not glTF's)")
    return json.loads(glb[20:20 + json_len]), json_len


def world_from_file(path) -> np.ndarray | None:
    """``[3, 3]`` the rotation taking a GLB's or OBJ's vertices back to the scene's frame (the transpose of the
    ``file_from_world`` recorded when it was written upright; module docstring), or None when none is recorded."""
    path = Path(path)
    R = None
    if path.suffix.lower() == ".glb":
        with open(path, "rb") as fh:
            head = fh.read(20)
            if len(head) == 20:
                import struct

                json_len = struct.unpack_from("<I", head, 12)[0]
                try:
                    doc, _ = read_glb_json(head + fh.read(json_len))
                except (GofError, ValueError):
                    return None
                R = (((doc.get("asset") or {}).get("extras") or {}).get("gof_warp") or {}).get("file_from_world")
    elif path.suffix.lower() == ".obj":
        with open(path, encoding="ascii", errors="replace") as fh:
            for _, line in zip(range(8), fh):
                if line.startswith(OBJ_ROTATION_TAG):
                    R = line[len(OBJ_ROTATION_TAG):].split()
                    break
    if R is None:
        return None
    try:
        R = np.asarray(R, np.float64).reshape(3, 3)
    except (ValueError, TypeError):
        raise GofError(f"{path}: its recorded file_from_world is not 9 numbers") from None
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5):
        raise GofError(f"{path}: its recorded file_from_world is not a rotation")
    return R.T
