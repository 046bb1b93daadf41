"""Bad inputs, tried as a new user would: each command must answer with one clear ``error:`` line (exit 2) or
a logged warning where going on is reasonable — never a traceback, a NaN or a silent success — and must not
overwrite what was already written.

Each case writes a tiny input under ``out/inputs/`` (scene folders of every format, Gaussian PLYs), runs a
command's ``main([...])`` in-process and reports:

* ``kind``: ``ply`` (extract on a broken model), ``scene`` (inspect on a broken scene folder), ``config`` or
  ``options`` (nonsense command options, an output path over an input);
* ``outcome``: ``"error"`` (exit 2 with an ``error:`` line), ``"warning"`` (exit 0 and a warning logged or
  listed by ``inspect``), ``"ok"`` (exit 0 and nothing said: a silent success), ``"crash"`` (an exception
  escaped, a traceback was printed, or another exit code);
* ``expected`` and ``as_expected``; ``nan_inf`` (a written mesh with non-finite vertices); ``kept``
  (``False`` when a file that existed before the command was changed by a failing command).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import traceback
from pathlib import Path

import numpy as np

from .stability_scenes import _blob, ring_cameras

SIZE = 32  # pixels: the readers' and the commands' logic is under test, not decoding speed
HUGE_LOG_SCALE = 50.0  # scale e^50: its square overflows float32 (a diverged model)
TINY_SCALE = 1e-12


# ----------------------------------------------------------------------------------------- input writers
def _images(folder: Path, names, seed: int = 0) -> None:
    from PIL import Image

    rng = np.random.default_rng(seed)
    for n in names:
        (folder / n).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)).save(folder / n)


def _gl_c2w(cam) -> list:
    m = cam.c2w.copy()
    m[:3, 1:3] *= -1.0  # OpenCV → OpenGL camera axes
    return m.tolist()


def write_transforms(folder: Path, cams, file_name: str = "transforms_train.json", edit=None) -> Path:
    """A Blender (``transforms_train.json``) or instant-ngp (``transforms.json``) folder; ``edit(frames)``
    may break the frames before they are written."""
    c = cams[0]
    frames = [{"file_path": f"images/{k.name}.png", "transform_matrix": _gl_c2w(k)} for k in cams]
    if edit is not None:
        edit(frames)
    _images(folder, [f["file_path"] for f in frames])
    top = {"fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": c.width, "h": c.height}
    (folder / file_name).write_text(json.dumps({**top, "frames": frames}))
    return folder


def write_dtu(folder: Path, cams, zero_view: int) -> Path:
    """NeuS/IDR ``cameras_sphere.npz`` + ``image/``; ``world_mat_<zero_view>`` is all zeros."""
    mats = {}
    for i, c in enumerate(cams):
        world = np.eye(4)
        world[:3] = c.K @ np.hstack([c.R, c.t[:, None]])
        mats[f"world_mat_{i}"] = np.zeros((4, 4)) if i == zero_view else world
        mats[f"scale_mat_{i}"] = np.eye(4)
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "cameras_sphere.npz", **mats)
    _images(folder / "image", [f"{i:06d}.png" for i in range(len(cams))])
    return folder


def write_colmap(folder: Path, cams, zero_view: int) -> Path:
    """A COLMAP text model (one PINHOLE camera, no points) + ``images/``; image ``zero_view`` has quaternion 0."""
    from scipy.spatial.transform import Rotation

    c = cams[0]
    model = folder / "sparse" / "0"
    model.mkdir(parents=True, exist_ok=True)
    (model / "cameras.txt").write_text(f"1 PINHOLE {c.width} {c.height} {c.fx} {c.fy} {c.cx} {c.cy}\n")
    lines = []
    for i, k in enumerate(cams):
        x, y, z, w = Rotation.from_matrix(k.R).as_quat()
        q = (0.0, 0.0, 0.0, 0.0) if i == zero_view else (w, x, y, z)
        lines += [f"{i + 1} {' '.join(map(str, q))} {' '.join(map(str, k.t))} 1 {k.name}.png", ""]
    (model / "images.txt").write_text("\n".join(lines) + "\n")
    (model / "points3D.txt").write_text("")
    _images(folder / "images", [f"{k.name}.png" for k in cams])
    return folder


def write_ply(path: Path, which: str) -> Path:
    """Gaussian PLYs: ``huge`` (every log-scale 50), ``some_huge`` (the stability blob, 20 of them log-scale
    50), both with a 3D filter as training writes them; ``tiny`` (every scale 1e-12, no filter)."""
    import torch

    from ..core.model import Gaussians

    m, q, s, o = _blob()
    if which == "tiny":
        s = np.full_like(s, TINY_SCALE)
    g = Gaussians.from_activated(m, q, s, o, np.full((len(m), 3), 0.5), device="cpu")
    with torch.no_grad():
        if which == "huge":
            g.params["log_scales"][:] = HUGE_LOG_SCALE
        elif which == "some_huge":
            g.params["log_scales"][:20] = HUGE_LOG_SCALE
        if which != "tiny":  # a filter would widen the tiny ones (and fade them out)
            g.filter_3d = torch.full((len(g),), 1e-3)
    path.parent.mkdir(parents=True, exist_ok=True)
    g.save_ply(path)
    return path


# ----------------------------------------------------------------------------------------- running a command
class _Warnings(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def run_cli(main, argv, watch: Path | None = None) -> dict:
    """Run ``main(argv)`` in-process: ``{outcome, rc, message, warnings, kept}`` (see the module docstring)."""
    before = watch.read_bytes() if watch is not None and watch.is_file() else None
    handler, err, out = _Warnings(), io.StringIO(), io.StringIO()
    logging.getLogger().addHandler(handler)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = main([str(a) for a in argv])
    except BaseException as e:  # noqa: BLE001 — an escaped exception is exactly what this reports
        rc, tb = None, f"{type(e).__name__}: {e}\n{traceback.format_exc()}"
    else:
        tb = err.getvalue() if "Traceback" in err.getvalue() else None
    finally:
        logging.getLogger().removeHandler(handler)
    warnings = list(handler.messages)
    try:  # inspect --json lists the scene's warnings on stdout
        warnings += [w for w in json.loads(out.getvalue()).get("warnings", []) if not any(w in m for m in warnings)]
    except (ValueError, AttributeError):
        pass
    errors = [ln[len("error: "):] for ln in err.getvalue().splitlines() if ln.startswith("error: ")]
    if tb is not None or rc not in (0, 2) or (rc == 2 and len(errors) != 1):
        outcome, message = "crash", (tb or f"exit code {rc}; stderr: {err.getvalue()[-500:]}").strip().splitlines()[-1]
    elif rc == 2:
        outcome, message = "error", errors[0]
    else:
        outcome, message = ("warning" if warnings else "ok"), "; ".join(warnings) or None
    kept = None if before is None else watch.is_file() and watch.read_bytes() == before
    return {"outcome": outcome, "rc": rc, "message": message, "warnings": warnings, "kept": kept}


def _mesh_nan(path: Path) -> bool:
    if not path.is_file():
        return False
    import trimesh

    v = np.asarray(trimesh.load(path, process=False, force="mesh").vertices)
    return bool(len(v)) and not bool(np.isfinite(v).all())


# ----------------------------------------------------------------------------------------- the cases
def _cases(root: Path):
    """``(name, kind, expected, needle, thunk)``: the outcome expected, a text its message must contain, and a
    thunk that writes the input and returns :func:`run_cli`'s report."""
    from ..cli import extract
    from ..cli import inspect_scene as inspect
    from ..cli import train

    cams = ring_cameras(8, SIZE)
    scene = root / "scene"
    if not scene.is_dir():
        write_transforms(scene, cams)

    def zero(k):
        return lambda frames: frames[k].update(transform_matrix=np.zeros((4, 4)).tolist())

    def same(frames):
        for f in frames:
            f["transform_matrix"] = frames[0]["transform_matrix"]

    def inspect_case(write, *args):
        def go(name):
            return {"method": "inspect", **run_cli(inspect.main, [write(root / name), "--json", *args])}
        return go

    def extract_case(which, method, existing=False):
        def go(name):
            ply = write_ply(root / f"{which}.ply", which)
            mesh = root / f"{name}.ply"
            if existing:
                mesh.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")  # a mesh made earlier
            argv = [ply, "--scene", scene, "--method", method, "--out", mesh, "--resolution", 32, "--binary-steps", 2,
                    "--no-pictures", "--quiet"]
            r = {"method": f"extract --method {method}", **run_cli(extract.main, argv, watch=mesh if existing else None)}
            r["nan_inf"] = _mesh_nan(mesh) if r["outcome"] != "error" else False
            return r
        return go

    yield "zero_c2w_blender", "scene", "error", "transforms_train.json frame 2", inspect_case(
        lambda p: write_transforms(p, cams, edit=zero(2)))
    yield "zero_c2w_ingp", "scene", "error", "transforms.json frame 1", inspect_case(
        lambda p: write_transforms(p, cams, "transforms.json", edit=zero(1)))
    yield "zero_world_mat_dtu", "scene", "error", "world_mat_3", inspect_case(lambda p: write_dtu(p, cams, 3))
    yield "zero_quaternion_colmap", "scene", "error", "images.txt (image s01.png)", inspect_case(
        lambda p: write_colmap(p, cams, 1))
    yield "single_view", "scene", "warning", "only 1 training view", inspect_case(
        lambda p: write_transforms(p, cams[:1]), "--test-every", 0)
    yield "identical_cameras", "scene", "warning", "no parallax", inspect_case(
        lambda p: write_transforms(p, cams, edit=same))
    for method in ("cubes", "tsdf", "tetra"):
        yield f"huge_scales_{method}", "ply", "error", "scales too large", extract_case("huge", method)
        yield f"tiny_scales_{method}", "ply", "error", "no surface crosses", extract_case("tiny", method, existing=True)
    yield "some_huge_scales_cubes", "ply", "warning", "left out of the mesh", extract_case("some_huge", "cubes")
    for case, arg in (("iterations_negative", ["--iterations", -5]), ("iterations_override_0", ["iterations=0"])):
        yield case, "config", "error", "iterations must be", lambda name, arg=arg: {
            "method": "train", **run_cli(train.main, [scene, "--out", root / name, "--quiet", *arg])}

    # ---- scene files that point elsewhere or are no plain files, oversized headers, bad matrices and camera files
    def outside(frames):
        frames[1]["file_path"] = "../../outside.png"

    def strings(frames):
        frames[2]["transform_matrix"] = [["a", "b", "c", "d"]] * 4

    def fifo_image(p):
        import os

        write_colmap(p, cams, zero_view=-1)
        first = p / "images" / f"{cams[0].name}.png"
        first.unlink()
        os.mkfifo(first)
        return p

    def bomb_image(p):
        import struct
        import zlib

        def chunk(kind, data):
            return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
        write_colmap(p, cams, zero_view=-1)
        (p / "images" / f"{cams[0].name}.png").write_bytes(
            b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 16)) + chunk(b"IEND", b""))
        return p

    def npy_cameras(p):
        write_dtu(p, cams, zero_view=-1)
        with open(p / "cameras_sphere.npz", "wb") as f:
            np.save(f, np.eye(4))
        return p

    def stale_bin(p):
        import os

        from ..data.colmap_model import read_model

        write_colmap(p, cams, zero_view=-1)
        model = p / "sparse" / "0"
        rec = read_model(model)  # the same model as a .bin, 100 s older than its .txt
        with open(model / "cameras.bin", "wb") as f:
            f.write(np.uint64(len(rec.cameras)).tobytes())
            for cid, c in rec.cameras.items():
                f.write(np.int32(cid).tobytes() + np.int32(1).tobytes() + np.uint64(c.width).tobytes()
                        + np.uint64(c.height).tobytes() + np.asarray(c.params, "<f8").tobytes())
        t = (model / "cameras.txt").stat().st_mtime
        os.utime(model / "cameras.bin", (t - 100, t - 100))
        return p

    yield "path_outside_scene_ingp", "scene", "error", "outside the scene folder", inspect_case(
        lambda p: write_transforms(p, cams, "transforms.json", edit=outside))
    yield "transform_matrix_strings", "scene", "error", "transforms_train.json frame 2", inspect_case(
        lambda p: write_transforms(p, cams, edit=strings))
    yield "fifo_image_colmap", "scene", "error", "not a regular file", inspect_case(fifo_image)
    yield "header_20000x20000_colmap", "scene", "error", "megapixels", inspect_case(bomb_image)
    yield "npy_as_npz_dtu", "scene", "error", "cameras_sphere.npz", inspect_case(npy_cameras)
    yield "stale_bin_colmap", "scene", "warning", "cameras.txt beside it is newer", inspect_case(stale_bin)

    def micro(frames):  # the scene at 1e-6 of its size: float32 tolerances are larger than it
        for f in frames:
            for r in range(3):
                f["transform_matrix"][r][3] *= 1e-6

    yield "scene_at_1e-6_scale", "scene", "error", "data.scale=", inspect_case(
        lambda p: write_transforms(p, cams, edit=micro))

    # ---- config files: not UTF-8, nested too deeply
    for case, content in (("config_latin1", b"iterations: 5\n# caf\xe9\n"), ("config_deep", b"[" * 3_000_000)):
        def go(name, content=content):
            path = root / f"{name}.yaml"
            path.write_bytes(content)
            return {"method": "train", **run_cli(train.main, [scene, "--out", root / name, "--quiet", "--config", path])}
        yield case, "config", "error", f"{case}.yaml", go


    # ---- extract and evaluate options that made silent or wrong outputs, and outputs over the inputs
    from ..cli import evaluate

    def extract_args(name, *args, out=None, watch=None):
        def go(_):
            ply = write_ply(root / "good.ply", "good")
            target = root / f"{name}.ply" if out is None else out(ply)
            argv = [ply, "--scene", scene, "--out", target, "--binary-steps", 2, "--no-pictures", "--quiet", *args]
            return {"method": "extract " + " ".join(map(str, args)),
                    **run_cli(extract.main, argv, watch=ply if watch else None)}
        return go

    for case, args, needle in (("resolution_0", ["--method", "cubes", "--resolution", 0], "--resolution"),
                               ("resolution_negative", ["--method", "cubes", "--resolution", -5], "--resolution"),
                               ("volume_with_method", ["--volume", "--method", "tsdf"], "--volume"),
                               ("levels_repeated", ["--levels", 0.5, 0.5], "--levels"),
                               ("binary_steps_1000", ["--binary-steps", 1000], "--binary-steps")):
        yield case, "options", "error", needle, extract_args(case, *args)
    yield "extract_out_over_the_model", "options", "error", "", extract_args(
        "over_model", out=lambda ply: ply, watch=True)

    def camera_inside(name):  # one more camera at the centre of the good model's shell, looking out
        from ..core.camera import look_at

        inner = look_at([0.0, 0.0, 0.0], [1.0, 0.0, 0.1], fx=0.9 * SIZE, width=SIZE, height=SIZE, name="inside")
        folder = write_transforms(root / name, [*cams[:3], inner, *cams[3:]])  # a training view (not every 8th)
        argv = [write_ply(root / "good.ply", "good"), "--scene", folder, "--out", root / f"{name}.ply",
                "--binary-steps", 2, "--no-pictures", "--quiet"]
        return {"method": "extract", **run_cli(extract.main, argv)}
    yield "camera_inside_the_object", "scene", "warning", "inside what the other views see as solid", camera_inside

    def empty_mesh(name):
        mesh = root / f"{name}.ply"
        mesh.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                         b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
        gt = write_ply(root / "good.ply", "good")
        return {"method": "evaluate", **run_cli(evaluate.main, ["--mesh", mesh, "--gt", gt])}
    yield "evaluate_mesh_without_faces", "options", "error", "has no faces", empty_mesh
    yield "render_near_negative", "config", "error", "render.near", lambda name: {
        "method": "train", **run_cli(train.main, [scene, "--out", root / name, "--quiet", "render.near=-1"])}


