#!/usr/bin/env bash
# Installs everything neuras-distill needs into ./.venv (or $VENV) on a fresh machine.
# System libraries: headless OpenGL (EGL + Mesa) and OpenMP, with apt-get on Debian/Ubuntu; elsewhere it names
# them and goes on. torch is installed first, as a CPU build, so that no resolver pulls gigabytes of CUDA
# packages; a torch already in the venv is kept (on a GPU machine, install the CUDA torch you want first).
# Environment: PYTHON (the interpreter, default python3), VENV (default .venv), TORCH_INDEX (a pip index URL
# to take torch from; default: a CPU wheel pip already finds, else PyTorch's CPU index).
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive PIP_DISABLE_PIP_VERSION_CHECK=1

need_apt=0
for lib in libEGL.so.1 libEGL_mesa.so.0 libgomp.so.1; do
  ldconfig -p 2>/dev/null | grep -q "$lib" || need_apt=1
done
ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 || need_apt=1
if [ "$need_apt" = 1 ]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq --no-install-recommends libegl1 libegl-mesa0 libgl1-mesa-dri libgomp1 >/dev/null
  else
    echo "setup: no apt-get; install EGL with Mesa's drivers and OpenMP yourself (Fedora: mesa-libEGL" \
         "mesa-dri-drivers libgomp; Arch: mesa libglvnd gcc-libs), or the GL tests and players will not run"
  fi
fi

PY=${PYTHON:-python3}
VENV=${VENV:-.venv}
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null 2>&1 || true
if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  TORCH="torch==2.13.0"
  CPU_INDEX="https://download.pytorch.org/whl/cpu"
  if [ -n "${TORCH_INDEX:-}" ]; then
    "$VENV/bin/python" -m pip install -q "$TORCH" --index-url "$TORCH_INDEX"
  else
    # the wheel pip would take: a local file or a +cpu build is the CPU one; PyPI's Linux x86_64 wheel is CUDA
    picked=$("$VENV/bin/python" -m pip install --dry-run --no-deps --quiet --report - "$TORCH" 2>/dev/null \
             | "$VENV/bin/python" -c "import json,sys; print(json.load(sys.stdin)['install'][0]['download_info']['url'])" \
             2>/dev/null || true)
    if [[ "$picked" == file:* || "$picked" == *"%2Bcpu"* || "$picked" == *"+cpu"* || "$(uname -s)" != Linux \
          || "$(uname -m)" != x86_64 ]]; then
      "$VENV/bin/python" -m pip install -q "$TORCH"
    elif "$VENV/bin/python" -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=10)" \
         "$CPU_INDEX/torch/" >/dev/null 2>&1; then
      "$VENV/bin/python" -m pip install -q "$TORCH" --index-url "$CPU_INDEX"
    else
      echo "setup: PyTorch's CPU index ($CPU_INDEX) is out of reach; installing $TORCH from your index (on Linux" \
           "x86_64 that is the CUDA build, several GB; set TORCH_INDEX to a CPU index to avoid it)"
      "$VENV/bin/python" -m pip install -q "$TORCH"
    fi
  fi
fi
"$VENV/bin/python" -m pip install -q -e ".[test]"
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
  # 3DTilesRendererJS (tests/test_tiles.py: the page of export --format 3dtiles streams a tileset with it)
  [ -f .tools/node_modules/3d-tiles-renderer/build/index.three.js ] \
    || npm install --silent --no-fund --no-audit --prefix .tools 3d-tiles-renderer@0.5.3 >/dev/null \
    || echo "setup: npm install 3d-tiles-renderer failed; the tiles page test will be skipped"
  # CesiumJS (tests/test_tiles.py: the tileset on the globe), its own prefix like model-viewer's
  [ -f .tools/cesium/node_modules/cesium/Build/Cesium/Cesium.js ] \
    || npm install --silent --no-fund --no-audit --prefix .tools/cesium cesium@1.145.0 >/dev/null \
    || echo "setup: npm install cesium failed; the CesiumJS test will be skipped"
  # Google's <model-viewer> (tests/test_gltf_up.py): its own prefix, since it pins an older three.js
  [ -f .tools/model-viewer/node_modules/@google/model-viewer/dist/model-viewer.min.js ] \
    || npm install --silent --no-fund --no-audit --prefix .tools/model-viewer @google/model-viewer@4.4.0 >/dev/null \
    || echo "setup: npm install @google/model-viewer failed; the model-viewer test will be skipped"
else
  echo "setup: no node/npm; the glTF validation and three.js tests will be skipped"
fi
echo "setup: done ($VENV ready)"
