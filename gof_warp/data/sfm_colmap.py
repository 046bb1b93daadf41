"""The COLMAP pipeline of triangulation from known poses (pycolmap, CPU): features → matching → verification
with the known poses → triangulation with the poses held fixed (steps 1–4 of :mod:`gof_warp.data.sfm`).

:func:`_run` works in a temporary folder the caller owns (PNG copies of the images, COLMAP's SQLite
database, the output model) and returns an :class:`~gof_warp.data.sfm_config.SfmResult`; caching, input
checks and the public entry are in :mod:`gof_warp.data.sfm`.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path

import numpy as np

from ..core.camera import Camera
from ..core.scene import View
from .sfm_config import SfmConfig, SfmError, SfmResult
from .sfm_geometry import _fundamental, pose_pairs, sampson_distance

log = logging.getLogger("gof_warp.data.sfm")  # the logger of the public entry: one name for the whole stage

MIN_PAIR_MATCHES = 4  # fewer raw matches than this in a pair are mostly chance (ratio-test survivors)


def _import_pycolmap():
    """pycolmap, imported after Pillow's C module: with pycolmap's wheel loaded first, Pillow's PNG writer aborts the
    process ("double free", measured with pycolmap 4.2.1), so this process could no longer write its pictures."""
    import PIL.Image  # noqa: F401  (first: see above)

    try:
        import pycolmap
    except ImportError as e:
        raise SfmError(f"triangulating points from the known poses needs pycolmap, which cannot be imported here "
                       f"({e}); install it (`pip install pycolmap`), carry the scene's sfm_known_poses/ cache made "
                       "for the same views, or start from random points (model.init=random)") from e
    return pycolmap


@contextlib.contextmanager
def _quiet_colmap():
    """Keep COLMAP's (glog) INFO chatter off stderr while it runs; restore the level afterwards."""
    pycolmap = _import_pycolmap()

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(old, 1)
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _write_images(views: list[View], folder: Path) -> list[str]:
    from PIL import Image

    names = []
    for i, v in enumerate(views):
        name = f"{i:05d}.png"  # view names may repeat or hold path characters; ours are unique and flat
        Image.fromarray(v.image).save(folder / name, compress_level=1)
        names.append(name)
    return names


