"""USD stages of a mesh, its training cameras and its collision mesh: :func:`write_usd` (``usd-core``, the optional
``gof_warp[usd]`` extra, imported lazily).

Stage layout (``defaultPrim`` ``/World``; up axis and metres per unit stated in the layer's metadata):

* ``/World/mesh``: ``UsdGeom.Mesh`` (``points``, ``faceVertexCounts`` all 3, ``faceVertexIndices``, ``extent``,
  ``subdivisionScheme = "none"``, right-handed: faces wound counter-clockwise seen from outside). With vertex colours,
  the ``displayColor`` primvar (``vertex`` interpolation, linear values: the sRGB colours decoded). With a texture,
  the ``st`` primvar and a material ``/World/Looks/mesh_material`` (``UsdPreviewSurface`` whose ``diffuseColor`` reads
  a ``UsdUVTexture`` of the image, written as ``<stem>_texture.png`` beside the stage and referenced by a relative
  path).
* ``/World/cameras/cam_XXXX``: one ``UsdGeom.Camera`` per training camera (:func:`usd_camera_params`), its pose as
  one ``xformOp:transform``, its clipping range from the camera's ``near`` (else :data:`DEFAULT_NEAR`); the camera's
  name and image size in its ``customData`` (``gof:name``, ``gof:imageSize``).
* ``/World/collision``: the closed mesh (:mod:`gof_warp.mesh.collision`) with ``UsdPhysics.CollisionAPI`` and
  ``UsdPhysics.MeshCollisionAPI`` (approximation ``"none"``: the triangles as they are, which physics engines take
  for static colliders), purpose ``guide`` so renderers do not draw it.

Coordinates are written as they are, in the scene's world frame; the stage states ``up_axis`` (default ``"Z"``, Isaac
Sim's and Omniverse's physics default), and with ``up`` (the scene's up direction: a COLMAP scene has whatever up its
reconstruction gave) ``/World`` carries the rotation taking it to that axis, so the asset stands upright and
gravity points down it. Scene units have no absolute scale unless the data has one, so
``meters_per_unit`` defaults to 1 (a unit is a metre) and should be given when known.

Cameras: gof_warp's are OpenCV world-to-camera (``x_cam = R x_world + t``, camera looks down +z, +y down the image;
``docs/conventions.md``); a USD camera looks down its local -z with +y up, so its local-to-world matrix is
``[R^T diag(1, -1, -1) | C]`` with ``C = -R^T t`` the centre. Intrinsics: USD measures focal length and apertures
in tenths of a scene unit; the horizontal aperture is a 36 mm film back (:data:`FILM_WIDTH_M`) in those units
(``0.36 / metersPerUnit``), ``focalLength = fx * aperture / W``,
``verticalAperture = H * focalLength / fy``; the principal point becomes the aperture offsets
``horizontalApertureOffset = (W / 2 - cx) * aperture / W``, ``verticalApertureOffset = (cy - H / 2) * verticalAperture
/ H``. The image spans the aperture edge to edge, pixel centres at ``i + 0.5`` (COLMAP's convention).

UVs (for the texture): ``st`` with ``(0, 0)`` at the image's bottom-left corner and ``t`` up (USD's and OBJ's
convention; glTF's ``v`` is ``1 - t``), either per face corner ``[F, 3, 2]`` (``faceVarying``) or per vertex
``[V, 2]`` (``vertex``).

Every file is written atomically: the layer is exported to a temporary file with the target's suffix in the same
folder (Sdf picks the format from the suffix: ``.usda`` text, ``.usdc`` and ``.usd`` binary crate) and renamed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.arrays import check_triangles
from ..core.errors import GofError
from ..core.io_utils import atomic_path, write_bytes_atomic

SUFFIXES = (".usd", ".usda", ".usdc")
FILM_WIDTH_M = 0.036  # the film back's width: a 35 mm full-frame sensor's, in metres
UP_AXES = ("Y", "Z")
DEFAULT_NEAR = 0.01  # a camera's near clipping distance (scene units) where the camera gives none


def pxr():
    """The ``pxr`` modules ``(Usd, UsdGeom, UsdShade, UsdPhysics, Sdf, Gf, Vt)``, or a :class:`GofError` naming the
    extra to install."""
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade, Vt
    except ImportError as e:
        raise GofError("USD output needs the usd-core package: pip install 'gof-warp[usd]' (or pip install "
                       f"usd-core) ({e})") from None
    return Usd, UsdGeom, UsdShade, UsdPhysics, Sdf, Gf, Vt


def usd_camera_params(camera, meters_per_unit: float = 1.0) -> dict:
    """USD camera attributes of a gof_warp :class:`~gof_warp.core.camera.Camera` on a stage of ``meters_per_unit``
    (see the module docstring):
    ``focalLength``, ``horizontalAperture``, ``verticalAperture``, ``horizontalApertureOffset``,
    ``verticalApertureOffset`` (floats) and ``transform`` (``[4, 4]`` float64 local-to-world, column-vector
    convention: ``x_world = M @ [x_local, 1]``)."""
    w, h = float(camera.width), float(camera.height)
    ha = FILM_WIDTH_M / float(meters_per_unit) * 10.0  # tenths of a scene unit
    focal = float(camera.fx) * ha / w
    va = h * focal / float(camera.fy)
    m = np.eye(4)
    m[:3, :3] = np.asarray(camera.R, np.float64).T @ np.diag([1.0, -1.0, -1.0])
    m[:3, 3] = np.asarray(camera.center, np.float64)
    return {"focalLength": focal, "horizontalAperture": ha, "verticalAperture": va,
            "horizontalApertureOffset": (w / 2 - float(camera.cx)) * ha / w,
            "verticalApertureOffset": (float(camera.cy) - h / 2) * va / h, "transform": m}


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _colours01(colours, n: int) -> np.ndarray:
    c = np.asarray(colours)
    if c.shape != (n, 3):
        raise GofError(f"vertex colours must be [{n}, 3], got {list(c.shape)}")
    if c.dtype == np.uint8:
        return c.astype(np.float64) / 255.0
    c = c.astype(np.float64)
    if not np.all(np.isfinite(c)):
        raise GofError("vertex colours contain NaN/inf")
    return np.clip(c, 0.0, 1.0)


def _check_texture(texture, uvs, n_verts: int, n_faces: int) -> tuple[np.ndarray, np.ndarray, str]:
    if (texture is None) != (uvs is None):
        raise GofError("a texture needs both the image and the UVs (give texture= and uvs=, or neither)")
    img = np.asarray(texture)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or img.shape[0] < 1 or img.shape[1] < 1:
        raise GofError(f"texture must be an RGB uint8 image [H, W, 3], got {img.dtype} {list(img.shape)}")
    st = np.asarray(uvs, np.float64)
    if st.shape == (n_faces, 3, 2):
        interp = "faceVarying"
        st = st.reshape(-1, 2)
    elif st.shape == (n_verts, 2):
        interp = "vertex"
    else:
        raise GofError(f"UVs must be per face corner [{n_faces}, 3, 2] or per vertex [{n_verts}, 2], "
                       f"got {list(st.shape)}")
    if not np.all(np.isfinite(st)):
        raise GofError("UVs contain NaN/inf")
    return img, st, interp


def _png_bytes(img: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def _define_mesh(stage, path: str, verts: np.ndarray, faces: np.ndarray):
    _, UsdGeom, _, _, _, Gf, Vt = pxr()
    mesh = UsdGeom.Mesh.Define(stage, path)
    v = np.ascontiguousarray(verts, np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, np.int32).reshape(-1)))
    lo, hi = (v.min(0), v.max(0)) if len(v) else (np.zeros(3, np.float32), np.zeros(3, np.float32))
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    return mesh


def _texture_material(stage, mesh, image_name: str, st: np.ndarray, interp: str):
    _, UsdGeom, UsdShade, _, Sdf, Gf, Vt = pxr()
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interp)
    primvar.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(st, np.float32)))
    material = UsdShade.Material.Define(stage, "/World/Looks/mesh_material")
    surface = UsdShade.Shader.Define(stage, "/World/Looks/mesh_material/surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    reader = UsdShade.Shader.Define(stage, "/World/Looks/mesh_material/st_reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex = UsdShade.Shader.Define(stage, "/World/Looks/mesh_material/diffuse_texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{image_name}"))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    material.CreateSurfaceOutput().ConnectToSource(surface.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def texture_path(path) -> Path:
    """The PNG a stage at ``path`` references for its texture: ``<stem>_texture.png`` beside it."""
    p = Path(path)
    return p.with_name(f"{p.stem}_texture.png")


def write_usd(path, vertices, faces, *, colours=None, cameras: Sequence = (), collision=None, texture=None,
              uvs=None, up_axis: str = "Z", meters_per_unit: float = 1.0, up=None) -> dict:
    """Write a USD stage (layout in the module docstring) atomically.

    Args:
        path: ``.usd``, ``.usda`` or ``.usdc`` file.
        vertices: ``[V, 3]`` float world positions; faces: ``[F, 3]`` integer vertex indices.
        colours: optional ``[V, 3]`` vertex colours, uint8 or float in ``[0, 1]`` (sRGB).
        cameras: :class:`~gof_warp.core.camera.Camera` sequence, written under ``/World/cameras``.
        collision: optional ``(vertices [Vc, 3], faces [Fc, 3])`` of the closed collision mesh.
        texture: optional RGB uint8 image ``[H, W, 3]``; uvs: its UVs, ``[F, 3, 2]`` per face corner or ``[V, 2]``
            per vertex (``(0, 0)`` at the image's bottom-left). Both or neither.
        up_axis: ``"Z"`` or ``"Y"``, the stage's stated up axis.
        up: ``[3]`` the scene's up direction (:func:`gof_warp.core.orientation.scene_up`); ``/World`` gets the
            rotation taking it to ``up_axis`` (its children keep the scene's coordinates). None: no rotation (the
            scene's frame is taken to be ``up_axis`` up).
        meters_per_unit: the stage's ``metersPerUnit``.

    Returns:
        ``{"path", "format" ("usda" or "usdc"), "cameras", "mesh_faces", "collision_faces", "texture" (the PNG's path
        or None)}``.

    Raises:
        GofError: bad inputs, a suffix that is not USD's, or ``usd-core`` missing.
    """
    Usd, UsdGeom, UsdShade, UsdPhysics, Sdf, Gf, Vt = pxr()
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise GofError(f"a USD stage's file must end in one of {SUFFIXES}, got {path}")
    if up_axis not in UP_AXES:
        raise GofError(f"up_axis must be one of {UP_AXES}, got {up_axis!r}")
    if not (np.isfinite(meters_per_unit) and meters_per_unit > 0):
        raise GofError(f"meters_per_unit must be a positive number, got {meters_per_unit!r}")
    v, f = check_triangles(vertices, np.asarray(faces, np.int64), path, GofError)
    col = None if colours is None else _colours01(colours, len(v))
    tex = None if texture is None and uvs is None else _check_texture(texture, uvs, len(v), len(f))
    if collision is not None:
        cv, cf = check_triangles(collision[0], np.asarray(collision[1], np.int64), f"{path} (collision)", GofError)

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up_axis == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    if up is not None:
        from ..core.orientation import rotation_taking

        R = rotation_taking(up, (0.0, 0.0, 1.0) if up_axis == "Z" else (0.0, 1.0, 0.0))
        if not np.array_equal(R, np.eye(3)):
            M = np.eye(4)
            M[:3, :3] = R
            world.AddTransformOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Matrix4d(M.T.tolist()))
    stage.GetRootLayer().documentation = "written by gof_warp"

    mesh = _define_mesh(stage, "/World/mesh", v, f)
    if col is not None:
        primvar = mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
        primvar.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(_srgb_to_linear(col), np.float32)))
    png = None
    if tex is not None:
        png = texture_path(path)
        _texture_material(stage, mesh, png.name, tex[1], tex[2])

    if cameras:
        UsdGeom.Scope.Define(stage, "/World/cameras")
    for i, cam in enumerate(cameras):
        p = usd_camera_params(cam, meters_per_unit)
        ucam = UsdGeom.Camera.Define(stage, f"/World/cameras/cam_{i:04d}")
        ucam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
        for name in ("focalLength", "horizontalAperture", "verticalAperture", "horizontalApertureOffset",
                     "verticalApertureOffset"):
            getattr(ucam, f"Create{name[0].upper()}{name[1:]}Attr")(float(p[name]))
        ucam.AddTransformOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Matrix4d(p["transform"].T.tolist()))
        near = float(getattr(cam, "near", 0.0) or 0.0) or DEFAULT_NEAR
        ucam.CreateClippingRangeAttr(Gf.Vec2f(near, max(near * 1e6, 1e4 * DEFAULT_NEAR)))
        prim = ucam.GetPrim()
        prim.SetCustomDataByKey("gof:name", str(getattr(cam, "name", "") or ""))
        prim.SetCustomDataByKey("gof:imageSize", Gf.Vec2i(int(cam.width), int(cam.height)))

    if collision is not None:
        cmesh = _define_mesh(stage, "/World/collision", cv, cf)
        cmesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
        UsdPhysics.CollisionAPI.Apply(cmesh.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(cmesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.none)

    if png is not None:  # the image first: a stage is never left pointing at a missing texture
        write_bytes_atomic(png, _png_bytes(tex[0]))
    with atomic_path(path) as tmp:
        staged = tmp.with_name(tmp.name + path.suffix.lower())  # Sdf picks the file format from the suffix
        try:
            if not stage.GetRootLayer().Export(str(staged)):
                raise GofError(f"USD could not write {path}")
            os.replace(staged, tmp)
        finally:
            if staged.exists():
                staged.unlink()
    return {"path": str(path), "format": "usda" if path.suffix.lower() == ".usda" else "usdc",
            "cameras": len(cameras), "mesh_faces": int(len(f)),
            "collision_faces": None if collision is None else int(len(cf)),
            "texture": None if png is None else str(png)}
