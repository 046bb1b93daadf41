# Source with W, N, DATA (and WARM) set: writes synthetic_run.py's N-Gaussian run folder to $W/run and compiles Warp's
# extraction kernels with a ${WARM:-20000}-Gaussian extraction outside any timed run; exits the caller on failure.
rm -rf "$W"; mkdir -p "$W"
_t0=$(date +%s)
python3 benchmarks/distributed/synthetic_run.py "$N" --out "$W/run" --data "$DATA" || { echo "model failed"; exit 1; }
python3 benchmarks/distributed/synthetic_run.py "${WARM:-20000}" --out "$W/warm" --data "$DATA" >/dev/null
python3 -m gof_warp.extract "$W/warm" --no-pictures --quiet > "$W/warm.log" 2>&1 || { tail "$W/warm.log"; exit 1; }
echo "model and warm-up in $(( $(date +%s) - _t0 )) s"
