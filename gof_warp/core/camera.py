"""Pinhole cameras.

Conventions (written once here and in ``docs/conventions.md``):

* **World-to-camera**: a camera stores ``R`` (``[3, 3]``) and ``t`` (``[3]``) with
  ``x_cam = R @ x_world + t``.
* **OpenCV camera axes**: x right, y down, z forward (into the scene). Depth is camera-space ``z``.
* **Pixel coordinates**: continuous, the top-left corner of the image is ``(0, 0)`` and the centre of
  pixel ``(i, j)`` (column ``i``, row ``j``) is ``(i + 0.5, j + 0.5)`` (COLMAP's convention). The
  principal point ``(cx, cy)`` is in these coordinates and may be anywhere (not only the image centre).
* The ray of pixel ``(i, j)`` in camera space is ``((i + 0.5 - cx) / fx, (j + 0.5 - cy) / fy, 1)``, so
  the ray parameter ``t`` of ``o + t * r`` equals camera-space depth ``z``.

Cameras are host-side float64 numpy objects; renderers convert them to device arrays.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .errors import SceneError


_MIN_SINGULAR_RATIO = 1e-3  # a stored rotation (possibly rounded or uniformly scaled) has equal singular values;
# below this ratio of smallest to largest the 3x3 block is not a rotation at all (e.g. all zeros)


def _as_matrix(x, shape, name):
    a = np.asarray(x, dtype=np.float64)
    if a.shape != shape:
        raise SceneError(f"camera {name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"camera {name} has NaN/inf entries")
    return a


@dataclass(frozen=True, kw_only=True)
class Intrinsics:
    """Pinhole intrinsics in pixels of a ``width × height`` image: the one declaration of ``fx fy cx cy width
    height``, shared by :class:`Camera` (intrinsics + pose) and :class:`~gof_warp.data.undistort.LensCamera`
    (intrinsics + lens distortion). Keyword-only; compared by value.

    Attributes:
        fx, fy: focal lengths in pixels (> 0).
        cx, cy: principal point in pixels (pixel centres at ``i + 0.5``; anywhere, not only the image centre).
        width, height: image size in pixels (> 0).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def _finite_numbers(self, names, label: str = "") -> None:
        """Each field in ``names`` as a finite float, or a ``SceneError`` naming it (``label``: e.g. "distortion ")."""
        for k in names:
            try:
                v = float(getattr(self, k))
            except (TypeError, ValueError):
                raise SceneError(f"{self._what()}: {label}{k} must be a number, got {getattr(self, k)!r}") from None
            if not np.isfinite(v):
                raise SceneError(f"{self._what()}: {label}{k} is not finite")
            object.__setattr__(self, k, v)

    def _what(self) -> str:
        """How messages name this object."""
        return "intrinsics"

    def __post_init__(self):
        self._finite_numbers(("fx", "fy", "cx", "cy"))
        if self.fx <= 0 or self.fy <= 0:
            raise SceneError(f"{self._what()}: focal lengths must be positive (fx={self.fx}, fy={self.fy})")
        w, h = int(self.width), int(self.height)
        if w <= 0 or h <= 0:
            raise SceneError(f"{self._what()}: image size must be positive, got {w}x{h}")
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)

    @property
    def intrinsics(self) -> "Intrinsics":
        """The plain :class:`Intrinsics` of this object (drops the pose or the distortion)."""
        return Intrinsics(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, width=self.width, height=self.height)

    @property
    def pinhole(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)``: the four numbers of the projection, e.g. for a kernel or a ``[4]`` tensor."""
        return (self.fx, self.fy, self.cx, self.cy)

    @property
    def K(self) -> np.ndarray:
        """``[3, 3]`` intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def resized(self, width: int, height: int):
        """The same object (same type, pose/distortion kept) for the image resized to ``width × height``:
        focal lengths and principal point scale with the size ratio per axis, so pixel-centre geometry stays
        exact (distortion coefficients are in normalised units and do not change)."""
        sx, sy = width / self.width, height / self.height
        return dataclasses.replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy,
                                   width=width, height=height)

    def fov(self) -> tuple[float, float]:
        """Horizontal and vertical field of view in radians (from the focal lengths and image size)."""
        return 2 * np.arctan(self.width / (2 * self.fx)), 2 * np.arctan(self.height / (2 * self.fy))


