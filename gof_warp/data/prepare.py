"""Camera poses for a folder of plain photos: structure from motion with pycolmap (CPU), written as a COLMAP scene.

:func:`prepare_scene` runs SIFT feature extraction → matching (exhaustive or sequential) → incremental mapping
(the largest reconstruction is kept) → undistortion to PINHOLE cameras, and writes ``OUT/images/``,
``OUT/sparse/0/`` (what :func:`gof_warp.data.load_scene` reads as ``colmap``) and ``OUT/prepare.json`` (the
report). Everything is written into a temporary folder beside ``OUT`` and moved into place at the end, so a
failed run leaves ``OUT`` as it was.

:func:`align_similarity` (Umeyama) and :func:`pose_errors` compare recovered poses with reference ones up to
the similarity that structure from motion cannot recover.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..core.errors import GofError
from ..core.io_utils import write_json_atomic
from ..core.progress import Stages, as_stages

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
MATCHERS = ("auto", "exhaustive", "sequential")
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
EXHAUSTIVE_MAX_IMAGES = 150  # matcher "auto": exhaustive up to this many photos, sequential (video frames) above
MIN_IMAGES = 3
MIN_REGISTERED_FRACTION = 0.5
REPORT_NAME = "prepare.json"


class PrepareError(GofError):
    """The photos cannot be turned into a scene (bad input folder, output folder, or too few registered)."""


@dataclass
class PrepareConfig:
    """How :func:`prepare_scene` runs.

    Attributes:
        matcher: ``"exhaustive"`` (every pair), ``"sequential"`` (neighbours in name order: video frames) or
            ``"auto"`` (exhaustive up to :data:`EXHAUSTIVE_MAX_IMAGES` photos, else sequential).
        max_size: photos whose longer side exceeds this many pixels are downscaled to it before SfM; the scene's
            images are written at that size. 0 keeps the full size.
        camera_model: COLMAP camera model estimated by SfM (the scene is written undistorted, PINHOLE).
        single_camera: one camera (intrinsics) shared by all photos (one phone or camera, fixed zoom);
            False estimates one per photo.
        max_features: SIFT features per image.
        sequential_overlap: neighbours matched per image by the sequential matcher.
        num_threads: CPU threads (-1: all).
        overwrite: replace an output folder that an earlier ``prepare`` wrote (it holds ``prepare.json``).
    """

    matcher: str = "auto"
    max_size: int = 1600
    camera_model: str = "SIMPLE_RADIAL"
    single_camera: bool = True
    max_features: int = 8192
    sequential_overlap: int = 10
    num_threads: int = -1
    overwrite: bool = False

    def __post_init__(self):
        if self.matcher not in MATCHERS:
            raise PrepareError(f"matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        if self.camera_model not in CAMERA_MODELS:
            raise PrepareError(f"camera model must be one of {', '.join(CAMERA_MODELS)}, got {self.camera_model!r}")
        if int(self.max_size) < 0 or (0 < int(self.max_size) < 64):
            raise PrepareError(f"max size must be 0 (full size) or >= 64 pixels, got {self.max_size!r}")
        if int(self.max_features) < 64:
            raise PrepareError(f"max features must be >= 64, got {self.max_features!r}")


def list_photos(folder) -> list[Path]:
    """The image files directly in ``folder`` (by extension, name-sorted); PrepareError if it is not a folder
    or holds fewer than :data:`MIN_IMAGES`."""
    folder = Path(folder).expanduser()
    if not folder.exists():
        raise PrepareError(f"{folder}: photo folder does not exist")
    if not folder.is_dir():
        raise PrepareError(f"{folder}: not a folder (give the folder that holds the photos)")
    photos = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
    if not photos:
        raise PrepareError(f"{folder}: no images (looked for files ending in {', '.join(IMAGE_EXTENSIONS)})")
    if len(photos) < MIN_IMAGES:
        raise PrepareError(f"{folder}: {len(photos)} image(s); structure from motion needs at least {MIN_IMAGES} "
                           "overlapping photos of the scene from different viewpoints")
    return photos


def folder_has_photos(folder) -> bool:
    """Whether ``folder`` holds at least one image file directly (the input of ``prepare``)."""
    try:
        return any(p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file() for p in Path(folder).iterdir())
    except OSError:
        return False


def _check_output(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise PrepareError(f"{out}: output exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise PrepareError(f"{out}: output folder is not empty (pass --overwrite to replace a scene that "
                               "prepare wrote there earlier)")
        if not (out / REPORT_NAME).is_file():
            raise PrepareError(f"{out}: output folder is not empty and was not written by prepare (no {REPORT_NAME}); "
                               "refusing to replace it even with --overwrite: choose another folder")
    if not out.parent.is_dir():
        raise PrepareError(f"{out.parent}: the output's parent folder does not exist")


def _stage_photos(photos: list[Path], dst: Path, max_size: int) -> list[str]:
    """Copy (or downscale, EXIF orientation applied) the photos into ``dst`` under their own names."""
    from PIL import Image, ImageOps

    for p in photos:
        try:
            with Image.open(p) as im:
                oriented = ImageOps.exif_transpose(im)
                w, h = oriented.size
                scale = max_size / max(w, h) if max_size and max(w, h) > max_size else 1.0
                if scale == 1.0 and oriented is im:
                    shutil.copyfile(p, dst / p.name)
                else:
                    if scale != 1.0:
                        w, h = max(1, round(w * scale)), max(1, round(h * scale))
                        oriented = oriented.resize((w, h), Image.LANCZOS)
                    if oriented.mode not in ("RGB", "L"):
                        oriented = oriented.convert("RGB")
                    kw = {"quality": 95} if p.suffix.lower() in (".jpg", ".jpeg") else {}
                    oriented.save(dst / p.name, **kw)
        except OSError as e:
            raise PrepareError(f"{p}: cannot read the image ({e})") from e
    return [p.name for p in photos]


EXTRACT_CHUNK = 8  # photos per feature-extraction call: the progress bar's step
MATCH_CHUNKS = 25  # matching calls (at least MATCH_CHUNK_MIN pairs each): the progress bar's steps
MATCH_CHUNK_MIN = 50


def _extract_features(pycolmap, db_path: Path, image_dir: Path, names: list[str], config: PrepareConfig,
                      stages: Stages) -> None:
    """SIFT on the photos in chunks (for the progress bar); with ``single_camera`` every chunk after the first
    reuses the first chunk's camera."""
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = int(config.max_size) if config.max_size else 100000
    extraction.num_threads = config.num_threads
    extraction.sift.max_num_features = config.max_features
    mode = pycolmap.CameraMode.SINGLE if config.single_camera else pycolmap.CameraMode.PER_IMAGE
    camera_id = -1
    with stages.bar(total=len(names), desc="photos", unit="img") as bar:
        for k in range(0, len(names), EXTRACT_CHUNK):
            chunk = names[k:k + EXTRACT_CHUNK]
            reader = pycolmap.ImageReaderOptions(camera_model=config.camera_model)
            if camera_id >= 0:
                reader.existing_camera_id = camera_id
            pycolmap.extract_features(db_path, image_dir, image_names=chunk, camera_mode=mode, reader_options=reader,
                                      extraction_options=extraction, device=pycolmap.Device.cpu)
            if config.single_camera and camera_id < 0:
                db = pycolmap.Database.open(str(db_path))
                try:
                    camera_id = int(next(iter(db.read_all_images())).camera_id)
                finally:
                    db.close()
            bar.goto(k + len(chunk))


