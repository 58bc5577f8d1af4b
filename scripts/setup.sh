#!/usr/bin/env bash
# Set up this study on a fresh Debian machine: headless GL libraries (apt) and
# the locked Python environment in ./.venv. Idempotent: a second run checks and
# returns quickly.
set -euo pipefail
cd "$(dirname "$0")/.."

GL_PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0 libosmesa6"
missing=""
for p in $GL_PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "setup: installing headless GL packages:$missing"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q $missing
fi

# Debian's Chromium for the real-browser test of the explorer notebook (tests/test_browser.py drives it
# with Playwright; no browser is downloaded at run time). Optional: without it that test is skipped, saying why.
if ! command -v chromium >/dev/null 2>&1; then
  echo "setup: installing chromium (browser test)"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  { $SUDO apt-get update -q && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q chromium; } \
    || echo "setup: chromium could not be installed; tests/test_browser.py will be skipped"
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$PY" -m venv .venv
fi
want="$(sha256sum environment.lock pyproject.toml | sha256sum | cut -c1-16)"
have="$(cat .venv/.setup-stamp 2>/dev/null || true)"
if [ "$want" != "$have" ]; then
  echo "setup: installing environment.lock into .venv"
  .venv/bin/python -m pip install -q --upgrade "pip==25.3"
  # --no-deps: the lock is complete (setuptools included, for the editable build below); it also keeps the mesh-source packages
  # (robosuite, metaworld, ...) from pulling simulators we never import.
  .venv/bin/python -m pip install -q --no-deps -r environment.lock
  .venv/bin/python -m pip install -q --no-deps --no-build-isolation -e .
  echo "$want" > .venv/.setup-stamp
fi
.venv/bin/python -c "import helpers.data.manifest as m; m.verify(); print('setup: ok, manifest verified')"