def _run(views: list[View], config: SfmConfig, work: Path, num_threads: int) -> SfmResult:
    pycolmap = _import_pycolmap()

    seconds: dict[str, float] = {}
    tick = time.perf_counter()

    def lap(stage):
        nonlocal tick
        now = time.perf_counter()
        seconds[stage] = round(now - tick, 3)
        tick = now

    image_dir, db_path, out_dir = work / "images", work / "database.db", work / "out"
    image_dir.mkdir()
    out_dir.mkdir()
    names = _write_images(views, image_dir)
    lap("write_images")

    n = len(views)
    log.info("sfm: SIFT on %d views (max side %d px, %d features)", n, config.max_image_size, config.max_features)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = config.max_image_size
    extraction.num_threads = num_threads
    extraction.sift.max_num_features = config.max_features
    reader = pycolmap.ImageReaderOptions(camera_model="PINHOLE")
    pycolmap.extract_features(db_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)  # fmt: skip
    db = pycolmap.Database.open(db_path)
    try:
        by_name = {im.name: im for im in db.read_all_images()}
        missing = [nm for nm in names if nm not in by_name]
        if missing:
            raise SfmError(f"COLMAP feature extraction skipped {len(missing)} image(s) (e.g. view {views[names.index(missing[0])].name!r})")
        image_ids = [by_name[nm].image_id for nm in names]
        camera_ids = [by_name[nm].camera_id for nm in names]
        for v, cid in zip(views, camera_ids):
            cam = db.read_camera(cid)
            c = v.camera
            cam.params = [c.fx, c.fy, c.cx, c.cy]
            cam.has_prior_focal_length = True
            db.update_camera(cam)
        features = [int(db.num_keypoints_for_image(i)) for i in image_ids]
    finally:
        db.close()
    lap("extract")

    mode = config.matching
    if mode == "auto":
        mode = "exhaustive" if n <= config.exhaustive_max_views else "pose"
    cams = [v.camera for v in views]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)] if mode == "exhaustive" else pose_pairs(cams, config.pose_neighbors)
    pairs_file = work / "pairs.txt"
    pairs_file.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    log.info("sfm: matching %d pairs (%s)", len(pairs), mode)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    matching.skip_geometric_verification = True
    matching.sift.max_ratio = config.max_ratio
    # COLMAP drops the matches of a pair with fewer than min_num_inliers even when it skips verification;
    # with known poses a pair with a handful of matches is still useful.
    verification = pycolmap.TwoViewGeometryOptions()
    verification.min_num_inliers = MIN_PAIR_MATCHES
    pycolmap.match_image_pairs(db_path, matching_options=matching,
                               pairing_options=pycolmap.ImportedPairingOptions(match_list_path=pairs_file),
                               verification_options=verification, device=pycolmap.Device.cpu)  # fmt: skip
    lap("match")

    # Verification against the known epipolar geometry (replaces RANSAC).
    db = pycolmap.Database.open(db_path)
    n_matches = n_inliers = n_verified = 0
    try:
        keypoints = [np.asarray(db.read_keypoints(i))[:, :2].astype(np.float64) for i in image_ids]
        for i, j in pairs:
            # columns: keypoint index in view i, in view j (pycolmap swaps stored pairs as needed)
            m = np.asarray(db.read_matches(image_ids[i], image_ids[j]), dtype=np.uint32).reshape(-1, 2)
            n_matches += len(m)
            if len(m) == 0:
                continue
            F = _fundamental(cams[i], cams[j])
            err = sampson_distance(F, keypoints[i][m[:, 0]], keypoints[j][m[:, 1]])
            inl = np.ascontiguousarray(m[err <= config.max_epipolar_error])
            if len(inl) == 0:
                continue
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            geometry.inlier_matches = inl
            geometry.F = F
            db.write_two_view_geometry(image_ids[i], image_ids[j], geometry)
            n_inliers += len(inl)
            n_verified += 1
    finally:
        db.close()
    lap("verify")
    if n_inliers == 0:
        raise SfmError(
            f"no feature matches agree with the known poses among {len(pairs)} pairs of {n} views "
            f"({n_matches} raw matches, {sum(features)} features): textureless images or wrong poses? "
            f"Use model.init=random instead"
        )

    log.info("sfm: triangulating %d verified matches in %d pairs", n_inliers, n_verified)
    rec = pycolmap.Reconstruction()
    db = pycolmap.Database.open(db_path)
    try:
        for k, c in enumerate(cams):
            rec.add_camera_with_trivial_rig(db.read_camera(camera_ids[k]))
            image = pycolmap.Image(name=names[k], camera_id=camera_ids[k], image_id=image_ids[k])
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(c.R), c.t))
    finally:
        db.close()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = num_threads
    options.ba_refine_focal_length = False
    options.ba_refine_principal_point = False
    options.ba_refine_extra_params = False
    options.min_num_matches = 1
    options.triangulation.ignore_two_view_tracks = config.min_track_length > 2
    options.triangulation.min_angle = config.min_triangulation_angle
    options.mapper.filter_min_tri_angle = config.min_triangulation_angle
    options.mapper.filter_max_reproj_error = max(config.max_reprojection_error, 1e-3)
    rec = pycolmap.triangulate_points(rec, db_path, image_dir, out_dir, clear_points=True, options=options,
                                      refine_intrinsics=False)  # fmt: skip
    lap("triangulate")

    _check_poses_unchanged(rec, image_ids, cams)
    pts = list(rec.points3D.values())
    raw = len(pts)
    keep = [p for p in pts if p.track.length() >= config.min_track_length and p.error <= config.max_reprojection_error]
    if not keep:
        raise SfmError(
            f"no points triangulated from {n} views ({n_inliers} verified matches, {raw} points before filtering "
            f"by track length >= {config.min_track_length} and reprojection error <= {config.max_reprojection_error} px); "
            f"use model.init=random instead"
        )
    points = np.array([p.xyz for p in keep], np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in keep], np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in keep], np.float64)
    errors = np.array([p.error for p in keep], np.float64)
    if config.max_points and len(points) > config.max_points:
        sel = np.sort(np.random.default_rng(0).choice(len(points), config.max_points, replace=False))
        points, colors, tracks, errors = points[sel], colors[sel], tracks[sel], errors[sel]
    stats = {
        "views": n,
        "matching": mode,
        "pairs": len(pairs),
        "pairs_verified": n_verified,
        "features": int(sum(features)),
        "features_per_view": round(sum(features) / n, 1),
        "matches": int(n_matches),
        "inlier_matches": int(n_inliers),
        "points_raw": raw,
        "points": int(len(points)),
        "mean_track_length": round(float(tracks.mean()), 3),
        "mean_reprojection_error_px": round(float(errors.mean()), 4),
        "seconds": seconds,
        "cached": False,
    }
    return SfmResult(points=points, colors=colors, stats=stats)


def _check_poses_unchanged(rec, image_ids: list[int], cams: list[Camera]) -> None:
    """Known poses are inputs: fail loudly if the triangulator's bundle adjustment moved any of them."""
    worst = 0.0
    for iid, c in zip(image_ids, cams):
        cfw = rec.images[iid].cam_from_world
        m = np.asarray((cfw() if callable(cfw) else cfw).matrix())
        worst = max(worst, float(np.abs(m[:, :3] - c.R).max()), float(np.abs(m[:, 3] - c.t).max() / max(1.0, np.abs(c.t).max())))
    if worst > 1e-6:
        raise SfmError(f"COLMAP changed the known camera poses during triangulation (by up to {worst:.3g})")