def run_input_cases(out) -> list[dict]:
    """Every bad-input case (see the module docstring); inputs are written under ``out/inputs``."""
    root = Path(out) / "inputs"
    root.mkdir(parents=True, exist_ok=True)
    reports = []
    for name, kind, expected, needle, go in _cases(root):
        try:
            r = go(name)
        except Exception as e:  # noqa: BLE001 — writing the input itself failed: a bug of this module
            r = {"outcome": "crash", "rc": None, "message": f"writing the input: {type(e).__name__}: {e}"}
        r = {"case": name, "kind": kind, "method": "", "expected": expected, "nan_inf": False, "kept": None, **r}
        r["as_expected"] = (r["outcome"] == expected and needle in (r["message"] or "") and r["kept"] is not False
                            and not r["nan_inf"])
        reports.append(r)
    return reports


def summarise(model_reports: list[dict], input_reports: list[dict]) -> dict:
    """Counts per kind tried (``model`` = the hand-made model cases × methods): ok, clear errors, warnings,
    crashes (must be 0), NaN/inf (must be 0), and for bad inputs the unexpected outcomes and lost files."""
    out: dict = {}
    for r in [{**r, "kind": "model"} for r in model_reports] + input_reports:
        s = out.setdefault(r["kind"], {"tried": 0, "ok": 0, "error": 0, "warning": 0, "crash": 0, "nan_inf": 0})
        s["tried"] += 1
        s[r["outcome"]] = s.get(r["outcome"], 0) + 1
        s["nan_inf"] += bool(r.get("nan_inf"))
        if "as_expected" in r:
            s["unexpected"] = s.get("unexpected", 0) + (not r["as_expected"])
            s["overwritten"] = s.get("overwritten", 0) + (r.get("kept") is False)
    return out
