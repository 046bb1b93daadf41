#!/usr/bin/env bash
# The collision mesh of the README job's run (built-in default scene, 1,200 iterations on the CPU), checked and
# scored against the scene's exact mesh. Writes benchmarks/collision/results_default_scene_cpu.json and
# RUN/mesh_tetra.usd + RUN/mesh_collision.ply (the command's own output, with the USD stage).
set -euo pipefail
RUN=${1:-runs/default}
[ -f "$RUN/point_cloud.ply" ] || python -m gof_warp.train --out "$RUN"
python -m gof_warp.extract "$RUN" --binary-steps 4 --collision --format usd --no-pictures
python -c "
import sys; from pxr import Usd, UsdGeom; import numpy as np
from gof_warp.mesh.extraction import save_mesh
m = UsdGeom.Mesh(Usd.Stage.Open(sys.argv[1] + '/mesh_tetra.usd').GetPrimAtPath('/World/mesh'))
save_mesh(sys.argv[1] + '/mesh_tetra.ply', np.array(m.GetPointsAttr().Get(), np.float32),
          np.array(m.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3))" "$RUN"
python benchmarks/collision/bench_collision.py "$RUN" --resolution 64 128 192 --faces 5000 20000
# Thin structures (results_thin_scene_cpu.json):
#   python -m gof_warp.synthetic --preset thin --out THIN_SCENE --device cpu
#   python -m gof_warp.train THIN_SCENE --out THIN --config quick
#   python -m gof_warp.extract THIN --binary-steps 4 --collision --no-pictures
#   python benchmarks/collision/bench_collision.py THIN --gt THIN_SCENE/gt_mesh.ply --resolution 128 256 \
#       --faces 20000 --out benchmarks/collision/results_thin_scene_cpu.json