def _pairs(n: int, matcher: str, overlap: int) -> list[tuple[int, int]]:
    """Photo index pairs to match: every pair (exhaustive), or each photo with the next ``overlap`` ones and the
    ones ``2**k`` ahead, k < ``overlap`` (sequential, as COLMAP's quadratic overlap)."""
    if matcher == "exhaustive":
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    pairs = set()
    for i in range(n):
        for d in range(1, overlap + 1):
            if i + d < n:
                pairs.add((i, i + d))
        for k in range(overlap):
            if i + 2**k < n:
                pairs.add((i, i + 2**k))
    return sorted(pairs)


def _match_pairs(pycolmap, db_path: Path, work: Path, pairs: list[tuple[str, str]], config: PrepareConfig,
                 stages: Stages) -> None:
    """Match and verify (RANSAC) the photo pairs in chunks (for the progress bar)."""
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    size = max(MATCH_CHUNK_MIN, -(-len(pairs) // MATCH_CHUNKS))
    with stages.bar(total=len(pairs), desc="pairs", unit="pair") as bar:
        for k in range(0, len(pairs), size):
            chunk = pairs[k:k + size]
            pairs_file = work / "pairs.txt"
            pairs_file.write_text("".join(f"{a} {b}\n" for a, b in chunk))
            pycolmap.match_image_pairs(db_path, matching_options=matching,
                                       pairing_options=pycolmap.ImportedPairingOptions(match_list_path=pairs_file),
                                       device=pycolmap.Device.cpu)
            bar.goto(k + len(chunk))


def _why_unregistered(db_path: Path, names: list[str]) -> dict[str, str]:
    """For each name, what the database says: its feature count and the photos it matched verifiably."""
    import pycolmap

    db = pycolmap.Database.open(str(db_path))
    try:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        pair_ids, geometries = db.read_two_view_geometries()
        partners: dict[int, int] = {}
        for pid, g in zip(pair_ids, geometries):
            if len(g.inlier_matches) == 0:
                continue
            for k in pycolmap.pair_id_to_image_pair(pid):
                partners[int(k)] = partners.get(int(k), 0) + 1
        why = {}
        for nm in names:
            if nm not in ids:
                why[nm] = "COLMAP could not read it"
                continue
            nf = int(db.num_keypoints_for_image(ids[nm]))
            npair = partners.get(int(ids[nm]), 0)
            why[nm] = (f"{nf} features, verified matches with {npair} photo(s)" if npair else
                       f"{nf} features, no verified matches with any photo")
        return why
    finally:
        db.close()


def prepare_scene(photos_dir, out, config: PrepareConfig | None = None, stages: Stages | None = None) -> dict:
    """Recover camera poses for the photos in ``photos_dir`` and write the COLMAP scene ``out``.

    Returns the report (also written as ``out/prepare.json``): ``registered``/``images``, ``points``,
    ``mean_reprojection_error_px``, the camera, ``unregistered`` names with reasons, seconds per stage.

    Raises:
        PrepareError: not a folder, no or too few images, output not empty (see :class:`PrepareConfig`),
            fewer than half (or fewer than 3) of the photos registered.
    """
    config = config or PrepareConfig()
    stages = as_stages(stages)
    photos_dir = Path(photos_dir).expanduser()
    out = Path(out).expanduser().absolute()
    photos = list_photos(photos_dir)
    _check_output(out, config.overwrite)

    from .sfm_colmap import _import_pycolmap, _quiet_colmap

    pycolmap = _import_pycolmap()
    n = len(photos)
    t_start = time.perf_counter()
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.prepare-", dir=out.parent))
    try:
        work, scene = staging / "work", staging / "scene"
        (work / "images").mkdir(parents=True)
        scene.mkdir()
        db_path = work / "database.db"
        with stages.stage("photos"):
            names = _stage_photos(photos, work / "images", config.max_size)

        with _quiet_colmap():
            with stages.stage("features"):
                _extract_features(pycolmap, db_path, work / "images", names, config, stages)

            matcher = config.matcher
            if matcher == "auto":
                matcher = "exhaustive" if n <= EXHAUSTIVE_MAX_IMAGES else "sequential"
            pairs = _pairs(n, matcher, config.sequential_overlap)
            with stages.stage("matching"):
                _match_pairs(pycolmap, db_path, work, [(names[i], names[j]) for i, j in pairs], config, stages)

            with stages.stage("mapping"):
                options = pycolmap.IncrementalPipelineOptions()
                options.num_threads = config.num_threads
                options.random_seed = 0
                (work / "sparse").mkdir()
                with stages.bar(total=n, desc="registered", unit="img") as bar:
                    registered = [0]

                    def next_image():
                        registered[0] += 1
                        bar.goto(min(registered[0] + 1, n))  # the initial pair registers two at once

                    recs = pycolmap.incremental_mapping(db_path, work / "images", work / "sparse", options=options,
                                                        initial_image_pair_callback=lambda: bar.goto(min(2, n)),
                                                        next_image_callback=next_image)
                    bar.goto(max((r.num_reg_images() for r in recs.values()), default=0))
            if not recs:
                why = _why_unregistered(db_path, names)
                raise PrepareError(f"structure from motion found no reconstruction from the {n} photos "
                                   f"(no pair with enough verified matches to start): {_reasons(why)}")
            best = max(recs.values(), key=lambda r: r.num_reg_images())
            reg_names = {best.images[i].name for i in best.reg_image_ids()}
            missing = [nm for nm in names if nm not in reg_names]
            n_reg = n - len(missing)
            why = _why_unregistered(db_path, missing) if missing else {}
            if n_reg < MIN_IMAGES or n_reg < MIN_REGISTERED_FRACTION * n:
                raise PrepareError(f"only {n_reg} of {n} photos registered (need at least half and at least "
                                   f"{MIN_IMAGES}); not registered: {_reasons(why)}. Photos need overlap "
                                   "(each part of the scene seen from several viewpoints), texture and sharpness")

            with stages.stage("undistortion"):
                model_dir = work / "model"
                model_dir.mkdir()
                best.write(model_dir)
                undist = work / "undistorted"
                pycolmap.undistort_images(undist, model_dir, work / "images", output_type="COLMAP",
                                          num_threads=config.num_threads)
                os.replace(undist / "images", scene / "images")
                (scene / "sparse").mkdir()
                os.replace(undist / "sparse", scene / "sparse" / "0")

        cams = {cid: c for cid, c in best.cameras.items()}
        camera_info = [{"model": c.model.name, "width": int(c.width), "height": int(c.height),
                        "params": [round(float(x), 6) for x in c.params]} for c in cams.values()]
        report = {
            "photos": str(photos_dir.resolve()),
            "images": n,
            "registered": n_reg,
            "registered_fraction": round(n_reg / n, 4),
            "points": int(best.num_points3D()),
            "mean_reprojection_error_px": round(float(best.compute_mean_reprojection_error()), 4),
            "mean_track_length": round(float(best.compute_mean_track_length()), 3),
            "reconstructions": len(recs),
            "matcher": matcher,
            "cameras_estimated": camera_info[:4],
            "num_cameras": len(camera_info),
            "unregistered": why,
            "config": asdict(config),
            "seconds": {**{k: round(v, 2) for k, v in stages.times.items()},
                        "total": round(time.perf_counter() - t_start, 2)},
        }
        write_json_atomic(scene / REPORT_NAME, report)
        _move_into_place(scene, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return report


def _reasons(why: dict[str, str], limit: int = 12) -> str:
    items = [f"{k} ({v})" for k, v in list(why.items())[:limit]]
    more = f" and {len(why) - limit} more" if len(why) > limit else ""
    return ", ".join(items) + more if items else "none"


def _move_into_place(scene: Path, out: Path) -> None:
    """``scene`` becomes ``out``: an empty (or absent) ``out`` receives its entries; an earlier prepare output is
    swapped out whole and then removed."""
    if not out.exists():
        os.replace(scene, out)
        return
    if not any(out.iterdir()):
        for entry in scene.iterdir():
            os.replace(entry, out / entry.name)
        scene.rmdir()
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    old.rmdir()
    os.replace(out, old)
    os.replace(scene, out)
    shutil.rmtree(old, ignore_errors=True)


# --- comparing poses -------------------------------------------------------------------------------------------


def align_similarity(src, dst) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama 1991) with ``dst ≈ s · R @ src + t`` for point sets of shape (N, 3).

    Returns ``(s, R, t)`` with ``R`` a proper rotation (det +1). Needs N >= 3 points not all on a line.
    """
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"align_similarity needs two (N, 3) arrays with N >= 3, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    var_s = (a**2).sum() / len(src)
    cov = b.T @ a / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def rotation_angle_deg(R) -> np.ndarray:
    """Angle (degrees) of rotation matrices of shape (..., 3, 3)."""
    tr = np.trace(np.asarray(R), axis1=-2, axis2=-1)
    return np.degrees(np.arccos(np.clip((tr - 1) / 2, -1.0, 1.0)))


def pose_errors(est_R, est_C, ref_R, ref_C) -> dict:
    """Errors of estimated poses against reference ones, after the similarity that best maps the estimated
    camera centres onto the reference ones.

    Args:
        est_R, ref_R: (N, 3, 3) world-to-camera rotations in the OpenCV/COLMAP convention (x right, y down,
            z forward), of the same N photos in the same order.
        est_C, ref_C: (N, 3) camera centres in world coordinates.
    Returns:
        ``rotation_deg`` and ``position_rel`` per photo (position error / camera spread, where the spread is
        the RMS distance of the reference centres from their centroid), their medians and maxima, and ``scale``.
    """
    est_R, ref_R = np.asarray(est_R, np.float64), np.asarray(ref_R, np.float64)
    est_C, ref_C = np.asarray(est_C, np.float64), np.asarray(ref_C, np.float64)
    s, A, t = align_similarity(est_C, ref_C)
    aligned_C = s * est_C @ A.T + t
    aligned_R = est_R @ A.T  # world-to-camera of the reference world: x_cam = R_est (A^T (x - t) / s) + ...
    spread = float(np.sqrt(((ref_C - ref_C.mean(0)) ** 2).sum(1).mean()))
    rot = rotation_angle_deg(aligned_R @ np.transpose(ref_R, (0, 2, 1)))
    pos = np.linalg.norm(aligned_C - ref_C, axis=1) / max(spread, 1e-12)
    return {
        "rotation_deg": rot,
        "position_rel": pos,
        "median_rotation_deg": float(np.median(rot)),
        "max_rotation_deg": float(rot.max()),
        "median_position_pct": float(np.median(pos) * 100),
        "max_position_pct": float(pos.max() * 100),
        "scale": s,
        "spread": spread,
    }


def read_scene_poses(scene) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{image name: (world-to-camera R, camera centre)}`` of the COLMAP model in a scene folder ``prepare`` wrote."""
    from .colmap import find_model_dir
    from .sfm_colmap import _import_pycolmap

    pycolmap = _import_pycolmap()
    model = find_model_dir(Path(scene))
    if model is None:
        raise PrepareError(f"{scene}: no COLMAP model (sparse/0)")
    rec = pycolmap.Reconstruction(str(model))
    poses = {}
    for iid in rec.reg_image_ids():
        im = rec.images[iid]
        cfw = im.cam_from_world
        m = np.asarray((cfw() if callable(cfw) else cfw).matrix())
        R, tt = m[:, :3], m[:, 3]
        poses[im.name] = (R, -R.T @ tt)
    return poses


__all__ = [
    "CAMERA_MODELS",
    "IMAGE_EXTENSIONS",
    "MATCHERS",
    "PrepareConfig",
    "PrepareError",
    "align_similarity",
    "folder_has_photos",
    "list_photos",
    "pose_errors",
    "prepare_scene",
    "read_scene_poses",
    "rotation_angle_deg",
]
