"""Run the torch-free Warp examples on one device and time them: the figures of ``results_examples_*.json``.

    python benchmarks/warp_embedding/run_examples.py --device cuda:0 [--nvdb RUN/opacity_volume.nvdb] \
        [--size small|large] --out results.json

Each example runs in its own Python process (as a user runs it), twice: the first call includes Warp's kernel
compilation or cache load, the second is the warm figure. The child reports the example's own result dict,
both wall times and whether ``torch`` entered ``sys.modules`` (it must not). ``--size small`` uses the CI
sizes; ``large`` the sizes a GPU is for. Writes one JSON object naming the machine.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"


def example_runs(size: str, nvdb: str | None, out: Path) -> list[tuple[str, list[str]]]:
    """``[(example file stem, argv)]`` for one size; the volume examples use ``nvdb`` when given."""
    large = size == "large"
    vol = ["--nvdb", nvdb] if nvdb else []
    return [
        ("warp_tape_render", ["--num", "20000", "--width", "800", "--height", "600"] if large else []),
        ("warp_fit_gaussians", ["--num", "2000", "--target", "500", "--views", "8", "--size", "256",
                                "--iterations", "300"] if large else []),
        ("warp_marching_gyroid", ["--resolution", "160" if large else "40", "--out", str(out / "gyroid")]),
        ("warp_query_volume", vol + (["--points", str(1 << 24), "--repeats", "20"] if large else [])),
        ("warp_particles_on_scene", vol + ["--out", str(out / "particles")]
         + (["--particles", "200000", "--steps", "800"] if large else [])),
    ]


def run_one(stem: str, argv: list[str]) -> dict:
    """In the child: import the example from its file, call ``main(argv)`` twice, report times and result."""
    spec = importlib.util.spec_from_file_location(stem, EXAMPLES / f"{stem}.py")
    module = importlib.util.module_from_spec(spec)
    t0 = time.perf_counter()
    spec.loader.exec_module(module)
    import_s = time.perf_counter() - t0
    times, result = [], None
    for _ in range(2):
        t0 = time.perf_counter()
        result = module.main(argv)
        times.append(time.perf_counter() - t0)
    return {"import_s": import_s, "first_call_s": times[0], "warm_call_s": times[1], "result": result,
            "torch_imported": "torch" in sys.modules}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="Warp device passed to every example (default: theirs)")
    ap.add_argument("--nvdb", default=None, help="a baked opacity volume for the two volume examples")
    ap.add_argument("--size", choices=("small", "large"), default="small")
    ap.add_argument("--work", default="/tmp/warp_examples", help="folder for the examples' outputs")
    ap.add_argument("--out", default="results_examples.json")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # child mode: an example's stem
    args, rest = ap.parse_known_args(argv)
    if args.one:
        rest = rest[1:] if rest[:1] == ["--"] else rest
        print("RESULT " + json.dumps(run_one(args.one, rest), default=str))
        return 0
    import warp as wp

    wp.init()
    device = wp.get_device(args.device)
    work = Path(args.work)
    rows = {}
    for stem, ex_argv in example_runs(args.size, args.nvdb, work):
        ex_argv = ex_argv + (["--device", args.device] if args.device else [])
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, __file__, "--one", stem, "--", *ex_argv], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        lines = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
        if p.returncode != 0 or not lines:
            rows[stem] = {"argv": ex_argv, "returncode": p.returncode, "error": (p.stderr or p.stdout)[-2000:]}
        else:
            rows[stem] = {"argv": ex_argv, "process_wall_s": wall, **json.loads(lines[-1][len("RESULT "):])}
        print(stem, json.dumps(rows[stem], default=str)[:600], flush=True)
    out = {
        "machine": {"device": device.name if device.is_cuda else platform.processor() or "cpu",
                    "warp_device": str(device), "warp": wp.config.version, "python": platform.python_version(),
                    "platform": platform.platform()},
        "size": args.size, "nvdb": args.nvdb, "examples": rows,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, default=str))
    failed = [k for k, v in rows.items() if "error" in v or v.get("torch_imported")]
    print(f"wrote {args.out}; failed or imported torch: {failed or 'none'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
