"""How much of a synthetic scene's seen GT lies at which height, per part, with every part occluding:
``seen_shell_census.py SCENE``. Splits the GT as region scoring does (1 % of the diagonal), ray-casts the training
cameras (:func:`gof_warp.region_metrics.observe`), and prints the seen area per part and the seen shell's area in
height bands. Session 17 ran it on `background_detail` at 96×96 (100 views) to see how much of the seen shell lies
below the lines `shell_profile.py` samples (z > ground + 0.4): 21.3 m² below the ground's height, 14.7 m² within
0.4 above it, of 134.1 m²."""
import sys
from pathlib import Path

from gof_warp.region_metrics import _soup, _triangle_areas, observe
from off_view_count import scene_parts  # same folder

cams, scene, names, tri, lab = scene_parts(Path(sys.argv[1]))
obs = observe(*_soup(tri), cams)
a = _triangle_areas(tri)
print("seen area, all parts", a[obs.seen].sum().round(1), {n: round(float(a[obs.seen & (lab == k)].sum()), 1) for k, n in enumerate(names)})
m0 = obs.seen & (lab == names.index("shell")); z = tri.mean(1)[:, 2]
for lo, hi in ((-9, -0.9), (-0.9, -0.5), (-0.5, 1.0), (1.0, 2.0), (2.0, 9)):
    m = m0 & (z >= lo) & (z < hi); print(f"seen shell, z in [{lo},{hi}): {a[m].sum():.1f} m2")
