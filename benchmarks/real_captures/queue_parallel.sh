#!/usr/bin/env bash
# Several gpu_queue.py queues on one GPU at once, one state folder and one $OUT subfolder per queue:
#   bash benchmarks/real_captures/queue_parallel.sh BUDGET "fox:30000" "can" "background --resolution 400 400 --views 100"
# Each argument after BUDGET is one queue: its --scenes value, then any further gpu_queue.py options; "TAG=SCENES ..."
# names the queue TAG instead of after its first scene (two queues of one scene, e.g. with different overrides).
# The state of queue "NAME..." is /tmp/rcp_NAME (resumable across calls, its log there as queue.log); its results come back in
# $OUT/NAME/results.tar.gz (with --pack, its geometry beside it: a call brings back at most 8 files).
# Times measured this way are of runs that shared the GPU (and the host's cores) with the others.
# With SPREAD=1 on a machine of several GPUs, queue i runs alone on GPU i (modulo the GPU count): its times are of a
# GPU of its own, on a host shared with the other queues.
set -u
budget=$1; shift
pids=()
ngpu=$(nvidia-smi -L 2>/dev/null | wc -l); [ "$ngpu" -ge 1 ] || ngpu=1
i=0
for q in "$@"; do
  read -r scenes opts <<<"$q"
  name=${scenes%%:*}; name=${name%%,*}
  case $scenes in *=*) name=${scenes%%=*}; scenes=${scenes#*=} ;; esac
  mkdir -p "$OUT/$name" "/tmp/rcp_$name"
  gpu=()
  if [ "${SPREAD:-0}" = 1 ]; then gpu=(env CUDA_VISIBLE_DEVICES=$((i % ngpu))); fi
  i=$((i + 1))
  OUT="$OUT/$name" "${gpu[@]}" python3 benchmarks/real_captures/gpu_queue.py --budget "$budget" --state "/tmp/rcp_$name" \
    --scenes "$scenes" $opts >> "/tmp/rcp_$name/queue.log" 2>&1 &
  pids+=($!)
done
rc=0
for p in "${pids[@]}"; do wait "$p" || rc=1; done
for q in "$@"; do
  read -r scenes _ <<<"$q"; name=${scenes%%:*}; name=${name%%,*}
  case $scenes in *=*) name=${scenes%%=*} ;; esac
  echo "== $name"; tail -5 "/tmp/rcp_$name/queue.log"
done
nvidia-smi --query-gpu=memory.used --format=csv,noheader || true
exit $rc
