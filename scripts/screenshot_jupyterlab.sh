#!/usr/bin/env bash
# Screenshot JupyterLab with one study notebook open, as a user sees it (headless Chromium from Debian's
# packages, installed here on demand). JupyterLab runs from .venv on 127.0.0.1 with a random port and token
# and is stopped afterwards.
#
#   bash scripts/screenshot_jupyterlab.sh [NOTEBOOK (repo-relative)] [OUT.png]
#   default: reports/quick/05_ablation_fusion.ipynb -> reports/quick/jupyterlab_05_ablation_fusion.png
set -euo pipefail
cd "$(dirname "$0")/.."
NB="${1:-reports/quick/05_ablation_fusion.ipynb}"
OUT="${2:-reports/quick/jupyterlab_$(basename "${NB%.ipynb}").png}"
[ -f "$NB" ] || { echo "screenshot: notebook $NB does not exist" >&2; exit 2; }
[ -x .venv/bin/jupyter ] || { echo "screenshot: .venv/bin/jupyter missing; run bash scripts/setup.sh" >&2; exit 2; }
if ! command -v chromium >/dev/null; then
  echo "screenshot: installing Debian's chromium (once)"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q chromium
fi
PY=.venv/bin/python
PORT=$($PY -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
TOKEN=$($PY -c "import secrets; print(secrets.token_hex(16))")
TMP=$(mktemp -d)
ROOT_FLAG=""; [ "$(id -u)" -eq 0 ] && ROOT_FLAG="--allow-root"  # JupyterLab refuses root without it
JUPYTERLAB_WORKSPACES_DIR="$TMP/ws" JUPYTER_RUNTIME_DIR="$TMP/rt" JUPYTERLAB_SETTINGS_DIR="$TMP/settings" \
  .venv/bin/jupyter lab --no-browser --ip=127.0.0.1 --port="$PORT" --IdentityProvider.token="$TOKEN" \
  --ServerApp.root_dir="$PWD" --ServerApp.port_retries=0 $ROOT_FLAG > "$TMP/lab.log" 2>&1 &
LAB=$!
trap 'kill "$LAB" 2>/dev/null || true; wait "$LAB" 2>/dev/null || true; rm -rf "$TMP"' EXIT
# Wait (at most 60 s) for the server to answer.
$PY - "$PORT" "$TOKEN" <<'EOF' || { echo "screenshot: jupyter lab did not start:" >&2; tail -20 "$TMP/lab.log" >&2; exit 1; }
import sys, time, urllib.request
port, token = sys.argv[1], sys.argv[2]
for _ in range(120):
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status?token={token}", timeout=2)
        sys.exit(0)
    except OSError:
        time.sleep(0.5)
sys.exit(1)
EOF
mkdir -p "$(dirname "$OUT")"
# The background-networking flags keep Chromium from calling out of this closed network.
timeout 180 chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run \
  --disable-background-networking --disable-component-update --disable-sync --hide-scrollbars \
  --user-data-dir="$TMP/chrome" --window-size=1500,1000 --virtual-time-budget=30000 \
  --screenshot="$OUT" "http://127.0.0.1:$PORT/lab/tree/$NB?token=$TOKEN&reset" 2> "$TMP/chrome.log" \
  || { echo "screenshot: chromium failed:" >&2; tail -20 "$TMP/chrome.log" >&2; exit 1; }
echo "screenshot: $OUT"
