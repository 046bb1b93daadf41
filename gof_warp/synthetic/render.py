"""Render :class:`~gof_warp.synthetic.meshes.SyntheticMesh` parts with Warp ray casting.

:class:`RayCaster` uploads the parts once (one ``wp.Mesh`` + BVH over their union, material tables,
textures) and renders :class:`~gof_warp.core.camera.Camera` views: colour with coverage alpha from
supersampling, and exact depth/normal/mask from the pixel-centre rays.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.camera import Camera
from ..core.errors import GofError
from ..kernels import raycast
from .meshes import SyntheticMesh

log = logging.getLogger(__name__)

_KINDS = {"constant": raycast.MAT_CONSTANT, "texture": raycast.MAT_TEXTURE, "procedural": raycast.MAT_PROCEDURAL}


def default_device() -> str:
    """Warp's name of the default device (:func:`gof_warp.core.devices.resolve_device`'s rule)."""
    from ..core.devices import warp_device

    return warp_device(None)


@dataclass(frozen=True)
class Lighting:
    """View-independent Lambertian lighting: ``albedo * (ambient + sum_l intensity_l * max(0, n . l))``.

    ``directions`` point from the surface towards each light (normalised on upload).
    """

    directions: tuple = ((0.45, -0.35, 0.82), (-0.6, 0.55, 0.35))
    intensities: tuple = (0.6, 0.35)
    ambient: float = 0.45

    def vectors(self) -> np.ndarray:
        d = np.asarray(self.directions, dtype=np.float64).reshape(-1, 3)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        return (d * np.asarray(self.intensities, dtype=np.float64)[:, None]).astype(np.float32)


@dataclass
class RenderedView:
    """One rendered camera (all numpy, ``H x W``).

    Attributes:
        rgba: ``[H, W, 4]`` float32 in ``[0, 1]``; straight (not premultiplied) colour of the covered
            samples and alpha = fraction of samples (centre + ``s x s`` grid) that hit geometry.
        depth: ``[H, W]`` float32 camera-space z of the pixel-centre ray's hit, 0 where it misses.
        normal: ``[H, W, 3]`` float32 unit geometric world normal at that hit, facing the camera; 0 on miss.
        mask: ``[H, W]`` bool, the pixel-centre ray hit something.
        face: ``[H, W]`` int32 index of the hit face in the concatenated mesh (-1 = miss).
    """

    rgba: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    mask: np.ndarray
    face: np.ndarray


def _stack_textures(textures: list[np.ndarray]) -> np.ndarray:
    """``[T, H, W, 3]`` float32; textures of other sizes are resized to the first one's size."""
    if not textures:
        return np.ones((1, 1, 1, 3), dtype=np.float32)
    from PIL import Image

    h, w = textures[0].shape[:2]
    out = []
    for t in textures:
        if t.shape[:2] != (h, w):
            t = np.stack([np.asarray(Image.fromarray(t[..., c]).resize((w, h), Image.BILINEAR)) for c in range(3)], -1)
        out.append(np.asarray(t, dtype=np.float32))
    return np.stack(out)


class RayCaster:
    """Ray caster over the union of ``parts`` on ``device``.

    Args:
        parts: the scene's meshes (world coordinates).
        lighting: the :class:`Lighting`.
        seed: selects the procedural noise fields.
        device: Warp device (default: cuda if available, else cpu).
    """

    def __init__(self, parts: list[SyntheticMesh], lighting: Lighting | None = None, seed: int = 0, device=None):
        if not parts:
            raise GofError("a synthetic scene needs at least one mesh")
        self.device = wp.get_device(device or default_device())
        self.lighting = lighting or Lighting()
        self.seed = int(seed)
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
        self.points = np.concatenate([p.vertices for p in parts]).astype(np.float32)
        self.faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets)]).astype(np.int32)
        normals = np.concatenate([p.vertex_normals for p in parts]).astype(np.float32)
        uvs = np.concatenate([p.corner_uvs if p.corner_uvs is not None else np.zeros((len(p.faces), 3, 2))
                              for p in parts]).astype(np.float32)
        self.face_part = np.repeat(np.arange(len(parts), dtype=np.int32), [len(p.faces) for p in parts])
        textures, tex_index = [], []
        for p in parts:
            if p.material.kind not in _KINDS:
                raise GofError(f"mesh {p.name!r}: unknown material kind {p.material.kind!r}")
            if p.material.kind == "texture":
                if p.material.texture is None or p.corner_uvs is None:
                    raise GofError(f"mesh {p.name!r}: a texture material needs a texture and corner UVs")
                textures.append(p.material.texture)
            tex_index.append(max(len(textures) - 1, 0))
        mats = [p.material for p in parts]
        dev = self.device

        def arr(x, dtype):
            return wp.array(np.ascontiguousarray(x), dtype=dtype, device=dev)

        self.shading = {
            "points": arr(self.points, wp.vec3),
            "indices": arr(self.faces.ravel(), wp.int32),
            "vertex_normals": arr(normals, wp.vec3),
            "corner_uvs": arr(uvs.reshape(-1, 2), wp.vec2),
            "face_material": arr(self.face_part, wp.int32),
            "mat_kind": arr(np.array([_KINDS[m.kind] for m in mats], np.int32), wp.int32),
            "mat_texture": arr(np.array(tex_index, np.int32), wp.int32),
            "mat_color_a": arr(np.array([m.color_a for m in mats], np.float32), wp.vec3),
            "mat_color_b": arr(np.array([m.color_b for m in mats], np.float32), wp.vec3),
            "mat_params": arr(np.array([[m.noise_scale, m.checker_scale, m.checker_strength, 0.0] for m in mats],
                                       np.float32), wp.vec4),
            "textures": arr(_stack_textures(textures), wp.vec3),
        }
        self.lights = arr(self.lighting.vectors(), wp.vec3)
        self.mesh = wp.Mesh(points=self.shading["points"], indices=self.shading["indices"])
        log.debug("ray caster: %d parts, %d triangles on %s", len(parts), len(self.faces), dev)

    def cast(self, camera: Camera, samples: int = 1) -> dict:
        """Raw hits of the ``samples x samples`` grid per pixel (``wp.array2d`` dict, see ``kernels/raycast``)."""
        c = camera
        return raycast.cast_pinhole_rays(self.mesh, c.R, c.t, c.fx, c.fy, c.cx, c.cy, c.width, c.height, samples)

    def render(self, camera: Camera, supersample: int = 2) -> RenderedView:
        """Render one view. ``supersample`` s: colour/alpha average the centre ray and an ``s x s`` grid."""
        centre = self.cast(camera, 1)
        centre_rgb = raycast.shade_hits(centre, self.shading, self.lights, self.lighting.ambient, self.seed)
        sub = sub_rgb = None
        if supersample > 1:
            sub = self.cast(camera, int(supersample))
            sub_rgb = raycast.shade_hits(sub, self.shading, self.lights, self.lighting.ambient, self.seed)
        rgba = raycast.resolve_pixels(centre, centre_rgb, sub, sub_rgb).numpy()
        face = centre["face"].numpy()
        return RenderedView(rgba=rgba, depth=centre["depth"].numpy(), normal=centre["normal"].numpy(),
                            mask=face >= 0, face=face)
