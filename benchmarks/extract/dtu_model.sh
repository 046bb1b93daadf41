# Source on the GPU machine: joins the packed halves of the trained DTU scan 24 model (/tmp/dtugeo/*.npz,
# carried in .dtugeo_a/.dtugeo_b; see pack_model.py) into the PLY $EX/dtu.ply (once per warm machine).
EX=${EX:-/tmp/ex}; mkdir -p $EX
if [ ! -f $EX/dtu.ply ] && ls /tmp/dtugeo/*.part0.npz >/dev/null 2>&1; then  # row parts (pack_model.py now)
  python3 benchmarks/extract/pack_model.py unpack "$(ls /tmp/dtugeo/*.part0.npz | head -1)" $EX/dtu.ply
fi
if [ ! -f $EX/dtu.ply ]; then  # the column halves of sessions 9-16
  python3 -c "
import numpy as np, glob
z = {}
for f in sorted(glob.glob('/tmp/dtugeo/*.npz')): z.update(dict(np.load(f)))
np.savez('$EX/dtu_geometry.npz', **z)"
  python3 benchmarks/extract/pack_model.py unpack $EX/dtu_geometry.npz $EX/dtu.ply
fi