@dataclass(frozen=True, eq=False)
class Camera(Intrinsics):
    """A pinhole camera with an arbitrary principal point: :class:`Intrinsics` plus a world-to-camera pose.

    Attributes:
        R: ``[3, 3]`` world-to-camera rotation (orthonormal, det +1).
        t: ``[3]`` world-to-camera translation.
        fx, fy, cx, cy, width, height: the :class:`Intrinsics` (pixels; pixel centres at ``i + 0.5``).
        name: image name (file stem), for messages and outputs.
        near: depth (world units) in front of which this camera photographed nothing, e.g. a fraction of its
            nearest SfM point (``RenderConfig.near_from_points``); the renderer clips at the larger of it and
            ``RenderConfig.near``. 0 (default): unknown, ``RenderConfig.near`` alone.

    ``R`` and ``t`` may be given by position; the intrinsics, ``name`` and ``near`` by keyword. Compared and hashed
    by identity (two views may share intrinsics and pose).
    """

    R: np.ndarray
    t: np.ndarray
    name: str = ""
    near: float = 0.0

    __eq__ = object.__eq__
    __hash__ = object.__hash__

    def _what(self) -> str:
        return f"camera {self.name!r}"

    def __post_init__(self):
        R = _as_matrix(self.R, (3, 3), "R")
        t = _as_matrix(self.t, (3,), "t")
        if abs(np.linalg.det(R) - 1.0) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
            raise SceneError(f"camera {self.name!r}: R is not a rotation (det={np.linalg.det(R):.4f})")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        super().__post_init__()
        self._finite_numbers(("near",))
        if self.near < 0:
            raise SceneError(f"camera {self.name!r}: near must be >= 0, got {self.near}")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_c2w(cls, c2w, fx, fy, cx, cy, width, height, name="", opengl=False) -> "Camera":
        """Build from a ``[4, 4]`` (or ``[3, 4]``) camera-to-world matrix.

        ``opengl=True`` means the matrix uses OpenGL/Blender camera axes (x right, y up, z backward),
        as NeRF ``transforms.json`` files do; the y and z axes are flipped to OpenCV's.
        """
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.shape not in ((4, 4), (3, 4)):
            raise SceneError(f"camera {name!r}: camera-to-world matrix must be 4x4 or 3x4, got {c2w.shape}")
        if not np.all(np.isfinite(c2w)):
            raise SceneError(f"camera {name!r}: camera-to-world matrix has NaN/inf entries")
        Rc2w = c2w[:3, :3].copy()
        if opengl:
            Rc2w[:, 1:3] *= -1.0
        # Re-orthonormalise (files often store rounded rotations, sometimes with scale) — but only a matrix
        # that is one: the SVD would turn an all-zero or rank-deficient block into an arbitrary rotation.
        U, sv, Vt = np.linalg.svd(Rc2w)
        if not sv[-1] > _MIN_SINGULAR_RATIO * sv[0]:
            rank = int(np.sum(sv > _MIN_SINGULAR_RATIO * max(sv[0], 1e-300)))
            raise SceneError(f"camera {name!r}: the camera-to-world rotation is singular (rank {rank} of 3, "
                             f"not invertible; e.g. an all-zero matrix): not a camera pose")
        Rc2w = U @ Vt
        if np.linalg.det(Rc2w) < 0:
            raise SceneError(f"camera {name!r}: camera-to-world rotation is a reflection")
        R = Rc2w.T
        t = -R @ c2w[:3, 3]
        return cls(R=R, t=t, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, name=name)

    # ------------------------------------------------------------------ derived quantities
    @property
    def center(self) -> np.ndarray:
        """``[3]`` camera centre in world space."""
        return -self.R.T @ self.t

    @property
    def w2c(self) -> np.ndarray:
        """``[4, 4]`` world-to-camera matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    @property
    def c2w(self) -> np.ndarray:
        """``[4, 4]`` camera-to-world matrix (OpenCV axes)."""
        m = np.eye(4)
        m[:3, :3] = self.R.T
        m[:3, 3] = self.center
        return m

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``[N, 3]`` → camera-space points ``[N, 3]``."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def project(self, points: np.ndarray):
        """Project world points ``[N, 3]``.

        Returns ``(uv [N, 2], depth [N])`` in continuous pixel coordinates (see module docstring);
        ``uv`` is meaningless where ``depth <= 0``.
        """
        pc = self.to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * pc[:, 0] / z + self.cx
            v = self.fy * pc[:, 1] / z + self.cy
        return np.stack([u, v], axis=1), z

    def to_camera_tensor(self, points):
        """:meth:`to_camera` of a torch tensor ``points [N, 3]`` on its device, in its dtype: ``R x + t`` ``[N, 3]``
        (``z``, the last column, is the depth)."""
        return points @ points.new_tensor(self.R).T + points.new_tensor(self.t)

    def project_tensor(self, points):
        """:meth:`project` of a torch tensor ``points [N, 3]`` on its device, in its dtype: ``(u [N], v [N], z [N])``.
        Where ``z <= 0`` the projection divides by 1 instead (finite, meaningless: test ``z`` first)."""
        pc = self.to_camera_tensor(points)
        z = pc[:, 2]
        zs = z.where(z > 0, z.new_ones(()))
        return self.fx * pc[:, 0] / zs + self.cx, self.fy * pc[:, 1] / zs + self.cy, z

    def in_image_tensor(self, points):
        """:meth:`project_tensor` plus ``inside [N]`` bool, as :meth:`in_image` with ``near`` 0: in front of the camera
        (``z > 0``) and within the image (``0 <= u < width``, ``0 <= v < height``). Returns ``(u, v, z, inside)``."""
        u, v, z = self.project_tensor(points)
        return u, v, z, (z > 0) & (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)

    def in_image(self, points: np.ndarray, near: float = 0.0):
        """:meth:`project` plus ``inside [N]`` bool: in front of the camera (``depth > near``) and within the image
        (``0 <= u < width``, ``0 <= v < height``). Returns ``(uv, depth, inside)``."""
        uv, z = self.project(points)
        inside = (z > near) & (uv[:, 0] >= 0) & (uv[:, 0] < self.width) & (uv[:, 1] >= 0) & (uv[:, 1] < self.height)
        return uv, z, inside

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through all pixel centres.

        Returns ``(origin [3], directions [H, W, 3])``; directions are *not* normalised: their
        camera-space ``z`` is 1, so the ray parameter is depth.
        """
        i = (np.arange(self.width) + 0.5 - self.cx) / self.fx
        j = (np.arange(self.height) + 0.5 - self.cy) / self.fy
        ii, jj = np.meshgrid(i, j, indexing="xy")
        d_cam = np.stack([ii, jj, np.ones_like(ii)], axis=-1)
        return self.center, d_cam @ self.R  # R^T applied to row vectors

    def scaled(self, factor: float) -> "Camera":
        """The camera for the image resized by ``factor`` (e.g. 0.5 halves the resolution).

        Width/height are rounded; focal lengths and principal point scale with the actual size
        ratio, so pixel-centre geometry stays exact.
        """
        return self.resized(max(1, int(round(self.width * factor))), max(1, int(round(self.height * factor))))

    def to_dict(self) -> dict:
        """Plain data (JSON-able): name, size, intrinsics, world-to-camera ``R``/``t``, and ``near`` when set."""
        d = {"name": self.name, "width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
             "cx": self.cx, "cy": self.cy, "R": self.R.tolist(), "t": self.t.tolist()}
        return {**d, "near": self.near} if self.near > 0 else d

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(R=np.array(d["R"]), t=np.array(d["t"]), fx=d["fx"], fy=d["fy"], cx=d["cx"], cy=d["cy"],
                       width=d["width"], height=d["height"], name=d.get("name", ""), near=d.get("near", 0.0))
        except (KeyError, TypeError) as e:
            raise SceneError(f"camera record {d.get('name', '?') if isinstance(d, dict) else d!r} is incomplete: {e}") from None

    def __repr__(self) -> str:
        c = self.center
        return (
            f"Camera({self.name!r}, {self.width}x{self.height}, f=({self.fx:.2f}, {self.fy:.2f}), "
            f"c=({self.cx:.2f}, {self.cy:.2f}), centre=({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}))"
        )


