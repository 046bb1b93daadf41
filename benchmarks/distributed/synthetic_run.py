"""A run folder (``point_cloud.ply`` + ``cameras.json``) of N synthetic Gaussians for extraction benchmarks that go
through the ``extract`` command, e.g. under torchrun (issue 17: a 3M-Gaussian model on 1 and 2 GPUs).

The Gaussians are ``benchmarks/extract/bench_extract.py``'s: a random subset of the 54,275 real trained Gaussians of
``../shared/data/gaussians_54k.npz`` (``--data``), or copies of them jittered by one σ beyond 54k, with opacities
uniform in [0.05, 1]; the cameras are its ring of ``--views`` cameras looking at the scene's centre.

    python benchmarks/distributed/synthetic_run.py 3000000 --out /tmp/run3m --data .bgdata/gaussians_54k.npz
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "extract"))
from bench_extract import ring_cameras, synthetic_model  # noqa: E402
from bench_marching import DEFAULT_DATA  # noqa: E402

from gof_warp.core.io_utils import write_json_atomic  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("gaussians", type=int)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--views", type=int, default=48)
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    a = ap.parse_args(argv)
    if a.gaussians < 1:
        ap.error("gaussians must be at least 1")
    gaussians, source = synthetic_model(a.gaussians, a.data, "cpu")
    cams = ring_cameras(gaussians.means.detach().numpy(), a.views, a.width, a.height)
    a.out.mkdir(parents=True, exist_ok=True)
    gaussians.save_ply(a.out / "point_cloud.ply")
    write_json_atomic(a.out / "cameras.json", {"convention": "world-to-camera, OpenCV axes", "source": source,
                                               "train": [c.to_dict() for c in cams], "test": []})
    print(f"wrote {a.out}: {len(gaussians)} Gaussians from {source}, {len(cams)} cameras")
    return 0


if __name__ == "__main__":
    sys.exit(main())
