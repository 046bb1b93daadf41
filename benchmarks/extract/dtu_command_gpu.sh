#!/usr/bin/env bash
# Session 32: the whole default `python -m gof_warp.extract RUN` on a DTU scan 24 run folder, timed as a command
# (Python start-up, loading, extraction, writing the PLY, the mesh picture), three times, then without the picture.
# The run folder is rebuilt on the GPU machine from parked parts (/tmp/gofdata/s32: the packed geometry of session
# 32's DTU model, 781,428 Gaussians, and the cameras.json/config.yaml of a 1-iteration run of the same scene, made on
# the CPU, its scene path pointing at /tmp/gofdata/dtu_scan24). Writes $OUT/dtu_command/ (JSONs, times, picture).
set -u
D=/tmp/dturun; R=$OUT/dtu_command; mkdir -p $R
if [ ! -f $D/point_cloud.ply ]; then
  mkdir -p $D && cp /tmp/gofdata/s32/cameras.json /tmp/gofdata/s32/config.yaml $D/ &&
    python3 benchmarks/extract/pack_model.py unpack /tmp/gofdata/s32/dtu_s32_geometry.part0.npz $D/point_cloud.ply ||
    { echo "cannot rebuild the run folder"; exit 1; }
fi
timed() {  # name, args...: one whole extract command
  local name=$1; shift
  local a=$(date +%s.%N)
  python3 -m gof_warp.extract $D "$@" > $R/$name.log 2>&1
  local rc=$?
  echo "$name rc $rc wall $(python3 -c "print(round($(date +%s.%N) - $a, 2))") s" | tee -a $R/times.txt
  cp $D/mesh_tetra.json $R/$name.json 2>/dev/null
}
timed default_1
timed default_2
timed default_3
timed no_pictures --no-pictures
cp $D/pictures/mesh_tetra.png $R/ 2>/dev/null
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader > $R/gpu.txt
