# On the GPU machine, after gpu_queue.py has trained a synthetic scene $S (garden or background) in --state $ST: mesh
# the run on the Delaunay grid and on the octree grid at each factor in $FACTORS, and score each mesh as the queue
# does (seen region, ground-and-objects crop). Results in $OUT/octree_$S, packed into one file (the device tool
# brings back only a few files per call).
S=${S:-garden}; ST=${ST:-/tmp/rc}; FACTORS=${FACTORS:-"0.7 0.5"}  # F or F:O (cell factor F, --opacity-min O); SKIP_DELAUNAY=1 skips the reference
RUN=$ST/run_$S; SCENE=$ST/$S; R=$OUT/octree_$S; mkdir -p $R
CROP=$(python3 -c "import sys; sys.path.insert(0, 'benchmarks/real_captures'); from gpu_queue import CROPS; print(*CROPS['$S'])")
for f in $([ -n "$SKIP_DELAUNAY" ] || echo delaunay) $FACTORS; do
  if [ $f = delaunay ]; then name=delaunay; args="--grid delaunay"
  else name=octree_x${f/:/_o}; args="--grid octree --cell-factor ${f%%:*}"; [ "${f#*:}" != "$f" ] && args="$args --opacity-min ${f#*:}"; fi
  python3 -m gof_warp.extract $RUN $args --out $RUN/$name.ply --quiet 2>&1 | grep -v "^Module" | tail -2
  cp $RUN/$name.json $R/$name.json; cp $RUN/pictures/mesh_$name.png $R/ 2>/dev/null
  python3 -m gof_warp.evaluate --mesh $RUN/$name.ply --gt $SCENE/gt_mesh.ply --scene $SCENE --json $R/${name}_evaluate_seen.json > /dev/null
  python3 -m gof_warp.evaluate --mesh $RUN/$name.ply --gt $SCENE/gt_mesh.ply --scene $SCENE --crop $CROP --json $R/${name}_evaluate_crop.json > /dev/null
done
python3 - <<PY
import json, glob
for f in sorted(glob.glob("$R/*_evaluate_*.json")):
    m = json.load(open(f))["metrics"]
    print(f.split("/")[-1], round(m["chamfer"], 5), [round(x, 4) for x in m["fscore"]])
PY
tar czf $OUT/octree_$S.tgz -C $OUT octree_$S && rm -rf $R
