"""CUDA check of the loss-spike census (tests/test_spike_report.py's trainer case, on the GPU) and its cost at 190k
Gaussians. Run on the GPU machine from the repository root; its recorded output is
results/s12_census_cost_h200.json:   python3 benchmarks/real_captures/census_cost.py
"""
import sys, time, torch
sys.path.insert(0, "tests")
from gof_warp.config import merge
from gof_warp.data import load_scene
from gof_warp.loss_monitor import LossSpikeMonitor
from gof_warp.near_camera import near_camera_census
from gof_warp.step_scalars import IterationScalars
from gof_warp.synthetic import make_scene
from gof_warp.trainer import TrainConfig, Trainer
from test_train import TINY
scene = load_scene(make_scene("default", "/tmp/smoke/s", views=6, resolution=(64, 64), device="cuda:0"), device="cuda")
t = Trainer(scene, merge(TrainConfig(), TINY), "/tmp/smoke/run", "cuda")
for _ in range(3):
    t.step()
cam = t.cameras[2]
with torch.no_grad():
    t.gaussians.params["means"][0] = torch.tensor(cam.center + 0.3 * cam.R[2], dtype=torch.float32, device="cuda")
t.spikes = LossSpikeMonitor(warmup=0)
for it in range(1, 6):
    v = 40.0 if it == 5 else 1.0
    t._pending.add(IterationScalars(it, cam.name, len(t.gaussians), False, 0.0, {}),
                   {"total": torch.tensor(v, device="cuda"), "l1": torch.tensor(v, device="cuda")})
t._drain()
print("event", t.spikes.report()["view_spikes"])
m = torch.randn(190000, 3, device="cuda") * 3
o = torch.rand(190000, device="cuda"); s = torch.rand(190000, 3, device="cuda")
near_camera_census(m, o, s, cam, within=1.0); torch.cuda.synchronize()
t0 = time.perf_counter()
for _ in range(10):
    c = near_camera_census(m, o, s, cam, within=1.0)
torch.cuda.synchronize()
print("census ms at 190k", (time.perf_counter() - t0) * 100, c["count"])
