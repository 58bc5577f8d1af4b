#!/usr/bin/env bash
# On a lent GPU machine (the `device` tool, which sends this checkout's files with the carried `.gpu/` of
# scripts/gpu_zoo/bundle.py): unpack the GL loaders and wheels, then train with run.py.
#   bash scripts/gpu_zoo/device.sh [run.py options] NAME ...
set -uo pipefail
export GPU_ZOO_T0="$(date +%s)"
cd "$(dirname "$0")/../.."
test -f .gpu/REVISION || { echo "device.sh: no .gpu/ (run scripts/gpu_zoo/bundle.py and carry .gpu)"; exit 2; }
for f in .gpu/gl/*.deb; do dpkg -x "$f" /; done; ldconfig
nv=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$nv" ] && export __EGL_VENDOR_LIBRARY_FILENAMES="$nv"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .gpu/whl/*.whl || exit 3
export PYTHONPATH="$PWD/src:$PWD/.gpu/mods:/tmp/site" HELPERS_CACHE_DIR="${HELPERS_CACHE_DIR:-/tmp/cache}"
export HELPERS_GIT_REVISION="$(cat .gpu/REVISION)" PYOPENGL_PLATFORM="${PYOPENGL_PLATFORM:-egl}"
export PYGLET_HEADLESS=1  # pyrender imports its viewer (pyglet), which looks for X libraries otherwise
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || true
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
python3 scripts/gpu_zoo/run.py "$@"
