# On the GPU machine (after benchmarks/extract/dtu_model.sh): the DTU model meshed on the Delaunay grid and on the
# octree grid at each cell factor in $FACTORS (default "0.7 0.5"), each with the extract CLI (per-stage JSON and the
# mesh picture), then each octree mesh scored against the Delaunay mesh inside the object's box (compare_in_box.py).
FACTORS=${FACTORS:-"0.7 0.5"}
SCENE=${SCENE:-/tmp/gofdata/dtu_scan24}
R=$OUT/octree_dtu; mkdir -p $R
run_extract() {  # name, extra args
  local name=$1; shift
  python3 -m gof_warp.extract $EX/dtu.ply --scene $SCENE --out $EX/$name.ply --quiet "$@" 2>&1 | grep -v "^Module" | tail -3
  cp $EX/$name.json $R/$name.json
  [ -f $EX/pictures/mesh_$name.png ] && cp $EX/pictures/mesh_$name.png $R/
}
[ -n "$SKIP_DELAUNAY" ] || [ -f $EX/delaunay.ply ] || run_extract delaunay --grid delaunay
for f in $FACTORS; do  # F or F:O (cell factor F, --opacity-min O)
  name=octree_x${f/:/_o}; args="--grid octree --cell-factor ${f%%:*}"
  [ "${f#*:}" != "$f" ] && args="$args --opacity-min ${f#*:}"
  run_extract $name $args
  [ -f $EX/delaunay.ply ] && python3 benchmarks/extract/compare_in_box.py $EX/$name.ply $EX/delaunay.ply \
      --box -1 -1 -1 1 1 1 --out $R/compare_$name.json | cut -c1-900
done
