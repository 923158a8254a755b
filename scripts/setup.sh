#!/usr/bin/env bash
# Set up assetpipe on a fresh Debian 12 machine (Python 3.11):
#   - Debian packages: Mesa lavapipe, the Vulkan loader, validation layers, glslang, spirv-tools,
#     and python3-venv (only what is missing; needs root or sudo);
#   - a virtual environment in .venv with assetpipe installed editable, with its test and farm extras.
# Idempotent: a second run installs nothing new.
set -euo pipefail
cd "$(dirname "$0")/.."

DEB_PKGS="mesa-vulkan-drivers libvulkan1 vulkan-validationlayers glslang-tools spirv-tools python3-venv python3-dev g++"
missing=""
for p in $DEB_PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "setup: installing Debian packages:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

# Node tools: ktx-parse (a second KTX2 implementation the tests check our files against),
# gltfpack (the LOD benchmark's peer) and meshoptimizer (its simplifier's WASM build, which the
# LOD step runs in-process with wasmtime: pipelines/meshopt_wasm.py), installed under .venv/node.
if ! command -v npm >/dev/null 2>&1; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "setup: installing Debian packages: nodejs npm"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq nodejs npm >/dev/null
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# Reinstall only when pyproject.toml changed since the last successful install.
stamp=.venv/.assetpipe-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[test,farm]"  # farm: the build-farm tests need Dask and s3fs
  touch "$stamp"
fi
if [ ! -f .venv/node/node_modules/ktx-parse/package.json ] || [ ! -f .venv/node/node_modules/gltfpack/package.json ] \
   || [ ! -f .venv/node/node_modules/meshoptimizer/package.json ]; then
  mkdir -p .venv/node
  npm install --silent --no-audit --no-fund --prefix .venv/node ktx-parse@2.0.0 gltfpack@1.3.0 meshoptimizer@1.3.0 >/dev/null
fi
