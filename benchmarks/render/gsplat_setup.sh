# Source on the GPU machine, after Warp's install.sh and benchmarks/device_setup.sh:
#     source benchmarks/render/gsplat_setup.sh
# Installs gsplat 1.5.3 (+ helpers) offline from the carried folder .whl_gs/ into /tmp/gsplat_site, sets
# up its CUDA build (nvcc, ninja, arch) and builds gsplat's CUDA extension once, printing the build time.
#
# How gsplat 1.5.3 gets its extension (gsplat/cuda/_backend.py, imported lazily on the first CUDA call):
# `from gsplat import csrc` (a prebuilt module, absent from the py3-none wheel) and, failing that, a JIT
# build with torch.utils.cpp_extension (_jit_compile, ninja) of gsplat/cuda/csrc/*.cu (20 files: 3DGS and
# 2DGS projection/rasterisation fwd+bwd, tile intersection, SH, Adam, relocation, ...) + csrc/*.cpp (8) +
# ext.cpp into $TORCH_EXTENSIONS_DIR/gsplat_cuda/gsplat_cuda.so, -O3 -use_fast_math, for the archs in
# TORCH_CUDA_ARCH_LIST, MAX_JOBS in parallel: 76 s on the H100 machine (16 cores, nvcc 13.0, arch 9.0a as
# that image presets). A later process on the same (warm) machine only re-checks the build (< 1 s).
#
# Fast path for a later cold machine: after a fresh build this script copies the extension to
# $OUT/gsplat_cuda.so.gz (+ .meta: torch version and arch). Put both into .whl_gs/ here and carry the
# folder again: the next run installs them as gsplat's prebuilt `gsplat.csrc` and skips the JIT build
# (only when torch and arch match; otherwise it builds as above).
_gs_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
_gs_whl="$_gs_root/.whl_gs"
_gs_site=/tmp/gsplat_site
if ! ls "$_gs_whl"/gsplat-*.whl >/dev/null 2>&1; then
  echo "gsplat_setup: no gsplat wheel in $_gs_whl: carry the .whl_gs folder (carry: [\".whl_gs\"])" >&2
  return 3 2>/dev/null || exit 3
fi

