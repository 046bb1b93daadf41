# Source on the GPU machine (after ../shared/device's Warp install.sh): makes this checkout importable
# without `pip install` (which that machine cannot do) and installs carried wheels from .whl/ if any.
ln -sfn ../kernels gof_warp/kernels
ln -sfn ../configs gof_warp/configs
if [ -d .whl ] && ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
fi
export PYTHONPATH="$PWD:/tmp/site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