def look_at(eye, target, up=(0.0, 0.0, 1.0), fx=500.0, fy=None, cx=None, cy=None, width=640, height=480, name="") -> Camera:
    """A camera at ``eye`` looking at ``target`` with ``up`` roughly up in the image (OpenCV axes)."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    z = target - eye
    nz = np.linalg.norm(z)
    if nz == 0:
        raise SceneError("look_at: eye and target coincide")
    z /= nz
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)  # image x points right when y (down) = z × x
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=0)
    fy = fx if fy is None else fy
    cx = width / 2.0 if cx is None else cx
    cy = height / 2.0 if cy is None else cy
    return Camera(R=R, t=-R @ eye, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, name=name)


def camera_arrays(cameras) -> dict[str, np.ndarray]:
    """The cameras packed for kernels that loop over them, float64, one row per camera: ``R [C, 3, 3]``,
    ``t [C, 3]`` (world-to-camera), ``f [C, 2]`` (fx, fy), ``c [C, 2]`` (cx, cy), ``wh [C, 2]`` (width, height)."""
    return {
        "R": np.array([c.R for c in cameras], np.float64).reshape(-1, 3, 3),
        "t": np.array([c.t for c in cameras], np.float64).reshape(-1, 3),
        "f": np.array([[c.fx, c.fy] for c in cameras], np.float64).reshape(-1, 2),
        "c": np.array([[c.cx, c.cy] for c in cameras], np.float64).reshape(-1, 2),
        "wh": np.array([[c.width, c.height] for c in cameras], np.float64).reshape(-1, 2),
    }


def camera_extent(cameras) -> float:
    """Scene extent as 3DGS computes it: 1.1 × the largest distance of a camera centre from their mean.

    Used to scale learning rates and pruning thresholds. When every centre coincides (one camera, or a
    rotating camera) there is no spread; the extent is then 1.1 (as if the spread were 1).
    """
    centers = np.stack([c.center for c in cameras]) if len(cameras) else np.zeros((0, 3))
    if len(centers) == 0:
        raise SceneError("cannot compute the scene extent of zero cameras")
    d = np.linalg.norm(centers - centers.mean(axis=0), axis=1).max()
    return 1.1 * (float(d) if d > 0 else 1.0)
