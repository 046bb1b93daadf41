#!/usr/bin/env bash
# Where DTU training's reserved memory goes, and what gives it back: memory_probe.py on the first ITERS iterations
# (default 4000) with the allocator as it is (allocation history and a snapshot), with expandable segments, and with
# torch.cuda.empty_cache() after every change of the Gaussian count. On the GPU machine, after device_setup.sh:
#   bash benchmarks/train/memory_variants.sh .bench_data/dtu_scan24 "$OUT" [ITERS]
set -u
scene=$1 out=$2 iters=${3:-4000}
probe=benchmarks/train/memory_probe.py
run() {  # name, extra args...
  local name=$1; shift
  timeout 200 python3 $probe "$scene" --config dtu --iterations "$iters" --out /tmp/probe_$name "$@" >"$out/$name.log" 2>&1
  echo "$name rc=$?"
  cp /tmp/probe_$name/memory_probe.json "$out/$name.json" 2>/dev/null
  grep -E '"(loop_s|max_reserved_mb|max_allocated_mb|num_alloc_retries)"' "$out/$name.log"
}
run asis --history 100000
[ -f /tmp/probe_asis/snapshot.pickle ] && gzip -c /tmp/probe_asis/snapshot.pickle >"$out/snapshot_asis.pickle.gz"
run expandable --alloc-conf expandable_segments:True
run emptycache --empty-cache-on-change
