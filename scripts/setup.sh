#!/usr/bin/env bash
# Installs everything neuras-distill needs into ./.venv on a fresh Debian/Ubuntu machine.
# System packages: headless OpenGL (EGL + Mesa) and libusb for open3d. torch is installed first and pinned
# to the CPU wheel so that no resolver pulls gigabytes of CUDA packages (on a GPU machine, install the
# CUDA torch you want first; pip then keeps it).
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive PIP_DISABLE_PIP_VERSION_CHECK=1

need_apt=0
for lib in libEGL.so.1 libEGL_mesa.so.0 libusb-1.0.so.0 libgomp.so.1; do
  ldconfig -p 2>/dev/null | grep -q "$lib" || need_apt=1
done
ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 || need_apt=1
if [ "$need_apt" = 1 ]; then
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends libegl1 libegl-mesa0 libgl1-mesa-dri libusb-1.0-0 libgomp1 >/dev/null
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
if ! .venv/bin/python -c "import torch" >/dev/null 2>&1; then
  .venv/bin/python -m pip install -q "torch==2.13.0"
fi
.venv/bin/python -m pip install -q -e ".[test]"
# the Khronos glTF-Validator (tests/test_gltf.py, scripts/gltf_validate.mjs) and three.js (its GLTFLoader:
# tests/test_gltf_viewers.py, scripts/gltf_three_render.html; the page of export --format threejs:
# tests/test_threejs.py; the README names this version) into .tools/ when node and npm exist
if command -v node >/dev/null 2>&1 && command -v npm >/dev/null 2>&1; then
  [ -d .tools/node_modules/gltf-validator ] \
    || npm install --silent --no-fund --no-audit --prefix .tools gltf-validator@2.0.0-dev.3.10 >/dev/null \
    || echo "setup: npm install gltf-validator failed; the glTF validation test will be skipped"
  [ -f .tools/node_modules/three/build/three.module.js ] \
    || npm install --silent --no-fund --no-audit --prefix .tools three@0.187.0 >/dev/null \
    || echo "setup: npm install three failed; the three.js glTF test will be skipped"
  # Google's <model-viewer> (tests/test_gltf_up.py): its own prefix, since it pins an older three.js
  [ -f .tools/model-viewer/node_modules/@google/model-viewer/dist/model-viewer.min.js ] \
    || npm install --silent --no-fund --no-audit --prefix .tools/model-viewer @google/model-viewer@4.4.0 >/dev/null \
    || echo "setup: npm install @google/model-viewer failed; the model-viewer test will be skipped"
else
  echo "setup: no node/npm; the glTF validation and three.js tests will be skipped"
fi
echo "setup: done (.venv ready)"