# 1. wheels: gsplat always; each helper only where the image's python3 lacks it (so that nothing the image
#    already has, e.g. rich or jaxtyping, is shadowed by another version on PYTHONPATH)
if [ ! -f "$_gs_site/gsplat/__init__.py" ]; then
  _gs_list=("$_gs_whl"/gsplat-*.whl)
  for _w in "$_gs_whl"/*.whl; do
    _n="$(basename "$_w" | cut -d- -f1)"
    case "$_n" in
      gsplat) continue ;;
      markdown_it_py) _m=markdown_it ;;
      *) _m="$_n" ;;
    esac
    python3 -c "import $_m" >/dev/null 2>&1 || _gs_list+=("$_w")
  done
  echo "gsplat_setup: installing $(for w in "${_gs_list[@]}"; do basename "$w" | cut -d- -f1-2; done | tr '\n' ' ')"
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$_gs_site" "${_gs_list[@]}" \
    || { echo "gsplat_setup: pip install from $_gs_whl failed" >&2; return 4 2>/dev/null || exit 4; }
fi
export PYTHONPATH="$_gs_site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
export PATH="$_gs_site/bin:$PATH"  # ninja, if its wheel was installed (the image has one too)

# 2. the CUDA build's environment
if ! command -v nvcc >/dev/null 2>&1; then
  for _d in "${CUDA_HOME:-}" /usr/local/cuda /usr/local/cuda-13.0 /usr/local/cuda-13; do
    if [ -n "$_d" ] && [ -x "$_d/bin/nvcc" ]; then export CUDA_HOME="$_d" PATH="$_d/bin:$PATH"; break; fi
  done
fi
command -v nvcc >/dev/null 2>&1 || echo "gsplat_setup: WARNING: no nvcc found: gsplat cannot build its extension" >&2
command -v ninja >/dev/null 2>&1 || echo "gsplat_setup: WARNING: no ninja found: torch's JIT build needs it" >&2
export TORCH_EXTENSIONS_DIR=/tmp/torch_ext
export MAX_JOBS="${MAX_JOBS:-16}"
if [ -z "${TORCH_CUDA_ARCH_LIST:-}" ]; then  # H100/H200: 9.0
  TORCH_CUDA_ARCH_LIST="$(python3 -c 'import torch; print("%d.%d" % torch.cuda.get_device_capability(0))' 2>/dev/null)"
  export TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-9.0}"
fi
_gs_key="$(python3 -c 'import torch; print(torch.__version__)')|$TORCH_CUDA_ARCH_LIST"
echo "gsplat_setup: nvcc $(nvcc --version 2>/dev/null | grep -o 'release [0-9.]*'), ninja $(ninja --version 2>/dev/null)," \
     "TORCH_CUDA_ARCH_LIST=$TORCH_CUDA_ARCH_LIST MAX_JOBS=$MAX_JOBS TORCH_EXTENSIONS_DIR=$TORCH_EXTENSIONS_DIR"

# 3. a carried prebuilt extension (see the fast path above), if it matches this torch and arch
if [ -f "$_gs_whl/gsplat_cuda.so.gz" ] && [ ! -f "$_gs_site/gsplat/csrc.py" ]; then
  if [ "$(cat "$_gs_whl/gsplat_cuda.so.gz.meta" 2>/dev/null)" = "$_gs_key" ]; then
    gzip -dc "$_gs_whl/gsplat_cuda.so.gz" > "$_gs_site/gsplat/gsplat_cuda.so"
    cat > "$_gs_site/gsplat/csrc.py" <<'PY'
# gsplat's "prebuilt extension" hook (gsplat/cuda/_backend.py tries `from gsplat import csrc` first): loads the
# carried gsplat_cuda.so (built by torch's JIT with TORCH_EXTENSION_NAME=gsplat_cuda) under its own name.
import importlib.util as _u
import os as _os

import torch as _torch  # noqa: F401  (the extension links against torch's libraries)

_spec = _u.spec_from_file_location("gsplat_cuda", _os.path.join(_os.path.dirname(__file__), "gsplat_cuda.so"))
_mod = _u.module_from_spec(_spec)
_spec.loader.exec_module(_mod)
globals().update({k: v for k, v in vars(_mod).items() if not k.startswith("__")})
PY
    echo "gsplat_setup: using the carried prebuilt extension ($_gs_key)"
  else
    echo "gsplat_setup: carried gsplat_cuda.so.gz is for '$(cat "$_gs_whl/gsplat_cuda.so.gz.meta" 2>/dev/null)', not '$_gs_key': building"
  fi
fi

# 4. build (or load) the extension once with a tiny render, timed
python3 - <<'PY' || { echo "gsplat_setup: gsplat's extension failed to build or run (see above)" >&2; return 5 2>/dev/null || exit 5; }
import time
import torch
t0 = time.time()
import gsplat
from gsplat.cuda._backend import _C  # triggers the JIT build when there is no gsplat.csrc
if _C is None:
    raise SystemExit("gsplat_setup: gsplat found no CUDA toolkit (nvcc) and disabled its extension")
t1 = time.time()
dev = "cuda"
n = 64
q = torch.nn.functional.normalize(torch.randn(n, 4, device=dev), dim=1)
means = torch.randn(n, 3, device=dev) * 0.3 + torch.tensor([0.0, 0.0, 3.0], device=dev)
K = torch.tensor([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]], device=dev)[None]
img, alpha, _ = gsplat.rasterization(means, q, torch.full((n, 3), 0.05, device=dev), torch.full((n,), 0.8, device=dev),
                                     torch.rand(n, 16, 3, device=dev), torch.eye(4, device=dev)[None], K, 64, 48,
                                     sh_degree=3, render_mode="RGB+ED")
torch.cuda.synchronize()
print(f"gsplat_setup: gsplat {gsplat.__version__} extension ready in {t1 - t0:.1f} s "
      f"(first render {time.time() - t1:.2f} s, mean alpha {float(alpha.mean()):.3f}), from {gsplat.cuda._backend.__file__}")
PY
_gs_so="$TORCH_EXTENSIONS_DIR/gsplat_cuda/gsplat_cuda.so"
if [ -n "${OUT:-}" ] && [ -d "$OUT" ] && [ -f "$_gs_so" ] && [ ! -f "$_gs_site/gsplat/csrc.py" ]; then
  gzip -c "$_gs_so" > "$OUT/gsplat_cuda.so.gz" && echo "$_gs_key" > "$OUT/gsplat_cuda.so.gz.meta"
  echo "gsplat_setup: saved the built extension to \$OUT/gsplat_cuda.so.gz ($(du -h "$OUT/gsplat_cuda.so.gz" | cut -f1)); copy it and its .meta into .whl_gs/ to skip the build next time"
fi
unset _gs_root _gs_whl _gs_site _gs_list _gs_key _gs_so _w _n _m _d
