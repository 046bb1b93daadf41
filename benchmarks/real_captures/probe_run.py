"""``probe_run.py SCENE RUN OUT.json``: the ground probe (:mod:`ground_probe`) of a trained run on a synthetic
scene with a ground plane (its ``scene.json`` ``ground`` entry)."""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ground_probe import probe, seen_ground_columns, summarise  # noqa: E402


def main(scene: str, run: str, out: str) -> int:
    import torch

    from gof_warp.extract import load_run

    scene_dir = Path(scene)
    ground_z = float(json.loads((scene_dir / "scene.json").read_text())["ground"]["height"])
    xy, _ = seen_ground_columns(scene_dir, ground_z=ground_z, half=2.4)
    g, cams, _, rc = load_run(Path(run), None, "cuda" if torch.cuda.is_available() else "cpu")
    result = {"ground_z": ground_z, "half_size": 2.4, "spacing": 0.025, **summarise(xy, probe(g, cams, xy, ground_z,
                                                                                           render_config=rc))}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(result, indent=1))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:4]))
