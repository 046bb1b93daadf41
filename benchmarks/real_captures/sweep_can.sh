#!/usr/bin/env bash
# colmap_can diagnosis on one GPU (session 6): short runs of the preset `train` picks, each with one change, all at
# once, through variants.sh (resumable: call again with the same arguments until every variant is done):
#   bash benchmarks/real_captures/sweep_can.sh SCENE ITERATIONS [BUDGET_S]  → $OUT/variants/<variant>/..., summary.json
# Runs share the GPU and the host, so their times are not comparable with runs that had it alone.
set -u
exec bash "$(dirname "$0")/variants.sh" "$1" "$2" "${3:-540}" \
  base="" \
  appearance="appearance=true" \
  half_res="data.downscale=2" \
  appearance_half_res="appearance=true data.downscale=2" \
  grad_x2="densify.grad_threshold=0.0004 densify.abs_grad_threshold=0.0004" \
  no_filter3d="model.use_filter_3d=false"
