#!/usr/bin/env bash
# Extraction variants on the trained DTU scan 24 geometry (packed by pack_model.py, carried in .dtugeo_a/_b;
# the DTU scene in /tmp/gofdata for the cameras), on the GPU machine. Writes JSON and logs under $OUT.
# Usage: bash benchmarks/extract/dtu_gpu.sh VARIANT... (band | procs | full | faces | procs_faces: the Delaunay grid;
# octree: the default grid)
set -u
source benchmarks/extract/dtu_model.sh  # $EX/dtu.ply
for v in "$@"; do
  case $v in
    band) args="--grid delaunay --band" ;;
    procs) args="--grid delaunay --delaunay-processes" ;;
    full) args="--grid delaunay" ;;
    faces) args="--grid delaunay --max-faces 4300000" ;;
    procs_faces) args="--grid delaunay --delaunay-processes --max-faces 4300000" ;;
    octree) args="" ;;  # the default since session 10
    *) echo "unknown variant $v"; continue ;;
  esac
  /usr/bin/time -v python3 -m gof_warp.extract $EX/dtu.ply --scene /tmp/gofdata/dtu_scan24 --out $EX/mesh_$v.ply \
      --no-pictures $args > $EX/extract_$v.log 2>&1
  echo "$v rc $?"; tail -3 $EX/extract_$v.log
  cp $EX/mesh_$v.json $OUT/extract_$v.json 2>/dev/null
  grep -E "Maximum resident|Elapsed" $EX/extract_$v.log
  grep -E "Maximum resident|Elapsed" $EX/extract_$v.log > $OUT/time_$v.txt
done
