#!/usr/bin/env bash
# Set up (scripts/setup.sh) and run the test suite: everything but the benchmarks, the
# corpus-wide runs included. Extra arguments go to pytest (e.g. -k textures, -m corpus).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
if [ "$#" -eq 0 ]; then
  set -- -m "not bench"
fi
exec .venv/bin/python -m pytest -p no:cacheprovider "$@"
