"""The viewer's page in a headless Chromium, showing a real run's photo-coloured GLB mesh from the start camera.

    python benchmarks/browser/viewer_coloured_mesh.py RUN [--out benchmarks/browser] [--max-size 256]

RUN: a training run folder (e.g. the README job's ``runs/default``). When it has no ``mesh_*.glb`` the mesh is
extracted first as the README job does, coloured from the photos (``python -m gof_warp.extract RUN --binary-steps 4
--color photos --format glb``, which also writes ``RUN/pictures/mesh_tetra.png``). Then ``python -m gof_warp.view RUN
--screenshot`` takes the page: the newest mesh (the GLB) shown from the start, over our render, at the training
camera the viewer opens at. Writes to ``--out``: ``viewer_<run>_glb.png`` (the page, 1200x800),
``pictures_<run>_glb.png`` (the run's pictures with the coloured-mesh column, when present) and
``viewer_<run>_glb.json`` (the mesh, the start camera, the Chromium and the seconds each step took).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("--out", default=str(Path(__file__).parent))
    ap.add_argument("--max-size", type=int, default=256)
    ap.add_argument("--device", default="cpu")
    a = ap.parse_args(argv)

    from gof_warp.cli.view import find_chromium
    from gof_warp.viz.mesh_files import find_mesh, load_mesh_file

    run, out = Path(a.run), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    chromium = find_chromium()
    if chromium is None:
        print("no Chromium: apt-get install chromium-headless-shell", file=sys.stderr)
        return 2
    from gof_warp.core.config import load_yaml

    config = load_yaml(run / "config.yaml") if (run / "config.yaml").is_file() else {}
    record = {"run": run.name, "iterations": config.get("iterations"), "machine": platform.node(),
              "cpus": os.cpu_count(), "python": platform.python_version()}
    if not list(run.glob("mesh_*.glb")):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "gof_warp.extract", str(run), "--binary-steps", "4", "--color", "photos",
                        "--format", "glb", "--device", a.device], check=True)
        record["extract_s"] = round(time.perf_counter() - t0, 1)
    mesh_path = find_mesh(run)
    mesh = load_mesh_file(mesh_path)
    record["mesh"] = {"file": mesh_path.name, "bytes": mesh_path.stat().st_size, "vertices": len(mesh.vertices),
                      "faces": len(mesh.faces), "colours": mesh.appearance}
    png = out / f"viewer_{run.name}_glb.png"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gof_warp.view", str(run), "--device", a.device, "--max-size",
                    str(a.max_size), "--port", "0", "--screenshot", str(png)], check=True)
    record["screenshot_s"] = round(time.perf_counter() - t0, 1)
    record["screenshot"] = png.name
    pictures = run / "pictures" / f"{mesh_path.stem}.png"
    if pictures.is_file():
        shutil.copyfile(pictures, out / f"pictures_{run.name}_glb.png")
        record["pictures"] = f"pictures_{run.name}_glb.png"
    record["start_camera"] = start_camera_name(run, a.device)
    version = subprocess.run([chromium, "--version"], capture_output=True, text=True)
    record["chromium"] = (version.stdout or version.stderr).strip()
    (out / f"viewer_{run.name}_glb.json").write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record, indent=2))
    return 0


def start_camera_name(run: Path, device: str) -> str:
    """The name of the training camera the viewer opens at for ``run``."""
    from gof_warp.viz.viewer import open_run

    viewer = open_run(run, device=device, mesh_path=False)
    return viewer.cameras[viewer.start_index].name


if __name__ == "__main__":
    sys.exit(main())
